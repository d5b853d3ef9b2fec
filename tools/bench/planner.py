"""Benchmark: the planner's A* against pyastar2d (C++) and scipy.sparse.csgraph.dijkstra, side by
side in one process, on 1000 x 1000 and 2000 x 2000 cost grids with 20 % obstacles (random
discs, seeded). Target: at most 1.5x pyastar2d's time.

Same costs and heuristic for the comparison: pyastar2d charges the weight (>= 1) of the cell a
step enters, diagonal or not, allows cutting corners, and uses the Chebyshev distance as H. The
planner's kernel runs that model (``share=0, orth=diag=1, corner_rule=False,
heuristic="chebyshev", h_scale=1``) and the path costs are checked to agree. The planner's own
model (averaged cells, sqrt(2) diagonals, no corner cutting, octile H) is timed too, and
Dijkstra runs on the pyastar2d-model graph (graph construction timed separately).

    python -m tools.bench.planner [--sizes 1000 2000] [--repeats 5] [--no-dijkstra]
"""

from __future__ import annotations

import argparse
import statistics
import time

import cv2
import numpy as np
from scipy import ndimage
from scipy.sparse.csgraph import dijkstra

from prox_workflows.algorithms.astar import astar_grid, grid_graph, warm_up
from rvs_params.jit import HAVE_NUMBA


def cost_grid(n: int, seed: int = 0, obstacles: float = 0.2) -> tuple[np.ndarray, tuple[int, int], tuple[int, int]]:
    """Weights 1..5 (a smooth random field), inf on random discs covering ``obstacles`` of the
    grid; start and goal are the free cells of the largest free region nearest two opposite
    corners."""
    rng = np.random.default_rng(seed)
    field = cv2.GaussianBlur(rng.random((n, n)).astype(np.float32), (0, 0), n / 125)
    weights = 1 + 4 * (field - field.min()) / (field.max() - field.min())
    blocked = np.zeros((n, n), np.uint8)
    while blocked.mean() < obstacles:
        for _ in range(200):
            r, c = (int(v) for v in rng.integers(0, n, 2))
            cv2.circle(blocked, (c, r), int(rng.integers(2, max(3, n // 100))), 1, -1)
    labels, _ = ndimage.label(blocked == 0, structure=np.ones((3, 3)))
    largest = np.argmax(np.bincount(labels.ravel())[1:]) + 1
    free = labels == largest
    weights = np.where(free, weights, np.inf).astype(np.float32)
    rows, cols = np.nonzero(free)
    s, g = np.argmin(rows + cols), np.argmax(rows + cols)
    return weights, (int(rows[s]), int(cols[s])), (int(rows[g]), int(cols[g]))


def timed(repeats: int, fn, *args, **kwargs) -> tuple[list[float], object]:
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn(*args, **kwargs)
        times.append(time.perf_counter() - t0)
    return times, out


def interleaved(repeats: int, runs: dict) -> dict[str, tuple[list[float], object]]:
    """Each contender once per round, so a change of load on a shared machine hits all alike."""
    results: dict[str, tuple[list[float], object]] = {name: ([], None) for name in runs}
    for _ in range(repeats):
        for name, (fn, args, kwargs) in runs.items():
            t0 = time.perf_counter()
            out = fn(*args, **kwargs)
            results[name] = (results[name][0] + [time.perf_counter() - t0], out)
    return results


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1000, 2000])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--no-dijkstra", action="store_true")
    args = ap.parse_args(argv)
    try:
        import pyastar2d
    except ImportError:
        print("pyastar2d is not installed: pip install pyastar2d")
        return 2
    t0 = time.perf_counter()
    warm_up()
    print(f"numba: {HAVE_NUMBA}; kernel compile or cache load: {time.perf_counter() - t0:.2f} s (excluded below)")
    print(f"best (median) of {args.repeats} runs; ratio = best time / pyastar2d's best time")
    worst = 0.0
    for n in args.sizes:
        weights, start, goal = cost_grid(n)
        w64 = weights.astype(np.float64)
        print(f"\n{n} x {n}: {np.isinf(weights).mean() * 100:.1f} % obstacles, start {start}, goal {goal}")
        res = interleaved(args.repeats, {
            "py": (pyastar2d.astar_path, (weights, start, goal), {"allow_diagonal": True}),
            "us": (astar_grid, (w64, start, goal), {"heuristic": "chebyshev", "orth": 1, "diag": 1, "share": 0,
                                                    "corner_rule": False, "h_scale": 1.0}),
            "own": (astar_grid, (w64, start, goal), {"heuristic": "octile"}),
        })
        (t_py, p), (t_us, ours), (t_own, own) = res["py"], res["us"], res["own"]
        cost_py = float(w64[p[1:, 0], p[1:, 1]].sum())
        base = min(t_py)
        rows = [("pyastar2d (C++)", t_py, cost_py, len(p), None),
                ("planner, pyastar2d's model", t_us, ours.cost, len(ours.cells), ours.expanded),
                ("planner, own model (octile)", t_own, own.cost, len(own.cells), own.expanded)]
        if not args.no_dijkstra:
            t_graph, graph = timed(1, grid_graph, w64, orth=1, diag=1, share=0, corner_rule=False)
            s_idx, g_idx = start[0] * n + start[1], goal[0] * n + goal[1]
            t_dij, dist = timed(1, dijkstra, graph, indices=s_idx)
            rows.append(("scipy dijkstra (+ graph build)", [t_dij[0] + t_graph[0]], float(dist[g_idx]), None, None))
            rows.append(("scipy dijkstra alone", t_dij, float(dist[g_idx]), None, None))
            del graph
        print(f"{'':32} {'best s':>8} {'median s':>9} {'ratio':>6} {'path cost':>14} {'points':>7} {'expanded':>9}")
        for name, times, cost, npts, expanded in rows:
            print(f"{name:32} {min(times):8.3f} {statistics.median(times):9.3f} {min(times) / base:6.2f} "
                  f"{cost:14.4f} {npts if npts else '':>7} {expanded if expanded else '':>9}")
        agree = abs(ours.cost - cost_py) <= 1e-5 * cost_py
        print(f"path costs agree (planner vs pyastar2d, rel 1e-5): {agree} "
              f"(difference {ours.cost - cost_py:+.6f})")
        ratio = min(t_us) / base
        worst = max(worst, ratio)
        print(f"planner / pyastar2d: {ratio:.2f} (target <= 1.5): {'met' if ratio <= 1.5 else 'NOT met'}")
    return 0 if worst <= 1.5 else 1


if __name__ == "__main__":
    raise SystemExit(main())
