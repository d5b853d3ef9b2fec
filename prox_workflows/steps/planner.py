"""The path planner (seed 000 sect. 3.1.7, 4.4.1-4.4.3): merge the global and local maps into one
planning image, expand the hazards by the rover's size, and find the path with A*.

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

Cost model (A* G)
    A step between 8-connected neighbours u -> v of length L (``grid`` or ``grid * sqrt(2)``
    metres) costs ``L * (w + (1 - w) * (c_u + c_v) / 2)``: G = w * distance + (1 - w) * the
    environmental cost integrated along the path (trapezoid rule), both in metres, so
    w = 1 is distance only, w = 0.5 weighs them equally (seed 000 used 0.4 and 0.7). The
    per-cell factor ``k = w + (1 - w) * c`` is the cost per metre. A diagonal step is refused
    when either of the two orthogonal cells it passes between is blocked (no corner cutting).

Heuristic (A* H)
    H = k_min * d(cell, goal), with d the euclidean, octile or manhattan distance in metres and
    k_min the smallest per-metre factor on the map (at least w). Each step costs at least
    k_min * its length, so euclidean and octile H are admissible and consistent: A* returns an
    optimal path (the tests check it against scipy's Dijkstra). Octile is the exact distance on
    an empty 8-connected grid and so expands the fewest cells. Manhattan overestimates diagonal
    moves by up to sqrt(2): it is *not* admissible here, so A* is greedier (fewer cells expanded)
    and the path may be a little dearer than the optimum. Chebyshev (``max(|dr|, |dc|)``) is the
    admissible choice when diagonal steps cost as much as orthogonal ones (pyastar2d's model,
    used by the benchmark).

Costs are summed in fixed point (int64, the unit below 1e-9 of a step), so paths of equal cost
tie exactly rather than differing in the last bit of a float; ties in f are then broken by the
squared distance to the goal in cells, then by the cell index. Over open ground the search so
runs straight at the goal, and the same input always gives the same path. A cell is closed for
good once expanded (no re-opening), which is optimal with the consistent heuristics. The
reported cost so far is summed again in floating point along the path.

Speed: the A* inner loop is compiled with numba (``cache=True``: compiled once per installation,
~5 s, then loaded from the cache in ~0.4 s per process; :func:`warm_up` does it ahead of time).
The open list is a binary heap with decrease-key, the grid has a blocked border so neighbours
need no bounds checks. On 1000 x 1000 and 2000 x 2000 grids it runs at pyastar2d's speed
(``tools/bench/planner.py``). Without numba the same kernel runs as plain Python: the same
results, two orders of magnitude slower.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import cv2
import numpy as np
from scipy import ndimage

from rvs_params import Settings, param
from rvs_params.hazard import HAZARDOUS, SAFE, UNDEFINED
from rvs_params.jit import HAVE_NUMBA, jit

from ..engine import step
from ..grid import GridGeometry
from ..mapview import Marks
from ..params import parameters

HEURISTICS = {"euclidean": 0, "manhattan": 1, "octile": 2, "chebyshev": 3}
SQRT2 = math.sqrt(2.0)
_MAX_CELLS = 2**31 - 16  # the kernel's heap positions are int32

REASONS = ("start_in_hazard", "goal_in_hazard", "enclosed", "outside_maps")


class PlanningError(Exception):
    """No path: ``reason`` is one of :data:`REASONS`, ``message`` says why in words."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason
        self.message = message

    def __str__(self) -> str:
        return f"{self.reason}: {self.message}"


# ------------------------------------------------------------------------------------ A* kernel


