"""The vehicle check (prox_workflows.algorithms.vehicle) on synthetic 1 cm surfaces with the declared
Pioneer 3-AT-like body (drivers.sim.rover.RoverBody): wheel relief against the 10 cm climb,
belly intrusion against the 8 cm clearance, tilt against 19.3 deg, and events along a track."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.sim.head import HeadGeometry
from drivers.sim.rover import RoverBody
from drivers.sim.scene import build_rover
from prox_workflows.algorithms.vehicle import check_poses, densify, track_poses, unsafe_events
from prox_workflows.grid import GridGeometry

BODY = RoverBody()
CELL = 0.01


def surface(half: float = 1.5) -> tuple[np.ndarray, GridGeometry, np.ndarray, np.ndarray]:
    """A flat 1 cm grid +-``half`` m around the origin, and the x, y of its cell centres."""
    g = GridGeometry.covering(-half, -half, half, half, CELL)
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    return np.zeros(g.shape, np.float32), g, X, Y


def rock(h: np.ndarray, X: np.ndarray, Y: np.ndarray, x: float, y: float, radius: float, height: float) -> None:
    h[np.hypot(X - x, Y - y) <= radius] = height


def test_the_body_is_declared_once_and_the_simulator_builds_it() -> None:
    assert np.allclose(BODY.wheels, [[0.145, 0.245], [0.145, -0.245], [-0.145, 0.245], [-0.145, -0.245]])
    assert (BODY.wheel_radius, BODY.clearance, BODY.climb, BODY.tilt) == (0.1075, 0.08, 0.10, 19.3)
    assert math.tan(math.radians(BODY.tilt)) == pytest.approx(0.35, abs=0.001)  # the P3-AT's 35 % grade
    rover = build_rover({}, HeadGeometry.from_spec(None))
    corners = rover.world_corners()
    assert corners[:, 1].max() == pytest.approx(0.29)  # the wheels' outer faces
    assert corners[:, 2].min() == pytest.approx(0.0)  # the wheels stand on the ground
    assert RoverBody.from_spec({"climb": 0.12}).climb == 0.12
    with pytest.raises(ValueError, match="unknown rover body key"):
        RoverBody.from_spec({"wheel_diameter": 0.2})


def test_flat_ground_is_safe() -> None:
    h, g, _, _ = surface()
    checks = check_poses(h, g, [(0.0, 0.0, 0.0), (0.1, 0.2, 37.0)], BODY)
    assert not checks.unsafe.any()
    assert np.abs(checks.relief).max() < 1e-6 and np.abs(checks.tilt).max() < 1e-6
    assert checks.intrusion == pytest.approx([-0.08, -0.08], abs=1e-6)


def test_a_rock_under_a_wheel_above_the_climb_fails_that_wheel_by_its_excess() -> None:
    h, g, X, Y = surface()
    rock(h, X, Y, 0.145, -0.245, 0.03, 0.13)  # under the front-right hub
    checks = check_poses(h, g, [(0.0, 0.0, 0.0)], BODY)
    assert checks.relief[0, 1] == pytest.approx(0.13, abs=0.005)
    assert max(checks.relief[0, [0, 2, 3]]) < 0.01
    assert checks.wheel[0] == 1
    events = unsafe_events(checks, np.array([(0.0, 0.0, 0.0)]), BODY)
    assert len(events) == 1
    assert events[0].kind == "wheel front-right"
    assert events[0].excess == pytest.approx(0.03, abs=0.005)
    # the same rock at the climb limit's side: 9 cm is climbed
    h2, _, _, _ = surface()
    rock(h2, X, Y, 0.145, -0.245, 0.03, 0.09)
    assert not check_poses(h2, g, [(0.0, 0.0, 0.0)], BODY).unsafe.any()


def test_a_rock_between_the_wheels_taller_than_the_clearance_fails_as_belly() -> None:
    h, g, X, Y = surface()
    rock(h, X, Y, 0.0, 0.0, 0.05, 0.10)
    checks = check_poses(h, g, [(0.0, 0.0, 0.0)], BODY)
    assert checks.intrusion[0] == pytest.approx(0.02, abs=1e-3)
    assert checks.relief.max() < 0.005 and checks.tilt[0] < 0.5
    (event,) = unsafe_events(checks, np.array([(0.0, 0.0, 0.0)]), BODY)
    assert (event.kind, event.excess) == ("belly", pytest.approx(0.02, abs=1e-3))
    # 7 cm passes under the 8 cm belly
    h2, _, _, _ = surface()
    rock(h2, X, Y, 0.0, 0.0, 0.05, 0.07)
    assert not check_poses(h2, g, [(0.0, 0.0, 0.0)], BODY).unsafe.any()


def test_a_slope_beyond_the_tilt_limit_fails_as_tilt_and_one_within_passes() -> None:
    _, g, X, Y = surface()
    for deg, bad in ((22.0, True), (17.0, False)):
        h = (np.tan(np.radians(deg)) * (X * 0.6 + Y * 0.8)).astype(np.float32)
        checks = check_poses(h, g, [(0.0, 0.0, 30.0)], BODY)
        assert checks.tilt[0] == pytest.approx(deg, abs=0.2)
        assert checks.relief.max() < 0.005  # a steady slope is no step for a wheel
        assert bool(checks.unsafe[0]) is bad
    events = unsafe_events(check_poses((np.tan(np.radians(22.0)) * X).astype(np.float32), g,
                                       [(0.0, 0.0, 0.0)], BODY), np.array([(0.0, 0.0, 0.0)]), BODY)
    assert [(e.kind, round(e.excess, 1)) for e in events] == [("tilt", 2.7)]


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
    assert checks.excess[:, 0].max() == pytest.approx(0.03, abs=0.005)  # the 13 cm rock under a wheel
    assert checks.relief[:, 2:].max(axis=0) == pytest.approx([0.13, 0.13], abs=0.005)  # both rear wheels pass it
    assert checks.relief[:, :2].max() < 0.01  # the front wheels never turn over it
    events = unsafe_events(checks, poses, BODY)
    assert len(events) == 1  # one sweep over it
    assert (events[0].kind, events[0].excess) == ("belly", pytest.approx(0.05, abs=0.002))


def test_a_track_without_headings_faces_along_itself() -> None:
    poses = track_poses(np.array([(0.0, 0.0), (0.05, 0.0), (0.05, 0.05), (0.05, 0.05)]))
    assert poses[:, 2].tolist() == pytest.approx([0.0, 90.0, 90.0, 90.0])
    assert track_poses(np.zeros((2, 2)), np.array([10.0, 20.0]))[:, 2].tolist() == [10.0, 20.0]


def test_the_margins_put_the_thresholds_below_the_capability_by_the_measured_budget() -> None:
    from prox_workflows.algorithms.vehicle import Margins

    assert Margins(read_low=0.02, tracking=0.05).thresholds(BODY) == {"step_max": 0.06, "slope_max": 19.3,
                                                                       "margin": 0.05}
    assert RoverBody(clearance=0.12).climb == 0.10
    assert Margins(read_low=0.02, tracking=0.05).thresholds(RoverBody(clearance=0.12))["step_max"] == 0.08
    with pytest.raises(ValueError, match="9.5 cm read-low budget leaves no step below the body's 8.0 cm"):
        Margins(read_low=0.095).thresholds(BODY)  # hirise's ToF at 5 cm
