"""The planner on maps in world coordinates: merging (local over global), hazard expansion, the
path's safety, the cut at the local map's border, the reasons for no path, determinism."""

from __future__ import annotations

import math
import warnings
from typing import Any

import cv2
import numpy as np
import pytest

from prox_workflows.algorithms.plan_maps import expand_hazards, planning_image
from prox_workflows.algorithms.planner import (
    NavMaps,
    PlannerParams,
    PlanningError,
    nearest_reachable,
    plan_path,
)
from prox_workflows.algorithms.waypoints import segment_cells
from prox_workflows.grid import GridGeometry
from rvs_params.hazard import HAZARDOUS, SAFE, UNDEFINED

# an off-origin frame, so a swapped axis or a sign error shows
GEOM = GridGeometry(0.05, 100.0, -40.0, 160, 120)  # x 100..106, y -48..-40


def rock_field(seed: int, rocks: int = 14, geom: GridGeometry = GEOM) -> NavMaps:
    rng = np.random.default_rng(seed)
    hz = np.zeros(geom.shape, np.uint8)
    for _ in range(rocks):
        r, c = int(rng.integers(0, geom.height)), int(rng.integers(20, geom.width - 20))
        cv2.circle(hz, (c, r), int(rng.integers(2, 6)), HAZARDOUS, -1)
    yy, xx = np.mgrid[: geom.height, : geom.width]
    slope = (8 + 8 * np.sin(xx / 9.0) * np.cos(yy / 13.0)).astype(np.float32)
    return NavMaps(hz, slope, geom)


def world(geom: GridGeometry, r: int, c: int) -> tuple[float, float]:
    xs, ys = geom.centers()
    return float(xs[c]), float(ys[r])


def test_path_never_enters_a_hazard_nor_the_margin() -> None:
    planned = 0
    for seed in range(12):
        maps = rock_field(seed)
        start, goal = world(GEOM, 60, 3), world(GEOM, 60, 156)
        params = PlannerParams(rover_radius=0.15, margin=0.05, border=0.0)
        try:
            res = plan_path(maps, None, start, goal, params)
        except PlanningError as exc:
            assert exc.reason in ("enclosed", "goal_in_hazard", "start_in_hazard")
            continue
        planned += 1
        img = res.image
        r, c = res.path_cells[:, 0], res.path_cells[:, 1]
        assert not (img.hazard[r, c] == HAZARDOUS).any()
        assert not img.blocked[r, c].any()
        # every point of the path polyline (not only the cell centres) keeps the clearance
        rows, cols = [], []
        for a, b in zip(res.path[:-1], res.path[1:], strict=True):
            rr, cc = segment_cells(a, b, img.geometry)
            rows.append(rr)
            cols.append(cc)
        rows, cols = np.concatenate(rows), np.concatenate(cols)
        assert not img.blocked[rows, cols].any()
        # and, in metres, stays rover radius + margin away from every hazardous pixel of the input
        hz_r, hz_c = np.nonzero(maps.hazard == HAZARDOUS)
        xs, ys = GEOM.centers()
        hx, hy = xs[hz_c], ys[hz_r]
        dense = np.concatenate([a + np.linspace(0, 1, 12)[:, None] * (b - a)
                                for a, b in zip(res.path[:-1], res.path[1:], strict=True)])
        gap = np.hypot(dense[:, :1] - hx[None, :], dense[:, 1:] - hy[None, :]).min()
        assert gap >= 0.2 - 1e-9
        # the waypoint legs too
        for a, b in zip(res.waypoints.xy[:-1], res.waypoints.xy[1:], strict=True):
            rr, cc = segment_cells(a, b, img.geometry)
            assert not img.blocked[rr, cc].any()
    assert planned >= 8


