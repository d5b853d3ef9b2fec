"""The trigger box front end: the pulse counter, the status snapshot and the lock, over a backend.

A pulse is the whole job of the box (seed 000 sect. 4.1.5: setting pin 2 of the LPT connector
fires both cameras), so the interface is small: ``pulse() -> count``. The count lets a caller
tell which pulse a captured frame belongs to.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Mapping
from typing import Any

from drivers.base import Cancel, DeviceError
from drivers.registry import Capability
from drivers.trigger.backend import BACKENDS, TriggerBackend
from rvs_params import Settings


class Trigger:
    """The box: one pulse at a time over whichever backend the settings name."""

    name = "trigger"

    def __init__(self, settings: Mapping[str, Any] | Settings | None = None, world: Any = None) -> None:
        self.settings = BACKENDS.settings(settings)
        self.pulse_us = float(self.settings.pulse_us)
        if not 0 < self.pulse_us <= 1_000_000:
            raise ValueError(f"trigger pulse_us must be in (0, 1e6] microseconds, got {self.pulse_us}")
        self.port: TriggerBackend = BACKENDS.create(self.settings, world)
        self.backend = self.port.name
        self.capabilities = self.port.capabilities
        self._lock = threading.Lock()  # one pulse at a time
        self._state_lock = threading.Lock()  # status() never waits for a pulse
        self._count = 0
        self._open = False
        self._busy = False
        self._last_error: str | None = None
        self._last_pulse_time: float | None = None

    # -- the device protocol ---------------------------------------------------------------
    def open(self) -> None:
        with self._lock:
            self.port.open()
            with self._state_lock:
                self._open = True
                self._last_error = None

    def close(self) -> None:
        with self._lock:
            try:
                self.port.close()
            finally:
                with self._state_lock:
                    self._open = False

    def reinit(self) -> None:
        """Close and open again: what clears a port that another driver grabbed meanwhile."""
        self.close()
        self.open()

    def reset(self, cancel: Cancel = None) -> None:
        """Drive the line low and reopen; the box has no other state to reset."""
        self.reinit()

    def status(self) -> dict[str, Any]:
        with self._state_lock:
            return {
                "backend": self.backend,
                "open": self._open,
                "busy": self._busy,
                "pulses": self._count,
                "pulse_us": self.pulse_us,
                "last_pulse_time": self._last_pulse_time,
                "last_error": self._last_error,
                **self.port.status(),
            }

    def check(self) -> dict[str, Any]:
        with self._lock:
            self._require_open()
            self.port.check()
        return self.status()

    def pulse(self) -> int:
        """Fire one pulse of ``pulse_us`` on pin 2 (D0); return the pulse count after it."""
        with self._lock:
            self._require_open()
            with self._state_lock:
                self._busy = True
            try:
                self.port.fire(self.pulse_us)
            except DeviceError as exc:
                with self._state_lock:
                    self._last_error = exc.message
                raise
            finally:
                with self._state_lock:
                    self._busy = False
            with self._state_lock:
                self._count += 1
                self._last_pulse_time = time.time()
                self._last_error = None
                return self._count

    __call__ = pulse  # a trigger is also a plain callable for the stereo device

    @property
    def count(self) -> int:
        with self._state_lock:
            return self._count

    # -- internals ---------------------------------------------------------------------------
    def _require_open(self) -> None:
        if not self._open:
            raise DeviceError(self.name, "trigger box is not open (call open() or reinit)")

    def inject_fault(self, kind: str | None) -> None:
        """A simulator's fault (its ``faults``), or None to clear it."""
        if Capability.FAULTS not in self.capabilities:
            raise DeviceError(self.name, f"faults can only be injected into the simulated trigger, not {self.backend!r}")
        self.port.inject_fault(kind)

    def reconfigure(self, settings: Settings) -> list[str]:
        """The box takes no setting while open: every change waits for its reinit."""
        return []

    def __enter__(self) -> Trigger:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
