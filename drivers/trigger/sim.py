"""The simulated trigger box: a pulse on the world's trigger bus wakes the simulated cameras.

Faults mirror what the real port does: ``busy`` (lp holds the port: EBUSY), ``missing`` (no
/dev/parportN: ENOENT) and ``denied`` (EACCES), each reported through the same messages as the
ppdev backend so the server and its tests see identical errors.
"""

from __future__ import annotations

import errno
import threading
import time
from typing import Any

from drivers.registry import Capability
from drivers.trigger.backend import BACKENDS, TriggerSettings
from drivers.trigger.errors import port_error

FAULTS = {"busy": errno.EBUSY, "missing": errno.ENOENT, "unplug": errno.ENOENT, "denied": errno.EACCES}


@BACKENDS.backend("sim")
class SimTrigger:
    """Pulses the world's trigger bus (when there is a world: a box alone just counts)."""

    capabilities = frozenset({Capability.FAULTS})
    faults = tuple(FAULTS)

    def __init__(self, settings: TriggerSettings, world: Any = None) -> None:
        self.world = world
        self.path = settings.device
        self._state_lock = threading.Lock()
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

    def open(self) -> None:
        self._raise_fault("claiming the trigger port")

    def close(self) -> None:
        pass

    def check(self) -> None:
        self._raise_fault("claiming the trigger port")

    def fire(self, pulse_us: float) -> None:
        self._raise_fault("claiming the trigger port")
        if pulse_us >= 1000:  # short pulses are below the scheduler's resolution anyway
            time.sleep(pulse_us / 1e6)
        if self.world is not None:
            self.world.trigger.pulse()

    def status(self) -> dict[str, Any]:
        bus = self.world.trigger if self.world is not None else None
        return {
            "device": self.path,
            "fault": self._fault,
            "bus_count": None if bus is None else bus.count,
        }
