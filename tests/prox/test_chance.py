"""The chance-constrained vehicle check (prox_workflows.algorithms.chance) on synthetic 5 cm grids
with the declared body: probabilities per limit from the cells' posteriors, the verdict against
epsilon, beside the worst-case check on bounds; and the posterior's ray and rock-edge variances."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from drivers.sim.rover import RoverBody
from prox_workflows.algorithms.bounds_map import BoundsMap, BoundsParams
from prox_workflows.algorithms.candidates import crop
from prox_workflows.algorithms.chance import ChanceParams, Posterior, chance_check, posterior, surfaces
from prox_workflows.algorithms.vehicle import LIMITS, check_poses
from prox_workflows.grid import GridGeometry

BODY = RoverBody()
CELL = 0.05
STEP = LIMITS.index("step")
AT_ORIGIN = np.array([[0.0, 0.0, 0.0]])


def grid() -> tuple[GridGeometry, np.ndarray, np.ndarray]:
    g = GridGeometry.covering(-1.0, -1.0, 1.0, 1.0, CELL)
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    return g, X, Y


def ledge(height: float) -> tuple[np.ndarray, GridGeometry]:
    """Raised ground beyond an edge 3 cm ahead of the front-right hub, under that wheel's track
    only (outside the box, which ends at y = -0.20): a step edge of ``height`` and nothing else."""
    g, X, Y = grid()
    h = np.zeros(g.shape)
    h[(X >= 0.175) & (Y <= -0.2) & (Y >= -0.35)] = height
    return h, g


def known(h: np.ndarray, sigma: float) -> Posterior:
    return Posterior(h, np.full(h.shape, sigma * sigma), np.full(h.shape, np.inf))


def test_flat_ground_known_to_millimetres_is_safe_with_no_chance_of_any_limit() -> None:
    h, g = ledge(0.0)
    c = chance_check(known(h, 0.003), g, AT_ORIGIN, BODY)
    assert c.safe.tolist() == [True]
    assert c.p_any[0] < 1e-6
    assert (c.prob[0] < 1e-6).all()


def test_a_step_edge_below_the_climb_is_unlikely_over_it_and_one_at_the_climb_is_a_coin_toss() -> None:
    h9, g = ledge(0.09)
    p9 = chance_check(known(h9, 0.005), g, AT_ORIGIN, BODY).prob[0]
    assert 1e-4 < p9[STEP] < 0.1  # 1 cm below the 10 cm climb, 5 mm per cell: small, not nil
    assert (p9[1:] < 1e-6).all()  # the edge is outside the box: no other limit is near
    p9_wide = chance_check(known(h9, 0.01), g, AT_ORIGIN, BODY).prob[0, STEP]
    assert p9[STEP] < p9_wide < 0.5
    h10, _ = ledge(0.10)
    p10 = chance_check(known(h10, 0.01), g, AT_ORIGIN, BODY).prob[0, STEP]
    # exactly at the limit, half the draws of each pair of samples across the edge are over it;
    # the wheel meets a few such pairs, so somewhat more than half
    assert 0.45 < p10 < 0.8


def test_more_variance_means_more_chance_of_an_edge_below_the_limit() -> None:
    h, g = ledge(0.09)
    probs = [chance_check(known(h, s), g, AT_ORIGIN, BODY).prob[0, STEP] for s in (0.002, 0.004, 0.006, 0.008, 0.012)]
    assert all(b > a for a, b in zip(probs, probs[1:], strict=False)), probs


def test_the_draws_are_seeded() -> None:
    h, g = ledge(0.095)
    poses = np.array([[0.0, 0.0, 0.0], [0.02, 0.01, 3.0], [-0.03, 0.0, -2.0]])
    a = chance_check(known(h, 0.01), g, poses, BODY, ChanceParams(seed=7))
    b = chance_check(known(h, 0.01), g, poses, BODY, ChanceParams(seed=7))
    c = chance_check(known(h, 0.01), g, poses, BODY, ChanceParams(seed=8))
    np.testing.assert_array_equal(a.prob, b.prob)
    assert not np.array_equal(a.prob, c.prob)
    np.testing.assert_allclose(a.prob, c.prob, atol=0.15)  # another seed, the same answer within its noise


def test_a_pose_over_cells_with_no_data_is_unknown_and_never_safe() -> None:
    h, g = ledge(0.0)
    g_, X, Y = grid()
    h[(np.abs(X - 0.145) < 0.06) & (np.abs(Y - 0.245) < 0.05)] = np.nan  # under the front-left wheel
    c = chance_check(known(h, 0.003), g, np.array([[0.0, 0.0, 0.0], [0.0, -0.6, 0.0]]), BODY)
    assert c.unknown.tolist() == [True, False]
    assert c.safe.tolist() == [False, True]
    assert np.isnan(c.prob[0]).all()


def test_it_passes_flat_ground_the_worst_case_refuses_yet_refuses_a_real_edge() -> None:
    # flat ground known to +-3 cm (the bounds map's k of 2.5 times a 1.2 cm sigma): the worst case
    # puts the ground under the box 3 cm up over wheels resting 3 cm down, into the belly (at +-2 cm
    # it still passes; the stability limit is the tip-over angle, far beyond the tilt it makes)
    sigma = 0.03 / 2.5
    h, g = ledge(0.0)
    worst = check_poses(((h - 0.03).astype(np.float32), (h + 0.03).astype(np.float32)), g, AT_ORIGIN, BODY)
    assert worst.safe.tolist() == [False] and worst.excess[0, LIMITS.index("belly")] > 0
    flat = chance_check(known(h, sigma), g, AT_ORIGIN, BODY, ChanceParams(epsilon=1e-4))
    assert flat.safe.tolist() == [True]
    h11, _ = ledge(0.11)
    edge = chance_check(known(h11, sigma), g, AT_ORIGIN, BODY, ChanceParams(epsilon=1e-4))
    assert edge.safe.tolist() == [False]
    assert edge.prob[0, STEP] > 0.9


def test_a_pose_gets_the_same_draws_whatever_window_it_is_judged_in() -> None:
    """The chooser judges a batch of paths in one window, the drive the chosen section again in a
    smaller one: the same map must give the same verdict, or a pose near the limit passes in the
    one and fails in the other."""
    h, g = ledge(0.09)
    g_, X, Y = grid()
    # the ground off the ledge a prior's (its error shared with its neighbours), the ledge seen
    post = Posterior(h, np.full(h.shape, 0.005**2), np.full(h.shape, np.inf), np.where(h > 0, 0.003, 0.0),
                     np.where(h > 0, 0.0, 0.004))
    poses = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 2.0], [-0.01, 0.005, -2.0]])
    whole = chance_check(post, g, poses, BODY)
    assert (whole.prob[:, STEP] > 1e-4).all()  # near the limit: the draws decide
    for box in ((-0.6, -0.7, 0.6, 0.5), (-0.45, -0.55, 0.65, 0.45)):
        sub, sl = crop(g, *box)
        part = chance_check(post.window(sl), sub, poses, BODY)
        np.testing.assert_allclose(part.prob, whole.prob, rtol=1e-9, atol=1e-300)  # (to the window's rounding)
        assert part.safe.tolist() == whole.safe.tolist()
    # and whatever is judged with it
    alone = chance_check(post, g, poses[1:2], BODY)
    np.testing.assert_allclose(alone.prob[0], whole.prob[1], rtol=1e-9, atol=1e-300)


def prior_plane(sigma: float, shared: bool) -> tuple[Posterior, GridGeometry, np.ndarray, np.ndarray]:
    """Ground rising 5 % along x on the map's 2.5 cm cells, known only to ``sigma`` as the set-down's
    prior knows the blind disc: the error shared by neighbouring cells (``shared``) or each cell's
    own, and 5 mm of each cell's own on top (``top_sigma``)."""
    g = GridGeometry.covering(-1.0, -1.0, 1.0, 1.0, 0.025)
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    h = 0.05 * X
    p = ChanceParams()
    own = p.top_sigma**2 + (p.prior_own if shared else 1.0) * sigma**2
    return (Posterior(h, np.full(h.shape, own), np.full(h.shape, np.inf), 0.0,
                      np.sqrt(1.0 - p.prior_own) * sigma if shared else 0.0), g, X, Y)


