"""The simulated trigger box: a pulse on the world's trigger bus wakes the simulated cameras.

Faults mirror what the real port does: ``busy`` (lp holds the port: EBUSY), ``missing`` (no
/dev/parportN: ENOENT) and ``denied`` (EACCES), each reported through the same messages as the
ppdev backend so the server and its tests see identical errors.
"""

from __future__ import annotations

import errno
import time
from typing import Any

from drivers.trigger.device import TriggerBase
from drivers.trigger.errors import port_error

FAULTS = {"busy": errno.EBUSY, "missing": errno.ENOENT, "unplug": errno.ENOENT, "denied": errno.EACCES}


class SimTrigger(TriggerBase):
    backend = "sim"

    def __init__(self, config: dict[str, Any], world: Any = None) -> None:
        super().__init__(config)
        self.world = world
        self.path = str(config.get("device", "/dev/parport0"))
        self._fault: str | None = None

    def inject_fault(self, kind: str | None) -> None:
        """``busy``, ``missing``/``unplug``, ``denied``, or None to clear."""
        if kind is not None and kind not in FAULTS:
            raise ValueError(f"unknown trigger fault {kind!r}; accepted: {', '.join(sorted(FAULTS))} or None")
        with self._state_lock:
            self._fault = kind

    def _raise_fault(self, action: str) -> None:
        with self._state_lock:
            kind = self._fault
        if kind is not None:
            code = FAULTS[kind]
            raise port_error(OSError(code, errno.errorcode[code]), self.path, action)

    def _open_impl(self) -> None:
        self._raise_fault("claiming the trigger port")

    def _close_impl(self) -> None:
        pass

    def _check_impl(self) -> None:
        self._raise_fault("claiming the trigger port")

    def _fire(self) -> None:
        self._raise_fault("claiming the trigger port")
        if self.pulse_us >= 1000:  # short pulses are below the scheduler's resolution anyway
            time.sleep(self.pulse_us / 1e6)
        bus = getattr(self.world, "trigger", None)
        if bus is not None:
            bus.pulse()

    def _status_extra(self) -> dict[str, Any]:
        bus = getattr(self.world, "trigger", None)
        return {
            "device": self.path,
            "fault": self._fault,
            "bus_count": None if bus is None else bus.count,
        }
