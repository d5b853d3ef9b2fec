"""A* on a grid of costs per unit length (the path planner's search, :mod:`.planner`), and the
same 8-connected graph for scipy's csgraph.

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
from dataclasses import dataclass
from typing import Any

import numpy as np

from rvs_params.jit import HAVE_NUMBA, jit

from ..grid import GridGeometry
from ._astar_kernel import astar_kernel

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


_compiled: list[Any] = []  # the compiled kernel, made on first use (importing numba takes ~0.3 s)


def _compiled_kernel() -> Any:
    """numba's compiled kernel; the plain-Python one (with a warning) when numba is missing."""
    if not _compiled:
        if not HAVE_NUMBA:  # pragma: no cover - exercised only where numba is missing
            import warnings

            warnings.warn("numba is not installed: the path planner's A* runs as plain Python, about "
                          "100x slower", RuntimeWarning, stacklevel=3)
        _compiled.append(jit(astar_kernel))
    return _compiled[0]


def warm_up() -> None:
    """Compile (or load from numba's cache) the A* kernel now rather than on the first plan."""
    astar_grid(np.ones((3, 3)), (0, 0), (2, 2))


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
    kernel = astar_kernel if python else _compiled_kernel()
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
