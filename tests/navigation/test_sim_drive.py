"""The simulated rover in simulated time (issue 12, items 1, 5 and 6): one world clock for the
drive, the PTU and the ToF; sim drive, wheel slip against the dead-reckoned pose, rocks added at
run time, scenes loaded from any path, and the hirise scene built on the real HiRISE DTM.

No test waits on the wall clock for a simulated duration: servers run at sim.time_scale 0
(the conftest default) or at a high scale, and the assertions read the simulated clock."""

from __future__ import annotations

import json
import math
import shutil
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import tifffile
from jsonschema import Draft202012Validator
from support.marks import long_suite

from drivers.rover import create as create_rover
from drivers.sim.clock import SimClock
from drivers.sim.world import World
from rvs_server.navigation.scan import WaypointPilot
from rvs_server.navigation.track import Track
from rvs_truth.orbital import write_global_maps

ROOT = Path(__file__).resolve().parents[2]
SCHEMA = Draft202012Validator(json.loads((ROOT / "docs" / "replies.schema.json").read_text()))


def num(r, key: str) -> float:
    return float(r.fields[key])


# ------------------------------------------------------------------ the clock


def test_the_clock_at_scale_zero_counts_time_without_waiting() -> None:
    clock = SimClock(0.0)
    t0 = time.monotonic()
    assert clock.sleep(3600.0)
    assert clock.now() == pytest.approx(3600.0)
    clock.advance_to(10.0)  # behind: no change
    assert clock.now() == pytest.approx(3600.0)
    assert time.monotonic() - t0 < 1.0


def test_the_clock_follows_a_changed_scale_without_jumping() -> None:
    scale = [1000.0]
    clock = SimClock(lambda: scale[0])
    assert clock.sleep(5.0)  # 5 ms of wall time
    before = clock.now()
    assert before >= 5.0
    scale[0] = 0.0
    after = clock.now()
    assert after - before < 1.0  # rebased at the change, no jump
    assert clock.sleep(100.0) and clock.now() == pytest.approx(after + 100.0, abs=0.5)
    assert not clock.sleep(1.0, cancel=lambda: True)


# ------------------------------------------------------------------ world level: drive, slip, rocks


def test_drive_integrates_v_and_w_and_odometry_equals_truth_without_slip() -> None:
    w = World.from_scene("office", clock_scale=0.0)
    w.drive(0.1, 0.0, 10.0)
    w.drive(0.0, 15.0, 6.0)
    t = w.truth()
    assert (t["x"], t["y"], t["heading"]) == pytest.approx((1.0, 0.0, 90.0), abs=1e-9)
    assert t["sim_time"] == pytest.approx(16.0)
    # An arc: radius v / w, a quarter circle in 2 pi r / 4 / v seconds.
    v, wd = 0.1, 10.0
    r = v / math.radians(wd)
    w.drive(v, wd, 9.0)
    t = w.truth()
    assert (t["x"], t["y"], abs(t["heading"])) == pytest.approx((1.0 - r, r, 180.0), abs=2e-3)
    assert w.odometry() == pytest.approx((t["x"], t["y"], t["heading"]))


def test_the_clock_keeps_what_moved_it_on_and_overlapping_waits_count_once() -> None:
    w = World.from_scene("office", clock_scale=0.0)
    w.drive(0.1, 0.0, 10.0)
    w.drive(0.0, 15.0, 6.0)
    w.drive(-0.1, 5.0, 2.0)
    w.clock.sleep(1.5, what="tof frames")
    now = w.clock.now()
    w.clock.advance_to(now + 3.0, "ptu moves")  # a slew awaited
    w.clock.advance_to(now + 2.0, "ptu moves")  # a second wait that ended within the first
    assert dict(w.clock.spent) == pytest.approx({"drive": 10.0, "turn on the spot": 6.0, "reverse": 2.0,
                                                 "tof frames": 1.5, "ptu moves": 3.0})
    assert sum(w.clock.spent.values()) == pytest.approx(w.clock.now())


@pytest.mark.parametrize("seed", [1, 2])
def test_slip_leaves_the_truth_short_of_and_beside_the_odometry(seed: int) -> None:
    w = World.from_scene("office", clock_scale=0.0)
    w.set_slip(0.05, 2.0, seed)
    w.drive(0.1, 0.0, 50.0)  # 5 m commanded along x
    t = w.truth()
    assert w.odometry() == pytest.approx((5.0, 0.0, 0.0), abs=1e-9)
    # 5 % of the distance lost (within the per-step draws' spread), 2 deg per metre of drift.
    assert math.hypot(t["x"], t["y"]) == pytest.approx(5.0 * 0.95, abs=0.03)
    assert abs(t["heading"]) == pytest.approx(10.0, abs=1.0)
    # Seeded: the same seed gives the same truth.
    w2 = World.from_scene("office", clock_scale=0.0)
    w2.set_slip(0.05, 2.0, seed)
    w2.drive(0.1, 0.0, 50.0)
    assert w2.truth()["x"] == t["x"] and w2.truth()["heading"] == t["heading"]


