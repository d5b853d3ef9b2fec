"""The ENav-style candidate search (prox_workflows.algorithms.candidates) on synthetic surfaces:
a 1 cm truth, and the 5 cm bounds a perfect map of it would hold, with the vehicle check of the
declared body on those bounds.

The bounds are each cell's lowest and highest true height half a centimetre out, spread over the
neighbouring cells as the bounds map spreads a return over the cells its horizontal error may
move it to: the check samples bounds bilinearly between cell centres, which holds the truth only
where a cell's bound also covers its neighbours' half (a rock whose edge lies on a cell's edge is
read up to 15 cm low a centimetre inside it without the spread).
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from scipy import ndimage

from drivers.sim.rover import RoverBody
from prox_workflows.algorithms.candidates import (
    SAFE,
    CandidateParams,
    arc_tree,
    bounds_check,
    choose,
    coarse_costs,
    cost_to_go,
    nearest_refusal,
    over_rays,
    posterior_check,
)
from prox_workflows.algorithms.chance import ChanceParams, Posterior
from prox_workflows.algorithms.vehicle import check_poses, densify, reach
from prox_workflows.grid import GridGeometry

BODY = RoverBody()
AREA = (-3.0, -3.0, 7.0, 3.0)  # xmin, ymin, xmax, ymax


class World:
    """A 1 cm true surface over AREA and its 5 cm bounds; ``unseen`` cells (5 cm) have none."""

    def __init__(self) -> None:
        self.tg = GridGeometry.covering(*AREA, 0.01)
        xs, ys = self.tg.centers()
        self.X, self.Y = np.meshgrid(xs, ys)
        self.truth = np.zeros(self.X.shape)
        self.g = GridGeometry.covering(*AREA, 0.05)
        self.unseen = np.zeros(self.g.shape, bool)

    def box(self, x0: float, x1: float, y0: float, y1: float, height: float) -> None:
        on = (self.X >= x0) & (self.X <= x1) & (self.Y >= y0) & (self.Y <= y1)
        self.truth[on] = np.maximum(self.truth[on], height)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        blocks = self.truth.reshape(self.g.height, 5, self.g.width, 5)
        lower = ndimage.minimum_filter(blocks.min(axis=(1, 3)), 3) - 0.005
        upper = ndimage.maximum_filter(blocks.max(axis=(1, 3)), 3) + 0.005
        lower[self.unseen], upper[self.unseen] = np.nan, np.nan
        return lower, upper

    def choose(self, pose: tuple[float, float, float], goal: tuple[float, float], check=None, **kw):
        heights = self.bounds()
        cost, cg = coarse_costs(heights, self.g, BODY)
        ctg = cost_to_go(cost, cg, goal)
        return choose(pose, heights, self.g, BODY, ctg, check or bounds_check(heights, self.g, BODY),
                      CandidateParams(**kw))

    def truly_safe(self, poses: np.ndarray) -> bool:
        dense = densify(poses, 0.02, BODY)
        return bool(check_poses(self.truth, self.tg, dense, BODY).safe.all())


def test_the_tree_holds_turns_sections_and_look_aheads_from_the_rover() -> None:
    tree = arc_tree(CandidateParams(), BODY)
    assert len(tree.paths) == 16 * 9 * 9
    assert (tree.part == 0).sum() == 16 and (tree.part == 1).sum() == 144
    # every section is 1 m of arc after its turn, every candidate 2.5 m deep; a candidate's nodes chain
    for t, s, b in tree.paths[::97]:
        assert tree.parent[s] == t and tree.parent[b] == s
        end = tree.node(s)[-1]
        assert math.hypot(end[0], end[1]) <= 1.0 + 1e-9
        assert tree.length[s] == pytest.approx(1.0) and tree.length[b] == pytest.approx(1.5)
    # poses no more than 5 cm apart at the body's farthest point through the sections
    seg = np.vstack([[0, 0, 0], tree.node(tree.paths[5][0]), tree.node(tree.paths[5][1])])
    moved = np.hypot(*np.diff(seg[:, :2], axis=0).T) + np.radians(np.abs(np.diff(seg[:, 2]))) * reach(BODY)
    assert moved.max() <= 0.05 + 1e-6


def test_on_flat_ground_it_commits_a_section_straight_to_the_goal_after_few_checks() -> None:
    w = World()
    sent: list[int] = []
    check = bounds_check(w.bounds(), w.g, BODY)

    def counting(poses: np.ndarray) -> np.ndarray:
        sent.append(len(poses))
        return check(poses)

    c = w.choose((0.0, 0.0, 0.0), (6.0, 0.0), counting)
    assert c.status == "drive", c.reason
    assert c.poses[0].tolist() == [0.0, 0.0, 0.0]
    end = c.poses[-1]
    assert end[0] == pytest.approx(1.0, abs=1e-6) and abs(end[1]) < 1e-6 and abs(end[2]) < 1e-6
    assert c.rank == 0 and not c.failures
    # lazy: one batch of four, against 1,296 candidates ranked
    assert c.total == 1296 and c.checked <= 4 and sum(sent) == c.poses_checked < 400
    assert w.truly_safe(c.poses)


def test_it_threads_the_gap_in_a_wall_of_rocks() -> None:
    w = World()
    w.box(1.5, 1.7, -3.0, 0.05, 0.25)  # a 25 cm ridge across the way: no wheel climbs it, no belly clears it
    w.box(1.5, 1.7, 1.15, 3.0, 0.25)  # ... with a 1.1 m gap from y 0.05 to 1.15
    c = w.choose((0.0, 0.0, 0.0), (5.0, 0.0))
    assert c.status == "drive", c.reason
    # any candidate ranked before it failed at the ridge
    assert all(f.part == "beyond" and 1.0 < f.x < 1.8 for f in c.failures if f.verdict != "unknown")
    # it heads for the gap: the section bends left, and the whole path crosses the ridge inside the gap
    assert c.poses[-1][1] > 0.1
    crossing = c.path[(c.path[:, 0] > 1.45) & (c.path[:, 0] < 1.75)]
    assert len(crossing) and (crossing[:, 1] > 0.05 + 0.29).all() and (crossing[:, 1] < 1.15 - 0.29).all()
    # what it commits passes the vehicle check on the true 1 cm surface, and so does the rest of its way
    assert w.truly_safe(c.poses)
    assert w.truly_safe(c.path)


def test_a_look_ahead_over_a_limit_ranks_its_section_down_instead_of_refusing_it() -> None:
    """The look-ahead is judged 1-2.5 m out, on ground seen from afar: its verdict prices the
    continuation it would lose, and the section, judged in full, still decides what is driven;
    except where it fails within ``ahead_min`` of the section's end."""
    w = World()
    heights = w.bounds()
    cost, cg = coarse_costs(heights, w.g, BODY)
    ctg = cost_to_go(cost, cg, (5.0, 0.0))
    check = bounds_check(heights, w.g, BODY)

    def rock_past(x0: float):  # a rock straight ahead past x0, judged over the belly limit
        def ahead(poses: np.ndarray) -> np.ndarray:
            return np.where((np.abs(poses[:, 1]) < 0.4) & (poses[:, 0] > x0), 2, SAFE)
        return ahead

    far, near = rock_past(1.8), rock_past(1.2)  # 0.8 m and 0.2 m past the straight section's end

    def pick(ahead, **kw):  # noqa: ANN001, ANN202
        return choose((0.0, 0.0, 0.0), heights, w.g, BODY, ctg, check, CandidateParams(**kw), ahead)

    priced = pick(far, ahead_cost=0.1)
    assert priced.status == "drive" and "priced" in priced.reason and priced.rank == 0
    assert priced.poses[-1][0] == pytest.approx(1.0, abs=1e-6) and abs(priced.poses[-1][1]) < 1e-6
    assert (far(priced.path) > 0).any()
    veto = pick(far, ahead_cost=0.0)
    assert veto.status == "drive" and "priced" not in veto.reason and not (far(veto.path) > 0).any()
    # the straight section is refused where its look-ahead fails within ahead_min of its end
    for c in (veto, pick(near, ahead_cost=0.1)):
        assert c.rank > 0 and c.failures[0].rank == 0 and c.failures[0].part == "beyond"
    # a continuation that passes whole costs less than the price of one that fails early
    c = pick(far, ahead_cost=2.0)
    assert c.status == "drive" and "priced" not in c.reason and not (far(c.path) > 0).any()

    def wall_past(poses: np.ndarray) -> np.ndarray:  # a wall 0.4 m past the straight section's end
        return np.where(poses[:, 0] > 1.4, 2, SAFE)

    # every continuation from the straight section's end fails: a pocket, not driven into, whatever
    # the price of its look-ahead
    c = pick(wall_past, ahead_cost=0.01, ahead_min=0.3)
    assert not (abs(c.poses[-1][0] - 1.0) < 1e-6 and abs(c.poses[-1][1]) < 1e-6)
    assert any(f.rank == 0 and f.part == "beyond" for f in c.failures)


