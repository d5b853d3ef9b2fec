"""D* Lite's repairs held to a fresh A*: a seeded 400 x 400 cost map as the planner sees it, and the
cycle the see loop runs (drive a few cells, the map changes ahead, repair) with every repaired
path's cost checked against A*'s on the same changed map (``tools.bench.replan`` times it)."""

from __future__ import annotations

import math
import time

import cv2
import numpy as np
from scipy import ndimage

from prox_workflows.algorithms.astar import PlanningError, astar_grid
from prox_workflows.algorithms.replan import IncrementalPlanner

N = 400  # cells a side
WEIGHT = 0.5  # the planner's cost floor w
ROVER = 0.3 + 0.1  # rover radius + margin, m


def grown(hazard: np.ndarray, cell: float) -> np.ndarray:
    """Blocked cells: within rover radius + margin + half a cell diagonal of a hazard (plan_maps.py)."""
    d = cv2.distanceTransform(np.where(hazard, 0, 255).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return d * cell <= ROVER + cell * math.sqrt(2) / 2


def slope_deg(z: np.ndarray, cell: float) -> np.ndarray:
    gy, gx = np.gradient(z.astype(np.float64), cell)
    return np.degrees(np.arctan(np.hypot(gx, gy)))


def cost_map(slope: np.ndarray, hazard: np.ndarray, cell: float, critical: float) -> dict:
    blocked = grown(hazard, cell)
    k = np.where(blocked, np.inf, WEIGHT + (1 - WEIGHT) * slope / critical)
    labels, _ = ndimage.label(np.isfinite(k), structure=np.ones((3, 3)))
    largest = np.argmax(np.bincount(labels.ravel())[1:]) + 1
    # start and goal: the roomiest free cells of that region in 15 % corner boxes, so that one
    # rock does not wall the rover in at the start
    room = cv2.distanceTransform((labels == largest).astype(np.uint8), cv2.DIST_L2, 5)
    b = int(0.15 * N)
    s = np.unravel_index(np.argmax(room[:b, :b]), (b, b))
    g = np.unravel_index(np.argmax(room[-b:, -b:]), (b, b))
    return {"k": k, "cell": cell, "critical": critical, "start": (int(s[0]), int(s[1])),
            "goal": (int(N - b + g[0]), int(N - b + g[1])), "blocked": float(blocked.mean())}


def sim_map(seed: int) -> dict:
    """Rolling ground (0.05 m cells) with rocks (5-25 cm) covering ~1.5 % of the area."""
    rng = np.random.default_rng(seed)
    cell = 0.05
    z = (cv2.GaussianBlur(rng.standard_normal((N, N)), (0, 0), 40) * 40
         + cv2.GaussianBlur(rng.standard_normal((N, N)), (0, 0), 8) * 1.5)
    hazard = np.zeros((N, N), np.uint8)
    while hazard.mean() < 0.015:
        r, c = (int(v) for v in rng.integers(0, N, 2))
        cv2.circle(hazard, (c, r), int(rng.integers(1, 6)), 1, -1)
    slope = slope_deg(z, cell)
    return cost_map(slope, (hazard > 0) | (slope > 20.0), cell, 20.0)


def _changes(rng: np.random.Generator, m: dict, k: np.ndarray, path: np.ndarray, what: str | int
             ) -> tuple[np.ndarray, np.ndarray]:
    """Cells and new costs for one cycle, ahead of the rover on ``path``."""
    cell = m["cell"]
    if what == "rock":  # a rock 0.25 m in radius on the path 3 m ahead
        steps = np.hypot(*np.diff(path, axis=0).T) * cell
        i = int(np.searchsorted(np.cumsum(steps), 3.0))
        i = min(i, len(path) - 2)
        rr = int(math.ceil((0.25 + ROVER) / cell + 1))
        r0, c0 = path[i]
        dr, dc = np.mgrid[-rr:rr + 1, -rr:rr + 1]
        disc = np.hypot(dr, dc) * cell <= 0.25 + ROVER + cell * math.sqrt(2) / 2
        cells = np.stack([r0 + dr[disc], c0 + dc[disc]], axis=1)
        cells = cells[(cells >= 0).all(axis=1) & (cells < N).all(axis=1)]
        return cells, np.full(len(cells), np.inf)
    n = int(what)
    lo, hi = int(2.0 / cell), int(6.0 / cell)
    centre = path[min(len(path) - 1, int(rng.integers(min(lo, len(path) - 1), max(min(hi, len(path)), lo + 1))))]
    spread = max(1.0, math.sqrt(n))  # a patch as big as the change, around a cell near the path
    cells = np.clip(np.rint(centre + rng.normal(0, spread, (n, 2)) + rng.integers(-10, 11, 2)), 0, N - 1)
    cells = cells.astype(np.int64)
    base = k[cells[:, 0], cells[:, 1]]
    base = np.where(np.isfinite(base), base, WEIGHT + (1 - WEIGHT) * 0.5)  # a freed cell: moderate ground
    vals = np.where(rng.random(n) < 0.3, np.inf, base * rng.uniform(0.5, 2.0, n))
    return cells, np.maximum(vals, WEIGHT)  # never below the cost floor w (inf stays inf)


def run(m: dict, what: str | int, trials: int, seed: int, advance: int = 6) -> dict:
    """``trials`` cycles of drive ``advance`` cells -> change -> repair, against a fresh A*."""
    rng = np.random.default_rng(seed)
    t_d, t_a, e_d, e_a, fails, checked, restarts = [], [], [], [], 0, 0, 0
    opts = {"orth": m["cell"], "diag": m["cell"] * math.sqrt(2)}
    planner = k = path = None
    while len(t_d) < trials:
        left = float(np.hypot(*np.diff(path, axis=0).T).sum()) * m["cell"] if planner is not None else 0.0
        if planner is None or len(path) <= advance + 2 or left < 4.0:  # (re)start the mission
            restarts += planner.restarts if planner is not None else 0
            k = m["k"].copy()  # (the planner's own restarts counted, before it is replaced)
            planner = IncrementalPlanner(k, m["start"], m["goal"], h_scale=WEIGHT, **opts)
            path = planner.plan().cells
        start = tuple(int(v) for v in path[advance])
        planner.move_start(start)
        if what == "move":
            cells = np.zeros((0, 2), np.int64)
            vals = np.zeros(0)
        else:
            cells, vals = _changes(rng, m, k, path[advance:], what)
            keep = ~((cells[:, 0] == m["goal"][0]) & (cells[:, 1] == m["goal"][1]))
            keep &= ~((cells[:, 0] == start[0]) & (cells[:, 1] == start[1]))
            cells, vals = cells[keep], vals[keep]
        k[cells[:, 0], cells[:, 1]] = vals
        t0 = time.perf_counter()
        planner.update(cells, vals)
        try:
            res = planner.plan()
        except PlanningError:
            res = None
        t1 = time.perf_counter()
        try:
            ref = astar_grid(k, start, m["goal"], **opts)
        except PlanningError:
            ref = None
        t2 = time.perf_counter()
        if (res is None) != (ref is None):
            raise AssertionError(f"D* Lite and A* disagree on reachability ({what})")
        if res is None:  # the change enclosed the rover or the goal: timed (both searched their whole
            fails += 1  # region to prove it), then a new mission
            t_d.append(t1 - t0)
            t_a.append(t2 - t1)
            restarts += planner.restarts
            planner = None
            continue
        if not math.isclose(res.cost, ref.cost, rel_tol=1e-9):
            raise AssertionError(f"D* Lite cost {res.cost} != A* cost {ref.cost} ({what})")
        checked += 1
        t_d.append(t1 - t0)
        t_a.append(t2 - t1)
        e_d.append(res.expanded)
        e_a.append(ref.expanded)
        path = res.cells
    restarts += planner.restarts if planner is not None else 0
    t_d_ms, t_a_ms = np.array(t_d) * 1e3, np.array(t_a) * 1e3
    return {"d50": np.percentile(t_d_ms, 50), "d99": np.percentile(t_d_ms, 99), "dmax": t_d_ms.max(),
            "a50": np.percentile(t_a_ms, 50), "a99": np.percentile(t_a_ms, 99),
            "e_d": int(np.median(e_d)), "e_a": int(np.median(e_a)), "checked": checked, "enclosed": fails,
            "restarts": restarts}
