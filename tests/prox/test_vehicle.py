"""The vehicle check (prox_workflows.algorithms.vehicle) on synthetic 1 cm surfaces with the declared
Pioneer 3-AT-like body (drivers.sim.rover.RoverBody): its four physical limits, each on a surface
whose answer is known by hand: a wheel's step edge against the 10 cm climb, the belly against the
8 cm clearance, the resting plane's tilt against the static tip-over angle over the 1.5 safety
factor, the plane under the whole body against the 35 % grade; and events along a track."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.sim.head import HeadGeometry
from drivers.sim.rover import RoverBody
from drivers.sim.scene import build_rover
from prox_workflows.algorithms.vehicle import (
    check_poses,
    densify,
    severity,
    tip_angle,
    track_poses,
    unsafe_events,
)
from prox_workflows.grid import GridGeometry

BODY = RoverBody()
CELL = 0.01
FRONT_RIGHT = (0.145, -0.245)
# the hand calculation of the tip-over angles: the centre of gravity 0.163 m over the contacts,
# the hubs +-0.145 m fore and aft, +-0.245 m to the sides
PITCH_TIP = math.degrees(math.atan(0.145 / 0.163))  # 41.7 deg
ROLL_TIP = math.degrees(math.atan(0.245 / 0.163))  # 56.4 deg


def surface(half: float = 1.5) -> tuple[np.ndarray, GridGeometry, np.ndarray, np.ndarray]:
    """A flat 1 cm grid +-``half`` m around the origin, and the x, y of its cell centres."""
    g = GridGeometry.covering(-half, -half, half, half, CELL)
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    return np.zeros(g.shape, np.float32), g, X, Y


def rock(h: np.ndarray, X: np.ndarray, Y: np.ndarray, x: float, y: float, radius: float, height: float) -> None:
    h[np.hypot(X - x, Y - y) <= radius] = height


def dome(h: np.ndarray, X: np.ndarray, Y: np.ndarray, x: float, y: float, radius: float, height: float) -> None:
    """A smooth cosine dome: ``height`` at its middle, 0 at ``radius`` with no edge anywhere."""
    d = np.hypot(X - x, Y - y)
    h += np.where(d < radius, height / 2 * (1 + np.cos(np.pi * d / radius)), 0.0).astype(np.float32)


def ledge(h: np.ndarray, X: np.ndarray, Y: np.ndarray, height: float) -> None:
    """A vertical edge 3 cm ahead of the front-right hub, raised ground beyond it under that
    wheel's track only (outside the box, which ends at y = -0.20)."""
    h[(X >= FRONT_RIGHT[0] + 0.03) & (Y <= -0.205) & (Y >= -0.35)] = height


def test_the_body_is_declared_once_and_the_simulator_builds_it() -> None:
    assert np.allclose(BODY.wheels, [[0.145, 0.245], [0.145, -0.245], [-0.145, 0.245], [-0.145, -0.245]])
    assert (BODY.wheel_radius, BODY.clearance, BODY.climb, BODY.grade) == (0.1075, 0.08, 0.10, 19.3)
    assert math.tan(math.radians(BODY.grade)) == pytest.approx(0.35, abs=0.001)  # the P3-AT's 35 % grade
    # the P3-AT's ROS model: chassis 21.5 kg at 0.177 m, four wheels 1.4 kg at their 0.111 m axles
    assert BODY.cog_height == pytest.approx((21.5 * 0.177 + 4 * 1.4 * 0.111) / (21.5 + 4 * 1.4), abs=0.0005)
    assert BODY.safety == 1.5
    rover = build_rover({}, HeadGeometry.from_spec(None))
    corners = rover.world_corners()
    assert corners[:, 1].max() == pytest.approx(0.29)  # the wheels' outer faces
    assert corners[:, 2].min() == pytest.approx(0.0)  # the wheels stand on the ground
    assert RoverBody.from_spec({"climb": 0.12}).climb == 0.12
    with pytest.raises(ValueError, match="unknown rover body key"):
        RoverBody.from_spec({"wheel_diameter": 0.2})
    with pytest.raises(ValueError, match="safety 0.8 must be >= 1"):
        RoverBody.from_spec({"safety": 0.8})


