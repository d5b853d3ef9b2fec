"""The 200 m traverse's scene and bench (tools.bench.scale): the long yard, its missions, the
true surface judged in tiles, and the per-stretch table."""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.marks import long_test

import rvs_truth.surface as surface
from drivers.sim.world import World
from prox_workflows.algorithms.vehicle import check_poses
from rvs_truth.surface import AREA, missions, truth_checks
from tools.bench.scale import judge, odometer, stretch_table


def _cover(world: World, bounds: tuple[float, float, float, float]) -> float:
    """The share of ``bounds`` the scene's rocks cover (their footprint ellipses)."""
    x0, y0, x1, y1 = bounds
    rocks = [r for r in world.terrain.rocks if x0 <= r["x"] <= x1 and y0 <= r["y"] <= y1]
    return sum(math.pi * r["a"] * r["b"] for r in rocks) / ((x1 - x0) * (y1 - y0))


@long_test  # builds the 212 m scene twice: a minute and 1.4 GB
def test_the_long_yard_has_the_yards_rock_cover_and_missions_200_m_apart() -> None:
    long = World.from_scene("marsyard_long")
    yard = World.from_scene("marsyard")
    x0, y0, x1, y1 = AREA["marsyard_long"]
    assert (x1 - x0, y1 - y0) == (211.0, 15.0)
    assert long.terrain.cell == 0.02  # 1 cm would be 34 M nodes and 5.6 GB to build
    cover, yard_cover = _cover(long, AREA["marsyard_long"]), _cover(yard, AREA["marsyard"])
    assert 0.6 * yard_cover <= cover <= 1.4 * yard_cover, (cover, yard_cover)
    assert not surface.whole_truth("marsyard_long") and surface.whole_truth("dense")
    del long, yard
    drawn = missions("marsyard_long", 2)
    assert len(drawn) == 2
    for (sx, sy), (gx, gy) in drawn:
        assert 199.0 <= math.hypot(gx - sx, gy - sy) <= 201.0
        assert x0 <= min(sx, gx) and max(sx, gx) <= x1 and y0 <= min(sy, gy) and max(sy, gy) <= y1


def test_the_truth_judged_in_tiles_is_the_whole_surfaces_judgement(monkeypatch: pytest.MonkeyPatch) -> None:
    """A 14 m track in marsyard, over the 40 cm rock at (4, 1) and turning back: the tiles (at
    most 10 m of poses each, so two or more) give every pose the whole surface's values."""
    world = World.from_scene("marsyard")
    xs = np.arange(0.0, 8.0, 0.02)
    out = np.column_stack([xs, np.full(xs.size, 1.0), np.zeros(xs.size)])
    back = np.column_stack([xs[::-1], np.full(xs.size, -1.5), np.full(xs.size, 180.0)])
    poses = np.vstack([out, back])
    whole = truth_checks(world, "marsyard", poses, world.body)
    assert whole.unsafe.any() and not whole.unsafe.all()
    monkeypatch.setattr(surface, "WHOLE_TRUTH_CELLS", 0)
    tiled = truth_checks(world, "marsyard", poses, world.body)
    # the samples of a tile and of the whole surface differ in the last float bits of their positions
    np.testing.assert_allclose(tiled.excess, whole.excess, atol=1e-4)
    np.testing.assert_array_equal(tiled.unsafe, whole.unsafe)