def _astar_kernel(k, width, start, goal, c_orth, c_diag, share, corner, htype, h_lin, h_diag, g, parent):  # noqa: C901
    """A* over a flattened grid ``k`` (per-metre cost factors, inf = blocked) whose outer ring is
    blocked, so a neighbour index never leaves the array. Costs are fixed-point integers: a step
    costs floor(c_step * (share * k[u] + (1 - share) * k[v])), c_step being the step length in
    cost units; H is the octile distance with integer weights (h_lin, h_diag) or h_lin times the
    euclidean / manhattan / chebyshev cell distance, floored. Writes g (int64) and parent;
    returns (found, expanded cells). Written in the subset of Python numba compiles."""
    n = k.shape[0]
    pos = np.full(n, -1, np.int32)  # -1 unseen, -2 closed, >= 0 position in the heap
    cap = 4096
    hf = np.empty(cap, np.int64)  # heap: f
    hk = np.empty(cap, np.int64)  # heap: (squared cell distance to goal << 32) | cell
    offs = np.array((-width - 1, -width, -width + 1, -1, 1, width - 1, width, width + 1), np.int64)
    drow = np.array((-1, -1, -1, 0, 0, 1, 1, 1), np.int64)
    dcol = np.array((-1, 0, 1, -1, 1, -1, 0, 1), np.int64)
    orow = np.array((-width, 0, -width, 0, 0, width, 0, width), np.int64)  # the two cells a
    ocol = np.array((-1, 0, 1, 0, 0, -1, 0, 1), np.int64)  # diagonal step passes between
    mask32 = (1 << 32) - 1
    dmax = (1 << 31) - 1
    rest = 1.0 - share
    gr = goal // width
    gc = goal - gr * width
    sr = start // width
    sc = start - sr * width
    dr = abs(sr - gr)
    dc = abs(sc - gc)
    if htype == 2:
        mn = min(dr, dc)
        h0 = h_lin * (max(dr, dc) - mn) + h_diag * mn
    elif htype == 0:
        h0 = np.int64(h_lin * math.sqrt(dr * dr + dc * dc))
    elif htype == 1:
        h0 = h_lin * (dr + dc)
    else:
        h0 = h_lin * max(dr, dc)
    g[start] = 0
    hf[0] = h0
    hk[0] = (min(dr * dr + dc * dc, dmax) << 32) | start
    pos[start] = 0
    size = 1
    expanded = 0
    found = False
    while size > 0:
        u = hk[0] & mask32
        pos[u] = -2
        size -= 1
        if size > 0:  # the last entry replaces the root and sinks
            lf = hf[size]
            lk = hk[size]
            i = 0
            while True:
                c1 = 2 * i + 1
                if c1 >= size:
                    break
                best = c1
                bf = hf[c1]
                bk = hk[c1]
                c2 = c1 + 1
                if c2 < size:
                    f2 = hf[c2]
                    k2 = hk[c2]
                    if f2 < bf or (f2 == bf and k2 < bk):
                        best = c2
                        bf = f2
                        bk = k2
                if bf < lf or (bf == lf and bk < lk):
                    hf[i] = bf
                    hk[i] = bk
                    pos[bk & mask32] = i
                    i = best
                else:
                    break
            hf[i] = lf
            hk[i] = lk
            pos[lk & mask32] = i
        expanded += 1
        if u == goal:
            found = True
            break
        gu = g[u]
        ku = share * k[u]
        ur = u // width
        uc = u - ur * width
        for d in range(8):
            v = u + offs[d]
            kv = k[v]
            if kv == np.inf:
                continue
            pv = pos[v]
            if pv == -2:
                continue
            if orow[d] != 0:  # diagonal
                if corner and (k[u + orow[d]] == np.inf or k[u + ocol[d]] == np.inf):
                    continue
                ng = gu + np.int64(c_diag * (ku + rest * kv))
            else:
                ng = gu + np.int64(c_orth * (ku + rest * kv))
            if ng < g[v]:
                g[v] = ng
                parent[v] = u
                dr = abs(ur + drow[d] - gr)
                dc = abs(uc + dcol[d] - gc)
                if htype == 2:
                    mn = min(dr, dc)
                    hv = h_lin * (max(dr, dc) - mn) + h_diag * mn
                elif htype == 0:
                    hv = np.int64(h_lin * math.sqrt(dr * dr + dc * dc))
                elif htype == 1:
                    hv = h_lin * (dr + dc)
                else:
                    hv = h_lin * max(dr, dc)
                fv = ng + hv
                kk = (min(dr * dr + dc * dc, dmax) << 32) | v
                if pv < 0:  # new entry at the bottom
                    if size == cap:
                        cap *= 2
                        nf = np.empty(cap, np.int64)
                        nf[:size] = hf[:size]
                        hf = nf
                        nk = np.empty(cap, np.int64)
                        nk[:size] = hk[:size]
                        hk = nk
                    i = size
                    size += 1
                else:  # decrease-key: the entry rises from where it is
                    i = pv
                while i > 0:
                    p = (i - 1) >> 1
                    pf = hf[p]
                    if fv < pf or (fv == pf and kk < hk[p]):
                        hf[i] = pf
                        hk[i] = hk[p]
                        pos[hk[p] & mask32] = i
                        i = p
                    else:
                        break
                hf[i] = fv
                hk[i] = kk
                pos[v] = i
    return found, expanded


_compiled: list[Any] = []  # the compiled kernel, made on first use (importing numba takes ~0.3 s)


def _compiled_kernel() -> Any:
    """numba's compiled kernel; the plain-Python one (with a warning) when numba is missing."""
    if not _compiled:
        if not HAVE_NUMBA:  # pragma: no cover - exercised only where numba is missing
            import warnings

            warnings.warn("numba is not installed: the path planner's A* runs as plain Python, about "
                          "100x slower", RuntimeWarning, stacklevel=3)
        _compiled.append(jit(_astar_kernel))
    return _compiled[0]


def warm_up() -> None:
    """Compile (or load from numba's cache) the A* kernel now rather than on the first plan."""
    astar_grid(np.ones((3, 3)), (0, 0), (2, 2))


MIN_LEG = 0.05  # m: a leg shorter than this makes no progress (navigate says E_DATA)


@dataclass
class GridPath:
    """An A* result on a grid: the cells from start to goal and the cost so far at each."""

    cells: np.ndarray  # (n, 2) int64 row, col
    g: np.ndarray  # (n,) float64 cost so far
    expanded: int  # cells taken off the open list

    @property
    def cost(self) -> float:
        return float(self.g[-1])


Search = Callable[[np.ndarray, tuple[int, int], tuple[int, int], GridGeometry], GridPath]


