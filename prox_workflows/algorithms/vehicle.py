"""The vehicle check: whether the rover's own body, standing at a pose on a height grid, is safe.

A rover fails on ground in four ways, each a physical limit of the declared body
(:class:`VehicleBody`, e.g. ``drivers.sim.rover.RoverBody``, which says where each figure comes from):

- **step**: a wheel meets an edge it cannot climb. Along the wheel's rolling direction (the
  heading), the greatest rise between two ground samples at most two samples apart (2 cm on the
  1 cm truth) anywhere under its footprint (``2 * wheel_radius`` along, ``wheel_width`` across),
  in either direction of travel (a drop driven forward is a rise reversing). Ground rising that
  much over so short a run meets the wheel's circle as an edge; ground the circle follows (a
  slope, a smooth dome) rises little over it: a 9 cm dome 30 cm wide rises at most 2 cm, a
  35 % grade 0.7 cm, a vertical 9 cm edge 9 cm. The footprint is the wheel's contact length
  forward and back of its hub, so every edge a track passes shows at a dozen poses 2 cm apart.
  On a turn on the spot a skid-steer wheel still rolls along the heading while it scrubs
  sideways; an edge swept in from the side enters its footprint's lanes and is caught there.
  Against ``climb``.
- **belly**: the ground under the box between the wheels rises above the belly. The body stands
  on its wheels: each wheel rests on the highest ground its circle touches, and a rigid body on
  four wheels rests on three of them with the fourth at or below that plane (it rocks between two
  such planes). Intrusion = the highest ground under the box over the worse of those planes,
  minus ``clearance``. Against 0.
- **stability**: the resting plane's tilt against the static tip-over angle in the direction it
  leans (:func:`tip_angle`: the centre of gravity ``cog_height`` over the plane, the support
  polygon the rectangle of the hubs), divided by ``safety``. A momentary pitch while a wheel
  climbs a rock it can climb is judged here, against what tips the body over, not against a grade.
- **grade**: the slope of the plane fitted to all the ground under the body, against ``grade``
  (a traction figure for a sustained slope: a rock under one wheel barely moves that plane).

ACE (Otsu et al. 2020) makes the same wheel-and-belly check on a rover's own geometry; this one
has no suspension to model (the P3-AT is a rigid skid steer).

Every excess is reported with a severity band (:data:`BANDS`: up to 0.5 cm or deg, up to 2,
beyond); one event of any band still fails a mission.

Everything is vectorised over poses: :func:`check_poses` takes N poses and returns per-pose
arrays, :func:`densify` turns a track (or a plan) into poses no more than a given distance apart,
turns on the spot included, and :func:`unsafe_events` counts the distinct unsafe stretches: any
run of consecutive unsafe poses is one event, with its worst excess and kind.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ..grid import GridGeometry

__all__ = ["VehicleBody", "PoseChecks", "Event", "Margins", "Gate", "check_poses", "densify", "gate_poses",
           "unsafe_events", "track_poses", "tip_angle", "reach", "severity", "WHEELS", "LIMITS", "BANDS",
           "BOUNDS_STEP"]

READ_LOW_P99 = 0.051  # m: the ToF's DEM at 5 cm, marsyard (docs/NAVIGATE_BENCH.md, Error budget)
TRACKING_P99 = 0.03  # m: the see loop's true track from its planned legs, worst mission p99
WHEELS = ("front-left", "front-right", "rear-left", "rear-right")
LIMITS = ("step", "belly", "stability", "grade")  # the excess columns, in order
# Severity bands of an excess (cm for step and belly, deg for stability and grade): upper edges.
BANDS = ((0.5, "slight"), (2.0, "moderate"), (math.inf, "severe"))
# The four planes a rigid body may rest on: three wheels each, the fourth named last.
_TRIPLETS = ((0, 1, 2, 3), (0, 1, 3, 2), (0, 2, 3, 1), (1, 2, 3, 0))
_EDGE_SAMPLES = 2  # a step is a rise within this many sample intervals along the rolling direction
_GRADE_DIRECTIONS = 32  # on bounds, the worst fitted plane is sought at twice this many zonotope vertices
# On bounds the body is sampled this many cells apart by default. A sample reads the one cell that
# holds it, so every cell under the body must hold one: a square lattice of spacing s, at any
# heading, leaves no disc wider than s * sqrt(2) empty, and a cell holds a disc one cell wide, so
# s < 1 / sqrt(2) puts a sample in every cell wholly under the body (at one cell apart, 5-12 of the
# 60 cells under the box at oblique headings hold none, and a rock there goes unseen).
BOUNDS_STEP = 0.7


class VehicleBody(Protocol):
    """What the check needs of a body (metres, degrees; rover frame x forward, y left)."""

    length: float
    width: float
    clearance: float
    wheel_radius: float
    wheel_width: float
    climb: float
    grade: float
    cog_height: float
    safety: float

    @property
    def wheels(self) -> np.ndarray: ...  # (4, 2) hubs: front-left, front-right, rear-left, rear-right


def tip_angle(body: VehicleBody, direction: np.ndarray | float) -> np.ndarray:
    """The static tip-over angle (deg) of ``body`` leaning toward ``direction`` (deg, rover frame:
    0 nose down, 90 left side down): the tilt at which the centre of gravity, ``cog_height`` over
    the resting plane, stands over the edge of the support polygon (the rectangle of the hubs)
    along that direction: atan(distance to that edge / cog_height). Pure pitch gives
    atan(half-wheelbase / h), pure roll atan(half-track / h)."""
    d = np.radians(np.asarray(direction, float))
    return _tip(body, -np.cos(d), -np.sin(d))


def _tip(body: VehicleBody, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`tip_angle` of planes z = a x + b y (rover frame), each leaning toward -(a, b): the
    check's own formula (``_vehicle_kernel._tip``: the centre of gravity's foot moves that way,
    and reaches the polygon's edge along it after min(fore / |cos|, side / |sin|) = |(a, b)|
    min(fore / |a|, side / |b|); a level plane's is 90)."""
    a, b = np.broadcast_arrays(np.asarray(a, np.float64), np.asarray(b, np.float64))
    out = np.empty(a.shape)
    _kernel().tips(np.ascontiguousarray(a).ravel(), np.ascontiguousarray(b).ravel(), *_support(body),
                   float(body.cog_height), out.reshape(-1))
    return out[()]


