"""Dynamic hazard detection (seed 000 sect. 6.2): the per-cycle check behind ``hazard-start``.

Between full 360-degree scans the rover drives blind; the thesis proposes pointing the ToF camera
forward with a tilt, building a drastically coarser DEM, and deciding from the hazard map, the
rover's size and its direction of motion whether it must stop. One cycle here is:

1. low-resolution ToF points (one frame, every ``subsample``-th pixel) moved into the rover frame;
2. a coarse DEM (:func:`dem_import`, a few centimetres per cell) over the *corridor* only: the
   strip ``width`` wide that the rover sweeps along ``heading`` for ``lookahead`` metres past its
   front, gridded in corridor coordinates (along, across) so the corridor is a rectangle of cells;
3. Dem2Hazard's step, slope and roughness tests on that grid (the same thresholds as the maps);
4. the nearest hazardous cell in the corridor: its *distance* is the free run from the rover's
   front to the cell's near edge (conservative: the cell is entered at its near edge), its
   *bearing* the direction from the rover's centre (degrees, counter-clockwise from the rover's x).

Two things make the stop timely and keep it honest:

- the level is decided on the distance *expected when the next cycle's answer can arrive*: the
  closing speed (from the pose the GNC reports, else from successive distances) makes a rover
  moving at v stop
  v x (latency) earlier than a static reading would (:class:`LevelTracker`);
- the ToF view starts some way ahead of the rover (a blind zone under the tilt). A hazard seen and
  then lost into that zone is remembered in the global frame (:class:`HazardMemory`), moved with
  the pose the GNC reports, and forgotten only where the camera sees the ground safe again; so
  driving on does not turn a stop into a clear.

Everything is plain numpy on arrays: the server's monitor thread supplies points, pose and clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rvs_params.hazard import HAZARDOUS, SAFE

from ..grid import GridGeometry
from .dem2hazard import HazardParams, dem2hazard
from .dem_import import dem_import

LEVELS = ("clear", "warning", "stop")


@dataclass(frozen=True)
class MonitorParams:
    """Corridor geometry and thresholds of one monitor (metres and degrees)."""

    width: float = 0.6  # corridor width, centred on the rover's path
    lookahead: float = 2.5  # corridor length past the rover's front
    heading: float = 0.0  # direction of motion in the rover frame, CCW from its x axis
    stop_distance: float = 0.5  # free run below which the level is stop
    warn_distance: float = 1.2  # ... warning
    cell: float = 0.05  # coarse DEM cell
    rover_length: float = 0.51
    rover_width: float = 0.40
    hysteresis: float = 0.1  # a level is left only this far past its threshold
    min_points: int = 2  # a cell with fewer points is undefined
    max_speed: float = 1.0  # cap on the closing speed estimated from readings (m/s; the rover's top
    # speed is 0.7): a hazard cell appearing nearer than the last one is not a rover at full tilt
    hazard: dict[str, float] = field(default_factory=dict)  # Dem2Hazard overrides (step_max, ...)

    def __post_init__(self) -> None:
        for name in ("width", "lookahead", "cell"):
            if not getattr(self, name) > 0:
                raise ValueError(f"hazard monitor: {name} must be > 0, not {getattr(self, name)}")
        if not 0 <= self.stop_distance <= self.warn_distance:
            raise ValueError(f"hazard monitor: need 0 <= stop distance ({self.stop_distance}) <= warn distance "
                             f"({self.warn_distance})")

    def hazard_params(self) -> HazardParams:
        """Dem2Hazard's thresholds with a window of at least three coarse cells."""
        base = HazardParams(**{k: float(v) for k, v in self.hazard.items()})
        return HazardParams(**{**base.as_dict(), "window": max(base.window, 3 * self.cell)})

    def front(self) -> float:
        """How far the rover's body reaches from its centre along the direction of motion."""
        h = math.radians(self.heading)
        return abs(self.rover_length / 2 * math.cos(h)) + abs(self.rover_width / 2 * math.sin(h))


