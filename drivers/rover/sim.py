"""The simulated rover: the server drives the simulated world's rover as its GNC would.

Motions run on the world's clock at the scene's drive model (``rover:`` speed and turn rate),
steered by the rover's odometry, so wheel slip and heading drift (``sim slip``) leave the true
rover short of and beside where it believes it is. At every step the odometry becomes the
server's pose (source ``odometry``), as a GNC streaming its pose would make it: status,
check-move and a break's recovery set see where the rover is mid-drive.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from drivers.base import DeviceError, DeviceInterrupted

from .backend import BACKENDS, Attitude, Motion, Pilot, Pose, PoseFeed, RoverBody, RoverSettings, Settle
from .imu import SimImu


@BACKENDS.backend("sim")
class SimRover:
    """Drives the shared simulated world's rover."""

    steers = True
    drives_auto = True

    def __init__(self, settings: RoverSettings, world: Any = None, poses: PoseFeed | None = None) -> None:
        self.world = world
        self.poses = poses
        self._imu = SimImu(world)

    def open(self) -> None:
        if self.world is None:
            raise DeviceError("rover", "the sim backend drives the simulated world, and this server has none; "
                                       "set drivers.rover.backend=gnc (the GNC drives and reports its pose)")

    def close(self) -> None:
        pass

    def pose(self) -> Pose:
        return self.world.odometry()

    def truth(self) -> Pose:
        return self.world.rover_pose()

    def speeds(self) -> tuple[float, float]:
        model = self.world.drive_model
        return model.speed, model.turn_rate

    def body(self) -> RoverBody:
        return self.world.body

    def attitude(self) -> Attitude:
        return self._imu.read()

    def drive(self, pilot: Pilot, stop: Callable[[], bool], settle: Settle, since: int) -> Pose:
        """Ask the pilot for a motion, run it, tell the pilot where the rover got to, again,
        until the pilot has none. The frames a pilot takes between motions are exposed while
        the rover rolls (``World.under_way``): a camera working while it drives."""
        world = self.world

        def step() -> None:
            self._report()
            pilot.moved(self.truth(), False)

        try:
            with world.under_way():
                while not stop():
                    motion = pilot.next(self.pose())
                    if motion is None:
                        break
                    self._run(motion, stop, step)
                    pilot.moved(self.truth(), True)
        finally:  # a break or a failing pilot too leaves the pose where the odometry stopped
            self._report()
        if stop():
            raise DeviceInterrupted("rover", "the drive was stopped")
        return self.pose()

    def _run(self, motion: Motion, stop: Callable[[], bool], step: Callable[[], None]) -> None:
        world = self.world
        if motion.target is None:
            world.drive(motion.speed, motion.rate, motion.seconds, stop, on_step=step)
            return
        dist = world.turn_toward(*motion.target, stop, on_step=step)
        if motion.advance and dist >= 1e-6 and not stop():
            speed = world.drive_model.speed
            world.drive(speed, 0.0, dist / speed, stop, on_step=step)

    def _report(self) -> None:
        if self.poses is not None:
            x, y, heading = self.world.odometry()
            self.poses.set_pose(x, y, heading, source="odometry")

    def place(self, pose: Pose) -> None:
        self.world.set_rover_pose(*pose)

    def take_fix(self, pose: Pose) -> None:
        self.world.set_odometry(*pose)

    def status(self) -> dict[str, Any]:
        x, y, heading = self.world.odometry() if self.world is not None else (None, None, None)
        return {"odom_x": x, "odom_y": y, "odom_heading": heading,
                "driving": bool(self.world is not None and self.world.rolling)}