def test_flat_ground_is_safe() -> None:
    h, g, _, _ = surface()
    checks = check_poses(h, g, [(0.0, 0.0, 0.0), (0.1, 0.2, 37.0)], BODY)
    assert not checks.unsafe.any()
    assert np.abs(checks.step).max() < 1e-6 and np.abs(checks.tilt).max() < 1e-6 and np.abs(checks.grade).max() < 1e-6
    assert checks.intrusion == pytest.approx([-0.08, -0.08], abs=1e-6)
    assert checks.excess.shape == (2, 4)


def test_the_tip_over_angle_is_the_hand_calculation_per_direction() -> None:
    """atan(half-wheelbase / h) nose or tail down, atan(half-track / h) to a side, and between
    them the support polygon's nearer edge along the lean."""
    assert tip_angle(BODY, [0.0, 180.0, 90.0, -90.0]) == pytest.approx([PITCH_TIP, PITCH_TIP, ROLL_TIP, ROLL_TIP],
                                                                       abs=1e-9)
    diagonal = min(0.145 / math.cos(math.radians(45)), 0.245 / math.sin(math.radians(45)))  # the front edge
    assert tip_angle(BODY, 45.0) == pytest.approx(math.degrees(math.atan(diagonal / 0.163)), abs=1e-9)
    corner = math.degrees(math.atan2(0.245, 0.145))  # toward the front-left hub: the polygon's corner
    assert tip_angle(BODY, corner) == pytest.approx(math.degrees(math.atan(math.hypot(0.145, 0.245) / 0.163)))
    assert 35.0 < PITCH_TIP < ROLL_TIP < 60.0
    # a body with its centre of gravity 0.5 m up: a 15 deg pitch tips it past 1.5x margin, the
    # same 15 deg to the side does not (atan(0.145 / 0.5) / 1.5 = 10.8, atan(0.245 / 0.5) / 1.5 = 17.4)
    tall = RoverBody(cog_height=0.5)
    _, g, X, Y = surface()
    tan15 = math.tan(math.radians(15.0))
    pitch = check_poses((tan15 * X).astype(np.float32), g, [(0.0, 0.0, 0.0)], tall)
    roll = check_poses((tan15 * X).astype(np.float32), g, [(0.0, 0.0, 90.0)], tall)
    assert pitch.tilt[0] == pytest.approx(15.0, abs=0.05) and roll.tilt[0] == pytest.approx(15.0, abs=0.05)
    assert pitch.tip[0] == pytest.approx(math.degrees(math.atan(0.145 / 0.5)), abs=0.05)
    assert roll.tip[0] == pytest.approx(math.degrees(math.atan(0.245 / 0.5)), abs=0.05)
    assert pitch.excess[0, 2] == pytest.approx(15.0 - math.degrees(math.atan(0.145 / 0.5)) / 1.5, abs=0.05)
    (event,) = unsafe_events(pitch, np.array([(0.0, 0.0, 0.0)]), tall)
    assert (event.kind, event.band) == ("stability", "severe")
    assert not roll.unsafe[0] and pitch.grade[0] < tall.grade  # 15 deg is within the grade either way
    # the declared body stands the same slope either way
    assert not check_poses((tan15 * X).astype(np.float32), g, [(0.0, 0.0, 0.0)], BODY).unsafe[0]


