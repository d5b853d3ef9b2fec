"""D* Lite (prox_workflows.algorithms.replan) against a fresh A* on the same map: equal path cost on
static random maps and after random batches of changes and start moves, the same errors, valid
paths (free cells, 8-neighbour steps, no cut corners), and repairs that expand few cells."""

from __future__ import annotations

import math
import os
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from prox_workflows.algorithms.astar import SQRT2, PlanningError, astar_grid
from prox_workflows.algorithms.replan import IncrementalPlanner

HEURISTICS = ("octile", "euclidean", "chebyshev")


def outcome(fn, *args, **kwargs) -> tuple[str, object]:
    try:
        return "ok", fn(*args, **kwargs)
    except PlanningError as exc:
        return exc.reason, None


def check_valid(k: np.ndarray, path, start, goal, corner_rule: bool = True) -> None:
    cells = path.cells
    assert tuple(cells[0]) == tuple(start) and tuple(cells[-1]) == tuple(goal)
    free = np.isfinite(k)
    assert free[cells[:, 0], cells[:, 1]].all(), "path crosses a blocked cell"
    steps = np.diff(cells, axis=0)
    assert (np.abs(steps).max(axis=1) == 1).all() if len(steps) else True
    if corner_rule:
        for (r0, c0), (dr, dc) in zip(cells[:-1], steps, strict=True):
            if dr and dc:
                assert free[r0 + dr, c0] and free[r0, c0 + dc], "path cuts a blocked corner"
    assert len({(int(r), int(c)) for r, c in cells}) == len(cells), "path visits a cell twice"


def same(a: tuple[str, object], b: tuple[str, object]) -> None:
    assert a[0] == b[0]
    if a[0] == "ok":
        ca, cb = a[1].cost, b[1].cost
        assert ca == pytest.approx(cb, rel=1e-9, abs=1e-9)


def random_map(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    weight = rng.uniform(0.0, 1.0)
    c = rng.uniform(0.0, 2.0, (h, w))
    if rng.random() < 0.3:
        c[rng.random((h, w)) < 0.3] = 0.0  # flat cells: zero cost with weight 0
        weight = 0.0 if rng.random() < 0.5 else weight
    k = weight + (1 - weight) * c
    k[rng.random((h, w)) < rng.uniform(0.0, 0.4)] = np.inf
    return k


def random_options(rng: np.random.Generator, trial: int) -> dict:
    cell = float(rng.choice([1.0, 0.05, 0.2]))
    return {"heuristic": HEURISTICS[trial % 3], "share": float(rng.choice([0.5, 0.0, 0.3, 1.0])),
            "orth": cell, "diag": cell * SQRT2, "corner_rule": bool(trial % 5 != 0)}


def random_cell(rng: np.random.Generator, shape: tuple[int, int]) -> tuple[int, int]:
    return int(rng.integers(0, shape[0])), int(rng.integers(0, shape[1]))


def test_static_maps_cost_equals_astar() -> None:
    rng = np.random.default_rng(12)
    kinds = {"ok": 0, "enclosed": 0, "start_in_hazard": 0, "goal_in_hazard": 0}
    for trial in range(150):
        shape = (int(rng.integers(1, 30)), int(rng.integers(1, 30)))
        k = random_map(rng, *shape)
        opts = random_options(rng, trial)
        start = random_cell(rng, shape)
        goal = start if trial % 10 == 0 else random_cell(rng, shape)
        ref = outcome(astar_grid, k, start, goal, **opts)
        got = outcome(IncrementalPlanner(k, start, goal, **opts).plan)
        same(got, ref)
        kinds[got[0]] += 1
        if got[0] == "ok":
            check_valid(k, got[1], start, goal, opts["corner_rule"])
    assert min(kinds.values()) > 0, kinds  # every outcome exercised


def test_repairs_after_random_changes_and_moves_equal_fresh_astar() -> None:
    rng = np.random.default_rng(7)
    repairs = 0
    for trial in range(60):
        shape = (int(rng.integers(5, 35)), int(rng.integers(5, 35)))
        k = random_map(rng, *shape)
        opts = random_options(rng, trial)
        start, goal = random_cell(rng, shape), random_cell(rng, shape)
        k[start] = k[goal] = 1.0
        planner = IncrementalPlanner(k, start, goal, **opts)
        for _ in range(8):
            m = int(rng.integers(1, 15))
            cells = np.stack([rng.integers(0, shape[0], m), rng.integers(0, shape[1], m)], axis=1)
            u = rng.random(m)
            vals = np.where(u < 0.3, np.inf, np.where(u < 0.5, 1.0, rng.uniform(0.0, 3.0, m)))
            planner.update(cells, vals)
            k[cells[:, 0], cells[:, 1]] = vals
            if rng.random() < 0.5:  # the rover moves: along its path, or anywhere (slip)
                got = outcome(planner.plan)
                if got[0] == "ok" and rng.random() < 0.7:
                    start = tuple(int(v) for v in got[1].cells[min(len(got[1].cells) - 1, 3)])
                else:
                    start = random_cell(rng, shape)
                planner.move_start(start)
            ref = outcome(astar_grid, k, start, goal, **opts)
            got = outcome(planner.plan)
            same(got, ref)
            if got[0] == "ok":
                check_valid(k, got[1], start, goal, opts["corner_rule"])
            repairs += 1
            assert planner.start == start and np.array_equal(planner.cost, k)
    assert repairs == 480


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(3, 16),
       ops=st.lists(st.tuples(st.sampled_from(["block", "free", "cost", "move"]), st.integers(0, 255),
                              st.floats(0.0, 4.0)), min_size=1, max_size=12))
