"""The pan-tilt unit (a Directed Perception / FLIR PTU-D46 on RS232).

``create(settings, world)`` returns a :class:`Ptu`. Every backend only provides the serial
line: the front end runs the same :class:`~drivers.ptu.client.PtuClient` over pyserial on
it. ``serial`` (:mod:`drivers.ptu.line`) hands over ``settings.port`` (any pyserial URL);
``sim`` starts a :class:`~drivers.ptu.emulator.PtuEmulator` on a pseudo-terminal and hands over
its slave side, so simulation exercises the real protocol byte for byte and the emulator moves
the sensor head in the simulated world (``world.set_ptu``) as it turns.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping
from typing import Any

from drivers.base import Cancel, DeviceError
from drivers.ptu import line as _line  # noqa: F401 - registers the sim and serial backends
from drivers.ptu import replay as _replay  # noqa: F401 - registers the replay backend
from drivers.ptu.backend import BACKENDS, PtuBackend, PtuSettings
from drivers.ptu.client import DEVICE, MoveInterrupted, PtuClient, ReplyTimeout
from drivers.ptu.emulator import PtuEmulator
from drivers.registry import Capability
from rvs_params import Settings

__all__ = ["BACKENDS", "PEERS", "MoveInterrupted", "Ptu", "PtuSettings", "ReplyTimeout", "create"]


class Ptu:
    """The PTU device: the registry's surface (open/close/status/check/reinit/reset) plus the
    pan-tilt operations the server and the console use, all in degrees.

    Any operation opens the device if it is closed, so a failed PTU is retried by simply using
    it again. ``status()`` never touches the serial line.
    """

    name = DEVICE

    def __init__(self, settings: Mapping[str, Any] | Settings | None = None, world: Any = None) -> None:
        self.settings = BACKENDS.settings(settings)
        self.line: PtuBackend = BACKENDS.create(self.settings, world)
        self.backend = self.line.name
        self.capabilities = self.line.capabilities
        self._lock = threading.RLock()  # open/close/reinit; exchanges are serialised by the client
        self._client: PtuClient | None = None
        self._port: str | None = None
        self._last_error: str | None = None

    # -- the device protocol ---------------------------------------------------------------------
    def open(self) -> None:
        with self._lock:
            if self._client is not None and self._client.is_open:
                return
            self._port = self.line.connect()
            st = self.settings
            client = PtuClient(
                self._port,
                st.baudrate,
                timeout=st.timeout,
                move_timeout=st.move_timeout,
                reset_timeout=st.reset_timeout,
                speed=st.speed,
                acceleration=st.acceleration,
            )
            try:
                client.open()
            except DeviceError as exc:
                self._last_error = exc.message
                raise
            self._client = client
            self._last_error = None

    def close(self) -> None:
        with self._lock:
            self._close_client()
            self.line.disconnect()
            self._port = None

    def reinit(self) -> None:
        """Close and reopen the serial side; a simulated unit keeps its state and faults, as a
        real one keeps its power."""
        with self._lock:
            self._close_client()
            self.open()

    def reset(self, cancel: Cancel = None) -> tuple[float, float]:
        return self._call(lambda c: c.reset(cancel=cancel))

    def check(self) -> dict[str, Any]:
        def probe(c: PtuClient) -> dict[str, Any]:
            pan, tilt = c.position()
            return {"pan_deg": pan, "tilt_deg": tilt, **_public(c.power_status())}

        return self._call(probe)

    def status(self) -> dict[str, Any]:
        client = self._client
        state: dict[str, Any] = client.snapshot() if client is not None else {"open": False}
        state.update(
            name=self.name, backend=self.backend, port=self._port or self.settings.port,
            baudrate=self.settings.baudrate, last_error=self._last_error,
        )
        state.update(self.line.status())
        return state

    # -- pan-tilt operations -----------------------------------------------------------------------
    def move(
        self,
        pan_deg: float | None,
        tilt_deg: float | None,
        wait: bool = True,
        *,
        cancel: Cancel = None,
        timeout: float | None = None,
    ) -> tuple[float, float]:
        """Absolute move in degrees (None keeps that axis); returns the reported position.

        ``cancel`` (a callable or threading.Event) and ``halt()`` stop the wait with
        :class:`MoveInterrupted`; a move that does not end within ``timeout`` (default
        ``move_timeout``) is halted and raises DeviceError.
        """
        return self._call(lambda c: c.move(pan_deg, tilt_deg, wait, cancel=cancel, timeout=timeout))

    def wait(self, *, cancel: Cancel = None, timeout: float | None = None) -> tuple[float, float]:
        """Await a move started with ``wait=False``."""
        def run(c: PtuClient) -> tuple[float, float]:
            c.await_motion(cancel=cancel, timeout=timeout)
            return c.position()

        return self._call(run)

    def position(self) -> tuple[float, float]:
        return self._call(lambda c: c.position())

    def limits(self) -> dict[str, dict[str, float]]:
        return self._call(lambda c: c.limits())

    def halt(self) -> None:
        """Stop both axes; a move awaiting in another thread stops at once with MoveInterrupted."""
        client = self._client
        if client is not None:
            client.interrupt()  # before any lock: a reinit queued behind the move must not delay it
        self._call(lambda c: c.halt())

    def set_speed(self, pan_pos_s: float | None, tilt_pos_s: float | None = None) -> None:
        self._call(lambda c: c.set_speed(pan_pos_s, tilt_pos_s))

    def set_acceleration(self, pan_pos_s2: float | None, tilt_pos_s2: float | None = None) -> None:
        self._call(lambda c: c.set_acceleration(pan_pos_s2, tilt_pos_s2))

    def speed(self) -> tuple[int, int]:
        return self._call(lambda c: c.get_speed())

    def acceleration(self) -> tuple[int, int]:
        return self._call(lambda c: c.get_acceleration())

    def motion(self) -> dict[str, dict[str, float]]:
        """Per axis: speed, acceleration and base speed in degrees (see PtuClient.motion)."""
        return self._call(lambda c: c.motion())

    def power_status(self) -> dict[str, Any]:
        return self._call(lambda c: c.power_status())

    def firmware(self) -> str:
        return self._call(lambda c: c.firmware())

    def raw(self, command: str) -> str:
        """Send any D46 command; returns the reply as printed ("* 583", "! Illegal command")."""
        return self._call(lambda c: c.raw(command))

    # -- simulation ------------------------------------------------------------------------------
    @property
    def emulator(self) -> PtuEmulator | None:
        """The simulated unit behind the line (None for a real one)."""
        return self.line.emulator

    def inject_fault(self, kind: str | None) -> None:
        """A simulator's fault (``silent``, ``garbage`` as at a wrong baud rate, ``stall``) or None."""
        if Capability.FAULTS not in self.capabilities:
            raise DeviceError(DEVICE, "faults can only be injected into the sim backend")
        if kind in ("", "none", "None"):
            kind = None
        if kind is not None and kind not in self.line.faults:
            raise DeviceError(DEVICE, f"unknown fault {kind!r}; use {', '.join(self.line.faults)} or none")
        with self._lock:
            self.line.inject_fault(kind)

    def reconfigure(self, settings: Settings) -> list[str]:
        """The unit takes no setting while open: every change waits for its reinit."""
        return []

    # -- internals -------------------------------------------------------------------------------
    def _close_client(self) -> None:
        client, self._client = self._client, None
        if client is not None:
            client.close()

    def _call(self, fn: Any) -> Any:
        try:
            with self._lock:
                if self._client is None or not self._client.is_open:
                    self.open()
                client = self._client
            assert client is not None
            result = fn(client)
        except MoveInterrupted:
            raise
        except DeviceError as exc:
            self._last_error = exc.message
            raise
        return result


def _public(power: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in power.items() if k != "raw"}


PEERS: tuple[str, ...] = ()  # built after, and given to create() as, these device kinds


def create(settings: Mapping[str, Any] | Settings | None, world: Any = None) -> Ptu:
    """The PTU for the ``drivers.ptu`` settings; not opened yet."""
    return Ptu(settings, world)