def test_with_unseen_ground_ahead_it_commits_nothing_and_asks_to_look_there() -> None:
    w = World()
    xs, ys = w.g.centers()
    X, Y = np.meshgrid(xs, ys)
    w.unseen = np.hypot(X, Y) > 0.9  # only the ground under and beside the rover is known
    c = w.choose((0.0, 0.0, 0.0), (5.0, 0.0))
    assert c.status == "look" and len(c.poses) == 0, c.reason
    assert "look there" in c.reason
    x, y = c.look_at
    assert 0.3 < x < 1.5 and abs(y) < 0.5  # ahead, toward the goal
    assert c.failures and all(f.verdict == "unknown" for f in c.failures)
    # the same ground seen: it drives
    w.unseen[:] = False
    assert w.choose((0.0, 0.0, 0.0), (5.0, 0.0)).status == "drive"


def test_a_refusal_on_ground_only_a_ray_bounds_asks_for_a_look_there_first() -> None:
    """A limit judged where no return met the ground, only a ray's ceiling over it, is judged on
    the ground's highest possible: a path refused there that ranks before every passing one by
    more than the price of a look asks for that look; on ground frames bounded, the refusal
    stands; priced over the gap, the rover drives the passing path."""
    w = World()
    heights = w.bounds()
    cost, cg = coarse_costs(heights, w.g, BODY)
    ctg = cost_to_go(cost, cg, (5.0, 0.0))
    xs, ys = w.g.centers()
    X, Y = np.meshgrid(xs, ys)
    patch = (X > 1.6) & (X < 2.0) & (np.abs(Y) < 0.9)  # 1.6-2.0 m straight ahead, across the way to the goal
    mean = np.zeros(w.g.shape)
    ceiling = np.full(w.g.shape, np.inf)
    mean[patch], ceiling[patch] = np.nan, 0.12  # a ray 12 cm up passed over it, no return met it

    def check(poses: np.ndarray) -> np.ndarray:  # what the ceiling gives there: a step over the climb
        return np.where((np.abs(poses[:, 0] - 1.8) < 0.45) & (np.abs(poses[:, 1]) < 1.1), 1, SAFE)

    rays = over_rays(mean, ceiling, w.g, BODY)
    # the box over the patch (the middle of what it covers of it), beside it, short of it, and its
    # front edge (0.255 m ahead of its centre) over the patch's first cells
    at = rays(np.array([[1.8, 0.0, 0.0], [1.8, 1.2, 0.0], [1.2, 0.0, 0.0], [1.4, 0.0, 0.0]]))
    assert at[0] == pytest.approx([1.8, 0.0], abs=0.03)
    assert np.isnan(at[1]).all() and np.isnan(at[2]).all()
    assert 1.6 < at[3][0] < 1.66 and abs(at[3][1]) < 0.01

    def pick(rays_=None, **kw):  # noqa: ANN001, ANN202
        return choose((0.0, 0.0, 0.0), heights, w.g, BODY, ctg, check, CandidateParams(**kw), rays=rays_)

    without = pick()
    assert without.status == "drive" and without.rank > 0 and without.failures[0].rank == 0
    gap = without.cost - 5.0  # what going round costs over the straight way (5 m to the goal)
    assert 0.5 < gap < 5.0
    c = pick(rays, ray_look_cost=gap / 2)
    assert c.status == "look" and c.look_for == "ray" and len(c.poses) == 0, c.reason
    assert "a ray bounds" in c.reason
    x, y = c.look_at  # at the patch, not at the refused pose's centre
    assert 1.6 < x < 2.0 and abs(y) < 0.9
    # the same refusal on ground a frame bounded: no look, the passing path is driven
    framed = pick(over_rays(np.zeros(w.g.shape), ceiling, w.g, BODY), ray_look_cost=gap / 2)
    assert framed.status == "drive" and framed.rank == without.rank
    # a look priced over what ranking past the refused paths costs: the passing path is driven
    dear = pick(rays, ray_look_cost=gap * 1.5)
    assert dear.status == "drive" and dear.rank == without.rank