def test_world_coordinates_and_cost() -> None:
    maps = rock_field(3, rocks=0)
    start, goal = (100.52, -44.03), (105.41, -41.27)
    res = plan_path(maps, maps, start, goal, PlannerParams(weight=1.0, border=0.0))
    assert tuple(res.path[0]) == start and tuple(res.path[-1]) == goal
    r, c = GEOM.cell_of(np.array([start[0], goal[0]]), np.array([start[1], goal[1]]))
    assert tuple(res.path_cells[0]) == (r[0], c[0]) and tuple(res.path_cells[-1]) == (r[1], c[1])
    xs, ys = GEOM.centers()
    assert np.allclose(res.path[1:-1, 0], xs[res.path_cells[1:-1, 1]])
    assert np.allclose(res.path[1:-1, 1], ys[res.path_cells[1:-1, 0]])
    # w = 1 on an open map: the cost is the octile distance between the two cells
    dr, dc = abs(int(r[1] - r[0])), abs(int(c[1] - c[0]))
    octile = 0.05 * (max(dr, dc) - min(dr, dc) + math.sqrt(2) * min(dr, dc))
    assert res.cost == pytest.approx(octile, rel=1e-9)
    assert res.reaches_goal and res.waypoints.xy[-1].tolist() == list(goal)
    # heading of the first leg points from the start towards the goal side (north-east here)
    assert 0 < res.waypoints.heading_deg[0] < 90


def test_weight_zero_follows_the_flat_ground() -> None:
    geom = GridGeometry(0.1, 0.0, 6.0, 60, 60)
    slope = np.full(geom.shape, 15.0, np.float32)
    slope[45:55, :] = 0.0  # a flat valley in the south
    maps = NavMaps(np.zeros(geom.shape, np.uint8), slope, geom)
    start, goal = world(geom, 30, 2), world(geom, 30, 57)
    short = plan_path(maps, None, start, goal, PlannerParams(weight=1.0, border=0.0))
    flat = plan_path(maps, None, start, goal, PlannerParams(weight=0.0, border=0.0))
    assert np.ptp(short.path_cells[:, 0]) <= 1  # straight across
    assert (flat.path_cells[:, 0] >= 45).mean() > 0.6  # mostly in the valley
    assert len(flat.path) > len(short.path)


def test_merge_local_over_global() -> None:
    g_geom = GridGeometry(0.2, 0.0, 10.0, 50, 50)  # 10 m x 10 m, coarse
    g_hz = np.zeros(g_geom.shape, np.uint8)
    g_hz[10:15, 10:15] = HAZARDOUS  # x 2..3, y 7..8: the local map will see it as safe
    g_hz[30:35, 30:35] = HAZARDOUS  # x 6..7, y 3..4: outside the local map, stays
    g_sl = np.full(g_geom.shape, 4.0, np.float32)
    l_geom = GridGeometry(0.05, 1.0, 9.0, 60, 60)  # x 1..4, y 6..9, fine
    l_hz = np.zeros(l_geom.shape, np.uint8)
    l_hz[50:60, :] = UNDEFINED  # y 6..6.5 unseen: the global map shows through
    l_hz[20, 40] = HAZARDOUS  # one small local rock at x 3.0..3.05, y 7.95..8.0
    l_sl = np.full(l_geom.shape, 10.0, np.float32)
    img = planning_image(NavMaps(l_hz, l_sl, l_geom), NavMaps(g_hz, g_sl, g_geom),
                         PlannerParams(grid=0.1, rover_radius=0.0, margin=0.0))
    geom = img.geometry
    assert geom.bounds == (0.0, 0.0, 10.0, 10.0) and geom.cell == 0.1

    def at(x: float, y: float) -> tuple[int, int]:
        r, c = geom.cell_of(np.array(x), np.array(y))
        return int(r), int(c)

    assert img.hazard[at(2.5, 7.5)] == SAFE and img.local[at(2.5, 7.5)]  # local overrules global
    assert img.slope[at(2.5, 7.5)] == 10.0 and img.slope[at(8.0, 1.0)] == 4.0
    assert img.hazard[at(6.5, 3.5)] == HAZARDOUS  # global hazard where no local map
    assert img.hazard[at(3.02, 7.97)] == HAZARDOUS  # a 5 cm local rock survives 10 cm cells
    assert not img.local[at(2.5, 6.2)] and img.slope[at(2.5, 6.2)] == 4.0  # unseen: global
    # a blank global map: unknown ground around the local map, dearer than the local ground
    img = planning_image(NavMaps(l_hz, l_sl, l_geom), None, PlannerParams(grid=0.1, blank_pad=1.0),
                         points=[(0.5, 8.0), (4.5, 7.0)])
    geom = img.geometry
    assert geom.bounds == pytest.approx((-0.5, 6.0, 5.5, 9.0))
    assert img.hazard[at(0.2, 8.0)] == UNDEFINED
    assert img.env_cost[at(0.2, 8.0)] == 1.0 and img.env_cost[at(2.5, 7.5)] == pytest.approx(0.5)