def test_an_added_rock_raises_the_terrain_and_the_renderer_sees_it() -> None:
    w = World.from_scene("office", clock_scale=0.0)
    bounds = (1.2, -0.3, 1.8, 0.3)
    before = w.true_dem(0.02, bounds)
    w.set_ptu(0.0, -35.0)
    depth_before = w.render_sensor("tof", 176, 144).depth
    n = len(w.rocks())
    rock = w.add_rock(1.5, 0.0, 0.2, 0.3)
    assert len(w.rocks()) == n + 1 and rock["height"] > 0.25
    after = w.true_dem(0.02, bounds)
    assert float(np.nanmax(after - before)) > 0.25
    assert float(np.nanmax(after - before)) == pytest.approx(rock["height"], abs=0.08)
    depth_after = w.render_sensor("tof", 176, 144).depth
    closer = np.nan_to_num(depth_before - depth_after)
    assert (closer > 0.1).sum() > 50  # the rock stands in front of the floor the camera saw


# ------------------------------------------------------------------ through the server


def test_sim_drive_and_slip_through_a_socket_in_simulated_time(server_factory) -> None:
    srv = server_factory(["sim.time_scale=1000"])
    c = srv.client()
    t0 = num(c.request("sim truth"), "sim_time")
    wall = time.monotonic()
    r = c.request("sim drive -v 0.2 -w 0 -seconds 5")
    assert r.status == "OK" and num(r, "seconds") == pytest.approx(5.0) and num(r, "x") == pytest.approx(1.0, abs=1e-3)
    r = c.request("sim drive -v 0 -w 15 -seconds 6")
    assert num(r, "heading") == pytest.approx(90.0, abs=1e-2) and num(r, "sim_time") - t0 >= 11.0
    assert time.monotonic() - wall < 5.0  # 11 simulated seconds at 1000x
    # The default speed is the scene's rover speed (0.1 m/s): forward is now +y.
    r = c.request("sim drive -seconds 10")
    assert (num(r, "x"), num(r, "y")) == pytest.approx((1.0, 1.0), abs=1e-3)
    r = c.request("sim slip -distance 0.05 -heading 2 -seed 7")
    assert r.status == "OK" and r.fields["seed"] == "7"
    r = c.request("sim drive -v 0.1 -seconds 20")
    assert (num(r, "odom_x"), num(r, "odom_y"), num(r, "odom_heading")) == pytest.approx((1.0, 3.0, 90.0), abs=1e-3)
    assert num(r, "y") - 1.0 == pytest.approx(2.0 * 0.95, abs=0.03)
    assert abs(num(r, "heading") - 90.0) == pytest.approx(4.0, abs=0.6)
    st = c.request("status")
    assert "truth" in st.fields and "sim_time" in st.fields
    assert c.request("sim drive -v 9").status == "ERROR"  # out of range: E_ARG
    # JSON: every new key is declared in the schema.
    c.request("format json")
    for line in ("sim truth", "sim slip -distance 0", "sim drive -seconds 0.5", "status",
                 "sim add-rock -x 2 -y 0 -radius 0.1 -height 0.1"):
        c.send(line)
        obj = json.loads(c.line())
        while obj["status"] == "EVENT":  # the JSON greeting after format json
            obj = json.loads(c.line())
        assert obj["status"] == "OK" and not list(SCHEMA.iter_errors(obj)), (line, obj)
    c.close()


def test_ptu_moves_and_tof_frames_take_their_time_on_the_world_clock(server_factory) -> None:
    """drivers.ptu.time_scale null (the default outside tests): the PTU follows the world clock;
    at sim.time_scale 0 a move is instant in wall time and still counts its simulated time."""
    srv = server_factory(["drivers.ptu.time_scale=null"])
    c = srv.client()
    t0 = num(c.request("sim truth"), "sim_time")
    assert c.request("move-ptu -pan 90 -tilt 0").status == "OK"
    t1 = num(c.request("sim truth"), "sim_time")
    assert 1.0 < t1 - t0 < 10.0  # a D46 at its default speed takes seconds for 90 degrees
    assert c.request("grab-tof -output clk").status == "OK"
    t2 = num(c.request("sim truth"), "sim_time")
    assert 0.005 < t2 - t1 < 1.0  # one or a few frames of 4 x integration + 5 ms
    c.close()