def test_a_9cm_step_edge_is_climbed_and_an_11cm_one_fails_that_wheel() -> None:
    for height, bad in ((0.09, False), (0.11, True)):
        h, g, X, Y = surface()
        ledge(h, X, Y, height)
        checks = check_poses(h, g, [(0.0, 0.0, 0.0)], BODY)
        assert checks.step[0, 1] == pytest.approx(height, abs=0.002), height  # the whole edge, one wheel
        assert max(checks.step[0, [0, 2, 3]]) < 0.005
        assert checks.intrusion[0] < 0 and checks.excess[0, 2:].max() < 0  # the belly, stability, grade hold
        assert bool(checks.unsafe[0]) is bad
    (event,) = unsafe_events(checks, np.array([(0.0, 0.0, 0.0)]), BODY)
    assert (event.kind, event.excess, event.band) == ("step front-right", pytest.approx(0.01, abs=0.002), "moderate")
    assert event.describe() == "step front-right +1.0 cm (moderate) at (0.00, 0.00, 0 deg)"
    # driven over, the edge shows at every pose whose footprint holds it, from the front wheel's
    # reach to the rear wheel's
    poses = densify(np.array([(-0.6, 0.0, 0.0), (0.6, 0.0, 0.0)]), 0.02, BODY)
    events = unsafe_events(check_poses(h, g, poses, BODY), poses, BODY)
    assert [e.kind for e in events] == ["step front-right", "step rear-right"]
    assert [e.x for e in events] == pytest.approx([-0.06, 0.24], abs=0.04)  # where each wheel meets it


def test_a_smooth_dome_the_wheel_follows_is_no_step() -> None:
    """A 9 cm dome 30 cm wide under the front-right wheel rises at most 1.9 cm over any 2 cm; so
    does a 12 cm one 40 cm wide, taller than the climb yet rolled over: neither is a step."""
    for height, radius in ((0.09, 0.15), (0.12, 0.20)):
        h, g, X, Y = surface()
        dome(h, X, Y, *FRONT_RIGHT, radius, height)
        poses = densify(np.array([(-0.6, 0.0, 0.0), (0.6, 0.0, 0.0)]), 0.02, BODY)
        checks = check_poses(h, g, poses, BODY)
        slope = height * np.pi / (2 * radius)  # the dome's steepest
        assert checks.step.max() == pytest.approx(2 * CELL * slope, abs=0.003), height
        assert checks.step.max() < 0.02
        assert not checks.unsafe.any(), height
        # the wheel rode up it: the body leaned by the dome's height over the wheelbase
        assert checks.tilt.max() == pytest.approx(math.degrees(math.atan(height / 0.29)), abs=0.5)


def test_a_momentary_23_deg_pitch_over_climbable_rocks_is_not_unsafe() -> None:
    """Both front wheels on smooth 12.3 cm mounds: the body pitches 23 deg, beyond the 19.3 deg
    grade, but it is a momentary tilt, far from tipping over (41.7 deg / 1.5 = 27.8), and the
    ground under the whole body is no 35 % slope."""
    h, g, X, Y = surface()
    for side in (1, -1):
        dome(h, X, Y, 0.145, side * 0.245, 0.25, 0.123)
    checks = check_poses(h, g, [(0.0, 0.0, 0.0)], BODY)
    assert checks.tilt[0] == pytest.approx(23.0, abs=0.2)
    assert checks.tip[0] == pytest.approx(PITCH_TIP, abs=0.1)  # it leans tail down
    assert checks.excess[0, 2] == pytest.approx(23.0 - PITCH_TIP / 1.5, abs=0.2)
    assert checks.grade[0] < 12.0
    assert checks.step.max() < 0.02 and checks.intrusion[0] < 0
    assert not checks.unsafe[0]


