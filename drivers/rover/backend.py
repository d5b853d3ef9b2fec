"""The small surface each rover backend fills in: run a drive, say where the rover is.

A drive is one loop per backend. The server's navigation supplies a :class:`Pilot`: at each
cycle it gets the rover's believed pose and answers the next :class:`Motion` (or None: the leg
is over), and it hears every true pose the rover passes through (its track). The ``sim``
backend executes those motions on the simulated world; the ``gnc`` backend executes nothing (the
rover's GNC steers by the waypoints it was sent) and makes each pose report that moved a cycle,
until the GNC says the rover stands. Everything above (what to drive, when to stop, what to
check) is navigation's and never knows which backend drives.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

from drivers.registry import BackendRegistry, Capability
from drivers.sim.rover import RoverBody
from rvs_params import Settings, param

Pose = tuple[float, float, float]  # x, y (m) and heading (deg, counter-clockwise from x) in the global frame
# roll (left side up), pitch (nose up) and their 1-sigma, deg: the body's attitude from its IMU
Attitude = tuple[float, float, float]


@dataclass
class RoverSettings(Settings):
    """drivers.rover keys every backend shares."""

    backend: str = param("gnc", "rover backend: gnc (the rover's GNC drives and reports its pose) or sim "
                                "(the server drives the simulated rover)")


@dataclass(frozen=True)
class Motion:
    """One motion the rover executes: toward ``target`` (turn on the spot to face it, then, with
    ``advance``, straight on to it, both by the rover's odometry), or, without a target, an arc
    at ``speed`` (m/s) and ``rate`` (deg/s, counter-clockwise) for ``seconds``."""

    target: tuple[float, float] | None = None
    advance: bool = True
    speed: float = 0.0
    rate: float = 0.0
    seconds: float = 0.0

    @classmethod
    def toward(cls, x: float, y: float) -> Motion:
        """Turn to face (x, y), then drive straight to it."""
        return cls((float(x), float(y)))

    @classmethod
    def face(cls, x: float, y: float) -> Motion:
        """Turn on the spot to face (x, y)."""
        return cls((float(x), float(y)), advance=False)

    @classmethod
    def arc(cls, speed: float, rate: float, seconds: float) -> Motion:
        return cls(None, speed=float(speed), rate=float(rate), seconds=float(seconds))


@dataclass(frozen=True)
class Settle:
    """When a drive the GNC makes is over: a report with ``stopped``, or reports that hold within
    ``distance`` (m) and ``degrees`` of the first of them for ``seconds``, reported again or
    not. With ``start`` (where the leg starts), the hold counts only once a report has left it:
    a GNC that reports its standing pose while it gets ready to drive has not driven the leg
    yet. ``timeout`` (s, 0: never) bounds the wait for the first report that left the start."""

    seconds: float = 2.0
    distance: float = 0.01
    degrees: float = 1.0
    timeout: float = 0.0
    start: Pose | None = None


class Pilot(Protocol):
    """Navigation's side of a drive."""

    def next(self, pose: Pose) -> Motion | None:
        """The motion from ``pose`` (where the rover believes it is), or None: the leg is over.
        With the GNC steering, the motion is what the server would have driven; it is not sent."""

    def moved(self, truth: Pose, end: bool) -> None:
        """The rover is at ``truth`` (the simulator's true pose; a GNC's report): at every step
        of a motion, and with ``end`` where a motion ended or the GNC stopped."""


class PoseFeed(Protocol):
    """The server's pose: the GNC's reports land there, and a simulated rover reports into it."""

    pose_changed: threading.Condition  # guards the pose; notified on every change

    @property
    def pose(self) -> Any:
        """The latest pose: x, y, heading and ``stopped``."""

    @property
    def pose_version(self) -> int:
        """Counts pose changes."""

    def set_pose(self, x: float, y: float, heading: float, *, stopped: bool = False, source: str = "gnc",
                 sigma: float = 0.0, sigma_heading: float = 0.0, roll: float | None = None,
                 pitch: float | None = None) -> None: ...


class Silent(Exception):
    """The GNC reported no pose that moved within the settle's timeout."""


class RoverBackend(Protocol):
    name: ClassVar[str]
    settings: ClassVar[type[Settings]]
    capabilities: ClassVar[frozenset[Capability]]
    faults: ClassVar[tuple[str, ...]]
    steers: ClassVar[bool]  # whether the server's motions are executed (else the GNC steers itself)
    drives_auto: ClassVar[bool]  # whether it drives a navigate -auto leg (the simulator; a replay of one)

    def open(self) -> None: ...

    def close(self) -> None: ...

    def pose(self) -> Pose:
        """Where the rover believes it is (the odometry; the GNC's last report)."""

    def truth(self) -> Pose:
        """Where it is, as well as this backend knows (the simulator's truth; the GNC's report)."""

    def speeds(self) -> tuple[float, float]:
        """Forward speed (m/s) and turn rate (deg/s) the server's motions run at."""

    def attitude(self) -> Attitude | None:
        """The body's roll and pitch where it stands, as its IMU reads them (the simulator's from
        the true ground under its wheels; the GNC's from its pose reports), or None: not known."""

    def body(self) -> RoverBody:
        """What the rover is and drives over: the wheels, the belly's clearance, the climb and tilt
        limits the vehicle check holds its motions to."""

    def drive(self, pilot: Pilot, stop: Callable[[], bool], settle: Settle, since: int) -> Pose:
        """The drive loop: until the pilot says the leg is over (sim) or the GNC stands (gnc);
        ``stop()`` true ends it at its next step with DeviceInterrupted. ``since``: the pose feed's
        version when the leg was announced (a report after it is the GNC's answer). Returns the
        pose the rover believes it ended at."""

    def place(self, pose: Pose) -> None:
        """The rover is set down at ``pose`` (navigate -start): the simulated rover goes there."""

    def take_fix(self, pose: Pose) -> None:
        """A localisation fix: the simulated rover's odometry takes it (a GNC gets it by EVENT)."""

    def status(self) -> dict[str, Any]: ...


BACKENDS: BackendRegistry[RoverBackend] = BackendRegistry("rover", RoverSettings, default="gnc")
