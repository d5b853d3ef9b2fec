"""The vehicle check's compiled pass (prox_workflows.algorithms._vehicle_kernel) against its
definitions written as whole-batch numpy (tools.bench.vehicle_check.reference) on the scenes' true
1 cm surfaces and on bounds of them; and how it reads a bounds map: each sample takes the bounds
of the cell that holds it, and every cell under the body holds a sample."""

from __future__ import annotations

import numpy as np
import pytest
from support.marks import long_only

from drivers.sim.rover import RoverBody
from drivers.sim.world import World
from prox_workflows.algorithms.vehicle import BOUNDS_STEP, LIMITS, _pattern, _sample, check_poses, gate_poses
from prox_workflows.grid import GridGeometry
from rvs_truth.surface import truth_surface
from tools.bench.vehicle_check import bounds_of, disagreement, reference, scene_poses

BODY = RoverBody()
ROCK = 0.25  # m: far over the belly's 8 cm and the wheel's 10 cm climb


@pytest.mark.parametrize("scene", ["marsyard", *(pytest.param(s, marks=long_only()) for s in ("hirise", "dense"))])
def test_the_check_is_its_numpy_definition_on_the_true_surface_and_on_bounds(scene: str) -> None:
    world = World.from_scene(scene)
    fine, g, coarse = truth_surface(world, scene)
    poses = scene_poses(scene, 300, seed=7)
    ours, peer = check_poses(fine, g, poses, world.body), reference(fine, g, poses, world.body)
    assert disagreement(ours, peer, world.body) == []
    # the draw meets every limit, safe and unsafe poses alike
    kinds = set(ours.worst(world.body)[0][ours.unsafe].tolist())
    assert 0.1 < ours.safe.mean() < 1.0 and len(kinds) >= 2, (ours.safe.mean(), kinds)
    lower, upper = bounds_of(fine, g, coarse)
    poses = scene_poses(scene, 300, seed=8)
    ours, peer = check_poses((lower, upper), coarse, poses, world.body), reference((lower, upper), coarse, poses,
                                                                                    world.body)
    assert disagreement(ours, peer, world.body) == []
    assert 0.1 < ours.safe.mean() < 1.0


def test_the_check_fills_holes_as_its_definition_does() -> None:
    """Ground off the grid or with no height: the lowest height the pose sees on one grid; on
    bounds, no upper bound makes the pose unknown, no lower bound under half a wheel too."""
    world = World.from_scene("marsyard")
    fine, g, coarse = truth_surface(world, "marsyard")
    rng = np.random.default_rng(3)
    # a 4 x 4 m corner of the scene, so that poses reach over its edges
    crop = fine[:400, :400].copy()
    cg = GridGeometry(g.cell, g.xmin, g.ymax, 400, 400)
    crop[rng.random(crop.shape) < 0.02] = np.nan
    crop[100:140, 200:260] = np.nan
    poses = np.column_stack([rng.uniform(cg.xmin - 0.3, cg.xmin + 4.3, 300), rng.uniform(cg.ymax - 4.3, cg.ymax + 0.3,
                                                                                          300),
                             rng.uniform(-180, 180, 300)])
    ours = check_poses(crop, cg, poses, world.body)
    assert disagreement(ours, reference(crop, cg, poses, world.body), world.body) == []
    lower, upper = bounds_of(fine, g, coarse)
    lower, upper = lower[:80, :80].copy(), upper[:80, :80].copy()
    bg = GridGeometry(coarse.cell, coarse.xmin, coarse.ymax, 80, 80)
    lower[rng.random(lower.shape) < 0.1] = np.nan  # ground a ray passed over: no lower bound
    upper[rng.random(upper.shape) < 0.01] = np.nan  # ground nothing bounds
    lower[20:30, 20:30] = np.nan
    ours = check_poses((lower, upper), bg, poses, world.body)
    assert disagreement(ours, reference((lower, upper), bg, poses, world.body), world.body) == []
    assert 0.1 < ours.unknown.mean() < 0.9


def _flat_bounds(half: float = 1.0, cell: float = 0.05) -> tuple[np.ndarray, np.ndarray, GridGeometry]:
    """Spread-less bounds of flat ground: every cell's lower and upper bound at 0."""
    n = int(round(2 * half / cell))
    return np.zeros((n, n)), np.zeros((n, n)), GridGeometry(cell, -half, half, n, n)