@dataclass
class CorridorCheck:
    """What one cycle saw in the corridor (all positions in the rover frame)."""

    distance: float | None  # free run from the rover's front to the nearest hazard (None: none)
    bearing: float | None  # direction of that hazard from the rover's centre, deg CCW
    x: float | None
    y: float | None
    hazard_cells: int  # hazardous cells inside the corridor
    observed: float  # share of the corridor's cells with a hazard verdict (safe or hazardous)
    blind: float  # free run from the front to the first observed corridor cell (the blind zone)
    hazards: np.ndarray  # K x 2 rover-frame x, y of every hazardous cell of the grid (for memory)
    safe: np.ndarray  # L x 2 rover-frame x, y of every cell seen safe (clears memory)
    points: int = 0


def rover_points(xyz_cam: np.ndarray, T_rover_cam: np.ndarray, subsample: int = 1, max_range: float = 4.5,
                 amplitude: np.ndarray | None = None, min_reflectivity: float = 0.0,
                 max_jump: float | None = None) -> np.ndarray:
    """Defined pixels of a ToF XYZ image (camera frame, -1/NaN undefined) as N x 3 rover-frame points.

    ``subsample`` keeps every k-th pixel in both directions: a coarse DEM needs no more and the
    cycle gets k^2 cheaper. ``min_reflectivity`` drops phase-wrapped far returns as
    :func:`acquire.view_from_xyz` does (amplitude x range^2 far below the frame's median).
    ``max_jump`` (a share of the range) drops pixels whose range differs from a neighbour's by
    more than that plus 1 cm: a pixel straddling a depth edge returns a mix of fore- and
    background, a point in mid-air or under the ground behind a rock's rim. A cell mean
    averages such a point away; a bound on the ground's lowest or highest takes it whole.
    Ground seen at a grazing angle stays: its neighbours' ranges differ by about 1 % of the range.
    """
    k = max(1, int(subsample))
    xyz = np.asarray(xyz_cam, dtype=np.float32)[::k, ::k]
    ok = ground_pixels(xyz_cam, subsample, max_range, amplitude, min_reflectivity, max_jump)
    p = xyz[ok].astype(np.float64)
    return (p @ T_rover_cam[:3, :3].T + T_rover_cam[:3, 3]).astype(np.float32)


def ground_pixels(xyz_cam: np.ndarray, subsample: int = 1, max_range: float = 4.5,
                  amplitude: np.ndarray | None = None, min_reflectivity: float = 0.0,
                  max_jump: float | None = None) -> np.ndarray:
    """The pixels (of the image subsampled by ``subsample``) :func:`rover_points` keeps, as a
    mask: a caller that weighs each point by its own pixel's amplitude reads it there."""
    k = max(1, int(subsample))
    xyz = np.asarray(xyz_cam, dtype=np.float32)[::k, ::k]
    z = xyz[..., 2]
    rng = np.linalg.norm(xyz, axis=2)
    ok = np.isfinite(z) & (z > 0) & (rng <= max_range)
    if max_jump is not None:
        r = np.where(ok, rng, np.nan)
        jump = np.zeros(r.shape, np.float32)
        with np.errstate(invalid="ignore"):
            for axis in (0, 1):
                d = np.abs(np.diff(r, axis=axis))
                d = np.where(np.isnan(d), 0.0, d)
                lead = [(0, 1), (0, 0)] if axis == 0 else [(0, 0), (0, 1)]
                trail = [(1, 0), (0, 0)] if axis == 0 else [(0, 0), (1, 0)]
                jump = np.maximum(jump, np.maximum(np.pad(d, lead), np.pad(d, trail)))
        ok &= jump <= max_jump * rng + 0.01
    if amplitude is not None and min_reflectivity > 0 and ok.any():
        refl = np.asarray(amplitude, dtype=np.float64)[::k, ::k] * rng.astype(np.float64) ** 2
        ok &= refl >= min_reflectivity * float(np.median(refl[ok]))
    return ok


def _to_corridor(xy: np.ndarray, heading: float) -> np.ndarray:
    """Rover-frame x, y to corridor coordinates (along the motion, across to its left)."""
    c, s = math.cos(math.radians(heading)), math.sin(math.radians(heading))
    return np.stack([xy[:, 0] * c + xy[:, 1] * s, -xy[:, 0] * s + xy[:, 1] * c], axis=1)