TURN = np.array([[0.0, 0.0, a] for a in range(0, 360, 15)])  # a turn on the spot


def test_a_plane_known_to_a_few_centimetres_draws_no_wheel_step_between_neighbours() -> None:
    """The set-down's prior over the blind disc: a plane the ground stands off by 3 cm (sd), as the
    true ground there does, smoothly (its correlation 0.95-0.98 between neighbouring 2.5 cm cells,
    python -m tools.bench.chance --correlation). Drawn cell by cell, neighbours step 4.3 cm (sd),
    the wheels' steps reach 12 cm (p99) and every pose of a turn on the spot is refused on them;
    drawn as a field shared by neighbours, they step 1.3 cm and no pose is near the climb (what
    refuses is the belly, over ground that may stand 3 cm (sd) up under the box: the prior's own
    verdict, not the draws')."""
    def drawn(post: Posterior, g: GridGeometry) -> tuple[np.ndarray, float, float]:
        """The wheels' steps at the turn's poses in every draw, the neighbours' steps' sd under
        the body and the drawn errors' sd."""
        ss = list(surfaces(post, g))
        wheel = np.array([check_poses(s, g, TURN, BODY).excess[:, STEP] for s in ss]) + BODY.climb
        under = (np.abs(X) < 0.6) & (np.abs(Y) < 0.6)
        step = np.concatenate([np.diff(s, axis=1)[under[:, 1:]] for s in ss])
        return wheel, float(step.std()), float(np.std([(s - post.mean)[under] for s in ss]))

    post, g, X, Y = prior_plane(0.03, shared=True)
    wheel, step, sd = drawn(post, g)
    assert step < 0.015, step
    assert np.percentile(wheel, 99) < 0.055 and wheel.max() < 0.07
    assert sd == pytest.approx(np.hypot(0.03, 0.005), rel=0.15)  # each cell's error as large as before
    shared = chance_check(post, g, TURN, BODY)
    assert (shared.prob[:, STEP] < 1e-9).all()
    apart, g, _, _ = prior_plane(0.03, shared=False)
    wheel, step, sd = drawn(apart, g)
    assert step == pytest.approx(np.sqrt(2) * np.hypot(0.03, 0.005), rel=0.1)
    assert np.percentile(wheel, 99) > 0.11
    cell_by_cell = chance_check(apart, g, TURN, BODY)
    assert not cell_by_cell.safe.any()
    assert (cell_by_cell.worst()[0] == STEP).all() and (cell_by_cell.prob[:, STEP] > 0.05).all()


def test_a_real_step_edge_under_a_prior_known_to_a_few_centimetres_is_still_refused() -> None:
    """An 11 cm edge (the climb is 10 cm) under the front-right wheel's track, on that prior: the
    shared field moves the edge's two sides together, and the step is there in every draw."""
    post, g, X, Y = prior_plane(0.03, shared=True)
    h = post.mean + np.where((X >= 0.175) & (Y <= -0.2) & (Y >= -0.35), 0.11, 0.0)
    edge = chance_check(Posterior(h, post.var, post.ceiling, 0.0, post.shared), g, AT_ORIGIN, BODY)
    assert edge.safe.tolist() == [False]
    assert edge.prob[0, STEP] > 0.9


def test_a_prior_s_draws_stay_under_the_belly_the_rover_stood_over_it_with() -> None:
    """Unseen ground under the rover's box known to 3 cm (sd) about its plane, as the set-down's
    prior takes it, under the ceiling the belly puts there (BoundsMap.stood: 4 cm over the plane):
    no draw of a prior's cell stands over it, and the belly is touched less often over a turn on
    the spot (its wheels drawn on the prior too). A cell a frame bounded keeps its draws
    whatever ceiling it has: there the returns are the evidence."""
    post, g, X, Y = prior_plane(0.03, shared=True)
    box = (np.abs(X) < 0.25) & (np.abs(Y) < 0.22)
    ceiling = np.where(box, post.mean + 0.04, np.inf)
    stood = Posterior(post.mean, post.var, ceiling, 0.0, post.shared)
    drawn = np.array([s[box] for s in surfaces(stood, g)])
    assert (drawn <= ceiling[box] + 1e-6).all() and (drawn >= ceiling[box] - 1e-6).any()
    belly = LIMITS.index("belly")
    under, over = chance_check(stood, g, TURN, BODY).prob[:, belly], chance_check(post, g, TURN, BODY).prob[:, belly]
    assert (under <= over).all() and under.mean() < 0.7 * over.mean(), (under, over)
    low = np.where(box, post.mean + 0.002, np.inf)
    seen = Posterior(post.mean, post.var, low, 0.0, 0.0)
    assert max(float((s[box] - low[box]).max()) for s in surfaces(seen, g)) > 0.005


def test_the_set_down_s_prior_is_shared_by_neighbours_and_the_frames_noise_is_each_cell_s_own() -> None:
    m = BoundsMap(GridGeometry.covering(0.0, 0.0, 1.0, 1.0, 0.025), BoundsParams())
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(0.6, 0.9, 2000), rng.uniform(0.6, 0.9, 2000), 0.002 * rng.standard_normal(2000)])
    m.fuse(pts, 0.002)
    m.set_down((0.3, 0.3), 0.2, 0.0, sigma=0.03)
    s, g = m.statistics(0.0, 0.0, 1.0, 1.0)
    post = posterior(s, g, m.params.k)
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    disc = np.hypot(X - 0.3, Y - 0.3) <= 0.2
    seen = (X > 0.65) & (X < 0.85) & (Y > 0.65) & (Y < 0.85)
    assert not s["framed"][disc].any() and s["framed"][seen].all()
    p = ChanceParams()
    np.testing.assert_allclose(post.shared[disc], np.sqrt(1 - p.prior_own) * 0.03, rtol=1e-6)
    # of its own: the prior's roughness at a cell's scale and the relief no return met
    np.testing.assert_allclose(post.var[disc], p.prior_own * 0.03**2 + p.top_sigma**2, rtol=1e-5)
    assert (post.shared[seen] == 0).all()
    np.testing.assert_allclose(post.var[seen], s["mean_var"][seen] + ChanceParams().top_sigma**2, rtol=1e-5)