def test_a_20_deg_plane_fails_grade_and_a_17_deg_one_passes() -> None:
    _, g, X, Y = surface()
    for deg, bad in ((20.0, True), (17.0, False)):
        h = (np.tan(np.radians(deg)) * (X * 0.6 + Y * 0.8)).astype(np.float32)
        checks = check_poses(h, g, [(0.0, 0.0, 30.0)], BODY)
        assert checks.grade[0] == pytest.approx(deg, abs=0.05)
        assert checks.tilt[0] == pytest.approx(deg, abs=0.05)  # resting on it, the body leans as much
        assert checks.step.max() < 0.008  # a steady slope is no step for a wheel: 0.7 cm over 2 cm
        assert checks.excess[0, 2] < 0  # nor near tipping over
        assert bool(checks.unsafe[0]) is bad
    events = unsafe_events(check_poses((np.tan(np.radians(20.0)) * X).astype(np.float32), g,
                                       [(0.0, 0.0, 0.0)], BODY), np.array([(0.0, 0.0, 0.0)]), BODY)
    assert [(e.kind, round(e.excess, 1), e.band) for e in events] == [("grade", 0.7, "moderate")]


def test_severity_bands() -> None:
    assert [severity("belly", x) for x in (0.004, 0.005, 0.006, 0.02, 0.021)] == [
        "slight", "slight", "moderate", "moderate", "severe"]
    assert [severity(k, x) for k, x in (("grade", 0.5), ("stability", 1.9), ("grade", 2.5))] == [
        "slight", "moderate", "severe"]
    assert severity("step rear-left", 0.03) == "severe"


def test_a_rock_under_a_wheel_above_the_climb_fails_that_wheel_by_its_excess() -> None:
    h, g, X, Y = surface()
    rock(h, X, Y, *FRONT_RIGHT, 0.03, 0.13)  # under the front-right hub
    checks = check_poses(h, g, [(0.0, 0.0, 0.0)], BODY)
    assert checks.step[0, 1] == pytest.approx(0.13, abs=0.005)
    assert max(checks.step[0, [0, 2, 3]]) < 0.01
    assert checks.wheel[0] == 1
    events = unsafe_events(checks, np.array([(0.0, 0.0, 0.0)]), BODY)
    assert len(events) == 1
    assert events[0].kind == "step front-right"
    assert events[0].excess == pytest.approx(0.03, abs=0.005)
    # the same rock at the climb limit's side: 9 cm is climbed
    h2, _, _, _ = surface()
    rock(h2, X, Y, *FRONT_RIGHT, 0.03, 0.09)
    assert not check_poses(h2, g, [(0.0, 0.0, 0.0)], BODY).unsafe.any()


def test_a_rock_between_the_wheels_taller_than_the_clearance_fails_as_belly() -> None:
    h, g, X, Y = surface()
    rock(h, X, Y, 0.0, 0.0, 0.05, 0.10)
    checks = check_poses(h, g, [(0.0, 0.0, 0.0)], BODY)
    assert checks.intrusion[0] == pytest.approx(0.02, abs=1e-3)
    assert checks.step.max() < 0.005 and checks.tilt[0] < 0.5
    (event,) = unsafe_events(checks, np.array([(0.0, 0.0, 0.0)]), BODY)
    assert (event.kind, event.excess) == ("belly", pytest.approx(0.02, abs=1e-3))
    # 7 cm passes under the 8 cm belly
    h2, _, _, _ = surface()
    rock(h2, X, Y, 0.0, 0.0, 0.05, 0.07)
    assert not check_poses(h2, g, [(0.0, 0.0, 0.0)], BODY).unsafe.any()


def test_consecutive_unsafe_poses_are_one_event_and_separate_rocks_two() -> None:
    h, g, X, Y = surface()
    rock(h, X, Y, -0.5, 0.0, 0.05, 0.11)
    rock(h, X, Y, 0.6, 0.0, 0.05, 0.12)
    poses = densify(np.array([(-1.0, 0.0, 0.0), (1.0, 0.0, 0.0)]), 0.02, BODY)
    assert len(poses) == 101
    checks = check_poses(h, g, poses, BODY)
    assert checks.unsafe.sum() > 10  # each rock is under the belly over many poses
    events = unsafe_events(checks, poses, BODY)
    assert [e.kind for e in events] == ["belly", "belly"]
    assert [round(e.excess, 3) for e in events] == pytest.approx([0.03, 0.04], abs=0.002)
    assert [e.band for e in events] == ["severe", "severe"]
    assert abs(events[0].x + 0.5) <= 0.31 and abs(events[1].x - 0.6) <= 0.31  # the rock under the body


