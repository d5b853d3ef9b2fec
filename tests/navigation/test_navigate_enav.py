"""navigate -loop see with its bounds map (see_gate bounds, the default): ENav's chooser plans every
section (rvs_server/navigation/sections.py). Judged by the vehicle on the simulator's true
surface (rvs_truth.vehicle), through the real server."""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.marks import long_only, long_test
from support.server import wait_for

from prox_workflows.algorithms.bounds_map import BoundsMap
from prox_workflows.algorithms.candidates import CandidateParams
from prox_workflows.algorithms.chance import ChanceParams
from prox_workflows.grid import GridGeometry
from rvs_truth.surface import fine_surface
from rvs_truth.vehicle import read_track, vehicle_check


def _events(srv, world, name: str, box: tuple[float, float, float, float]) -> tuple[list, int]:
    fine, g = fine_surface(world, box)
    surface = (fine, GridGeometry(0.01, g.xmin, g.ymax, g.width * 5, g.height * 5), g)
    return vehicle_check(read_track(srv.data / "nav" / f"{name}_track.csv"), surface, world.body)


@long_test  # 2.5 m among marsyard's rocks, every section chosen with the chance check: about a minute of CPU
def test_the_see_loop_gets_out_where_the_gated_planner_stopped_at_its_start(server_factory) -> None:
    """Marsyard mission 0 of the benchmark (tools.bench.navigate): the gated see loop made a safe
    stop 0.1 m from its start there ("no way on ... enclosed": its circle planner on the window
    step and the refusals kept as hazard points closed every way). The chooser drives the first
    2.5 m of that mission to its goal, without one unsafe pose on the true surface."""
    srv = server_factory(["server.scene=marsyard"])
    world = srv.app.world
    world.set_target_visible(False)
    start, heading = (11.68, 6.88), -128.96  # toward the mission's goal (1.12, -6.18)
    goal = (start[0] + 2.5 * math.cos(math.radians(heading)), start[1] + 2.5 * math.sin(math.radians(heading)))
    c = srv.client()
    job = c.start_job(f"navigate -start {start[0]},{start[1]},{heading} -goal {goal[0]:.2f},{goal[1]:.2f} -auto "
                      "-loop see -name out")
    final = c.until_final(job=job, timeout=1800)[-1]
    assert final.status == "OK" and final.fields["reached"] == "true", final.fields
    assert int(final.fields["scans"]) == 0  # the chooser needs no 360-degree scan
    truth = world.truth()
    assert math.hypot(truth["x"] - goal[0], truth["y"] - goal[1]) <= 0.3
    events, checked = _events(srv, world, "out", (8.5, 3.5, 12.5, 7.5))
    assert checked > 100
    assert events == [], [e.describe() for e in events]


@long_test  # a whole blocked mission, 10-16 s: CI's long suite runs it; the chooser's sections are driven by default
def test_a_blocked_mission_is_a_safe_stop_with_its_reason(server_factory) -> None:
    """A ring of 20 cm rocks round the rover, no gap the body fits through: after a look round
    the chooser finds every candidate failing on the body's limits and the job ends E_DATA with
    that reason and the failures by limit, having driven nowhere near a rock."""
    srv = server_factory(["server.scene=quarry"])
    world = srv.app.world
    world.set_target_visible(False)
    c = srv.client()
    for k in range(12):
        a = 2 * math.pi * k / 12
        r = c.request(f"sim add-rock -x {0.62 * math.cos(a):.3f} -y {0.62 * math.sin(a):.3f} -radius 0.16 "
                      "-height 0.2")
        assert r.status == "OK", r.fields
    job = c.start_job("navigate -start 0,0,0 -goal 3,0 -auto -loop see -name ring")
    lines = c.until_final(job=job, timeout=900)
    final = lines[-1]
    assert final.status == "ERROR" and final.fields["code"] == "E_DATA", final.fields
    message = final.fields["message"]
    assert message.startswith("no way on within the body's limits"), message
    assert any(limit in message for limit in ("belly", "step", "stability", "grade")), message
    assert not any("360" in r.fields.get("message", "") for r in lines if r.status == "PROGRESS")
    truth = world.truth()
    assert math.hypot(truth["x"], truth["y"]) < 0.2  # it stood
    track = srv.data / "nav" / "ring_track.csv"
    if track.exists():
        events, _ = _events(srv, world, "ring", (-1.5, -1.5, 1.5, 1.5))
        assert events == [], [e.describe() for e in events]