def test_any_sequence_of_changes_and_moves(seed: int, n: int, ops: list) -> None:
    rng = np.random.default_rng(seed)
    k = random_map(rng, n, n)
    start, goal = (0, 0), (n - 1, n - 1)
    k[start] = k[goal] = 1.0
    opts = random_options(rng, seed % 15)
    planner = IncrementalPlanner(k, start, goal, **opts)
    for kind, where, value in ops:
        cell = divmod(where % (n * n), n)
        if kind == "move":
            start = cell
            planner.move_start(cell)
        else:
            v = {"block": math.inf, "free": 1.0, "cost": value}[kind]
            planner.update([cell], [v])
            k[cell] = v
        got = outcome(planner.plan)
        same(got, outcome(astar_grid, k, start, goal, **opts))
        if got[0] == "ok":
            check_valid(k, got[1], start, goal, opts["corner_rule"])


def test_repair_expands_few_cells_and_an_unchanged_plan_none() -> None:
    rng = np.random.default_rng(3)
    k = 0.5 + 0.5 * rng.uniform(0, 1, (120, 120))
    planner = IncrementalPlanner(k, (5, 5), (110, 110), h_scale=0.5)
    first = planner.plan()
    assert planner.plan().expanded == 0  # nothing changed: nothing to do
    r, c = first.cells[40]
    planner.move_start((r, c))
    moved = planner.plan()
    assert moved.expanded <= 2
    assert moved.cost == pytest.approx(first.cost - first.g[40], rel=1e-9)
    blocked = first.cells[80]
    planner.update([blocked], [np.inf])  # a cell on the path ahead
    k[tuple(blocked)] = np.inf
    repaired = planner.plan()
    fresh = astar_grid(k, (r, c), (110, 110))
    assert repaired.cost == pytest.approx(fresh.cost, rel=1e-9)
    assert repaired.expanded < fresh.expanded / 5


def test_update_map_passes_on_only_the_changes() -> None:
    k = np.ones((20, 30))
    planner = IncrementalPlanner(k, (0, 0), (19, 29))
    planner.plan()
    k2 = k.copy()
    k2[5:15, 10] = np.inf
    k2[3, 3] = 2.0
    assert planner.update_map(k2) == 11
    assert planner.plan().cost == pytest.approx(astar_grid(k2, (0, 0), (19, 29)).cost, rel=1e-12)
    assert planner.update_map(k2) == 0


def test_costs_beyond_the_units_restart_and_stay_right() -> None:
    k = np.full((15, 15), 1.0)
    planner = IncrementalPlanner(k, (0, 0), (14, 14))
    planner.plan()
    planner.update([(7, 7), (7, 6)], [1e6, 1e6])  # > 64x the dearest cost at construction
    k[7, 7] = k[7, 6] = 1e6
    assert planner.restarts == 1
    assert planner.plan().cost == pytest.approx(astar_grid(k, (0, 0), (14, 14)).cost, rel=1e-9)
    planner.update([(3, 3)], [0.1])  # below the heuristic's weight: it would overestimate
    k[3, 3] = 0.1
    assert planner.restarts == 2
    assert planner.plan().cost == pytest.approx(astar_grid(k, (0, 0), (14, 14)).cost, rel=1e-9)


def test_cost_to_go_is_the_remaining_path_cost() -> None:
    rng = np.random.default_rng(9)
    k = random_map(rng, 25, 25)
    k[0, 0] = k[24, 24] = 1.0
    planner = IncrementalPlanner(k, (0, 0), (24, 24))
    try:
        path = planner.plan()
    except PlanningError:
        pytest.skip("seed gives an enclosed map")
    ctg = planner.cost_to_go(path.cells, exact=False)
    assert ctg == pytest.approx(path.cost - path.g, rel=1e-9, abs=1e-9)
    cells = np.stack([rng.integers(0, 25, 30), rng.integers(0, 25, 30)], axis=1)
    exact = planner.cost_to_go(cells)  # any cell, as if the rover stood there
    for (r, c), got in zip(cells, exact, strict=True):
        ref = outcome(astar_grid, k, (r, c), (24, 24))
        assert got == (pytest.approx(ref[1].cost, rel=1e-9, abs=1e-9) if ref[0] == "ok" else np.inf)
    assert planner.start == (0, 0)
    assert planner.plan().cost == pytest.approx(path.cost, rel=1e-12)  # the planner is where it was