def test_a_body_reaching_past_the_mission_area_is_judged_on_the_world_s_ground_there(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Hirise's area ends at y = 14 m, 1 m inside its terrain. A rover turning at (-7.58, 13.85)
    puts its right wheels past that edge: read on the area's surface alone, the ground off it is
    taken as a drop (a 4 cm step over the climb at the front-right wheel that the world does not
    have); judged where the world goes on, it is safe with 7 cm to spare. A pose the area covers
    is judged on it as before. (The area is cut down to 2 x 1 m here to keep the surface small.)"""
    world = World.from_scene("hirise")
    monkeypatch.setitem(AREA, "hirise", (-8.5, 13.0, -6.5, 14.0))
    monkeypatch.setattr(surface, "_TRUTH", {})
    poses = np.array([[-7.582, 13.854, -152.491], [-7.6, 13.3, 0.0]])
    fine, g, _ = surface.truth_surface(world, "hirise")
    cut = check_poses(fine, g, poses, world.body)
    assert cut.excess[0, 0] > 0.03  # the edge read as a step
    judged = truth_checks(world, "hirise", poses, world.body)
    around, ga, _ = surface.surface_over(world, (-9.0, 12.5, -6.0, 15.0))
    np.testing.assert_allclose(judged.excess, check_poses(around, ga, poses, world.body).excess, atol=1e-4)
    assert judged.excess[0, 0] < -0.05 and not judged.unsafe.any()
    np.testing.assert_allclose(judged.excess[1], cut.excess[1], atol=1e-6)


def test_an_event_is_put_at_the_distance_driven_where_it_starts() -> None:
    world = World.from_scene("marsyard")
    track = np.array([(2.0, 1.0, 0.0), (6.0, 1.0, 0.0)])
    events = judge(world, "marsyard", track, world.body, offset=100.0)
    assert events, "the 40 cm rock at (4, 1) is under the body"
    at, kind = events[0]
    # the body's front reaches the rock (a 0.45 m half axis at x = 4) within 2 m of x = 2
    assert 100.5 < at < 102.0 and kind in ("step", "belly", "stability", "grade")
    assert judge(world, "marsyard", np.array([(0.0, -1.5, 0.0), (1.0, -1.5, 0.0)]), world.body) == []


def test_the_odometer_adds_up_the_track() -> None:
    assert odometer(np.array([(0.0, 0.0), (3.0, 4.0), (3.0, 4.0), (3.0, 5.0)])).tolist() == [0.0, 5.0, 5.0, 6.0]
    assert odometer(np.zeros((1, 2))).tolist() == [0.0]


def test_the_stretch_table_of_a_synthetic_series() -> None:
    """Cycles every 2.5 m over 120 m, their wall ms 10 per index within the stretch (the CPU half
    of it), a choice every 10 m, memory growing 1 MB a metre, events at 49.99, 50 and 120 m."""
    timings = []
    for k in range(3):
        for i in range(20 if k < 2 else 9):  # 0, 2.5, ... 47.5 past the stretch's start; 100-120 in the last
            at = k * 50.0 + i * 2.5
            timings.append((at, "cycle", 10.0 * i, 5.0 * i))
        for i in range(5 if k < 2 else 3):
            timings.append((k * 50.0 + i * 10.0, "choice", 1000.0 + 100.0 * i, 900.0))
    memory = [(float(m), 500.0 + m, 40.0) for m in range(0, 121)]
    events = [(49.99, "step"), (50.0, "belly"), (120.0, "stability")]
    rows = stretch_table(timings, memory, events, driven=120.0)
    assert [(r["from_m"], r["to_m"]) for r in rows] == [(0.0, 50.0), (50.0, 100.0), (100.0, 120.0)]
    assert [r["cycles"] for r in rows] == [20, 20, 9]
    # 20 values 0, 10, ... 190: the 95th percentile lies 0.05 of the way from 180 to 190
    assert [r["cycle_ms_p95"] for r in rows] == [180.5, 180.5, 76.0]
    assert [r["cycle_cpu_ms_p95"] for r in rows] == [90.2, 90.2, 38.0]
    assert [r["choices"] for r in rows] == [5, 5, 3]
    assert [r["choice_ms_p95"] for r in rows] == [1380.0, 1380.0, 1190.0]
    assert [r["rss_mb_max"] for r in rows] == [549.0, 599.0, 620.0]
    assert [r["rss_mb_last"] for r in rows] == [549.0, 599.0, 620.0]
    assert [r["maps_mb_max"] for r in rows] == [40.0, 40.0, 40.0]
    assert [(r["events"], r["event_kinds"]) for r in rows] == [(1, ["step"]), (1, ["belly"]), (1, ["stability"])]
    # a mission that ends on a boundary has no empty last row; one that never moved has one row
    assert len(stretch_table(timings, memory, events, driven=100.0)) == 2
    only = stretch_table([], [(0.0, 300.0, 1.0)], [], driven=0.0)
    assert [(r["from_m"], r["to_m"], r["cycles"], r["rss_mb_max"]) for r in only] == [(0.0, 0.0, 0, 300.0)]


def test_the_sampler_reads_the_mission_the_bus_hands_over() -> None:
    """The sampler takes the running loop from the server bus's ``mission`` item (its
    strategy's driver, its track), and reads their timings and maps from then on."""
    import time
    from types import SimpleNamespace

    from rvs_server.bus import Bus
    from rvs_server.navigation.loop_stats import LoopStats
    from tools.bench.scale import Sampler

    stats = LoopStats(cycle_ms=[10.0, 20.0], cycle_cpu_ms=[5.0, 6.0], replan_ms=[300.0], replan_cpu_ms=[100.0])
    driver = SimpleNamespace(stats=stats, bounds=None, map=None)
    track = SimpleNamespace(rows=[(0.0, 0.0, 0.0), (3.0, 4.0, 0.0)])
    mission = SimpleNamespace(strategy=SimpleNamespace(driver=driver), track=track)
    bus = Bus()
    world = SimpleNamespace(clock=SimpleNamespace(now=lambda: 0.0))
    sampler = Sampler(world, "marsyard", 50.0, 0.01, lambda row: None)
    bus.subscribe(sampler.on_bus)
    bus.publish("reply", conn=1, reply=None, job=False)
    assert sampler.mission is None
    bus.publish("mission", mission=mission)
    assert sampler.mission is mission
    sampler.start()
    deadline = time.monotonic() + 30.0
    while sampler.driven < 5.0 and time.monotonic() < deadline:
        time.sleep(0.02)
    sampler.halt.set()
    sampler.join()
    assert sampler.driver is driver and sampler.track is track
    assert sampler.driven == pytest.approx(5.0)
    assert [t[1:] for t in sampler.timings[:3]] == [("cycle", 10.0, 5.0), ("cycle", 20.0, 6.0),
                                                    ("choice", 300.0, 100.0)]


def test_a_body_reaching_past_the_world_s_terrain_is_not_judged() -> None:
    """Dense_fresh's terrain ends at x = -15 m, 1 m past its area. The rover at (-14.656, 0.819)
    turned to 24.1 deg puts its rear-left wheel's footprint over that edge, where the truth has no
    ground: read as a drop it was a 12 cm step (an event no rover could have). The truth leaves
    that pose unjudged, never unsafe; 0.3 m further in, the same heading is judged."""
    world = World.from_scene("dense_fresh")
    assert world.terrain.bounds[0] == pytest.approx(-15.0)
    poses = np.array([[-14.656, 0.819, 24.1], [-14.356, 0.819, 24.1]])
    judged = truth_checks(world, "dense_fresh", poses, world.body)
    assert judged.unknown.tolist() == [True, False]
    assert np.isnan(judged.excess[0]).all() and not judged.unsafe[0]
    assert np.isfinite(judged.excess[1]).all()
