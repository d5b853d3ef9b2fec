"""The path planner's maps: hazard and slope maps (:class:`NavMaps`), merged onto one planning
grid with the hazards expanded by the rover's size (:func:`planning_image`), and the bounds on
how large that grid may be.

Planning image
    A grid of ``grid`` metres covering the local and the global maps (or, without global maps, a
    blank one made to cover the local map, the start and the goal). Each map is pooled onto it:
    a planning cell takes the maximum of the source pixels whose centres fall in it (a hazard or
    a steep pixel is never averaged away), or the source pixel under its centre when the planning
    grid is finer. The local map lies over the global one where it is *defined*: at least half
    of a cell's local pixels are not undefined (hazard 128). A local hazardous pixel always makes
    its cell hazardous; a global hazard is overruled where the local map sees the ground.

Cell classes and environmental cost ``c`` (dimensionless)
    - known safe ground: ``c = slope / critical_slope`` (slope in degrees; 0 flat, 1 at the
      critical slope, more beyond it);
    - unknown ground (undefined in every map, e.g. a blank global map): ``c = unknown_cost``,
      default 1.0, as dear as ground at the critical slope: the planner may plan into unexplored
      ground, at a price, and the path is later cut where the locally seen ground ends
      (:mod:`.waypoints`); ``unknown_cost = inf`` forbids unknown ground;
    - ground beyond a global map that the local maps do not show either: not traversable. An
      orbital map bounds where the rover may go; past its edge not even the orbiter saw the
      ground (a scene's edge, where the ToF gets no returns, looked like open unknown ground);
    - hazardous (255), and every cell whose centre is within ``rover_radius + margin`` plus half
      a cell diagonal of a hazardous cell's centre: blocked. The half diagonal makes it
      conservative: the rover's disc, centred on a free cell, never touches a hazardous cell's
      square (the thesis grew OpenCV contours for the same purpose; an exact distance transform
      does it here). A start inside that margin, but not on a hazard, is let out: near the
      start, the cells at least as far from every hazard as the start is are unblocked, and the
      plan says so in its warnings.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from rvs_params.hazard import HAZARDOUS, SAFE, UNDEFINED

from ..grid import GridGeometry
from .astar import SQRT2
from .plan_params import PlannerParams


@dataclass
class NavMaps:
    """A hazard map (0 / 128 / 255) and a slope map (degrees, NaN undefined) on one geometry;
    ``whole`` marks the cells whose verdict rests on a wholly seen hazard window (None: all do,
    as in a map made from a finished DEM), so that merging maps can tell a safe verdict that
    may have missed a rock from one that cannot."""

    hazard: np.ndarray
    slope: np.ndarray
    geometry: GridGeometry
    whole: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.hazard = np.asarray(self.hazard)
        self.slope = np.asarray(self.slope, dtype=np.float32)
        if self.hazard.shape != self.geometry.shape or self.slope.shape != self.geometry.shape:
            raise ValueError(f"hazard {self.hazard.shape} and slope {self.slope.shape} must both match "
                             f"the grid {self.geometry.shape}")


# The most cells a planning grid may hold. Its arrays (cost, distances, the search's own) take
# about 70 bytes a cell: 64 million cells (a 400 m square of 5 cm cells) is some 4.5 GB and a
# minute of search; a larger request is refused before anything is allocated.
MAX_PLAN_CELLS = 64_000_000


def blank_geometry(points: Sequence[Sequence[float]], cell: float, pad: float,
                   bounds: Sequence[float] | None = None) -> GridGeometry:
    """The grid of :func:`blank_maps`, known before anything is allocated (navigate checks a
    goal's distance against :data:`MAX_PLAN_CELLS` with it before it starts)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    xmin, ymin = pts.min(axis=0) - pad
    xmax, ymax = pts.max(axis=0) + pad
    if bounds is not None:
        xmin, ymin = min(xmin, bounds[0]), min(ymin, bounds[1])
        xmax, ymax = max(xmax, bounds[2]), max(ymax, bounds[3])
    return GridGeometry.covering(float(xmin), float(ymin), float(xmax), float(ymax), cell)


def check_plan_size(geom: GridGeometry, what: str = "planning grid") -> None:
    """ValueError (E_ARG on the wire) for a grid over :data:`MAX_PLAN_CELLS`, naming the limit."""
    if geom.width * geom.height > MAX_PLAN_CELLS:
        side = math.sqrt(MAX_PLAN_CELLS) * geom.cell
        raise ValueError(f"the {what} of {geom.height} x {geom.width} cells of {geom.cell:g} m is over the "
                         f"{MAX_PLAN_CELLS:,} cells a plan may span (a square of about {side:.0f} m): give a nearer "
                         "goal, a coarser grid or a window")


def blank_maps(points: Sequence[Sequence[float]], cell: float, pad: float,
               bounds: Sequence[float] | None = None) -> NavMaps:
    """Blank global maps (all undefined) covering ``points`` and ``bounds`` with ``pad`` metres
    around: what the planner uses when there is no global map (seed 000 sect. 4.4.4)."""
    geom = blank_geometry(points, cell, pad, bounds)
    check_plan_size(geom, "blank global map")
    return NavMaps(np.full(geom.shape, UNDEFINED, np.uint8), np.full(geom.shape, np.nan, np.float32), geom)


def _pool(values: np.ndarray, src: GridGeometry, dst: GridGeometry, how: str) -> np.ndarray:
    """``values`` (float, NaN = no data) onto ``dst``: max or mean of the source pixels whose
    centres fall in each cell, else the source pixel under the cell's centre; NaN where neither.
    Both grids are north-up, so the pixel-to-cell mapping is monotone and separable by rows and
    columns: the pooling is two ``reduceat`` passes over contiguous runs."""
    values = np.asarray(values, dtype=np.float32)
    if src == dst:
        return values.copy()
    out = np.full(dst.shape, np.nan, np.float32)
    if dst.cell < src.cell * (1 - 1e-9):
        # sample at the destination centres (a destination finer than the source: some cells
        # hold no source centre)
        xs, ys = dst.centers()
        r = np.floor((src.ymax - ys) / src.cell).astype(np.int64)
        c = np.floor((xs - src.xmin) / src.cell).astype(np.int64)
        rin = (r >= 0) & (r < src.height)
        cin = (c >= 0) & (c < src.width)
        if rin.any() and cin.any():
            out[np.ix_(np.nonzero(rin)[0], np.nonzero(cin)[0])] = values[np.ix_(r[rin], c[cin])]
    # pool the source pixels by destination cell (covers a destination coarser than the source)
    sx, sy = src.centers()
    dr = np.floor((dst.ymax - sy) / dst.cell).astype(np.int64)
    dc = np.floor((sx - dst.xmin) / dst.cell).astype(np.int64)
    rsel = np.nonzero((dr >= 0) & (dr < dst.height))[0]
    csel = np.nonzero((dc >= 0) & (dc < dst.width))[0]
    if not (len(rsel) and len(csel)):
        return out
    dr, dc = dr[rsel], dc[csel]
    rstart = np.flatnonzero(np.diff(dr, prepend=dr[0] - 1))
    cstart = np.flatnonzero(np.diff(dc, prepend=dc[0] - 1))
    block = values[rsel[0]:rsel[-1] + 1, csel[0]:csel[-1] + 1]

    def reduce(ufunc: np.ufunc, a: np.ndarray) -> np.ndarray:
        if len(rstart) < len(dr):  # else one source row per cell: nothing to reduce
            a = ufunc.reduceat(a, rstart, axis=0)
        if len(cstart) < len(dc):
            a = ufunc.reduceat(a, cstart, axis=1)
        return a

    if how == "max":
        pooled = reduce(np.fmax, block)
    else:
        ok = ~np.isnan(block)
        total = reduce(np.add, np.where(ok, block, np.float32(0)))
        count = reduce(np.add, ok.astype(np.float32))
        with np.errstate(invalid="ignore", divide="ignore"):
            pooled = np.where(count > 0, total / count, np.nan)
    rows, cols = dr[rstart], dc[cstart]
    if len(rows) == rows[-1] - rows[0] + 1 and len(cols) == cols[-1] - cols[0] + 1:  # contiguous
        out[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1] = pooled
    else:
        out[np.ix_(rows, cols)] = pooled
    return out


@dataclass
class PlanningImage:
    """The merged maps on the planning grid, and what A* plans on."""

    geometry: GridGeometry
    hazard: np.ndarray  # uint8 0 / 128 / 255, merged, before expansion
    slope: np.ndarray  # float32 degrees, NaN unknown
    local: np.ndarray  # bool: the local map defines the cell
    blocked: np.ndarray  # bool: hazardous or within rover radius + margin of a hazard
    hazard_distance: np.ndarray  # float32 m from the cell centre to the nearest hazardous cell centre
    env_cost: np.ndarray  # float32 c: slope / critical slope, unknown_cost where unknown, inf hazardous
    border_distance: np.ndarray  # float32 m to the outer border of the locally defined region
    clearance: float  # m: blocked where hazard_distance <= clearance
    turn_clearance: float  # m: the rover may stop and turn on the spot where hazard_distance > this

    @property
    def turnable(self) -> np.ndarray:
        """Where the rover's body fits at any heading: it may stop and turn on the spot there."""
        return self.hazard_distance > self.turn_clearance

    def cost_per_metre(self, weight: float) -> np.ndarray:
        """k = w + (1 - w) * c, inf where blocked (or c is inf)."""
        c = self.env_cost.astype(np.float64)
        with np.errstate(invalid="ignore"):  # w = 1 times an inf cost: that cell is inf anyway
            return np.where(self.blocked | ~np.isfinite(c), np.inf, weight + (1.0 - weight) * c)


def _distance_cells(zero_at: np.ndarray) -> np.ndarray:
    """Exact euclidean distance (cells, float32) from each cell to the nearest ``zero_at`` cell.
    OpenCV's precise transform is exact up to float32 rounding that may differ by one ulp from
    run to run; a distance is the root of an integer, so rounding its square restores the exact,
    repeatable value (below 1000 cells, far beyond any threshold used here)."""
    d = cv2.distanceTransform(np.where(zero_at, np.uint8(0), np.uint8(255)), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    near = d < 1000.0  # with no zero cell at all, every distance is 2^64, whose square overflows float32
    exact = np.sqrt(np.rint(np.square(np.where(near, d, 0.0))))
    return np.where(near, exact, d)


def expand_hazards(hazardous: np.ndarray, radius: float, cell: float) -> tuple[np.ndarray, np.ndarray, float]:
    """(blocked, distance to the nearest hazardous cell in metres, clearance): a cell is blocked
    when its centre is within ``radius`` of some point of a hazardous cell's square, taken
    conservatively as centre distance <= radius + half the cell diagonal."""
    clearance = float(radius) + cell * SQRT2 / 2
    if not hazardous.any():
        return hazardous.copy(), np.full(hazardous.shape, np.inf, np.float32), clearance
    dist = _distance_cells(hazardous) * cell
    return hazardous | (dist <= clearance), dist, clearance


def border_distance(local: np.ndarray, cell: float, passable: np.ndarray | None = None) -> np.ndarray:
    """Metres from each cell centre to the nearest cell outside the local map's outer border.
    Holes inside the local map (occlusion shadows, the blind spot under the rover) are not
    border: seed 000 sect. 4.4.2 measures to "just the outer border of the local DEM region".
    With ``passable`` (the cells on an orbital map), only outer cells the rover could drive
    onto are border: past the orbital map's edge unseen ground is no way on, and where the
    seen ground reaches beyond that edge (the rover sees past it) the edge is where ground ends,
    not where unseen ground begins. Measured to it, a rover beside hirise's edge was kept from
    the seen strip along it: every leg cut after 2 points, then "no way on" (mission 9)."""
    outside = np.pad(~np.asarray(local, bool), 1, constant_values=True).astype(np.uint8)
    mask = np.zeros((outside.shape[0] + 2, outside.shape[1] + 2), np.uint8)
    cv2.floodFill(outside, mask, (0, 0), 2)  # the background reached from the edge (4-connected)
    border = outside == 2  # outside the local map with its holes filled
    if passable is not None:
        border &= np.pad(np.asarray(passable, bool), 1, constant_values=False)
    return (_distance_cells(border)[1:-1, 1:-1] * cell).astype(np.float32)


def planning_image(local: NavMaps, global_: NavMaps | None, params: PlannerParams,
                   points: Sequence[Sequence[float]] = ()) -> PlanningImage:
    """Merge the maps onto the planning grid (local over global) and expand the hazards."""
    cell = params.grid or local.geometry.cell
    orbital = global_ is not None
    if global_ is None:
        global_ = blank_maps(list(points) or [(local.geometry.xmin, local.geometry.ymin)], cell,
                             params.blank_pad, local.geometry.bounds)
    lb, gb = local.geometry.bounds, global_.geometry.bounds
    bounds = [min(lb[0], gb[0]), min(lb[1], gb[1]), max(lb[2], gb[2]), max(lb[3], gb[3])]
    if params.window is not None:
        pts = np.asarray(list(points) or [], dtype=np.float64).reshape(-1, 2)
        wx = [lb[0], lb[2], *pts[:, 0]]
        wy = [lb[1], lb[3], *pts[:, 1]]
        win = [min(wx) - params.window, min(wy) - params.window, max(wx) + params.window, max(wy) + params.window]
        bounds = [max(bounds[0], win[0]), max(bounds[1], win[1]), min(bounds[2], win[2]), min(bounds[3], win[3])]
    geom = GridGeometry.covering(*bounds, cell)
    check_plan_size(geom)

    def layers(maps: NavMaps) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(share of the cell's pixels that are defined, any pixel hazardous, max safe slope)."""
        hz = maps.hazard
        nan = np.float32(np.nan)
        frac = _pool((hz != UNDEFINED).astype(np.float32), maps.geometry, geom, "mean")  # NaN: off the map
        danger = _pool(np.where(hz == HAZARDOUS, np.float32(1), np.where(hz == UNDEFINED, nan, np.float32(0))),
                       maps.geometry, geom, "max")
        slope = _pool(np.where(hz == SAFE, maps.slope, nan), maps.geometry, geom, "max")
        with np.errstate(invalid="ignore"):
            return frac >= 0.5, danger > 0, slope  # NaN compares False

    local_def, l_haz, l_slope = layers(local)
    global_def, g_haz, g_slope = layers(global_)
    hazardous = l_haz | (g_haz & ~local_def)
    known = local_def | global_def
    slope = np.where(local_def, l_slope, np.where(global_def, g_slope, np.nan)).astype(np.float32)
    hazard = np.where(hazardous, HAZARDOUS, np.where(known, SAFE, UNDEFINED)).astype(np.uint8)
    # The circle of rover radius + margin is where the body fits at every heading: where the rover
    # stops and turns on the spot. Along a straight stretch only its half width sweeps sideways, so
    # with a half width (footprint "body") the cells between are blocked at half width + margin:
    # a rock field that closes every gap to the circle leaves gaps the body drives through (ACE's
    # lesson against GESTALT's disc), and the waypoints are put where turning is safe.
    reach = params.rover_radius if params.half_width is None else min(params.half_width, params.rover_radius)
    blocked, hdist, clearance = expand_hazards(hazardous, reach + params.margin, cell)
    turn_clearance = params.rover_radius + params.margin + cell * SQRT2 / 2
    with np.errstate(invalid="ignore"):
        c = np.where(np.isfinite(slope), slope / params.critical_slope, params.unknown_cost)
    c = np.where(known & np.isfinite(slope), c, params.unknown_cost)
    on_global = None
    if orbital:
        on_global = np.isfinite(_pool(np.zeros(global_.geometry.shape, np.float32), global_.geometry, geom, "mean"))
        c = np.where(on_global | local_def, c, np.inf)
    c = np.where(hazardous, np.inf, c).astype(np.float32)
    return PlanningImage(geometry=geom, hazard=hazard, slope=slope, local=local_def, blocked=blocked,
                         hazard_distance=hdist.astype(np.float32), env_cost=c,
                         border_distance=border_distance(local_def, cell, on_global), clearance=clearance,
                         turn_clearance=turn_clearance)