def _flat(x0: float, x1: float, rock: float = 0.0) -> np.ndarray:
    """Returns every centimetre of level ground at z 0 over x0..x1, y -1..1 m, with a ``rock``
    high block at x 1.2..1.5 m, |y| < 0.15 m."""
    x, y = (a.ravel() for a in np.meshgrid(np.arange(x0, x1, 0.01) + 0.005, np.arange(-1.0, 1.0, 0.01) + 0.005))
    z = np.where((x > 1.2) & (x < 1.5) & (np.abs(y) < 0.15), rock, 0.0)
    return np.column_stack([x, y, z])


def test_a_refusal_does_not_outlive_the_frames_of_its_ground() -> None:
    """The way straight ahead to the goal crosses a strip no frame has shown (1.0-1.7 m ahead):
    the chooser does not drive it (it asks to look there first, or drives round). A frame that
    then shows level ground there makes the straight section pass at once: nothing of the first
    verdict is kept. A frame that shows a rock there refuses the straight way again."""
    from drivers.sim.rover import RoverBody
    from rvs_server.navigation.sections import choose_from

    params, chance = CandidateParams(), ChanceParams()
    for rock, straight_after in ((0.0, True), (0.2, False)):
        bounds = BoundsMap.covering([[-1.0, -1.0], [4.0, 1.0]], 0.0)
        origin = np.array([0.0, 0.0, 0.8])
        for x0, x1 in ((-0.6, 1.0), (1.7, 3.2)):
            bounds.fuse(_flat(x0, x1), 0.002, origin)
        before, _ = choose_from(bounds, (0.0, 0.0, 0.0), (3.0, 0.0), RoverBody(), "chance", params, chance)
        assert not (before.status == "drive" and before.turn == 0.0 and before.curvature == 0.0), before.reason
        if before.status == "look":
            assert 0.9 < before.look_at[0] < 1.8, before.look_at
        bounds.fuse(_flat(1.0, 1.7, rock), 0.002, origin)  # a later frame shows that ground
        after, _ = choose_from(bounds, (0.0, 0.0, 0.0), (3.0, 0.0), RoverBody(), "chance", params, chance)
        assert after.status == "drive", after.reason
        straight = after.turn == 0.0 and abs(after.curvature) < 1e-9
        assert straight == straight_after, (after.turn, after.curvature, after.reason)
        if straight_after:
            assert after.poses[-1][0] > 0.95  # the whole metre of the section, toward the goal


@long_test  # 15-21 s of a GNC driving sections: CI's long suite runs it; the chooser's own sections run by default
def test_the_gnc_drives_each_chosen_section_as_waypoints(server_factory) -> None:
    """Without -auto the GNC drives: the start's turn for the hazard cameras, then each section the
    chooser picks (at most its configured length, a turn on the spot first where there is one), is
    sent as a waiting EVENT's waypoints,
    every pose the GNC reports while driving is a cycle, and the goal is reached without a
    360-degree scan."""
    srv = server_factory(["server.scene=quarry", "navigate.pose_settle=0.5", "navigate.see.chooser.section=0.7"])
    world = srv.app.world
    world.set_target_visible(False)
    c, gnc = srv.client(), srv.client()
    job = c.start_job("navigate -start 0,0,0 -goal 2.0,0 -loop see -name gnc")
    sections = []
    while True:
        r = c.reply(timeout=300)
        if r.status == "EVENT" and r.fields.get("kind") == "waiting":
            wps = np.array([float(v) for v in r.fields["waypoints"].split(",")]).reshape(-1, 3)
            sections.append(wps)
            for x, y, h in wps:
                world.set_rover_pose(x, y, h)
                assert gnc.request(f"pose -x {x:.3f} -y {y:.3f} -heading {h:.2f}").status == "OK"
            assert gnc.request(f"pose -x {x:.3f} -y {y:.3f} -heading {h:.2f} -stopped true").status == "OK"
        elif r.status in ("OK", "ERROR") and r.fields.get("job") == job:
            final = r
            break
    assert final.status == "OK" and final.fields["reached"] == "true", final.fields
    assert int(final.fields["scans"]) == 0 and len(sections) == int(final.fields["legs"]) >= 4
    # first the start's turn on the spot, which shows the hazard camera pairs the ground round the
    # body: each step one waypoint where the rover stands, with the heading it turns to
    assert [w.shape for w in sections[:2]] == [(1, 3), (1, 3)], sections[:2]
    assert [w[0, 2] for w in sections[:2]] == pytest.approx([60.0, 120.0]), sections[:2]
    assert np.abs(np.vstack(sections[:2])[:, :2]).max() < 1e-3
    for wps in sections:  # a section: at most 0.7 m of arc from where the rover stands
        assert float(np.hypot(*(wps[-1, :2] - wps[0, :2]))) <= 0.7 + 1e-6, wps