def test_a_ray_ceiling_with_no_return_stands_as_the_ground_at_its_height() -> None:
    h, g = ledge(0.0)
    g_, X, Y = grid()
    ceiling = np.full(h.shape, np.inf)
    under_box = (np.abs(X) < 0.06) & (np.abs(Y) < 0.06)
    h[under_box] = np.nan
    low, high = ceiling.copy(), ceiling.copy()
    low[under_box], high[under_box] = 0.02, 0.12  # a ray 2 cm over the ground, or 12 cm (over the belly)
    var = np.full(h.shape, 0.003**2)
    assert chance_check(Posterior(h, var, low), g, AT_ORIGIN, BODY).safe.tolist() == [True]
    over = chance_check(Posterior(h, var, high), g, AT_ORIGIN, BODY)
    assert over.safe.tolist() == [False] and not over.unknown[0]
    assert over.prob[0, LIMITS.index("belly")] == pytest.approx(1.0)


def stats(top: np.ndarray, sigma: float, shift: float) -> dict[str, np.ndarray]:
    """A bounds map's statistics with the ground's tops known to ``sigma``; its upper bound the tops
    themselves (no headroom but a rock's own beside it)."""
    return {"mean": top.copy(), "mean_var": np.full(top.shape, sigma * sigma), "rise": np.zeros(top.shape),
            "drop": np.zeros(top.shape), "shift": np.full(top.shape, shift), "ceiling": np.full(top.shape, np.inf),
            "upper": top.copy(), "lower": top.copy()}


def test_the_range_error_lies_along_the_ray() -> None:
    g, X, Y = grid()
    top = np.where(X >= 0.0, 0.10, 0.0)  # an edge across x: seen along the ray from -x, along it from -y
    no_edge = ChanceParams(edge_bias=0.0, edge_sigma=0.0, top_sigma=0.0, rock_sigma=0.0)
    k = 2.5
    along = posterior(stats(top, 0.004, k * 0.02), g, k, no_edge, viewpoint=(-3.0, 0.0, 1.0))
    across = posterior(stats(top, 0.004, k * 0.02), g, k, no_edge, viewpoint=(0.0, -30.0, 1.0))
    at = (np.abs(X - 0.025) < 1e-6) & (np.abs(Y - 0.025) < 1e-6)  # the edge's upper cell, on the ray y = 0
    assert along.var[at][0] > 10 * 0.004**2  # a shift along the ray moves it onto the 10 cm edge
    # seen along the edge (rays 30 m off, nearly parallel to it) the shift moves it along flat tops
    assert across.var[at][0] == pytest.approx(0.004**2, rel=0.1)
    flat = np.abs(X + 0.5) < 0.1
    np.testing.assert_allclose(along.var[flat], 0.004**2)  # on flat ground nothing is added
    # the mean's horizontal error is its height error over the ray's elevation, never more than one return's
    assert along.var[at][0] <= 0.004**2 + (0.10 / CELL * 0.02) ** 2 + 1e-12


def pebbles(height: float) -> tuple[np.ndarray, GridGeometry]:
    """2.5 cm tops of ground rising 10 % along x, strewn with 40 round pebbles ``height`` tall
    (a normal bump of 2.5 cm sigma): steep where a pebble's flank is, a step nowhere near the climb."""
    g = GridGeometry.covering(-1.0, -1.0, 1.0, 1.0, 0.025)
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    rng = np.random.default_rng(0)
    top = 0.1 * X + 0.002 * rng.standard_normal(X.shape)
    for x, y in rng.uniform(-0.6, 0.6, (40, 2)):
        top += height * np.exp(-((X - x) ** 2 + (Y - y) ** 2) / (2 * 0.025**2))
    return top, g


def test_without_a_viewpoint_the_slope_takes_the_mean_s_averaged_horizontal_error() -> None:
    top, g = pebbles(0.05)
    k, one = 2.5, 0.02  # one return's horizontal sigma along its ray: 2 cm
    no_edge = ChanceParams(edge_bias=0.0, edge_sigma=0.0, top_sigma=0.0, rock_sigma=0.0)
    bare = stats(top, 0.001, k * one)
    averaged = dict(bare, along_var=np.full(top.shape, one**2 / 16))  # 16 returns fused
    single = dict(bare, along_var=np.full(top.shape, one**2))  # one return: no better than it
    gy, gx = np.gradient(top, g.cell)
    slope = np.hypot(gx, gy)
    np.testing.assert_allclose(posterior(averaged, g, k, no_edge).var, 0.001**2 + (slope * one / 4) ** 2)
    np.testing.assert_allclose(posterior(single, g, k, no_edge).var, 0.001**2 + (slope * one) ** 2)
    # a map without the averaged error (a replayed map) keeps one return's
    np.testing.assert_allclose(posterior(bare, g, k, no_edge).var, posterior(single, g, k, no_edge).var)


def test_a_turn_on_the_spot_among_pebbles_seen_by_many_returns_passes() -> None:
    """The wheels' steps on 5 cm pebbles reach 4.7 cm on the tops themselves (the climb is 10 cm):
    with one return's horizontal error on the pebbles' steep flanks the draws make steps of 10 cm
    between neighbouring cells and refuse a fifth of the turn; with the mean's own (16 returns)
    every pose passes. The same map with a 11 cm edge under the turn still refuses it."""
    top, g = pebbles(0.05)
    k, one = 2.5, 0.02
    p = ChanceParams(edge_bias=0.0, edge_sigma=0.0, top_sigma=0.005, rock_sigma=0.0)
    turn = np.column_stack([np.zeros(37), np.zeros(37), np.arange(0.0, 181.0, 5.0)])
    assert check_poses(top.astype(np.float32), g, turn, BODY).step.max() < 0.05
    bare = stats(top, 0.001, k * one)
    single = chance_check(posterior(bare, g, k, p), g, turn, BODY, p)
    assert (~single.safe).sum() >= 3  # what the chooser made of such ground
    averaged = dict(bare, along_var=np.full(top.shape, one**2 / 16))
    assert chance_check(posterior(averaged, g, k, p), g, turn, BODY, p).safe.all()
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    ledge = top + np.where((np.hypot(X, Y) > 0.33) & (np.hypot(X, Y) < 0.5), 0.11, 0.0)
    edged = dict(stats(ledge, 0.001, k * one), along_var=np.full(top.shape, one**2 / 16))
    assert not chance_check(posterior(edged, g, k, p), g, turn, BODY, p).safe.any()


def test_beside_a_rock_the_top_reads_low_by_one_error_for_all_its_cells() -> None:
    g, X, Y = grid()
    top = np.where(np.hypot(X, Y) < 0.2, 0.10, 0.0)
    p = ChanceParams(edge_bias=0.05, edge_sigma=0.2, top_sigma=0.003, rock_sigma=0.0)
    post = posterior(stats(top, 0.004, 0.0), g, 2.5, p, viewpoint=(-3.0, 0.0, 1.0))
    rim = (np.abs(X - 0.225) < 1e-6) & (np.abs(Y - 0.025) < 1e-6)  # outside the rock, beside its 10 cm top
    middle = (np.abs(X - 0.025) < 1e-6) & (np.abs(Y - 0.025) < 1e-6)
    assert post.mean[rim][0] == pytest.approx(0.05 * 0.10)
    assert post.common[rim][0] == pytest.approx(0.2 * 0.10)
    assert post.var[rim][0] == pytest.approx(0.004**2 + 0.003**2)
    assert post.mean[middle][0] == pytest.approx(0.10)
    assert post.common[middle][0] == 0.0
    assert post.var[middle][0] == pytest.approx(0.004**2 + 0.003**2)