def test_add_rock_is_seen_by_a_tof_grab(server_factory) -> None:
    srv = server_factory()
    c = srv.client()
    assert c.request("move-ptu -pan 0 -tilt -35").status == "OK"

    def grab(name: str) -> np.ndarray:
        r = c.request(f"grab-tof -type distance -output {name}")
        assert r.status == "OK", r
        return tifffile.imread(srv.data / r.fields["file"])

    before = grab("before")
    r = c.request("sim add-rock -x 1.5 -y 0 -radius 0.2 -height 0.3")
    assert r.status == "OK" and num(r, "height") > 0.25 and int(r.fields["rocks"]) >= 1
    after = grab("after")
    assert (np.nan_to_num(before - after) > 0.1).sum() > 50
    assert c.request("sim add-rock -x 500 -y 0").status == "ERROR"  # off the terrain: E_ARG
    c.close()


def test_sim_scene_loads_a_scene_file_from_any_path(server_factory, tmp_path: Path) -> None:
    srv = server_factory()
    c = srv.client()
    copy = tmp_path / "elsewhere" / "my_office.yaml"
    copy.parent.mkdir()
    shutil.copy(ROOT / "config" / "scenes" / "office.yaml", copy)
    text = copy.read_text().replace("name: office", "name: my_office")
    copy.write_text(text)
    r = c.request(f'sim scene "{copy}"')
    assert r.status == "OK" and r.fields["scene"] == "my_office", r
    assert c.request("sim scene").fields["scene"] == "my_office"
    r = c.request(f'sim scene "{tmp_path / "none.yaml"}"')
    assert r.status == "ERROR" and r.fields["code"] == "E_ARG"
    assert c.request("sim scene office").fields["scene"] == "office"  # by name, as before
    c.close()


# ------------------------------------------------------------------ hirise


def test_the_hirise_scene_is_the_dtm_with_rocks_at_15_percent_cover(tmp_path: Path) -> None:
    # A copy of the scene file elsewhere still finds the DTM shipped in the package.
    copy = tmp_path / "hirise.yaml"
    shutil.copy(ROOT / "config" / "scenes" / "hirise.yaml", copy)
    w = World.from_scene(copy, clock_scale=0.0)
    xmin, ymin, xmax, ymax = w.terrain.bounds
    area = (xmax - xmin) * (ymax - ymin)
    cover = sum(math.pi * r["a"] * r["b"] for r in w.rocks()) / area
    assert 0.08 < cover < 0.2  # k = 0.15, rocks of 5 cm to 1 m (the rest of k is bigger rocks)
    relief = float(np.ptp(w.terrain.heights))
    assert relief > 2.0  # the DTM's metres of relief, not a flat yard

    from prox_workflows.grid import read_geotiff

    paths = write_global_maps(str(copy), tmp_path / "global")
    hazard, g = read_geotiff(paths["hazard"])
    slope, g2 = read_geotiff(paths["slope"])
    dem, _ = read_geotiff(paths["dem"])
    # 31 x 31 DTM nodes; the edge cells reach past the scene's +-15 m terrain and are dropped
    assert g == g2 and g.cell == pytest.approx(1.01) and g.shape == (29, 29)
    assert xmin <= g.xmin and g.xmax <= xmax and ymin <= g.ymin and g.ymax <= ymax
    assert set(np.unique(hazard)) <= {0, 128, 255} and (hazard == 0).mean() > 0.8
    # The orbital map and the simulated ground agree away from rocks (to the roughness added).
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs[5:-5], ys[5:-5])
    ground = w.terrain.sample(X, Y)
    assert float(np.nanmedian(np.abs(ground - dem[5:-5, 5:-5]))) < 0.1


def test_a_dem_full_tof_runs_on_the_hirise_scene(server_factory, tmp_path: Path) -> None:
    from rvs_server.navigation.planning import load_global_folder

    maps = load_global_folder(str(write_global_maps("hirise", tmp_path / "global").get("hazard").parent))
    assert maps is not None and maps.geometry.cell == pytest.approx(1.01)  # usable as navigate.global_maps
    srv = server_factory(["server.scene=hirise"])
    c = srv.client()
    r = c.request("dem-full-tof -range -20,20,-50,-30 -name hirise", timeout=300)
    assert r.status == "OK", r
    assert int(r.fields["cells"]) > 1000 and float(r.fields["coverage"]) > 0.05
    c.close()


# ------------------------------------------------------------------ navigate -auto on odometry


def drive_simulated(world: World, waypoints: list[tuple[float, float]], reached: Any = None) -> Track:
    """navigate -auto's scan leg on the simulated rover: to each waypoint, turn, then straight."""
    rover = create_rover({"backend": "sim"}, world)
    rover.open()
    track = Track()
    track.add(world.rover_pose())
    rover.drive(WaypointPilot(np.asarray(waypoints, float), track, reached or (lambda k: None), rover.steers))
    return track