def test_a_motion_s_end_by_the_rover_s_own_kinematics() -> None:
    # where the see loop aims the next frame's look, sent with the cycle's motion
    from drivers.rover.backend import Motion
    from rvs_server.navigation.sections import motion_end

    x, y, h = motion_end((1.0, 2.0, 90.0), Motion.arc(0.1, 0.0, 1.0))
    assert (x, y, h) == pytest.approx((1.0, 2.1, 90.0), abs=1e-9)
    # a quarter circle of 1 m radius to the left, heading east from the origin
    x, y, h = motion_end((0.0, 0.0, 0.0), Motion.arc(math.pi / 2, 90.0, 1.0))
    assert (x, y, h) == pytest.approx((1.0, 1.0, 90.0), abs=1e-9)
    x, y, h = motion_end((0.0, 0.0, 0.0), Motion.arc(-math.pi / 2, 90.0, 1.0))  # backing: -1 m of arc
    assert (x, y, h) == pytest.approx((-1.0, -1.0, 90.0), abs=1e-9)
    assert motion_end((1.0, 1.0, 0.0), Motion.face(1.0, 0.0)) == pytest.approx((1.0, 1.0, -90.0))


@long_test  # 2 m on quarry with every section chosen with the chance check: about 6 s of CPU
@pytest.mark.parametrize("start_look", [True, False])
def test_the_gaze_alternates_near_and_far_and_slews_while_driving(server_factory, monkeypatch,
                                                                   start_look: bool) -> None:
    """The gaze alternates its near and its far look frame by frame, so between two frames taken
    while driving the mast's tilt changes on most cycles, and the goal is reached. The look for the
    next frame is sent with the cycle's motion, without waiting (the mast slews while the wheels
    turn), and every frame finds the mast standing where it was sent. A section's first frame is a
    look along it, the mast's one standing slew there (``navigate.see_start_look``, the default);
    without it a section waits for no slew at all: the mast waits standing only to look round."""
    srv = server_factory(["server.scene=quarry", f"navigate.see_start_look={str(start_look).lower()}"])
    world = srv.app.world
    world.set_target_visible(False)
    ptu, tof = srv.app.devices.get("ptu"), srv.app.devices.get("tof")
    log: list[tuple[str, float]] = []
    move, grab = ptu.move, tof.grab_xyz
    sent: list[tuple[float, float, bool]] = []  # every move: pan, tilt, waited
    off_aim: list[tuple[tuple[float, float], tuple[float, float]]] = []

    def logged_move(pan, tilt, wait=True, *a, **k):  # noqa: ANN001, ANN002, ANN003, ANN202
        log.append(("move", float(tilt)))
        sent.append((float(pan), float(tilt), bool(wait)))
        return move(pan, tilt, wait, *a, **k)

    def logged_grab(integrate: int = 1, *a, **k):  # noqa: ANN002, ANN003, ANN202
        log.append(("drive" if integrate == 1 else "look", 0.0))
        at = ptu.position()
        if sent and max(abs(at[0] - sent[-1][0]), abs(at[1] - sent[-1][1])) > 0.05:
            off_aim.append((at, sent[-1][:2]))
        return grab(integrate, *a, **k)

    monkeypatch.setattr(ptu, "move", logged_move)
    monkeypatch.setattr(tof, "grab_xyz", logged_grab)
    final = srv.client().request("navigate -start 0,0,0 -goal 2.0,0 -auto -loop see -name hold", timeout=600)
    assert final.status == "OK" and final.fields["reached"] == "true", final.fields
    tilt, tilts = None, []  # the tilt each frame was taken at
    for kind, t in log:
        if kind == "move":
            tilt = round(t, 3)
        else:
            tilts.append((kind, tilt))
    pairs = [(a, b) for a, b in zip(tilts, tilts[1:], strict=False) if a[0] == b[0] == "drive"]
    changed = sum(a[1] != b[1] for a, b in pairs)
    assert len(pairs) >= 15
    assert changed >= 0.7 * len(pairs), (changed, len(pairs))
    assert len({t for kind, t in tilts if kind == "drive"}) >= 2  # near and far
    assert sum(not waited for *_, waited in sent) >= 3  # looks sent with the motion
    assert not off_aim, off_aim[:5]
    # a waited move, then a frame taken driving: the rover stood for the slew at a section's start
    moves = [i for i, (kind, _) in enumerate(log) if kind == "move"]
    waited_then_drive = [i for n, i in enumerate(moves) if sent[n][2] and i + 1 < len(log) and log[i + 1][0] == "drive"]
    assert len(moves) == len(sent)
    if start_look:  # one standing slew at a section's start, after the frames the section was chosen on
        assert waited_then_drive and all(log[i - 1][0] in ("drive", "look") for i in waited_then_drive), \
            [log[i - 2:i + 2] for i in waited_then_drive][:5]
    else:
        assert waited_then_drive == [], [log[i - 1:i + 2] for i in waited_then_drive][:5]