def test_a_rock_top_shares_one_error_by_its_height_over_the_ground_round_it() -> None:
    g, X, Y = grid()
    top = np.where(np.hypot(X, Y) < 0.2, 0.10, 0.0) + 0.02 * X  # on a gentle slope
    p = ChanceParams(edge_bias=0.0, edge_sigma=0.0, top_sigma=0.0, rock_sigma=0.2)
    post = posterior(stats(top, 0.004, 0.0), g, 2.5, p)
    middle = (np.abs(X - 0.025) < 1e-6) & (np.abs(Y - 0.025) < 1e-6)
    # the lowest top within 0.2 m (+-0.1 m: two cells) is the rock's own, 0.1 m down the slope
    assert post.common[middle][0] == pytest.approx(0.2 * 0.02 * 0.1, rel=1e-6)
    # inside by its rim; the ground beside the rock at the same x (0.175, 0.125) is the lowest
    rim = (np.abs(X - 0.175) < 1e-6) & (np.abs(Y - 0.025) < 1e-6)
    assert post.common[rim][0] == pytest.approx(0.2 * 0.10, rel=1e-6)
    flat = (np.abs(X + 0.7) < 0.05) & (np.abs(Y) < 0.5)
    np.testing.assert_allclose(post.common[flat], 0.2 * 0.02 * 0.1, rtol=1e-6)  # the slope over 0.1 m: 0.4 mm


def test_a_tall_rocks_top_is_read_low_by_no_more_than_a_low_ones() -> None:
    """The rock top's common sigma grows with the rock's height up to ``rock_sigma_max``: the
    apex its returns miss, not the rock's height, is what the top is read low by."""
    g, X, Y = grid()
    top = np.where(np.hypot(X, Y) < 0.2, 0.15, 0.0)
    low = np.where(np.hypot(X, Y) < 0.2, 0.05, 0.0)
    p = ChanceParams(edge_bias=0.0, edge_sigma=0.0, top_sigma=0.0, rock_sigma=0.2, rock_sigma_max=0.015)
    rim = (np.abs(X - 0.175) < 1e-6) & (np.abs(Y - 0.025) < 1e-6)
    assert posterior(stats(top, 0.004, 0.0), g, 2.5, p).common[rim][0] == pytest.approx(0.015)
    assert posterior(stats(low, 0.004, 0.0), g, 2.5, p).common[rim][0] == pytest.approx(0.2 * 0.05, rel=1e-6)
    uncapped = dataclasses.replace(p, rock_sigma_max=1.0)
    assert posterior(stats(top, 0.004, 0.0), g, 2.5, uncapped).common[rim][0] == pytest.approx(0.2 * 0.15, rel=1e-6)


def test_a_common_error_moves_a_wheel_and_the_ground_beside_it_together() -> None:
    h, g = ledge(0.09)
    g_, X, Y = grid()
    own = known(h, 0.004)
    # the same spread, all of it one error of the raised ground: the edge's height itself varies,
    # where errors of each cell apart partly cancel between the cells a sample reads
    common = Posterior(h, np.full(h.shape, 1e-12), own.ceiling, np.where(h > 0, 0.004 * np.sqrt(2.0), 0.0))
    p_own = chance_check(own, g, AT_ORIGIN, BODY, ChanceParams(samples=256)).prob[0, STEP]
    p_common = chance_check(common, g, AT_ORIGIN, BODY, ChanceParams(samples=256)).prob[0, STEP]
    # one error of sqrt(2) x 4 mm on the 1 cm to spare: P = 1 - Phi(1 / 0.566) = 0.039
    assert p_common == pytest.approx(0.039, abs=0.02)
    assert p_common > 10 * p_own


def test_the_bounds_map_gives_its_statistics_over_a_box() -> None:
    m = BoundsMap(GridGeometry.covering(0.0, 0.0, 1.0, 1.0, 0.05), BoundsParams())
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(0.3, 0.5, 400), rng.uniform(0.3, 0.5, 400), 0.02 + 0.002 * rng.standard_normal(400)])
    m.fuse(pts, 0.002)
    s, sub = m.statistics(0.26, 0.26, 0.54, 0.54)
    assert s["mean"].shape == sub.shape == (6, 6)
    inner = s["mean"][1:5, 1:5]
    assert np.isfinite(inner).all() and np.abs(inner - 0.02).max() < 0.002
    assert np.all(s["mean_var"][1:5, 1:5] < 0.002**2)  # averaged returns: the mean is better than one
    assert np.isnan(s["mean"][0]).all()
    s["mean"][:] = 5.0
    assert np.nanmax(m.mean) < 1.0  # a copy: a posterior made from it leaves the map alone


def test_a_planner_s_verdict_only_check_gives_the_full_check_s_verdicts() -> None:
    """``verdict_only`` refuses a pose on its best estimate's excess, or as soon as one draw in a
    batch is over a limit, without the rest of the draws: over ledges from far below to above the
    climb, seen at three noise levels, its verdicts are the full check's, pose for pose."""
    poses = np.column_stack([np.linspace(-0.3, 0.1, 9), np.zeros(9), np.zeros(9)])
    for height in (0.05, 0.085, 0.095, 0.1, 0.12):
        h, g = ledge(height)
        for sigma in (0.002, 0.005, 0.01):
            full = chance_check(known(h, sigma), g, poses, BODY)
            quick = chance_check(known(h, sigma), g, poses, BODY, verdict_only=True)
            assert quick.unsafe.tolist() == full.unsafe.tolist(), (height, sigma)
            assert quick.safe.tolist() == full.safe.tolist()


def test_the_shared_field_is_correlated_by_1_over_e_at_its_length_as_the_bench_measures_it() -> None:
    """The draws' shared field, measured as ``tools.bench.chance --correlation`` measures the truth's:
    1/e at ``shared_length`` (20 cm: 8 cells of 2.5 cm), near 1 between neighbours; white noise
    (the cells' own errors) not correlated at all."""
    from tools.bench.chance import lag_correlation

    p = ChanceParams()
    post, g, X, Y = prior_plane(0.03, shared=True)
    field = [(s - post.mean) for s in surfaces(Posterior(post.mean, np.zeros(g.shape), post.ceiling, 0.0, 1.0), g,
                                                         ChanceParams(samples=8))]
    ok = np.ones(g.shape, bool)
    at = {lag: np.mean([lag_correlation(f, ok, lag) for f in field]) for lag in (1, 2, 4, 8)}
    assert at[8] == pytest.approx(np.exp(-1.0), abs=0.08)  # 8 cells = p.shared_length
    assert p.shared_length == pytest.approx(8 * g.cell)
    assert at[1] > 0.95 and at[1] > at[2] > at[4] > at[8]
    own = [s - post.mean for s in surfaces(Posterior(post.mean, np.ones(g.shape), post.ceiling), g,
                                           ChanceParams(samples=8))]
    assert abs(np.mean([lag_correlation(f, ok, 1) for f in own])) < 0.02


