"""The small surface each trigger backend fills in: claim the port, fire one pulse, release it.

Everything above it (the pulse counter, the status snapshot, one pulse at a time) lives once in
:class:`drivers.trigger.device.Trigger`, which never knows which backend it drives.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

from drivers.registry import BackendRegistry, Capability
from rvs_params import Settings, param


@dataclass
class TriggerSettings(Settings):
    """drivers.trigger keys every backend shares."""

    backend: str = param("sim", "trigger backend")
    device: str = param("/dev/parport0", "parallel port device node (ppdev; the sim names it in its errors)")
    pulse_us: float = param(100.0, "width of the pin-2 (D0) pulse", unit="us", min=0.0, max=1_000_000.0)


class TriggerBackend(Protocol):
    """A trigger port. Errors are DeviceError with the fix in the message (drivers.trigger.errors)."""

    name: ClassVar[str]
    settings: ClassVar[type[Settings]]
    capabilities: ClassVar[frozenset[Capability]]
    faults: ClassVar[tuple[str, ...]]

    def open(self) -> None:
        """Claim the port once to prove it can be claimed (a busy port fails here, not at a grab)."""

    def close(self) -> None: ...

    def check(self) -> None:
        """Claim and release the open port."""

    def fire(self, pulse_us: float) -> None:
        """One pulse on pin 2; the line is low again when this returns, whatever happened."""

    def status(self) -> dict[str, Any]:
        """Backend details for the status snapshot (the port, a simulator's fault)."""

    def inject_fault(self, kind: str | None) -> None:
        """Capability.FAULTS only."""


BACKENDS: BackendRegistry[TriggerBackend] = BackendRegistry("trigger", TriggerSettings)
