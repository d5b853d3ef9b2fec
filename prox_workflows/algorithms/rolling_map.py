"""A rolling local elevation map for driving while seeing.

Between 360-degree scans a rover on the last scan's maps drives blind to what changed. Here every
forward ToF frame taken while it drives is fused into a fixed-size elevation map that moves with
the rover, and the hazard layers are recomputed only where the frame changed them, so one cycle
(fuse + Dem2Hazard + the footprint check of the next metres) costs a few milliseconds whatever the
length of the traverse.

Why these choices
    - Fixed size, global lattice: the map is a square of ``size`` metres on the global frame's
      ``cell`` lattice; when the rover is ``recentre`` metres from its centre the arrays shift by
      whole cells (nothing is resampled, so a cell's estimate never blurs) and what falls off is
      forgotten. The global scan maps stay the planner's memory; this map is the fresh view.
    - Fusion as DemMosaik's ``fuse`` rule (seed 003 eq. 6.1): each frame's information-weighted
      mean height per cell is a measurement with variance 1 / sum(1 / s_i^2) (per-point sigma
      growing with range); it is Kalman-fused into the prior, and a measurement that disagrees
      by more than ``gate`` sigmas is rejected while the prior's variance inflates, so a rock
      that appears where flat ground was seen is accepted after a few frames, not by one
      outlier. :func:`.dem_mosaik.dem_mosaik` does the update, on the frame's window only.
    - Incremental Dem2Hazard: slope, roughness and step depend on a window of ``window`` metres,
      so a changed cell changes the hazard of cells within half a window; the frame's window
      grown by that half window is recomputed from the DEM grown by another half window, which
      gives the same values as Dem2Hazard over the whole map (tested).
    - Each frame's heights are aligned to the map's where they overlap (the median difference):
      the frame's z comes from the rover's believed height, which jumps by centimetres from
      stop to stop; fused unaligned, frames would meet in phantom steps at each view's edge.
      That height is the map's own ground under the rover (:meth:`RollingMap.ground_height`),
      so a frame that overlaps too little to be aligned (a look to the side) still lands in the
      map's datum; off the scanned ground the scan DEM gave 0, decimetres off on a slope.
    - The check sweeps the rover's footprint along the next metres of the path (poses), as
      check-move does along one motion: blocked anywhere is ``not_traversable``.
    - What scrolls off may be kept for the planner: with a :class:`MapMemory` the verdicts
      (hazard class, slope, frame stamp) of the cells the map shifts away are kept on a grid over
      the mission's area. Without it a dead end the rover drove into and out of is forgotten
      4 m later and D* Lite may send the rover back into it (hirise mission 2 drove north, south
      and north again along one rock wall); with it, a false hazard or a drifted frame's phantom
      step is kept as long, and closes ways the forgetting map reopens (navigate.see_memory,
      off by default: docs/PROTOCOL.md has the measured trade-off).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from rvs_params.hazard import HAZARDOUS, SAFE, UNDEFINED

from ..grid import GridGeometry, Layers, median_near
from .dem2hazard import HazardParams, dem2hazard
from .dem_import import dem_import
from .dem_mosaik import dem_mosaik
from .plan_maps import NavMaps, check_plan_size
from .safety import MoveCheck, check_move


@dataclass(frozen=True)
class RollingParams:
    """Geometry and noise model of the rolling map (metres)."""

    size: float = 8.0  # side of the square map, centred near the rover
    cell: float = 0.05
    recentre: float = 1.0  # shift the map when the rover is this far from its centre
    sigma: float = 0.01  # a ToF height's standard deviation at 0 m ...
    sigma_per_m: float = 0.004  # ... growing by this much per metre of range
    gate: float = 3.0  # DemMosaik fuse: Mahalanobis gate
    inflation: float = 0.0025  # DemMosaik fuse: prior variance added on a rejected measurement (m^2)
    min_points: int = 2  # a frame's cell with fewer points is no measurement
    align_min_cells: int = 30  # overlap (cells) needed to align a frame's heights to the map's (0: never)

    def __post_init__(self) -> None:
        if not (self.size > 0 and self.cell > 0 and self.size >= 4 * self.cell):
            raise ValueError(f"rolling map: size {self.size} and cell {self.cell} must be > 0, size >= 4 cells")


@dataclass
class FuseResult:
    """What one frame changed: the window recomputed (rows, cols slices) and the points used."""

    window: tuple[slice, slice] | None
    points: int
    rejected: int = 0


class MapMemory:
    """The rolling map's verdicts for a whole mission: hazard class, slope, whether the verdict
    rests on a wholly seen window and the frame that measured each cell, on a fixed grid on the
    rolling map's lattice (cells off it are not kept). The latest verdict of a cell wins, but
    for :func:`overrides`: a safe verdict from a partly seen window never erases a hazard."""

    def __init__(self, geometry: GridGeometry) -> None:
        self.geometry = geometry
        self.hazard = np.full(geometry.shape, UNDEFINED, np.uint8)
        self.slope = np.full(geometry.shape, np.nan, np.float32)
        self.whole = np.zeros(geometry.shape, bool)
        self.stamp = np.zeros(geometry.shape, np.int32)

    @classmethod
    def covering(cls, points: Any, pad: float, cell: float) -> MapMemory:
        """A memory over the box of ``points`` (x, y) grown by ``pad`` metres."""
        xy = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        geometry = GridGeometry.covering(xy[:, 0].min() - pad, xy[:, 1].min() - pad, xy[:, 0].max() + pad,
                                         xy[:, 1].max() + pad, cell)
        check_plan_size(geometry, "see loop's memory")  # it spans the mission, as a plan does
        return cls(geometry)

    def remember(self, m: RollingMap) -> None:
        """Keep what ``m`` has verdicts for (its cells and the memory's share one lattice)."""
        g, mg = self.geometry, m.geometry
        dc = int(round((mg.xmin - g.xmin) / g.cell))
        dr = int(round((g.ymax - mg.ymax) / g.cell))
        r0, r1 = max(0, dr), min(g.height, dr + mg.height)
        c0, c1 = max(0, dc), min(g.width, dc + mg.width)
        if r1 <= r0 or c1 <= c0:
            return
        src = (slice(r0 - dr, r1 - dr), slice(c0 - dc, c1 - dc))
        dst = (slice(r0, r1), slice(c0, c1))
        take = (m.stamp[src] > 0) & overrides(self.hazard[dst], m.hazard[src], m.whole[src])
        for name in ("hazard", "slope", "whole", "stamp"):
            getattr(self, name)[dst][take] = getattr(m, name)[src][take]

    def move(self, pivot: tuple[float, float], dx: float, dy: float, dyaw: float, since: int) -> None:
        """Move the verdicts of frames after ``since`` by a pose fix, as :meth:`RollingMap.move`
        moves the heights: they were placed with the pose the fix corrects."""
        move_since(self, ("hazard", "slope", "whole", "stamp"), since, pivot, dx, dy, dyaw)

    def nav_maps(self) -> NavMaps:
        """The kept verdicts as the planner takes them."""
        return NavMaps(self.hazard.copy(), self.slope.copy(), self.geometry, self.whole.copy())


def overrides(old: np.ndarray, new: np.ndarray, whole: np.ndarray | None) -> np.ndarray:
    """Where a later verdict ``new`` replaces ``old``: wherever it has one, except that a safe
    verdict from a partly seen window (``whole`` false) never erases a hazard. Dem2Hazard judges
    a window from its seen cells alone, so such a "safe" may simply not have seen the rock that
    made the earlier verdict; a wholly seen window has, and stands either way."""
    if whole is None:
        return new != UNDEFINED
    return (new != UNDEFINED) & ~((old == HAZARDOUS) & (new == SAFE) & ~whole)


class RollingMap:
    """The rover-centred elevation map: height, variance, count, and Dem2Hazard's layers;
    ``memory`` keeps the verdicts of what scrolls off (and, on :meth:`remember`, of the rest)."""

    def __init__(self, params: RollingParams, hazard: HazardParams, centre: tuple[float, float],
                 memory: MapMemory | None = None) -> None:
        self.params = params
        self.memory = memory
        self.hazard_params = hazard
        n = int(math.ceil(params.size / params.cell))
        self.n = n
        self.geometry = self._geometry_at(centre)
        shape = (n, n)
        self.height = np.full(shape, np.nan)
        self.variance = np.full(shape, np.nan)
        self.count = np.zeros(shape, np.int32)
        self.stamp = np.zeros(shape, np.int32)  # the frame (1, 2, ...) that last measured the cell; 0 never
        self.hazard = np.full(shape, UNDEFINED, np.uint8)
        self.slope = np.full(shape, np.nan, np.float32)
        self.traversability = np.full(shape, np.nan, np.float32)
        self.whole = np.zeros(shape, bool)  # the cell's hazard window is seen in every cell
        self.frames = 0
        self.last_offset = 0.0  # the last frame's height offset to the map (m)
        self._half = hazard.window_cells(params.cell) // 2 + 1  # cells a change reaches in the hazard layers

    def _geometry_at(self, centre: tuple[float, float]) -> GridGeometry:
        c = self.params.cell
        half = self.n * c / 2
        x0 = math.floor((centre[0] - half) / c + 0.5) * c
        y1 = math.floor((centre[1] + half) / c + 0.5) * c
        return GridGeometry(c, x0, y1, self.n, self.n)

    @property
    def centre(self) -> tuple[float, float]:
        g = self.geometry
        return (g.xmin + g.width * g.cell / 2, g.ymax - g.height * g.cell / 2)

    def follow(self, x: float, y: float) -> bool:
        """Keep the rover near the centre: shift by whole cells once it is ``recentre`` away.
        Returns whether the map moved."""
        cx, cy = self.centre
        if max(abs(x - cx), abs(y - cy)) < self.params.recentre:
            return False
        new = self._geometry_at((x, y))
        self.remember()
        dc = int(round((new.xmin - self.geometry.xmin) / new.cell))
        dr = int(round((self.geometry.ymax - new.ymax) / new.cell))
        for name, fill in (("height", np.nan), ("variance", np.nan), ("count", 0), ("stamp", 0),
                           ("hazard", UNDEFINED), ("slope", np.nan), ("traversability", np.nan),
                           ("whole", False)):
            setattr(self, name, _shift(getattr(self, name), dr, dc, fill))
        self.geometry = new
        # cells that were at the old border had hazard verdicts from a partial window: redo them
        # where the window now extends; cheap, and it keeps the layers equal to a full recompute
        self._rehazard((slice(0, self.n), slice(0, self.n)))
        return True

    def fuse(self, points: np.ndarray, ranges: np.ndarray | None = None) -> FuseResult:
        """Fuse one frame's global-frame points (N x 3); ``ranges`` (N, m) sets their sigma."""
        p = self.params
        g = self.geometry
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        keep = (pts[:, 0] >= g.xmin) & (pts[:, 0] < g.xmax) & (pts[:, 1] > g.ymin) & (pts[:, 1] <= g.ymax)
        keep &= np.isfinite(pts).all(axis=1)
        pts = pts[keep]
        self.frames += 1
        if len(pts) == 0:
            return FuseResult(None, 0)
        rng = np.zeros(len(pts)) if ranges is None else np.asarray(ranges, dtype=np.float64)[keep]
        pvar = (p.sigma + p.sigma_per_m * rng) ** 2
        r, c = g.cell_of(pts[:, 0], pts[:, 1])
        r0, r1 = int(np.clip(r.min(), 0, self.n - 1)), int(np.clip(r.max(), 0, self.n - 1)) + 1
        c0, c1 = int(np.clip(c.min(), 0, self.n - 1)), int(np.clip(c.max(), 0, self.n - 1)) + 1
        win = GridGeometry(g.cell, g.xmin + c0 * g.cell, g.ymax - r0 * g.cell, c1 - c0, r1 - r0)
        meas = dem_import(pts, geometry=win, point_variance=pvar, stats=("dem", "mean", "count"), height="mean")
        few = meas["count"] < p.min_points
        meas["dem"] = np.where(few, np.nan, meas["dem"]).astype(np.float32)
        meas["count"] = np.where(few, 0, meas["count"]).astype(np.int32)
        sl = (slice(r0, r1), slice(c0, c1))
        self.last_offset = 0.0
        if p.align_min_cells > 0:
            # the frame's height datum against the map's: the rover's z (the ground under it,
            # seen earlier) is a few centimetres off and different at every stop; unaligned,
            # frames would meet in steps at the edge of each new view
            both = np.isfinite(meas["dem"]) & np.isfinite(self.height[sl])
            if int(both.sum()) >= p.align_min_cells:
                self.last_offset = float(np.median(meas["dem"][both] - self.height[sl][both]))
                meas["dem"] = (meas["dem"] - self.last_offset).astype(np.float32)
        prior = Layers(win, meta={"variance": "estimate"})
        prior["dem"] = self.height[sl].astype(np.float32)
        prior["variance"] = self.variance[sl].astype(np.float32)
        prior["count"] = self.count[sl]
        fused = dem_mosaik([prior, meas], rule="fuse", geometry=win, gate=p.gate, inflation=p.inflation)
        self.height[sl] = fused["dem"]
        self.variance[sl] = fused["variance"]
        self.count[sl] = fused["count"]
        self.stamp[sl][np.isfinite(meas["dem"])] = self.frames
        self._rehazard(sl)
        return FuseResult(sl, int(len(pts)), int(fused.meta.get("rejected_cells", 0)))

    def _rehazard(self, sl: tuple[slice, slice]) -> None:
        """Dem2Hazard over the cells whose window overlaps ``sl``, from the DEM around them."""
        h = self._half
        n = self.n
        a0, a1 = max(0, sl[0].start - h), min(n, sl[0].stop + h)  # cells whose verdict may change
        b0, b1 = max(0, sl[1].start - h), min(n, sl[1].stop + h)
        i0, i1 = max(0, a0 - h), min(n, a1 + h)  # the DEM they depend on
        j0, j1 = max(0, b0 - h), min(n, b1 + h)
        out = dem2hazard(self.height[i0:i1, j0:j1].astype(np.float32), self.params.cell, self.hazard_params)
        inner = (slice(a0 - i0, a1 - i0), slice(b0 - j0, b1 - j0))
        self.hazard[a0:a1, b0:b1] = out["hazard"][inner]
        self.slope[a0:a1, b0:b1] = out["slope"][inner]
        self.traversability[a0:a1, b0:b1] = out["traversability"][inner]
        self.whole[a0:a1, b0:b1] = whole_windows(self.height[i0:i1, j0:j1],
                                                 self.hazard_params.window_cells(self.params.cell))[inner]

    def remember(self) -> None:
        """Put the current verdicts into the memory (if any): before a shift, and before the
        planner reads the memory."""
        if self.memory is not None:
            self.memory.remember(self)

    def since(self, frame: int) -> np.ndarray:
        """The heights measured after ``frame`` (NaN elsewhere): what frames placed with the
        pose since then show, for a pose fix to match."""
        return np.where(self.stamp > frame, self.height, np.nan)

    def move(self, pivot: tuple[float, float], dx: float, dy: float, dyaw: float, since: int = 0) -> None:
        """Move what frames after ``since`` measured by a pose fix (rotation ``dyaw`` degrees
        about ``pivot``, then ``dx, dy``): they were placed with the pose the fix corrects, so
        they move with it (nearest cell), over what earlier frames left; the hazard layers are
        recomputed."""
        move_since(self, ("height", "variance", "count", "stamp"), since, pivot, dx, dy, dyaw)
        self._rehazard((slice(0, self.n), slice(0, self.n)))
        if self.memory is not None:
            self.memory.move(pivot, dx, dy, dyaw, since)
            self.remember()

    def ground_height(self, x: float, y: float, radius: float = 0.5, min_cells: int = 20) -> float | None:
        """The map's height under (x, y): the median within ``radius`` (None when fewer than
        ``min_cells`` are known). The rover's z for a frame: the ground it stands on was seen
        as it came, in this map's datum; the scan DEM (or 0 off it) can be decimetres from that
        once the rover has left the scanned ground, and a frame that overlaps the map too little
        to be aligned would then land as a phantom step."""
        return median_near(self.height, self.geometry, x, y, radius, min_cells)

    def nav_maps(self) -> NavMaps:
        """The hazard and slope layers as the planner takes them."""
        return NavMaps(self.hazard.copy(), self.slope.copy(), self.geometry, self.whole.copy())

    def check(self, poses: np.ndarray, length: float, width: float, min_score: float = 0.0) -> MoveCheck:
        """The footprint swept along ``poses`` (x, y, heading deg), as check-move sweeps one motion."""
        return sweep_check(self.traversability, self.geometry, poses, length, width, min_score)

    def seen_by(self, maps: NavMaps) -> np.ndarray:
        """``maps``' verdicts on this map's grid (nearest cell) as traversability: 0 hazardous,
        1 safe, NaN where they saw nothing. The scans the leg was planned on saw ground this map
        never held (round the rover, behind it); the check counts that ground as seen."""
        xs, ys = self.geometry.centers()
        r, c = maps.geometry.cell_of(xs[None, :], ys[:, None])
        r, c = np.broadcast_arrays(r, c)
        inside = maps.geometry.inside(r, c)
        hz = np.full(self.geometry.shape, UNDEFINED, np.uint8)
        hz[inside] = maps.hazard[r[inside], c[inside]]
        return np.where(hz == HAZARDOUS, np.float32(0), np.where(hz == SAFE, np.float32(1), np.float32(np.nan)))


def whole_windows(dem: np.ndarray, n: int) -> np.ndarray:
    """Cells whose ``n`` x ``n`` window (Dem2Hazard's) is defined in every cell; cells off the
    grid count as unseen."""
    import cv2

    seen = np.isfinite(dem).astype(np.float32)
    count = cv2.boxFilter(seen, -1, (n, n), normalize=False, borderType=cv2.BORDER_CONSTANT)
    return count >= n * n - 0.5


def move_since(grid: MapMemory | RollingMap, names: tuple[str, ...], since: int, pivot: tuple[float, float],
               dx: float, dy: float, dyaw: float) -> None:
    """Move the cells of ``grid``'s layers ``names`` (``stamp`` among them) that frames after
    ``since`` measured by a pose fix (rotation ``dyaw`` degrees about ``pivot``, then ``dx,
    dy``; nearest cell), over what earlier frames left where nothing moved lands."""
    from .map_match import transform_layers, undefined_fill

    recent = grid.stamp > since
    layers = Layers(grid.geometry)
    for name in names:
        a = getattr(grid, name)
        layers[name] = np.where(recent, a, undefined_fill(a)).astype(a.dtype)
    moved = transform_layers(layers, pivot, dx, dy, dyaw)
    earlier = ~recent & (moved["stamp"] == 0)  # a moved cell has a stamp > since >= 0
    for name in names:
        a = getattr(grid, name)
        setattr(grid, name, np.where(earlier, a, moved[name]).astype(a.dtype))


def sweep_check(trav: np.ndarray, geometry: GridGeometry, poses: np.ndarray, length: float, width: float,
                min_score: float = 0.0) -> MoveCheck:
    """check_move over each chord of a pose sequence, merged: blocked anywhere wins; the worst
    reported is the first blocked cell along the way (what the rover would meet first), else the
    first unseen one."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    if len(poses) == 1:
        poses = np.vstack([poses, poses])
    cells = unknown = blocked = 0
    first: dict[str, MoveCheck] = {}
    worst: MoveCheck | None = None
    for a, b in zip(poses[:-1], poses[1:], strict=True):
        m = check_move(trav, geometry, tuple(a), tuple(b), length, width, min_score)
        cells += m.cells
        unknown += m.unknown_cells
        blocked += m.blocked_cells
        first.setdefault(m.verdict, m)
        if worst is None or (math.isfinite(m.worst_score) and not m.worst_score >= worst.worst_score):
            worst = m
    assert worst is not None
    pick = first.get("not_traversable") or first.get("unknown") or worst
    verdict = "not_traversable" if blocked else "unknown" if unknown else "ok"
    return MoveCheck(verdict, pick.worst_score, pick.worst_x, pick.worst_y, cells, unknown, blocked)


def path_poses(pose: tuple[float, float, float], waypoints: np.ndarray, distance: float,
               step: float = 0.1) -> np.ndarray:
    """Poses every ``step`` along the polyline from the rover's ``pose`` through ``waypoints``
    (the ones still ahead), for ``distance`` metres: what the rover sweeps next. The heading is
    each stretch's direction (the rover turns on the spot at a waypoint)."""
    pts = [np.array(pose[:2], dtype=np.float64)] + [np.asarray(w, dtype=np.float64)[:2] for w in waypoints]
    out: list[tuple[float, float, float]] = []
    left = distance
    heading = float(pose[2])
    for a, b in zip(pts[:-1], pts[1:], strict=True):
        d = float(np.hypot(*(b - a)))
        if d < 1e-6:
            continue
        heading = math.degrees(math.atan2(b[1] - a[1], b[0] - a[0]))
        take = min(d, left)
        n = max(1, math.ceil(take / step))
        for t in np.linspace(0.0, take, n + 1):
            q = a + (b - a) * (t / d)
            out.append((float(q[0]), float(q[1]), heading))
        left -= take
        if left <= 1e-9:
            break
    if not out:
        out = [(float(pose[0]), float(pose[1]), heading)]
    return np.array(out)


def merge_nav_maps(base: NavMaps, fresh: NavMaps, older: np.ndarray | None = None) -> NavMaps:
    """The scan maps with the rolling map laid over them, on their union grid at ``base``'s cell:
    the latest measurement of a cell gives its verdict, as :func:`overrides` allows (a partly
    seen "safe" never erases a hazard). Where the rolling map measured a cell after the scan,
    its verdict stands: it saw the cell from within 3 m (see_max_range) while the scan's cells
    reach 4.5 m, where the scan misses true hazards and calls cells hazardous that are not;
    kept, such a false hazard can close the way to the goal, or the goal itself, for good. Elsewhere the scan's verdict stands (a rock the scan saw
    and the rolling map has not is still there); the slope is the fresh map's where it has one.
    ``older`` (on ``fresh``'s grid) marks the cells the rolling map last measured before the
    scan was made: there the scan's verdict stands where it has one, since a 360-degree scan
    fuses many views taken standing at a fixed pose, while those cells may hold a frame placed
    with a pose that has drifted since (a phantom step that would otherwise close the way for
    good)."""
    from .dem_mosaik import resample, union_geometry

    g = union_geometry([base.geometry, fresh.geometry], cell=base.geometry.cell)

    def on_union(a: np.ndarray, m: NavMaps) -> np.ndarray:
        return resample(a.astype(np.float64), np.zeros(m.geometry.shape), np.zeros(m.geometry.shape, np.int64),
                        m.geometry, g)[0]

    def hazard(m: NavMaps) -> np.ndarray:
        h = on_union(np.where(m.hazard == UNDEFINED, np.nan, m.hazard), m)
        return np.where(np.isfinite(h), h, UNDEFINED).astype(np.uint8)

    bh, fh = hazard(base), hazard(fresh)
    if older is not None:
        fh = np.where((on_union(older, fresh) > 0.5) & (bh != UNDEFINED), UNDEFINED, fh).astype(np.uint8)
    whole = None if fresh.whole is None else on_union(fresh.whole, fresh) > 0.5
    take = overrides(bh, fh, whole)
    merged = np.where(take, fh, bh).astype(np.uint8)
    fs = on_union(fresh.slope, fresh)
    slope = np.where(np.isfinite(fs), fs, on_union(base.slope, base)).astype(np.float32)
    return NavMaps(merged, slope, g)


def mark_unseen(maps: NavMaps, centre: tuple[float, float], inner: float, outer: float, value: int) -> NavMaps:
    """``maps`` with the cells no map has seen (undefined) farther than ``inner`` and at most
    ``outer`` from ``centre`` set to ``value`` (SAFE: ground taken as seen; HAZARDOUS: ground
    the body must not be driven onto, expanded by the planner as a rock is)."""
    xs, ys = maps.geometry.centers()
    d = np.hypot(xs[None, :] - centre[0], ys[:, None] - centre[1])
    hazard = np.where((maps.hazard == UNDEFINED) & (d > inner) & (d <= outer), np.uint8(value), maps.hazard)
    return NavMaps(hazard.astype(np.uint8), maps.slope, maps.geometry)


def mark_points(maps: NavMaps, points: list[tuple[float, float]], value: int) -> NavMaps:
    """``maps`` with the cells holding ``points`` (x, y) set to ``value`` (HAZARDOUS: ground the
    planner keeps the body's footprint off, as off a rock)."""
    xy = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    r, c = maps.geometry.cell_of(xy[:, 0], xy[:, 1])
    inside = maps.geometry.inside(r, c)
    hazard = maps.hazard.copy()
    hazard[r[inside], c[inside]] = value
    return NavMaps(hazard, maps.slope, maps.geometry, maps.whole)


def _shift(a: np.ndarray, dr: int, dc: int, fill: Any) -> np.ndarray:
    """``a`` moved so that old cell (r, c) lands at (r - dr, c - dc); new cells get ``fill``."""
    out = np.full_like(a, fill)
    h, w = a.shape
    rs0, rs1 = max(0, dr), min(h, h + dr)
    cs0, cs1 = max(0, dc), min(w, w + dc)
    if rs1 > rs0 and cs1 > cs0:
        out[rs0 - dr:rs1 - dr, cs0 - dc:cs1 - dc] = a[rs0:rs1, cs0:cs1]
    return out