def wheel_edge_over_unseen_ground() -> tuple[Posterior, GridGeometry, np.ndarray, np.ndarray]:
    """Flat ground known to 3 mm with a rock under the box 1 cm over the belly's clearance (the
    truth: unsafe), and under both front wheels' footprint ends (x 0.20-0.25 m) no return, only a
    ray 15 cm up: the ground's top there, the highest it may be."""
    g, X, Y = grid()
    h = np.zeros(g.shape)
    h[(np.abs(X) < 0.05) & (np.abs(Y) < 0.05)] = BODY.clearance + 0.01
    ceiling = np.full(h.shape, np.inf)
    unseen = (X > 0.2) & (X < 0.25) & (np.abs(Y) > 0.2) & (np.abs(Y) < 0.3)
    h[unseen], ceiling[unseen] = np.nan, 0.15
    return Posterior(h, np.full(h.shape, 0.003**2), ceiling), g, X, Y


def test_a_wheel_does_not_rest_on_a_ray_s_height_over_ground_no_return_met() -> None:
    # one surface: the front wheels rest 4 cm up on the ray's height, the plane lifts the belly
    # clear of the rock; judged as bounds, the wheels rest on the ground their returns show
    post, g, _, _ = wheel_edge_over_unseen_ground()
    lifted = chance_check(post, g, AT_ORIGIN, BODY)
    assert lifted.safe.tolist() == [True] and lifted.nominal.excess[0, LIMITS.index("belly")] < -0.005
    within = chance_check(Posterior(post.mean, post.var, post.ceiling, span=np.zeros(post.mean.shape)), g,
                          AT_ORIGIN, BODY)
    assert within.safe.tolist() == [False] and not within.unknown[0]
    assert within.prob[0, LIMITS.index("belly")] == pytest.approx(1.0)
    assert within.nominal.excess[0, LIMITS.index("belly")] == pytest.approx(0.01, abs=0.002)


BARE = {"edge_bias": 0.0, "edge_sigma": 0.0, "rock_sigma": 0.0, "top_sigma": 0.002}  # the top's own sigma alone


def spread(top: np.ndarray, cells: np.ndarray, relief: float) -> dict[str, np.ndarray]:
    """:func:`stats` of ``top`` known to 2 mm, where ``cells`` hold returns that rise and drop
    ``relief`` about their mean (a rock's edge in the cell: its top ``2 relief`` over its low)."""
    st = stats(top, 0.002, 0.0)
    st["mean"][cells] -= relief
    st["rise"][cells], st["drop"][cells] = relief, relief
    return st


def test_a_pair_s_wheel_over_ground_only_a_ray_bounds_is_unknown_not_safe() -> None:
    # the front half of the front-left wheel over cells no return met (a ray 15 cm up), a rock
    # under the box: read between the cell centres, most of that wheel rests on nothing and no
    # plane is judged in any draw (read cellwise, as the screen reads bounds, less than half);
    # that is ground not seen, never a safe pose
    post, g, X, Y = wheel_edge_over_unseen_ground()
    mean, ceiling = post.mean.copy(), post.ceiling.copy()
    under = (X > 0.15) & (X < 0.3) & (Y > 0.15) & (Y < 0.35)
    mean[under], ceiling[under] = np.nan, 0.15
    pair = chance_check(Posterior(mean, post.var, ceiling, span=np.zeros(mean.shape)), g, AT_ORIGIN, BODY)
    assert pair.unknown.tolist() == [True] and pair.safe.tolist() == [False]


def test_a_wheel_meeting_a_rock_edge_cell_may_rest_below_its_top() -> None:
    # the front wheels' footprint ends over cells whose returns rise 7.5 cm over their mean and drop
    # 7.5 cm under it (a rock's edge in the cell): their top, read all over the cell, lifts the wheels
    g, X, Y = grid()
    top = np.zeros(g.shape)
    top[(np.abs(X) < 0.05) & (np.abs(Y) < 0.05)] = BODY.clearance + 0.01
    edge = (X > 0.2) & (X < 0.25) & (np.abs(Y) > 0.2) & (np.abs(Y) < 0.3)
    top[edge] = 0.15
    st = spread(top, edge, 0.075)
    one = posterior(st, g, 2.5, ChanceParams(within=0.0, **BARE))
    assert one.span is None and chance_check(one, g, AT_ORIGIN, BODY).safe.tolist() == [True]
    post = posterior(st, g, 2.5, ChanceParams(within=1.0, **BARE))
    assert post.span[edge] == pytest.approx(0.15) and post.span[~edge].max() == 0.0
    c = chance_check(post, g, AT_ORIGIN, BODY)
    assert c.safe.tolist() == [False] and c.prob[0, LIMITS.index("belly")] == pytest.approx(1.0)


def test_a_drawn_pair_rests_its_wheels_on_the_lows_not_on_the_worst_corner_of_their_box() -> None:
    # a rock under the box's front-left corner 1 cm under the clearance over flat ground, and the
    # rear-left wheel over cells whose returns rise and drop 3 cm about their mean (its top 6 cm
    # over its low, 0: the floor the wheel stands on). Resting anywhere in that box, the worst
    # corner stands the rear-left wheel at its top and the others at their lows, a plane that
    # leans the front-left corner 2 cm down into the rock; on the lows the body is level
    g, X, Y = grid()
    top = np.zeros(g.shape)
    rock = (X > 0.2) & (X < 0.3) & (Y > 0.05) & (Y < 0.2)
    top[rock] = BODY.clearance - 0.01
    wheel = (X > -0.26) & (X < -0.03) & (Y > 0.2) & (Y < 0.3)
    top[wheel] = 0.06
    post = posterior(spread(top, wheel, 0.03), g, 2.5, ChanceParams(within=1.0, **BARE))
    c = chance_check(post, g, AT_ORIGIN, BODY)
    assert c.safe.tolist() == [True]
    assert c.nominal.excess[0, LIMITS.index("belly")] == pytest.approx(-0.01, abs=0.002)
    assert c.nominal.tilt[0] == pytest.approx(0.0, abs=0.2)
    # the same pair judged as bounds (each wheel anywhere between its low and its top)
    low = np.where(np.isfinite(post.mean), post.mean - post.span, np.nan).astype(np.float32)
    box = check_poses((low, post.mean.astype(np.float32)), g, AT_ORIGIN, BODY, CELL, cellwise=False)
    assert box.excess[0, LIMITS.index("belly")] == pytest.approx(0.0107, abs=0.002)


