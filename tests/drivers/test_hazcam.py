"""The body hazard cameras: the simulated pairs' points against the world's true ground, the rear
pair looking behind, the switch that keeps them off by default (the simulated rover's config
switches both on), and their settings through the
device registry and a real server (~10 s in all); the start's ring bench through its CLI (a few
minutes)."""

from __future__ import annotations

import threading
from typing import Any

import numpy as np
import pytest
from support.marks import long_test

import drivers.hazcam as hazcam
from drivers.base import DeviceError, DeviceInterrupted
from drivers.registry import DEVICE_KINDS, registry
from drivers.sim.world import World
from rvs_server.devices import stereo_points


@pytest.fixture(scope="module")
def marsyard() -> World:
    return World.from_scene("marsyard", seed=1)


def opened(world: World, cameras: str = "front,rear", **settings: Any) -> hazcam.Hazcam:
    dev = hazcam.create({"cameras": cameras, **settings}, world, stereo_points)
    dev.open()
    return dev


def heights_against_truth(world: World, frame: hazcam.HazcamFrame) -> tuple[np.ndarray, np.ndarray]:
    """Each point's height over the true ground under it (m) and its declared height sigma."""
    T = world.T_world_rover()
    pw = frame.points @ T[:3, :3].T + T[:3, 3]
    cell = 0.005
    box = (pw[:, 0].min() - 0.05, pw[:, 1].min() - 0.05, pw[:, 0].max() + 0.05, pw[:, 1].max() + 0.05)
    dem = world.true_dem(cell, box)
    col = np.clip(((pw[:, 0] - box[0]) / cell).astype(int), 0, dem.shape[1] - 1)
    row = np.clip(((box[3] - pw[:, 1]) / cell).astype(int), 0, dem.shape[0] - 1)
    ray = frame.points - frame.origin
    return pw[:, 2] - dem[row, col], frame.sigma_range * np.abs(ray[:, 2]) / np.linalg.norm(ray, axis=1)


def test_the_front_pair_measures_the_ground_ahead_within_its_declared_sigma(marsyard: World) -> None:
    marsyard.set_rover_pose(0.0, 0.0, 0.0)
    dev = opened(marsyard, "front")
    frame = dev.grab("front")
    assert frame.camera == "front" and frame.points.dtype == np.float64 and frame.points.shape[1] == 3
    assert frame.sigma_range.shape == (len(frame.points),) and np.all(frame.sigma_range > 0)
    np.testing.assert_allclose(frame.origin, [0.27, 0.05, 0.35])  # half the baseline left of the mount
    assert len(frame.points) > 100_000  # most of the 480 x 360 pixels: textured ground, no sky within 3 m
    # ahead of the nose, from the image's bottom edge (0.35 m) to the top's, which the body's 7.6 deg
    # nose-down pitch here (the ground it rests on) brings in from max_range (3 m) to 2.2 m
    assert marsyard.rover_attitude()[1] == pytest.approx(-7.56, abs=0.05)
    ranges = np.linalg.norm(frame.points - frame.origin, axis=1)
    assert frame.points[:, 0].min() > 0.3 and 2.1 < ranges.max() <= 3.0
    assert np.linalg.norm(frame.points - frame.origin, axis=1).max() <= 3.0 + 1e-9
    dz, sigma = heights_against_truth(marsyard, frame)
    assert abs(np.median(dz)) < 0.002
    within = np.abs(dz) < 3 * sigma
    assert within.mean() > 0.95, within.mean()  # the tails: rock edges (a point a little off sideways)
    # and the sigma is the noise, not a blanket: most points lie within one declared sigma
    assert 0.7 < (np.abs(dz) < sigma).mean() < 0.95
    # the farther the point, the noisier (z^2 of stereo)
    far = np.linalg.norm(frame.points - frame.origin, axis=1) > 2.0
    assert np.median(frame.sigma_range[far]) > 4 * np.median(frame.sigma_range[~far])
    assert frame.left.shape == frame.right.shape == (360, 480) and frame.left.dtype == np.uint8
    rows, cols = frame.pixels.T
    assert rows.max() < 360 and cols.max() < 480
    # the capture's own time, apart from the matching: the one the device's status reports
    assert frame.capture_s == pytest.approx(dev.status()["last_grab"]["capture_ms"] / 1000, abs=2e-3)
    assert frame.capture_s > 0 and frame.capture_cpu_s > 0


def test_the_rear_pair_sees_behind_the_rover_whatever_its_heading(marsyard: World) -> None:
    marsyard.set_rover_pose(1.0, 0.5, 90.0)  # facing +y: behind is -y in the world
    dev = opened(marsyard, "rear", size=[320, 240])
    frame = dev.grab("rear")
    assert dev.cameras() == ["rear"]
    assert len(frame.points) > 30_000
    assert frame.points[:, 0].max() < -0.3 and np.all(np.abs(frame.points[:, 1]) < 3.0)
    np.testing.assert_allclose(frame.origin, [-0.27, -0.05, 0.35])  # its left is the rover's right
    T = marsyard.T_world_rover()
    world_y = (frame.points @ T[:3, :3].T + T[:3, 3])[:, 1]
    assert world_y.max() < 0.5 - 0.3
    dz, sigma = heights_against_truth(marsyard, frame)
    assert (np.abs(dz) < 3 * sigma).mean() > 0.95