def test_expansion_radius() -> None:
    hz = np.zeros((41, 41), bool)
    hz[20, 20] = True
    cell = 0.1
    blocked, dist, clearance = expand_hazards(hz, 0.3, cell)
    assert clearance == pytest.approx(0.3 + 0.1 * math.sqrt(0.5))
    rr, cc = np.mgrid[:41, :41]
    centre = np.hypot(rr - 20, cc - 20) * cell
    assert np.array_equal(blocked, centre <= clearance + 1e-9)
    assert np.allclose(dist, centre, atol=1e-6)
    # the rover's disc never touches the hazardous square from a free cell centre
    free = ~blocked
    nearest = np.hypot(np.maximum(np.abs(rr - 20) - 0.5, 0), np.maximum(np.abs(cc - 20) - 0.5, 0)) * cell
    assert nearest[free].min() >= 0.3
    assert not expand_hazards(np.zeros((5, 5), bool), 0.3, cell)[0].any()


def test_cut_at_the_local_border() -> None:
    geom = GridGeometry(0.05, 0.0, 4.0, 80, 80)  # local map x 0..4, y 0..4
    hz = np.zeros(geom.shape, np.uint8)
    yy, xx = np.mgrid[:80, :80]
    hz[(yy - 40) ** 2 + (xx - 40) ** 2 > 38**2] = UNDEFINED  # a round local map
    hz[(yy - 40) ** 2 + (xx - 40) ** 2 < 4**2] = UNDEFINED  # the blind spot under the rover
    maps = NavMaps(hz, np.full(geom.shape, 5.0, np.float32), geom)
    start, goal = (2.0, 2.0), (9.0, 2.3)  # goal 5 m beyond the local map
    res = plan_path(maps, None, start, goal, PlannerParams(border=0.3))
    assert not res.reaches_goal and 1 < res.cut < len(res.path)
    bd = res.image.border_distance[res.path_cells[:, 0], res.path_cells[:, 1]]
    assert (bd[: res.cut] >= 0.3).all()  # the blind spot is no border
    assert bd[res.cut] < 0.3
    off_start = np.hypot(*(res.path[: res.cut] - start).T) > 0.25  # out of the blind spot
    assert res.image.local[res.path_cells[: res.cut, 0], res.path_cells[: res.cut, 1]][off_start].all()
    end = res.waypoints.xy[-1]
    assert tuple(end) == tuple(res.path[res.cut - 1])
    assert 3.5 < end[0] < 3.8  # 1.9 m local radius minus the 0.3 m border from x = 2
    assert any("cut" in w for w in res.warnings)
    # the goal inside the local map is reached, and the goal heading applies only then
    res = plan_path(maps, None, start, (3.0, 2.5), PlannerParams(border=0.3), goal_heading=90.0)
    assert res.reaches_goal and res.waypoints.turn_deg[-1] != 0.0


def test_a_map_without_hazards_is_far_from_any_and_says_so_quietly() -> None:
    """OpenCV gives 2^64 as the distance when no cell is a hazard; squaring it to restore
    the exact value overflowed (a RuntimeWarning in every plan on a hazard-free map)."""
    from prox_workflows.algorithms.plan_maps import _distance_cells

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        far = _distance_cells(np.zeros((4, 5), bool))
        one = np.zeros((4, 5), bool)
        one[0, 0] = True
        near = _distance_cells(one)
    assert (far > 1e18).all()
    assert near[0, 0] == 0.0 and near[0, 3] == 3.0 and near[3, 4] == 5.0