def _from_corridor(uv: np.ndarray, heading: float) -> np.ndarray:
    c, s = math.cos(math.radians(heading)), math.sin(math.radians(heading))
    return np.stack([uv[:, 0] * c - uv[:, 1] * s, uv[:, 0] * s + uv[:, 1] * c], axis=1)


def corridor_grid(params: MonitorParams) -> GridGeometry:
    """The coarse grid in corridor coordinates: the corridor plus half a Dem2Hazard window around it."""
    margin = params.hazard_params().window / 2 + params.cell
    front = params.front()
    return GridGeometry.covering(front - margin, -params.width / 2 - margin,
                                 front + params.lookahead + margin, params.width / 2 + margin, params.cell)


def check_corridor(points_rover: np.ndarray, params: MonitorParams) -> CorridorCheck:
    """One cycle's verdict on the corridor from rover-frame points (N x 3)."""
    g = corridor_grid(params)
    pts = np.asarray(points_rover, dtype=np.float64).reshape(-1, 3)
    uv = _to_corridor(pts[:, :2], params.heading) if len(pts) else np.zeros((0, 2))
    cp = np.column_stack([uv, pts[:, 2]]) if len(pts) else np.zeros((0, 3))
    xs, ys = g.centers()
    U, V = np.meshgrid(xs, ys)
    front = params.front()
    inside = (U >= front) & (U <= front + params.lookahead) & (np.abs(V) <= params.width / 2)
    empty = np.zeros((0, 2))
    if len(cp) == 0:
        return CorridorCheck(None, None, None, None, 0, 0.0, params.lookahead, empty, empty, 0)
    layers = dem_import(cp, geometry=g, stats=("dem", "mean", "count"))
    # The cell mean, not the max the full DEMs keep: one frame's noise and a stray mixed pixel
    # would otherwise raise a cell by centimetres and, through the step window, flag a patch.
    dem = np.where(layers["count"] >= params.min_points, layers["mean"], np.nan)
    maps = dem2hazard(dem, g.cell, params.hazard_params())
    hz = maps["hazard"]
    bad = hz == HAZARDOUS
    ok = hz == SAFE
    seen = (bad | ok) & inside
    observed = float(seen.sum()) / max(int(inside.sum()), 1)
    near_edge = U - g.cell / 2 - front  # free run to each cell's near edge
    blind = float(np.clip(near_edge[seen], 0.0, None).min()) if seen.any() else params.lookahead
    hits = bad & inside
    distance = bearing = x = y = None
    if hits.any():
        d = np.where(hits, np.clip(near_edge, 0.0, None), np.inf)
        i = np.unravel_index(int(np.argmin(d)), d.shape)
        distance = float(d[i])
        xy = _from_corridor(np.array([[U[i], V[i]]]), params.heading)[0]
        x, y = float(xy[0]), float(xy[1])
        bearing = math.degrees(math.atan2(y, x))
    return CorridorCheck(distance, bearing, x, y, int(hits.sum()), observed, blind,
                         _from_corridor(np.column_stack([U[bad], V[bad]]), params.heading),
                         _from_corridor(np.column_stack([U[ok], V[ok]]), params.heading), len(cp))


def _transform_xy(T: np.ndarray, xy: np.ndarray) -> np.ndarray:
    return xy @ T[:2, :2].T + T[:2, 2]


def _planar(x: float, y: float, heading: float) -> np.ndarray:
    c, s = math.cos(math.radians(heading)), math.sin(math.radians(heading))
    return np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])


