"""The rover front end: one drive at a time, the stop, and the status snapshot, over a backend.

Navigation asks the rover where it is (:meth:`Rover.pose`) and has it drive a leg
(:meth:`Rover.drive`, with navigation's :class:`~drivers.rover.backend.Pilot`); which backend
runs the drive (the simulated world, or the GNC's pose reports) it never knows.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping
from typing import Any

from drivers.base import Cancel, DeviceError
from rvs_params import Settings

from .backend import BACKENDS, Attitude, Pilot, Pose, PoseFeed, RoverBackend, Settle


class Rover:
    """The rover's drive, over whichever backend the settings name."""

    name = "rover"

    def __init__(self, settings: Mapping[str, Any] | Settings | None = None, world: Any = None,
                 poses: PoseFeed | None = None) -> None:
        self.settings = BACKENDS.settings(settings)
        self.port: RoverBackend = BACKENDS.create(self.settings, world, poses)
        self.backend = self.port.name
        self.capabilities = self.port.capabilities
        self.poses = poses
        self._drive_lock = threading.Lock()  # one drive at a time
        self._stop = threading.Event()
        self._state_lock = threading.Lock()  # status() never waits for a drive
        self._open = False
        self._driving = False

    # -- the device protocol ---------------------------------------------------------------
    def open(self) -> None:
        self.port.open()
        with self._state_lock:
            self._open = True

    def close(self) -> None:
        self.stop()
        self.port.close()
        with self._state_lock:
            self._open = False

    def reinit(self) -> None:
        self.close()
        self.open()

    def reset(self, cancel: Cancel = None) -> None:
        """Stop any drive and reopen: the rover has no other state of the server's to reset."""
        self.reinit()

    def check(self) -> dict[str, Any]:
        self._require_open()
        return self.status()

    def status(self) -> dict[str, Any]:
        with self._state_lock:
            state = {"backend": self.backend, "open": self._open, "driving": self._driving}
        return {**state, **self.port.status()}

    def reconfigure(self, settings: Settings) -> list[str]:
        """The backend is the one key: a change waits for the reinit that builds the other."""
        return []

    def inject_fault(self, kind: str | None) -> None:
        raise DeviceError(self.name, f"the {self.backend} rover has no faults to inject")

    # -- the rover ---------------------------------------------------------------------------
    @property
    def steers(self) -> bool:
        """Whether the motions a pilot answers are executed (the simulator), or the GNC steers."""
        return self.port.steers

    @property
    def drives_auto(self) -> bool:
        """Whether it drives a navigate -auto leg itself (else -auto takes the simulator)."""
        return self.port.drives_auto

    def pose(self) -> Pose:
        """Where the rover believes it is."""
        return self.port.pose()

    def truth(self) -> Pose:
        """Where it is, as well as the backend knows: the simulator's truth, the GNC's report."""
        return self.port.truth()

    def speeds(self) -> tuple[float, float]:
        """Forward speed (m/s) and turn rate (deg/s) of the motions the server runs (sim only)."""
        return self.port.speeds()

    def attitude(self, *, cancel: Cancel = None) -> Attitude | None:
        """Roll, pitch and their 1-sigma (deg) where the rover stands, from its IMU (the simulator's
        true ground under its wheels; the GNC's pose reports), or None: the backend has none.
        ``cancel`` as every device call takes it: a read is immediate, so nothing waits on it."""
        return self.port.attitude()

    def body(self) -> Any:
        """The rover's body (:class:`drivers.sim.rover.RoverBody`): what its motions are checked
        against."""
        return self.port.body()

    def mark(self) -> int:
        """Where the pose reports stand now: a drive started with this mark takes reports after it
        as the GNC's answer (take it before announcing the leg: a GNC may answer at once)."""
        return self.poses.pose_version if self.poses is not None else 0

    def drive(self, pilot: Pilot, *, cancel: Cancel = None, settle: Settle | None = None,
              since: int | None = None) -> Pose:
        """Drive one leg with ``pilot`` until it is over (see the backend); ``cancel`` (a job's
        break) or :meth:`stop` ends it at its next step with DeviceInterrupted. Returns the
        pose the rover believes it ended at."""
        self._require_open()

        def stop() -> bool:
            if self._stop.is_set():
                return True
            if cancel is None:
                return False
            return cancel.is_set() if isinstance(cancel, threading.Event) else bool(cancel())

        with self._drive_lock:
            self._stop.clear()
            with self._state_lock:
                self._driving = True
            try:
                return self.port.drive(pilot, stop, settle or Settle(), self.mark() if since is None else since)
            finally:
                with self._state_lock:
                    self._driving = False

    def stop(self) -> None:
        """End the drive under way at its next step (the simulator's; the wait for the GNC)."""
        self._stop.set()

    def place(self, pose: Pose) -> None:
        """The rover is set down at ``pose`` (the simulated rover goes there; the GNC knows)."""
        self.port.place(pose)

    def take_fix(self, pose: Pose) -> None:
        """A localisation fix for the rover's own estimate (the simulated odometry takes it)."""
        self.port.take_fix(pose)

    def _require_open(self) -> None:
        if not self._open:
            raise DeviceError(self.name, "rover is not open (send reinit -device rover)")