def astar_grid(cost: np.ndarray, start: Sequence[int], goal: Sequence[int], *, heuristic: str = "octile",
               orth: float = 1.0, diag: float = SQRT2, share: float = 0.5, corner_rule: bool = True,
               h_scale: float | None = None, python: bool = False) -> GridPath:
    """A* over a cost grid: ``cost`` is the cost per unit length of each cell (>= 0; inf
    blocked). A step u -> v of length ``orth`` or ``diag`` costs
    ``length * (share * cost[u] + (1 - share) * cost[v])``; ``share = 0.5`` averages the two cells,
    ``share = 0`` charges the entered cell only (pyastar2d's model, with ``diag = orth = 1``).
    ``h_scale`` defaults to the smallest finite cost, which keeps euclidean/octile admissible.
    ``python`` runs the uncompiled kernel (for tests). Raises :class:`PlanningError`."""
    if heuristic not in HEURISTICS:
        raise ValueError(f"heuristic must be one of {', '.join(HEURISTICS)}, not {heuristic!r}")
    cost = np.asarray(cost, dtype=np.float64)
    if cost.ndim != 2:
        raise ValueError("cost must be a 2-D grid")
    if np.isnan(cost).any() or (cost < 0).any():
        raise ValueError("cost must be >= 0 (inf for blocked cells), without NaN")
    h, w = cost.shape
    if (h + 2) * (w + 2) > _MAX_CELLS:
        raise ValueError(f"grid of {h} x {w} cells is too large for the planner")
    (sr, sc), (gr, gc) = (int(start[0]), int(start[1])), (int(goal[0]), int(goal[1]))
    for name, (r, c) in (("start", (sr, sc)), ("goal", (gr, gc))):
        if not (0 <= r < h and 0 <= c < w):
            raise PlanningError("outside_maps", f"{name} cell ({r}, {c}) is outside the {h} x {w} grid")
    if not np.isfinite(cost[sr, sc]):
        raise PlanningError("start_in_hazard", f"start cell ({sr}, {sc}) is blocked")
    if not np.isfinite(cost[gr, gc]):
        raise PlanningError("goal_in_hazard", f"goal cell ({gr}, {gc}) is blocked")
    finite = cost[np.isfinite(cost)]
    if h_scale is None:
        h_scale = float(finite.min())
    padded = np.pad(cost, 1, constant_values=np.inf).ravel()
    width = w + 2
    s = (sr + 1) * width + sc + 1
    t = (gr + 1) * width + gc + 1
    # Fixed-point costs: exact sums, so equal-cost paths tie exactly and the tie-break (nearest
    # the goal) steers the search, rather than rounding noise in the last bit of a float. The
    # unit is chosen so that no g or f can exceed 2**62; its error is < 1e-9 of a step.
    bits = 61 - math.ceil(math.log2(padded.size + 1))
    max_step = max(orth, diag) * max(float(finite.max()), h_scale)
    scale = 2.0**bits / max_step if max_step > 0 else 1.0
    g = np.full(padded.size, np.iinfo(np.int64).max, np.int64)
    parent = np.full(padded.size, -1, np.int32)
    kernel = _astar_kernel if python else _compiled_kernel()
    found, expanded = kernel(padded, width, s, t, float(orth) * scale, float(diag) * scale, float(share),
                             bool(corner_rule), HEURISTICS[heuristic], int(math.floor(h_scale * orth * scale)),
                             int(math.floor(h_scale * diag * scale)), g, parent)
    if not found:
        reached = int((g != np.iinfo(np.int64).max).sum())
        raise PlanningError("enclosed", f"the goal is not reachable: the start's region has {reached} cells "
                                        f"and does not contain the goal")
    chain = [t]
    while chain[-1] != s:
        chain.append(int(parent[chain[-1]]))
    idx = np.array(chain[::-1], np.int64)
    cells = np.stack([idx // width - 1, idx % width - 1], axis=1)
    # the cost so far in floating point, step by step along the path
    steps = np.diff(idx)
    length = np.where(np.abs(steps) == 1, orth, np.where(np.abs(steps) == width, orth, diag))
    kc = padded[idx]
    gf = np.concatenate([[0.0], np.cumsum(length * (share * kc[:-1] + (1 - share) * kc[1:]))])
    return GridPath(cells=cells, g=gf, expanded=int(expanded))


def grid_graph(cost: np.ndarray, *, orth: float = 1.0, diag: float = SQRT2, share: float = 0.5,
               corner_rule: bool = True):
    """The same 8-connected graph as :func:`astar_grid` as a scipy CSR matrix (node = row * w +
    col), for scipy.sparse.csgraph (cost-to-go maps, the benchmark's Dijkstra peer)."""
    from scipy.sparse import coo_matrix

    cost = np.asarray(cost, dtype=np.float64)
    h, w = cost.shape
    free = np.isfinite(cost)
    idx = np.arange(h * w).reshape(h, w)
    rows, cols, vals = [], [], []
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr == 0 and dc == 0:
                continue
            r0, r1 = max(0, -dr), h - max(0, dr)
            c0, c1 = max(0, -dc), w - max(0, dc)
            u = (slice(r0, r1), slice(c0, c1))
            v = (slice(r0 + dr, r1 + dr), slice(c0 + dc, c1 + dc))
            ok = free[u] & free[v]
            length = orth
            if dr and dc:
                length = diag
                if corner_rule:
                    ok &= free[r0 + dr:r1 + dr, c0:c1] & free[r0:r1, c0 + dc:c1 + dc]
            with np.errstate(invalid="ignore"):  # 0 * inf on blocked cells, masked out by ok
                weight = length * (share * cost[u] + (1 - share) * cost[v])
            rows.append(idx[u][ok])
            cols.append(idx[v][ok])
            # csgraph drops explicit zeros; a tiny positive weight keeps zero-cost edges
            vals.append(np.where(weight[ok] > 0, weight[ok], 1e-300))
    n = h * w
    return coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)).tocsr()


