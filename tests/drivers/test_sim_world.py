"""World state: the sensor-pose chain, rover motion, ground-truth DEM, trigger bus, target."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from drivers.sim.trajectory import Trajectory
from drivers.sim.world import World

FLAT = {
    "name": "flat",
    "terrain": {
        "bounds": [-1.0, -2.0, 5.0, 2.0], "cell": 0.01,
        "primitives": [
            {"type": "steps", "x": 1.0, "y": 1.0, "yaw": 0, "n": 3, "rise": 0.05, "run": 0.1, "width": 0.4},
            {"type": "box", "x": 2.0, "y": -1.0, "sx": 0.3, "sy": 0.2, "yaw": 0, "h": 0.12},
            {"type": "rock", "x": 3.0, "y": 1.0, "a": 0.2, "b": 0.1, "h": 0.15},
            {"type": "crater", "x": 3.5, "y": -1.0, "r": 0.4, "depth": 0.1, "rim": 0.03},
        ],
    },
    "objects": [{"type": "wall", "name": "wall", "p0": [4.5, -2.0], "p1": [4.5, 2.0], "height": 2.0,
                 "thickness": 0.2}],
    "target": {"type": "astronaut", "visible": True,
               "waypoints": [[0.0, 2.0, 0.0], [10.0, 2.0, 1.0], [20.0, 1.0, 1.0]]},
}


@pytest.fixture()
def office() -> World:
    return World.from_scene("office")


@pytest.fixture(scope="module")
def flat() -> World:
    return World(FLAT, seed=0)


def test_sensor_pose_chain_with_numbers(office: World) -> None:
    # Head: PTU base (0.10, 0, 1.20) on the rover, tilt axis 0.06 higher, sensors 0.06 ahead
    # of the tilt axis, stereo cameras at +-0.10 (baseline 0.2 m).
    office.set_ptu(0.0, 0.0)
    T = office.sensor_pose("tof")
    assert np.allclose(T[:3, 3], [0.16, 0.0, 1.26])
    assert np.allclose(T[:3, 2], [1, 0, 0])  # optical axis forward (+x)
    assert np.allclose(T[:3, 0], [0, -1, 0])  # image x to the right (-y)
    assert np.allclose(T[:3, 1], [0, 0, -1])  # image y down
    assert np.allclose(office.sensor_pose("left")[:3, 3], [0.16, 0.10, 1.26])
    assert np.allclose(office.sensor_pose("right")[:3, 3], [0.16, -0.10, 1.26])

    office.set_ptu(90.0, 0.0)  # pan left: the optical axis turns to +y
    T = office.sensor_pose("tof")
    assert np.allclose(T[:3, 2], [0, 1, 0], atol=1e-12)
    assert np.allclose(T[:3, 3], [0.10, 0.06, 1.26])
    assert np.allclose(office.sensor_pose("left")[:3, 3], [0.0, 0.06, 1.26])

    office.set_ptu(0.0, -30.0)  # negative tilt looks down
    T = office.sensor_pose("tof")
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    assert np.allclose(T[:3, 2], [c, 0, -s])
    assert np.allclose(T[:3, 3], [0.10 + 0.06 * c, 0.0, 1.26 - 0.06 * s])
    assert office.ptu() == (0.0, -30.0)

    # The rover's pose comes first in the chain: turn it 90 deg left and move it to (1, 2).
    office.set_rover_pose(1.0, 2.0, 90.0)
    office.set_ptu(0.0, 0.0)
    T = office.sensor_pose("tof")
    assert np.allclose(T[:3, 2], [0, 1, 0], atol=1e-12)
    assert np.allclose(T[:3, 3], [1.0, 2.16, 1.26])


def test_stereo_truth_matches_poses(office: World) -> None:
    office.set_ptu(25.0, -12.0)
    R, t = office.true_stereo_extrinsics()
    Tl, Tr = office.sensor_pose("left"), office.sensor_pose("right")
    X = np.array([0.3, -0.2, 4.0])  # a point in the left camera frame
    Xw = Tl[:3, :3] @ X + Tl[:3, 3]
    Xr = Tr[:3, :3].T @ (Xw - Tr[:3, 3])
    assert np.allclose(R @ X + t, Xr)
    assert np.allclose(t, [-0.2, 0, 0])
    truth = office.true_calibration("left", 1920, 1080)
    assert np.allclose(truth.T_world_cam, Tl)
    assert truth.K[0, 0] == pytest.approx(960 / np.tan(np.radians(30)))
    tof = office.camera_intrinsics("tof", 176, 144)
    assert 2 * np.degrees(np.arctan(88 / tof[0, 0])) == pytest.approx(43.6)
    assert 2 * np.degrees(np.arctan(72 / tof[1, 1])) == pytest.approx(34.6)
    assert tof[0, 2] == pytest.approx(87.5) and tof[1, 2] == pytest.approx(71.5)


def test_move_rover_is_in_the_rover_frame(office: World) -> None:
    office.set_rover_pose(0.0, 0.0, 0.0)
    office.move_rover(1.0, 0.0, 90.0)  # forward 1 m, then turn left 90
    assert np.allclose(office.rover_pose(), (1.0, 0.0, 90.0))
    office.move_rover(1.0, 0.0, 0.0)  # forward is now +y
    assert np.allclose(office.rover_pose(), (1.0, 1.0, 90.0))
    office.move_rover(0.0, 0.5, 0.0)  # left is now -x
    assert np.allclose(office.rover_pose(), (0.5, 1.0, 90.0))
    office.move_rover(0.0, 0.0, 100.0)
    assert office.rover_pose()[2] == pytest.approx(-170.0)  # wrapped to (-180, 180]


def test_true_dem_at_known_primitives(flat: World) -> None:
    dem = flat.true_dem(0.01, (-1.0, -2.0, 5.0, 2.0))
    assert dem.shape == (400, 600) and dem.dtype == np.float32

    def at(x: float, y: float) -> float:
        # north-up grid of cell centres: column j at x = -1 + (j + 0.5) cell, row i at y = 2 - (i + 0.5) cell
        j = int(np.floor((x + 1.0) / 0.01))
        i = int(np.floor((2.0 - y) / 0.01))
        return float(dem[i, j])

    assert at(0.0, 0.0) == pytest.approx(0.0, abs=1e-6)
    for k, h in enumerate((0.05, 0.10, 0.15)):  # the middle of each step
        assert at(1.0 + 0.1 * k + 0.05, 1.0) == pytest.approx(h, abs=1e-6)
    assert at(2.0, -1.0) == pytest.approx(0.12, abs=1e-6)  # box top
    assert at(3.005, 1.005) == pytest.approx(0.15 * np.sqrt(1 - 0.005**2 / 0.04 - 0.005**2 / 0.01), abs=1e-3)
    assert at(3.505, -0.995) == pytest.approx(-0.1 + (0.13) * (0.005**2 * 2 / 0.16), abs=1e-3)  # crater floor
    assert at(4.505, 0.0) == pytest.approx(2.0)  # the wall stands at 4.4..4.6
    assert np.isnan(flat.true_dem(0.1, (5.5, 0.0, 6.5, 1.0))).all()  # off the map
    no_obj = flat.true_dem(0.01, (4.4, -0.1, 4.6, 0.1), include_objects=False)
    assert np.allclose(no_obj, 0.0, atol=1e-6)
    # any grid: 5 cm cells over part of the map, sampled at cell centres
    coarse = flat.true_dem(0.05, (1.5, -1.5, 2.5, -0.5))
    assert coarse.shape == (20, 20)
    assert coarse[10, 10] == pytest.approx(0.12)  # centre (2.025, -1.025): on the box
    assert coarse[0, 0] == pytest.approx(0.0, abs=1e-6)


def test_true_dem_includes_rover_only_on_request(office: World) -> None:
    plain = office.true_dem(0.02, (-0.4, -0.4, 0.4, 0.4))
    with_rover = office.true_dem(0.02, (-0.4, -0.4, 0.4, 0.4), include_rover=True)
    assert np.allclose(plain, 0.0)
    assert with_rover.max() == pytest.approx(1.08)  # mast top, 0.12 m under the PTU base
    assert with_rover[20, 10] == pytest.approx(0.28)  # body top


def test_trigger_bus_pulse_wait_timeout(office: World) -> None:
    bus = office.trigger
    start = bus.count
    assert bus.wait_for_pulse(start, timeout=0.05) is None
    got: list[int | None] = []

    def waiter() -> None:
        got.append(bus.wait_for_pulse(start, timeout=5.0))

    threads = [threading.Thread(target=waiter) for _ in range(2)]
    for t in threads:
        t.start()
    time.sleep(0.05)
    n = bus.pulse()
    for t in threads:
        t.join(5.0)
    assert n == start + 1 and got == [n, n]  # both cameras see the same pulse
    assert bus.wait_for_pulse(start, timeout=0.0) == n  # already past: returns at once
    assert bus.count == n


def test_target_follows_its_trajectory(flat: World) -> None:
    flat.set_target_time(5.0)
    x, y, z, heading = flat.target_pose()
    assert (x, y) == pytest.approx((2.0, 0.5)) and heading == pytest.approx(90.0)
    assert z == pytest.approx(0.0, abs=1e-6)
    flat.set_target_time(15.0)
    assert flat.target_pose()[:2] == pytest.approx((1.5, 1.0))
    assert flat.target_pose()[3] == pytest.approx(180.0)
    flat.set_target_time(99.0)  # after the end it stands still
    assert flat.target_pose()[:2] == pytest.approx((1.0, 1.0))
    loop = Trajectory.from_spec([[0, 0, 0], [10, 10, 0]], loop=True)
    assert loop.at(25.0)[:2] == pytest.approx((5.0, 0.0))
    with pytest.raises(ValueError):
        Trajectory.from_spec([[0, 0, 0], [0, 1, 1]])
    # rendered where it stands: seen from 3 m away, dead ahead
    flat.set_target_time(0.0)
    K = flat.camera_intrinsics("tof", 176, 144)
    flat.set_rover_pose(-1.0, 0.0, 0.0)
    flat.set_ptu(0.0, 0.0)
    r = flat.render_sensor("tof", 176, 144)
    tgt = r.object_id == flat.object_ids["target"]
    assert tgt[72, 88]
    # front of the body: 2 m ahead of the rover centre minus the sensor offset and radius 0.22
    assert float(r.depth[72, 88]) == pytest.approx(2.0 - (-1.0 + 0.16) - 0.22, abs=1e-3)
    assert K.shape == (3, 3)


def test_state_is_thread_safe_and_render_sees_one_snapshot(office: World) -> None:
    # A PTU thread flips the tilt between -20 and -40 while renders run; each render must
    # match one of the two poses exactly (its depth on the flat floor tells which).
    K = office.camera_intrinsics("tof", 40, 30)
    expected = []
    for tilt in (-20.0, -40.0):
        T = office.head.T_rover_from_sensor("tof", 0.0, tilt)
        ray = T[:3, :3] @ np.linalg.solve(K, [20.0, 15.0, 1.0])
        expected.append(-T[2, 3] / ray[2])
    stop = threading.Event()

    def sweep() -> None:
        k = 0
        while not stop.is_set():
            office.set_ptu(0.0, -20.0 if k % 2 else -40.0)
            k += 1

    th = threading.Thread(target=sweep)
    th.start()
    try:
        for _ in range(10):
            d = float(office.render_sensor("tof", 40, 30).depth[15, 20])
            assert min(abs(d - e) for e in expected) < 1e-4, (d, expected)
    finally:
        stop.set()
        th.join()


def test_truth_reports_pose_and_ptu_together() -> None:
    w = World.from_scene("quarry")
    w.set_rover_pose(10.0, 0.0, 45.0)  # on the slope: the rover stands on the ground there
    w.set_ptu(12.5, -7.0)
    t = w.truth()
    assert (t["x"], t["y"], t["heading"], t["pan"], t["tilt"]) == (10.0, 0.0, 45.0, 12.5, -7.0)
    assert t["z"] == pytest.approx(float(w.terrain.sample(10.0, 0.0)), abs=0.005)  # the wheels' plane there
    assert t["z"] > 1.0
    # the body tilts with the slope: heading 45 deg across it, the ground rises ahead and falls
    # to the left, so the nose is up and the left side down; the mast's top leans with it
    gx = (w.terrain.sample(10.2, 0.0) - w.terrain.sample(9.8, 0.0)) / 0.4
    gy = (w.terrain.sample(10.0, 0.2) - w.terrain.sample(10.0, -0.2)) / 0.4
    assert gx + gy > 0.3 and gy - gx < -0.5
    assert (t["roll"], t["pitch"]) == w.rover_attitude()
    assert t["pitch"] > 10.0 and t["roll"] < -15.0
    mast = w.T_world_rover()[:3, :3] @ np.array([0.16, 0.0, 1.26 - 0.06 * np.sin(np.radians(7.0))])
    assert w.sensor_pose("tof")[2, 3] == pytest.approx(t["z"] + mast[2], abs=0.01)


def test_a_scene_built_again_shares_its_ground_and_a_rock_added_to_one_world_stays_there() -> None:
    """A process that builds a scene again (each test's server, a load-scene back to it) takes
    the ground it built (terrain, shadows, detail tile) instead of building it anew; a rock added
    at run time changes only the world it was added to."""
    from drivers.sim import world as world_mod

    a = World.from_scene("office", clock_scale=0.0)
    b = World.from_scene("office", clock_scale=0.0)
    assert b.terrain is a.terrain and b.detail.tile is a.detail.tile and b.z_shift == a.z_shift
    assert World.from_scene("office", seed=5).terrain is not a.terrain  # another seed, another ground
    bounds = (1.2, -0.3, 1.8, 0.3)
    pristine = a.true_dem(0.02, bounds)
    a.add_rock(1.5, 0.0, 0.2, 0.3)
    assert float(np.nanmax(a.true_dem(0.02, bounds) - pristine)) > 0.25
    np.testing.assert_array_equal(b.true_dem(0.02, bounds), pristine)
    np.testing.assert_array_equal(World.from_scene("office").true_dem(0.02, bounds), pristine)
    # the ground kept is the ground a fresh build makes, value for value
    world_mod._GROUNDS.clear()
    fresh = World.from_scene("office")
    assert fresh.terrain is not b.terrain
    for name in ("heights", "albedo", "sunlit"):
        np.testing.assert_array_equal(getattr(fresh.terrain, name), getattr(b.terrain, name))
    np.testing.assert_array_equal(fresh.detail.tile, b.detail.tile)
    assert fresh.terrain.rocks == b.terrain.rocks and fresh.z_shift == b.z_shift


def test_the_world_serves_the_rover_and_the_ptu_while_a_rock_is_being_made(monkeypatch) -> None:
    """A rock added at run time costs seconds of shading on a loaded machine; meanwhile the rover's
    pose, the PTU's move (which asks the world where the camera will look) and the true DEM are
    served, on the ground before the rock; the rock is there once the call returns. Held under the
    world's lock, the shading made the simulated PTU miss its 2 s reply during a drive."""
    from drivers.sim import world as world_mod

    world = World.from_scene("office", clock_scale=0.0)
    shading, release = threading.Event(), threading.Event()
    shade = world_mod._with_shadows

    def held_shade(terrain, sun):
        shading.set()
        assert release.wait(30), "the test never released the shading"
        return shade(terrain, sun)

    monkeypatch.setattr(world_mod, "_with_shadows", held_shade)
    bounds = (1.2, -0.3, 1.8, 0.3)
    pristine = world.true_dem(0.02, bounds)
    adder = threading.Thread(target=world.add_rock, args=(1.5, 0.0, 0.2, 0.3))
    adder.start()
    try:
        assert shading.wait(30)
        served: list[object] = []
        reader = threading.Thread(target=lambda: served.extend(
            [world.rover_pose(), world.set_ptu_target(40.0, -30.0), world.sensor_pose_at("tof", 40.0, -30.0),
             world.true_dem(0.02, bounds)]))
        reader.start()
        reader.join(20)
        assert not reader.is_alive() and len(served) == 4, "the world's readers waited for the rock's shading"
        np.testing.assert_array_equal(served[3], pristine)
    finally:
        release.set()
        adder.join(30)
    assert float(np.nanmax(world.true_dem(0.02, bounds) - pristine)) > 0.25
