"""Trapezoidal axis motion, as the PTU-D46 runs it: speeds up to the base (start-up) speed are
reached at once, faster ones by symmetric acceleration from the base speed up to the commanded
speed, cruise, then symmetric deceleration down to the base speed and an instant stop on the
target (PTU-D46 manual v2.14, 4.4.4-4.4.5: acceleration applies "for speeds above the base
speed", which defaults to 1000 positions/s). A new target or speed while moving is planned from
the current position and velocity (the D46 changes both on the fly).

Profiles are exact piecewise-constant-acceleration segments rather than a numerical
integration, so the emulator's simulated move time is the analytic one whatever its tick.

It sits in the bottom layer because the PTU's emulator and the scan planner
(:mod:`prox_workflows.algorithms.ptu_positions`, which may not import a driver) both time moves by it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

_EPS = 1e-9

# (duration s, velocity at the segment's start pos/s, acceleration pos/s^2): the velocity may
# jump between segments by up to the base speed (a start, a stop or a reversal below it)
Segment = tuple[float, float, float]


def plan(p0: float, v0: float, target: float, vmax: float, acc: float, base: float = 0.0) -> list[Segment]:
    """Segments taking (p0, v0) to rest at ``target``; ``base`` is the axis's base speed."""
    vmax, acc, base = abs(float(vmax)), abs(float(acc)), abs(float(base))
    if vmax <= 0 or acc <= 0:
        raise ValueError("speed and acceleration must be positive")
    ve = min(base, vmax)  # the speed an axis starts at and stops from without a ramp
    d = float(target) - float(p0)
    if abs(d) < _EPS and abs(v0) <= ve + _EPS:
        return []
    s = 1.0 if (d > 0 or (abs(d) < _EPS and v0 < 0)) else -1.0
    dist, u = d * s, v0 * s  # in the frame where the target lies ahead
    if u < -ve - _EPS:  # moving away from the target faster than it can stop: slow to the base speed
        t = (-u - ve) / acc
        return [(t, v0, acc * s)] + plan(_pos(p0, v0, acc * s, t), 0.0, target, vmax, acc, base)
    u = max(u, 0.0)  # below the base speed a reversal is a stop and a start, both instant
    if (u * u - ve * ve) / (2 * acc) > dist + _EPS:  # cannot stop in time: stop past it, then come back
        t = (u - ve) / acc
        return [(t, u * s, -acc * s)] + plan(_pos(p0, u * s, -acc * s, t), 0.0, target, vmax, acc, base)
    if u > vmax + _EPS:  # speed lowered on the fly: slow down to it first
        t = (u - vmax) / acc
        return [(t, u * s, -acc * s)] + plan(_pos(p0, u * s, -acc * s, t), vmax * s, target, vmax, acc, base)
    u = max(u, ve)
    if vmax <= ve + _EPS:  # the commanded speed is within the base speed: no ramp at all
        return _nonzero([(dist / vmax, vmax * s, 0.0)])
    peak = math.sqrt(acc * dist + (u * u + ve * ve) / 2)
    if peak <= vmax:  # triangular
        return _nonzero([((peak - u) / acc, u * s, acc * s), ((peak - ve) / acc, peak * s, -acc * s)])
    t1 = (vmax - u) / acc
    d1 = (vmax * vmax - u * u) / (2 * acc)
    d3 = (vmax * vmax - ve * ve) / (2 * acc)
    return _nonzero([(t1, u * s, acc * s), ((dist - d1 - d3) / vmax, vmax * s, 0.0),
                     ((vmax - ve) / acc, vmax * s, -acc * s)])


def trapezoid_time(distance: float, vmax: float, acc: float, base: float = 0.0) -> float:
    """Rest-to-rest move time (the planner's and the tests' prediction of a move)."""
    distance, vmax, acc = abs(distance), abs(vmax), abs(acc)
    ve = min(abs(base), vmax)
    if distance < _EPS:
        return 0.0
    if vmax <= ve:
        return distance / vmax
    ramps = (vmax * vmax - ve * ve) / acc  # the distance both ramps cover
    if distance <= ramps:
        return 2 * (math.sqrt(acc * distance + ve * ve) - ve) / acc
    return 2 * (vmax - ve) / acc + (distance - ramps) / vmax


def stop_distance(v: float, acc: float, base: float = 0.0) -> float:
    """How far an axis moving at ``v`` runs on after a halt (decelerating to the base speed)."""
    return max(v * v - min(abs(base), abs(v)) ** 2, 0.0) / (2 * abs(acc))


def _pos(p: float, v: float, a: float, t: float) -> float:
    return p + v * t + 0.5 * a * t * t


def _nonzero(segs: list[Segment]) -> list[Segment]:
    return [seg for seg in segs if seg[0] > _EPS]


@dataclass
class Profile:
    """A planned motion started at simulated time ``t0``; ``at(t)`` gives (position, velocity)."""

    t0: float
    p0: float
    v0: float
    target: float
    segments: list[Segment]

    def __post_init__(self) -> None:
        self._starts: list[tuple[float, float]] = []  # (t, p) at each segment start
        t, p = self.t0, self.p0
        for dt, v, a in self.segments:
            self._starts.append((t, p))
            p, t = _pos(p, v, a, dt), t + dt
        self.end = t

    @classmethod
    def start(cls, t0: float, p0: float, v0: float, target: float, vmax: float, acc: float,
              base: float = 0.0) -> Profile:
        return cls(t0, p0, v0, target, plan(p0, v0, target, vmax, acc, base))

    def at(self, t: float) -> tuple[float, float]:
        if t >= self.end:
            return self.target, 0.0
        if t <= self.t0:
            return self.p0, self.v0
        for (ts, p), (_dt, v, a) in zip(reversed(self._starts), reversed(self.segments), strict=True):
            if t >= ts:
                tau = t - ts
                return _pos(p, v, a, tau), v + a * tau
        return self.p0, self.v0
