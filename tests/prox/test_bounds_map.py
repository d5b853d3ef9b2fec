"""The bounds map keeps, per cell, a lower and an upper bound on the ground's height, and never
claims a bound it has no measurement for: returns bound a cell both ways, a ray that passed over
a cell bounds it from above only, and a cell nothing saw has no bound at all. Repeated looks
tighten the bounds; a look that disagrees (a rock dropped in) widens them to cover both."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.sim.world import World
from prox_workflows.algorithms.bounds_map import BoundsMap, BoundsParams
from prox_workflows.algorithms.noise import tof_height_variance, tof_sigma
from prox_workflows.grid import GridGeometry
from tools.bench.bounds import tof_frame

SENSOR = np.array([0.0, 0.0, 1.2])


def _ground(rng: np.random.Generator, n: int, rock: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Returns from flat ground at z = 0 over x 1..2 m, y -0.5..0.5 m, with a 0.2 m square block
    of height ``rock`` at x 1.4..1.6, y -0.1..0.1; range noise along each ray, as a ToF has."""
    x, y = rng.uniform(1.0, 2.0, n), rng.uniform(-0.5, 0.5, n)
    z = np.where((np.abs(x - 1.5) < 0.1) & (np.abs(y) < 0.1), rock, 0.0)
    pts = np.column_stack([x, y, z])
    d = pts - SENSOR
    r = np.linalg.norm(d, axis=1)
    noisy = pts + d / r[:, None] * (tof_sigma(r) * rng.standard_normal(n))[:, None]
    return noisy, np.sqrt(tof_height_variance(noisy, SENSOR))


def _map() -> BoundsMap:
    return BoundsMap(GridGeometry(0.025, 0.0, 1.0, 100, 80), BoundsParams())


def _changing() -> BoundsMap:
    """A map that drops what it held round ground a frame finds changed (``changed`` 5 cm)."""
    return BoundsMap(GridGeometry(0.025, 0.0, 1.0, 100, 80), BoundsParams(changed=0.05))


def _cells(m: BoundsMap, x0: float, x1: float, y0: float, y1: float) -> tuple[slice, slice]:
    g = m.geometry
    return (slice(int(round((g.ymax - y1) / g.cell)), int(round((g.ymax - y0) / g.cell))),
            slice(int(round((x0 - g.xmin) / g.cell)), int(round((x1 - g.xmin) / g.cell))))


def _look(m: BoundsMap, world: World, rng: np.random.Generator, pan: float, across: bool = True) -> None:
    """One ToF frame of ``world`` at ``pan`` into ``m`` (:func:`support.tof_looks.tof_frame`)."""
    f = tof_frame(world, rng, pan, across)
    m.fuse(f["points"], f["sigma"], f["origin"], *f["args"], **f["kwargs"])


def _hirise_looks(reach: float) -> tuple[World, BoundsMap]:
    """The hirise world and a bounds map of three ToF looks (pans -40 / 0 / +40, tilt -35) over
    the ground out to ``reach`` metres ahead, each frame with the range noise it is told of."""
    world = World.from_scene("hirise", seed=1)
    rng = np.random.default_rng(0)
    m = BoundsMap.covering([[-1.0, -3.0], [reach, 3.0]], 0.0)
    for pan in (-40.0, 0.0, 40.0):
        _look(m, world, rng, pan, across=False)
    return world, m


def test_returns_bound_the_ground_both_ways_and_more_looks_tighten_the_bounds() -> None:
    rng = np.random.default_rng(1)
    m = _map()
    m.fuse(*_ground(rng, 40_000))
    flat = _cells(m, 1.05, 1.95, -0.45, 0.45)
    lower, upper = m.lower[flat], m.upper[flat]
    assert np.isfinite(upper).all() and np.isfinite(lower).all()
    # k = 2.5 sigmas: a Gaussian mean stays inside on 99.4 % of cells per side
    assert np.mean(upper >= 0.0) > 0.99 and np.mean(lower <= 0.0) > 0.99
    width_one = float(np.median(upper - lower))
    for _ in range(8):
        m.fuse(*_ground(rng, 40_000))
    lower, upper = m.lower[flat], m.upper[flat]
    assert np.mean(upper >= 0.0) > 0.99 and np.mean(lower <= 0.0) > 0.99
    width_nine = float(np.median(upper - lower))
    assert width_nine < 0.5 * width_one  # nine looks: the mean's sigma falls by three
    assert width_nine < 0.02


def test_the_mean_s_horizontal_error_along_its_rays_averages_as_its_height_does() -> None:
    """One return's horizontal error along its ray is 2 cm; a cell's mean of n returns is off along
    the ray by 2 cm / sqrt(n), and two frames of equal weight halve that variance again: what the
    chance check weighs the slope with (``along_var``), where ``shift`` keeps one return's."""
    m = BoundsMap(GridGeometry(0.05, 0.0, 1.0, 20, 20), BoundsParams())
    xs = np.repeat(0.525 + 0.05 * np.arange(4), 16)  # 16 returns in each of 4 cells along a row
    pts = np.column_stack([xs + np.tile(np.linspace(-0.02, 0.02, 16), 4), np.full(64, 0.525), np.zeros(64)])
    origin = np.array([-1.0, 0.525, 1.0])
    m.fuse(pts, 0.01, origin, sigma_xy=0.02, sigma_across=0.005)
    stats, _ = m.statistics(0.51, 0.51, 0.69, 0.54)  # the row of 4 cells
    np.testing.assert_allclose(stats["along_var"], np.full((1, 4), 0.02**2 / 16), rtol=1e-5)
    np.testing.assert_allclose(stats["shift"], np.full((1, 4), m.params.k * 0.02), rtol=1e-5)  # one return's, as before
    m.fuse(pts, 0.01, origin, sigma_xy=0.02, sigma_across=0.005)
    stats, _ = m.statistics(0.51, 0.51, 0.69, 0.54)
    np.testing.assert_allclose(stats["along_var"], np.full((1, 4), 0.02**2 / 32), rtol=1e-5)
    beside, _ = m.statistics(0.51, 0.56, 0.69, 0.59)  # the row north of it: no return there
    assert np.isnan(beside["mean"]).all() and (beside["along_var"] == 0).all()