def test_unseen_ground_beyond_the_section_is_a_cost_not_a_refusal() -> None:
    w = World()
    xs, ys = w.g.centers()
    X, _ = np.meshgrid(xs, ys)
    w.unseen = X > 1.6  # the section's band is seen, the look-ahead's is not
    c = w.choose((0.0, 0.0, 0.0), (5.0, 0.0))
    assert c.status == "drive", c.reason
    assert c.poses[-1][0] == pytest.approx(1.0, abs=1e-6)
    assert w.truly_safe(c.poses)


def test_with_the_goal_behind_it_turns_on_the_spot_first() -> None:
    w = World()
    c = w.choose((1.0, 0.0, 0.0), (-2.5, 0.0))
    assert c.status == "drive", c.reason
    turning = c.poses[1:][np.hypot(c.poses[1:, 0] - 1.0, c.poses[1:, 1]) < 1e-9]
    assert len(turning) > 5  # the first poses turn on the spot
    assert abs(turning[-1, 2]) >= 135.0
    assert c.poses[-1][0] < 0.2 and abs(c.poses[-1][2]) > 150.0  # then it drives toward the goal
    assert w.truly_safe(c.poses)


def test_walled_in_it_says_blocked_with_each_candidates_limit() -> None:
    w = World()
    X, Y = w.X, w.Y
    ring = (np.hypot(X, Y) > 0.75) & (np.hypot(X, Y) < 0.95)
    w.truth[ring] = 0.3
    c = w.choose((0.0, 0.0, 0.0), (5.0, 0.0))
    assert c.status == "blocked" and len(c.poses) == 0
    assert "limits" in c.reason
    assert c.checked == c.total
    assert c.reasons and not any("unknown" in k for k in c.reasons)


