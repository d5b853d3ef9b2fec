"""Footprint-aware planning (the dense scene's 15 % rock cover, where a circle-expanded
planner finds no way; ACE against GESTALT): straight stretches keep the rover's half width +
margin from the hazards, waypoints (where it stops and turns on the spot) its whole circle; and
the any-angle shortcut of the waypoint polyline."""

from __future__ import annotations

import math

import numpy as np
import pytest

from prox_workflows.algorithms.planner import HAZARDOUS, NavMaps, PlannerParams, PlanningError, plan_path
from prox_workflows.algorithms.safety import check_move
from prox_workflows.grid import GridGeometry

GEOM = GridGeometry(0.05, 10.0, 5.0, 160, 120)  # x 10..18, y -1..5
LENGTH, WIDTH = 0.51, 0.40
RADIUS = math.hypot(LENGTH, WIDTH) / 2  # 0.324


def gap_maps(gap: float) -> NavMaps:
    """A wall of rock across x = 14 with one gap of ``gap`` metres centred on y = 2."""
    hz = np.zeros(GEOM.shape, np.uint8)
    xs, ys = GEOM.centers()
    wall = (np.abs(xs - 14.0) <= 0.15)[None, :] & (np.abs(ys - 2.0) > gap / 2)[:, None]
    hz[wall] = HAZARDOUS
    return NavMaps(hz, np.full(GEOM.shape, 5.0, np.float32), GEOM)


def params(footprint: str, **kw) -> PlannerParams:
    return PlannerParams(rover_radius=RADIUS, half_width=WIDTH / 2 if footprint == "body" else None, margin=0.1,
                         border=0.0, unknown_cost=math.inf, **kw)  # not round the map


def swept_hazard_cells(waypoints: np.ndarray, maps: NavMaps, margin: float) -> int:
    """The rover body (+ margin) swept along the waypoint polyline over the hazard map."""
    trav = np.where(maps.hazard == HAZARDOUS, np.float32(0), np.float32(1))
    blocked = 0
    for a, b in zip(waypoints[:-1], waypoints[1:], strict=True):
        h = math.degrees(math.atan2(b[1] - a[1], b[0] - a[0]))
        blocked += check_move(trav, maps.geometry, (a[0], a[1], h), (b[0], b[1], h), LENGTH + 2 * margin,
                              WIDTH + 2 * margin).blocked_cells
    return blocked


def test_a_gap_the_circle_closes_the_body_drives_through_and_turns_only_where_it_fits() -> None:
    maps = gap_maps(0.66)  # > width + 2 margin (0.60), < the circle's 2 (radius + margin) (0.85)
    start, goal = (11.0, 0.5), (17.0, 3.5)
    with pytest.raises(PlanningError) as exc:
        plan_path(maps, None, start, goal, params("circle"))
    assert exc.value.reason == "enclosed"
    res = plan_path(maps, None, start, goal, params("body"))
    wps = res.waypoints.xy
    assert res.reaches_goal
    xs = wps[:, 0]
    assert (xs < 14.0).any() and (xs > 14.0).any()  # it crossed the wall ...
    crossing = np.flatnonzero(np.diff(np.sign(xs - 14.0)))[0]
    a, b = wps[crossing], wps[crossing + 1]
    y_at_wall = a[1] + (b[1] - a[1]) * (14.0 - a[0]) / (b[0] - a[0])
    assert abs(y_at_wall - 2.0) < 0.33 - 0.2  # ... through the gap, body inside it
    assert swept_hazard_cells(wps, maps, margin=0.0) == 0
    # every waypoint after the start is where the whole body fits at any heading
    img = res.image
    r, c = GEOM.cell_of(wps[1:, 0], wps[1:, 1])
    assert img.turnable[r, c].all()
    assert (img.hazard_distance[r, c] > RADIUS + 0.1).all()


def test_the_body_footprint_keeps_the_circle_where_the_gap_is_too_narrow_for_the_body() -> None:
    maps = gap_maps(0.55)  # < width + 2 margin
    with pytest.raises(PlanningError) as exc:
        plan_path(maps, None, (11.0, 0.5), (17.0, 3.5), params("body"))
    assert exc.value.reason == "enclosed"


def test_a_goal_where_the_body_does_not_fit_is_refused_with_either_footprint() -> None:
    maps = gap_maps(0.66)
    for fp in ("circle", "body"):
        with pytest.raises(PlanningError) as exc:
            plan_path(maps, None, (11.0, 0.5), (14.0, 2.0), params(fp))  # the middle of the gap
        assert exc.value.reason == "goal_in_hazard", fp


@pytest.mark.parametrize("goal", [(17.3, 3.1), (16.0, 4.4), (13.1, 4.6), (17.9, -0.6)])
def test_on_open_ground_the_waypoints_are_the_straight_line(goal: tuple[float, float]) -> None:
    """An 8-connected A* path is up to 8 % longer than the line; the shortcut takes the line
    where it costs no more by the planner's own measure (on uniform ground: always)."""
    maps = NavMaps(np.zeros(GEOM.shape, np.uint8), np.full(GEOM.shape, 5.0, np.float32), GEOM)
    start = (10.6, -0.4)
    res = plan_path(maps, None, start, goal, params("circle", weight=1.0))
    assert len(res.waypoints) == 2
    length = float(np.sum(np.hypot(*np.diff(res.waypoints.xy, axis=0).T)))
    assert length == pytest.approx(math.dist(start, goal), abs=1e-9)
    assert length <= res.cost  # the A* path is no shorter than its line


def test_the_shortcut_never_crosses_a_hazard_nor_costs_more_than_the_path() -> None:
    from prox_workflows.algorithms.waypoints import segment_cells

    rng = np.random.default_rng(3)
    hz = np.zeros(GEOM.shape, np.uint8)
    for _ in range(25):
        r, c = rng.integers(0, GEOM.height), rng.integers(15, GEOM.width - 15)
        hz[max(0, r - 3):r + 3, max(0, c - 3):c + 3] = HAZARDOUS
    yy, xx = np.mgrid[: GEOM.height, : GEOM.width]
    slope = (10 + 8 * np.sin(xx / 7.0) * np.cos(yy / 11.0)).astype(np.float32)
    maps = NavMaps(hz, slope, GEOM)
    res = plan_path(maps, None, (10.3, 2.0), (17.7, 2.2), params("body"))
    k = res.image.cost_per_metre(0.5)
    total = 0.0
    for a, b in zip(res.waypoints.xy[:-1], res.waypoints.xy[1:], strict=True):
        rows, cols = segment_cells(a, b, res.image.geometry)
        assert np.isfinite(k[rows, cols]).all()
        total += float(np.mean(k[rows, cols])) * float(np.hypot(*(b - a)))
    assert total <= res.cost + 1e-6