def test_unreachable_reasons() -> None:
    geom = GridGeometry(0.05, 0.0, 3.0, 60, 60)
    hz = np.zeros(geom.shape, np.uint8)
    hz[10:14, 10:14] = HAZARDOUS  # x 0.5..0.7, y 2.3..2.5
    yy, xx = np.mgrid[:60, :60]
    ring = np.abs(np.hypot(yy - 40, xx - 40) - 10) < 1.5
    hz[ring] = HAZARDOUS  # a closed ring around (2.0, 1.0)
    maps = NavMaps(hz, np.full(geom.shape, 5.0, np.float32), geom)
    p = PlannerParams(rover_radius=0.1, margin=0.05)
    cases = {
        ("goal_in_hazard", "hazardous cell"): ((0.2, 0.2), (0.6, 2.4)),
        ("goal_in_hazard", "margin"): ((0.2, 0.2), (0.8, 2.4)),
        ("start_in_hazard", "hazardous cell"): ((0.6, 2.4), (0.2, 0.2)),
        ("enclosed", "goal is enclosed"): ((0.2, 0.2), (2.0, 1.0)),
        ("enclosed", "start is enclosed"): ((2.0, 1.0), (0.2, 0.2)),
    }
    for (reason, words), (s, g) in cases.items():
        with pytest.raises(PlanningError) as err:
            plan_path(maps, None, s, g, p)
        assert err.value.reason == reason and words in err.value.message
    # with global maps given, a goal beyond them is outside the maps
    with pytest.raises(PlanningError) as err:
        plan_path(maps, maps, (0.2, 0.2), (7.0, 1.0), p)
    assert err.value.reason == "outside_maps" and "outside the maps" in err.value.message
    # unknown ground forbidden: a goal on it is refused
    with pytest.raises(PlanningError) as err:
        plan_path(maps, None, (0.2, 0.2), (4.0, 1.0), PlannerParams(unknown_cost=math.inf))
    assert err.value.reason == "goal_in_hazard" and "unknown" in err.value.message


def test_nearest_reachable_is_where_to_judge_an_unreachable_goal_from() -> None:
    """navigate drives there when the goal was judged unreachable from far: the free cell the
    start reaches that is nearest the goal, outside the ring that encloses the goal, and just
    outside the margin of a hazard the goal lies on; A* reaches it."""
    geom = GridGeometry(0.05, 0.0, 3.0, 60, 60)
    hz = np.zeros(geom.shape, np.uint8)
    hz[10:14, 10:14] = HAZARDOUS  # x 0.5..0.7, y 2.3..2.5
    yy, xx = np.mgrid[:60, :60]
    hz[np.abs(np.hypot(yy - 40, xx - 40) - 10) < 1.5] = HAZARDOUS  # a closed ring around (2.0, 1.0)
    maps = NavMaps(hz, np.full(geom.shape, 5.0, np.float32), geom)
    p = PlannerParams(rover_radius=0.1, margin=0.05)
    image = planning_image(maps, None, p, points=[(0.2, 0.2), (2.0, 1.0)])
    free = ~image.blocked
    for goal, lo, hi in (((2.0, 1.0), 0.5 + 0.15, 0.5 + 0.15 + 0.2), ((0.6, 2.4), 0.1 + 0.15, 0.1 + 0.15 + 0.1)):
        with pytest.raises(PlanningError):
            plan_path(maps, None, (0.2, 0.2), goal, p)
        x, y = nearest_reachable(maps, None, (0.2, 0.2), goal, p)
        r, c = geom.cell_of(np.array(x), np.array(y))
        assert free[int(r), int(c)]
        assert lo <= math.hypot(x - goal[0], y - goal[1]) <= hi  # outside ring (radius 0.5 m) / rock + margin
        plan = plan_path(maps, None, (0.2, 0.2), (x, y), p)
        assert plan.reaches_goal
    # a reachable goal is its own nearest reachable cell (to the grid)
    x, y = nearest_reachable(maps, None, (0.2, 0.2), (1.0, 0.5), p)
    assert math.hypot(x - 1.0, y - 0.5) <= 0.05
    with pytest.raises(PlanningError) as err:
        nearest_reachable(maps, None, (0.6, 2.4), (0.2, 0.2), p)
    assert err.value.reason == "start_in_hazard"


def test_start_inside_the_margin_may_leave_it() -> None:
    geom = GridGeometry(0.05, 0.0, 3.0, 60, 60)
    hz = np.zeros(geom.shape, np.uint8)
    hz[28:32, 28:32] = HAZARDOUS  # x 1.4..1.6, y 1.4..1.6
    maps = NavMaps(hz, np.full(geom.shape, 5.0, np.float32), geom)
    start = (1.725, 1.525)  # 0.15 m east of the rock, inside the 0.35 m margin
    res = plan_path(maps, None, start, (2.8, 2.8), PlannerParams(rover_radius=0.25, margin=0.1, border=0.0))
    assert any("relaxed" in w for w in res.warnings)
    d = res.image.hazard_distance[res.path_cells[:, 0], res.path_cells[:, 1]]
    assert d.min() >= d[0]  # it never gets closer to the rock than where it started
    assert (res.image.hazard[res.path_cells[:, 0], res.path_cells[:, 1]] != HAZARDOUS).all()


