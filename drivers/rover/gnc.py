"""The rover's own GNC drives: the server waits for its pose reports (seed 000 sect. 5.4).

The GNC gets the leg's waypoints from navigate's ``EVENT kind=waiting`` and reports where the
rover is with ``pose`` (into the server's pose, the :class:`~drivers.rover.backend.PoseFeed`).
A drive here is the wait for those reports: each one that moved is a cycle of the pilot (the
see loop's check), and the drive ends when the rover has stopped: a report with ``-stopped
true``, or reports that hold still for the settle time, reported again or not, once one has
left the leg's start (a GNC may report its standing pose while it gets ready). Where it stopped
does not matter: a GNC streaming its pose passes the leg's end, or comes within the tolerance of
it, while still moving, and a scan started then would start on a moving rover.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

from drivers.base import DeviceError, DeviceInterrupted

from .backend import BACKENDS, Attitude, Pilot, Pose, PoseFeed, RoverBody, RoverSettings, Settle, Silent
from .imu import SimImu

# deg, 1-sigma taken for the roll and pitch a GNC reports (docs/PROTOCOL.md, pose): a rover's IMU
# levels to about 0.1 deg at rest; twice that covers one that reports while rolling
GNC_ATTITUDE_SIGMA = 0.2


@BACKENDS.backend("gnc")
class GncRover:
    """Waits for the GNC's pose reports."""

    steers = False
    drives_auto = False  # the GNC drives its own legs; -auto asks for the simulator

    def __init__(self, settings: RoverSettings, world: Any = None, poses: PoseFeed | None = None) -> None:
        self.poses = poses
        # in the simulator the simulated rover is the GNC's too: its IMU gives the attitude a
        # report leaves out, as the GNC reading it would (a scan on the default server, whose
        # operator sends a planar pose, is placed with the body's tilt)
        self._imu = SimImu(world) if world is not None else None

    def open(self) -> None:
        if self.poses is None:
            raise DeviceError("rover", "the gnc backend needs the server's pose reports")

    def close(self) -> None:
        pass

    def pose(self) -> Pose:
        p = self.poses.pose
        return p.x, p.y, p.heading

    truth = pose  # the GNC's report is all the server knows of where the rover is

    def attitude(self) -> Attitude | None:
        """Roll and pitch where the GNC's last pose report gave them (``pose -roll -pitch``), good
        to :data:`GNC_ATTITUDE_SIGMA`; where it gave none, the simulated rover's IMU in the
        simulator, and None on a real rover."""
        p = self.poses.pose
        roll, pitch = getattr(p, "roll", None), getattr(p, "pitch", None)
        if roll is None or pitch is None:
            return self._imu.read() if self._imu is not None else None
        return float(roll), float(pitch), GNC_ATTITUDE_SIGMA

    def body(self) -> RoverBody:
        return RoverBody()  # the rover the server is built for; a scene's body is the simulator's

    def speeds(self) -> tuple[float, float]:
        raise DeviceError("rover", "the GNC steers itself: the server runs no motion of its own")

    def drive(self, pilot: Pilot, stop: Callable[[], bool], settle: Settle, since: int) -> Pose:
        """Each report that moved goes to the pilot outside the pose lock, so the pose command is
        never kept waiting by it; the hold is timed from the end of that cycle, so a cycle slower
        than the GNC's reports does not pass for a standing rover. Reports that hold at
        ``settle.start`` start no hold (the rover has not left yet), and the timeout runs only
        until a report leaves it: once the rover has moved, a GNC gone quiet is a rover that
        stands. The pilot's motions are not sent (the GNC steers by the waypoints): it stops
        the rover by its own EVENT."""
        feed = self.poses
        deadline = time.monotonic() + settle.timeout if settle.timeout > 0 else math.inf
        version = since
        anchor: Pose | None = settle.start  # the first report of the run of reports that hold still
        left = anchor is None  # whether a report has left the leg's start (only then may a hold end it)
        anchor_at = 0.0
        latest: Any = None
        while True:
            with feed.pose_changed:
                if stop():
                    raise DeviceInterrupted("rover", "the wait for the GNC's pose was stopped")
                if feed.pose_version == version:
                    now = time.monotonic()
                    if latest is not None and now - anchor_at >= settle.seconds:
                        return self._ended(pilot, latest)
                    if latest is None and now >= deadline:
                        raise Silent(f"no pose within {settle.timeout:g} s")
                    wake = anchor_at + settle.seconds - now if latest is not None else 0.1
                    feed.pose_changed.wait(min(0.1, max(wake, 0.001)))
                    continue
                version = feed.pose_version
                p = feed.pose
            if p.stopped:
                return self._ended(pilot, p)
            turned = abs((p.heading - anchor[2] + 180.0) % 360.0 - 180.0) if anchor is not None else 0.0
            if anchor is None or math.hypot(p.x - anchor[0], p.y - anchor[1]) > settle.distance or \
                    turned > settle.degrees:
                anchor = (p.x, p.y, p.heading)
                left = True
                pilot.moved(anchor, False)
                pilot.next(anchor)  # a report that holds still shows nothing new: no cycle for it
                anchor_at = time.monotonic()  # the hold counts from when the server took the report in
            if left:
                latest = p

    @staticmethod
    def _ended(pilot: Pilot, p: Any) -> Pose:
        pose = (p.x, p.y, p.heading)
        pilot.moved(pose, True)
        return pose

    def place(self, pose: Pose) -> None:
        """The GNC knows where its rover stands: nothing to move."""

    def take_fix(self, pose: Pose) -> None:
        """The GNC gets a fix by navigate's ``localised`` EVENT and applies it itself."""

    def status(self) -> dict[str, Any]:
        p = self.poses.pose if self.poses is not None else None
        return {"last_report": None if p is None else [p.x, p.y, p.heading], "stopped": bool(p and p.stopped)}