def test_a_turn_on_the_spot_over_a_rock_is_caught() -> None:
    """A rock in the gap between the left wheels is safe at heading 0 and at 180 deg, but a rear
    wheel and the belly's corner sweep over it in between (the short way round is to the right)."""
    h, g, X, Y = surface()
    rock(h, X, Y, 0.0, 0.26, 0.02, 0.13)
    ends = np.array([(0.0, 0.0, 0.0), (0.0, 0.0, 180.0)])
    assert not check_poses(h, g, ends, BODY).unsafe.any()
    poses = densify(ends, 0.02, BODY)
    assert len(poses) > 40 and np.allclose(poses[:, :2], 0.0)
    checks = check_poses(h, g, poses, BODY)
    assert checks.excess[:, 0].max() == pytest.approx(0.03, abs=0.005)  # the 13 cm rock's edge under a wheel
    assert checks.step[:, 2:].max(axis=0) == pytest.approx([0.13, 0.13], abs=0.005)  # both rear wheels pass it
    assert checks.step[:, :2].max() < 0.01  # the front wheels never turn over it
    events = unsafe_events(checks, poses, BODY)
    assert len(events) == 1  # one sweep over it
    assert (events[0].kind, events[0].excess) == ("belly", pytest.approx(0.05, abs=0.002))


def test_a_track_without_headings_faces_along_itself() -> None:
    poses = track_poses(np.array([(0.0, 0.0), (0.05, 0.0), (0.05, 0.05), (0.05, 0.05)]))
    assert poses[:, 2].tolist() == pytest.approx([0.0, 90.0, 90.0, 90.0])
    assert track_poses(np.zeros((2, 2)), np.array([10.0, 20.0]))[:, 2].tolist() == [10.0, 20.0]


def test_the_margins_put_the_thresholds_below_the_capability_by_the_measured_budget() -> None:
    from prox_workflows.algorithms.vehicle import Margins

    assert Margins(read_low=0.02, tracking=0.05).thresholds(BODY) == {"step_max": 0.06, "slope_max": BODY.grade,
                                                                       "margin": 0.05}
    assert RoverBody(clearance=0.12).climb == 0.10
    assert Margins(read_low=0.02, tracking=0.05).thresholds(RoverBody(clearance=0.12))["step_max"] == 0.08
    with pytest.raises(ValueError, match="9.5 cm read-low budget leaves no step below the body's 8.0 cm"):
        Margins(read_low=0.095).thresholds(BODY)  # hirise's ToF at 5 cm


def test_a_pair_read_between_the_cell_centres_judges_equal_bounds_as_one_grid() -> None:
    # a surface drawn as a pair (chance.chance_check) is read bilinearly as one grid is: with its
    # lows equal to its highs it gives the one grid's verdicts; read cellwise, as a map's bounds
    # are, each rock's top stands over its whole cell and the verdicts differ
    g = GridGeometry.covering(-1.0, -1.0, 1.0, 1.0, 0.05)
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    h = np.zeros(g.shape, np.float32)
    for x, y in ((0.3, 0.25), (-0.1, -0.3), (0.05, 0.05)):
        h[np.hypot(X - x, Y - y) < 0.07] = 0.10
    poses = np.column_stack([np.linspace(-0.2, 0.2, 9) + 0.013, np.full(9, 0.011), np.linspace(0.0, 80.0, 9)])
    one = check_poses(h, g, poses, BODY)
    pair = check_poses((h, h.copy()), g, poses, BODY, 0.05, cellwise=False)
    np.testing.assert_allclose(pair.excess, one.excess, atol=1e-5)
    walled = check_poses((h, h.copy()), g, poses, BODY, 0.05)
    assert np.abs(walled.excess - one.excess).max() > 0.005