def test_the_auto_drive_steers_by_odometry_so_slip_leaves_the_truth_off_the_waypoints() -> None:
    w = World.from_scene("office", clock_scale=0.0)
    w.set_slip(0.05, 2.0, 5)
    reached: list[int] = []
    track = drive_simulated(w, [(0.0, 0.0), (1.0, 1.0), (2.0, 0.0)], reached=reached.append).rows
    assert reached == [1, 2]
    ox, oy, _ = w.odometry()
    assert (ox, oy) == pytest.approx((2.0, 0.0), abs=1e-6)  # where it believes it is: the last waypoint
    t = w.truth()
    assert 0.05 < math.hypot(t["x"] - 2.0, t["y"]) < 0.5  # where it is: short and beside
    assert track[-1] == (t["x"], t["y"], t["heading"]) and len(track) > 20  # the true track, every 5 cm
    # 2 * sqrt(2) m at 0.1 m/s plus turns of 45 and 90 degrees at 15 deg/s, in simulated time
    assert t["sim_time"] == pytest.approx(2 * math.sqrt(2) / 0.1 + 135.0 / 15.0, abs=0.2)


def test_the_track_records_the_heading_and_turns_on_the_spot() -> None:
    """A turn on the spot sweeps the body's corners over ground a position never shows: the track
    gets a row every 5 degrees turned while the rover stands, each with its true heading."""
    w = World.from_scene("office", clock_scale=0.0)
    track = drive_simulated(w, [(0.0, 0.0), (0.0, 1.0)]).rows  # face +y (a 90-degree turn), then 1 m
    standing = np.array([row for row in track if math.hypot(row[0], row[1]) < 1e-9])
    steps = np.diff(standing[:, 2])
    assert len(standing) >= 16 and standing[-1, 2] == pytest.approx(90.0, abs=1e-6)
    assert np.all(steps >= 5.0 - 1e-9) and np.all(steps <= 6.0 + 1e-9)  # 1.5 deg per 0.1 s step at 15 deg/s
    t = w.truth()
    assert track[-1] == (t["x"], t["y"], t["heading"]) and t["y"] == pytest.approx(1.0, abs=1e-6)


@long_suite
def test_navigate_auto_believes_the_odometry_not_the_truth(server_factory) -> None:
    """With slip, navigate -auto's pose after each leg is the rover's dead reckoning (what a GNC
    would report), so the server's pose and the truth part; the drive takes simulated time
    (turns at 15 deg/s, 0.1 m/s) and its PROGRESS counts segments in one phase per leg."""
    srv = server_factory(["server.scene=office"])
    c = srv.client()
    assert c.request("sim slip -distance 0.05 -heading 2 -seed 3").status == "OK"
    t0 = num(c.request("sim truth"), "sim_time")
    c.send("navigate -goal 1.5,-1.2 -auto -loop scan -scan-plan circle -name slip")
    lines = c.until_final(timeout=600)
    final = lines[-1]
    assert final.status == "OK" and final.fields["reached"] == "true", final.fields
    drive = [r for r in lines if r.status == "PROGRESS" and r.fields.get("phase") == "drive"]
    assert drive and all(r.fields["total"] == drive[0].fields["total"] for r in drive
                         if r.fields["leg"] == drive[0].fields["leg"])
    truth = c.request("sim truth")
    pose = [float(v) for v in c.request("status").fields["pose"].split(",")]
    assert pose[:2] == pytest.approx([num(truth, "odom_x"), num(truth, "odom_y")], abs=2e-3)
    assert math.hypot(pose[0] - num(truth, "x"), pose[1] - num(truth, "y")) > 0.01  # slip showed
    dist = math.hypot(num(truth, "odom_x"), num(truth, "odom_y"))
    assert num(truth, "sim_time") - t0 >= dist / 0.1  # it drove at 0.1 m/s in simulated time
    c.close()


def test_a_frame_taken_while_the_rover_is_under_way_costs_no_standing_time(server_factory) -> None:
    """The see loop's frames are exposed while the rover rolls (World.under_way): the clock
    moves only with the drive; standing, a frame takes its own time."""
    srv = server_factory(["drivers.ptu.time_scale=null"])
    world = srv.app.world
    tof = srv.app.devices.get("tof")
    t0 = world.clock.now()
    tof.grab_xyz(1, 0.0)
    standing = world.clock.now() - t0
    assert standing > 0.005
    with world.under_way():
        assert world.rolling
        t1 = world.clock.now()
        tof.grab_xyz(1, 0.0)
        assert world.clock.now() - t1 == 0.0
        world.drive(0.1, 0.0, 0.5)
        assert world.clock.now() - t1 == pytest.approx(0.5)
    assert not world.rolling