def test_a_rock_reads_at_its_top_and_a_later_look_at_a_new_rock_widens_the_cell_or_drops_what_was_round_it() -> None:
    rng = np.random.default_rng(2)
    m = _map()
    for _ in range(4):
        m.fuse(*_ground(rng, 40_000, rock=0.12))
    top = _cells(m, 1.42, 1.58, -0.08, 0.08)
    assert (m.upper[top] >= 0.12).mean() > 0.99 and (m.lower[top] <= 0.12).mean() > 0.99
    assert float(np.median(m.upper[top])) < 0.14  # the top, not a wall of doubt over it
    # a rock where the map saw flat ground: with the rule off (``changed`` 0) the cells cover both stories
    m1 = BoundsMap(GridGeometry(0.025, 0.0, 1.0, 100, 80), BoundsParams(changed=0.0))
    for _ in range(4):
        m1.fuse(*_ground(rng, 40_000))
    m1.fuse(*_ground(rng, 40_000, rock=0.12))
    assert (m1.upper[top] >= 0.12).mean() > 0.99 and (m1.lower[top] <= 0.0).mean() > 0.99
    # with ``changed`` (the default, for frames placed on the map's ground): the ground changed, and
    # its cells take the new frame's word alone
    m2 = _changing()
    for _ in range(4):
        m2.fuse(*_ground(rng, 40_000))
    m2.fuse(*_ground(rng, 40_000, rock=0.12))
    inner = _cells(m2, 1.45, 1.55, -0.05, 0.05)  # (the edge cells' bounds spread to the ground beside)
    assert (m2.upper[top] >= 0.12).mean() > 0.99 and (m2.lower[inner] > 0.06).all()
    # the new frame seeing only the rock and what lies past it: the ground the map held on the
    # near side within stale_radius (0.3 m) of the rock is unknown (the rock's flank may reach
    # there), the ground farther off keeps its bounds
    m3 = _changing()
    for _ in range(4):
        m3.fuse(*_ground(rng, 40_000))
    pts, sig = _ground(rng, 40_000, rock=0.12)
    far = pts[:, 0] >= 1.4
    m3.fuse(pts[far], sig[far])
    assert (m3.upper[top] >= 0.12).mean() > 0.99
    assert np.isnan(m3.upper[_cells(m3, 1.15, 1.35, -0.1, 0.1)]).all()
    assert np.isfinite(m3.upper[_cells(m3, 1.0, 1.05, -0.4, 0.4)]).all()
    assert np.isfinite(m3.upper[_cells(m3, 1.2, 1.35, 0.45, 0.5)]).all()  # beside it, farther than 0.3 m
    # frames that disagree by less (a rock's edge read from another side) are fused as before
    m4 = _changing()
    for _ in range(4):
        m4.fuse(*_ground(rng, 40_000))
    seen = np.isfinite(m4.upper)
    m4.fuse(*_ground(rng, 40_000, rock=0.04))
    assert (m4.lower[top] <= 0.0).mean() > 0.99 and np.isfinite(m4.upper[seen]).all()



def _level(rng: np.random.Generator, z: float, noise: float, n: int = 40_000) -> np.ndarray:
    """Returns over x 1..2 m, y -0.5..0.5 m at height ``z`` with independent noise ``noise``."""
    return np.column_stack([rng.uniform(1.0, 2.0, n), rng.uniform(-0.5, 0.5, n), z + noise * rng.standard_normal(n)])


def test_a_stereo_frames_pixels_in_a_cell_share_one_error() -> None:
    # a stereo frame reads flat ground at z = 0 two of its pixels' sigmas low, all its pixels alike
    # (they share the matcher's window): its ~16 pixels a cell are one measurement, not sixteen
    rng = np.random.default_rng(3)
    sigma = 0.003
    frame = _level(rng, -2 * sigma, 0.0002)
    flat = _cells(_map(), 1.05, 1.95, -0.45, 0.45)
    as_stereo, as_independent = _map(), _map()
    as_stereo.fuse(frame, sigma, sensor="stereo")
    as_independent.fuse(frame, sigma)
    assert (as_stereo.upper[flat] >= 0.0).all()  # -6 mm + 2.5 x 3 mm
    assert (as_independent.upper[flat] < 0.0).all()  # -6 mm + 2.5 x 3 mm / 4: the truth out
    assert float(np.median(as_stereo.upper[flat] - as_stereo.lower[flat])) < 0.02
    with pytest.raises(ValueError, match="sensor 'lidar' is not one of tof, stereo"):
        _map().fuse(frame, sigma, sensor="lidar")


def test_a_stereo_frame_fuses_with_the_tofs_by_default_and_stands_alone_with_stereo_first() -> None:
    rng = np.random.default_rng(4)
    tof, stereo = _level(rng, 0.004, 0.006), _level(rng, 0.0, 0.0005)
    flat = _cells(_map(), 1.05, 1.95, -0.45, 0.45)
    alone = _map()
    alone.fuse(stereo, 0.002, sensor="stereo")
    # by default the ToF's mean pulls the stereo's bounds up by a third of its offset
    fused = _map()
    fused.fuse(tof, 0.006)
    fused.fuse(stereo, 0.002, sensor="stereo")
    assert float(np.median(fused.lower[flat] - alone.lower[flat])) > 0.0005
    first = BoundsMap(_map().geometry, BoundsParams(stereo_first=True))
    first.fuse(tof, 0.006)
    first.fuse(stereo, 0.002, sensor="stereo")
    first.fuse(_level(rng, 0.004, 0.006), 0.006)  # a later ToF frame changes nothing there
    assert np.array_equal(first.upper[flat], alone.upper[flat]) and np.array_equal(first.lower[flat], alone.lower[flat])
    assert (first.sensors[flat] == 2).all()  # the stereo's bit alone


def _patch(rng: np.random.Generator, z: float, n: int = 2_000) -> np.ndarray:
    """Returns over the 3 x 3 cells x 1.5..1.575 m, y 0..0.075 m at height ``z``: fewer cells than
    a changed ground needs (``changed_cells``), so they are fused, not taken as a rock come."""
    return np.column_stack([rng.uniform(1.5, 1.575, n), rng.uniform(0.0, 0.075, n), z + 0.0005 * rng.standard_normal(n)])