def _support(body: VehicleBody) -> tuple[float, float]:
    """How far the support polygon (the rectangle of the hubs) reaches fore and to the side."""
    hubs = np.abs(np.asarray(body.wheels, float))
    return float(hubs[:, 0].min()), float(hubs[:, 1].min())


def severity(kind: str, excess: float) -> str:
    """The band of an ``excess`` over the limit ``kind`` names (m for step and belly, judged in
    cm; deg for stability and grade)."""
    value = excess * 100 if _in_cm(kind) else excess
    return next(name for edge, name in BANDS if value <= edge)


def _in_cm(kind: str) -> bool:
    return kind.startswith("step") or kind == "belly"


def _shown(kind: str, excess: float) -> str:
    value, unit = (excess * 100, "cm") if _in_cm(kind) else (excess, "deg")
    return f"{kind} +{value:.1f} {unit} ({severity(kind, excess)})"


@dataclass(frozen=True)
class Margins:
    """How far below the body's capability the planner and the live check must judge, so that
    what the maps read and how the rover follows its path stay within it: the error budget
    ``python -m tools.bench.navigate --budget`` measures and prints (docs/NAVIGATE_BENCH.md,
    "Error budget"). The defaults are its figures, not guesses:

    - ``read_low``: how much lower than the true top the ToF's map (what both loops map with)
      reads a rock cell, p99 at 5 cm cells in marsyard; hirise's is 0.095, above the body's 8 cm
      step capability itself, so no threshold is left there (:meth:`thresholds` says so);
    - ``tracking``: how far the see loop's true track strays from its planned legs, p99 of the
      worst mission (the scan loop follows its waypoints exactly: 0).
    """

    read_low: float = READ_LOW_P99
    tracking: float = TRACKING_P99

    def thresholds(self, body: VehicleBody) -> dict[str, float]:
        """Dem2Hazard's step and slope limits and the planner's lateral margin for ``body``: its
        step capability (the lower of its climb and its belly: a rock under the box must pass
        beneath it) less the read-low error; its grade (Dem2Hazard's slope is a plane fitted over
        its window, as the grade limit's is over the body); the tracking error. A ValueError when
        the read-low error leaves no step at all."""
        cap = min(body.climb, body.clearance)
        if self.read_low >= cap:
            raise ValueError(f"a {self.read_low * 100:.1f} cm read-low budget leaves no step below the body's "
                             f"{cap * 100:.1f} cm capability: the maps must read rocks closer to their tops")
        return {"step_max": round(cap - self.read_low, 3), "slope_max": body.grade, "margin": self.tracking}