def test_deterministic() -> None:
    maps = rock_field(5)
    start, goal = world(GEOM, 100, 3), world(GEOM, 10, 150)
    a = plan_path(maps, None, start, goal, PlannerParams())
    b = plan_path(rock_field(5), None, start, goal, PlannerParams())
    assert np.array_equal(a.path, b.path) and np.array_equal(a.cost_so_far, b.cost_so_far)
    assert np.array_equal(a.waypoints.table(), b.waypoints.table(), equal_nan=True)
    assert a.cut == b.cut


def test_unknown_ground_is_dear_but_allowed() -> None:
    geom = GridGeometry(0.05, 0.0, 3.0, 60, 60)
    hz = np.zeros(geom.shape, np.uint8)
    hz[:, 25:35] = UNDEFINED  # an unseen strip across the map
    hz[25:35, 25:35] = SAFE  # with a seen gap in the middle
    maps = NavMaps(hz, np.zeros(geom.shape, np.float32), geom)
    start, goal = world(geom, 5, 5), world(geom, 5, 55)
    through = plan_path(maps, maps, start, goal, PlannerParams(weight=0.5, border=0.0, unknown_cost=0.0))
    detour = plan_path(maps, maps, start, goal, PlannerParams(weight=0.5, border=0.0, unknown_cost=5.0))
    never = plan_path(maps, maps, start, goal, PlannerParams(weight=0.5, border=0.0, unknown_cost=math.inf))
    known = hz != UNDEFINED
    assert not known[through.path_cells[:, 0], through.path_cells[:, 1]].all()  # straight across
    assert known[detour.path_cells[:, 0], detour.path_cells[:, 1]].all()  # through the gap
    assert known[never.path_cells[:, 0], never.path_cells[:, 1]].all()


def test_a_global_map_bounds_where_the_rover_may_go() -> None:
    """Past an orbital map's edge, where the local maps show nothing either, the planner does
    not go (a scene's edge, beyond which the ToF gets no returns, looked like open unknown
    ground, and hirise missions drove off it); ground the rover itself saw there is allowed, and
    without a global map the blank one bounds nothing."""
    g_geom = GridGeometry(0.5, 0.0, 4.0, 8, 8)  # x 0..4, y 0..4
    g_hz = np.zeros(g_geom.shape, np.uint8)
    g_hz[:, 4] = HAZARDOUS  # a wall at x 2..2.5 from y 0 to 4: the way round leaves the map
    orbit = NavMaps(g_hz, np.zeros(g_geom.shape, np.float32), g_geom)
    l_geom = GridGeometry(0.05, -1.0, 5.0, 120, 120)  # x -1..5, y -1..5: unseen but for one strip
    l_hz = np.full(l_geom.shape, UNDEFINED, np.uint8)
    local = NavMaps(l_hz, np.zeros(l_geom.shape, np.float32), l_geom)
    params = PlannerParams(grid=0.1, rover_radius=0.2, margin=0.0, border=0.0)
    with pytest.raises(PlanningError) as exc:
        plan_path(local, orbit, (1.0, 2.0), (3.5, 2.0), params)
    assert exc.value.reason == "enclosed"
    l_hz[:24, :] = SAFE  # the rover saw the ground across the map's north edge (y 3.8..5)
    plan = plan_path(local, orbit, (1.0, 2.0), (3.5, 2.0), params)
    assert plan.reaches_goal and plan.path[:, 1].max() > 3.8  # round the wall over the ground it saw
    blank = plan_path(NavMaps(np.full(l_geom.shape, UNDEFINED, np.uint8), local.slope, l_geom), None,
                      (1.0, 2.0), (3.5, 2.0), PlannerParams(grid=0.1, rover_radius=0.2, margin=0.0, border=0.0))
    assert blank.reaches_goal


