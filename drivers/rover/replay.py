"""The rover replayed from a recording (drivers/replay.py): it starts where the recorded rover
was, and a drive is the recorded believed poses that follow the last call the replay served,
reported into the server's pose as a GNC reports them (``replay_timing``: at their recorded
pace or at once), until the recorded rover stood still. The server's motions are not executed
(it steers nothing, as with the ``gnc`` backend); the poses are the recording's whatever the
replayed navigation plans. A recording samples the pose ten times a second, so a drive replays
at that resolution, and a drive the recording does not hold is a DeviceError saying so.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from typing import Any

from drivers.base import DeviceError, DeviceInterrupted
from drivers.replay import Replay, ReplaySettings, open_replay

from .backend import BACKENDS, Attitude, Pilot, Pose, PoseFeed, Settle
from .gnc import GncRover

STAND_S = 1.0  # recorded seconds without motion that end a drive
STILL_M, STILL_DEG = 0.001, 0.1
# A drive the server ran (the simulator's, a navigate -auto leg's) was reported from the rover's
# odometry, which a navigate's localiser takes as dead reckoning; a GNC's own reports are pose
# requests, which rvs-replay --mcap sends as recorded.
DRIVE_SOURCE = "odometry"
AUTO = re.compile(r"^(@\S+\s+)?navigate\b.*\s-auto(=|\s+)(true|1|yes|on)\b", re.IGNORECASE)  # an -auto leg's request


@BACKENDS.backend("replay")
class ReplayRover(GncRover):
    """A GNC whose pose reports come from a recording."""

    settings = ReplaySettings
    # a recorded -auto leg is a recorded drive like any other: the replay drives it, with no world
    drives_auto = True

    def __init__(self, settings: Any, world: Any = None, poses: PoseFeed | None = None) -> None:
        super().__init__(settings, world, poses)
        self._file = settings.replay_file
        self._timing = settings.replay_timing
        self._replay: Replay | None = None

    def open(self) -> None:
        super().open()
        run = self._replay = open_replay("rover", self._file)
        # the navigation takes the path it took in the recorded run: the server steered the
        # simulator through its -auto legs, else a GNC steered itself
        self.steers = any(AUTO.search(line) for line in run.recording.requests)
        start = run.recording.metadata.get("pose")
        if start is not None and not run.placed:
            run.placed = True
            # the estimate as it stood, its accuracy too: a navigate's localiser grows it from there
            source, sigma, sigma_heading = run.recording.metadata.get("pose_estimate") or ("replay", 0.0, 0.0)
            self.poses.set_pose(*map(float, start), source=str(source), sigma=float(sigma),
                                sigma_heading=float(sigma_heading))

    def attitude(self) -> Attitude | None:
        """The recorded run's next read of the rover's roll and pitch (each frame was placed with
        one): the replayed frames are placed with the tilt the recorded ones were. None where the
        recording holds no read (a server that placed its frames level, a recording of devices
        alone)."""
        run = self._replay
        if run is None:
            raise DeviceError("rover", "the replayed rover is not open; run reinit or reset")
        if not any(c.call == "attitude" for c in run.recording.calls.get("rover", ())):
            return None
        result = run.next("rover", ("attitude",), self._timing).result
        return None if result is None else (float(result[0]), float(result[1]), float(result[2]))

    def drive(self, pilot: Pilot, stop: Callable[[], bool], settle: Settle, since: int) -> Pose:
        run = self._replay
        if run is None:
            raise DeviceError("rover", "the replayed rover is not open; run reinit or reset")
        segment = drive_after(run.recording.poses, run.last_ns)
        if not segment:
            raise DeviceError("rover", f"the recording {run.recording.path.name} holds no drive after the calls "
                                       "replayed so far: the replay drives where the recorded run did not")
        pose: Pose = self.pose()
        for t_ns, x, y, heading in segment:
            if stop():
                raise DeviceInterrupted("rover", "the replayed drive was stopped")
            run.pace(t_ns, self._timing)
            run.last_ns = max(run.last_ns, t_ns)
            self.poses.set_pose(x, y, heading, source=DRIVE_SOURCE)
            pose = (x, y, heading)
            pilot.moved(pose, False)
            pilot.next(pose)
        self.poses.set_pose(*pose, stopped=True, source=DRIVE_SOURCE)
        pilot.moved(pose, True)
        return pose

    def status(self) -> dict[str, Any]:
        run = self._replay
        return {**super().status(), "replay": run.recording.path.name if run is not None else self._file}


def drive_after(poses: list[tuple[int, float, float, float]], after_ns: int) -> list[tuple[int, float, float, float]]:
    """The recorded poses of the first drive after ``after_ns``: from the first that moved to
    where the rover then stood :data:`STAND_S`, or the recording ended."""
    later = [p for p in poses if p[0] > after_ns]
    before = [p for p in poses if p[0] <= after_ns]
    anchor = before[-1] if before else (later[0] if later else None)
    out: list[tuple[int, float, float, float]] = []
    for p in later:
        if anchor is not None and _still(anchor, p):
            if out and p[0] - anchor[0] >= STAND_S * 1e9:
                break
            continue
        out.append(p)
        anchor = p
    return out


def _still(a: tuple[int, float, float, float], b: tuple[int, float, float, float]) -> bool:
    turned = abs((b[3] - a[3] + 180.0) % 360.0 - 180.0)
    return math.hypot(b[1] - a[1], b[2] - a[2]) <= STILL_M and turned <= STILL_DEG