@dataclass
class PoseChecks:
    """Per-pose results of :func:`check_poses` (N poses)."""

    step: np.ndarray  # (N, 4) m, the greatest edge under each wheel (WHEELS order)
    intrusion: np.ndarray  # (N,) m, ground over the belly (> 0: touches)
    tilt: np.ndarray  # (N,) deg, the resting plane's tilt (the plane worst for stability)
    tip: np.ndarray  # (N,) deg, the tip-over angle in the direction that plane leans (before safety)
    grade: np.ndarray  # (N,) deg, the slope of the plane fitted under the whole body
    excess: np.ndarray  # (N, 4) over the limits (LIMITS order): step (m), belly (m), stability, grade (deg); <= 0 safe
    wheel: np.ndarray  # (N,) int, the wheel with the greatest step
    unknown: np.ndarray  # (N,) bool: on bounds, ground under the body no bound covers (never safe)

    @property
    def unsafe(self) -> np.ndarray:
        return (self.excess > 0).any(axis=1)

    @property
    def safe(self) -> np.ndarray:
        """Judged and within every limit: what a rover may drive on."""
        return ~self.unsafe & ~self.unknown

    def relative(self, body: VehicleBody) -> np.ndarray:
        """(N, 4) each excess over its own limit (stability's: the tip-over angle in the direction
        the body leans, over the safety factor), so that limits in m and deg compare; NaN (no
        ground judged) as -inf."""
        n = len(self.tip)
        limits = np.column_stack([np.full(n, body.climb), np.full(n, body.clearance), self.tip / body.safety,
                                  np.full(n, body.grade)])
        return np.nan_to_num(self.excess / limits, nan=-np.inf)

    def worst(self, body: VehicleBody) -> tuple[np.ndarray, np.ndarray]:
        """Per pose, the limit with the greatest relative excess (LIMITS index) and that excess
        (m or deg)."""
        k = np.argmax(self.relative(body), axis=1)
        return k, self.excess[np.arange(len(k)), k]

    def kind(self, i: int, k: int) -> str:
        """The name of limit ``k`` at pose ``i``: ``step front-left``..., ``belly``, ``stability``,
        ``grade``."""
        return f"step {WHEELS[self.wheel[i]]}" if k == 0 else LIMITS[k]


@dataclass(frozen=True)
class Event:
    """A run of consecutive unsafe poses: where it starts and ends (pose indices, inclusive), the
    kind of the worst excess (``step front-left``..., ``belly``, ``stability``, ``grade``), that
    excess (m, or deg for stability and grade) and the pose where it is worst."""

    first: int
    last: int
    kind: str
    excess: float
    x: float
    y: float
    heading: float

    @property
    def band(self) -> str:
        """The excess's severity band (:data:`BANDS`)."""
        return severity(self.kind, self.excess)

    def describe(self) -> str:
        return f"{_shown(self.kind, self.excess)} at ({self.x:.2f}, {self.y:.2f}, {self.heading:.0f} deg)"


