"""The vehicle yardstick (rvs_truth.vehicle) the navigate benchmark scores with: the track it judges, the plan poses,
the tracking error, stop reasons and the thresholds a mission runs with."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import rvs_server.navigation.sections as sections
from drivers.sim.rover import RoverBody
from drivers.sim.world import World
from prox_workflows.algorithms.candidates import SAFE, UNKNOWN
from prox_workflows.algorithms.vehicle import check_poses, densify
from prox_workflows.grid import GridGeometry
from rvs_truth.orbital import from_orbit
from rvs_truth.stats import clopper_pearson_upper
from rvs_truth.surface import area, missions, set_down_safe, truth_surface
from rvs_truth.vehicle import (
    capability_hazard,
    cross_track,
    mission_hazard,
    plan_poses,
    read_track,
    stop_reason,
    vehicle_check,
)
from tools.bench.live_risk import Recorder, live_risk, summed


def test_a_track_is_read_with_its_headings_or_faces_along_itself(tmp_path: Path) -> None:
    with_heading = tmp_path / "a.csv"
    with_heading.write_text("x,y,heading\n0,0,0\n0,0,30\n0.05,0.03,30\n")
    assert read_track(with_heading).tolist() == [[0, 0, 0], [0, 0, 30], [0.05, 0.03, 30]]
    without = tmp_path / "b.csv"
    without.write_text("x,y\n0,0\n0,0.05\n0,0.10\n")
    assert read_track(without)[:, 2].tolist() == pytest.approx([90.0, 90.0, 90.0])


def test_a_plan_is_driven_with_a_turn_on_the_spot_at_each_waypoint() -> None:
    poses = plan_poses(np.array([(0.0, 0.0), (1.0, 0.0), (1.0, 1.0)]), 45.0)
    assert np.allclose(poses, [[0, 0, 45], [0, 0, 0], [1, 0, 0], [1, 0, 90], [1, 1, 90]])
    assert np.allclose(plan_poses(np.array([(0.0, 0.0), (1.0, 0.0)]), 0.0), [[0, 0, 0], [1, 0, 0]])


def test_a_turn_in_a_plan_over_a_rock_is_an_event_the_straight_leg_is_not() -> None:
    """A rock beside the start, outside the corridor the leg drives and outside the box the rover
    starts in, is swept by the rear-right wheel while the rover turns from 90 deg to face the leg."""
    g = GridGeometry.covering(-1.0, -1.0, 2.0, 2.0, 0.01)
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    h = np.where(np.hypot(X - 0.15, Y + 0.35) <= 0.03, 0.13, 0.0).astype(np.float32)
    body, surface = RoverBody(), (h, g, g)
    leg = np.array([(0.0, 0.0), (1.0, 0.0)])
    events, checked = vehicle_check(plan_poses(leg, 0.0), surface, body)
    assert (events, checked) == ([], 51)  # 1 m at 2 cm, clear
    events, _ = vehicle_check(plan_poses(leg[:1].repeat(2, axis=0), 90.0), surface, body)
    assert events == []  # standing at 90 deg, clear
    events, checked = vehicle_check(plan_poses(leg, 90.0), surface, body)
    assert checked > 51
    assert [e.kind for e in events] == ["step rear-right"]
    assert events[0].excess == pytest.approx(0.03, abs=0.005) and (events[0].x, events[0].y) == (0.0, 0.0)


def test_cross_track_is_the_distance_to_the_nearest_stretch_of_the_same_leg() -> None:
    wps = np.array([(0.0, 0.0), (2.0, 0.0), (2.0, 0.0), (2.0, 2.0)])
    legs = np.array([1, 1, 2, 2])
    track = np.array([(1.0, 0.1, 0.0), (2.05, 1.0, 90.0), (3.0, 0.0, 0.0)])
    assert cross_track(track, wps, legs).tolist() == pytest.approx([0.1, 0.05, 1.0])
    # no stretch joins the last waypoint of leg 1 to the first of a leg elsewhere
    assert cross_track(np.array([(1.0, 1.0, 0.0)]), np.array([(0.0, 0.0), (2.0, 0.0), (0.0, 2.0), (2.0, 2.0)]),
                       np.array([1, 2, 3, 3])).tolist() == pytest.approx([1.0])


def test_stop_reasons_and_the_thresholds_a_mission_runs_with() -> None:
    assert stop_reason("goal unreachable (enclosed): the goal lies in ...") == "goal unreachable"
    assert stop_reason("goal not reached after 3 scans and 30 legs; the rover is at (1, 2)") == "goal not reached"
    assert mission_hazard(()) == {"step_max": 0.15, "slope_max": 20.0}
    assert mission_hazard(("dem2hazard.step_max=0.06", "navigate.margin=0.05")) == {"step_max": 0.06,
                                                                                    "slope_max": 20.0}
    assert capability_hazard(RoverBody()) == {"step_max": 0.08, "slope_max": 19.3}


def test_every_mission_start_is_one_the_rover_can_be_set_down_and_turn_at() -> None:
    """(-3.67, 2.62) in marsyard is 1 m from every hazard of the 15 cm map, yet a full turn there
    puts the body past its own limits on the true surface: the missions refuse it and draw on."""
    world = World.from_scene("marsyard")
    unsafe = (-3.67, 2.62)
    assert not set_down_safe(world, "marsyard", unsafe)
    drawn = missions("marsyard", 8)
    assert unsafe not in [s for s, _ in drawn] and len(drawn) == 8
    fine, g, _ = truth_surface(world, "marsyard")
    for start, _ in drawn:
        turn = densify(np.array([(*start, h) for h in (0.0, 120.0, 240.0, 360.0)]), 0.02, world.body)
        assert check_poses(fine, g, turn, world.body).safe.all(), start


def test_a_held_out_rock_draw_has_its_scenes_area_and_orbit() -> None:
    assert area("dense_fresh") == area("dense") and from_orbit("dense_fresh") and not from_orbit("marsyard")
    with pytest.raises(KeyError, match="no mission area"):
        area("office")


def test_a_slip_run_slips_each_mission_its_own_seeded_way() -> None:
    from tools.bench.navigate import parse_slip, slip_lines

    assert parse_slip("0.05,2") == (0.05, 2.0)
    assert slip_lines((0.05, 2.0), 0, 2) == ["sim slip -distance 0.05 -heading 2 -seed 2"]
    assert slip_lines((0.05, 2.0), 1, 0) == ["sim slip -distance 0.05 -heading 2 -seed 1000"]
    assert slip_lines(None, 0, 2) == []
    for bad in ("5%", "0.05", "0.95,2"):
        with pytest.raises(ValueError, match="--slip"):
            parse_slip(bad)


def test_a_noise_draw_reseeds_every_simulated_sensor_and_reach_is_counted_per_mission(tmp_path: Path) -> None:
    """The noise draw reaches the three simulated sensors that draw noise, through the server's
    own settings (a server started with them reads them back), and the rows of several draws
    are counted per mission."""
    from rvs_server.client.session import ServerThread
    from tools.bench.navigate import noise_sets, reach_over_draws

    sets = noise_sets(7)
    assert sets == ["drivers.tof.seed=7", "drivers.stereo.seed=7", "drivers.hazcam.seed=7"]
    srv = ServerThread([f"server.data={tmp_path}", "server.port=0", *sets], log_level="warning")
    srv.start(60)
    try:
        drivers = srv.app.config.get("drivers")
        assert (drivers.tof.seed, drivers.stereo.seed, drivers.hazcam.seed) == (7, 7, 7)
    finally:
        srv.stop()
    rows = [{"scene": "dense", "mode": "see", "mission": m, "noise": n, "reached": r}
            for m, n, r in [(0, 0, True), (0, 1, False), (0, 2, True), (3, 0, False), (3, 1, False), (3, 2, False)]]
    assert reach_over_draws(rows) == ["dense see: m0 2/3 m3 0/3; 2 of 6 runs"]


def test_a_sensor_seed_given_by_set_is_refused_for_the_noise_draw() -> None:
    """The noise draw's settings come after ``--set``'s, so a sensor's seed given there would be
    overridden without a word: every run under draw 0, whatever the command said."""
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "tools.bench.navigate", "--set", "drivers.tof.seed=3"],
                       capture_output=True, text=True, cwd=Path(__file__).resolve().parents[2], timeout=120)
    assert r.returncode == 2
    assert ("--set drivers.tof.seed=3: the simulated sensors' noise draw is --noise-seeds N (it sets "
            "drivers.hazcam.seed, drivers.stereo.seed, drivers.tof.seed); give the draw there") in r.stderr


def test_the_slip_option_refuses_a_bad_value_on_the_command_line() -> None:
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "tools.bench.navigate", "--slip", "5%"], capture_output=True,
                       text=True, cwd=Path(__file__).resolve().parents[2], timeout=120)
    assert r.returncode == 2
    assert "--slip '5%': give SHARE,DEG_PER_M, e.g. 0.05,2" in r.stderr


def test_the_arrival_is_judged_by_the_truth_beside_the_loops_belief() -> None:
    """5 m commanded with 5 % slip and 2 deg/m: the odometry (the loop's pose without a GNC) says
    the goal at (5, 0) is reached; the true rover stopped about 0.25 m short and to one side."""
    from tools.bench.navigate import arrival

    w = World.from_scene("marsyard", clock_scale=0.0)
    w.set_slip(0.05, 2.0, 3)
    w.drive(0.1, 0.0, 50.0)
    ox, oy, _ = w.odometry()
    got = arrival(w, (ox, oy), (5.0, 0.0), 0.3)
    assert got["believed_miss"] < 1e-6
    assert 0.2 < got["true_miss"] < 0.6 and got["true_reached"] == (got["true_miss"] <= 0.3)
    t = w.truth()
    assert got["true_miss"] == round(math.hypot(t["x"] - 5.0, t["y"]), 3)
    w.set_slip(0.0, 0.0, 0)
    w.set_rover_pose(0.0, 0.0, 0.0)
    w.drive(0.1, 0.0, 50.0)
    assert arrival(w, w.odometry()[:2], (5.0, 0.0), 0.3) == {"true_miss": 0.0, "believed_miss": 0.0,
                                                              "true_reached": True}


def test_a_localised_run_matches_on_the_scenes_true_dem_from_orbit(tmp_path: Path) -> None:
    from prox_workflows.grid import read_geotiff
    from tools.bench.navigate import localise_options

    world = World.from_scene("marsyard")
    assert localise_options(world, tmp_path, "none") == ""
    opts = localise_options(world, tmp_path, "map")
    assert opts == f"-localise map -global {tmp_path / 'orbit.tif'} -global-origin 500000.0,4000000.0"
    dem, g = read_geotiff(tmp_path / "orbit.tif")
    assert g.cell == 0.5 and (g.xmin, g.ymax) == (500000.0 - 6.0, 4000000.0 + 10.0)  # marsyard's terrain bounds
    # the cell (4.0-4.5, 1.0-1.5) on the big rock at (4, 1), 0.4 m high: its true height at the centre
    r, c = int(round((g.ymax - 4000001.5) / 0.5)), int(round((500004.0 - g.xmin) / 0.5))
    top = world.true_dem(0.5, (4.0, 1.0, 4.5, 1.5), include_target=False)[0, 0]
    assert top > 0.2 and dem[r, c] == pytest.approx(top, abs=1e-4)


def test_the_live_risk_counts_passes_the_truth_refuses_per_judgement_and_per_pose() -> None:
    """Truth: unsafe where x > 1. The chance check passes (2, 0, 10) twice and (2.004, 0, 10.2)
    once (the same pose at 1 cm, 1 deg), refuses (2.5, 0, 0), leaves (3, 0, 0) unknown; the
    worst-case check's pass at x 2 is not the chance check's; the drive's pass is its own part.
    The truth cannot judge past x 2.4 (the world's terrain ends): (2.5, 0, 0) counts nowhere."""
    p = np.array([[2.0, 0.0, 10.0], [2.004, 0.0, 10.2], [0.0, 0.0, 0.0], [2.5, 0.0, 0.0], [3.0, 0.0, 0.0]], np.float32)
    judged = [(p, np.array([SAFE, SAFE, SAFE, 2, UNKNOWN], np.int8), "chance", "choose", 4),
              (p[:1], np.array([SAFE], np.int8), "chance", "choose", 5),
              (p[:1], np.array([SAFE], np.int8), "bounds", "choose", 5),
              (p[2:3], np.array([SAFE], np.int8), "chance", "drive", 6)]

    def truth(poses: np.ndarray) -> SimpleNamespace:
        off = poses[:, 0] > 2.4
        return SimpleNamespace(unsafe=(poses[:, 0] > 1.0) & ~off, unknown=off)

    live = live_risk(judged, truth)
    choose, drive, every = live["choose"], live["drive"], live["all"]
    assert (choose["judged"], choose["distinct"], choose["passed"], choose["truly_unsafe"]) == (4, 2, 4, 3)
    assert (choose["false_safes"], choose["false_safes_distinct"]) == (3, 1)
    assert choose["misses"] == [{"pose": [2.0, 0.0, 10.0], "choice": 4}]
    assert choose["bound"] == pytest.approx(clopper_pearson_upper(3, 4))
    assert choose["bound_distinct"] == pytest.approx(clopper_pearson_upper(1, 2))
    assert (drive["judged"], drive["false_safes"], drive["distinct"]) == (1, 0, 1)
    assert (every["judged"], every["false_safes"]) == (5, 3)
    assert summed([live, live])["choose"]["false_safes_distinct"] == 2


def test_the_recorder_sees_the_loops_checks_and_puts_them_back() -> None:
    body = RoverBody()
    g = GridGeometry(0.025, -2.0, 2.0, 160, 160)
    ground = np.zeros((160, 160), np.float32)
    ground[:, 100:] = np.nan  # no bound east of x 0.5
    kept = sections.bounds_check
    with Recorder().installed() as rec:
        codes = sections.bounds_check((ground, ground.copy()), g, body)(np.array([[-1.0, 0.0, 0.0], [1.5, 0.0, 0.0]]))
    assert sections.bounds_check is kept
    assert list(codes) == [SAFE, UNKNOWN]
    (poses, recorded, kind, where, choice), = rec.judged
    assert kind == "bounds" and where == "choose" and choice == -1 and list(recorded) == list(codes)
    assert len(poses) == 2 and list(rec.refusals()) == []
