"""Visual odometry step against the simulated world's truth: ideal rendered frames (exact depth,
view-independent texture) hold the geometry to the millimetre; the corner cases use the same
frames."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.sim.world import World
from prox_workflows.algorithms import odometry as od
from prox_workflows.algorithms.transforms import apply, invert, make_T, rot_z

W, H = 320, 240


def ideal_frame(world: World, K: np.ndarray) -> od.DepthFrame:
    """The left camera's view rendered as a perfect pinhole: albedo as the image (it does not
    change with the viewpoint), the true point of every pixel in the camera frame."""
    T_wc = world.sensor_pose("left")
    r = world.render(K, W, H, T_wc)
    image = np.clip(np.nan_to_num(r.albedo) * 255.0, 0, 255).astype(np.uint8)
    points = apply(invert(T_wc), np.nan_to_num(r.points, nan=0.0))
    points[~np.isfinite(r.depth)] = np.nan
    pan, tilt = world.ptu()
    return od.DepthFrame(image, points, K, np.zeros(5), world.head.T_rover_from_sensor("left", pan, tilt))


@pytest.fixture(scope="module")
def world() -> World:
    w = World.from_scene("quarry")
    w.set_target_visible(False)
    return w


@pytest.fixture
def K(world: World) -> np.ndarray:
    return world.camera_intrinsics("left", W, H)


def _pair(world: World, K: np.ndarray, move: tuple[float, float, float],
          tilts: tuple[float, float] = (-20.0, -20.0)) -> tuple[od.DepthFrame, od.DepthFrame, np.ndarray]:
    world.set_rover_pose(0.0, 0.0, 0.0)
    world.set_ptu(0.0, tilts[0])
    a = ideal_frame(world, K)
    T_a = world.T_world_rover()
    world.move_rover(*move)
    world.set_ptu(0.0, tilts[1])
    b = ideal_frame(world, K)
    return a, b, invert(T_a) @ world.T_world_rover()


@pytest.mark.parametrize("move,detector", [
    ((1.0, 0.0, 0.0), "shi-tomasi"),
    ((1.0, 0.0, 6.0), "shi-tomasi"),
    ((0.8, 0.3, -4.0), "harris"),
])
def test_ideal_frames_recover_the_rover_motion(world: World, K: np.ndarray, move, detector: str) -> None:
    a, b, truth = _pair(world, K, move)
    m = od.estimate_motion(a, b, od.OdometryParams(detector=detector))
    err = np.linalg.norm(m.T[:3, 3] - truth[:3, 3])
    yaw_true = math.degrees(math.atan2(truth[1, 0], truth[0, 0]))
    assert err < 0.003, (m.as_dict(), truth[:3, 3])
    assert abs(m.dyaw - yaw_true) < 0.03
    # the whole rotation, the body's tilt on the ground it rests on at each end included
    dR = m.T[:3, :3].T @ truth[:3, :3]
    assert math.degrees(math.acos(min(1.0, (np.trace(dR) - 1) / 2))) < 0.05
    assert m.inliers >= 0.8 * m.matches and m.matches >= 150
    assert m.rms_px < 0.3 and m.spread > 0.4


def test_each_frame_uses_its_own_sensor_pose(world: World, K: np.ndarray) -> None:
    """The PTU tilted between the acquisitions: the camera moved on the rover, the rover did not
    move more for it."""
    a, b, truth = _pair(world, K, (0.7, 0.0, 3.0), tilts=(-20.0, -26.0))
    m = od.estimate_motion(a, b)
    assert np.linalg.norm(m.T[:3, 3] - truth[:3, 3]) < 0.003
    assert abs(m.dyaw - 3.0) < 0.03


def test_prior_gives_the_same_motion(world: World, K: np.ndarray) -> None:
    a, b, truth = _pair(world, K, (1.0, 0.0, 4.0))
    rough = truth @ make_T(rot_z(1.5), (0.08, -0.05, 0.0))  # a wheel odometry guess, a bit off
    m = od.estimate_motion(a, b, prior=rough)
    assert np.linalg.norm(m.T[:3, 3] - truth[:3, 3]) < 0.003
    assert abs(m.dyaw - 4.0) < 0.03


def test_views_with_nothing_in_common_raise_with_counts(world: World, K: np.ndarray) -> None:
    a, b, _ = _pair(world, K, (0.0, 0.0, 150.0))
    with pytest.raises(od.OdometryError) as info:
        od.estimate_motion(a, b)
    exc = info.value
    assert exc.points >= 200
    assert exc.matches < od.OdometryParams().min_matches or exc.inliers < od.OdometryParams().min_inliers
    assert "points" in str(exc) or "agree" in str(exc)


def test_compose_pose_applies_the_motion_in_the_rover_frame() -> None:
    m = od.Motion(make_T(rot_z(10.0), (1.0, 0.5, 0.0)), np.eye(4), 0, 0, 0, 0.0, 0.0)
    x, y, h = od.compose_pose(2.0, 3.0, 90.0, m)
    assert (x, y, h) == pytest.approx((1.5, 4.0, 100.0))
    x, y, h = od.compose_pose(0.0, 0.0, 175.0, m)
    assert h == pytest.approx(-175.0)


def test_motion_angles() -> None:
    from prox_workflows.algorithms.transforms import rpy

    m = od.Motion(make_T(rpy(1.0, -2.0, 30.0), (0.0, 0.0, 0.0)), np.eye(4), 0, 0, 0, 0.0, 0.0)
    assert (m.droll, m.dpitch, m.dyaw) == pytest.approx((1.0, -2.0, 30.0))


def test_lift_is_bilinear_and_drops_depth_edges() -> None:
    h, w = 20, 30
    pts = np.zeros((h, w, 3), np.float32)
    xs, ys = np.meshgrid(np.arange(w), np.arange(h))
    pts[..., 0], pts[..., 1] = xs * 0.01, ys * 0.01
    pts[..., 2] = 2.0
    pts[:, 20:, 2] = 4.0  # a step in depth between columns 19 and 20
    pts[5, 5] = np.nan
    f = od.DepthFrame(np.zeros((h, w), np.uint8), pts, np.eye(3), np.zeros(5), np.eye(4))
    out = od.lift(f, np.array([[10.5, 10.25], [19.5, 10.0], [5.5, 5.5], [28.2, 3.0]], np.float32), od.OdometryParams())
    assert out[0] == pytest.approx([0.105, 0.1025, 2.0], abs=1e-6)
    assert np.isnan(out[1]).all()  # straddles the step
    assert np.isnan(out[2]).all()  # a neighbour is undefined
    assert out[3, 2] == pytest.approx(4.0)


def test_tof_amplitudes_map_to_the_same_grey_whatever_the_gain() -> None:
    rng = np.random.default_rng(1)
    texture = np.exp(rng.normal(0.0, 0.2, (144, 176))).astype(np.float32)
    yy, xx = np.mgrid[0:144, 0:176]
    falloff = (1.0 / (1.0 + ((yy - 72) ** 2 + (xx - 88) ** 2) / 8000.0)).astype(np.float32)
    a = od.to_gray(texture * falloff * 1000.0)
    b = od.to_gray(texture * falloff * 2500.0)  # the same ground, nearer: brighter
    assert np.abs(a.astype(int) - b.astype(int)).max() <= 1
    assert a.std() > 20  # the texture survives the high-pass


def test_rover_body_mask_removes_the_rover_itself() -> None:
    T = make_T(np.eye(3), (0.0, 0.0, 1.0))  # a sensor 1 m above the rover origin, axes as the rover's
    pts = np.array([[[0.1, 0.0, -0.7], [2.0, 0.0, -1.0]]])  # on the body, on the ground 2 m ahead
    assert od.rover_body_mask(pts, T, 0.5, 0.4, 0.1).tolist() == [[False, True]]