@dataclass(frozen=True)
class _Pattern:
    """Sample offsets in the rover frame every ``step``: the points (S, 2), each one's wheel (or
    -1), the belly mask, the along-heading offset from its wheel's hub, and per wheel its samples
    as lanes along the heading ((W, L) indices into the points, W lanes across, L along)."""

    pts: np.ndarray
    wheel_of: np.ndarray
    belly: np.ndarray
    dx: np.ndarray
    lanes: tuple[np.ndarray, ...]


def _pattern(body: VehicleBody, step: float) -> _Pattern:
    hubs = np.asarray(body.wheels, float)
    r, half_w = body.wheel_radius, body.wheel_width / 2
    xmax = max(body.length / 2, float(np.abs(hubs[:, 0]).max()) + r)
    ymax = max(body.width / 2, float(np.abs(hubs[:, 1]).max()) + half_w)
    xs = np.arange(-xmax, xmax + step / 2, step)
    ys = np.arange(-ymax, ymax + step / 2, step)
    X, Y = np.meshgrid(xs, ys)  # (rows across, columns along the heading)
    wheel = np.full(X.shape, -1)
    dx = np.zeros(X.shape)
    for i, (hx, hy) in enumerate(hubs):
        on = (np.abs(X - hx) <= r + 1e-9) & (np.abs(Y - hy) <= half_w + 1e-9)
        wheel[on] = i
        dx[on] = X[on] - hx
    belly = (np.abs(X) <= body.length / 2 + 1e-9) & (np.abs(Y) <= body.width / 2 + 1e-9) & (wheel < 0)
    keep = (wheel >= 0) | belly
    index = np.full(X.shape, -1)
    index[keep] = np.arange(int(keep.sum()))
    lanes = []
    for i in range(len(hubs)):
        rows, cols = np.nonzero(wheel == i)
        lanes.append(index[rows.min():rows.max() + 1, cols.min():cols.max() + 1])  # a rectangle of samples
    return _Pattern(np.stack([X[keep], Y[keep]], axis=1), wheel[keep], belly[keep], dx[keep], tuple(lanes))


def _kernel():  # noqa: ANN202 - the compiled module, imported on first use (numba costs ~0.3 s)
    from . import _vehicle_kernel

    return _vehicle_kernel


def _sample(heights: np.ndarray, geom: GridGeometry, x: np.ndarray, y: np.ndarray, cellwise: bool = False
            ) -> np.ndarray:
    """Heights at the points (x, y) (NaN off the grid): bilinear between the cell centres on a
    height grid (the surface between its samples); ``cellwise``, the value of the cell that holds
    each point (a bounds map: a cell's bound holds for every point in it, so a point near a rock
    cell's edge reads the rock's bound, not a share of it). What :func:`check_poses` reads."""
    x, y = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
    out = np.empty(x.shape)
    _kernel().sample(heights, float(geom.xmin), float(geom.ymax), float(geom.cell), np.ascontiguousarray(x).ravel(),
                     np.ascontiguousarray(y).ravel(), cellwise, out.reshape(-1))
    return out


@dataclass(frozen=True)
class _Plan:
    """What :func:`check_poses` derives from the body and the sample spacing alone, once: the
    sample pattern (:func:`_pattern`) and the linear maps each limit applies to the samples."""

    pair_a: np.ndarray  # the step's sample pairs along each wheel's lanes, and the wheel of each
    pair_b: np.ndarray
    pair_wheel: np.ndarray
    ground: np.ndarray  # (2, S): the fitted plane's slope rows of the pseudo-inverse
    pulls: np.ndarray  # (2, S, D): the zonotope's signed pulls along each direction
    inv: np.ndarray  # (P, 3, 3) the resting planes through three hubs, and their wheels (P, 4)
    triplets: np.ndarray
    sag: np.ndarray  # (S,) the wheel circle's rise over each wheel sample
    belly: np.ndarray  # (B,) indices of the samples under the box
    px: np.ndarray  # (S,) the samples' offsets, and the wheel of each (-1: none)
    py: np.ndarray
    wheel_of: np.ndarray
    hubs: np.ndarray  # (4, 2)
    support: tuple[float, float]  # how far the hubs' rectangle reaches fore and to the side
    corners: tuple[np.ndarray, np.ndarray]  # the contacts' corners (lowest 0, highest 1): one grid, bounds