def test_where_a_pair_and_the_tof_disagree_the_tofs_reading_stands() -> None:
    # a pair's mismatch at a rock's edge reads 12 cm high (and elsewhere 8 cm low) over ground the
    # ToF read flat: kept as the union, the cell's top stood 12 cm over the ground
    rng = np.random.default_rng(5)
    tof = _level(rng, 0.0, 0.004)
    patch = _cells(_map(), 1.5, 1.575, 0.0, 0.075)
    flat = _cells(_map(), 1.05, 1.45, -0.45, -0.05)
    high, low = _patch(rng, 0.12), _patch(rng, -0.08) - [0.0, 0.2, 0.0]
    low_cells = _cells(_map(), 1.5, 1.575, -0.2, -0.125)
    level = _level(rng, 0.0, 0.0005)
    level = level[~((np.abs(level[:, 0] - 1.54) < 0.05) & (np.abs(level[:, 1] + 0.06) < 0.15))]
    maps = {rule: BoundsMap(_map().geometry, BoundsParams(disagree=rule)) for rule in ("tof_stands", "pair_yields", "union")}
    for m in maps.values():
        m.fuse(tof, 0.004)
    alone = maps["tof_stands"].mean_var.copy()
    for m in maps.values():
        m.fuse(np.vstack([level, high, low]), 0.002, sensor="stereo")
    for rule in ("tof_stands", "pair_yields"):  # either way the pair leaves what the ToF bounded
        assert (maps[rule].upper[patch] < 0.02).all() and (maps[rule].lower[low_cells] > -0.02).all()
        assert (maps[rule].mean_var[flat] < alone[flat]).all()  # agreeing: fused
        assert (maps[rule].sensors[flat] == 3).all() and (maps[rule].sensors[patch] == 1).all()
    assert (maps["union"].upper[patch] > 0.12).all() and (maps["union"].lower[low_cells] < -0.08).all()
    # a ToF frame disagreeing with what only a pair said replaces it with tof_stands; the union
    # with the other two
    tof_only = _map()
    tof_only.fuse(tof, 0.004)
    for rule in ("tof_stands", "pair_yields", "union"):
        m = BoundsMap(_map().geometry, BoundsParams(disagree=rule))
        m.fuse(high, 0.002, sensor="stereo")
        m.fuse(tof, 0.004)
        if rule == "tof_stands":
            assert np.array_equal(m.upper[patch], tof_only.upper[patch]) and (m.sensors[patch] == 1).all()
        else:
            assert (m.upper[patch] > 0.12).all() and (m.sensors[patch] == 3).all()


def test_where_frames_disagree_the_map_keeps_how_far_apart_their_stories_stand() -> None:
    # a pair reads a patch 12 cm over the ground the ToF read flat: the union's top stands on the
    # pair's story, and the split says the ToF's stands 12 cm under it; frames that agree since fade it
    rng = np.random.default_rng(5)
    patch = _cells(_map(), 1.5, 1.575, 0.0, 0.075)
    flat = _cells(_map(), 1.05, 1.45, -0.45, -0.05)
    m = _map()
    m.fuse(_level(rng, 0.0, 0.004), 0.004)
    m.fuse(np.vstack([_level(rng, 0.0, 0.0005), _patch(rng, 0.12)]), 0.002, sensor="stereo")
    assert m.split[patch] == pytest.approx(0.12, abs=0.01) and m.split[flat].max() == 0.0
    st, _ = m.statistics(1.0, -0.5, 2.0, 0.5)
    assert st["split"].max() == pytest.approx(m.split[patch].max())
    before = m.split[patch].copy()
    for _ in range(3):
        m.fuse(_level(rng, 0.0, 0.004), 0.004)
    agreed = m.split[patch] < before
    assert agreed.any() and (m.split[patch] <= before).all()


def test_a_ray_over_a_cell_bounds_it_from_above_only_and_unseen_cells_have_no_bound() -> None:
    m = _map()
    ret = np.array([[2.0, -0.005, 0.0], [2.005, -0.01, 0.0]])  # two returns 2 m out; its ray passes over x 0..1.94, 0.5 m up at 1.17
    m.fuse(ret, 0.005, SENSOR)
    r, c = m.geometry.cell_of(np.array([1.5]), np.array([0.0]))
    cell = (int(r[0]), int(c[0]))
    assert m.upper[cell] == pytest.approx(1.2 * (1 - 1.5 / 2.0) + 2.5 * 0.005, abs=0.02)
    high = m.geometry.cell_of(np.array([0.5]), np.array([0.0]))  # the ray 0.9 m up: no use, not walked
    assert np.isnan(m.upper[int(high[0][0]), int(high[1][0])])
    assert np.isnan(m.lower[cell])  # a ray says nothing of a hole beneath it
    assert m.bounded()[cell]
    off = m.geometry.cell_of(np.array([1.5]), np.array([0.5]))
    assert np.isnan(m.upper[int(off[0][0]), int(off[1][0])])  # nothing passed there
    assert not m.bounded()[int(off[0][0]), int(off[1][0])]
    # the cell of the returns is bounded by them, not by their rays
    rr, rc = m.geometry.cell_of(np.array([2.0]), np.array([-0.005]))
    # (and the grain: the relief within the cell no return met)
    assert m.upper[int(rr[0]), int(rc[0])] == pytest.approx(2.5 * 0.005 / np.sqrt(2) + m.params.grain, abs=1e-3)
    # a lone return gives no bounds: read long or short it may belong to another cell
    lone = _map()
    lone.fuse(np.array([[1.5, 0.2, 0.0]]), 0.005, SENSOR)
    lr, lc = lone.geometry.cell_of(np.array([1.5]), np.array([0.2]))
    assert np.isnan(lone.lower[int(lr[0]), int(lc[0])])


def test_the_simulated_tof_frames_bound_the_true_surface_where_a_footprint_reads_them() -> None:
    """On the hirise scene the returns of three ToF looks bound the true highest ground of a cell
    on 99.5 % of the cells they reached, though a return read long lands on a rock's flank with
    the ground's height (each cell spreads its bounds by its returns' horizontal error), and the
    bounds sit close: the median upper bound within 5 cm of the top."""
    world, m = _hirise_looks(5.0)
    g = m.geometry
    fine = world.true_dem(0.005, (g.xmin, g.ymin, g.xmax, g.ymax))
    f = 5
    true_top = fine.reshape(g.height, f, g.width, f).max(axis=(1, 3))
    seen = np.isfinite(m.mean)
    assert seen.sum() > 12_000
    upper = m.upper
    assert np.mean(true_top[seen] <= upper[seen]) > 0.995
    assert float(np.median(upper[seen] - true_top[seen])) < 0.05
    # each cell on its own returns alone (no spread) does not hold
    own = m.mean + m.rise + m.params.k * np.sqrt(m.mean_var)
    assert np.mean(true_top[seen] <= own[seen]) < 0.97


def _flat(half: float = 1.0, cell: float = 0.02) -> tuple[np.ndarray, GridGeometry]:
    n = int(round(2 * half / cell))
    return np.zeros((n, n), np.float32), GridGeometry(cell, -half, half, n, n)