def test_a_prefix_is_judged_once_and_a_refused_section_spares_its_look_aheads() -> None:
    w = World()
    w.box(0.7, 0.9, -0.6, 0.6, 0.25)  # a rock in the way of the straight sections
    heights = w.bounds()
    check = bounds_check(heights, w.g, BODY)
    sent: list[np.ndarray] = []

    def recording(poses: np.ndarray) -> np.ndarray:
        sent.append(poses.copy())
        return check(poses)

    # the tree's poses alone (the poses between a chosen candidate's are judged apart: verify_step)
    c = w.choose((0.0, 0.0, 0.0), (5.0, 0.0), recording, verify_step=0.0)
    assert c.status == "drive" and c.rank > 0
    allp = np.vstack(sent)
    assert len(np.unique(np.round(allp, 9), axis=0)) == len(allp)  # no pose sent twice
    # past the first batch (sent whole, in one call), a refused section's look-aheads are never sent
    failed_sections = {f.candidate for f in c.failures if f.part == "section" and f.rank >= CandidateParams().batch}
    assert failed_sections
    tree = arc_tree(CandidateParams(), BODY)
    seen = {tuple(np.round(p, 6)) for p in allp}
    for cand in failed_sections:
        leaf = tree.node(int(tree.paths[cand][2]))
        # the look-ahead's poses, in the world (the rover at the origin, heading 0: the same)
        assert not any(tuple(np.round(p, 6)) in seen for p in leaf)
    assert w.truly_safe(c.poses)


def test_a_turn_is_judged_between_its_poses_before_it_is_chosen() -> None:
    # a 2 cm post, 15 cm high, on the circle the rear-left wheel's outer corner sweeps turning
    # right, between two of the tree's headings (5 cm apart there): the tree's poses of a turn
    # toward a goal on the right all pass it, and the corner passes over it between them
    w = World()
    w.box(-0.03, -0.01, 0.365, 0.385, 0.15)
    check = bounds_check(w.truth, w.tg, BODY)  # the 1 cm truth itself: no error in the map
    coarse = w.choose((0.0, 0.0, 0.0), (0.0, -5.0), check, verify_step=0.0)
    assert coarse.status == "drive" and coarse.turn < -60
    assert check_poses(w.truth, w.tg, coarse.poses, BODY).safe.all()  # every pose the tree judged
    assert not w.truly_safe(coarse.poses)  # and the turn between them
    fine = w.choose((0.0, 0.0, 0.0), (0.0, -5.0), check)
    assert fine.status == "drive" and w.truly_safe(fine.poses)
    assert any(f.part == "turn" and f.verdict == "step" for f in fine.failures)


