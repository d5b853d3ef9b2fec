"""The trigger box of a replay (drivers/replay.py): the replayed cameras' frames come from the
recording whether or not a pulse is fired, so a pulse only counts (the front end numbers it, as
the recorded run's grabs were numbered). It opens only with a recording to point at, so a
replay configured without one says so at once rather than at the first grab."""

from __future__ import annotations

from typing import Any

from drivers.base import DeviceError
from drivers.replay import Replay, ReplaySettings, open_replay
from drivers.trigger.backend import BACKENDS


@BACKENDS.backend("replay")
class ReplayTrigger:
    settings = ReplaySettings

    def __init__(self, settings: Any, world: Any = None) -> None:
        self._file = settings.replay_file
        self._replay: Replay | None = None

    def open(self) -> None:
        self._replay = open_replay("trigger", self._file)

    def close(self) -> None:
        self._replay = None

    def check(self) -> None:
        self.open()

    def fire(self, pulse_us: float) -> None:
        pass

    def status(self) -> dict[str, Any]:
        return {"replay": self._replay.recording.path.name if self._replay is not None else self._file}

    def inject_fault(self, kind: str | None) -> None:
        raise DeviceError("trigger", "a replayed trigger box has no simulated faults: inject them into the sim backend")