def _cell_of(g: GridGeometry, x: float, y: float) -> tuple[int, int]:
    return int(np.floor((g.ymax - y) / g.cell)), int(np.floor((x - g.xmin) / g.cell))


@pytest.mark.parametrize("part", ["belly", "wheel"])
def test_a_rock_in_one_cell_of_a_bounds_map_is_read_at_its_top_near_the_cells_edge(part: str) -> None:
    """A bounds map's cell bounds every point in it, so a sample anywhere in a rock's cell reads
    the rock's top. Read between cell centres, a 25 cm rock confined to one 5 cm cell and sampled
    near the cell's corner reads as 7.6 cm: under the belly's clearance and the wheel's climb,
    and the pose passed."""
    lower, upper, g = _flat_bounds()
    # at heading 0 the body's samples one cell apart (the spacing a bilinear read used) fall
    # 2.5 mm inside the corners of their cells
    pose = np.array([[0.0025, 0.0375, 0.0]])
    pts = _pattern(BODY, g.cell).pts
    if part == "belly":
        at = pts[np.argmin(np.hypot(pts[:, 0], pts[:, 1]))]  # the box's middle
    else:
        at = pts[np.argmin(np.hypot(pts[:, 0] - 0.145, pts[:, 1] - 0.245))]  # the front-left wheel's hub
    x, y = pose[0, 0] + at[0], pose[0, 1] + at[1]
    r, c = _cell_of(g, x, y)
    lower[r, c] = upper[r, c] = ROCK
    cx, cy = g.xmin + (c + 0.5) * g.cell, g.ymax - (r + 0.5) * g.cell
    assert max(abs(x - cx), abs(y - cy)) == pytest.approx(0.0225, abs=1e-9)  # near the cell's corner
    # the bilinear read there: a share of the rock, under both limits
    assert _sample(upper, g, np.array([x]), np.array([y]))[0] == pytest.approx(ROCK * 0.55**2, abs=1e-9)
    # each sample reads the cell that holds it: the rock's top
    assert _sample(upper, g, np.array([x]), np.array([y]), cellwise=True)[0] == ROCK
    checks = check_poses((lower, upper), g, pose, BODY)
    assert not checks.safe[0] and not checks.unknown[0]
    limit = LIMITS[int(checks.worst(BODY)[0][0])]
    if part == "belly":  # over wheels resting on flat ground (their circles sampled up to 1.75 cm off
        # the hubs rest up to a millimetre low)
        assert limit == "belly" and 0.0 <= checks.intrusion[0] - (ROCK - BODY.clearance) < 0.001
    else:
        assert limit == "step" and checks.step[0, 0] == pytest.approx(ROCK, abs=1e-9)
    gate = gate_poses(lower, upper, g, pose, BODY)
    assert gate.verdict == "unsafe" and (gate.x, gate.y) == pytest.approx((cx, cy), abs=g.cell / 2)


def test_every_cell_under_the_body_holds_a_sample_at_any_heading() -> None:
    """Samples one cell apart, at 45 deg, leave cells under the box that none falls in: a rock
    there is unseen. The check samples bounds every BOUNDS_STEP cells, which leaves none."""
    lower, upper, g = _flat_bounds()
    pose = np.array([[0.013, -0.021, 45.0]])
    pts = _pattern(BODY, g.cell).pts
    c, s = np.cos(np.radians(45.0)), np.sin(np.radians(45.0))
    held = {_cell_of(g, pose[0, 0] + c * px - s * py, pose[0, 1] + s * px + c * py) for px, py in pts}
    # a cell wholly under the box (its corners within 20 cm of the middle) that holds no sample
    xs, ys = g.centers()
    empty = [(r, k) for r, y in enumerate(ys) for k, x in enumerate(xs)
             if np.hypot(x - pose[0, 0], y - pose[0, 1]) < 0.2 - g.cell * 0.75 and (r, k) not in held]
    assert empty
    r, k = empty[0]
    lower[r, k] = upper[r, k] = ROCK
    assert check_poses((lower, upper), g, pose, BODY, step=g.cell).safe[0]  # missed one cell apart
    checks = check_poses((lower, upper), g, pose, BODY)
    assert not checks.safe[0] and 0.0 <= checks.intrusion[0] - (ROCK - BODY.clearance) < 0.001
    assert BOUNDS_STEP < 2**-0.5