def test_the_cost_to_go_takes_unseen_ground_as_a_cost_and_known_walls_as_walls() -> None:
    g = GridGeometry(0.25, 0.0, 5.0, 20, 20)
    cost = np.ones(g.shape)
    cost[10, :16] = np.inf  # a wall across, open at its east end
    cost[:5, :] = 2.0  # unseen ground to the north
    ctg = cost_to_go(cost, g, (2.5, 0.5))
    assert ctg.at(np.array([2.5]), np.array([0.5]))[0] == pytest.approx(0.0, abs=0.2)
    behind = float(ctg.at(np.array([0.5]), np.array([3.5]))[0])
    assert behind > 2 * math.hypot(3.5 - 0.5, 2.0) * 0.9  # around the wall's end, not through it
    assert np.isfinite(ctg.field[:5]).all()  # unseen ground is not a wall
    # a goal off the grid is reached over the border
    far = cost_to_go(np.ones(g.shape), g, (20.0, 2.5))
    assert far.at(np.array([4.9]), np.array([2.5]))[0] == pytest.approx(15.1, abs=0.2)


def test_the_coarse_cost_from_the_vehicle_check_prices_what_the_body_meets_not_the_slope() -> None:
    """``rough_headings``: a coarse cell costs 1 + rough_cost times the share of the poses centred
    on it that the check refuses. A slope within the grade, which the relief prices, is free; a
    rock the body straddles is free; one under the belly costs the most, and the cells round it
    what the headings that reach it refuse. Unseen ground keeps its own cost."""
    g = GridGeometry(0.05, 0.0, 4.0, 80, 80)
    x = (np.arange(80) + 0.5) * g.cell
    slope = np.tile(x * math.tan(math.radians(8.0)), (80, 1))
    slope[36:39, 36:39] += 0.07  # 7 cm, 15 cm across: below the belly's 8 cm and the wheels' climb
    relief, _ = coarse_costs(slope, g, BODY)
    checked, _ = coarse_costs(slope, g, BODY, rough_headings=4)
    assert relief[4, 4] == pytest.approx(1 + 0.2 * math.tan(math.radians(8.0)) / BODY.climb)
    assert relief[7, 7] > 1.8
    assert (checked[1:15, 1:15] == 1.0).all()  # within the grid's edge, where every pose is judged
    flat = np.zeros(g.shape)
    flat[36:39, 36:39] = 0.09  # 9 cm: over the belly's clearance, under the climb (not a wall)
    flat[:, 75:] = np.nan  # the east strip unseen (coarse column 15)
    cost, _ = coarse_costs(flat, g, BODY, rough_cost=3.0, rough_headings=4)
    assert cost[7, 7] == 4.0  # every heading centred on it puts the rock under the belly
    assert cost[6, 7] == cost[7, 6] == cost[8, 7] == cost[7, 8] == 1.75  # one heading of four reaches it
    assert cost[5, 5] == 1.0 and cost[9, 9] == 1.0
    assert (cost[:, 15] == 2.0).all()  # unseen: UNKNOWN_COST


def test_the_check_wrapper_names_unknown_and_limits() -> None:
    w = World()
    w.box(1.9, 2.1, -0.1, 0.1, 0.3)
    w.unseen[:, w.g.cell_of(np.array([0.0]), np.array([-2.5]))[1][0]:][:5] = True
    check = bounds_check(w.bounds(), w.g, BODY)
    codes = check(np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.9, 0.0]]))
    assert codes[0] == SAFE and codes[1] > 0 and codes[2] == -1


def test_a_pose_budget_stops_the_search_and_says_so() -> None:
    w = World()
    ring = (np.hypot(w.X, w.Y) > 0.75) & (np.hypot(w.X, w.Y) < 0.95)
    w.truth[ring] = 0.3
    c = w.choose((0.0, 0.0, 0.0), (5.0, 0.0), max_poses=300)
    assert c.status == "blocked" and "budget of 300 poses" in c.reason
    assert 0 < c.checked < c.total and c.poses_checked >= 300