@long_test  # a 3.5 m mission round the rock on rendered frames: 20-25 s of CPU
def test_a_rock_dropped_ahead_of_the_driving_chooser_is_not_driven_into(server_factory) -> None:
    """A rock the body can neither climb nor clear (20 cm radius, 25 cm high) is added 1 m ahead
    of the rover while it drives a section on the quarry's floor: the section's recheck on the
    new frames stops it, or the next choice steers round, before the body touches it. The true
    track keeps the body's outline off the rock's base and the vehicle check on the true surface
    (the rock included) finds no event. A loop that drove its section on regardless of the new
    ground puts the body on the rock."""
    from tools.bench.rock_drop import clearance, clock_held

    # the simulated PTU answers over a pseudo-terminal: on a loaded machine its 2 s reply wait can
    # run out, which is the machine's, not the loop's
    srv = server_factory(["server.scene=quarry", "drivers.ptu.timeout=30"])
    world = srv.app.world
    world.set_target_visible(False)
    c, op = srv.client(), srv.client()
    job = c.start_job("navigate -start 0,0,0 -goal 3.5,0 -auto -loop see -name drop")
    radius = 0.2
    # once it has driven 0.5 m: a rock 1 m ahead along its heading
    assert wait_for(lambda: world.truth()["x"] >= 0.5, timeout=600, interval=0.01), "the rover never drove 0.5 m"
    with clock_held(op.request, world):
        t = world.truth()
        h = math.radians(t["heading"])
        rock = (t["x"] + math.cos(h), t["y"] + math.sin(h), radius)
        r = op.request(f"sim add-rock -x {rock[0]:.3f} -y {rock[1]:.3f} -radius {radius} -height 0.25")
        landed = world.truth()
    assert r.status == "OK", r.fields
    assert math.hypot(rock[0] - landed["x"], rock[1] - landed["y"]) > 0.98, (rock, landed)
    lines = c.until_final(job=job, timeout=900)
    final = lines[-1]
    track = read_track(srv.data / "nav" / "drop_track.csv")
    assert clearance(track, rock, world.body) > 0.0, (final.fields, rock)
    events, checked = _events(srv, world, "drop", (-1.0, -1.5, 4.5, 1.5))
    assert checked >= 25, final.fields  # the 0.5 m it drove, every 2 cm
    assert events == [], [e.describe() for e in events]
    # it went on afterwards: round the rock to the goal, or a safe stop with its reason
    assert final.status == "OK" or final.fields["code"] == "E_DATA", final.fields


