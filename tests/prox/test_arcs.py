"""Heading-aware local choice: drive arcs judged by the swept footprint and scored by arc cost plus
the incremental planner's cost to go."""

from __future__ import annotations

import math

import numpy as np
import pytest

from prox_workflows.algorithms.arcs import arc_poses, choose_arc, default_curvatures
from prox_workflows.algorithms.astar import SQRT2, astar_grid
from prox_workflows.algorithms.replan import IncrementalPlanner
from prox_workflows.grid import GridGeometry

G = GridGeometry(0.1, -5.0, 5.0, 100, 100)  # 10 x 10 m, x right, y up
ROVER = {"rover_length": 0.5, "rover_width": 0.4}


def setup(trav: np.ndarray, goal_xy=(4.0, 0.0), start_xy=(-3.0, 0.0)):
    grown = np.zeros(G.shape, bool)
    bad = ~(trav > 0.0)
    for dr in range(-3, 4):  # the planner's hazards grown by ~ the rover's half width
        for dc in range(-3, 4):
            grown |= np.roll(np.roll(bad, dr, 0), dc, 1)
    cost = np.where(grown, np.inf, 1.0)
    r, c = G.cell_of(np.array([start_xy[0], goal_xy[0]]), np.array([start_xy[1], goal_xy[1]]))
    start, goal = (int(r[0]), int(c[0])), (int(r[1]), int(c[1]))
    planner = IncrementalPlanner(cost, start, goal, orth=G.cell, diag=G.cell * SQRT2)
    planner.plan()
    return planner, cost, goal


def test_arc_poses_follow_the_circle() -> None:
    p = arc_poses((0.0, 0.0, 0.0), 1.0, math.pi / 2, 0.05)
    assert p[-1] == pytest.approx([1.0, 1.0, 90.0], abs=1e-9)
    assert np.hypot(p[:, 0], p[:, 1] - 1.0) == pytest.approx(1.0, abs=1e-12)  # radius 1 about (0, 1)
    s = arc_poses((1.0, 2.0, 90.0), 0.0, 2.0, 0.5)
    assert s[-1] == pytest.approx([1.0, 4.0, 90.0], abs=1e-12) and len(s) == 5
    assert default_curvatures(2.0, 5) == pytest.approx([0.5, 0.25, 0.0, -0.25, -0.5])


def test_open_ground_goes_straight_at_the_goal() -> None:
    trav = np.ones(G.shape, np.float32)
    planner, _, _ = setup(trav)
    best, ranked = choose_arc(planner, G, trav, G, (-3.0, 0.0, 0.0), **ROVER)
    assert best is not None and best.curvature == 0.0 and best.verdict == "ok"
    assert all(a.verdict == "ok" for a in ranked)
    assert best.end == pytest.approx((-2.0, 0.0, 0.0), abs=1e-9)


def test_rock_ahead_turns_to_the_open_side_with_a_drivable_heading() -> None:
    trav = np.ones(G.shape, np.float32)
    x, y = G.centers()
    X, Y = np.meshgrid(x, y)
    trav[(X > -2.1) & (X < -1.8) & (Y > -1.5) & (Y < 0.05)] = 0.0  # ahead and to the right
    planner, cost, goal = setup(trav)
    best, ranked = choose_arc(planner, G, trav, G, (-3.0, 0.0, 0.0), **ROVER, length=1.2, min_turn_radius=1.0)
    straight = next(a for a in ranked if a.curvature == 0.0)
    assert straight.verdict == "not_traversable" and math.isinf(straight.score)
    assert best is not None and best.verdict == "ok" and best.curvature > 0  # left, round the rock
    assert best.end[2] == pytest.approx(math.degrees(best.curvature * 1.2))  # the heading it drives to
    # the score is the arc's cost plus the exact cost to go from its end cell
    r, c = G.cell_of(np.array(best.end[0]), np.array(best.end[1]))
    ref = astar_grid(cost, (int(r), int(c)), goal, orth=G.cell, diag=G.cell * SQRT2).cost
    assert best.cost_to_go == pytest.approx(ref, rel=1e-9)
    assert best.score == pytest.approx(best.arc_cost + ref, rel=1e-12)
    assert best.arc_cost == pytest.approx(1.2, rel=1e-3)  # cost 1 per metre on free ground (chords)
    finite = [a.score for a in ranked if np.isfinite(a.score)]
    assert best.score == min(finite)


def test_unknown_ground_only_when_allowed() -> None:
    trav = np.ones(G.shape, np.float32)
    x, y = G.centers()
    X, Y = np.meshgrid(x, y)
    trav[(X > -2.3) & (X < -1.9) & (np.abs(Y) < 2.0)] = np.nan  # an unseen band across the way
    planner, _, _ = setup(np.ones(G.shape, np.float32))
    best, ranked = choose_arc(planner, G, trav, G, (-3.0, 0.0, 0.0), **ROVER)
    assert best is None and all(a.verdict == "unknown" for a in ranked)
    best, _ = choose_arc(planner, G, trav, G, (-3.0, 0.0, 0.0), **ROVER, allow_unknown=True)
    assert best is not None and best.curvature == 0.0