def test_a_drawn_pair_s_grade_is_the_plane_fitted_to_it_as_the_truth_s_is() -> None:
    # a uniform 9 deg slope, each cell's pair its top and its low a cell's rise under it: the
    # steepest plane within every cell's pair read 9.6 deg; the truth's plane, fitted on its 1 cm
    # grid, reads 9.0, and a drawn pair is one ground
    slope = np.tan(np.radians(9.0))
    g = GridGeometry(0.025, -1.5, 1.5, 120, 120)
    xs, _ = g.centers()
    top = np.tile(slope * (xs + g.cell / 2), (g.height, 1))
    post = Posterior(top, np.full(g.shape, 1e-8), np.full(g.shape, np.inf), span=np.full(g.shape, slope * g.cell))
    poses = np.array([[0.0, 0.0, h] for h in (0.0, 30.0, 90.0)])
    c = chance_check(post, g, poses, BODY, ChanceParams(**BARE))
    fine = GridGeometry(0.01, -1.5, 1.5, 300, 300)
    truth = check_poses(np.tile(slope * fine.centers()[0], (fine.height, 1)).astype(np.float32), fine, poses, BODY)
    assert truth.grade == pytest.approx([9.0] * 3, abs=0.02)
    assert c.nominal.grade == pytest.approx(truth.grade, abs=0.05)
    # as bounds (each sample anywhere within its cell's pair) the grade is the steepest they allow
    low = (top - slope * g.cell).astype(np.float32)
    box = check_poses((low, top.astype(np.float32)), g, poses, BODY, g.cell, cellwise=False)
    assert box.grade.min() > 9.4


def test_the_miss_trace_stands_the_body_as_the_vehicle_check_does() -> None:
    # tools.bench.chance_trace: a rock under the box and one wheel on a 3 cm slab; the trace's
    # contacts, resting plane and belly point give the check's own intrusion
    from tools.bench.chance_trace import stand

    g, X, Y = grid()
    h = np.zeros(g.shape)
    h[(np.abs(X) < 0.05) & (np.abs(Y) < 0.05)] = 0.07
    h[(X > 0.05) & (Y < -0.2)] = 0.03  # under the front-right wheel
    body = stand(h.astype(np.float32), g, np.array([0.0, 0.0, 0.0]), BODY, CELL)
    check = check_poses(h.astype(np.float32), g, AT_ORIGIN, BODY)
    assert body["intrusion"] == pytest.approx(check.intrusion[0], abs=1e-6)
    assert [round(c[0], 3) for c in body["contacts"]][1] == pytest.approx(0.03, abs=0.002)
    assert np.hypot(*body["belly_xy"]) < 0.08


def rock_and_slab() -> tuple[GridGeometry, np.ndarray, np.ndarray]:
    """A 7 cm rock under the box's front left and a 6 cm slab under the rear-left wheel: the tops,
    and the slab's cells (where a trace's pair puts the lows under them)."""
    g, X, Y = grid()
    high = np.zeros(g.shape)
    high[(X > 0.2) & (X < 0.3) & (Y > 0.05) & (Y < 0.2)] = 0.07
    wheel = (X > -0.26) & (X < -0.03) & (Y > 0.2) & (Y < 0.3)
    high[wheel] = 0.06
    return g, high, wheel


def test_the_rest_trace_stands_a_pair_as_the_vehicle_check_does() -> None:
    # tools.bench.rest_trace: a rock under the box, the rear-left wheel over cells whose lows lie
    # 6 cm under their tops; its contacts and plane give the check's own belly figure, on the lows
    # and over the worst corner of the box of rests alike
    from tools.bench.rest_trace import stand_pair

    g, high, wheel = rock_and_slab()
    low = np.where(wheel, 0.0, high).astype(np.float32)
    high = high.astype(np.float32)
    for rest_low in (True, False):
        body = stand_pair(low, high, g, np.array([0.0, 0.0, 0.0]), BODY, CELL, rest_low=rest_low)
        check = check_poses((low, high), g, AT_ORIGIN, BODY, CELL, cellwise=False, rest_low=rest_low)
        assert body["intrusion"] == pytest.approx(check.intrusion[0], abs=1e-6)
        assert body["contact_low"][2] == pytest.approx(0.0, abs=0.002)
        assert body["contact_high"][2] == pytest.approx(0.06, abs=0.005)
    assert stand_pair(low, high, g, np.array([0.0, 0.0, 0.0]), BODY, CELL, rest_low=False)["triplet"][1] != [0, 0, 0]


def test_the_miss_trace_stands_the_wheels_on_the_lows_as_the_declared_check_does() -> None:
    # tools.bench.chance_trace with the pair: a rock under the box, the rear-left wheel over cells
    # whose lows lie 6 cm under their tops; the trace rests that wheel on the lows and reads the
    # belly over the tops, and so gives the declared check's own belly figure, where standing the
    # body on the tops alone (the one surface) puts the plane elsewhere: its belly figure is 2 cm off
    from prox_workflows.algorithms.chance import _judge
    from tools.bench.chance_trace import stand

    g, high, wheel = rock_and_slab()
    span = np.where(wheel, 0.06, 0.0)
    low = (high - span).astype(np.float32)
    pair = stand(high.astype(np.float32), g, np.array([0.0, 0.0, 0.0]), BODY, CELL, low)
    check = _judge(high, np.ones(g.shape, bool), span, g, AT_ORIGIN, BODY, None)
    assert pair["intrusion"] == pytest.approx(check.intrusion[0], abs=1e-6)
    assert min(c[0] for c in pair["contacts"]) == pytest.approx(0.0, abs=0.002)
    one = stand(high.astype(np.float32), g, np.array([0.0, 0.0, 0.0]), BODY, CELL)
    assert abs(pair["intrusion"] - one["intrusion"]) > 0.02


def test_the_kept_trace_gives_each_lost_pose_to_the_first_term_that_loses_it() -> None:
    # tools.bench.chance_trace --kept: six poses, the first four truly safe; the one surface keeps
    # 0-2 and 4, the pair without relief leaves 0 unknown and refuses 4 (a false safe caught by
    # the rays), the declared pair also refuses 1 and keeps 3, which the one surface refuses
    from types import SimpleNamespace

    from tools.bench.chance_trace import by_term

    def verdicts(safe: list[int], unknown: list[int]) -> SimpleNamespace:
        return SimpleNamespace(safe=np.array(safe, bool), unknown=np.array(unknown, bool))

    truly_unsafe = np.array([0, 0, 0, 0, 1, 1], bool)
    checks = {"one": verdicts([1, 1, 1, 0, 1, 0], [0] * 6), "rays": verdicts([0, 1, 1, 1, 0, 0], [1, 0, 0, 0, 0, 0]),
              "pair": verdicts([0, 0, 1, 1, 0, 0], [1, 0, 0, 0, 0, 0])}
    out = by_term(truly_unsafe, checks)
    assert out["kept"] == {"one": 3, "rays": 3, "pair": 2}
    assert out["false_safe"] == {"one": 1, "rays": 0, "pair": 0}
    assert out["lost_to_rays"] == {"poses": 1, "unknown": 1}
    assert out["caught_by_rays"] == 1
    assert (out["lost_to_relief"], out["caught_by_relief"], out["gained_by_relief"]) == (1, 0, 1)


