"""The state lattice and its A* (prox_workflows.algorithms.lattice) with edge checks on arrays: the
primitives end where they say, the search goes round what its check refuses, proves a walled-in
goal unreachable, and judges lazily in batches without changing the path it finds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from prox_workflows.algorithms.lattice import EdgeCache, directions, primitives, search

RES = 0.05


def wall(x0: float, x1: float, y0: float, y1: float):
    """An edge check that refuses every pose whose centre lies in the box, and counts its calls."""
    calls = []

    def check(poses: np.ndarray) -> np.ndarray:
        calls.append(len(poses))
        x, y = poses[:, 0], poses[:, 1]
        return ~((x >= x0) & (x <= x1) & (y >= y0) & (y <= y1))

    check.calls = calls  # type: ignore[attr-defined]
    return check


def test_the_primitives_end_on_their_states_and_move_no_point_farther_than_the_step() -> None:
    prims = primitives(RES, 16, step=0.02, reach=0.4)
    dirs = directions(16)
    ang = np.degrees(np.arctan2(dirs[:, 1], dirs[:, 0]))
    assert len(prims) == 16 and all(len(row) == 5 for row in prims)
    for k, row in enumerate(prims):
        kinds = sorted(p.kind for p in row)
        assert kinds == ["arc", "arc", "straight", "turn", "turn"]
        for p in row:
            end = p.poses[-1]
            assert end[:2] == pytest.approx(np.array(p.cells) * RES, abs=1e-9)
            assert (end[2] - ang[p.end] + 180) % 360 - 180 == pytest.approx(0.0, abs=1e-6)
            # the heuristic is admissible: no primitive costs less than its chord
            assert p.cost >= math.hypot(*p.cells) * RES - 1e-9
            full = np.vstack([[0.0, 0.0, ang[k]], p.poses])
            moved = (np.hypot(*np.diff(full[:, :2], axis=0).T)
                     + 0.4 * np.radians(np.abs((np.diff(full[:, 2]) + 180) % 360 - 180)))
            assert moved.max() <= 0.02 + 1e-6
        assert {p.end for p in row} == {k, (k + 1) % 16, (k - 1) % 16}


def test_free_ground_gives_the_straight_line() -> None:
    r = search((0.0, 0.0), 0.0, (1.0, 0.0), (-0.5, -0.5, 1.5, 0.5), wall(9, 9, 9, 9))
    assert r.reason == "found"
    assert r.path.length == pytest.approx(1.0)
    assert r.path.poses[-1][:2] == pytest.approx([1.0, 0.0])
    assert {s[2] for s in r.path.states} == {0}


def test_the_search_goes_round_a_wall_and_every_pose_of_its_path_passes_the_check() -> None:
    check = wall(0.45, 0.55, -0.6, 0.3)
    r = search((0.0, 0.0), 0.0, (1.0, 0.0), (-0.5, -1.0, 1.5, 1.0), check, batch=32)
    assert r.reason == "found"
    assert check(r.path.poses).all()
    assert r.path.poses[:, 1].max() > 0.3  # over the wall's end
    assert 1.15 < r.path.length < 1.4  # up past its end and down again: not the 1 m straight line
    # the successors of many states go to one call of the check
    assert max(check.calls) > 64 and len(check.calls) < r.expanded


def test_a_walled_in_goal_is_proven_unreachable() -> None:
    ring = [wall(0.8, 1.2, 0.18, 0.22), wall(0.8, 1.2, -0.22, -0.18), wall(0.78, 0.82, -0.22, 0.22),
            wall(1.18, 1.22, -0.22, 0.22)]

    def check(poses: np.ndarray) -> np.ndarray:
        return np.logical_and.reduce([w(poses) for w in ring])

    r = search((0.0, 0.0), 0.0, (1.0, 0.0), (-0.5, -0.5, 1.5, 0.5), check)
    assert r.path is None and r.reason == "exhausted"
    opened = search((0.0, 0.0), 0.0, (1.0, 0.0), (-0.5, -0.5, 1.5, 0.5), lambda p: ring[0](p) & ring[1](p) & ring[3](p))
    assert opened.reason == "found"  # the same ring with its near side gone
    budget = search((0.0, 0.0), 0.0, (1.0, 0.0), (-0.5, -0.5, 1.5, 0.5), check, max_expansions=50)
    assert budget.path is None and budget.reason == "budget"  # not a proof: the budget ran out


def test_lazy_judging_finds_the_same_path_for_fewer_poses() -> None:
    # a thin slanted wall only dense poses meet: the sparse judge lets some motions through it,
    # the path is then judged in full and the search runs again
    def check(poses: np.ndarray) -> np.ndarray:
        x, y = poses[:, 0], poses[:, 1]
        return ~((np.abs(x - 0.5 - 0.2 * y) < 0.03) & (y < 0.35))

    bounds = (-0.5, -1.0, 1.5, 1.0)
    dense = search((0.0, 0.0), 0.0, (1.0, 0.0), bounds, check)
    lazy = search((0.0, 0.0), 0.0, (1.0, 0.0), bounds, check, judge_every=4)
    assert check(lazy.path.poses).all()
    assert lazy.path.cost == pytest.approx(dense.path.cost)
    assert lazy.searches > 1 and lazy.poses_checked < dense.poses_checked
    cache = EdgeCache()
    search((0.0, 0.0), 0.0, (1.0, 0.0), bounds, check, judge_every=4, cache=cache)
    again = search((0.0, 0.0), 0.0, (1.0, 0.0), bounds, check, judge_every=4, cache=cache)
    assert again.poses_checked == 0 and again.path.cost == pytest.approx(dense.path.cost)


def test_a_weighted_search_is_within_its_weight_of_the_shortest() -> None:
    check = wall(0.45, 0.55, -0.6, 0.3)
    exact = search((0.0, 0.0), 0.0, (1.0, 0.0), (-0.5, -1.0, 1.5, 1.0), check)
    fast = search((0.0, 0.0), 0.0, (1.0, 0.0), (-0.5, -1.0, 1.5, 1.0), check, weight=2.0)
    assert exact.path.cost <= fast.path.cost <= 2.0 * exact.path.cost
    assert fast.expanded < exact.expanded


def test_a_goal_on_the_edge_of_the_bounds_is_searched_to_its_nearest_state_inside() -> None:
    # 0.99 m is nearest the state at 1.0 m, whose centre lies past the bounds' 0.99
    r = search((0.0, 0.0), 0.0, (0.99, 0.0), (-0.5, -0.5, 0.99, 0.5), wall(9, 9, 9, 9))
    assert r.reason == "found" and r.path.poses[-1][0] == pytest.approx(0.95)


def test_bad_input_is_refused() -> None:
    with pytest.raises(ValueError, match="8 or 16"):
        directions(12)
    with pytest.raises(ValueError, match="inside the search bounds"):
        search((0.0, 0.0), 0.0, (5.0, 0.0), (-0.5, -0.5, 1.5, 0.5), wall(9, 9, 9, 9))