_PLANS: dict[tuple, _Plan] = {}


def _plan(body: VehicleBody, step: float) -> _Plan:
    """The plan for ``body`` sampled every ``step``, made once per body geometry and spacing (a
    process meets a few)."""
    key = (body.length, body.width, body.wheel_radius, body.wheel_width, np.asarray(body.wheels, float).tobytes(),
           float(step))
    plan = _PLANS.get(key)
    if plan is not None:
        return plan
    pat = _pattern(body, step)
    pts = pat.pts
    hubs = np.asarray(body.wheels, float)
    r = body.wheel_radius
    # a step: a rise within _EDGE_SAMPLES samples along a lane, either way
    pairs = []
    for w, lanes in enumerate(pat.lanes):
        for k in range(1, min(_EDGE_SAMPLES, lanes.shape[1] - 1) + 1):
            a, b = lanes[:, :-k].ravel(), lanes[:, k:].ravel()
            pairs.append((a, b, np.full(len(a), w)))
    pair_a, pair_b, pair_wheel = (np.concatenate(col).astype(np.int64) for col in zip(*pairs, strict=True))
    # the ground plane z = a x + b y + c over all samples, as one pseudo-inverse for every pose
    ground_pinv = np.linalg.pinv(np.column_stack([pts, np.ones(len(pts))]))  # (3, S)
    # on bounds the fitted slope (a, b) is linear in the ground, so over the box of grounds it
    # ranges over a zonotope; its steepest point is a vertex, the one each direction u picks by
    # taking every sample at the bound u's sign asks for; u and -u pick the two vertices
    # mid +- pull(u), so a half circle of directions gives 64 (within 0.1 % of the steepest)
    u = np.linspace(0.0, np.pi, _GRADE_DIRECTIONS, endpoint=False)
    signs = np.sign(np.cos(u)[:, None] * ground_pinv[0] + np.sin(u)[:, None] * ground_pinv[1])  # (D, S)
    pulls = np.stack([(signs * ground_pinv[0]).T, (signs * ground_pinv[1]).T]).copy()  # (2, S, D)
    # the wheel's circle: a point dx from the hub lifts the wheel's bottom by its height minus
    # the circle's rise there (the wheel rests on whatever touches it first)
    sag = r - np.sqrt(np.maximum(r * r - pat.dx * pat.dx, 0.0))
    # each resting plane through three hubs: z = [x y 1] @ inv(A) @ z3
    inv = np.stack([np.linalg.inv(np.column_stack([hubs[list(t[:3])], np.ones(3)])) for t in _TRIPLETS])
    corners = np.array([(a, b, c) for a in (0, 1) for b in (0, 1) for c in (0, 1)], np.int64)
    plan = _Plan(pair_a, pair_b, pair_wheel, np.ascontiguousarray(ground_pinv[:2]), pulls, inv,
                 np.asarray(_TRIPLETS, np.int64), sag, np.flatnonzero(pat.belly), np.ascontiguousarray(pts[:, 0]),
                 np.ascontiguousarray(pts[:, 1]), pat.wheel_of.astype(np.int64), hubs, _support(body),
                 (corners[:1].copy(), corners))
    _PLANS[key] = plan
    return plan


def _default_step(geom: GridGeometry, bounded: bool) -> float:
    return geom.cell * BOUNDS_STEP if bounded else geom.cell


