"""What every device shares: the error the server turns into E_DEVICE, and the interface.

Each device package (one per kind in drivers.registry.DEVICE_KINDS) exposes
``create(settings, world)``: a front end (satisfying :class:`Device`) over the backend its
registry has under ``settings.backend`` (pyserial-style: one interface, the backend chosen by
config). A real backend whose hardware or library is missing raises :class:`DeviceError` from
``open()``; it never falls back to the simulator.
"""

from __future__ import annotations

import contextvars
import threading
from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

# What a long device operation looks at to stop early: a job's threading.Event or a callable.
Cancel = Callable[[], bool] | threading.Event | None
# The cancel of the device call this thread is making, for a backend that may wait deep below
# the front end's checks (a replay holding a frame back until its recorded turn): set by the
# caller around the call (a monitor's stop).
CALL_CANCEL: contextvars.ContextVar[threading.Event | None] = contextvars.ContextVar("call_cancel", default=None)


class DeviceError(Exception):
    """A device failed, timed out or is absent.

    ``device`` is the registry name ("ptu", "tof", "stereo", "trigger") so the server can name
    it in the E_DEVICE reply; the message says what went wrong and, where known, how to fix it.
    """

    def __init__(self, device: str, message: str) -> None:
        super().__init__(f"{device}: {message}")
        self.device = device
        self.message = message


class DeviceInterrupted(DeviceError):
    """A device operation stopped early by its ``cancel`` (a break), not a device failure: the
    server ends the job as interrupted and leaves the device open."""


@runtime_checkable
class Device(Protocol):
    """The surface the server's device registry relies on (reset, reinit, continue, status)."""

    name: str
    backend: str
    capabilities: frozenset[str]  # drivers.registry.Capability members its backend has

    def open(self) -> None: ...

    def close(self) -> None: ...

    def status(self) -> dict[str, Any]:
        """A thread-safe snapshot, cheap enough to call from the event loop."""
        ...

    def check(self) -> dict[str, Any]:
        """Talk to the device to prove it answers; raise DeviceError if it does not."""
        ...

    def reinit(self) -> None: ...

    def reset(self, cancel: Cancel = None) -> None:
        """Back to the power-on state; one that takes long (the PTU's R) stops waiting on ``cancel``."""
        ...

    def reconfigure(self, settings: Any) -> list[str]:
        """Take the changed keys declared live while open; return them (the rest wait for reinit)."""
        ...

    def inject_fault(self, kind: str | None) -> None:
        """Capability.FAULTS only: one of the simulator's ``faults``, or None to clear."""
        ...