def test_deterministic_and_errors() -> None:
    rng = np.random.default_rng(1)
    k = random_map(rng, 30, 30)
    k[0, 0] = k[29, 29] = 1.0
    a = outcome(IncrementalPlanner(k, (0, 0), (29, 29)).plan)
    b = outcome(IncrementalPlanner(k, (0, 0), (29, 29)).plan)
    assert a[0] == b[0] and (a[0] != "ok" or np.array_equal(a[1].cells, b[1].cells))
    with pytest.raises(ValueError, match="manhattan"):
        IncrementalPlanner(k, (0, 0), (1, 1), heuristic="manhattan")
    with pytest.raises(ValueError):
        IncrementalPlanner(np.full((3, 3), np.nan), (0, 0), (1, 1))
    with pytest.raises(PlanningError) as err:
        IncrementalPlanner(k, (0, 0), (30, 0))
    assert err.value.reason == "outside_maps"
    planner = IncrementalPlanner(k, (0, 0), (29, 29))
    with pytest.raises(PlanningError):
        planner.move_start((-1, 0))
    with pytest.raises(ValueError):
        planner.update([(0, 0)], [-1.0])


def test_plain_python_kernels_agree() -> None:
    """Without numba (NUMBA_DISABLE_JIT: the kernels run as plain Python) the same results."""
    code = (
        "import numpy as np\n"
        "from prox_workflows.algorithms.replan import IncrementalPlanner\n"
        "from prox_workflows.algorithms.astar import astar_grid\n"
        "rng = np.random.default_rng(4)\n"
        "for _ in range(5):\n"
        "    k = 0.5 + rng.uniform(0, 1, (12, 12)); k[rng.random((12, 12)) < 0.2] = np.inf\n"
        "    k[0, 0] = k[11, 11] = 1.0\n"
        "    p = IncrementalPlanner(k, (0, 0), (11, 11))\n"
        "    try:\n"
        "        c = p.plan().cost\n"
        "    except Exception as e:\n"
        "        c = type(e).__name__\n"
        "    p.update([(5, 5), (6, 6)], [np.inf, 3.0]); k[5, 5] = np.inf; k[6, 6] = 3.0\n"
        "    try:\n"
        "        a, d = astar_grid(k, (0, 0), (11, 11)).cost, p.plan().cost\n"
        "        assert abs(a - d) < 1e-9, (a, d)\n"
        "    except Exception as e:\n"
        "        assert type(e).__name__ == 'PlanningError', e\n"
        "print('ok')\n")
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "ok"


def test_benchmark_runs_and_agrees_with_astar_on_400_cells() -> None:
    """The replanning benchmark's cycle (rvs_truth.replan: drive, change ahead, repair) on its
    simulated 400 x 400 map: it raises if a repaired cost ever differs from the fresh A*'s."""
    from rvs_truth.replan import run, sim_map

    m = sim_map(1)
    for what in (10, "rock", "move"):
        r = run(m, what, trials=3, seed=1)
        assert r["checked"] + r["enclosed"] == 3 and r["e_d"] < r["e_a"] / 5  # cells, not (loaded) seconds


def test_plan_path_with_the_replanner_equals_astar_and_repairs() -> None:
    """plan_path with a Replanner (the see loop's D* Lite) gives A*'s path cost on the same maps
    while rocks appear on the way and the rover moves on; with the mission's box as ``cover``
    the planning grid keeps its geometry, so only the first plan is a whole search."""
    from prox_workflows.algorithms.planner import HAZARDOUS, NavMaps, PlannerParams, plan_path
    from prox_workflows.algorithms.replan import Replanner
    from prox_workflows.grid import GridGeometry

    geom = GridGeometry(0.05, 0.0, 6.0, 200, 120)  # x 0..10, y 0..6
    hz = np.zeros(geom.shape, np.uint8)
    slope = np.full(geom.shape, 3.0, np.float32)
    xs, ys = geom.centers()
    params = PlannerParams(rover_radius=0.3, margin=0.1, border=0.0, unknown_cost=math.inf)
    replanner = Replanner(params.heuristic, params.weight)
    start, goal = (1.0, 3.0), (9.0, 3.0)
    cover = [(-1.0, -1.0), (11.0, 7.0)]
    rng = np.random.default_rng(4)
    for _ in range(5):
        maps = NavMaps(hz.copy(), slope, geom)
        fresh = plan_path(maps, None, start, goal, params, cover=cover)
        repaired = plan_path(maps, None, start, goal, params, search=replanner, cover=cover)
        assert repaired.cost_so_far[-1] == pytest.approx(fresh.cost_so_far[-1], rel=1e-9)
        assert repaired.image.geometry == fresh.image.geometry
        # a rock appears on the way, 1.5-2.5 m ahead, and the rover drives 0.5 m on
        ahead = fresh.path[min(len(fresh.path) - 1, int(rng.integers(30, 50)))]
        rock = (np.hypot(xs[None, :] - ahead[0], ys[:, None] - ahead[1] - rng.uniform(-0.2, 0.2)) <= 0.25)
        hz[rock] = HAZARDOUS
        start = tuple(fresh.path[10])
    assert replanner.searches == 1 and replanner.repairs == 4 and replanner.changed > 0
