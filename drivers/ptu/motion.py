"""Trapezoidal axis motion, as the PTU-D46 runs it: symmetric acceleration up to the commanded
speed, cruise, symmetric deceleration onto the target; a new target or speed while moving is
planned from the current position and velocity (the D46 changes both on the fly).

Profiles are exact piecewise-constant-acceleration segments rather than a numerical
integration, so the emulator's simulated move time is the analytic one whatever its tick.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

_EPS = 1e-9


def plan(p0: float, v0: float, target: float, vmax: float, acc: float) -> list[tuple[float, float]]:
    """Segments (duration s, acceleration pos/s^2) taking (p0, v0) to rest at ``target``."""
    vmax, acc = abs(float(vmax)), abs(float(acc))
    if vmax <= 0 or acc <= 0:
        raise ValueError("speed and acceleration must be positive")
    d = float(target) - float(p0)
    if abs(d) < _EPS and abs(v0) < _EPS:
        return []
    s = 1.0 if (d > 0 or (abs(d) < _EPS and v0 < 0)) else -1.0
    dist, u = d * s, v0 * s  # in the frame where the target lies ahead
    if u < -_EPS:  # moving away from the target: stop first
        t = -u / acc
        return [(t, acc * s)] + plan(_pos(p0, v0, acc * s, t), 0.0, target, vmax, acc)
    if u * u / (2 * acc) > dist + _EPS:  # cannot stop in time: stop past it, then come back
        t = u / acc
        return [(t, -acc * s)] + plan(_pos(p0, v0, -acc * s, t), 0.0, target, vmax, acc)
    if u > vmax + _EPS:  # speed lowered on the fly: slow down to it first
        t = (u - vmax) / acc
        return [(t, -acc * s)] + plan(_pos(p0, v0, -acc * s, t), vmax * s, target, vmax, acc)
    u = max(u, 0.0)
    peak = math.sqrt(acc * dist + u * u / 2)
    if peak <= vmax:  # triangular
        return _nonzero([((peak - u) / acc, acc * s), (peak / acc, -acc * s)])
    t1 = (vmax - u) / acc
    d1 = (vmax * vmax - u * u) / (2 * acc)
    d3 = vmax * vmax / (2 * acc)
    return _nonzero([(t1, acc * s), ((dist - d1 - d3) / vmax, 0.0), (vmax / acc, -acc * s)])


def trapezoid_time(distance: float, vmax: float, acc: float) -> float:
    """Rest-to-rest move time, for callers that want to predict a move (and for tests)."""
    distance, vmax, acc = abs(distance), abs(vmax), abs(acc)
    if distance * acc <= vmax * vmax:
        return 2 * math.sqrt(distance / acc)
    return distance / vmax + vmax / acc


def _pos(p: float, v: float, a: float, t: float) -> float:
    return p + v * t + 0.5 * a * t * t


def _nonzero(segs: list[tuple[float, float]]) -> list[tuple[float, float]]:
    return [(t, a) for t, a in segs if t > _EPS]


@dataclass
class Profile:
    """A planned motion started at simulated time ``t0``; ``at(t)`` gives (position, velocity)."""

    t0: float
    p0: float
    v0: float
    target: float
    segments: list[tuple[float, float]]

    def __post_init__(self) -> None:
        self._starts: list[tuple[float, float, float]] = []  # (t, p, v) at each segment start
        t, p, v = self.t0, self.p0, self.v0
        for dt, a in self.segments:
            self._starts.append((t, p, v))
            p, v, t = _pos(p, v, a, dt), v + a * dt, t + dt
        self.end = t

    @classmethod
    def start(cls, t0: float, p0: float, v0: float, target: float, vmax: float, acc: float) -> Profile:
        return cls(t0, p0, v0, target, plan(p0, v0, target, vmax, acc))

    def at(self, t: float) -> tuple[float, float]:
        if t >= self.end:
            return self.target, 0.0
        if t <= self.t0:
            return self.p0, self.v0
        for (ts, p, v), (_dt, a) in zip(reversed(self._starts), reversed(self.segments), strict=True):
            if t >= ts:
                tau = t - ts
                return _pos(p, v, a, tau), v + a * tau
        return self.p0, self.v0
