"""The PTU replayed from a recording (drivers/replay.py): an emulated D46 on a pseudo-terminal,
so the front end speaks the real protocol, that starts where the recorded run's PTU stood and
turns instantly (``replay_timing=fast``) or at its configured speed (``recorded``).

A PTU's states are where it was sent, which the replayed requests send it again; what the
recording guards is the pointing of every frame: the replayed ToF and stereo frames are served
only where the PTU points as it did when they were taken (this line tells the replay where it
is). A real unit that stopped a count off its target is not reproduced: the emulator reaches
every target.
"""

from __future__ import annotations

import os
from typing import Any

from drivers.base import DeviceError
from drivers.ptu.backend import BACKENDS
from drivers.ptu.emulator import PtuEmulator, open_pty
from drivers.ptu.protocol import deg_to_pos
from drivers.replay import Replay, ReplaySettings, open_replay


@BACKENDS.backend("replay")
class ReplayLine:
    """The emulated D46 a replay points; it keeps its position across reinits, as a unit keeps
    its power."""

    settings = ReplaySettings
    emulator = None  # no simulator to inject faults into

    def __init__(self, settings: Any, world: Any = None) -> None:
        self._file = settings.replay_file
        self._timing = settings.replay_timing
        self._replay: Replay | None = None
        self._unit: PtuEmulator | None = None
        self._fds: tuple[int, int] | None = None
        self._path: str | None = None

    def connect(self) -> str:
        if self._unit is not None and self._unit.running and self._path is not None:
            return self._path
        run = self._replay = open_replay("ptu", self._file)
        master, slave, path = open_pty()
        self._fds, self._path = (master, slave), path
        unit = PtuEmulator(master, time_scale=1.0 if self._timing == "recorded" else 0.0,
                           on_position=self._moved)
        start = run.recording.metadata.get("ptu")
        if start is not None:
            for key, deg in zip("PT", start, strict=True):
                axis = unit.axes[key]
                axis.pos = axis.target = deg_to_pos(float(deg), unit.resolution)
        self._unit = unit.start()
        return path

    def _moved(self, pan: float, tilt: float) -> None:
        if self._replay is not None:
            self._replay.ptu_at = (pan, tilt)

    def disconnect(self) -> None:
        if self._unit is not None:
            self._unit.stop()
            self._unit = None
        for fd in self._fds or ():
            try:
                os.close(fd)
            except OSError:
                pass
        self._fds = self._path = None

    def status(self) -> dict[str, Any]:
        run = self._replay
        return {"replay": run.recording.path.name if run is not None else self._file, "timing": self._timing}

    def inject_fault(self, kind: str | None) -> None:
        raise DeviceError("ptu", "a replayed PTU has no simulated faults: inject them into the sim backend")
