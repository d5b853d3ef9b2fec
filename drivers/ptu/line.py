"""The PTU's two lines: a real serial port, and the emulated unit on a pseudo-terminal."""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

from drivers.ptu.backend import BACKENDS, PtuSettings
from drivers.ptu.emulator import FAULTS, FLAVOURS, PtuEmulator, open_pty
from drivers.registry import Capability
from rvs_params import Settings, param


@dataclass
class SimPtuSettings(Settings):
    time_scale: float | None = param(None, "sim: wall seconds per simulated second of a move (0 instant, 1 real "
                                     "time, 0.1 ten times faster); null: follow the simulated world's clock "
                                     "(sim.time_scale), so moves take their time on the clock the rover drives on",
                                     min=0.0, max=1000.0)
    sim_flavour: str = param(
        "manual",
        "sim: whose replies the emulated unit gives: manual (the PTU-D46 manual's wording and bounds) or "
        "field (a recorded real unit's: pos/sec, axis limits a few counts off, lower speed ceilings)",
        choices=tuple(FLAVOURS),
    )


@BACKENDS.backend("sim")
class EmulatedLine:
    """The emulator on a pty; it keeps its state and faults across reinits, as a real unit
    keeps its power."""

    settings = SimPtuSettings
    capabilities = frozenset({Capability.FAULTS})
    faults = tuple(f for f in FAULTS if f is not None)

    def __init__(self, settings: SimPtuSettings, world: Any = None) -> None:
        self.time_scale = settings.time_scale
        self.flavour = settings.sim_flavour
        self.world = world
        self._emulator: PtuEmulator | None = None
        self._fds: tuple[int, int] | None = None
        self._path: str | None = None
        self._fault: str | None = None

    @property
    def emulator(self) -> PtuEmulator | None:
        return self._emulator

    def connect(self) -> str:
        if self._emulator is not None and self._emulator.running and self._path is not None:
            return self._path
        master, slave, path = open_pty()
        self._fds, self._path = (master, slave), path
        on_position = self.world.set_ptu if self.world is not None else None
        clock = self.world.clock if self.time_scale is None and self.world is not None else None
        scale = 1.0 if self.time_scale is None else self.time_scale
        on_target = getattr(self.world, "set_ptu_target", None)  # a world that renders ahead
        self._emulator = PtuEmulator(
            master, time_scale=scale, on_position=on_position, on_target=on_target, fault=self._fault, clock=clock,
            flavour=self.flavour
        ).start()
        return path

    def disconnect(self) -> None:
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
            self._path = None

    def status(self) -> dict[str, Any]:
        emu = self._emulator
        scale = emu.time_scale if emu is not None else self.time_scale
        return {"fault": self._fault, "time_scale": scale, "flavour": self.flavour,
                "emulator_running": bool(emu and emu.running)}

    def inject_fault(self, kind: str | None) -> None:
        self._fault = kind
        if self._emulator is not None:
            self._emulator.inject_fault(kind)


@BACKENDS.backend("serial")
class SerialLine:
    """A real PTU-D46 on ``settings.port``."""

    emulator = None

    def __init__(self, settings: PtuSettings, world: Any = None) -> None:
        self.port = settings.port

    def connect(self) -> str:
        return self.port

    def disconnect(self) -> None:
        pass

    def status(self) -> dict[str, Any]:
        return {}

    def inject_fault(self, kind: str | None) -> None:
        raise NotImplementedError("a real PTU has no simulated faults")
