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

from prox_workflows.algorithms.astar import astar_grid
from prox_workflows.algorithms.astar import warm_up as astar_warm_up
from prox_workflows.algorithms.replan import IncrementalPlanner
from prox_workflows.algorithms.replan import warm_up as replan_warm_up
from rvs_truth.replan import WEIGHT, N, cost_map, run, sim_map, slope_deg

DTM = Path(__file__).resolve().parents[2] / ".." / "shared" / "realdata" / "dem" / "mars_dtm.npy"


def hirise_map() -> dict:
    """The real Mars DTM: its central 70 x 70 m, upsampled to N x N."""
    dtm = np.load(DTM).astype(np.float64)
    r0 = (dtm.shape[0] - dtm.shape[1]) // 2
    crop = dtm[r0:r0 + dtm.shape[1], :]
    cell = 1.01 * crop.shape[0] / N
    z = cv2.resize(crop, (N, N), interpolation=cv2.INTER_CUBIC)
    slope = slope_deg(z, cell)
    return cost_map(slope, slope > 45.0, cell, 45.0)


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