def test_a_section_passing_the_goal_stops_at_it() -> None:
    w = World()
    c = w.choose((0.0, 0.0, 0.0), (0.6, 0.02))
    assert c.status == "drive", c.reason
    end = c.poses[-1]
    assert math.hypot(end[0] - 0.6, end[1] - 0.02) <= 0.1
    assert len(c.poses) < len(c.path) - 20  # cut short of its 1 m section


def test_the_chance_check_draws_a_section_no_further_than_its_first_refusal_and_chooses_the_same(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Sections are read to their first failing pose: the draws past it are not made, and the
    choice and every failure (candidate, part, limit, place) are what judging every pose gives."""
    import prox_workflows.algorithms.chance as chance

    w = World()
    w.box(0.6, 1.5, -0.35, 0.35, 0.085)  # a ledge 0.6 m ahead a wheel may just climb, on the best estimate
    w.box(0.5, 0.7, 0.55, 0.8, 0.2)
    blocks = w.truth.reshape(w.g.height, 5, w.g.width, 5).max(axis=(1, 3))
    post = Posterior(blocks, np.full(blocks.shape, 0.006**2), np.full(blocks.shape, np.inf))
    check = posterior_check(post, w.g, BODY)
    drawn: list[int] = []
    real = chance.check_poses

    def counted(heights, geom, poses, body, step=None):  # noqa: ANN001, ANN202
        if not isinstance(heights, tuple) and len(poses):
            drawn.append(len(poses))
        return real(heights, geom, poses, body, step)

    monkeypatch.setattr(chance, "check_poses", counted)
    by_runs = w.choose((0.0, 0.0, 0.0), (5.0, 0.0), check)
    with_runs = sum(drawn)
    drawn.clear()
    every = w.choose((0.0, 0.0, 0.0), (5.0, 0.0), lambda poses: check(poses))  # no runs: every pose judged
    assert by_runs.status == every.status == "drive" and by_runs.candidate != 0  # not straight on
    assert (by_runs.candidate, by_runs.rank, by_runs.checked) == (every.candidate, every.rank, every.checked)
    assert by_runs.failures == every.failures and len(every.failures) > 0
    assert any(f.part == "section" for f in every.failures)
    np.testing.assert_array_equal(by_runs.poses, every.poses)
    # the draws: one check per pose and draw, fewer where sections stop at their first refusal (8 %
    # here: how many depends on where the draws put the first refusals)
    assert with_runs < 0.95 * sum(drawn)


@pytest.mark.parametrize(("height", "over"), [(0.3, True), (0.085, False)])
def test_a_blocked_choice_names_the_candidate_nearest_to_passing(height: float, over: bool) -> None:
    """Walled in by rock, the nearest candidate is over a limit on the best estimate (P about 1);
    by a ledge the wheels could just climb, every candidate is inside the limits on the best
    estimate and refused on its draws alone, at a probability above epsilon but far under 0.5:
    the operator's call, which the sentence must tell from the wall."""
    w = World()
    w.truth[(np.hypot(w.X, w.Y) > 0.75) & (np.hypot(w.X, w.Y) < 0.95)] = height
    blocks = w.truth.reshape(w.g.height, 5, w.g.width, 5).max(axis=(1, 3))
    post = Posterior(blocks, np.full(blocks.shape, 0.006**2), np.full(blocks.shape, np.inf))
    params = CandidateParams(headings=8, arcs=3)
    c = w.choose((0.0, 0.0, 0.0), (5.0, 0.0), posterior_check(post, w.g, BODY), headings=8, arcs=3)
    assert c.status == "blocked"
    said = nearest_refusal(post, w.g, BODY, (0.0, 0.0, 0.0), c.failures, params)
    m = re.search(r"ranked (\d+), is at worst at \(.*\): P\((\w+)\) ([0-9.e+-]+) against epsilon ([0-9.e+-]+), "
                  r"the best estimate [0-9.]+ (cm|deg) (inside|over) the limit$", said)
    assert m, said
    rank, limit, p, epsilon = int(m[1]), m[2], float(m[3]), float(m[4])
    assert 1 <= rank <= c.total and limit == "step" and epsilon == ChanceParams().epsilon
    assert (p >= 0.5) == over and p > epsilon and (m[6] == "over") == over
    # where nothing was refused on a limit, there is nothing to name
    assert nearest_refusal(post, w.g, BODY, (0.0, 0.0, 0.0), [f for f in c.failures if f.part == "beyond"],
                           params) == ""