# ----------------------------------------------------------------------------- maps and merging


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


@parameters("plan")
@dataclass
class PlanParams(Settings):
    """Path planning on hazard and slope maps (a navigate leg, ``rvs-path-planner``): the settings an
    operator or a script sets. :class:`PlannerParams`, what :func:`plan_path` is called with,
    takes its defaults and checks from here and adds what the caller knows of the rover."""

    weight: float = param(0.5, "A* weight w: 1 distance only, 0 environmental cost only", min=0.0, max=1.0)
    heuristic: str = param("octile", "A* heuristic", choices=("euclidean", "manhattan", "octile"))
    grid: float = param(0.05, "planning cell size", unit="m", min=0.01, max=1.0)
    margin: float = param(0.1, "added to the rover radius around hazards", unit="m", min=0.0, max=2.0)
    max_deviation: float = param(0.1, "waypoint polyline's largest deviation from the A* path", unit="m",
                                 min=0.0, max=5.0)
    border: float = param(1.0, "stop this far inside the locally seen ground: at least the radius the next "
                          "scan cannot see around the rover, so the legs join; halved (down to 0) where the "
                          "seen ground is too narrow for the rover to move at all", unit="m", min=0.0, max=5.0)
    footprint: str = param("circle", "what must clear the hazards: circle, the rover's circumscribed circle (radius + "
                           "margin) along the whole path; body, its half width + margin along straight stretches "
                           "and the circle only where it stops and turns on the spot (waypoints and the goal), "
                           "which opens the gaps of a rock field that the circle closes", choices=("circle", "body"))


_PLAN = PlanParams()


