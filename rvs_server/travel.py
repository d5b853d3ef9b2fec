"""Where the rover has been, where it was last sent and the last move checked: the driven track,
the last navigate's goal and the last check-move's answer, kept by the server whoever watches (the
console's map and Foxglove's ``/nav/track`` and ``/nav/check_move`` read them), so a page opened
after a drive shows the whole of it; and the ground the last navigate's map held round where the
rover stands, for the next navigate from there."""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

TRACK_POINTS = 5000  # positions kept: at TRACK_STEP apart, 100 m of driving
TRACK_STEP = 0.02  # m the rover moves (x + y) before the track gets a point
# where a navigate starts this near the pose the last one left the rover at, it takes that one's map
STILL_XY = 0.05  # m
STILL_HEADING = 2.0  # deg


@dataclass(frozen=True)
class Goal:
    x: float
    y: float
    tolerance: float
    job: int  # the navigate that was sent there


@dataclass(frozen=True)
class KeptGround:
    """A navigate's bounds map as it ended, the pose the rover stood at then, and the settings the
    map was made with (``key``: a map made otherwise is not the one the next navigate would make)."""
    bounds: Any  # prox_workflows.algorithms.bounds_map.BoundsMap
    pose: tuple[float, float, float]
    key: Any

    def still(self, pose: tuple[float, float, float]) -> bool:
        """Whether a rover at ``pose`` still stands where this map was left."""
        turned = abs((pose[2] - self.pose[2] + 180.0) % 360.0 - 180.0)
        return self.moved(pose) <= STILL_XY and turned <= STILL_HEADING

    def moved(self, pose: tuple[float, float, float]) -> float:
        """How far (m) a rover at ``pose`` stands from where this map was left."""
        return math.hypot(pose[0] - self.pose[0], pose[1] - self.pose[1])


@dataclass(frozen=True)
class CheckedMove:
    """A check-move's answer with the pose it was asked from: the reply names only where the move
    ends, and by the time a watcher reads the reply the rover may have moved."""
    start: tuple[float, float, float]  # x, y, heading where the rover stood when it was asked
    fields: dict[str, Any]  # the reply's fields (verdict, worst, to, ...)

    @property
    def to(self) -> tuple[float, float]:
        return float(self.fields["to"][0]), float(self.fields["to"][1])


class Travel:
    """Thread-safe: the pose's writer (a rover's thread) feeds the track, a navigate job sets
    the goal, the console and the telemetry hub read both."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._track: deque[tuple[float, float, float]] = deque(maxlen=TRACK_POINTS)
        self._goal: Goal | None = None
        self._check: CheckedMove | None = None
        self._version = 0  # counts track points added: a reader tells a new track from the one it has
        self._ground: KeptGround | None = None

    def moved(self, x: float, y: float, ground: Callable[[float, float], float]) -> None:
        """The rover is at (x, y): a point once it is TRACK_STEP from the last, at the height
        ``ground(x, y)`` (asked only then: the pose changes at every step of a drive)."""
        with self._lock:
            if self._track and abs(self._track[-1][0] - x) + abs(self._track[-1][1] - y) <= TRACK_STEP:
                return
            self._track.append((x, y, ground(x, y)))
            self._version += 1

    def track(self) -> list[tuple[float, float, float]]:
        """The points, oldest first: x, y and the ground's height there when the rover passed."""
        with self._lock:
            return list(self._track)

    @property
    def version(self) -> int:
        return self._version

    @property
    def goal(self) -> Goal | None:
        """The last navigate's goal while it runs or after it reached it; None once one ended in
        an error or a break (nothing on the map claims a goal nobody drives to)."""
        return self._goal

    def aim(self, goal: Goal | None) -> None:
        self._goal = goal

    @property
    def check(self) -> CheckedMove | None:
        """The last check-move's answer, whoever asked: every page and the live view draw it."""
        return self._check

    def checked(self, move: CheckedMove) -> None:
        self._check = move

    def leave(self, ground: KeptGround) -> None:
        """A navigate ended with the rover at ``ground.pose``: what its map holds round the rover
        (the ground it saw on the way there, the wheels' contacts it felt) is the next one's start."""
        with self._lock:
            self._ground = ground

    def take(self, pose: tuple[float, float, float], key: Any, within: float = 0.0) -> KeptGround | None:
        """What the last navigate left, for a navigate starting at ``pose`` with the settings
        ``key``: where the rover still stands (:meth:`KeptGround.still`), or has moved no farther
        than ``within`` metres since (a drive of the GNC's own between goals: the map's ground is
        the world's, and the rover is set down again on it where it stands). None farther, after
        ``sim move-rover`` (:meth:`forget`), or where the settings changed: that navigate starts on
        a fresh map and the set-down. A map is taken once: two jobs never share one."""
        with self._lock:
            ground, self._ground = self._ground, None
        if ground is None or ground.key != key:
            return None
        return ground if ground.still(pose) or 0.0 < within and ground.moved(pose) <= within else None

    def forget(self) -> None:
        """The rover was carried off (``sim move-rover``, another scene): no map holds its ground."""
        with self._lock:
            self._ground = None