def test_the_orbital_maps_edge_is_no_border_to_stop_short_of() -> None:
    """Seen ground that reaches past the orbital map's edge ends where the ground ends: the
    rover may drive along it without stopping the border inside it (hirise's east edge cut every
    leg after 2 points); the edge toward unseen ground on the orbital map stays a border."""
    g_geom = GridGeometry(0.5, 0.0, 4.0, 8, 8)  # x 0..4, y 0..4
    g_hz = np.zeros(g_geom.shape, np.uint8)
    g_hz[:, 4] = HAZARDOUS  # a wall at x 2..2.5 from y 0 to 4
    orbit = NavMaps(g_hz, np.zeros(g_geom.shape, np.float32), g_geom)
    l_geom = GridGeometry(0.05, -1.0, 5.0, 120, 120)  # x -1..5, y -1..5
    l_hz = np.full(l_geom.shape, UNDEFINED, np.uint8)
    l_hz[4:40, 20:120] = SAFE  # seen: x 0..5, y 3..4.8, past the map's north and east edges
    l_hz[20:40, 60:70] = HAZARDOUS  # the wall, seen, up to the map's edge
    local = NavMaps(l_hz, np.zeros(l_geom.shape, np.float32), l_geom)
    params = PlannerParams(grid=0.05, rover_radius=0.2, margin=0.0, border=0.5)
    plan = plan_path(local, orbit, (1.0, 3.5), (3.5, 3.5), params)
    assert plan.reaches_goal and not any("cut" in w for w in plan.warnings)
    assert plan.path[:, 1].max() > 4.0  # round the wall, along the seen strip past the edge
    bd = plan.image.border_distance
    r, c = plan.image.geometry.cell_of(np.array([1.0, 1.0]), np.array([3.05, 4.75]))
    assert bd[r[0], c[0]] < 0.1  # unseen ground on the map south of the strip: a border
    assert bd[r[1], c[1]] > 1.0  # past the map's edge: none, the nearest is the strip's south side


def test_every_plan_setting_the_planner_declares_reaches_it_by_name() -> None:
    """A navigate leg, the see loop and the plan_leg script build the planner's parameters through
    PlannerParams.of: a setting declared in both classes reaches the planner with no more wiring."""
    from dataclasses import fields

    from prox_workflows.algorithms.plan_params import PlannerParams, PlanParams

    specs = PlanParams.specs()

    def other(spec: Any) -> Any:  # a valid value that is not the default
        if spec.choices:
            return next(c for c in spec.choices if c != spec.default)
        return (spec.default + spec.max) / 2

    changed = {f.name: other(specs[f.name]) for f in fields(PlannerParams) if f.name in specs}
    assert {"weight", "heuristic", "grid", "margin", "max_deviation", "border"} <= set(changed)
    for given in (PlanParams(**changed, footprint="body"), {**changed, "footprint": "body", "extra": 1}):
        p = PlannerParams.of(given, rover_radius=0.4, half_width=0.25, critical_slope=15.0)
        assert {name: getattr(p, name) for name in changed} == changed
        assert (p.rover_radius, p.half_width, p.critical_slope, p.unknown_cost) == (0.4, 0.25, 15.0, 1.0)
    circle = PlannerParams.of(PlanParams(), rover_radius=0.4, half_width=0.25, critical_slope=15.0, unknown_cost=3.0)
    assert circle.half_width is None and circle.unknown_cost == 3.0 and circle.border == PlanParams().border
    with pytest.raises(ValueError, match="half width"):
        PlannerParams.of({"footprint": "body"}, rover_radius=0.4, critical_slope=15.0)


def test_a_plan_that_gets_the_rover_nowhere_says_so() -> None:
    """navigate's loops both end a leg whose driven part ends within MIN_LEG (or the see loop's
    10 cm) of where it starts: a plan says so itself (``PlanResult.stands_still``)."""
    maps = rock_field(3, rocks=0)
    start = (100.52, -44.03)
    far = plan_path(maps, None, start, (101.52, -44.03), PlannerParams(weight=1.0, border=0.0))
    assert not far.stands_still() and not far.stands_still(0.1)
    # 8 cm east: more than MIN_LEG (5 cm), less than the see loop's 10 cm
    near = plan_path(maps, None, start, (100.60, -44.03), PlannerParams(weight=1.0, border=0.0))
    moved = math.hypot(*(near.path[near.cut - 1] - near.path[0]))
    assert moved == pytest.approx(0.08, abs=1e-9)
    assert not near.stands_still() and near.stands_still(0.1)
    # 3 cm: less than MIN_LEG
    step = plan_path(maps, None, start, (100.55, -44.03), PlannerParams(weight=1.0, border=0.0))
    assert step.stands_still()
