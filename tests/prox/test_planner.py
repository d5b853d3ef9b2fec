"""A* on cost grids: optimal against scipy's Dijkstra on the same graph, heuristics, weights,
corner rule, determinism, and the plain-Python kernel against the compiled one."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from prox_workflows.algorithms.astar import SQRT2, PlanningError, astar_grid, grid_graph

OFFSETS = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]


def reference_graph(k: np.ndarray, cell: float = 1.0) -> coo_matrix:
    """The 8-connected graph written out edge by edge (independent of the planner's code):
    step cost = length * (k[u] + k[v]) / 2, no diagonal between two blocked orthogonal cells."""
    h, w = k.shape
    free = np.isfinite(k)
    rows, cols, vals = [], [], []
    for r in range(h):
        for c in range(w):
            if not free[r, c]:
                continue
            for dr, dc in OFFSETS:
                rr, cc = r + dr, c + dc
                if not (0 <= rr < h and 0 <= cc < w) or not free[rr, cc]:
                    continue
                if dr and dc and not (free[r + dr, c] and free[r, c + dc]):
                    continue
                length = cell * (math.sqrt(2) if dr and dc else 1.0)
                rows.append(r * w + c)
                cols.append(rr * w + cc)
                vals.append(max(length * (k[r, c] + k[rr, cc]) / 2, 1e-300))
    return coo_matrix((vals, (rows, cols)), shape=(h * w, h * w)).tocsr()


def random_map(rng: np.random.Generator, n: int = 100, obstacles: float | None = None) -> np.ndarray:
    w = rng.uniform(0.0, 1.0)
    c = rng.uniform(0.0, 2.0, (n, n))
    if rng.random() < 0.5:  # smooth costs as well as white noise
        import cv2

        c = cv2.GaussianBlur(c, (0, 0), 3) * 2
    k = w + (1 - w) * c
    frac = rng.uniform(0.05, 0.35) if obstacles is None else obstacles
    k[rng.random((n, n)) < frac] = np.inf
    return k


def check_path(k: np.ndarray, cells: np.ndarray, g: np.ndarray, cell: float = 1.0) -> None:
    """Each step is an 8-neighbour move onto a free cell, never cuts a blocked corner, and the
    cost so far grows by exactly the step's cost."""
    free = np.isfinite(k)
    assert free[cells[:, 0], cells[:, 1]].all()
    assert g[0] == 0.0
    for (r0, c0), (r1, c1), g0, g1 in zip(cells[:-1], cells[1:], g[:-1], g[1:], strict=True):
        dr, dc = r1 - r0, c1 - c0
        assert max(abs(dr), abs(dc)) == 1
        if dr and dc:
            assert free[r0 + dr, c0] and free[r0, c0 + dc]
        length = cell * (math.sqrt(2) if dr and dc else 1.0)
        assert g1 - g0 == pytest.approx(length * (k[r0, c0] + k[r1, c1]) / 2, rel=1e-12, abs=1e-12)


def test_reference_graph_matches_grid_graph() -> None:
    rng = np.random.default_rng(5)
    k = random_map(rng, 12, 0.3)
    a = reference_graph(k, 0.2)
    b = grid_graph(k, orth=0.2, diag=0.2 * SQRT2)
    assert a.nnz == b.nnz
    assert np.allclose(a.toarray(), b.toarray(), rtol=1e-14, atol=0)


def test_astar_cost_equals_dijkstra_on_200_random_maps() -> None:
    rng = np.random.default_rng(2024)
    compared = unreachable = 0
    for trial in range(200):
        n = 100
        k = random_map(rng, n)
        free = np.flatnonzero(np.isfinite(k))
        s, t = rng.choice(free, 2, replace=False)
        start, goal = divmod(int(s), n), divmod(int(t), n)
        heuristic = ("octile", "euclidean")[trial % 2]
        ref = dijkstra(grid_graph(k), indices=int(s), directed=True)[int(t)]
        if not np.isfinite(ref):
            with pytest.raises(PlanningError) as err:
                astar_grid(k, start, goal, heuristic=heuristic)
            assert err.value.reason == "enclosed"
            unreachable += 1
            continue
        path = astar_grid(k, start, goal, heuristic=heuristic)
        assert path.cost == pytest.approx(ref, rel=1e-6)
        assert tuple(path.cells[0]) == start and tuple(path.cells[-1]) == goal
        check_path(k, path.cells, path.g)
        compared += 1
    assert compared > 150 and unreachable > 0  # both outcomes exercised


def test_dijkstra_reference_is_the_independent_graph() -> None:
    # a few maps against the edge-by-edge graph, so grid_graph itself is not trusted blindly
    rng = np.random.default_rng(11)
    for _ in range(5):
        k = random_map(rng, 40, 0.2)
        free = np.flatnonzero(np.isfinite(k))
        s, t = (int(v) for v in rng.choice(free, 2, replace=False))
        ref = dijkstra(reference_graph(k, 0.1), indices=s)[t]
        if np.isfinite(ref):
            got = astar_grid(k, divmod(s, 40), divmod(t, 40), orth=0.1, diag=0.1 * SQRT2).cost
            assert got == pytest.approx(ref, rel=1e-9)


def test_weight_one_on_an_empty_map_is_the_octile_distance() -> None:
    k = np.ones((60, 80))  # w = 1: k = 1 everywhere whatever the slope
    for goal in [(59, 79), (0, 79), (37, 5), (10, 60)]:
        path = astar_grid(k, (3, 2), goal, orth=0.05, diag=0.05 * SQRT2)
        dr, dc = abs(goal[0] - 3), abs(goal[1] - 2)
        octile = 0.05 * (max(dr, dc) - min(dr, dc) + SQRT2 * min(dr, dc))
        assert path.cost == pytest.approx(octile, rel=1e-12)
        length = np.hypot(*np.diff(path.cells, axis=0).T).sum() * 0.05
        assert length == pytest.approx(octile, rel=1e-12)


def test_weight_trades_distance_against_environmental_cost() -> None:
    """As w grows the optimal path gets shorter and its environmental cost larger (never the
    other way round): the weighted-sum trade-off of seed 000 sect. 3.1.7."""
    rng = np.random.default_rng(3)
    import cv2

    c = cv2.GaussianBlur(rng.uniform(0, 3, (80, 80)), (0, 0), 6) * 3
    c[c < np.percentile(c, 15)] = 0.0  # cheap valleys
    blocked = rng.random((80, 80)) < 0.1
    blocked[:3, :3] = blocked[-3:, -3:] = False
    lengths, envs = [], []
    for w in (0.0, 0.25, 0.5, 0.75, 1.0):
        k = np.where(blocked, np.inf, w + (1 - w) * c)
        path = astar_grid(k, (0, 0), (79, 79))
        steps = np.hypot(*np.diff(path.cells, axis=0).T)
        cu = c[path.cells[:-1, 0], path.cells[:-1, 1]]
        cv = c[path.cells[1:, 0], path.cells[1:, 1]]
        lengths.append(steps.sum())
        envs.append((steps * (cu + cv) / 2).sum())
        assert path.cost == pytest.approx(w * lengths[-1] + (1 - w) * envs[-1], rel=1e-9)
    assert all(a >= b - 1e-9 for a, b in zip(lengths, lengths[1:], strict=False))
    assert all(a <= b + 1e-9 for a, b in zip(envs, envs[1:], strict=False))
    assert lengths[0] > lengths[-1] + 1 and envs[0] < envs[-1]  # the trade-off is real here


def test_heuristics() -> None:
    k = np.full((120, 120), 0.7)
    k[20:100, 60] = np.inf
    res = {h: astar_grid(k, (60, 5), (60, 115), heuristic=h) for h in ("octile", "euclidean")}
    ref = dijkstra(grid_graph(k), indices=60 * 120 + 5)[60 * 120 + 115]
    # admissible ones are optimal; octile, the exact empty-grid distance, expands fewer cells
    assert res["octile"].cost == pytest.approx(ref, rel=1e-12)
    assert res["euclidean"].cost == pytest.approx(ref, rel=1e-12)
    assert res["octile"].expanded < res["euclidean"].expanded
    # manhattan overestimates diagonal moves: never better than optimal, often dearer, greedier
    rng = np.random.default_rng(7)
    worse = fewer = compared = 0
    for _ in range(30):
        k = random_map(rng, 60)
        free = np.flatnonzero(np.isfinite(k))
        s, t = (int(v) for v in rng.choice(free, 2, replace=False))
        best = dijkstra(grid_graph(k), indices=s)[t]
        if not np.isfinite(best):
            continue
        man = astar_grid(k, divmod(s, 60), divmod(t, 60), heuristic="manhattan")
        octile = astar_grid(k, divmod(s, 60), divmod(t, 60), heuristic="octile")
        assert man.cost >= best * (1 - 1e-12)
        assert octile.cost == pytest.approx(best, rel=1e-9)
        worse += man.cost > best * (1 + 1e-9)
        fewer += man.expanded < octile.expanded
        compared += 1
    assert worse > 0 and fewer > compared * 0.8
    # an unscaled heuristic would overestimate where cells are cheap: it is scaled by min k
    k2 = np.full((50, 50), 0.2)
    assert astar_grid(k2, (0, 0), (49, 30)).cost == pytest.approx(
        dijkstra(grid_graph(k2), indices=0)[49 * 50 + 30], rel=1e-12)
    with pytest.raises(ValueError, match="heuristic"):
        astar_grid(k2, (0, 0), (1, 1), heuristic="dijkstra")


def test_no_corner_cutting() -> None:
    k = np.ones((3, 3))
    k[0, 1] = np.inf  # (0,0) -> (1,1) would pass between (0,1) and (1,0)
    path = astar_grid(k, (0, 0), (1, 1))
    assert [tuple(c) for c in path.cells] == [(0, 0), (1, 0), (1, 1)]
    k[1, 0] = np.inf  # both orthogonal cells blocked: no way through the corner
    with pytest.raises(PlanningError) as err:
        astar_grid(k, (0, 0), (1, 1))
    assert err.value.reason == "enclosed"
    # with the rule off (pyastar2d's model) the diagonal is taken
    assert len(astar_grid(k, (0, 0), (1, 1), corner_rule=False).cells) == 2


def test_unreachable_reasons() -> None:
    k = np.ones((20, 20))
    k[5, 5] = np.inf
    k[10:15, 10] = k[10:15, 14] = np.inf
    k[10, 10:15] = k[14, 10:15] = np.inf
    cases = {"goal_in_hazard": ((0, 0), (5, 5)), "start_in_hazard": ((5, 5), (0, 0)),
             "enclosed": ((0, 0), (12, 12)), "outside_maps": ((0, 0), (20, 3))}
    for reason, (s, g) in cases.items():
        with pytest.raises(PlanningError) as err:
            astar_grid(k, s, g)
        assert err.value.reason == reason
        assert err.value.message


def test_start_equals_goal() -> None:
    path = astar_grid(np.ones((4, 4)), (2, 2), (2, 2))
    assert path.cost == 0.0 and [tuple(c) for c in path.cells] == [(2, 2)]


def test_ties_are_broken_deterministically() -> None:
    # an empty uniform grid is all ties; the path must be the same every time, and it prefers
    # cells nearer the goal (it does not wander)
    k = np.ones((200, 200))
    a = astar_grid(k, (0, 0), (150, 199))
    b = astar_grid(k.copy(), (0, 0), (150, 199))
    assert np.array_equal(a.cells, b.cells) and np.array_equal(a.g, b.g)
    assert a.expanded < 2 * len(a.cells)


def test_plain_python_kernel_matches_the_compiled_one() -> None:
    rng = np.random.default_rng(8)
    for trial in range(4):
        k = random_map(rng, 24, 0.25)
        free = np.flatnonzero(np.isfinite(k))
        s, t = (divmod(int(v), 24) for v in rng.choice(free, 2, replace=False))
        h = ("octile", "euclidean", "manhattan", "chebyshev")[trial]
        try:
            fast = astar_grid(k, s, t, heuristic=h)
        except PlanningError as exc:
            with pytest.raises(PlanningError, match=exc.reason):
                astar_grid(k, s, t, heuristic=h, python=True)
            continue
        slow = astar_grid(k, s, t, heuristic=h, python=True)
        assert np.array_equal(fast.cells, slow.cells) and np.array_equal(fast.g, slow.g)
        assert fast.expanded == slow.expanded


def test_pyastar2d_model() -> None:
    """share=0, diagonal = orthogonal = 1, no corner rule, chebyshev: the model the benchmark
    compares with pyastar2d (cost = sum of the entered cells' weights)."""
    rng = np.random.default_rng(4)
    wgt = rng.uniform(1, 5, (50, 50))
    wgt[rng.random((50, 50)) < 0.2] = np.inf
    wgt[0, 0] = wgt[49, 49] = 2.0
    path = astar_grid(wgt, (0, 0), (49, 49), heuristic="chebyshev", orth=1, diag=1, share=0,
                      corner_rule=False, h_scale=1.0)
    ref = dijkstra(grid_graph(wgt, orth=1, diag=1, share=0, corner_rule=False), indices=0)[-1]
    assert path.cost == pytest.approx(ref, rel=1e-12)
    assert path.cost == pytest.approx(wgt[path.cells[1:, 0], path.cells[1:, 1]].sum(), rel=1e-12)


def test_bad_cost_grids_are_refused() -> None:
    with pytest.raises(ValueError):
        astar_grid(np.array([[1.0, np.nan]]), (0, 0), (0, 1))
    with pytest.raises(ValueError):
        astar_grid(np.array([[1.0, -1.0]]), (0, 0), (0, 1))