def test_the_vehicle_check_on_equal_bounds_is_the_check_on_the_surface() -> None:
    """One code path: bounds that pin the ground give what the ground itself gives where both are
    read alike. A bounds cell bounds every point in it, so a sample reads the cell that holds it;
    a height grid is read between its cell centres: at poses whose samples fall on the centres
    (the body sampled every cell, square to the grid) the two reads are one."""
    from drivers.sim.rover import RoverBody
    from prox_workflows.algorithms.vehicle import check_poses

    h, g = _flat()
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    h += np.where(np.hypot(X - 0.15, Y - 0.25) < 0.06, 0.12, 0.0).astype(np.float32)  # under a wheel
    h += np.where(np.hypot(X + 0.05, Y) < 0.08, 0.1, 0.0).astype(np.float32)  # under the belly
    # the body's samples lie every 2 cm from (-0.255, -0.29): these put them on the 2 cm centres
    poses = np.array([[0.005, 0.0, 0.0], [0.3, -0.195, 90.0], [-0.305, 0.3, 180.0]])
    one = check_poses(h, g, poses, RoverBody())
    pair = check_poses((h, h.copy()), g, poses, RoverBody(), step=g.cell)
    for name in ("step", "intrusion", "tilt", "tip", "grade", "excess"):
        np.testing.assert_allclose(getattr(pair, name), getattr(one, name), atol=1e-9, err_msg=name)
    assert one.unsafe[0] and not pair.unknown.any()


def test_the_vehicle_check_on_bounds_takes_the_worst_and_never_calls_unseen_ground_safe() -> None:
    from drivers.sim.rover import RoverBody
    from prox_workflows.algorithms.vehicle import check_poses

    body = RoverBody()
    h, g = _flat()
    pose = np.array([[0.0, 0.0, 0.0]])
    # flat ground known to +-2 cm: the worst edge a wheel may meet is 4 cm, the belly may find the
    # ground 2 cm up over wheels resting 2 cm down, the body may lean by the wheels' spread, and
    # the ground under it may slope as steeply as any ground within the bounds does
    lower, upper = h - 0.02, h + 0.02
    worst = check_poses((lower, upper), g, pose, body)
    np.testing.assert_allclose(worst.step[0], 0.04, atol=1e-6)
    xs, ys = g.centers()
    X, _ = np.meshgrid(xs, ys)
    halves = np.where(X > 0, 0.02, -0.02).astype(np.float32)  # one ground the bounds allow
    assert worst.grade[0] >= check_poses(halves, g, pose, body).grade[0] > 1.0
    # the belly: 4 cm over the level plane, more where the worst plane leans away under it
    assert 0.04 - body.clearance - 1e-6 <= worst.intrusion[0] < 0.0
    assert worst.tilt[0] > 0.0 and worst.safe[0]
    # ground under the belly nothing saw: not safe, whatever else is known
    upper[45:55, 45:55] = np.nan
    hidden = check_poses((lower, upper), g, pose, body)
    assert hidden.unknown[0] and not hidden.safe[0]
    assert not check_poses(h, g, pose, body).unknown[0]  # a surface has no unseen ground


def test_the_four_limits_on_bounds_that_pin_the_ground_within_3mm() -> None:
    """The synthetic answers of tests/prox/test_vehicle.py on bounds +-3 mm round the ground: a
    9 cm step edge is climbed and an 11 cm one is not, a 20 deg plane fails the grade, and the
    23 deg pitch with both front wheels on smooth mounds is no unsafe pose."""
    from drivers.sim.rover import RoverBody
    from prox_workflows.algorithms.vehicle import check_poses

    body = RoverBody()
    pose = np.array([[0.0, 0.0, 0.0]])
    for height, bad in ((0.09, False), (0.11, True)):
        h, g = _flat(1.0, 0.01)
        xs, ys = g.centers()
        X, Y = np.meshgrid(xs, ys)
        h[(X >= 0.175) & (Y <= -0.205) & (Y >= -0.35)] = height  # an edge 3 cm ahead of the front-right hub
        checks = check_poses((h - 0.003, h + 0.003), g, pose, body)
        assert checks.step[0, 1] == pytest.approx(height + 0.006, abs=0.002)
        assert bool(checks.unsafe[0]) is bad and checks.excess[0, 0] > 0 if bad else not checks.unsafe[0]
    h, g = _flat(1.0, 0.01)
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    plane = (np.tan(np.radians(20.0)) * X).astype(np.float32)
    checks = check_poses((plane - 0.003, plane + 0.003), g, pose, body)
    assert checks.grade[0] >= 20.0 - 1e-6 and checks.unsafe[0] and checks.excess[0, 3] > 0
    for side in (1, -1):
        d = np.hypot(X - 0.145, Y - side * 0.245)
        h += np.where(d < 0.25, 0.0615 * (1 + np.cos(np.pi * d / 0.25)), 0.0).astype(np.float32)
    checks = check_poses((h - 0.003, h + 0.003), g, pose, body)
    assert 23.0 <= checks.tilt[0] < 25.0 and not checks.unsafe[0] and not checks.unknown[0]


def test_bounds_from_simulated_tof_looks_never_call_an_unsafe_pose_safe() -> None:
    """hirise, three ToF looks: every pose the vehicle check on the true 1 cm surface finds
    unsafe is unsafe or unknown on the bounds map (ACE's rule: no false negative). How many
    truly safe poses the bounds still call safe is the benchmark's figure (tools/bench/bounds.py)."""
    from drivers.sim.rover import RoverBody
    from prox_workflows.algorithms.vehicle import check_poses

    world, m = _hirise_looks(6.0)
    g = m.geometry
    truth = world.true_dem(0.01, (g.xmin, g.ymin, g.xmin + g.width * g.cell, g.ymax))
    tg = GridGeometry(0.01, g.xmin, g.ymax, truth.shape[1], truth.shape[0])
    xs, ys = np.meshgrid(np.arange(1.6, 4.0, 0.1), np.arange(-1.2, 1.25, 0.1))
    poses = np.column_stack([np.repeat(xs.ravel(), 4), np.repeat(ys.ravel(), 4),
                             np.tile([0.0, 45.0, 90.0, 135.0], xs.size)])
    body = RoverBody()
    on_truth = check_poses(truth, tg, poses, body)
    on_bounds = check_poses((m.lower, m.upper), g, poses, body)
    judged = ~on_bounds.unknown
    assert judged.sum() > 100 and (judged & on_truth.unsafe).sum() > 10  # rocks among the judged poses
    assert not (on_truth.unsafe & on_bounds.safe).any()


