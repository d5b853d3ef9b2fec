"""The simulated rover's drive: commanded motion, the wheel odometry that dead-reckons it, and the
truth that wheel slip and heading drift pull away from it.

A real rover knows how far its wheels turned, not how far it went: on loose ground it covers
less than its odometry says and its heading drifts (MER and MSL report several percent of
distance and a few degrees per metre on sand). The simulator keeps both poses, so navigation
can be run on the believed one (as the GNC would) and scored against the true one.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, fields

import numpy as np

__all__ = ["IMU_SIGMA_DEG", "RoverBody", "RoverDrive", "Slip", "resting_attitude", "resting_plane", "resting_pose",
           "step_pose"]

# deg, 1-sigma: the simulated IMU's roll and pitch at rest (an industrial MEMS IMU levels to about
# 0.05-0.1 deg from gravity); the sim rover's attitude carries this noise and says so
IMU_SIGMA_DEG = 0.1


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


@dataclass(frozen=True)
class RoverBody:
    """The simulated rover's body and what it can drive over: one declaration that the rendered
    body (:func:`drivers.sim.scene.build_rover`) and the vehicle check
    (:mod:`prox_workflows.algorithms.vehicle`) both read. A scene overrides any field in its
    ``rover: body:`` block.

    The body copies a Pioneer 3-AT (MobileRobots/Adept; 508 x 497 x 277 mm, four 21.5 cm wheels,
    skid steering, "max. traversable grade 35 %" in its documentation). Where the figure is the
    P3-AT's, the field says so; the rest is the simulated body's own, which differs from the P3-AT
    on purpose in one way: its wheels stand outside the 0.40 m box (the hubs 0.49 m apart, the
    outer wheel faces at +-0.29 m), so the box is all belly between the wheel tracks.

    - ``wheel_radius`` 0.1075 m: the P3-AT's 21.5 cm wheel (the ROS/Gazebo P3-AT drive plugins'
      ``wheelDiameter`` 0.215).
    - ``wheelbase`` 0.29 m, ``track`` 0.49 m: hub to hub, front to back and side to side; the wheels
      sit at the box's corners (0.51 m long box: hubs one radius in from its ends, 0.255 - 0.11).
    - ``clearance`` 0.08 m: the underside of the box over the plane through the wheel contacts.
    - ``climb`` 0.10 m: the greatest step edge one wheel climbs, the traversable step quoted for
      the P3-AT (its datasheet was not at hand to confirm it); it is also what a rigid four-wheel
      skid steer with pneumatic tyres climbs at most: about half its 21.5 cm wheel, a step whose
      edge still lies below the hub with margin.
    - ``grade`` 19.3 deg: the steepest sustained slope, the P3-AT's "max. traversable grade 35 %"
      (atan 0.35): a traction figure, judged on the plane fitted under the whole body, not on a
      momentary tilt. Dem2Hazard's 20 deg slope limit sits just above it.
    - ``cog_height`` 0.163 m: the centre of gravity over the plane through the wheel contacts, over
      the middle of the hubs. The P3-AT's: MobileRobots' own ROS model
      (github.com/MobileRobots/amr-ros-config, ``description/urdf/pioneer3at.urdf.xacro``) puts
      the chassis with three batteries (21.5 kg) at 0.177 m over the ground and the four wheels
      with axles and hubs (4 x 1.4 kg) at their 0.111 m axles: (21.5 x 0.177 + 5.6 x 0.111) / 27.1
      = 0.163 m. It puts the chassis' mass at x 0; its -0.1 m lateral offset is not taken, the
      P3-AT's chassis being symmetric side to side. The simulated body has no mass
      of its own; its box (0.08-0.28 m) centres at 0.18 m, so it takes the P3-AT's figure.
    - ``safety`` 1.5: the static tip-over angle (from ``cog_height`` and the support polygon, the
      rectangle of the hubs) is divided by it before the resting plane's tilt is judged against
      it: the margin for what a static figure leaves out (dynamics, a wheel sinking, the CoG's
      uncertainty).
    """

    length: float = 0.51  # m, the box (P3-AT: 0.508)
    width: float = 0.40  # m, the box between the wheels
    height: float = 0.28  # m, top of the box over the ground (P3-AT: 0.277)
    clearance: float = 0.08  # m, belly over the contact plane
    wheel_radius: float = 0.1075  # m (P3-AT: 21.5 cm wheels)
    wheel_width: float = 0.09  # m
    wheelbase: float = 0.29  # m, front to rear hub
    track: float = 0.49  # m, left to right hub
    climb: float = 0.10  # m, greatest step edge a wheel climbs (P3-AT: 10 cm)
    grade: float = 19.3  # deg, steepest sustained slope (P3-AT: 35 % grade)
    cog_height: float = 0.163  # m, centre of gravity over the contact plane (P3-AT's ROS model)
    safety: float = 1.5  # the static tip-over angle is divided by it

    @classmethod
    def from_spec(cls, spec: dict | None) -> RoverBody:
        """From a scene's ``rover: body:`` block (any subset of the fields); a bad or unknown key
        is a ValueError naming the fields."""
        spec = dict(spec or {})
        names = [f.name for f in fields(cls)]
        unknown = sorted(set(spec) - set(names))
        if unknown:
            raise ValueError(f"unknown rover body key(s) {', '.join(unknown)}; known: {', '.join(names)}")
        out = cls(**{k: float(v) for k, v in spec.items()})
        if min(getattr(out, n) for n in names) <= 0:
            raise ValueError(f"rover body figures must be > 0: {out}")
        if out.clearance >= out.height or out.wheelbase / 2 + out.wheel_radius > out.length / 2 + 1e-9:
            raise ValueError("rover body: the belly must lie under the top, and the wheels within the box's length")
        if out.safety < 1.0:
            raise ValueError(f"rover body: safety {out.safety:g} must be >= 1 (it divides the tip-over angle)")
        return out

    @property
    def wheels(self) -> np.ndarray:
        """The four hubs (x forward, y left, rover frame), front-left, front-right, rear-left,
        rear-right."""
        a, b = self.wheelbase / 2, self.track / 2
        return np.array([(a, b), (a, -b), (-a, b), (-a, -b)])


_TRIPLETS = ((0, 1, 2, 3), (0, 1, 3, 2), (0, 2, 3, 1), (1, 2, 3, 0))  # three wheels a body rests on, the fourth


def resting_plane(body: RoverBody, heights: Callable[[np.ndarray, np.ndarray], np.ndarray],
                  pose: tuple[float, float, float], step: float = 0.01) -> tuple[float, float, float, float]:
    """The plane ``body`` rests on at ``pose`` on the surface ``heights(x, y)``: its height at
    the rover's centre, its rise per metre along the body's x and y (level axes turned by the
    heading), and how far the fourth wheel's ground lies below it (m, <= 0). Each wheel rests on
    the highest ground its circle touches under its footprint, the rigid body on three wheels
    with the fourth at or below their plane; of the two planes it may rock between, it settles
    on the one that puts its centre lower."""
    r, half_w = body.wheel_radius, body.wheel_width / 2
    # odd counts: the samples hold the wheel's lowest point, so it rests on flat ground at its height
    dx, dy = (a.ravel() for a in np.meshgrid(np.linspace(-r, r, 2 * math.ceil(r / step) + 1),
                                             np.linspace(-half_w, half_w, 2 * math.ceil(half_w / step) + 1)))
    sag = r - np.sqrt(np.maximum(r * r - dx * dx, 0.0))
    c, s = math.cos(math.radians(pose[2])), math.sin(math.radians(pose[2]))
    hubs = body.wheels
    contact = np.zeros(4)
    for w, (hx, hy) in enumerate(hubs):
        px, py = hx + dx, hy + dy
        z = np.asarray(heights(pose[0] + c * px - s * py, pose[1] + s * px + c * py), float) - sag
        contact[w] = float(np.nanmax(z)) if np.isfinite(z).any() else 0.0
    rests = []
    for t in _TRIPLETS:
        a, b, k = np.linalg.solve(np.column_stack([hubs[list(t[:3])], np.ones(3)]), contact[list(t[:3])])
        below = contact[t[3]] - (a * hubs[t[3], 0] + b * hubs[t[3], 1] + k)
        if below <= 1e-9:
            rests.append((float(k), float(a), float(b), float(below)))
    return min(rests)  # of the two planes it rocks between, it settles on the lower


def resting_pose(body: RoverBody, heights: Callable[[np.ndarray, np.ndarray], np.ndarray],
                 pose: tuple[float, float, float], step: float = 0.01) -> tuple[float, float, float]:
    """Height, roll (left side up) and pitch (nose up), deg, of ``body`` resting at ``pose``
    (:func:`resting_plane`). The height is where the plane meets the rover's centre, the rover
    frame's origin: its sensors ride on the body, so every frame is taken from this pose. The
    fourth wheel's ground below the plane no IMU shows."""
    k, a, b, _ = resting_plane(body, heights, pose, step)
    pitch = math.atan(a)
    return k, math.degrees(math.atan(b * math.cos(pitch))), math.degrees(pitch)


def resting_attitude(body: RoverBody, heights: Callable[[np.ndarray, np.ndarray], np.ndarray],
                     pose: tuple[float, float, float], step: float = 0.01) -> tuple[float, float]:
    """Roll and pitch (deg) of :func:`resting_pose`: what the rover's IMU reads at rest."""
    return resting_pose(body, heights, pose, step)[1:]


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
