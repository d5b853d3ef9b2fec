"""Steering geometry of the see loop: pure pursuit along the waypoints, the arc or the turn on
the spot it commands, and the poses the rover passes through doing it (what the live check
sweeps)."""

from __future__ import annotations

import math

import numpy as np

from prox_workflows.algorithms.arcs import arc_poses


def arc_rate(pose: tuple[float, float, float], target: tuple[float, float], speed: float, turn_rate: float,
             arc_turn: float) -> float | None:
    """Pure pursuit: the turn rate (deg/s) of the arc at ``speed`` from ``pose`` through
    ``target``, or None when the heading error is turned on the spot instead: above
    ``arc_turn``, or when that arc is tighter than ``turn_rate`` allows. A capped arc would
    swing wide of the path, over ground neither the plan nor the check looked at (with the
    body footprint hugging rocks in hirise, onto them)."""
    dx, dy = target[0] - pose[0], target[1] - pose[1]
    error = (math.degrees(math.atan2(dy, dx)) - pose[2] + 180.0) % 360.0 - 180.0
    w = math.degrees(speed * 2.0 * math.sin(math.radians(error)) / max(math.hypot(dx, dy), 1e-6))
    return None if abs(error) > arc_turn or abs(w) > turn_rate else w


def motion_poses(pose: tuple[float, float, float], target: tuple[float, float], w: float | None, speed: float,
                 dt: float) -> np.ndarray:
    """The poses the rover passes through in one cycle of the see loop's drive (:class:`~rvs_server.navigation.map_legs.SeePilot`): the arc at
    turn rate ``w`` (deg/s, :func:`arc_rate`) for ``dt`` seconds at ``speed``, or, with ``w``
    None, the turn on the spot to face ``target`` (its two end poses; the check sweeps the turn
    between them in 5-degree steps)."""
    if w is None:
        bearing = math.degrees(math.atan2(target[1] - pose[1], target[0] - pose[0]))
        turn = (bearing - pose[2] + 180.0) % 360.0 - 180.0
        return np.array([pose, (pose[0], pose[1], pose[2] + turn)], dtype=np.float64)
    return arc_poses(pose, math.radians(w) / speed, speed * max(dt, 0.0), step=0.05)


def passed(pose: tuple[float, float, float], a: np.ndarray, b: np.ndarray, reach: float = 0.02) -> bool:
    """Whether the rover (by odometry) has reached waypoint ``b`` of the stretch a-b: within
    ``reach`` of it, or past the line through it square to the stretch."""
    dx, dy = float(b[0] - a[0]), float(b[1] - a[1])
    px, py = pose[0] - float(b[0]), pose[1] - float(b[1])
    if math.hypot(px, py) <= reach:
        return True
    return (dx != 0.0 or dy != 0.0) and dx * px + dy * py >= 0.0


def nearest_stretch(pose: tuple[float, float, float], wps: np.ndarray, k: int, window: int = 3) -> int:
    """The waypoint ending the stretch nearest the rover among k-1..k and the next ones (the
    earliest of equals). :func:`passed` alone leaves the rover on a short side stretch it drove
    beside without crossing the line square to its end; pursuit from the foot on that stretch
    aims behind the rover, which then turns about and drives where no check has looked."""
    here = np.asarray(pose[:2], dtype=np.float64)
    best, best_j = math.inf, k
    for j in range(k, min(k + window, len(wps))):
        a, b = wps[j - 1], wps[j]
        ab = b - a
        n = float(ab @ ab)
        t = 0.0 if n == 0.0 else min(1.0, max(0.0, float((here - a) @ ab) / n))
        d = float(np.hypot(*(a + t * ab - here)))
        if d < best - 1e-9:
            best, best_j = d, j
    return best_j


def pursuit_point(pose: tuple[float, float, float], wps: np.ndarray, k: int, ahead: float) -> tuple[float, float]:
    """The point ``ahead`` metres along the path from the rover's foot on stretch k-1..k (the
    last waypoint when the path is shorter)."""
    a, b = wps[k - 1], wps[k]
    ab = b - a
    n = float(ab @ ab)
    t = 0.0 if n == 0.0 else min(1.0, max(0.0, float((np.array(pose[:2]) - a) @ ab) / n))
    here = a + t * ab
    left = ahead
    for j in range(k, len(wps)):
        seg = wps[j] - here
        d = float(np.hypot(*seg))
        if d >= left:
            p = here + seg * (left / d)
            return float(p[0]), float(p[1])
        left -= d
        here = wps[j]
    return float(wps[-1][0]), float(wps[-1][1])