@pytest.mark.parametrize("heading,turn", [(-105.0, -180.0), (75.0, 180.0), (0.0, 157.5), (30.0, -112.5), (10.0, 45.0)])
def test_a_turn_on_the_spot_is_faced_the_way_round_it_was_judged(heading: float, turn: float) -> None:
    """The simulated rover turns to face each heading the shortest way; the faces of a section's
    turn (``sections.turn_faces``) bring it round the way the check judged, all the way: a half
    turn faced at once goes either way (hirise mission 0: planned clockwise from -105 deg, driven
    counter-clockwise over a step the check never saw)."""
    from rvs_server.navigation.sections import turn_faces

    at, swept = heading, 0.0
    for face in turn_faces(heading, turn):
        step = (face - at + 180.0) % 360.0 - 180.0  # the shortest way round, as World.turn_toward turns
        assert step * turn > 0 and abs(step) < 179.0, (face, at, step)
        swept += step
        at = face
    assert swept == pytest.approx(turn)


def test_the_bounds_maps_params_are_set_like_any_other(server_factory) -> None:
    """``navigate.see.bounds.*`` reaches the bounds map the see loop builds: the map the loop
    publishes has the cell and k set on the command line, and ``config`` shows them."""
    srv = server_factory(["server.scene=quarry", "navigate.see.bounds.cell=0.05", "navigate.see.bounds.k=3"])
    srv.app.world.set_target_visible(False)
    seen: list = []
    srv.app.bus.subscribe(lambda item: seen.append(item.data["bounds"]) if item.kind == "bounds" else None)
    c = srv.client()
    shown = c.request("config -module navigate")
    assert shown.status == "OK", shown.fields
    text = " ".join(f"{k}={v}" for k, v in shown.fields.items())
    assert "cell=0.05" in text and "bounds" in text, text
    job = c.start_job("navigate -start 0,0,0 -goal 2,0 -auto -name params")
    wait_for(lambda: seen, timeout=300)
    c.request("break")
    c.until_final(job=job, timeout=300)
    assert seen[0].geometry.cell == 0.05 and seen[0].params.k == 3.0


def test_the_section_pilot_judges_the_poses_past_the_one_the_rover_stands_on() -> None:
    """The pilot's recheck judges what is still to drive as the choice judged it: from the pose
    past the rover's. The pose it stands on (a section's first, or the arc's pose at the metres
    driven) is left out: judged, a spread the frames taken standing there give it would stop every
    section set off from it, over and over."""
    from types import SimpleNamespace

    from prox_workflows.algorithms.candidates import Choice
    from rvs_server.navigation.sections import SectionPilot

    xs = np.round(np.arange(0.0, 1.0 + 1e-9, 0.1), 3)
    straight = np.column_stack([xs, np.zeros_like(xs), np.zeros_like(xs)])
    chooser = SimpleNamespace(d=SimpleNamespace(bounds=SimpleNamespace(frames=0), rover=SimpleNamespace(steers=True),
                                                gazes=True))
    pilot = SectionPilot(chooser, Choice("drive", "test", straight, straight, length=1.0), None)
    assert np.array_equal(pilot._ahead(), straight[1:])
    pilot.driven = 0.3  # the rover stands on the arc's pose at 0.3 m
    assert np.allclose(pilot._ahead()[:, 0], xs[4:])
    pilot.driven = 1.0
    assert len(pilot._ahead()) == 0
    # a turn on the spot of 30 deg first, then the arc: before the turn, all but the pose it stands on
    turn = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 15.0], [0.0, 0.0, 30.0]])
    arc = np.column_stack([xs[1:] * math.cos(math.radians(30)), xs[1:] * math.sin(math.radians(30)),
                           np.full(10, 30.0)])
    poses = np.vstack([turn, arc])
    pilot = SectionPilot(chooser, Choice("drive", "test", poses, poses, turn=30.0, length=1.0), None)
    assert not pilot.turned and np.array_equal(pilot._ahead(), poses[1:])