def test_the_hazcams_are_off_by_default_and_say_how_to_switch_them_on(marsyard: World) -> None:
    assert hazcam.BACKENDS.settings().cameras == "off"
    dev = hazcam.create(None, marsyard, stereo_points)
    dev.open()  # the device stands while off
    status = dev.status()
    assert status["open"] and not status["enabled"] and status["cameras"] == []
    assert "drivers.hazcam.cameras front,rear" in status["note"]
    assert dev.cameras() == []
    for call in (dev.grab, dev.images):
        with pytest.raises(DeviceError, match="hazcams are off: set drivers.hazcam.cameras front,rear") as err:
            call("front")
        assert err.value.device == "hazcam"
    front_only = opened(marsyard, "front", size=[160, 120])
    with pytest.raises(DeviceError, match="rear hazcams are off"):
        front_only.grab("rear")
    with pytest.raises(ValueError, match="front, rear"):
        front_only.grab("left")
    left, right = front_only.images("front")
    assert left.shape == (120, 160) and not np.array_equal(left, right)  # two viewpoints
    stop = threading.Event()
    stop.set()
    with pytest.raises(DeviceInterrupted):
        front_only.grab("front", cancel=stop)
    with pytest.raises(DeviceError, match="no stereo matcher"):
        hazcam.create({"cameras": "front"}, marsyard).grab("front")


def test_the_settings_are_the_registry_s_and_the_mount_is_declared_once(marsyard: World) -> None:
    assert "hazcam" in DEVICE_KINDS and registry("hazcam") is hazcam.BACKENDS
    keys = hazcam.BACKENDS.settings_class().specs()
    assert {"cameras", "front_xyz", "front_pitch_deg", "rear_yaw_deg", "hfov_deg", "size", "baseline", "sigma_d",
            "seed", "library", "front_left_id"} <= set(keys)
    with pytest.raises(ValueError, match="front,rear"):
        hazcam.BACKENDS.settings({"cameras": "sideways"})
    # a pair tilted further down sees nearer ground: the rig follows the settings
    steep = hazcam.pair_rig(hazcam.BACKENDS.settings({"front_pitch_deg": 70.0}), "front")
    flat = hazcam.pair_rig(hazcam.BACKENDS.settings(), "front")
    assert steep.T_rover_left[2, 2] < flat.T_rover_left[2, 2] < 0  # the optical axis points further down


def test_the_simulated_rover_carries_both_pairs(server_factory: Any) -> None:
    """The device's default is off (a real rover names the pairs it carries); the simulated
    rover's config/drivers.yaml names both, for the see loop's start."""
    srv = server_factory([])
    assert srv.app.devices.get("hazcam").cameras() == ["front", "rear"]
    assert srv.app.devices.get("hazcam").backend == "sim"


def test_the_server_builds_the_hazcams_and_config_set_switches_them(server_factory: Any) -> None:
    srv = server_factory(["drivers.hazcam.cameras=front", "drivers.hazcam.size=320,240"])
    c = srv.client()
    try:
        assert "hazcam:ok" in c.request("status").fields["devices"]
        dev = srv.app.devices.get("hazcam")
        frame = dev.grab("front")  # the server's own matcher, on its world (the office's flat floor)
        assert len(frame.points) > 20_000 and abs(np.median(frame.points[:, 2])) < 0.01
        r = c.request("config -module drivers -set hazcam.cameras=rear")
        assert r.status == "OK" and r.fields["pending"] == "hazcam.cameras"
        assert c.request("reinit -device hazcam").status == "OK"
        assert srv.app.devices.get("hazcam").cameras() == ["rear"]
        r = c.request("config -module drivers -set hazcam.cameras=left")
        assert r.fields["code"] == "E_ARG" and "front,rear" in r.fields["message"]
    finally:
        c.close()


def test_a_pair_grabbed_standing_takes_its_exposure_and_readout_on_the_simulated_clock() -> None:
    """The rover's time is the simulated clock's: a pair exposed while the rover stands costs its
    shutter and its readout (drivers.hazcam.sim_readout) there; one exposed while it rolls
    overlaps the drive and costs nothing more."""
    world = World.from_scene("quarry", seed=1, clock_scale=0.0)
    dev = opened(world, "front", sim_readout=0.25)
    t0 = world.clock.now()
    dev.images("front")
    standing = world.clock.now() - t0
    assert 0.25 < standing < 0.25 + 0.1, standing  # the readout, and a shutter of at most 0.1 s
    with world.under_way():
        t1 = world.clock.now()
        dev.images("front")
        assert world.clock.now() == t1


@long_test  # the bench's two starts rendered and matched, 20-40 s
@pytest.mark.timeout(900)  # two starts' turns of both pairs rendered and matched: minutes on a loaded machine
def test_the_ring_bench_holds_the_truth_fused_as_stereo_and_misses_it_as_independent_returns() -> None:
    """``python -m tools.bench.hazcam --ring``: at marsyard's first mission start the pairs over the
    start's turn bound nearly all the ring past the disc the body turns in; fused as a stereo frame
    the bounds hold the true surface in all but a few cells, fused as independent returns the
    true bottom lies under the lower bound in several per cent of them."""
    import subprocess
    import sys

    rows = {}
    for sensor in ("stereo", "tof"):
        out = subprocess.run([sys.executable, "-m", "tools.bench.hazcam", "--ring", "--missions", "1", "--scenes",
                              "marsyard", "--sensor", sensor], capture_output=True, text=True, check=True).stdout
        line = next(row for row in out.splitlines() if row.startswith("| marsyard"))
        cells = [c.strip() for c in line.strip("|").split("|")]
        rows[sensor] = [float(c.rstrip(" %")) for c in cells[4:10]]  # seen .. over 3 sigma
    seen, past, over, under, sd, over3 = rows["stereo"]
    assert seen > 85.0 and past > 98.0, rows
    assert over < 0.5 and under < 0.5 and sd < 1.0 and over3 < 3.0, rows
    assert rows["tof"][3] > 3.0 and rows["tof"][4] > 3.0, rows  # under the lower bound; the mean's error sd