def test_the_gate_stops_at_the_first_pose_over_a_rock_and_blames_its_top() -> None:
    from drivers.sim.rover import RoverBody
    from prox_workflows.algorithms.vehicle import densify, gate_poses

    body = RoverBody()
    h, g = _flat()
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    lower, upper = h - 0.005, h + 0.005
    poses = densify(np.array([[-0.6, 0.0, 0.0], [0.6, 0.0, 0.0]]), 0.02, body)
    assert gate_poses(lower, upper, g, poses, body).verdict == "safe"
    # a 9 cm rock on the centre line: under the climb, over the belly's 8 cm clearance
    on = np.hypot(X - 0.4, Y) <= 0.04
    lower[on], upper[on] = 0.085, 0.095
    gate = gate_poses(lower, upper, g, poses, body)
    assert (gate.verdict, gate.kind) == ("unsafe", "belly")
    assert gate.describe().startswith("belly +") and gate.describe().endswith(f"at ({gate.x:.2f}, {gate.y:.2f})")
    assert np.hypot(gate.x - 0.4, gate.y) <= 0.05  # the rock's top
    # the first pose whose box reaches the rock: its front edge is at the rock's near side
    assert poses[gate.index, 0] + body.length / 2 == pytest.approx(0.36, abs=0.03)
    # the rock's edge first meets the box: a sample in a rock cell reads its whole upper bound, over
    # the lowest plane the wheels may rest on, the front pair at their lowest (-0.5 cm) and the rear
    # at their highest (+0.5 cm), which at the box's front edge (11 cm before the front hubs) is
    # another 1 cm * 11 / 29 lower: 2.38 cm at most (and a wheel's circle sampled off its hub, a
    # fraction of a millimetre lower)
    assert 0.0 < gate.excess <= 0.095 + 0.005 + 0.01 * 0.11 / 0.29 - body.clearance + 1e-4
    # ground beside the path that no frame saw: the gate does not guess
    lower[on], upper[on] = h[on] - 0.005, h[on] + 0.005
    hole = (np.abs(X - 0.2) <= 0.05) & (np.abs(Y) <= 0.05)
    lower[hole] = upper[hole] = np.nan
    gate = gate_poses(lower, upper, g, poses, body)
    assert gate.verdict == "unknown" and np.hypot(gate.x - 0.2, gate.y) <= 0.1
    assert gate.describe().startswith("unseen ground at (")
    # bounded only by a ray that passed over it, high: not a rock, ground to look at
    upper[hole] = 0.3
    assert gate_poses(lower, upper, g, poses, body).verdict == "unknown"


def test_the_ground_the_rover_stands_on_and_was_set_down_on_is_assessed() -> None:
    from drivers.sim.rover import RoverBody
    from prox_workflows.algorithms.vehicle import check_poses

    body = RoverBody()
    m = BoundsMap.covering([[-1.0, -1.0], [1.0, 1.0]], 0.0)
    pose = np.array([[0.0, 0.0, 30.0]])
    assert check_poses((m.lower, m.upper), m.geometry, pose, body).unknown[0]  # nothing seen
    m.stood((0.0, 0.0, 30.0), 0.02, body)
    here = check_poses((m.lower, m.upper), m.geometry, pose, body)
    assert here.safe[0]  # the pose it stands at passes the worst case
    # the wheels' ground is at the contact, the box's no higher than the belly
    assert np.nanmax(m.upper) <= 0.02 + body.clearance
    turned = check_poses((m.lower, m.upper), m.geometry, np.array([[0.0, 0.0, 90.0]]), body)
    assert turned.unknown[0]  # turning on the spot sweeps ground its body did not cover
    m.set_down((0.0, 0.0), 0.5, 0.02)
    assert check_poses((m.lower, m.upper), m.geometry, np.array([[0.0, 0.0, 90.0]]), body).safe[0]
    # a return already there is kept: what a frame saw outranks the assumption
    m2 = BoundsMap.covering([[-1.0, -1.0], [1.0, 1.0]], 0.0)
    assert m2.fuse(np.array([[0.31, 0.01, 0.2], [0.315, 0.015, 0.2]]), 0.002) == 1
    m2.set_down((0.0, 0.0), 0.5, 0.0)
    r, c = m2.geometry.cell_of(np.array([0.31]), np.array([0.01]))
    assert m2.mean[r[0], c[0]] == pytest.approx(0.2, abs=0.01)


def test_rocks_on_the_bounds_stand_out_of_a_slope_which_alone_flags_nothing() -> None:
    m = BoundsMap.covering([[-1.5, -1.5], [1.5, 1.5]], 0.0)
    g = m.geometry
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    ground = np.tan(np.radians(15.0)) * X  # a 15 deg slope
    m.mean[:] = ground
    m.mean_var[:] = 0.002**2
    assert len(m.rocks((0.0, 0.0), 1.0, 0.08)) == 0
    on = np.hypot(X - 0.5, Y - 0.2) <= 0.06
    m.mean[on] += 0.10  # a 10 cm rock: over the belly's 8 cm
    small = np.hypot(X + 0.5, Y + 0.3) <= 0.06
    m.mean[small] += 0.05  # a 5 cm one: the body passes over it
    found = m.rocks((0.0, 0.0), 1.0, 0.08)
    assert len(found) and np.hypot(found[:, 0] - 0.5, found[:, 1] - 0.2).max() <= 0.08
    assert len(m.rocks((0.0, 0.0), 0.2, 0.08)) == 0  # outside the radius asked


