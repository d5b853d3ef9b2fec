"""What a PTU backend provides: a serial line the PTU-D46 protocol runs over.

The front end (:class:`drivers.ptu.Ptu`) speaks the protocol itself, so a backend is only the
line: a real port, or an emulated unit on a pseudo-terminal.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

from drivers.ptu.emulator import PtuEmulator
from drivers.registry import BackendRegistry, Capability
from rvs_params import Settings, param


@dataclass
class PtuSettings(Settings):
    """drivers.ptu keys of the front end (the D46 protocol client), shared by all backends."""

    backend: str = param("sim", "PTU backend")
    port: str = param("/dev/ttyUSB0", "any pyserial URL (serial backend; the sim uses its own pty)")
    baudrate: int = param(9600, "serial line speed", unit="baud", min=50, max=4_000_000)
    timeout: float = param(2.0, "wait for a reply before DeviceError", unit="s", min=0.0, max=3600.0)
    move_timeout: float = param(30.0, "wait for a move to finish (await)", unit="s", min=0.0, max=3600.0)
    reset_timeout: float = param(60.0, "wait for the R command (the D46 runs both axes into their limits)",
                                 unit="s", min=0.0, max=3600.0)
    speed: int = param(1000, "pan and tilt speed", unit="positions/s", min=0, max=100_000)
    acceleration: int = param(2000, "pan and tilt acceleration", unit="positions/s^2", min=0, max=1_000_000)


class PtuBackend(Protocol):
    name: ClassVar[str]
    settings: ClassVar[type[Settings]]
    capabilities: ClassVar[frozenset[Capability]]
    faults: ClassVar[tuple[str, ...]]

    def connect(self) -> str:
        """Make the line ready (idempotent) and return its pyserial URL."""

    def disconnect(self) -> None: ...

    def status(self) -> dict[str, Any]:
        """Backend details for the status snapshot; never touches the line."""

    @property
    def emulator(self) -> PtuEmulator | None:
        """The emulated unit (Capability.FAULTS backends), None for a real one."""

    def inject_fault(self, kind: str | None) -> None:
        """Capability.FAULTS only; ``kind`` is one of ``faults`` or None."""


BACKENDS: BackendRegistry[PtuBackend] = BackendRegistry("ptu", PtuSettings)