def test_the_slack_bench_counts_false_safes_and_kept_poses_per_margin() -> None:
    # tools.bench.chance --slack: five poses, the last two truly unsafe, the first unknown; a pose
    # passes at t where its drawn margin is t sigmas or more under the limits
    from tools.bench.chance import slack, slack_counts

    unsafe = np.array([0, 0, 0, 1, 1], bool)
    unknown = np.array([1, 0, 0, 0, 0], bool)
    declared = np.array([0, 1, 0, 0, 0], bool)
    z = np.array([-9.0, -4.0, -1.2, -2.2, 0.5])
    look = slack_counts(unsafe, declared, unknown, z, (3.0, 2.0, 1.0))
    assert look["judged"] == 4 and look["truly_safe"] == 3
    assert look["verdicts"] == {"declared": [0, 1], "t 3": [0, 1], "t 2": [1, 1], "t 1": [1, 2]}
    rows = slack([{"scene": "s", **look}, {"scene": "s", **look}])
    at = {r["verdict"]: r for r in rows}
    assert at["t 1"]["false_safe"] == 2 and at["t 1"]["kept"] == pytest.approx(4 / 6)
    assert at["declared"]["bound"] == pytest.approx(1 - 0.05 ** (1 / 8))  # 0 of 8: the one-sided 95 % bound


def test_a_drawn_pose_s_margin_is_its_draws_mean_excess_over_their_spread() -> None:
    # the chance check's z: under the limit (negative) on a low edge, over it (positive) on an edge
    # above the climb, -inf where the screen cleared the pose, NaN where the ground is unknown
    h, g = ledge(0.09)
    low = chance_check(known(h, 0.005), g, AT_ORIGIN, BODY)
    high = chance_check(known(ledge(0.11)[0], 0.005), g, AT_ORIGIN, BODY)
    assert low.z[0, STEP] < 0 < high.z[0, STEP]
    flat = chance_check(known(ledge(0.0)[0], 0.001), g, AT_ORIGIN, BODY)
    assert flat.screened[0] and (flat.z[0] == -np.inf).all()
    blank = known(np.full(h.shape, np.nan), 0.005)
    assert np.isnan(chance_check(blank, g, AT_ORIGIN, BODY).z[0]).all()


def test_a_wheel_rests_on_the_tops_of_the_cells_it_covers_whole_for_stability() -> None:
    # rough ground under the front-left wheel: cells whose returns rise 6 cm over their low (the
    # relief a wheel rests on the peaks of). Within's rule rests it on the lows, a level body; a
    # cell the footprint covers whole holds its top under the wheel, which tilts the body
    g = GridGeometry.covering(-1.0, -1.0, 1.0, 1.0, 0.025)
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    hx, hy = BODY.wheels[0]
    rough = (np.abs(X - hx) < BODY.wheel_radius) & (np.abs(Y - hy) < BODY.wheel_width / 2)
    top = np.where(rough, 0.06, 0.0)
    post = Posterior(top, np.full(top.shape, 0.002**2), np.full(top.shape, np.inf), span=np.where(rough, 0.06, 0.0))
    low = chance_check(post, g, AT_ORIGIN, BODY, ChanceParams(samples=16))
    raised = chance_check(post, g, AT_ORIGIN, BODY, ChanceParams(samples=16, rest_tops=True))
    assert low.nominal.tilt[0] < 0.5  # resting on the lows: level
    assert raised.nominal.tilt[0] > 5.0  # on the covered cells' tops, less the circle's sag
    stab, belly = LIMITS.index("stability"), LIMITS.index("belly")
    assert raised.nominal.excess[0, stab] > low.nominal.excess[0, stab] + 5.0
    assert raised.nominal.excess[0, belly] == pytest.approx(low.nominal.excess[0, belly])


def shadow_beside_a_wheel(ceiling: float) -> tuple[Posterior, GridGeometry]:
    """Flat ground known to 3 mm and, in the front-left wheel's lane ahead of its hub, a strip no
    return met under rays ``ceiling`` up (a rock's shadow, the blind disc's rim), as wide as the
    wheel, 5 cm deep: most of the wheel rests on seen ground."""
    g, X, Y = grid()
    h = np.zeros(g.shape)
    hx, hy = BODY.wheels[0]
    roof = np.full(h.shape, np.inf)
    strip = (X > hx + 0.05) & (X < hx + 0.1) & (np.abs(Y - hy) < BODY.wheel_width / 2)
    h[strip], roof[strip] = np.nan, ceiling
    return Posterior(h, np.full(h.shape, 0.003**2), roof, span=np.zeros(h.shape)), g


def test_ground_under_a_ray_is_drawn_between_the_ground_round_it_and_the_ray() -> None:
    # at the ray (under_ray 0) every draw puts the shadow's ground 12 cm up, a step over the
    # climb at its edge wherever the truth is flat; drawn between the lowest top seen within
    # 0.2 m and the ray, its draws spread evenly over that depth
    post, g = shadow_beside_a_wheel(0.12)
    strip = ~np.isfinite(post.mean) & np.isfinite(post.ceiling)
    at_ray = np.array([s[strip] for s in surfaces(post, g, ChanceParams(samples=200))])
    assert np.allclose(at_ray, 0.12)
    under = np.array([s[strip] for s in surfaces(post, g, ChanceParams(samples=200, under_ray=1.0))])
    assert under.min() >= 0.0 and under.max() <= 0.12 + 1e-6
    assert np.mean(under) == pytest.approx(0.06, abs=0.006)  # uniform over the 12 cm
    assert np.mean(under > 0.10) == pytest.approx(2 / 12, abs=0.03)  # the share that hides a step
    # a rock's hidden back under rays 25 cm up is refused either way: it may hide a step the
    # wheel cannot climb
    post, g = shadow_beside_a_wheel(0.25)
    for share in (0.0, 1.0):
        c = chance_check(post, g, AT_ORIGIN, BODY, ChanceParams(under_ray=share))
        assert not c.safe[0] and not c.unknown[0] and c.prob[0, STEP] > c.epsilon

    # beside a rock seen in the next cell, 20 cm up, the ground under the ray may be the rock's back
    # the mast does not see: there the draws keep the ceiling
    post, g = shadow_beside_a_wheel(0.12)
    mean = post.mean.copy()
    r, c = np.argwhere(strip)[0]
    mean[r, c - 1] = 0.2
    rock = Posterior(mean, post.var, post.ceiling, span=post.span)
    drawn = np.array([s[r, c] for s in surfaces(rock, g, ChanceParams(samples=50, under_ray=1.0))])
    assert np.allclose(drawn, 0.12)