class HazardMemory:
    """Hazard cells seen earlier, kept in the global frame for the blind zone near the rover.

    The pose is the server's belief (the GNC's ``pose``); if it never changes, remembered hazards
    stay where they were relative to the rover, which errs on the side of stopping.
    """

    def __init__(self, cell: float, keep: float = 6.0) -> None:
        self.cell = cell
        self.keep = keep  # forget hazards farther than this from the rover
        self.points = np.zeros((0, 2))

    def update(self, check: CorridorCheck, pose: tuple[float, float, float]) -> None:
        """Forget remembered cells now seen safe, remember the hazardous ones seen now."""
        T = _planar(*pose)
        if len(self.points) and len(check.safe):
            safe = {tuple(k) for k in np.floor(_transform_xy(T, check.safe) / self.cell).astype(np.int64)}
            keys = np.floor(self.points / self.cell).astype(np.int64)
            gone = np.array([tuple(k) in safe for k in keys], bool)
            self.points = self.points[~gone]
        if len(check.hazards):
            self.points = np.concatenate([self.points, _transform_xy(T, check.hazards)])
        if len(self.points):
            keys = np.floor(self.points / self.cell).astype(np.int64)
            _, first = np.unique(keys, axis=0, return_index=True)
            self.points = self.points[np.sort(first)]
            near = np.hypot(*(self.points - np.array(pose[:2])).T) <= self.keep
            self.points = self.points[near]

    def nearest(self, pose: tuple[float, float, float], params: MonitorParams
                ) -> tuple[float, float, float, float] | None:
        """(distance, bearing, x, y) of the nearest remembered hazard in the corridor, rover frame."""
        if not len(self.points):
            return None
        Tinv = np.linalg.inv(_planar(*pose))
        xy = _transform_xy(Tinv, self.points)
        uv = _to_corridor(xy, params.heading)
        front = params.front()
        half = params.cell / 2
        inside = (uv[:, 0] + half >= front) & (uv[:, 0] - half <= front + params.lookahead) & \
                 (np.abs(uv[:, 1]) <= params.width / 2 + half)
        if not inside.any():
            return None
        d = np.clip(uv[:, 0] - half - front, 0.0, None)
        d[~inside] = np.inf
        i = int(np.argmin(d))
        return float(d[i]), math.degrees(math.atan2(xy[i, 1], xy[i, 0])), float(xy[i, 0]), float(xy[i, 1])


class LevelTracker:
    """clear / warning / stop from successive distances, looking ahead by the monitor's latency."""

    def __init__(self, params: MonitorParams) -> None:
        self.params = params
        self.level = "clear"
        self.speed = 0.0  # estimated closing speed, m/s
        self._raw: list[float] = []  # the last few speeds from readings
        self._last: tuple[float, float] | None = None  # (time, distance)

    def _rank(self, distance: float) -> int:
        p = self.params
        return 2 if distance <= p.stop_distance else 1 if distance <= p.warn_distance else 0

    def update(self, distance: float | None, t: float, lead: float, speed: float | None = None
               ) -> tuple[str, float | None]:
        """The level after a reading at time ``t`` whose successor arrives ``lead`` s later;
        returns it with the distance it was judged on (the reading minus speed x lead).

        ``speed`` is the closing speed when known from elsewhere (the rover's reported motion);
        without it the speed comes from successive readings: the median of the last three
        differences, so one jump of the nearest cell is not taken for a sprint.
        """
        p = self.params
        if distance is not None and self._last is not None and t > self._last[0]:
            v = (self._last[1] - distance) / (t - self._last[0])
            self._raw = [*self._raw[-2:], float(np.clip(v, 0.0, p.max_speed))]
        if speed is not None:
            self.speed = max(0.0, float(speed))
        elif distance is None:
            self.speed *= 0.5
        elif self._raw:
            self.speed = float(np.median(self._raw))
        if distance is None:
            self._last = None
            self._raw = []
            expected = None
        else:
            self._last = (t, distance)
            expected = max(0.0, distance - self.speed * max(lead, 0.0))
        rank = LEVELS.index(self.level)
        want = 0 if expected is None else self._rank(expected)
        if want < rank and expected is not None:
            # a level is left only once the reading is past its threshold by the hysteresis
            want = min(rank, max(want, self._rank(expected - p.hysteresis)))
        self.level = LEVELS[want]
        return self.level, expected


def summary(check: CorridorCheck) -> dict[str, Any]:
    """A loggable digest of one cycle."""
    return {"distance": check.distance, "bearing": check.bearing, "hazard_cells": check.hazard_cells,
            "observed": round(check.observed, 3), "blind": round(check.blind, 3), "points": check.points}