@pytest.mark.parametrize("ground", ["level", "graded", "rocking"])
def test_a_rover_set_down_knows_the_ground_under_its_wheels_from_its_attitude(ground: str) -> None:
    """Set down, the rover's IMU (roll and pitch, 0.1 deg) puts the plane its wheels rest on to a
    few millimetres: no wheel's ground stands above it, and one may hang up to 2.5 cm below (a
    rigid body on four wheels rests on three). On level ground the worst-case check of the pose
    it stands at then reads 7.1 deg, not the 11.4 deg the set-down's 1 cm prior alone allows, and
    its belly clear by 1.5 cm, not 1.0; on a 9 % grade, and with the rear-right wheel over a 2 cm
    dip, the bounds still hold the true tilt."""
    from drivers.sim.rover import RoverBody, resting_attitude
    from prox_workflows.algorithms.bounds_map import contact_plane
    from prox_workflows.algorithms.vehicle import check_poses

    body = RoverBody()
    pose = (0.3, -0.2, 30.0)
    gx, gy = (0.08, -0.05) if ground == "graded" else (0.0, 0.0)
    c, s = np.cos(np.radians(pose[2])), np.sin(np.radians(pose[2]))

    def surface(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        dx, dy = np.asarray(x) - pose[0], np.asarray(y) - pose[1]
        z = gx * dx + gy * dy
        if ground == "rocking":  # a dip under the rear-right wheel
            fx, fy = c * dx + s * dy, -s * dx + c * dy
            z = z - 0.02 * ((np.abs(fx + 0.145) < 0.12) & (np.abs(fy + 0.245) < 0.06))
        return z

    fine = GridGeometry(0.01, -1.0, 1.0, 200, 200)
    xs, ys = fine.centers()
    truth = check_poses(surface(xs[None, :], ys[:, None]).astype(np.float32), fine, np.array([pose]), body)
    roll, pitch = resting_attitude(body, surface, pose)
    if ground != "rocking":
        assert contact_plane(pose[2], roll, pitch) == pytest.approx((gx, gy), abs=1e-6)

    def set_down(attitude: tuple[float, float, float] | None) -> BoundsMap:
        m = BoundsMap.covering([[-1.0, -1.0], [1.0, 1.0]], 0.0)
        plane = None if attitude is None else (pose[0], pose[1], *contact_plane(pose[2], *attitude[:2]))
        m.set_down(pose[:2], 0.82, 0.0, plane=plane)
        m.stood(pose, 0.0, body, attitude)
        return m

    m = set_down((roll + 0.1, pitch - 0.1, 0.1))  # the IMU's error, one sigma each way
    felt = check_poses((m.lower, m.upper), m.geometry, np.array([pose]), body)
    assert felt.safe[0] and truth.tilt[0] <= felt.tilt[0] + 0.2
    if ground == "level":
        prior = set_down(None)  # no attitude: the 1 cm prior under the wheels too
        old = check_poses((prior.lower, prior.upper), prior.geometry, np.array([pose]), body)
        assert old.tilt[0] > 9.5 and old.intrusion[0] > -0.011
        assert felt.tilt[0] < 7.5 and felt.intrusion[0] < -0.014 and old.tilt[0] - felt.tilt[0] > 2.0
    # no wheel's ground above the plane: the upper bound under the front-left hub is the plane's
    hub = (pose[0] + c * 0.145 - s * 0.245, pose[1] + s * 0.145 + c * 0.245)
    r, col = m.geometry.cell_of(np.array([hub[0]]), np.array([hub[1]]))
    plane = contact_plane(pose[2], roll, pitch)
    at = plane[0] * (hub[0] - pose[0]) + plane[1] * (hub[1] - pose[1])
    assert at < m.upper[r[0], col[0]] < at + 0.008 and m.lower[r[0], col[0]] < at - 0.025
    # the ground under the box between the wheels keeps the set-down's prior, on that plane
    r, col = m.geometry.cell_of(np.array([pose[0]]), np.array([pose[1]]))
    assert m.stamp[r[0], col[0]] == 0 and m.upper[r[0], col[0]] == pytest.approx(0.025, abs=2e-3)


def _bits_equal(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and bool((a.view(np.uint32) == b.view(np.uint32)).all())


def test_the_compiled_spread_gives_the_bits_of_the_image_morphology() -> None:
    """The bounds' spread (each cell's top dilated and its bottom eroded over its ellipse, one
    compiled scatter over the seen cells) gives bit for bit what the straightforward form gives (an
    OpenCV dilation and erosion of the whole window per shape of ellipse), on the ToF frames of
    hirise with the rover's wheels and box as a sensor too (cells that spread to no neighbour),
    over the whole map and over a window at its edge."""
    from prox_workflows.algorithms.bounds_map import _spread_shapes
    from tools.bench.choice import reference

    world = World.from_scene("hirise", seed=1)
    rng = np.random.default_rng(0)
    m = BoundsMap.covering([[-1.0, -3.0], [5.0, 3.0]], 0.0)
    for pan in (-40.0, 0.0, 40.0):
        _look(m, world, rng, pan)
    m.stood((0.5, 0.0, 20.0), 0.0, world.body, (1.0, -2.0, 0.5))
    g = m.geometry
    shapes = np.unique(np.where(m.stamp > 0, _spread_shapes(m.spread, m.params.k, g.cell, m.params.max_shift), 0)
                       [np.isfinite(m.mean)])
    assert len(shapes) > 20 and shapes[0] == 0  # many ellipses, and cells that spread to none
    boxes = [(slice(0, g.height), slice(0, g.width)), (slice(g.height // 3, g.height // 2), slice(g.width // 2, g.width))]
    for sl in boxes:
        fast = m.bounds(sl)
        with reference():
            slow = m.bounds(sl)
        assert all(_bits_equal(f, s) for f, s in zip(fast, slow, strict=True))
        assert np.isfinite(fast[1]).sum() > 500


def test_a_frames_sums_per_cell_are_those_of_the_sorted_reduction() -> None:
    """The compiled pass that sums a frame's returns per cell gives what sorting the returns by
    cell and summing each run gives: the same cells and counts, the sums to within float64's
    rounding (numpy sums a run in its own order), on a hazard pair's frame cut at its range, and
    on ToF returns with their errors along and across the rays, some off the grid."""
    from prox_workflows.algorithms.bounds_map import _cell_moments
    from tools.bench.choice import reference_moments
    from tools.bench.hazcam import pair_frames

    pts, sigma, sigma_xy, origin, cut = (np.asarray(v, np.float64) for v in pair_frames("marsyard", 1)[0][:5])
    g = BoundsMap.around(tuple(origin[:2]), 4.0, 0.025).geometry
    rng = np.random.default_rng(3)
    tof, tof_sigma_h = (np.asarray(v, np.float64) for v in _ground(rng, 20_000, rock=0.15))
    frames = [(pts, sigma, sigma_xy, sigma_xy, origin, cut, False, g),
              (tof, tof_sigma_h, 0.01 * tof[:, 0], 0.002 * tof[:, 0], SENSOR, None, True, _map().geometry)]
    for frame in frames:
        fast, slow = _cell_moments(*frame), reference_moments(*frame)
        assert len(fast[0]) > 1_000
        assert np.array_equal(fast[0], slow[0]) and np.array_equal(fast[1], slow[1])
        np.testing.assert_allclose(fast[2], slow[2], rtol=1e-12, atol=1e-15)
    # the cut left out the cells it crosses: fewer cells than all the returns' on the grid
    uncut = _cell_moments(pts, sigma, sigma_xy, sigma_xy, origin, None, False, g)  # (as fuse takes them: float64)
    assert len(uncut[0]) > len(_cell_moments(*frames[0])[0])


def test_the_whole_maps_bounds_kept_between_frames_are_those_computed_whole() -> None:
    """:meth:`BoundsMap.whole` recomputes only where the inputs changed since its last call (the
    frames' cells, the rays' ceilings, the wheels' ground), and what it gives is bit for bit the
    bounds computed over the whole map, after each frame of a look round and a stand."""
    world = World.from_scene("hirise", seed=1)
    rng = np.random.default_rng(0)
    m = BoundsMap.covering([[-1.0, -3.0], [3.0, 3.0]], 3.0)
    g = m.geometry
    whole = (slice(0, g.height), slice(0, g.width))
    computed: list[tuple[slice, slice]] = []
    inner = m._bounds

    def spy(sl: tuple[slice, slice], as_whole: bool) -> tuple[np.ndarray, np.ndarray]:
        computed.append(sl)
        return inner(sl, as_whole)

    m._bounds = spy  # type: ignore[method-assign]
    lower, upper = m.whole()
    assert np.isnan(upper).all()
    for step, pan in enumerate((-40.0, 0.0, 40.0)):
        _look(m, world, rng, pan)
        if step == 1:
            m.stood((0.0, 0.0, 0.0), 0.0, world.body, (0.5, 0.5, 0.3))
        computed.clear()
        kept = m.whole()
        assert len(computed) == 1 and computed[0] != whole  # a part, not the whole map
        assert all(_bits_equal(k, f) for k, f in zip(kept, m.bounds(whole), strict=True))
        assert not kept[1].flags.writeable
    assert np.isfinite(kept[1]).sum() > 10_000
    computed.clear()
    assert m.whole()[1] is kept[1] and not computed  # nothing changed: nothing computed


def test_frames_that_disagree_widen_the_spread_but_not_the_cell_s_relief() -> None:
    # the same flat ground seen twice, the second frame placed 4 cm high (its datum's error): the
    # cells keep the union of both frames' intervals (rise plus drop: centimetres), while the relief
    # each frame sees in them is its returns' own (millimetres), which the chance check's wheel
    # rests on (a rock edge's relief is a frame's own; the frames' disagreement is not the ground's)
    from prox_workflows.algorithms.chance import ChanceParams, posterior

    rng = np.random.default_rng(3)
    m = _map()
    for lift in (0.0, 0.04):
        pts, sig = _ground(rng, 40000)
        m.fuse(pts + np.array([0.0, 0.0, lift]), sig, SENSOR)
    stats, g = m.statistics(1.1, -0.4, 1.9, 0.4)
    seen = np.isfinite(stats["mean"])
    spread = (stats["rise"] + stats["drop"])[seen]
    assert np.median(spread) > 0.03
    assert np.median(stats["relief"][seen]) < 0.005
    post = posterior(stats, g, m.params.k, ChanceParams(within=1.0))
    np.testing.assert_allclose(post.span[seen], stats["relief"][seen], atol=1e-6)


def test_a_frame_is_placed_on_the_ground_the_map_holds_and_a_rock_dropped_since_does_not_move_it() -> None:
    # flat ground seen four times; a frame of it placed 3 cm high (the height read round the
    # rover's centre is not where its camera rides) reads 3 cm over the map, with a 0.2 m rock
    # dropped onto that ground since or without; a frame over ground the map never held, none
    rng = np.random.default_rng(4)
    m = _map()
    for _ in range(4):
        m.fuse(*_ground(rng, 40_000))
    for rock in (0.0, 0.12):
        pts, _sig = _ground(rng, 40_000, rock=rock)
        rise = m.offset(pts + np.array([0.0, 0.0, 0.03]))
        assert rise is not None and abs(rise - 0.03) < 0.002
    elsewhere, _sig = _ground(rng, 40_000)
    assert m.offset(elsewhere + np.array([-1.5, 0.0, 0.0])) is None


def test_a_driving_rover_rests_its_unseen_wheel_on_the_ground_frames_bounded_under_the_others() -> None:
    """While driving, the frames bounded the ground under three wheels but not under the fourth;
    the frame's own height at the centre is 7 cm off (its registration jumped). The body rests on
    the seen wheels' ground tipped by the IMU's attitude, so the fourth wheel's ground is put
    within a centimetre of the truth, and the chance check passes the pose the rover stands on.
    Taken level through the frame's height, as without an attitude, it stands over 5 cm high."""
    from drivers.sim.rover import RoverBody, resting_pose
    from prox_workflows.algorithms.chance import ChanceParams, chance_check, posterior

    body = RoverBody()
    pose = (0.3, -0.2, 30.0)

    def surface(x: np.ndarray, y: np.ndarray) -> np.ndarray:  # a 9 % grade and a 4 cm hummock
        x, y = np.asarray(x, float), np.asarray(y, float)
        return 0.08 * x - 0.05 * y + 0.04 * np.exp(-((x + 0.5) ** 2 + (y - 0.6) ** 2) / 0.02)

    height, roll, pitch = resting_pose(body, surface, pose)
    c, s = np.cos(np.radians(pose[2])), np.sin(np.radians(pose[2]))
    hub = (pose[0] - c * 0.145 + s * 0.245, pose[1] - s * 0.145 - c * 0.245)  # rear-right
    rng = np.random.default_rng(5)
    x, y = rng.uniform(-1.0, 1.0, 200_000), rng.uniform(-1.0, 1.0, 200_000)
    seen = np.hypot(x - hub[0], y - hub[1]) > 0.15  # no return under the rear-right wheel
    pts = np.column_stack([x[seen], y[seen], surface(x[seen], y[seen]) + 0.002 * rng.standard_normal(seen.sum())])
    truth = float(surface(np.array([hub[0]]), np.array([hub[1]]))[0])

    def stood(attitude: tuple[float, float, float] | None) -> tuple[BoundsMap, bool]:
        m = BoundsMap.covering([[-1.0, -1.0], [1.0, 1.0]], 0.0)
        m.fuse(pts, np.full(len(pts), 0.002), np.array([pose[0], pose[1], height + 1.2]))
        m.stood(pose, height + 0.07, body, attitude)
        st, sub = m.statistics(-1.0, -1.0, 1.0, 1.0)
        check = chance_check(posterior(st, sub, m.params.k), sub, np.array([pose]), body, ChanceParams())
        return m, bool(check.safe[0])

    m, safe = stood((roll + 0.1, pitch - 0.1, 0.1))  # the IMU one sigma off
    r, col = m.geometry.cell_of(np.array([hub[0]]), np.array([hub[1]]))
    assert m.stamp[r[0], col[0]] == 0 and np.isfinite(m.mean[r[0], col[0]])  # the body's, not a frame's
    assert truth - 0.004 < m.upper[r[0], col[0]] < truth + 0.01
    assert safe
    level, _ = stood(None)
    assert level.upper[r[0], col[0]] > truth + 0.05


def test_the_ground_under_a_driving_rover_s_box_no_frame_saw_is_the_ground_round_it_below_the_roof() -> None:
    """The frames never saw the ground under the middle of the box (the rover drove onto it). The
    body says only that nothing there reaches the belly; left at that roof, the chance check reads
    the ground just under the belly and refuses the pose the rover stands on. Taken as the framed
    ground under the body lies about the wheels' plane, within its spread, the pose passes, and
    the cells keep the roof over them."""
    from drivers.sim.rover import RoverBody, resting_pose
    from prox_workflows.algorithms.chance import ChanceParams, chance_check, posterior

    body = RoverBody()
    pose = (0.3, -0.2, 30.0)

    def surface(x: np.ndarray, y: np.ndarray) -> np.ndarray:  # a 9 % grade, rough to 5 mm
        x, y = np.asarray(x, float), np.asarray(y, float)
        return 0.08 * x - 0.05 * y + 0.005 * np.sin(17 * x) * np.cos(13 * y)

    height, roll, pitch = resting_pose(body, surface, pose)
    rng = np.random.default_rng(6)
    x, y = rng.uniform(-1.0, 1.0, 200_000), rng.uniform(-1.0, 1.0, 200_000)
    seen = np.hypot(x - pose[0], y - pose[1]) > 0.08  # no return under the middle of the box
    pts = np.column_stack([x[seen], y[seen], surface(x[seen], y[seen]) + 0.002 * rng.standard_normal(seen.sum())])

    def stood(fill_under: bool) -> tuple[BoundsMap, bool]:
        m = BoundsMap.covering([[-1.0, -1.0], [1.0, 1.0]], 0.0)
        m.fuse(pts, np.full(len(pts), 0.002), np.array([pose[0], pose[1], height + 1.2]))
        m.stood(pose, height, body, (roll, pitch, 0.1), fill_under=fill_under)
        st, sub = m.statistics(-1.0, -1.0, 1.0, 1.0)
        check = chance_check(posterior(st, sub, m.params.k), sub, np.array([pose]), body, ChanceParams())
        return m, bool(check.safe[0])

    m, safe = stood(True)
    r, col = m.geometry.cell_of(np.array([pose[0]]), np.array([pose[1]]))
    truth = float(surface(np.array([pose[0]]), np.array([pose[1]]))[0])
    assert m.stamp[r[0], col[0]] == 0 and abs(m.mean[r[0], col[0]] - truth) < 0.01
    assert m.ceiling[r[0], col[0]] < truth + body.clearance and safe
    bare, safe = stood(False)
    assert not np.isfinite(bare.mean[r[0], col[0]]) and not safe


def test_a_turn_on_the_spot_stands_the_body_on_the_ground_it_swept_between_two_frames() -> None:
    """A frame comes before a turn on the spot and after it, none during it. The body swept the
    ground between: standing after a 90 deg turn, it stands at the headings between too, as if a
    frame had come at each, so the turn's corners hold the belly's roof and the ground under it;
    a jump longer than a drive between two frames (a fix) stands nothing between."""
    from drivers.sim.rover import RoverBody
    from prox_workflows.algorithms.bounds_map import attitude_at, contact_plane, swept_poses

    body = RoverBody()
    assert attitude_at(70.0, *contact_plane(70.0, 3.0, -4.0), 0.2) == pytest.approx((3.0, -4.0, 0.2))
    rng = np.random.default_rng(2)
    x, y = rng.uniform(-1.0, 1.0, 100_000), rng.uniform(-1.0, 1.0, 100_000)
    seen = np.hypot(x, y) > 0.45  # the frames saw none of the disc the body turns in
    pts = np.column_stack([x[seen], y[seen], 0.002 * rng.standard_normal(seen.sum())])

    def held(headings: list[float], since: tuple[float, float, float] | None = None) -> np.ndarray:
        m = BoundsMap.covering([[-1.0, -1.0], [1.0, 1.0]], 0.0)
        m.fuse(pts, np.full(len(pts), 0.002), np.array([0.0, 0.0, 1.2]))
        for h in headings:
            m.stood((0.0, 0.0, h), 0.0, body, (0.0, 0.0, 0.1), since=since)
        return np.isfinite(m.ceiling) & np.isfinite(m.mean)

    ends = held([0.0, 90.0])
    swept = held([90.0], since=(0.0, 0.0, 0.0))
    assert swept.sum() > ends.sum() + 20
    assert np.array_equal(swept, held([10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 90.0]))
    assert np.array_equal(held([90.0], since=(-0.8, 0.0, 0.0)), held([90.0]))
    assert len(swept_poses((0.0, 0.0, 0.0), (0.0, 0.0, 90.0), None)) == 8


def test_the_ground_swept_on_a_grade_is_stood_on_at_the_grade_s_height() -> None:
    """No frame bounded the ground the body drove over (0.3 m up a 10 % grade): the poses between
    the two stands take their height from the end's along the plane the attitude gives, so the
    wheels' ground halfway is on the grade, not level with the end."""
    from drivers.sim.rover import RoverBody
    from prox_workflows.algorithms.bounds_map import attitude_at

    body = RoverBody()
    m = BoundsMap.covering([[-1.0, -1.0], [1.0, 1.0]], 0.0)
    roll, pitch, _ = attitude_at(0.0, 0.1, 0.0, 0.1)
    m.stood((0.3, 0.0, 0.0), 0.03, body, (roll, pitch, 0.1), since=(0.0, 0.0, 0.0))
    # the rear wheels' ground halfway (hubs at x = 0.15 - 0.145), which neither end's wheels cover
    r, c = m.geometry.cell_of(np.array([0.005]), np.array([0.245]))
    top = m.mean[r[0], c[0]] + m.rise[r[0], c[0]]
    assert top == pytest.approx(0.1 * 0.0125, abs=0.002)  # the cell's centre on the grade


def test_a_rover_back_where_it_stood_keeps_the_wheels_ground_it_read_there_and_a_prior_gives_way() -> None:
    """The rover stood here once and comes back; this frame's height is 3 cm under the first's
    (frames placed unregistered disagree by that). The wheels' ground stays where the first stand
    read it: moved with each frame's height, it lowered the wheels under framed ground beside them
    and the check refused the pose the rover stood on. A set-down's prior, a centimetre wide, gives
    way to the first stand."""
    from drivers.sim.rover import RoverBody

    body = RoverBody()
    pose = (0.0, 0.0, 40.0)
    m = BoundsMap.covering([[-1.0, -1.0], [1.0, 1.0]], 0.0)
    m.set_down((0.0, 0.0), 0.7, 0.02, 0.01)
    c, s = np.cos(np.radians(pose[2])), np.sin(np.radians(pose[2]))
    ax, side = body.wheelbase / 2, body.track / 2
    hub = (c * ax - s * side, s * ax + c * side)  # front-left
    r, col = m.geometry.cell_of(np.array([hub[0]]), np.array([hub[1]]))
    assert m.mean[r[0], col[0]] == pytest.approx(0.02)
    m.stood(pose, 0.0, body, (0.0, 0.0, 0.1))
    first = float(m.upper[r[0], col[0]])
    assert abs(first) < 0.003  # the prior gave way
    m.stood(pose, -0.03, body, (0.0, 0.0, 0.1))
    assert m.upper[r[0], col[0]] == pytest.approx(first)
