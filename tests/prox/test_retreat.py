"""Backing out of a dead end (prox_workflows.algorithms.retreat): the reverse sections and their
check, and the dead end's cost on the cost to go."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.sim.rover import RoverBody
from prox_workflows.algorithms.arcs import arc_poses
from prox_workflows.algorithms.bounds_map import BoundsMap
from prox_workflows.algorithms.candidates import coarse_costs, cost_to_go, posterior_check
from prox_workflows.algorithms.chance import ChanceParams, posterior
from prox_workflows.algorithms.retreat import (
    DeadEnd,
    RetreatBudget,
    RetreatParams,
    add_dead_ends,
    choose_reverse,
    reverse_options,
)
from prox_workflows.grid import GridGeometry

BODY = RoverBody()
POSE = (0.0, 0.0, 0.0)


def _ground(x0: float, x1: float, rock: tuple[float, float, float, float] | None = None) -> np.ndarray:
    """Every centimetre of level ground at z 0 over x0..x1, y -1..1 m; ``rock`` (x0, x1, half width,
    height) a block on it."""
    x, y = (a.ravel() for a in np.meshgrid(np.arange(x0, x1, 0.01) + 0.005, np.arange(-1.0, 1.0, 0.01) + 0.005))
    z = np.zeros_like(x)
    if rock is not None:
        z = np.where((x > rock[0]) & (x < rock[1]) & (np.abs(y) < rock[2]), rock[3], z)
    return np.column_stack([x, y, z])


def _choose(bounds: BoundsMap, track_back: tuple[float, float] | None, track: str = "framed"):
    """The reverse choice from POSE as the see loop makes it: the reverse arcs on the chance check,
    the track back with ``track`` (``sections.map_check``'s: framed, as the loop judges it)."""
    from rvs_server.navigation.sections import map_check

    chance = ChanceParams()
    stats, g = bounds.statistics(-2.0, -1.0, 1.0, 1.0)
    check = posterior_check(posterior(stats, g, bounds.params.k, chance), g, BODY, chance)
    lower, upper, wg = bounds.window(-2.0, -1.0, 1.0, 1.0)
    ctg = cost_to_go(*coarse_costs((lower, upper), wg, BODY), (3.0, 0.0))
    options = reverse_options(POSE, track_back, RetreatParams(), 2.4, 0.05)
    return choose_reverse(POSE, options, check, ctg, map_check(bounds, (-2.0, -1.0, 1.0, 1.0), BODY, track, chance))


def _map(*grounds: np.ndarray) -> BoundsMap:
    bounds = BoundsMap.covering([[-2.0, -1.0], [1.0, 1.0]], 0.0)
    for ground in grounds:
        bounds.fuse(ground, 0.002, np.array([0.0, 0.0, 0.8]))
    return bounds


def test_arc_poses_with_a_negative_length_run_backwards_with_the_body_s_heading() -> None:
    back = arc_poses((1.0, 2.0, 90.0), 0.0, -0.6, 0.05)
    assert len(back) == 13
    np.testing.assert_allclose(back[-1], [1.0, 1.4, 90.0], atol=1e-9)
    left = arc_poses((0.0, 0.0, 0.0), 1.0, -0.5, 0.05)  # backing on a left arc: the heading falls
    assert left[-1, 0] < 0 and left[-1, 1] > 0 and left[-1, 2] == pytest.approx(-np.degrees(0.5))


def test_a_reverse_arc_is_never_judged_on_unseen_ground() -> None:
    """Level ground seen only ahead of the rover and under it (x from -0.35 m on): every reverse arc
    puts the body's rear on ground no frame has bounded and fails as unknown; the same ground seen
    behind lets a reverse arc pass."""
    blind = _choose(_map(_ground(-0.35, 1.0)), None)
    assert blind.status == "blocked", blind.reason
    assert blind.reasons == {"reverse arc unknown": 5}, blind.reasons
    seen = _choose(_map(_ground(-0.35, 1.0), _ground(-2.0, -0.35)), None)
    assert seen.status == "drive" and seen.backward == "arc", seen.reason
    assert seen.poses[-1, 0] < -0.3 and np.all(np.diff(seen.poses[:, 0]) < 0)  # backwards all the way
    assert seen.poses[-1, 2] == pytest.approx(-np.degrees(seen.curvature * seen.length))  # the body's heading


def test_the_track_back_passes_over_ground_the_body_drove_and_not_over_a_rock_seen_on_it() -> None:
    """The track back (the last arc driven, reversed) runs over ground the body stood on: the map
    not bounding it is no reason to refuse it, while the reverse arcs there fail as unknown. A rock
    the map shows on that track refuses it on a limit."""
    driven = _choose(_map(_ground(-0.35, 1.0)), (0.0, 0.6))
    assert driven.status == "drive" and driven.backward == "track", driven.reason
    assert driven.poses[-1, 0] == pytest.approx(-0.6) and driven.length == pytest.approx(0.6)
    rock = _choose(_map(_ground(-0.35, 1.0), _ground(-2.0, -0.35, (-0.9, -0.6, 0.3, 0.2))), (0.0, 0.6))
    assert not (rock.status == "drive" and rock.backward == "track"), rock.reason
    assert any(k.startswith("track back ") and not k.endswith("unknown") for k in rock.reasons), rock.reasons


def test_the_track_back_is_taken_where_it_passes_though_a_reverse_arc_ends_nearer_the_goal() -> None:
    """Level ground seen all round: the track back (0.9 m straight back) and the reverse arcs
    (0.6 m) all pass, and the curved arcs end nearer the goal ahead. The track back is driven: its
    ground is the one the body proved; an arc is judged on the map that has just shown no way on."""
    bounds = _map(_ground(-0.35, 1.0), _ground(-2.0, -0.35))
    options = reverse_options(POSE, (0.0, 0.9), RetreatParams(), 2.4, 0.05)
    lower, upper, wg = bounds.window(-2.0, -1.0, 1.0, 1.0)
    ctg = cost_to_go(*coarse_costs((lower, upper), wg, BODY), (3.0, 0.0))
    ends = np.array([o.poses[-1, :2] for o in options])
    worth = ctg.at(ends[:, 0], ends[:, 1])
    assert worth[0] > worth[1:].min() + 0.2  # an arc's end is nearer the goal
    choice = _choose(bounds, (0.0, 0.9))
    assert choice.status == "drive" and choice.backward == "track", choice.reason
    assert choice.reasons == {}, choice.reasons  # every option passed
    assert choice.poses[-1, 0] == pytest.approx(-0.9)


def test_a_prior_on_the_track_back_does_not_refuse_it_where_no_frame_shows_a_change() -> None:
    """The start's blind disc holds the set-down's guess at the ground (a plane carried on from the
    ring round it), not a frame's: here 12 cm over the seen ground behind the rover, a step over
    the wheel's climb. The rover drove over that ground, so the track back over it passes (judged
    on the cells frames bounded only), where the best estimate, prior included, refuses it on the
    step; a reverse arc there still fails (its ground is no frame's and the body never stood on
    it)."""
    bounds = _map(_ground(-0.35, 1.0))
    bounds.set_down((-0.6, 0.0), 0.4, 0.12, sigma=0.005)
    on_prior = _choose(bounds, (0.0, 0.6), "best")
    assert not (on_prior.status == "drive" and on_prior.backward == "track"), on_prior.reason
    assert any(k.startswith("track back ") and not k.endswith("unknown") for k in on_prior.reasons), \
        on_prior.reasons
    driven = _choose(bounds, (0.0, 0.6))
    assert driven.status == "drive" and driven.backward == "track", driven.reason
    assert driven.poses[-1, 0] == pytest.approx(-0.6)


def test_a_dead_end_prices_its_disc_until_frames_from_outside_cover_it() -> None:
    """A dead end adds its cost per metre on the coarse cells of its disc, so the cost to go through
    it rises and round it does not; walls stay walls. Frames the rover takes standing near it only
    move its mark; once frames taken from farther away cover half its ground, it expires."""
    g = GridGeometry(0.25, -2.0, 2.0, 16, 16)
    cost = np.ones((16, 16))
    cost[0, 0] = np.inf
    end = DeadEnd(0.0, 0.0, 0.6, mark=10)
    priced = add_dead_ends(cost, g, [end], 4.0)
    assert priced[8, 8] == 5.0 and priced[7, 7] == 5.0 and priced[8, 11] == 1.0 and np.isinf(priced[0, 0])
    before, after = cost_to_go(cost, g, (1.9, 0.0)), cost_to_go(priced, g, (1.9, 0.0))
    x, y = np.array([0.0, -1.9]), np.array([0.0, 0.0])
    inside, across = after.at(x, y) - before.at(x, y)
    assert inside >= 1.0  # out of the disc at 5 a metre instead of 1
    assert 0.1 < across < 4.0 * 1.2  # from beyond it, round it: dearer than straight, cheaper than through
    fine = GridGeometry(0.05, -2.0, 2.0, 80, 80)
    stamp = np.full((80, 80), 12, np.int32)  # frames 11 and 12 touched everything
    assert not end.expired((0.8, 0.0, 0.0), stamp, fine, 12, 1.0)  # near: its own frames
    assert end.mark == 12
    assert not end.expired((3.0, 0.0, 0.0), stamp, fine, 12, 1.0)  # far, but nothing new on it
    stamp[30:50, 30:50] = 13
    assert end.expired((3.0, 0.0, 0.0), stamp, fine, 13, 1.0)


def test_a_path_over_a_dead_end_pays_for_it_though_it_ends_beyond() -> None:
    """Level ground seen all round, the goal 3 m straight ahead: the chooser drives straight. With
    a dead end 1 m ahead (where the straight section ends; the look-ahead runs on past it, so the
    cost to go at the path's end does not see it) the straight way pays the dead end's price and
    another section is chosen."""
    from prox_workflows.algorithms.candidates import CandidateParams
    from rvs_server.navigation.sections import choose_from

    bounds = BoundsMap.covering([[-1.0, -1.0], [4.0, 1.0]], 0.0)
    bounds.fuse(_ground(-1.0, 4.0), 0.002, np.array([0.0, 0.0, 0.8]))
    args = (bounds, POSE, (3.0, 0.0), BODY, "chance", CandidateParams(), ChanceParams())
    free, _ = choose_from(*args)
    assert free.status == "drive" and free.turn == 0.0 and abs(free.curvature) < 1e-9, free.reason
    priced, _ = choose_from(*args, dead_ends=[DeadEnd(1.0, 0.0, 0.4, 0)], dead_end_cost=4.0)
    assert priced.status == "drive", priced.reason
    assert not (priced.turn == 0.0 and abs(priced.curvature) < 1e-9), (priced.turn, priced.curvature)
    assert np.hypot(priced.path[:, 0] - 1.0, priced.path[:, 1]).min() > 0.3  # round it


def test_the_reverse_section_chosen_is_judged_between_its_poses() -> None:
    # a check that passes the options' own poses and refuses every pose between them: the arc the
    # cost to go prefers is passed over once it is judged between its poses, and with every arc so
    # refused none is driven
    options = reverse_options(POSE, None, RetreatParams(), 2.4, 0.05)
    own = {tuple(np.round(p, 6)) for o in options for p in o.poses}

    def check(poses: np.ndarray) -> np.ndarray:
        return np.array([0 if tuple(np.round(p, 6)) in own else 2 for p in poses])

    cost, cg = coarse_costs((np.zeros((40, 40)), np.zeros((40, 40))), GridGeometry(0.05, -1.0, 1.0, 40, 40), BODY)
    ctg = cost_to_go(cost, cg, (-0.8, 0.6))
    coarse = choose_reverse(POSE, options, check, ctg)
    assert coarse.status == "drive"
    fine = choose_reverse(POSE, options, check, ctg, body=BODY, verify=0.02)
    assert fine.status == "blocked" and fine.reasons == {"reverse arc belly": len(options)}


def test_the_count_of_retreats_begins_again_each_time_the_rover_comes_regain_closer_to_the_goal() -> None:
    """A long traverse through rock meets more pockets than a short one: the budget of retreats is
    counted from where the rover stood, and begins again once it stands ``regain`` m closer to the
    goal than there (half the way there when that is less), never for standing as close again;
    with ``regain`` 0 it is the mission's."""
    budget = RetreatBudget(RetreatParams(retreats=2, regain=2.0))
    budget.stand(15.0)
    budget.made = 2
    assert budget.spent
    budget.stand(13.5)  # closer, not 2 m closer
    assert budget.spent and budget.count_from == 15.0
    assert str(budget) == "2 of 2 retreats made since the rover stood 15.00 m from the goal, none 2.00 m closer"
    budget.stand(13.0)
    assert not budget.spent and budget.made == 0 and budget.count_from == 13.0
    budget.made = 2
    budget.stand(14.0)  # backed away and back: the count stands
    budget.stand(13.0)
    assert budget.spent
    near = RetreatBudget(RetreatParams(retreats=2, regain=2.0))  # nearer than 4 m: half the way
    near.stand(1.9)
    near.made = 2
    near.stand(1.0)
    assert near.spent and str(near).endswith("none 0.95 m closer")
    near.stand(0.9)
    assert not near.spent and near.count_from == 0.9
    mission = RetreatBudget(RetreatParams(retreats=1, regain=0.0))
    mission.stand(15.0)
    mission.made = 1
    mission.stand(1.0)
    assert mission.spent and str(mission) == "1 of 1 retreats made in the mission"
    assert str(RetreatBudget(RetreatParams(retreats=0))) == "0 of 0 retreats made"