# both in the long suite (the default run's 6 minutes: 40-60 s of it); the see loop's chooser runs by default
@pytest.mark.parametrize("goal, stretch", [pytest.param(1.5, 0.6, marks=long_only()),
                                           pytest.param(2.4, 1.0, marks=long_only())])
def test_the_scan_loop_on_the_chooser_scans_every_stretch_and_drives_by_the_vehicle_check(
        server_factory, goal: float, stretch: float) -> None:
    """``-loop scan -scan-plan chooser``: every stretch starts with a 360-degree scan (and the look
    round standing that feeds the bounds map), then the chooser's sections are driven, seeing as
    the see loop does, until ``scan_stretch`` metres are behind, and the next scan follows.
    Judged by the vehicle on the true surface, as the see loop is."""
    srv = server_factory(["server.scene=quarry", f"navigate.scan_stretch={stretch}",
                          "navigate.range=-60,60,-50,-10"])
    world = srv.app.world
    world.set_target_visible(False)
    c = srv.client()
    job = c.start_job(f"navigate -start 0,0,0 -goal {goal},0 -auto -loop scan -scan-plan chooser -name stop")
    lines = c.until_final(job=job, timeout=1800)
    final = lines[-1]
    assert final.status == "OK" and final.fields["reached"] == "true", final.fields
    assert final.fields["loop"] == "scan"
    # stretches of at least ``stretch``, over 2.5 of them: a scan at the start and one or two on the way
    assert 2 <= int(final.fields["scans"]) <= 3, final.fields
    assert int(final.fields["cycles"]) > 0  # frames while driving, each a check of the section's rest
    assert int(final.fields["legs"]) >= 3  # sections of at most the chooser's length, not one leg a scan
    truth = world.truth()
    assert math.hypot(truth["x"] - goal, truth["y"]) <= 0.3
    events, checked = _events(srv, world, "stop", (-1.0, -1.5, 3.5, 1.5))
    assert checked > 50
    assert events == [], [e.describe() for e in events]


@long_test  # three short navigates on the quarry: CI's long suite; the keeping rules run by default (tests/server/test_kept_ground.py)
def test_a_navigate_from_where_the_last_one_left_the_rover_starts_on_its_map(server_factory) -> None:
    """A GNC sends goal after goal. The second navigate starts where the first ended and takes its
    bounds map (no set-down: the ground round the rover is what the first one's frames saw and its
    wheels felt). Backed 0.3 m by the GNC's own drive, the third takes that map too and is set down
    again on it; the rover carried off (sim move-rover), the fourth is set down on a fresh map."""
    srv = server_factory(["server.scene=quarry"])
    srv.app.world.set_target_visible(False)
    c = srv.client()

    def navigate(line: str) -> list:
        lines = c.until_final(job=c.start_job(line), timeout=900)
        assert lines[-1].status == "OK" and lines[-1].fields["reached"] == "true", lines[-1].fields
        return [r.fields.get("message", "") for r in lines if r.status == "PROGRESS"]

    first = navigate("navigate -start 0,0,0 -goal 1.0,0 -auto -loop see -name a")
    assert any(m.startswith("set down on") for m in first)
    second = navigate("navigate -goal 2.0,0 -auto -loop see -name b")
    assert not any(m.startswith("set down on") for m in second)
    kept = [m for m in second if m.startswith("the ground round the rover as the last navigate left it")]
    assert len(kept) == 1 and int(kept[0].split("(")[1].split()[0]) > 0, second
    drove = c.request("sim drive -v -0.1 -seconds 3")  # the GNC backs the rover 0.3 m, and says so
    assert drove.status == "OK"
    assert c.request(f"pose -x {drove.fields['odom_x']} -y {drove.fields['odom_y']} "
                     f"-heading {drove.fields['odom_heading']} -stopped true").status == "OK"
    third = navigate("navigate -goal 2.6,0 -auto -loop see -name c")
    again = [m for m in third if m.startswith("set down on") and "on the map the last navigate left" in m]
    assert len(again) == 1 and " 0.30 m from where it left the rover" in again[0], third
    assert c.request("sim move-rover -dx 0.3").status == "OK"
    fourth = navigate("navigate -goal 3.9,0 -auto -loop see -name d")
    assert any(m.startswith("set down on") and "the last navigate left" not in m for m in fourth)
