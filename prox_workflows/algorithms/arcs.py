"""Heading-aware local choice (Carsten et al. 2007, GESTALT + Field D* on MER):
the grid path of the incremental planner turns on the spot at every cell, which a rover with a
turning limit cannot drive; so the rover chooses among the arcs it *can* drive from its pose, each
judged safe or not by its footprint swept over the traversability map (as the move gate,
:func:`.safety.check_move`, judges it) and scored by what it costs to drive plus the global
planner's cost to go from where it ends. The arc's end pose is a waypoint with a drivable heading.

Costs are in the planner's units: the planner's ``orth`` step is the planning cell in metres, so
the cost to go is metres of ``w * distance + (1 - w) * environmental cost``, and an arc costs the
cost per metre of the cells it crosses times its length.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..grid import GridGeometry
from .replan import IncrementalPlanner
from .safety import check_move


@dataclass
class Arc:
    """One candidate drive arc and its verdict."""

    curvature: float  # 1/m, left (counter-clockwise) positive
    poses: np.ndarray  # (n, 3) x, y, heading deg along the arc, from the rover's pose to its end
    verdict: str  # ok | not_traversable | unknown (check_move's, over the whole arc)
    arc_cost: float  # cost of driving the arc (planner units), inf if it leaves the planning grid
    cost_to_go: float  # planner's cost from the arc's end cell to the goal
    score: float  # arc_cost + cost_to_go for an admissible arc, inf otherwise

    @property
    def end(self) -> tuple[float, float, float]:
        x, y, h = self.poses[-1]
        return float(x), float(y), float(h)


def arc_poses(pose: Sequence[float], curvature: float, length: float, step: float) -> np.ndarray:
    """Poses along a constant-curvature arc of ``length`` metres from ``pose`` (x, y, heading
    deg), every ``step`` metres or closer (the last exactly at the end). A negative ``length``
    runs the arc backwards: the rover reversing, its heading the body's."""
    n = max(1, math.ceil(abs(length) / step))
    s = np.linspace(0.0, length, n + 1)
    x0, y0, h0 = float(pose[0]), float(pose[1]), math.radians(float(pose[2]))
    if abs(curvature) < 1e-9:
        x = x0 + s * math.cos(h0)
        y = y0 + s * math.sin(h0)
        h = np.full_like(s, h0)
    else:
        h = h0 + curvature * s
        x = x0 + (np.sin(h) - math.sin(h0)) / curvature
        y = y0 - (np.cos(h) - math.cos(h0)) / curvature
    return np.stack([x, y, np.degrees(h)], axis=1)


def default_curvatures(min_turn_radius: float, count: int = 11) -> np.ndarray:
    """``count`` curvatures spread evenly in 1/radius from the tightest left to the tightest
    right turn, straight ahead among them when ``count`` is odd (GESTALT's arc fan)."""
    if count < 1:
        raise ValueError("count must be >= 1")
    kmax = 1.0 / min_turn_radius if min_turn_radius > 0 else 0.0
    return np.linspace(kmax, -kmax, count) if count > 1 else np.zeros(1)


def choose_arc(planner: IncrementalPlanner, plan_geometry: GridGeometry, traversability: np.ndarray,
               trav_geometry: GridGeometry, pose: Sequence[float], *, rover_length: float, rover_width: float,
               length: float = 1.0, curvatures: Sequence[float] | None = None, min_turn_radius: float = 1.0,
               min_score: float = 0.0, allow_unknown: bool = False) -> tuple[Arc | None, list[Arc]]:
    """The best drivable arc from ``pose`` (x, y, heading deg) and every candidate, best first.

    An arc is admissible when its swept footprint is ``ok`` (``unknown`` too with
    ``allow_unknown``: driving into unseen ground is the caller's choice, as for the move gate)
    and its end cell has a path to the goal (an end inside the planner's hazard margin has none);
    among those the lowest arc cost + cost to go wins (ties: the straighter arc). None when no arc is admissible: turn on the spot, or replan.
    ``planner``'s grid is ``plan_geometry``; its goal is the global goal."""
    ks = default_curvatures(min_turn_radius) if curvatures is None else np.asarray(curvatures, dtype=np.float64)
    step = max(plan_geometry.cell, min(rover_length, rover_width) / 4)
    cost = planner.cost
    finite = cost[np.isfinite(cost)]
    margin_cost = float(finite.max()) if finite.size else 1.0
    arcs: list[Arc] = []
    ends: list[tuple[int, int]] = []
    for kappa in ks:
        poses = arc_poses(pose, float(kappa), length, step)
        verdict = _sweep_verdict(traversability, trav_geometry, poses, rover_length, rover_width, min_score)
        arc_cost, end = _arc_cost(cost, plan_geometry, poses, margin_cost)
        arcs.append(Arc(float(kappa), poses, verdict, arc_cost, math.inf, math.inf))
        ends.append(end)
    admissible = [i for i, a in enumerate(arcs)
                  if np.isfinite(a.arc_cost) and (a.verdict == "ok" or (allow_unknown and a.verdict == "unknown"))]
    if admissible:
        ctg = planner.cost_to_go([ends[i] for i in admissible])
        for i, c in zip(admissible, ctg, strict=True):
            arcs[i].cost_to_go = float(c)
            arcs[i].score = arcs[i].arc_cost + float(c)
    order = sorted(range(len(arcs)), key=lambda i: (arcs[i].score, abs(arcs[i].curvature), -arcs[i].curvature))
    ranked = [arcs[i] for i in order]
    best = ranked[0] if ranked and np.isfinite(ranked[0].score) else None
    return best, ranked


def _sweep_verdict(trav: np.ndarray, geometry: GridGeometry, poses: np.ndarray, length: float, width: float,
                   min_score: float) -> str:
    """check_move over each chord of the arc: blocked anywhere wins over unknown anywhere."""
    verdicts = {check_move(trav, geometry, tuple(a), tuple(b), length, width, min_score).verdict
                for a, b in zip(poses[:-1], poses[1:], strict=True)}
    for v in ("not_traversable", "unknown"):
        if v in verdicts:
            return v
    return "ok"


def _arc_cost(cost: np.ndarray, geometry: GridGeometry, poses: np.ndarray,
              margin_cost: float) -> tuple[float, tuple[int, int]]:
    """The planner's cost per metre integrated along the arc (trapezoid rule over its samples, as
    the planner integrates its steps), and the arc's end cell; inf if the arc leaves the grid.

    The planner blocks a disc of rover radius + margin around each hazard, wider than the
    footprint the sweep checks: an arc the sweep passes may graze that margin, and is charged
    ``margin_cost`` per metre there rather than refused (the sweep decides safety, the map cost)."""
    rows, cols = geometry.cell_of(poses[:, 0], poses[:, 1])
    rows, cols = np.asarray(rows), np.asarray(cols)
    inside = geometry.inside(rows, cols)
    end = (int(rows[-1]), int(cols[-1]))
    if not np.all(inside):
        return math.inf, end
    k = cost[rows, cols]
    k = np.where(np.isfinite(k), k, margin_cost)
    ds = np.hypot(np.diff(poses[:, 0]), np.diff(poses[:, 1]))
    return float(np.sum(ds * (k[:-1] + k[1:]) / 2)), end