def check_poses(heights: np.ndarray | tuple[np.ndarray, np.ndarray], geom: GridGeometry, poses: np.ndarray,
                body: VehicleBody, step: float | None = None, cellwise: bool | None = None,
                rest_low: bool = False, rest_tops: bool = False) -> PoseChecks:
    """Step, belly intrusion, stability and grade of ``body`` at each of ``poses`` ((N, 3): x, y,
    heading in degrees) on ``heights`` over ``geom``: one height grid (the truth; the finer the
    truer: 1-2 cm), read bilinearly between its cell centres, or a ``(lower, upper)`` pair of bound
    grids (a bounds map, as ACE checks), each sample reading the bounds of the cell that holds it.

    On bounds every measure is its worst case over the ground they allow: a wheel's step from one
    sample's lower bound to a neighbour's upper bound, the belly's ground at its upper bound over
    the lowest plane the wheels may rest on, the resting plane's lean toward its tip-over edge
    over every plane their contacts allow (each of the three contacts at its lowest or highest:
    the worst plane is at a corner of that box), the fitted plane's steepest slope over the
    bounds. A pose whose body covers ground with no upper bound, or a wheel with no lower bound
    under more than half of it, is ``unknown``: never safe. Ground a ray passed over but no
    return met has no lower bound: a hole narrower than a wheel's reach there is bridged (the
    wheel rests on the ground around it), so the wheel is judged on the ground its bounds cover;
    an unbounded low takes no part in a wheel's edges or contact, and stands in by its high in
    the plane fitted under the body. On one grid, ground off it takes the lowest height the pose
    sees (an edge is judged as a drop, not as a wall). The body is sampled every ``step``
    (default: the grid's cell on one grid, :data:`BOUNDS_STEP` of it on bounds). ``cellwise``
    (default: on bounds) reads each sample from the cell that holds it; False reads a pair
    bilinearly as one grid is read (a pair of surfaces of cell tops and lows drawn from a
    posterior, not a map's bounds: ``chance.chance_check``). ``rest_low`` (on a pair): each wheel
    rests on the lower surface (its highest low under the circle), one plane per pose, where bounds
    let each wheel rest anywhere between its lowest and highest contact and judge the worst corner of
    that box: a drawn pair is one ground, whose wheel rests the lows give (``chance._judge``), and
    whose grade is the plane fitted to its middles: the steepest plane within every cell's pair read
    a uniform slope 7 % steep (9.6 deg on 9), the grade's best estimate 0.5-0.7 deg over the truth's
    at the median on every judged pose of a look.
    ``rest_tops`` (on a pair): stability is also judged with each wheel raised onto the upper
    surface's top of every cell wholly inside its footprint (a cell's top lies somewhere in the
    cell, and such a cell holds it under the wheel), the worse of the two counting; the belly stays
    over the planes on the lows (a wheel raised lifts the box off the ground it judges).

    The per-pose work is one compiled pass (:mod:`._vehicle_kernel`)."""
    lower, upper = heights if isinstance(heights, tuple) else (heights, heights)
    bounded = lower is not upper
    poses = np.ascontiguousarray(np.atleast_2d(np.asarray(poses, float)))
    plan = _plan(body, step or _default_step(geom, bounded))
    n = len(poses)
    edge = np.empty((n, 4))
    intrusion, tilt, tip, grade, stability = (np.empty(n) for _ in range(5))
    unknown = np.zeros(n, bool)
    if n:  # the grids as they are (a window of a larger map is read in place, not copied)
        _kernel().check(lower, upper, bounded, bounded if cellwise is None else cellwise, float(geom.xmin),
                        float(geom.ymax), float(geom.cell), poses, plan.px, plan.py, plan.wheel_of, plan.belly, plan.sag, plan.pair_a, plan.pair_b, plan.pair_wheel,
                        plan.ground[0], plan.ground[1], plan.pulls[0], plan.pulls[1], plan.inv, plan.triplets,
                        plan.corners[bounded and not rest_low], plan.hubs, *plan.support, float(body.cog_height),
                        float(body.safety), edge, intrusion, tilt, tip, grade, stability, unknown, rest_tops,
                        float(body.wheel_radius), float(body.wheel_width) / 2, rest_low)
    intrusion -= body.clearance
    excess = np.column_stack([edge.max(axis=1) - body.climb, intrusion, stability, grade - body.grade])
    return PoseChecks(step=edge, intrusion=intrusion, tilt=tilt, tip=tip, grade=grade, excess=excess,
                      wheel=np.nan_to_num(edge, nan=-np.inf).argmax(axis=1), unknown=unknown)


