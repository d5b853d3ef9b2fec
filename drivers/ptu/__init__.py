"""The pan-tilt unit (a Directed Perception / FLIR PTU-D46 on RS232).

``create(config, world)`` returns a :class:`Ptu`. Both backends run the same
:class:`~drivers.ptu.client.PtuClient` over pyserial: ``serial`` opens ``config["port"]`` (any
pyserial URL); ``sim`` starts a :class:`~drivers.ptu.emulator.PtuEmulator` on a pseudo-terminal
and opens its slave side, so simulation exercises the real protocol byte for byte and the
emulator moves the sensor head in the simulated world (``world.set_ptu``) as it turns.
"""

from __future__ import annotations

import os
import threading
from typing import Any

from drivers.base import DeviceError
from drivers.ptu.client import DEVICE, Cancel, MoveInterrupted, PtuClient, ReplyTimeout
from drivers.ptu.emulator import FAULTS, PtuEmulator, open_pty

__all__ = ["BACKENDS", "DEFAULTS", "FAULTS", "MoveInterrupted", "Ptu", "ReplyTimeout", "create"]

BACKENDS = ("sim", "serial")
DEFAULTS: dict[str, Any] = {
    "backend": "sim",
    "port": "/dev/ttyUSB0",
    "baudrate": 9600,
    "timeout": 2.0,
    "move_timeout": 30.0,
    "reset_timeout": 60.0,
    "speed": 1000,
    "acceleration": 2000,
    "time_scale": 1.0,
}


class Ptu:
    """The PTU device: the registry's surface (open/close/status/check/reinit/reset) plus the
    pan-tilt operations the server and the console use, all in degrees.

    Any operation opens the device if it is closed, so a failed PTU is retried by simply using
    it again. ``status()`` never touches the serial line.
    """

    name = DEVICE

    def __init__(self, config: dict[str, Any] | None = None, world: Any = None) -> None:
        self.config = {**DEFAULTS, **(config or {})}
        backend = str(self.config["backend"])
        if backend not in BACKENDS:
            raise DeviceError(DEVICE, f"unknown backend {backend!r} for drivers.ptu.backend; use sim or serial")
        self.backend = backend
        self.world = world
        self._lock = threading.RLock()  # open/close/reinit; exchanges are serialised by the client
        self._client: PtuClient | None = None
        self._emulator: PtuEmulator | None = None
        self._fds: tuple[int, int] | None = None
        self._port = str(self.config["port"]) if backend == "serial" else None
        self._fault: str | None = None
        self._last_error: str | None = None

    # -- the device protocol ---------------------------------------------------------------------
    def open(self) -> None:
        with self._lock:
            if self._client is not None and self._client.is_open:
                return
            if self.backend == "sim":
                self._start_emulator()
            assert self._port is not None
            client = PtuClient(
                self._port,
                int(self.config["baudrate"]),
                timeout=float(self.config["timeout"]),
                move_timeout=float(self.config["move_timeout"]),
                reset_timeout=float(self.config["reset_timeout"]),
                speed=self.config.get("speed"),
                acceleration=self.config.get("acceleration"),
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
            if self._emulator is not None:
                self._emulator.stop()
                self._emulator = None
            if self._fds is not None:
                for fd in self._fds:
                    try:
                        os.close(fd)
                    except OSError:
                        pass
                self._fds = None
                self._port = None

    def reinit(self) -> None:
        """Close and reopen the serial side; a simulated unit keeps its state and faults, as a
        real one keeps its power."""
        with self._lock:
            self._close_client()
            self.open()

    def reset(self) -> tuple[float, float]:
        return self._call(lambda c: c.reset())

    def check(self) -> dict[str, Any]:
        def probe(c: PtuClient) -> dict[str, Any]:
            pan, tilt = c.position()
            return {"pan_deg": pan, "tilt_deg": tilt, **_public(c.power_status())}

        return self._call(probe)

    def status(self) -> dict[str, Any]:
        client = self._client
        state: dict[str, Any] = client.snapshot() if client is not None else {"open": False}
        state.update(
            name=self.name, backend=self.backend, port=self._port or self.config["port"],
            baudrate=int(self.config["baudrate"]), last_error=self._last_error,
        )
        if self.backend == "sim":
            emu = self._emulator
            state.update(fault=self._fault, time_scale=float(self.config["time_scale"]),
                         emulator_running=bool(emu and emu.running))
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
        return self._emulator

    def inject_fault(self, kind: str | None) -> None:
        """sim only: None (healthy), "silent", "garbage" (wrong baud rate) or "stall"."""
        if self.backend != "sim":
            raise DeviceError(DEVICE, "faults can only be injected into the sim backend")
        if kind in ("", "none", "None"):
            kind = None
        if kind not in FAULTS:
            raise DeviceError(DEVICE, f"unknown fault {kind!r}; use silent, garbage, stall or none")
        with self._lock:
            self._fault = kind
            if self._emulator is not None:
                self._emulator.inject_fault(kind)

    # -- internals -------------------------------------------------------------------------------
    def _start_emulator(self) -> None:
        if self._emulator is not None and self._emulator.running:
            return
        master, slave, path = open_pty()
        self._fds, self._port = (master, slave), path
        on_position = getattr(self.world, "set_ptu", None) if self.world is not None else None
        self._emulator = PtuEmulator(
            master, time_scale=float(self.config["time_scale"]), on_position=on_position, fault=self._fault
        ).start()

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


def create(config: dict[str, Any], world: Any = None) -> Ptu:
    """The PTU for ``config`` (the ``drivers.ptu`` section); not opened yet."""
    return Ptu(config, world)
