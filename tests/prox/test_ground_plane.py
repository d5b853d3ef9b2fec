"""Ground-plane step: RANSAC plane fit, averaging, and the mount correction that levels the
ground, on synthetic point clouds made with a known (mis)aligned head."""

from __future__ import annotations

import numpy as np
import pytest

from prox_workflows.algorithms import ground_plane as gp
from prox_workflows.algorithms.transforms import HeadCalibration, apply, invert, rpy


def ground_seen_by(head: HeadCalibration, sensor: str, pan: float, tilt: float, rng: np.random.Generator,
                   noise: float = 0.005, clutter: int = 0) -> np.ndarray:
    """Points of the level ground (z = 0 in the rover frame) 1-4 m ahead, in the sensor frame of
    the *true* head, with range noise and optional clutter (a box standing on the ground)."""
    n = 20000
    x = rng.uniform(1.0, 4.0, n)
    y = rng.uniform(-1.5, 1.5, n)
    pts = np.column_stack([x, y, rng.normal(0.0, noise, n)])
    if clutter:
        box = np.column_stack([rng.uniform(2.0, 2.5, clutter), rng.uniform(-0.3, 0.3, clutter),
                               rng.uniform(0.05, 0.6, clutter)])
        pts = np.vstack([pts, box])
    return apply(invert(head.T_rover_from_sensor(sensor, pan, tilt)), pts).astype(np.float64)


def misaligned(roll: float, pitch: float, sensors: tuple[str, ...] = ("tof",)) -> HeadCalibration:
    head = HeadCalibration()
    for s in sensors:
        head.mounts[s] = {"xyz": list(head.mounts[s]["xyz"]), "rpy": [roll, pitch, 0.0]}
    return head


def test_fit_plane_finds_the_ground_among_clutter() -> None:
    rng = np.random.default_rng(0)
    head = HeadCalibration()
    pts = ground_seen_by(head, "tof", 0.0, -40.0, rng, clutter=6000)
    plane = gp.fit_plane(pts, 0.02)
    n_true = head.T_rover_from_sensor("tof", 0.0, -40.0)[:3, :3].T @ np.array([0.0, 0.0, 1.0])
    angle = np.degrees(np.arccos(np.clip(plane.normal @ n_true, -1, 1)))
    assert angle < 0.05
    assert plane.d == pytest.approx(head.T_rover_from_sensor("tof", 0.0, -40.0)[2, 3], abs=0.002)
    assert 0.7 < plane.share < 0.8  # the box is not ground
    assert plane.rms == pytest.approx(0.005, rel=0.2)


def test_average_planes_reports_the_spread() -> None:
    planes = [gp.Plane(np.array([0.0, np.sin(a), np.cos(a)]), 1.2, 100, 0.01, 0.9)
              for a in np.radians([-0.2, 0.0, 0.2])]
    mean, spread = gp.average_planes(planes)
    assert mean.normal == pytest.approx([0.0, 0.0, 1.0], abs=1e-9)
    assert spread == pytest.approx(0.2, abs=1e-6)
    assert mean.inliers == 300


@pytest.mark.parametrize("roll,pitch,tilt", [(0.0, 2.0, -40.0), (2.0, 0.0, -40.0), (-1.5, 1.2, -60.0),
                                             (2.0, 0.0, -75.0)])
def test_align_mount_recovers_the_true_mount(roll: float, pitch: float, tilt: float) -> None:
    rng = np.random.default_rng(3)
    truth = misaligned(roll, pitch)
    pts = ground_seen_by(truth, "tof", 0.0, tilt, rng)
    result = gp.align_mount(HeadCalibration(), "tof", 0.0, tilt, gp.fit_plane(pts, 0.02))
    assert result.rpy_before == [0.0, 0.0, 0.0]
    assert result.rpy_after[0] == pytest.approx(roll, abs=0.02)
    assert result.rpy_after[1] == pytest.approx(pitch, abs=0.02)
    assert result.rpy_after[2] == 0.0  # a turn about the vertical is invisible in the ground
    t_tilt, t_roll, _ = gp.sensor_attitude(truth.T_rover_from_sensor("tof", 0.0, tilt))
    assert result.tilt == pytest.approx(t_tilt, abs=0.02)
    assert result.roll == pytest.approx(t_roll, abs=0.02)
    assert result.height == pytest.approx(truth.T_rover_from_sensor("tof", 0.0, tilt)[2, 3], abs=0.002)
    assert result.ground_z == pytest.approx(0.0, abs=0.002)
    # with the corrected mount the ground is level in the rover frame
    fixed = HeadCalibration()
    fixed.mounts.update(result.mounts)
    level = apply(fixed.T_rover_from_sensor("tof", 0.0, tilt), pts)
    assert np.std(level[:, 2]) < 0.007


def test_stereo_followers_get_the_same_rotation() -> None:
    rng = np.random.default_rng(4)
    truth = misaligned(1.0, 1.5, ("left", "right"))
    pts = ground_seen_by(truth, "left", 0.0, -40.0, rng)
    head = HeadCalibration()
    result = gp.align_mount(head, "left", 0.0, -40.0, gp.fit_plane(pts, 0.02), followers=("right",))
    assert result.mounts["right"]["rpy"] == pytest.approx([1.0, 1.5, 0.0], abs=0.02)
    assert result.mounts["right"]["xyz"] == head.mounts["right"]["xyz"]


def test_rpy_of_inverts_rpy() -> None:
    for angles in [(1.0, -2.0, 30.0), (-10.0, 5.0, -170.0), (0.0, 0.0, 0.0)]:
        assert gp.rpy_of(rpy(*angles)) == pytest.approx(angles, abs=1e-9)


def test_fit_plane_needs_points() -> None:
    with pytest.raises(ValueError):
        gp.fit_plane(np.zeros((2, 3)))