def warm_up() -> None:
    """Compile (first run after installing) or load the check's kernel now, for float32 and float64
    grids and bounds, rather than in the first check."""
    from types import SimpleNamespace

    body = SimpleNamespace(length=0.5, width=0.4, clearance=0.08, wheel_radius=0.1, wheel_width=0.1, climb=0.1,
                           grade=20.0, cog_height=0.2, safety=1.5,
                           wheels=np.array([[0.15, 0.25], [0.15, -0.25], [-0.15, 0.25], [-0.15, -0.25]]))
    g = GridGeometry(0.05, -1.0, 1.0, 40, 40)
    for dtype in (np.float32, np.float64):
        ground = np.zeros((40, 40), dtype)
        check_poses(ground, g, np.zeros((1, 3)), body)
        check_poses((ground, ground.copy()), g, np.zeros((1, 3)), body)
        _sample(ground, g, np.zeros(1), np.zeros(1))
    tip_angle(body, 0.0)


@dataclass(frozen=True)
class Gate:
    """The verdict on a motion before the rover executes it (:func:`gate_poses`): ``safe``, or the
    first pose that is not, why (``unsafe``: judged and over a limit; ``unknown``: ground under it
    no bound covers) and the ground to blame: the highest upper bound under the body over its
    lowest wheel ground (a rock's top; the body's middle for stability or grade), or the middle
    of the unseen ground under it. ``kind`` names the worst excess as :class:`Event` does."""

    verdict: str
    index: int = -1
    x: float = math.nan
    y: float = math.nan
    kind: str = ""
    excess: float = 0.0

    def describe(self) -> str:
        if self.verdict == "unknown":
            return f"unseen ground at ({self.x:.2f}, {self.y:.2f})"
        return f"{_shown(self.kind, self.excess)} at ({self.x:.2f}, {self.y:.2f})"


def gate_poses(lower: np.ndarray, upper: np.ndarray, geom: GridGeometry, poses: np.ndarray,
               body: VehicleBody) -> Gate:
    """The worst-case check of ``poses`` (in the order the rover passes them) on bounds: the first
    that is not safe stops the motion. Unknown ground is never safe (ACE's rule: a false negative
    is never accepted); the caller looks at it or plans round it."""
    poses = np.atleast_2d(np.asarray(poses, float))
    checks = check_poses((lower, upper), geom, poses, body)
    bad = np.flatnonzero(~checks.safe)
    if not len(bad):
        return Gate("safe")
    i = int(bad[0])
    pts = _pattern(body, _default_step(geom, True)).pts
    x, y, heading = poses[i]
    c, s = math.cos(math.radians(heading)), math.sin(math.radians(heading))
    wx, wy = x + c * pts[:, 0] - s * pts[:, 1], y + s * pts[:, 0] + c * pts[:, 1]
    hi = _sample(upper, geom, wx, wy, cellwise=True)
    if checks.unknown[i]:
        at = np.isnan(hi) | np.isnan(_sample(lower, geom, wx, wy, cellwise=True))
        return Gate("unknown", i, float(wx[at].mean()), float(wy[at].mean()), "unknown")
    ks, values = checks.worst(body)
    worst, value = int(ks[i]), float(values[i])
    kind = checks.kind(i, worst)
    if worst >= 2 or np.isnan(hi).all():
        return Gate("unsafe", i, float(x), float(y), kind, value)
    top = int(np.nanargmax(hi))
    # a top bounded only by a ray that passed over it (no return there) is ground not yet seen,
    # which a look may clear: unknown, not a rock
    seen = np.isfinite(_sample(lower, geom, wx[top:top + 1], wy[top:top + 1], cellwise=True))[0]
    return Gate("unsafe" if seen else "unknown", i, float(wx[top]), float(wy[top]), kind if seen else "unknown",
                value)


