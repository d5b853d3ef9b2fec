"""Where the rover has been and where it was last sent: the driven track and the last navigate's
goal, kept by the server whoever watches (the console's map and Foxglove's ``/nav/track`` both
read them), so a page opened after a drive shows the whole of it."""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

TRACK_POINTS = 5000  # positions kept: at TRACK_STEP apart, 100 m of driving
TRACK_STEP = 0.02  # m the rover moves (x + y) before the track gets a point


@dataclass(frozen=True)
class Goal:
    x: float
    y: float
    tolerance: float
    job: int  # the navigate that was sent there


class Travel:
    """Thread-safe: the pose's writer (a rover's thread) feeds the track, a navigate job sets
    the goal, the console and the telemetry hub read both."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._track: deque[tuple[float, float, float]] = deque(maxlen=TRACK_POINTS)
        self._goal: Goal | None = None
        self._version = 0  # counts track points added: a reader tells a new track from the one it has

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
