"""The simulated rover's drive: commanded motion, the wheel odometry that dead-reckons it, and the
truth that wheel slip and heading drift pull away from it.

A real rover knows how far its wheels turned, not how far it went: on loose ground it covers
less than its odometry says and its heading drifts (MER and MSL report several percent of
distance and a few degrees per metre on sand). The simulator keeps both poses, so navigation
can be run on the believed one (as the GNC would) and scored against the true one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["RoverDrive", "Slip", "step_pose"]


@dataclass(frozen=True)
class RoverDrive:
    """How the simulated rover drives: the speeds ``navigate -auto`` and ``sim drive`` use.

    Defaults: a Pioneer-class rover crawling as planetary rovers do (0.1 m/s, 15 deg/s on the
    spot); a scene overrides them in its ``rover:`` block (``speed``, ``turn_rate``).
    """

    speed: float = 0.1  # m/s
    turn_rate: float = 15.0  # deg/s
    step: float = 0.1  # simulated seconds per integration step (1 cm at 0.1 m/s)

    @classmethod
    def from_spec(cls, spec: dict | None) -> RoverDrive:
        spec = spec or {}
        out = cls(float(spec.get("speed", cls.speed)), float(spec.get("turn_rate", cls.turn_rate)),
                  float(spec.get("drive_step", cls.step)))
        if out.speed <= 0 or out.turn_rate <= 0 or out.step <= 0:
            raise ValueError("rover speed, turn_rate and drive_step must be > 0")
        return out


@dataclass
class Slip:
    """Wheel slip and heading drift, seeded so a mission is repeatable.

    ``distance``: the share of the commanded distance the rover falls short by (0.05: it covers
    95 % of what its odometry counts); ``heading``: degrees of unnoticed yaw per metre driven,
    always to the same side (drawn from the seed), as a rover with one sinking wheel drifts.
    Each step draws its own factor in [0.5, 1.5] around both, so the error is not a clean scale
    that a calibration would remove, yet averages to the configured fractions over a few metres.
    """

    distance: float = 0.0
    heading: float = 0.0
    seed: int = 0
    rng: np.random.Generator = field(init=False, repr=False)
    side: float = field(init=False)

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng(self.seed)
        self.side = 1.0 if self.rng.uniform() < 0.5 else -1.0

    @property
    def active(self) -> bool:
        return self.distance != 0.0 or self.heading != 0.0

    def apply(self, ds: float, dyaw: float) -> tuple[float, float]:
        """The true (distance, yaw) of a step commanded as (ds, dyaw)."""
        if not self.active:
            return ds, dyaw
        u1, u2 = self.rng.uniform(0.5, 1.5, 2)
        return float(ds * (1.0 - self.distance * u1)), float(dyaw + self.side * self.heading * abs(ds) * u2)


def step_pose(pose: tuple[float, float, float], ds: float, dyaw: float) -> tuple[float, float, float]:
    """Move forward ``ds`` while turning ``dyaw`` degrees (midpoint heading: an arc to second order)."""
    x, y, h = pose
    mid = math.radians(h + dyaw / 2.0)
    return x + ds * math.cos(mid), y + ds * math.sin(mid), (h + dyaw + 180.0) % 360.0 - 180.0