def unsafe_events(checks: PoseChecks, poses: np.ndarray, body: VehicleBody) -> list[Event]:
    """The distinct unsafe events along ``poses`` (in the order driven): each run of consecutive
    unsafe poses is one, named by its worst excess relative to its limit."""
    poses = np.atleast_2d(np.asarray(poses, float))
    bad = checks.unsafe
    if not bad.any():
        return []
    edges = np.flatnonzero(np.diff(np.concatenate([[0], bad.astype(np.int8), [0]])))
    rel_all = checks.relative(body)
    out = []
    for first, end in zip(edges[::2], edges[1::2], strict=True):
        k, kind = np.unravel_index(int(np.argmax(rel_all[first:end])), (end - first, 4))
        i = first + int(k)
        out.append(Event(int(first), int(end - 1), checks.kind(i, int(kind)),
                         round(float(checks.excess[i, kind]), 4), float(poses[i, 0]), float(poses[i, 1]),
                         float(poses[i, 2])))
    return out


def reach(body: VehicleBody) -> float:
    """How far the body's farthest point (a corner of the box or of a wheel) lies from its centre:
    what sweeps furthest when it turns on the spot."""
    hubs = np.abs(np.asarray(body.wheels, float))
    return math.hypot(max(body.length / 2, float(hubs[:, 0].max()) + body.wheel_radius),
                      max(body.width / 2, float(hubs[:, 1].max()) + body.wheel_width / 2))


def densify(poses: np.ndarray, step: float = 0.02, body: VehicleBody | None = None) -> np.ndarray:
    """Poses between consecutive ``poses`` ((N, 3): x, y, heading deg) so that no point of the body
    moves more than ``step`` from one to the next: along a move every ``step``, through a turn on
    the spot every ``step`` of arc at the body's farthest corner (``body``; 0.4 m without one).
    Headings turn the short way round."""
    poses = np.atleast_2d(np.asarray(poses, float))
    if len(poses) < 2:
        return poses.copy()
    far = 0.4 if body is None else reach(body)
    d = np.hypot(*np.diff(poses[:, :2], axis=0).T)
    turn = (np.diff(poses[:, 2]) + 180.0) % 360.0 - 180.0
    n = np.maximum(1, np.ceil(np.maximum(d, np.radians(np.abs(turn)) * far) / step - 1e-9)).astype(int)
    out = [poses[:1]]
    for k in range(len(d)):
        t = (np.arange(1, n[k] + 1) / n[k])[:, None]
        seg = np.empty((n[k], 3))
        seg[:, :2] = poses[k, :2] + t * (poses[k + 1, :2] - poses[k, :2])
        seg[:, 2] = ((poses[k, 2] + t[:, 0] * turn[k]) + 180.0) % 360.0 - 180.0
        out.append(seg)
    return np.concatenate(out)


def track_poses(xy: np.ndarray, heading: np.ndarray | None = None) -> np.ndarray:
    """(N, 3) poses of a track: its own headings (degrees) when recorded, else each point's
    heading toward the next (the last keeps the one before; a rover that stood still keeps
    its heading)."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    if heading is not None:
        return np.column_stack([xy, np.asarray(heading, float)])
    if len(xy) < 2:
        return np.column_stack([xy, np.zeros(len(xy))])
    d = np.diff(xy, axis=0)
    h = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
    moved = np.hypot(*d.T) > 1e-9
    for k in range(1, len(h)):  # a still step keeps the heading before it
        if not moved[k]:
            h[k] = h[k - 1]
    return np.column_stack([xy, np.append(h, h[-1])])