def test_a_wheel_on_cells_two_frames_disagree_on_rests_on_either_frame_s_story() -> None:
    # a rock 5 mm over the clearance under the belly's front, and the front wheels' cells where one
    # frame read the ground 4 cm high and the other at 0 (the truth): the union's top lifts the
    # front wheels and the belly clears the rock by 2.8 cm; each frame's story in turn (one story
    # over a patch) puts a wheel down and the belly into the rock
    g, X, Y = grid()
    top = np.zeros(g.shape)
    rock = (X > 0.05) & (X < 0.2) & (np.abs(Y) < 0.1)
    top[rock] = BODY.clearance + 0.005
    wheels = (X > 0.05) & (X < 0.3) & (np.abs(Y) > 0.18) & (np.abs(Y) < 0.32)
    union = np.where(wheels, 0.04, top)
    st = spread(union, np.zeros(g.shape, bool), 0.0)
    st["relief"], st["split"] = np.zeros(g.shape), np.where(wheels, 0.04, 0.0)
    belly = LIMITS.index("belly")
    assert check_poses(top.astype(np.float32), g, AT_ORIGIN, BODY).excess[0, belly] == pytest.approx(0.005, abs=0.001)
    kept = chance_check(posterior(st, g, 2.5, ChanceParams(within=1.0, **BARE)), g, AT_ORIGIN, BODY)
    assert kept.safe.tolist() == [True] and kept.nominal.excess[0, belly] < -0.02  # the union: a false safe
    post = posterior(st, g, 2.5, ChanceParams(within=1.0, stories=True, **BARE))
    assert post.split[wheels] == pytest.approx(0.04) and post.split[~wheels].max() == 0.0
    told = chance_check(post, g, AT_ORIGIN, BODY)
    assert told.safe.tolist() == [False] and told.prob[0, belly] > 0.05
    # without the rock, either story is safe ground: the stories refuse nothing the truth allows
    st["mean"][rock] = 0.0
    flat = chance_check(posterior(st, g, 2.5, ChanceParams(within=1.0, stories=True, **BARE)), g, AT_ORIGIN, BODY)
    assert flat.safe.tolist() == [True]
    # the draws a trace reads are the check's: some put the wheels' cells on the other story
    drawn = np.array([s[wheels].mean() for s in surfaces(post, g, ChanceParams(within=1.0, stories=True, **BARE))])
    assert (drawn < 0.02).any() and (drawn > 0.02).any()


def test_the_belly_s_tail_does_not_run_past_the_ceiling_the_rover_stood_under() -> None:
    """A rover stands on ground round it that is a prior known to 3 cm (sd), as the set-down's is,
    its wheels' contacts known to their contact sigma and its belly setting a ceiling over the box
    (BoundsMap.stood). No draw puts the belly through, yet the normal fitted to the draws'
    intrusion runs on past the ceiling that stops them and puts its own pose over epsilon. The
    check's tail takes the ceiling: the pose is safe, and the same prior with no ceiling is not
    (dense_fresh 0's start: docs/NAVIGATE_BENCH.md, Dense starts that stop cold)."""
    g = GridGeometry.covering(-1.0, -1.0, 1.0, 1.0, 0.025)
    pose = (0.0, 0.0, 0.0)
    m = BoundsMap(g, BoundsParams())
    m.set_down((0.0, 0.0), 0.9, 0.0, sigma=0.03)
    m.stood(pose, 0.0, BODY, (0.0, 0.0, 0.05))
    s, sub = m.statistics(-1.0, -1.0, 1.0, 1.0)
    post = posterior(s, sub, m.params.k)
    # the wheels' contacts to their contact sigma alone (the posterior adds a frame's top sigma)
    contact = np.isfinite(s["mean"]) & (s["mean_var"] < 1e-5)
    post = Posterior(post.mean, np.where(contact, s["mean_var"], post.var), post.ceiling, post.common,
                     np.where(contact, 0.0, post.shared))
    p = ChanceParams()
    belly = LIMITS.index("belly")
    drawn = np.array([check_poses(d, sub, np.array([pose]), BODY).excess[0, belly] for d in surfaces(post, sub, p)])
    assert drawn.max() < 0
    from scipy.special import ndtr
    assert ndtr(drawn.mean() / drawn.std(ddof=1)) > p.epsilon  # the draws' own normal refuses
    check = chance_check(post, sub, np.array([pose]), BODY, p)
    assert check.safe.tolist() == [True] and check.prob[0, belly] < 1e-4
    open_sky = Posterior(post.mean, post.var, np.full(post.mean.shape, np.inf), post.common, post.shared)
    assert chance_check(open_sky, sub, np.array([pose]), BODY, p).safe.tolist() == [False]



def test_a_prior_s_cells_neither_have_nor_lend_a_rock_edge() -> None:
    """The rock edge (headroom) is a frame's error: a top a frame read low beside ground its bounds
    allow higher. A prior's upper bound is its own sigma, which its variance already carries; beside
    framed ground it lends that ground no edge, and it has none of its own. Ground only a ray
    bounds (no top) still lends its edge."""
    g = GridGeometry.covering(-0.5, -0.5, 0.5, 0.5, 0.025)
    xs, ys = g.centers()
    X, _ = np.meshgrid(xs, ys)
    top = np.zeros(X.shape)
    s = stats(top, 0.002, 0.01)
    framed = X < 0.0
    s["framed"] = framed
    s["mean_var"] = np.where(framed, 0.002**2, 0.02**2)  # a prior known to 2 cm beyond x = 0
    s["upper"] = np.where(framed, top, top + 2.5 * 0.02)
    p = ChanceParams(rock_sigma=0.0)
    post = posterior(s, g, 2.5, p)
    edge = np.abs(X + 0.0125) < 1e-6  # the framed column beside the prior
    np.testing.assert_allclose(post.mean[edge], 0.0, atol=1e-12)
    np.testing.assert_allclose(np.broadcast_to(post.common, X.shape)[~framed], 0.0, atol=1e-12)
    np.testing.assert_allclose(np.broadcast_to(post.common, X.shape)[edge], 0.0, atol=1e-12)
    # the same 5 cm a ray allows over cells with no top beyond x = 0: an edge the framed cells read low
    ray = dict(s, framed=np.ones(X.shape, bool), mean=np.where(framed, top, np.nan))
    ray_post = posterior(ray, g, 2.5, p)
    assert (ray_post.mean[edge] > 0.0).all() and (np.broadcast_to(ray_post.common, X.shape)[edge] > 0.0).all()


def test_a_prior_s_slope_is_no_rock_top() -> None:
    """On a prior (the set-down's plane, here 10 % steep) a cell's height over the lowest ground
    round it is the plane's slope, not a rock's top a frame read low: the prior's cells carry their
    prior's error and the relief no return met, and framed cells on the same slope the rock top's."""
    g = GridGeometry.covering(-1.0, -1.0, 1.0, 1.0, 0.025)
    xs, ys = g.centers()
    X, _ = np.meshgrid(xs, ys)
    m = BoundsMap(g, BoundsParams())
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(0.5, 0.95, 8000), rng.uniform(-0.95, 0.95, 8000), np.zeros(8000)])
    pts[:, 2] = 0.1 * pts[:, 0] + 0.001 * rng.standard_normal(len(pts))
    m.fuse(pts, 0.001)
    m.set_down((-0.3, 0.0), 0.6, -0.03, sigma=0.02, plane=(-0.3, 0.0, 0.1, 0.0))
    s, sub = m.statistics(-1.0, -1.0, 1.0, 1.0)
    p = ChanceParams()
    post = posterior(s, sub, m.params.k, p)
    common = np.broadcast_to(post.common, X.shape)
    prior = np.isfinite(s["mean"]) & ~s["framed"]
    assert prior.sum() > 500
    np.testing.assert_allclose(common[prior], 0.0, atol=1e-12)
    np.testing.assert_allclose(post.var[prior], p.prior_own * 0.02**2 + p.top_sigma**2, rtol=1e-5)
    inner = s["framed"] & (X > 0.6) & (X < 0.9)
    assert (common[inner] > 0).mean() > 0.5  # the slope within ROCK_WINDOW reads as a rock top there
