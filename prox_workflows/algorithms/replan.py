"""Incremental replanning: D* Lite (Koenig & Likhachev 2002) on the same grid
graph and cost model as :func:`.astar.astar_grid`, so that a rover that sees a few cells change
repairs its path in milliseconds instead of searching the map again.

Why D* Lite and not A* again
    A* from scratch on 400 x 400 cells takes tens of milliseconds and grows with the map; after
    a change of a few cells near the rover, most of the previous search is still right. D* Lite
    searches backwards, from the goal, so the cost to the goal of every cell it settled survives
    the rover's moves; a change re-opens only the cells whose cost to the goal it can alter, and
    the repair stops as soon as the rover's own cell is settled again.

Same graph, same costs
    8-connected, a step u -> v of length ``orth`` or ``diag`` costs
    ``length * (share * cost[u] + (1 - share) * cost[v])``, diagonals refused past a blocked
    corner (``corner_rule``), inf = blocked; costs summed in the same fixed point as A* (exact
    ties, so results do not depend on float rounding), the reported cost so far summed again in
    floating point along the path. The path cost equals a fresh ``astar_grid`` on the same map
    (tests/prox/test_replan.py checks it on random maps, before and after random changes).

Where it differs from astar_grid, and why
    - The heuristic must be *consistent* for D* Lite's repair to stay optimal; ``manhattan``
      (not admissible on this graph) is refused, and the weights of the others are clamped a few
      fixed-point units below the cheapest step. ``h_scale`` above the cheapest cell is lowered
      to it, so the path is the optimum where A* with such an ``h_scale`` may return a dearer one.
    - A step costs at least one fixed-point unit (~1e-11 of the dearest step): zero-cost steps
      would let the path read-out wander among equal costs.
    - The fixed-point unit leaves 2**6 of headroom: an update that makes a cell dearer than 64
      times the dearest cost at construction, or cheaper than the heuristic's weight, cannot be
      repaired in the same units and restarts the search (correct, as slow as the first plan).
      Pass ``h_scale`` = the map's cost floor (the planner's ``w``) to rule the second out.
    - The goal is fixed (D* Lite's search is rooted there); a new goal is a new planner.

Between ``plan()`` calls the rover may ``move_start`` (any free cell, on the path or not: slip)
and the map may ``update`` (any cells, blocked, freed, dearer, cheaper) in any order and number.

Speed: a repair after a few changed cells or a start move costs a small fraction of a fresh A*;
the first plan of a mission has nothing to repair and costs more than an A* (its backward search
keeps two values per cell and a two-part key). ``python -m tools.bench.replan`` measures both
against A* (figures in the README). The kernels are compiled on first use (:func:`warm_up`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from .astar import HEURISTICS, SQRT2, GridPath, PlanningError

HEADROOM_BITS = 6  # costs may grow 64x over the dearest at construction before a restart
_SAFETY_UNITS = 2  # heuristic weights this far below the cheapest step: float rounding of the step
_MAX_CELLS = 2**31 - 16


def _kernels() -> Any:
    """The kernel module, imported on first use: importing numba costs ~0.3 s."""
    from . import _replan_kernels

    return _replan_kernels


def warm_up() -> None:
    """Compile (or load from numba's cache) the kernels now rather than on the first plan."""
    planner = IncrementalPlanner(np.ones((4, 4)), (0, 0), (3, 3))
    planner.plan()
    planner.update([(1, 1)], [np.inf])
    planner.move_start((0, 1))
    planner.plan()
    planner.cost_to_go([(0, 0), (3, 2)])
    planner.cost_to_go([(0, 0)], exact=False)


class IncrementalPlanner:
    """D* Lite on a cost grid (see the module docstring); the same arguments as
    :func:`.astar.astar_grid` except ``python`` (without numba the kernels run as Python)."""

    def __init__(self, cost: np.ndarray, start: Sequence[int], goal: Sequence[int], *,
                 heuristic: str = "octile", orth: float = 1.0, diag: float = SQRT2, share: float = 0.5,
                 corner_rule: bool = True, h_scale: float | None = None) -> None:
        if heuristic not in HEURISTICS:
            raise ValueError(f"heuristic must be one of {', '.join(HEURISTICS)}, not {heuristic!r}")
        if heuristic == "manhattan":
            raise ValueError("heuristic 'manhattan' is not admissible on the 8-connected grid, and D* Lite's "
                             "repair is only optimal with a consistent one: use octile, euclidean or chebyshev")
        cost = np.asarray(cost, dtype=np.float64)
        if cost.ndim != 2:
            raise ValueError("cost must be a 2-D grid")
        _check_values(cost)
        h, w = cost.shape
        if (h + 2) * (w + 2) > _MAX_CELLS:
            raise ValueError(f"grid of {h} x {w} cells is too large for the planner")
        if not (orth > 0 and diag > 0):
            raise ValueError("orth and diag must be > 0")
        self.shape = (h, w)
        self.heuristic = heuristic
        self.orth = float(orth)
        self.diag = float(diag)
        self.share = float(share)
        self.corner_rule = bool(corner_rule)
        self._width = w + 2
        self._k = np.pad(cost, 1, constant_values=np.inf).ravel()
        self._start = self._index(start, "start")
        self._goal = self._index(goal, "goal")
        finite = cost[np.isfinite(cost)]
        floor = float(finite.min()) if finite.size else 0.0
        self._h_scale = floor if h_scale is None else max(0.0, min(float(h_scale), floor))
        self._restarts = 0
        n = self._k.size
        self._g = np.empty(n, np.int64)
        self._rhs = np.empty(n, np.int64)
        self._h1 = np.empty(n, np.int64)
        self._h2 = np.empty(n, np.int64)
        self._hc = np.empty(n, np.int64)
        self._pos = np.empty(n, np.int32)
        self._meta = np.zeros(4, np.int64)
        wd = self._width
        self._nb = np.array([(-wd - 1, -wd, -wd + 1, -1, 1, wd - 1, wd, wd + 1),
                             (-wd, 0, -wd, 0, 0, wd, 0, wd),
                             (-1, 0, 1, 0, 0, -1, 0, 1),
                             (-1, -1, -1, 0, 0, 1, 1, 1),
                             (-1, 0, 1, -1, 1, -1, 0, 1)], np.int64)
        self._reset(float(finite.max()) if finite.size else 1.0)

    # ------------------------------------------------------------------------------ public API

    @property
    def start(self) -> tuple[int, int]:
        return self._cell(self._start)

    @property
    def goal(self) -> tuple[int, int]:
        return self._cell(self._goal)

    @property
    def cost(self) -> np.ndarray:
        """The map as the planner now knows it (a copy)."""
        h, w = self.shape
        return self._k.reshape(h + 2, w + 2)[1:-1, 1:-1].copy()

    @property
    def restarts(self) -> int:
        """How often an update could not be repaired in the current units and restarted."""
        return self._restarts

    def plan(self) -> GridPath:
        """The optimal path from the current start to the goal, repairing the previous search.
        Raises :class:`.astar.PlanningError` as astar_grid does (start_in_hazard,
        goal_in_hazard, enclosed); ``expanded`` counts the cells this call expanded."""
        kern = _kernels()
        if not np.isfinite(self._k[self._start]):
            r, c = self.start
            raise PlanningError("start_in_hazard", f"start cell ({r}, {c}) is blocked")
        if not np.isfinite(self._k[self._goal]):
            r, c = self.goal
            raise PlanningError("goal_in_hazard", f"goal cell ({r}, {c}) is blocked")
        expanded = kern.compute_shortest_path(self._k, self._g, self._rhs, self._h1, self._h2, self._hc,
                                              self._pos, self._meta, self._nb, self._ip, self._fp,
                                              self._start, self._goal)
        if self._rhs[self._start] >= kern.INF:  # on termination rhs(start) <= g(start) is its cost
            reached = int((self._g < kern.INF).sum())
            raise PlanningError("enclosed", f"the goal is not reachable: the goal's region has {reached} "
                                            f"cells and does not contain the start")
        out = np.empty(self._k.size, np.int64)
        m = kern.read_path(self._k, self._g, self._nb, self._ip, self._fp, self._start, self._goal, out)
        if m < 0:  # pragma: no cover - would be a bug in the repair
            raise RuntimeError("D* Lite path read-out broke off; the search state is inconsistent")
        return self._grid_path(out[:m], int(expanded))

    def update(self, cells: np.ndarray | Sequence[Sequence[int]], costs: np.ndarray | float | Sequence[float]) -> None:
        """Tell the planner that ``cells`` ((m, 2) row, col) now cost ``costs`` (one value or m;
        inf blocks). The repair itself happens in the next :meth:`plan`."""
        rc = np.asarray(cells, dtype=np.int64).reshape(-1, 2)
        vals = np.broadcast_to(np.asarray(costs, dtype=np.float64), (len(rc),)).copy()
        if not len(rc):
            return
        _check_values(vals)
        h, w = self.shape
        if ((rc[:, 0] < 0) | (rc[:, 0] >= h) | (rc[:, 1] < 0) | (rc[:, 1] >= w)).any():
            raise ValueError(f"cells must lie in the {h} x {w} grid")
        idx = (rc[:, 0] + 1) * self._width + rc[:, 1] + 1
        finite = vals[np.isfinite(vals)]
        if finite.size and (finite.max() > self._k_cap or finite.min() < self._h_scale):
            # not representable in the current units, or would make the heuristic overestimate
            self._k[idx] = vals
            self._h_scale = min(self._h_scale, float(finite.min()))
            self._restarts += 1
            kf = self._k[np.isfinite(self._k)]
            self._reset(float(kf.max()) if kf.size else 1.0)
            return
        kern = _kernels()
        kern.update_cells(self._k, self._g, self._rhs, self._h1, self._h2, self._hc, self._pos, self._meta,
                          self._nb, self._ip, self._fp, self._start, self._goal, idx, vals)

    def update_map(self, cost: np.ndarray) -> int:
        """Replace the whole map, passing on only the cells that differ (a hazard map recomputed
        wholesale changes few cells); returns how many changed."""
        cost = np.asarray(cost, dtype=np.float64)
        if cost.shape != self.shape:
            raise ValueError(f"cost must be {self.shape}, not {cost.shape}")
        old = self.cost
        changed = np.argwhere(~((old == cost) | (np.isnan(old) & np.isnan(cost))))
        self.update(changed, cost[changed[:, 0], changed[:, 1]])
        return len(changed)

    def move_start(self, cell: Sequence[int]) -> None:
        """The rover is now at ``cell``: the next plan starts there (the search tree rooted at the
        goal is kept; D* Lite's km absorbs the heuristic's change of origin)."""
        self._move_to(self._index(cell, "start"))

    def cost_to_go(self, cells: np.ndarray | Sequence[Sequence[int]], exact: bool = True) -> np.ndarray:
        """The cost from each of ``cells`` to the goal (inf where there is no path), for scoring
        local moves near the start (:mod:`.arcs`). ``exact`` settles each cell as if the rover
        stood there (a small repair for cells near the searched region; a whole search for a
        free cell cut off from the goal); otherwise the one-step lookahead over what the search
        has settled: exact on and around the optimal path, an upper bound (or inf) elsewhere."""
        rc = np.asarray(cells, dtype=np.int64).reshape(-1, 2)
        h, w = self.shape
        if ((rc[:, 0] < 0) | (rc[:, 0] >= h) | (rc[:, 1] < 0) | (rc[:, 1] >= w)).any():
            raise ValueError(f"cells must lie in the {h} x {w} grid")
        idx = (rc[:, 0] + 1) * self._width + rc[:, 1] + 1
        kern = _kernels()
        out = np.empty(len(idx), np.int64)
        if exact:
            home = self._start
            for i, s in enumerate(idx):
                if s == self._goal or not np.isfinite(self._k[s]):
                    out[i] = 0 if s == self._goal else kern.INF
                    continue
                self._move_to(int(s))
                kern.compute_shortest_path(self._k, self._g, self._rhs, self._h1, self._h2, self._hc,
                                           self._pos, self._meta, self._nb, self._ip, self._fp, self._start,
                                           self._goal)
                out[i] = self._rhs[s]
            self._move_to(home)
        else:
            kern.cost_to_go(self._k, self._g, self._nb, self._fp, self._ip, idx, out)
            out[idx == self._goal] = 0
        res = out.astype(np.float64) / self._scale
        res[out >= kern.INF] = np.inf
        return res

    # ----------------------------------------------------------------------------- internals

    def _reset(self, k_max: float) -> None:
        """Fix the fixed-point units and the heuristic's weights, and start the search afresh."""
        n = self._k.size
        bits = 61 - math.ceil(math.log2(n + 1)) - HEADROOM_BITS
        max_step = max(self.orth, self.diag) * max(k_max, self._h_scale)
        self._scale = 2.0**bits / max_step if max_step > 0 else 1.0
        self._k_cap = max(k_max, self._h_scale) * 2**HEADROOM_BITS if max_step > 0 else 0.0
        h_lin = max(0, math.floor(self._h_scale * self.orth * self._scale) - _SAFETY_UNITS)
        h_diag = max(0, math.floor(self._h_scale * self.diag * self._scale) - _SAFETY_UNITS)
        a = min(h_lin, h_diag)  # no cheaper per cell crossed, whichever way
        b = min(h_diag, 2 * a)  # octile must stay a metric: one diagonal <= two orthogonal
        # euclidean: an orthogonal cell <= the cheapest orthogonal step and sqrt(2) cells <= the
        # cheapest diagonal one, less the float error of the product (relative 2**-52 per cell)
        eps = 8.0 * 2.0**-52 * (self.shape[0] + self.shape[1] + 2)
        h_eu = min(h_lin, h_diag / SQRT2) * (1.0 - eps)
        self._ip = np.array([self._width, int(self.corner_rule), HEURISTICS[self.heuristic], a, b], np.int64)
        self._fp = np.array([self.orth * self._scale, self.diag * self._scale, self.share, 1.0 - self.share, h_eu],
                            np.float64)
        _kernels().initialise(self._g, self._rhs, self._h1, self._h2, self._hc, self._pos, self._meta,
                              self._ip, self._fp, self._start, self._goal)

    def _move_to(self, s: int) -> None:
        if s == self._start:
            return
        kern = _kernels()
        self._meta[1] += kern.heuristic(self._start, s, self._ip, self._fp)
        self._start = s
        kern.set_start(self._meta, self._ip, s)
        if self._meta[1] > 2**60:  # km could overflow the keys after a very long drive
            self._restarts += 1
            kf = self._k[np.isfinite(self._k)]
            self._reset(float(kf.max()) if kf.size else 1.0)

    def _index(self, cell: Sequence[int], name: str) -> int:
        r, c = int(cell[0]), int(cell[1])
        h, w = self.shape
        if not (0 <= r < h and 0 <= c < w):
            raise PlanningError("outside_maps", f"{name} cell ({r}, {c}) is outside the {h} x {w} grid")
        return (r + 1) * self._width + c + 1

    def _cell(self, i: int) -> tuple[int, int]:
        return int(i // self._width - 1), int(i % self._width - 1)

    def _grid_path(self, idx: np.ndarray, expanded: int) -> GridPath:
        wd = self._width
        cells = np.stack([idx // wd - 1, idx % wd - 1], axis=1)
        steps = np.abs(np.diff(idx))
        length = np.where((steps == 1) | (steps == wd), self.orth, self.diag)
        kc = self._k[idx]
        gf = np.concatenate([[0.0], np.cumsum(length * (self.share * kc[:-1] + (1 - self.share) * kc[1:]))])
        return GridPath(cells=cells, g=gf, expanded=expanded)


def _check_values(values: np.ndarray) -> None:
    if np.isnan(values).any() or (values < 0).any():
        raise ValueError("cost must be >= 0 (inf for blocked cells), without NaN")


class Replanner:
    """A :data:`.astar.Search` for :func:`.planner.plan_path` that keeps one D* Lite search
    for as long as the planning grid's geometry and the goal cell stay the same, and repairs it
    with the cells that changed since the last call (``update_map``) and the rover's new cell.
    A new grid (the maps grew past it) or a new goal starts a new search: the see loop passes
    the mission's box as ``cover`` so that happens seldom."""

    def __init__(self, heuristic: str = "octile", h_scale: float | None = None) -> None:
        self.heuristic = "octile" if heuristic == "manhattan" else heuristic  # D* Lite needs a consistent one
        self.h_scale = h_scale
        self.planner: IncrementalPlanner | None = None
        self.key: tuple[Any, ...] | None = None
        self.searches = 0  # new searches (first plan, new grid or goal)
        self.repairs = 0  # searches repaired
        self.changed = 0  # cells changed over all repairs

    def __call__(self, cost: np.ndarray, start: tuple[int, int], goal: tuple[int, int], geometry: Any) -> GridPath:
        key = (cost.shape, geometry.xmin, geometry.ymax, geometry.cell, tuple(goal))
        if self.planner is None or key != self.key:
            self.planner = IncrementalPlanner(cost, start, goal, heuristic=self.heuristic, orth=geometry.cell,
                                              diag=geometry.cell * SQRT2, h_scale=self.h_scale)
            self.key = key
            self.searches += 1
        else:
            self.changed += self.planner.update_map(cost)
            self.planner.move_start(start)
            self.repairs += 1
        return self.planner.plan()
