"""Benchmark: incremental replanning (D* Lite, :mod:`prox_workflows.algorithms.replan`) against a fresh
A* (:func:`prox_workflows.algorithms.astar.astar_grid`) on the same changed 400 x 400 map, side by
side in one process: the see loop needs its replans in milliseconds.

Two maps, both as the planner sees them (cost per metre ``k = w + (1 - w) * slope / critical``,
hazards grown by rover radius + margin + half a cell diagonal, blocked):

- ``sim``: 20 x 20 m at 0.05 m, a smooth random terrain with rocks (seeded), like the simulator's;
- ``hirise``: the real HiRISE Mars DTM crop (``../shared/realdata/dem/mars_dtm.npy``, 1.01 m
  cells), its central 70 x 70 m upsampled (bicubic) to 400 x 400 cells of 0.177 m; slopes over
  45 deg are hazards (its median slope is 21 deg, so the costs vary everywhere).

The rover drives the current path (a few cells per cycle, ``move_start``); each cycle the map
changes ahead of it, where its sensors look (within the next 2-6 m of the path): ``k`` cells
(k = 1, 10, 100: blocked 30 %, otherwise dearer or cheaper 0.5-2x), or a rock of 0.25 m radius
(grown by the margin: a few hundred cells blocked) appearing on the path 3 m ahead; or only the
start moves. Timed: D* Lite's ``update`` + ``plan`` (the repair), and ``astar_grid`` from the
same start on the same changed map; the costs are checked to agree. Ratio = A* p50 / D* p50.

    python -m tools.bench.replan [--trials 60] [--seed 0] [--maps sim hirise]
"""

from __future__ import annotations

import argparse
import math
import os
import time
from pathlib import Path

import cv2
import numpy as np
from scipy import ndimage

from prox_workflows.algorithms.astar import PlanningError, astar_grid
from prox_workflows.algorithms.astar import warm_up as astar_warm_up
from prox_workflows.algorithms.replan import IncrementalPlanner
from prox_workflows.algorithms.replan import warm_up as replan_warm_up

N = 400
WEIGHT = 0.5
ROVER = 0.3 + 0.1  # rover radius + margin, m
DTM = Path(__file__).resolve().parents[2] / ".." / "shared" / "realdata" / "dem" / "mars_dtm.npy"


def _grow(hazard: np.ndarray, cell: float) -> np.ndarray:
    """Blocked cells: within rover radius + margin + half a cell diagonal of a hazard (plan_maps.py)."""
    d = cv2.distanceTransform(np.where(hazard, 0, 255).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return d * cell <= ROVER + cell * math.sqrt(2) / 2


def _slope_deg(z: np.ndarray, cell: float) -> np.ndarray:
    gy, gx = np.gradient(z.astype(np.float64), cell)
    return np.degrees(np.arctan(np.hypot(gx, gy)))


def _finish(slope: np.ndarray, hazard: np.ndarray, cell: float, critical: float) -> dict:
    blocked = _grow(hazard, cell)
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
    slope = _slope_deg(z, cell)
    return _finish(slope, (hazard > 0) | (slope > 20.0), cell, 20.0)


def hirise_map() -> dict:
    """The real Mars DTM: its central 70 x 70 m, upsampled to N x N."""
    dtm = np.load(DTM).astype(np.float64)
    r0 = (dtm.shape[0] - dtm.shape[1]) // 2
    crop = dtm[r0:r0 + dtm.shape[1], :]
    cell = 1.01 * crop.shape[0] / N
    z = cv2.resize(crop, (N, N), interpolation=cv2.INTER_CUBIC)
    slope = _slope_deg(z, cell)
    return _finish(slope, slope > 45.0, cell, 45.0)


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


def first_plan(m: dict, repeats: int = 5) -> dict:
    """The first plan of a mission: D* Lite has nothing to repair and searches as A* does."""
    opts = {"orth": m["cell"], "diag": m["cell"] * math.sqrt(2)}
    td, ta = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        p = IncrementalPlanner(m["k"], m["start"], m["goal"], h_scale=WEIGHT, **opts)
        r = p.plan()
        t1 = time.perf_counter()
        a = astar_grid(m["k"], m["start"], m["goal"], **opts)
        t2 = time.perf_counter()
        assert math.isclose(r.cost, a.cost, rel_tol=1e-9)
        td.append(t1 - t0)
        ta.append(t2 - t1)
    d, a_ = np.array(td) * 1e3, np.array(ta) * 1e3
    return {"d50": np.median(d), "d99": d.max(), "dmax": d.max(), "a50": np.median(a_), "a99": a_.max(),
            "e_d": r.expanded, "e_a": a.expanded, "checked": repeats, "enclosed": 0, "restarts": 0}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", type=int, default=60, help="replans per scenario and map")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--maps", nargs="+", default=["sim", "hirise"], choices=["sim", "hirise"])
    args = ap.parse_args(argv)
    astar_warm_up()
    replan_warm_up()
    maps = {}
    if "sim" in args.maps:
        maps["sim"] = sim_map(args.seed)
    if "hirise" in args.maps:
        if DTM.exists():
            maps["hirise"] = hirise_map()
        else:
            print(f"(no {DTM}: hirise rows skipped)")
    for name, m in maps.items():
        print(f"{name}: {N} x {N} cells of {m['cell']:.3f} m, {100 * m['blocked']:.0f} % blocked, "
              f"start {m['start']} -> goal {m['goal']}")
    scenarios: list[tuple[str, str | int | None]] = [("first plan", None), ("k=1", 1), ("k=10", 10),
                                                     ("k=100", 100), ("rock 3 m ahead", "rock"),
                                                     ("start move", "move")]
    head = (f"{'map':<7} {'update':<15} {'D* p50':>8} {'D* p99':>8} {'D* max':>8} {'A* p50':>8} {'A* p99':>8} "
            f"{'A*/D*':>7} {'exp D*':>7} {'exp A*':>7} {'n':>4}")
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores (a shared machine: compare the ratio)")
    print()
    print("times in ms per replan (D*: update + plan; A*: astar_grid on the changed map), expanded cells p50")
    print(head)
    print("-" * len(head))
    for label, what in scenarios:
        for name, m in maps.items():
            r = first_plan(m) if what is None else run(m, what, args.trials, args.seed)
            ratio = r["a50"] / r["d50"] if r["d50"] > 0 else float("inf")
            print(f"{name:<7} {label:<15} {r['d50']:8.2f} {r['d99']:8.2f} {r['dmax']:8.2f} {r['a50']:8.2f} "
                  f"{r['a99']:8.2f} {ratio:7.1f} {r['e_d']:7d} {r['e_a']:7d} {r['checked']:4d}"
                  + (f"  ({r['enclosed']} enclosed: new mission)" if r["enclosed"] else "")
                  + (f"  ({r['restarts']} restarts)" if r["restarts"] else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