@dataclass(frozen=True)
class PlannerParams:
    """The planner's parameters (metres and degrees)."""

    grid: float | None = None  # planning cell size; default: the local map's
    weight: float = _PLAN.weight  # w: 1 distance only, 0 environmental cost only
    heuristic: str = _PLAN.heuristic
    rover_radius: float = 0.3
    half_width: float | None = None  # footprint "body": straight stretches keep this + margin from hazards
    margin: float = _PLAN.margin
    critical_slope: float = 20.0  # degrees: c = 1 here
    unknown_cost: float = 1.0  # c of unknown ground (inf: not traversable)
    max_deviation: float = _PLAN.max_deviation  # of the waypoint polyline from the A* path
    border: float = 0.3  # stop this far inside the local map's outer border
    blank_pad: float = 2.0  # blank global maps reach this far beyond start, goal and local map
    window: float | None = None  # plan only within this margin around start, goal and local map

    def __post_init__(self) -> None:
        specs = PlanParams.specs()  # the operator's range and choices are the planner's own
        specs["weight"].coerce(self.weight, "planner")
        specs["heuristic"].coerce(self.heuristic, "planner")
        for name in ("rover_radius", "margin", "max_deviation", "border", "blank_pad"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0")
        if self.grid is not None and not self.grid > 0:
            raise ValueError("grid must be > 0")
        if not self.critical_slope > 0:
            raise ValueError("critical_slope must be > 0")
        if not self.unknown_cost >= 0:
            raise ValueError("unknown_cost must be >= 0 (inf forbids unknown ground)")

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


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


# ------------------------------------------------------------------------------------ planning


@dataclass
class PlanResult:
    """A plan in world coordinates: the whole A* path, where it is cut, and the waypoints."""

    image: PlanningImage
    params: PlannerParams
    start: tuple[float, float]
    goal: tuple[float, float]
    path: np.ndarray  # (n, 2) x, y: the A* path, exact start and goal at its ends
    path_cells: np.ndarray  # (n, 2) row, col on the planning grid
    cost_so_far: np.ndarray  # (n,)
    cut: int  # the rover drives path[:cut]
    waypoints: Any  # waypoints.Waypoints
    expanded: int
    warnings: list[str] = field(default_factory=list)

    @property
    def cost(self) -> float:
        """The cost of the whole A* path to the goal (metres, weighted)."""
        return float(self.cost_so_far[-1])

    @property
    def reaches_goal(self) -> bool:
        """Whether the driven part ends at the goal (not cut at the local map's border)."""
        return self.cut == len(self.path)


def _relax_start(image: PlanningImage, cell: tuple[int, int]) -> float | None:
    """A start inside the hazard margin (not on a hazard) may leave it: unblock the cells near
    the start that are at least as far from every hazard as the start is. Returns that distance."""
    r, c = cell
    if not image.blocked[r, c] or image.hazard[r, c] == HAZARDOUS:
        return None
    d0 = float(image.hazard_distance[r, c])
    reach = int(math.ceil(image.clearance / image.geometry.cell)) + 1
    r0, r1 = max(0, r - reach), min(image.geometry.height, r + reach + 1)
    c0, c1 = max(0, c - reach), min(image.geometry.width, c + reach + 1)
    rr, cc = np.mgrid[r0:r1, c0:c1]
    near = (rr - r) ** 2 + (cc - c) ** 2 <= reach**2
    win = (slice(r0, r1), slice(c0, c1))
    free = near & image.blocked[win] & (image.hazard[win] != HAZARDOUS) & (image.hazard_distance[win] >= d0)
    image.blocked[win] &= ~free
    return d0


def plan_path(local: NavMaps, global_: NavMaps | None, start: Sequence[float], goal: Sequence[float],
              params: PlannerParams | None = None, start_heading: float | None = None,
              goal_heading: float | None = None, search: Search | None = None,
              cover: Sequence[Sequence[float]] = ()) -> PlanResult:
    """Plan from ``start`` to ``goal`` (world x, y): merge, expand, A*, cut at the local map's
    border, simplify into waypoints. Raises :class:`PlanningError` when there is no path.

    ``search`` replaces the A* on the cost grid (the see loop's D* Lite, which repairs the last
    search instead of starting again: the same graph and costs, so the same path cost); it gets
    the grid, the start and goal cells and the grid's geometry. ``cover``: points the planning
    grid must reach besides start and goal (a mission's box, so that the grid keeps its
    geometry from one replan to the next and the repair has something to repair)."""
    from .waypoints import make_waypoints, shortcut, simplify

    params = params or PlannerParams()
    start = (float(start[0]), float(start[1]))
    goal = (float(goal[0]), float(goal[1]))
    image = planning_image(local, global_, params, points=[start, goal, *cover])
    geom = image.geometry
    cells = {}
    for name, (x, y) in (("start", start), ("goal", goal)):
        r, c = geom.cell_of(np.array(x), np.array(y))
        if not geom.inside(r, c):
            raise PlanningError("outside_maps", f"{name} ({x:.3f}, {y:.3f}) is outside the maps, which cover "
                                                f"x {geom.xmin:.2f}..{geom.xmax:.2f}, y {geom.ymin:.2f}..{geom.ymax:.2f}")
        cells[name] = (int(r), int(c))
    notes: list[str] = []
    radius = params.rover_radius + params.margin
    gr, gc = cells["goal"]
    if image.hazard[gr, gc] == HAZARDOUS:
        raise PlanningError("goal_in_hazard", f"goal ({goal[0]:.3f}, {goal[1]:.3f}) is on a hazardous cell")
    if image.blocked[gr, gc] or not image.turnable[gr, gc]:  # the rover stops there: its body must fit
        raise PlanningError("goal_in_hazard", f"goal ({goal[0]:.3f}, {goal[1]:.3f}) is "
                                              f"{float(image.hazard_distance[gr, gc]):.2f} m from a hazardous "
                                              f"cell, closer than rover radius + margin ({radius:.2f} m) "
                                              f"+ half a cell diagonal")
    if not np.isfinite(image.env_cost[gr, gc]):
        raise PlanningError("goal_in_hazard", f"goal ({goal[0]:.3f}, {goal[1]:.3f}) is on unknown ground, "
                                              "which is not traversable (unknown_cost = inf)")
    sr, sc = cells["start"]
    if image.hazard[sr, sc] == HAZARDOUS:
        raise PlanningError("start_in_hazard", f"start ({start[0]:.3f}, {start[1]:.3f}) is on a hazardous cell")
    d0 = _relax_start(image, cells["start"])
    if d0 is not None:
        notes.append(f"start is {d0:.2f} m from a hazard, inside the {radius:.2f} m margin: near the start the "
                     f"margin is relaxed to {d0:.2f} m so the rover can move away")
    k = image.cost_per_metre(params.weight)
    if not np.isfinite(k[sr, sc]):
        raise PlanningError("start_in_hazard", f"start ({start[0]:.3f}, {start[1]:.3f}) is on unknown ground, "
                                               "which is not traversable (unknown_cost = inf)")
    try:
        if search is not None:
            gp = search(k, cells["start"], cells["goal"], geom)
        else:
            gp = astar_grid(k, cells["start"], cells["goal"], heuristic=params.heuristic, orth=geom.cell,
                            diag=geom.cell * SQRT2, share=0.5, corner_rule=True)
    except PlanningError as exc:
        if exc.reason != "enclosed":
            raise
        raise PlanningError("enclosed", _enclosed_message(np.isfinite(k), cells["start"], cells["goal"],
                                                          geom.cell)) from None
    xs, ys = geom.centers()
    path = np.stack([xs[gp.cells[:, 1]], ys[gp.cells[:, 0]]], axis=1)
    path[0] = start
    path[-1] = goal
    cut, border = _adaptive_cut(path, image.border_distance[gp.cells[:, 0], gp.cells[:, 1]], params.border,
                                geom.cell)
    if border < params.border:
        notes.append(f"border relaxed from {params.border:g} m to {border:g} m: the seen ground is too narrow "
                     "to stop that far inside it")
    if cut < len(path):
        notes.append(f"path cut at the local map's border: the rover drives {cut} of {len(path)} points")
    turnable = image.turnable[gp.cells[:, 0], gp.cells[:, 1]]
    if cut < len(path):  # the rover stops at the cut and turns there next leg: where its body fits
        back = np.flatnonzero(turnable[1:cut])
        if back.size:
            cut = int(back[-1]) + 2
    if cut <= 1 and len(path) > 1:
        notes.append("the path does not enter locally seen ground: no move")
    driven = path[:max(cut, 1)]
    keep = simplify(driven, params.max_deviation, blocked=~np.isfinite(k), geometry=geom,
                    turnable=turnable[:max(cut, 1)])
    keep = shortcut(driven, keep, k, gp.g, geom)
    wps = make_waypoints(driven[keep], start_heading=start_heading,
                         goal_heading=goal_heading if cut == len(path) else None)
    return PlanResult(image=image, params=params, start=start, goal=goal, path=path, path_cells=gp.cells,
                      cost_so_far=gp.g, cut=max(cut, 1), waypoints=wps, expanded=gp.expanded, warnings=notes)


def nearest_reachable(local: NavMaps, global_: NavMaps | None, start: Sequence[float], goal: Sequence[float],
                      params: PlannerParams | None = None) -> tuple[float, float]:
    """The free cell reachable from ``start`` that is nearest ``goal`` (world x, y): where to
    drive when the goal itself is judged unreachable from far, to judge it again from closer.

    Reachable as :func:`plan_path` sees it: the same planning image, the same relaxed start, and
    8-connected free cells (a diagonal between two blocked cells may make a cell look reachable
    that A* will not reach; plan_path to it then fails as enclosed, which is the honest answer).
    Raises :class:`PlanningError` (``start_in_hazard``, ``outside_maps``) as plan_path does."""
    params = params or PlannerParams()
    start = (float(start[0]), float(start[1]))
    goal = (float(goal[0]), float(goal[1]))
    image = planning_image(local, global_, params, points=[start, goal])
    geom = image.geometry
    r, c = geom.cell_of(np.array(start[0]), np.array(start[1]))
    if not geom.inside(r, c):
        raise PlanningError("outside_maps", f"start ({start[0]:.3f}, {start[1]:.3f}) is outside the maps")
    cell = (int(r), int(c))
    if image.hazard[cell] == HAZARDOUS:
        raise PlanningError("start_in_hazard", f"start ({start[0]:.3f}, {start[1]:.3f}) is on a hazardous cell")
    _relax_start(image, cell)
    free = np.isfinite(image.cost_per_metre(params.weight))
    if not free[cell]:
        raise PlanningError("start_in_hazard", f"start ({start[0]:.3f}, {start[1]:.3f}) is on unknown ground, "
                                               "which is not traversable (unknown_cost = inf)")
    labels, _ = ndimage.label(free, structure=np.ones((3, 3), bool))
    region = labels == labels[cell]
    stop = region & image.turnable  # where the rover's body fits when it stops
    rows, cols = np.nonzero(stop if stop.any() else region)
    xs, ys = geom.centers()
    d = np.hypot(xs[cols] - goal[0], ys[rows] - goal[1])
    i = int(np.argmin(d))
    return float(xs[cols[i]]), float(ys[rows[i]])


def _adaptive_cut(path: np.ndarray, border_distance: np.ndarray, border: float, cell: float) -> tuple[int, float]:
    """Cut the path ``border`` inside the seen ground, halving the border where that leaves the
    rover nothing to drive (a scan from a corner sees a narrow strip, seed 000's ~1 m border
    would stop every leg at its start); returns the cut and the border used."""
    from .waypoints import cut_at_border

    while True:
        cut = cut_at_border(border_distance, border)
        moved = float(np.hypot(*(path[max(cut, 1) - 1] - path[0])))
        if moved >= MIN_LEG or border <= 0.0:
            return cut, border
        border = border / 2 if border / 2 >= 2 * cell else 0.0


def _enclosed_message(free: np.ndarray, start: tuple[int, int], goal: tuple[int, int], cell: float) -> str:
    labels, _ = ndimage.label(free, structure=np.ones((3, 3), bool))
    ls, lg = labels[start], labels[goal]
    size_s = int((labels == ls).sum())
    size_g = int((labels == lg).sum())
    area = cell * cell
    if ls == lg:
        return ("the goal is not reachable: start and goal are separated only by hazard corners the rover "
                "may not cut")
    which = "start" if size_s <= size_g else "goal"
    return (f"the goal is not reachable: the {which} is enclosed by hazards (the start's free region is "
            f"{size_s * area:.2f} m^2, the goal's {size_g * area:.2f} m^2)")


def plan_summary(result: PlanResult) -> dict[str, Any]:
    """YAML-ready plan: parameters, path and waypoints."""
    wp = result.waypoints
    return {
        "start": list(result.start),
        "goal": list(result.goal),
        "cost": result.cost,
        "cost_driven": float(result.cost_so_far[result.cut - 1]),
        "reaches_goal": result.reaches_goal,
        "expanded_cells": result.expanded,
        "grid": {"cell": result.image.geometry.cell, "xmin": result.image.geometry.xmin,
                 "ymax": result.image.geometry.ymax, "width": result.image.geometry.width,
                 "height": result.image.geometry.height},
        "parameters": result.params.as_dict(),
        "warnings": list(result.warnings),
        "path": [[float(x), float(y), float(g), int(i < result.cut)]
                 for i, ((x, y), g) in enumerate(zip(result.path, result.cost_so_far, strict=True))],
        "path_columns": ["x", "y", "cost_so_far", "drive"],
        "waypoints": wp.rows(),
        "waypoint_columns": list(wp.COLUMNS),
    }



# ------------------------------------------------------------------------------------- outputs

GREEN = (0, 200, 0)
DIM_GREEN = (0, 110, 0)
BLUE = (0, 0, 255)
RED = (220, 0, 0)
ORANGE = (255, 140, 0)
UNKNOWN_TAN = (205, 190, 150)
MARGIN_SLATE = (95, 95, 120)

_LEGEND = ("green: A* path (dim beyond the cut)", "blue: waypoints", "black: hazard",
           "slate: rover radius + margin", "tan: unknown ground", "orange: local map border",
           "grey: slope cost (darker = steeper)")


def _scale_for(shape: tuple[int, int], target: int = 800, limit: int = 4000) -> int:
    return max(1, min(target // max(shape), limit // max(shape)))


def plan_map_rgb(image: PlanningImage) -> np.ndarray:
    """The planning image as RGB: slope cost in grey (white flat, darker steeper), hazards black,
    the rover margin slate, unknown ground tan (seed 000 figs. 54-55)."""
    c = np.nan_to_num(image.env_cost.astype(np.float64), nan=0.0, posinf=1.0)
    grey = (255 - 200 * np.clip(c, 0.0, 1.0)).astype(np.uint8)
    rgb = np.repeat(grey[:, :, None], 3, axis=2)
    rgb[image.hazard == UNDEFINED] = UNKNOWN_TAN
    rgb[image.blocked] = MARGIN_SLATE
    rgb[image.hazard == HAZARDOUS] = (0, 0, 0)
    return rgb


def draw_plan(rgb: np.ndarray, geometry: GridGeometry, path: np.ndarray | None, waypoints: np.ndarray | None,
              cut: int | None = None, local: np.ndarray | None = None, legend: bool = True) -> np.ndarray:
    """An RGB map (on ``geometry``) enlarged for viewing, with the A* path in green (dim after
    ``cut``), the waypoints in blue and, if given, the border of the ``local`` mask in orange."""
    s = _scale_for(rgb.shape[:2])
    out = cv2.resize(rgb, (rgb.shape[1] * s, rgb.shape[0] * s), interpolation=cv2.INTER_NEAREST)
    out = np.ascontiguousarray(out)
    thick = max(1, s // 2)

    def px(xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        col = (xy[:, 0] - geometry.xmin) / geometry.cell * s
        row = (geometry.ymax - xy[:, 1]) / geometry.cell * s
        return np.round(np.stack([col, row], axis=1) * 16).astype(np.int32)  # 4 bits of sub-pixel

    if local is not None and local.any():
        mask = cv2.resize(local.astype(np.uint8), (out.shape[1], out.shape[0]), interpolation=cv2.INTER_NEAREST)
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        cv2.drawContours(out, contours, -1, ORANGE, 1)
    if path is not None and len(path) > 1:
        cut = len(path) if cut is None else cut
        if cut < len(path):
            cv2.polylines(out, [px(path[max(cut - 1, 0):])], False, DIM_GREEN, thick, cv2.LINE_AA, shift=4)
        cv2.polylines(out, [px(path[:cut])], False, GREEN, thick + 1, cv2.LINE_AA, shift=4)
    if path is not None and len(path):
        cv2.circle(out, tuple(int(v) for v in px(path[0])[0]), 6 * 16, GREEN, 2, cv2.LINE_AA, shift=4)
        gx, gy = (int(v) for v in px(path[-1])[0])
        d = 6 * 16
        cv2.line(out, (gx - d, gy - d), (gx + d, gy + d), RED, 2, cv2.LINE_AA, shift=4)
        cv2.line(out, (gx - d, gy + d), (gx + d, gy - d), RED, 2, cv2.LINE_AA, shift=4)
    if waypoints is not None and len(waypoints):
        pts = px(waypoints)
        if len(pts) > 1:
            cv2.polylines(out, [pts], False, BLUE, 1, cv2.LINE_AA, shift=4)
        for p in pts:
            cv2.circle(out, (int(p[0]), int(p[1])), max(3, min(6, s // 2)) * 16, BLUE, -1, cv2.LINE_AA, shift=4)
    if legend:
        out = _with_legend(out)
    return out


def _with_legend(img: np.ndarray) -> np.ndarray:
    line = 18
    if img.shape[1] < 340:
        img = np.concatenate([img, np.full((img.shape[0], 340 - img.shape[1], 3), 255, np.uint8)], axis=1)
    panel = np.full((line * len(_LEGEND) + 8, img.shape[1], 3), 255, np.uint8)
    for i, text in enumerate(_LEGEND):
        cv2.putText(panel, text, (6, line * (i + 1)), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return np.concatenate([img, panel], axis=0)


def ortho_figure(ortho: np.ndarray, geometry: GridGeometry, title: str, marks: Marks) -> np.ndarray:
    """The ortho-image with a plan or a traverse drawn over it, as an operator-ready figure whose
    legend names exactly what is drawn (the ortho's own colours mean only brightness)."""
    from ..mapview import Style, figure, layer_rgba

    rgba, legend = layer_rgba(np.asarray(ortho), Style("grey"), geometry.cell)
    return figure(rgba, geometry, legend, title, marks)


def write_plan(result: PlanResult, prefix: str, ortho: tuple[np.ndarray, GridGeometry] | None = None,
               made_by: str = "rvs-path-planner", inputs: Sequence[str] = ()) -> list[str]:
    """PREFIX_path.csv, PREFIX_waypoints.csv, PREFIX_plan.yaml, PREFIX_plan_map.png and, with an
    ortho-image, PREFIX_plan_ortho.png (each product with its YAML sidecar). Returns the paths."""
    from pathlib import Path

    from ..products import write_png, write_sidecar, write_text_atomic, write_yaml_atomic

    base = Path(prefix)
    params = result.params.as_dict()
    written: list[str] = []
    drive = (np.arange(len(result.path)) < result.cut).astype(int)
    lines = ["x,y,cost_so_far,drive"] + [f"{x:.4f},{y:.4f},{g:.6f},{d}" for (x, y), g, d
                                          in zip(result.path, result.cost_so_far, drive, strict=True)]
    p = write_text_atomic(base.with_name(base.name + "_path.csv"), "\n".join(lines) + "\n")
    written.append(str(p))
    write_sidecar(p, made_by, params, list(inputs), columns={
        "x, y": "world coordinates of the planning cells' centres (exact start and goal at the ends), m",
        "cost_so_far": "A* G from the start (w * distance + (1 - w) * environmental cost), m",
        "drive": "1 for the part the rover drives (before the cut at the local map's border)"})
    wp = result.waypoints
    lines = [",".join(wp.COLUMNS)] + [",".join(f"{v:.4f}" if np.isfinite(v) else "nan" for v in row)
                                      for row in wp.table()]
    p = write_text_atomic(base.with_name(base.name + "_waypoints.csv"), "\n".join(lines) + "\n")
    written.append(str(p))
    write_sidecar(p, made_by, params, list(inputs), columns={
        "x, y": "waypoint, world coordinates, m",
        "heading_deg": "heading of the leg leaving the waypoint (the last: arrival heading), deg CCW from x",
        "turn_deg": "turn on the spot at the waypoint before its leg, deg, left positive (NaN: heading unknown)",
        "leg_length": "length of the leg leaving the waypoint, m"})
    p = write_yaml_atomic(base.with_name(base.name + "_plan.yaml"),
                          {"made_by": made_by, "inputs": list(inputs), **plan_summary(result)})
    written.append(str(p))
    img = result.image
    rgb = draw_plan(plan_map_rgb(img), img.geometry, result.path, wp.xy, result.cut, img.local)
    p = write_png(base.with_name(base.name + "_plan_map.png"), rgb)
    written.append(str(p))
    write_sidecar(p, made_by, params, list(inputs), legend=list(_LEGEND))
    if ortho is not None:
        o_img, o_geom = ortho
        rgb = ortho_figure(o_img, o_geom, "plan over the ortho-image", Marks(
            path=result.path, driven=result.cut, waypoints=wp.xy, goal=(float(result.goal[0]), float(result.goal[1]))))
        p = write_png(base.with_name(base.name + "_plan_ortho.png"), rgb)
        written.append(str(p))
        write_sidecar(p, made_by, params, list(inputs))
    return written


# ------------------------------------------------------------------------------ workflow steps


@step("plan_path", outputs={"plan": "PlanResult"})
def plan_step(local: NavMaps, global_maps: NavMaps | None, start: Sequence[float], goal: Sequence[float],
              start_heading: float | None = None, weight: float = 0.5, heuristic: str = "octile",
              grid: float | None = None, margin: float = 0.1, max_deviation: float = 0.1, border: float = 0.3,
              rover_radius: float = 0.3, critical_slope: float = 20.0,
              unknown_cost: float | None = None, footprint: str | None = None,
              rover_half_width: float | None = None) -> PlanResult:
    """:func:`plan_path` with the planner's parameters as the script passes them one by one."""
    if footprint == "body" and rover_half_width is None:
        raise ValueError("footprint body needs the rover's half width (rover_half_width)")
    params = PlannerParams(grid=grid, weight=weight, heuristic=heuristic, rover_radius=rover_radius, margin=margin,
                           half_width=rover_half_width if footprint == "body" else None,
                           critical_slope=critical_slope, max_deviation=max_deviation, border=border,
                           **({} if unknown_cost is None else {"unknown_cost": unknown_cost}))
    return plan_path(local, global_maps, start, goal, params, start_heading=start_heading)


@step("write_plan", outputs={"files": "list[str]"})
def write_plan_step(plan: PlanResult, prefix: str, ortho: tuple[np.ndarray, GridGeometry] | None = None,
                    made_by: str | None = None, inputs: Sequence[str] | None = None) -> list[str]:
    """The plan's products (:func:`write_plan`): path, waypoints, summary and drawings."""
    return write_plan(plan, str(prefix), ortho=ortho, made_by=made_by or "rvs-prox", inputs=inputs or ())
