"""Renderer accuracy: depth against closed-form ray-surface intersections, objects, albedo."""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest
from scipy import ndimage

from drivers.sim.render import camera_rays
from drivers.sim.transforms import R_BODY_FROM_OPTICAL, make_T, rot_y, rot_z
from drivers.sim.world import World

GX, GY = 0.10, 0.05  # test plane slope
CAP = {"x": 3.0, "y": 0.3, "a": 0.3, "h": 0.2}


def _look(eye, target) -> np.ndarray:
    """T_world_cam (OpenCV optical frame) at eye, looking at target, image x to the right."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_T(np.column_stack([x, y, z]), eye)


def _K(w: int, h: int, hfov: float = 60.0) -> np.ndarray:
    f = (w / 2) / np.tan(np.radians(hfov / 2))
    return np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])


@pytest.fixture(scope="module")
def slope_world() -> World:
    spec = {
        "name": "slope",
        "terrain": {
            "bounds": [0.0, -2.0, 6.0, 2.0], "cell": 0.01,
            "primitives": [
                {"type": "plane", "gx": GX, "gy": GY, "x0": 0.0, "y0": 0.0},
                {"type": "rock", "shape": "cap", **CAP},
            ],
        },
        "rover": {"start": {"x": -50.0, "y": 0.0}},
    }
    return World(spec, seed=1)


def _analytic_depth(o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form first hit of each ray with max(plane, spherical cap); also the radial
    distance of the hit from the cap axis (to exclude the rim, where the surface has a kink)."""
    a, h = CAP["a"], CAP["h"]
    R = (a * a + h * h) / (2 * h)
    base = GX * CAP["x"] + GY * CAP["y"]
    c = np.array([CAP["x"], CAP["y"], base - (R - h)])

    def plane_z(p):
        return GX * p[:, 0] + GY * p[:, 1]

    def cap_z(p):
        r2 = (p[:, 0] - c[0]) ** 2 + (p[:, 1] - c[1]) ** 2
        return np.where(r2 < a * a, c[2] + np.sqrt(np.maximum(R * R - r2, 0)), -np.inf)

    t_p = (GX * o[0] + GY * o[1] - o[2]) / (d[:, 2] - GX * d[:, 0] - GY * d[:, 1])
    p_p = o + t_p[:, None] * d
    t_p = np.where((t_p > 0) & (cap_z(p_p) <= plane_z(p_p)), t_p, np.inf)

    oc = o - c
    A = (d * d).sum(1)
    B = 2 * (d @ oc)
    C = oc @ oc - R * R
    disc = B * B - 4 * A * C
    t_s = (-B - np.sqrt(np.maximum(disc, 0))) / (2 * A)
    p_s = o + t_s[:, None] * d
    r_s = np.hypot(p_s[:, 0] - c[0], p_s[:, 1] - c[1])
    t_s = np.where((disc >= 0) & (t_s > 0) & (r_s < a) & (p_s[:, 2] >= plane_z(p_s)), t_s, np.inf)
    t = np.minimum(t_p, t_s)
    p = o + np.where(np.isfinite(t), t, 0)[:, None] * d
    return t, np.hypot(p[:, 0] - c[0], p[:, 1] - c[1])


@pytest.mark.parametrize("eye", [(0.5, -0.4, 1.5), (3.0, -1.5, 0.8), (1.8, 1.2, 0.6)])
def test_depth_matches_analytic_plane_and_rock_cap(slope_world: World, eye) -> None:
    W, H = 320, 240
    K = _K(W, H)
    T = _look(eye, (CAP["x"], CAP["y"], GX * CAP["x"] + 0.1))
    r = slope_world.render(K, W, H, T)
    o, d = camera_rays(K, W, H, T)
    t_true, rad = _analytic_depth(o, d)
    t_true = t_true.reshape(H, W)
    rad = rad.reshape(H, W)
    terrain = (r.object_id == 0) & np.isfinite(t_true)
    # The cap meets the plane in a kink that bilinear patches (1 cm) round off: leave out a
    # two-cell band around the rim. Rays grazing the cap's silhouette may pass a hair above
    # or below the sampled surface and land metres apart: leave out depth edges too (where
    # the true depth jumps by over 5 cm within a pixel). Everywhere else the surface is the
    # same to float precision.
    tt = np.where(np.isfinite(t_true), t_true, 1e3)
    span = ndimage.maximum_filter(tt, 3) - ndimage.minimum_filter(tt, 3)
    away = terrain & (np.abs(rad - CAP["a"]) > 0.02) & (span < 0.05)
    on_cap = away & (rad < CAP["a"])
    assert on_cap.sum() > 500 and (away & ~on_cap).sum() > 5000
    err = np.abs(r.depth - t_true)[away]
    assert err.max() < 0.002, f"max depth error {err.max() * 1000:.2f} mm"
    # Rays that miss everything analytically miss in the render too.
    assert np.isnan(r.depth[~np.isfinite(t_true) & (r.object_id == -1)]).all()
    assert ((r.object_id == 0) == np.isfinite(r.depth))[np.isfinite(t_true)].all()


def test_range_points_normals_are_consistent(slope_world: World) -> None:
    W, H = 160, 120
    K = _K(W, H)
    T = _look((0.5, 0.0, 1.5), (2.0, -0.8, 0.2))
    r = slope_world.render(K, W, H, T)
    ok = np.isfinite(r.depth)
    assert ok.mean() > 0.8
    # points lie at depth along the optical axis and at range from the centre
    pc = (r.points[ok] - T[:3, 3]) @ T[:3, :3]
    assert np.allclose(pc[:, 2], r.depth[ok], atol=1e-4)
    assert np.allclose(np.linalg.norm(pc, axis=1), r.range[ok], atol=1e-4)
    # on the bare plane the normal is (-gx, -gy, 1) normalised
    far = ok & (np.hypot(r.points[..., 0] - CAP["x"], r.points[..., 1] - CAP["y"]) > CAP["a"] + 0.02)
    n_true = np.array([-GX, -GY, 1.0]) / np.linalg.norm([-GX, -GY, 1.0])
    assert np.allclose(r.normal[far], n_true, atol=1e-4)
    # cos_incidence is the cosine between normal and the ray back to the camera
    v = T[:3, 3] - r.points[far]
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    assert np.allclose((v * n_true).sum(1), r.cos_incidence[far], atol=1e-4)
    assert r.depth.dtype == np.float32 and r.object_id.dtype == np.int16 and r.normal.shape == (H, W, 3)


def test_wall_depth_is_exact_and_texture_is_deterministic() -> None:
    w = World.from_scene("office", seed=0)
    W, H = 176, 144
    K = w.camera_intrinsics("tof", W, H)
    # Camera 1.0 m up at x = 2, looking straight at the front wall (inner face at x = 5.45).
    T = make_T(rot_z(0.0) @ R_BODY_FROM_OPTICAL, (2.0, 0.0, 1.0))
    r = w.render(K, W, H, T)
    ids = w.object_ids
    centre = r.object_id[H // 2 - 5:H // 2 + 5, W // 2 - 5:W // 2 + 5]
    assert (centre == ids["wall_front"]).all()
    assert np.allclose(r.depth[H // 2 - 5:H // 2 + 5, W // 2 - 5:W // 2 + 5], 3.45, atol=1e-5)
    r2 = World.from_scene("office", seed=0).render(K, W, H, T)
    assert np.array_equal(r.albedo, r2.albedo)


def test_rover_body_seen_when_looking_down() -> None:
    w = World.from_scene("office")
    w.set_ptu(0.0, -90.0)
    r = w.render_sensor("tof", 176, 144)
    rover = r.object_id == w.object_ids["rover"]
    assert 0.1 < rover.mean() < 0.9
    # Under the camera: the flat top of the body (0.28 m high) and the top of the mast
    # (0.12 m under the PTU base at 1.2 m), the nearest thing in view.
    cam_z = w.sensor_pose("tof")[2, 3]
    top = np.abs(r.depth[rover] - (cam_z - 0.28)) < 1e-4
    assert top.mean() > 0.3
    assert float(np.nanmin(r.depth[rover])) == pytest.approx(cam_z - (1.20 - 0.12), abs=1e-4)
    w.set_ptu(0.0, 0.0)
    assert not (w.render_sensor("tof", 176, 144).object_id == w.object_ids["rover"]).any()


def test_checkerboard_is_found_by_opencv_where_the_truth_says() -> None:
    w = World.from_scene("office")
    rows, cols, sq = 7, 9, 0.06
    W, H = 1024, 768
    K = w.camera_intrinsics("left", W, H)
    T_cam = _look((0.5, 0.0, 1.0), (2.0, 0.0, 1.0))  # in front of the rover's mast
    # Board 2 m ahead, facing the camera, slightly turned; board z points away from the camera.
    R_board = rot_z(0.0) @ R_BODY_FROM_OPTICAL @ rot_y(15.0)
    centre = np.array([2.0, 0.0, 1.0])
    T_board = make_T(R_board, centre - R_board @ np.array([cols * sq / 2, rows * sq / 2, 0.0]))
    w.place_checkerboard(T_board, rows, cols, sq)
    r = w.render(K, W, H, T_cam)
    assert (r.object_id == w.object_ids["checkerboard"]).sum() > 10000
    # The board's squares are box-filtered over each pixel's footprint (anti-aliased), so
    # corners come out at sub-pixel accuracy (one hard-edged ray per pixel gives ~0.3 px).
    img = (r.albedo * 255).astype(np.uint8)
    found, corners = cv2.findChessboardCorners(img, (cols - 1, rows - 1))
    assert found
    corners = cv2.cornerSubPix(img, corners, (5, 5), (-1, -1),
                               (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)).reshape(-1, 2)
    truth = w.checkerboard_corners()
    pc = (truth - T_cam[:3, 3]) @ T_cam[:3, :3]
    uv = pc[:, :2] / pc[:, 2:] @ K[:2, :2].T + K[:2, 2]
    # OpenCV may start from either end of the grid
    err = min(np.abs(corners - uv).max(), np.abs(corners[::-1] - uv).max())
    assert err < 0.1
    w.remove_checkerboard()
    assert "checkerboard" not in w.object_ids


def test_parallel_strips_give_the_same_image_as_one_pass() -> None:
    from drivers.sim import render as R

    w = World.from_scene("office")
    w.set_ptu(-15.0, -20.0)
    K = w.camera_intrinsics("left", 800, 450)  # 360k pixels: split into strips
    T = w.sensor_pose("left")
    hf, objs, detail = w._snapshot()
    whole = R._render(hf, objs, detail, K, 800, 450, T)
    split = w.render(K, 800, 450, T)
    # The strips' rays differ from the full image's only by rounding (u - c0 + c0): depths
    # agree to float32 precision; a ray exactly on a patch edge may pick the other patch.
    assert np.array_equal(whole.object_id, split.object_id)
    assert np.array_equal(np.isnan(whole.depth), np.isnan(split.depth))
    assert np.nanmax(np.abs(whole.depth - split.depth)) < 1e-4
    assert (np.abs(whole.normal - split.normal).max(-1) > 1e-3).sum() <= 5
    assert (np.abs(whole.albedo - split.albedo) > 1e-3).sum() <= 5


def test_a_cancellable_render_gives_the_same_image_and_stops_when_cancelled(monkeypatch) -> None:
    from drivers.sim import render as R

    w = World.from_scene("office")
    w.set_ptu(-15.0, -20.0)
    K = w.camera_intrinsics("left", 800, 450)
    T = w.sensor_pose("left")
    plain = w.render(K, 800, 450, T)
    strips = w.render(K, 800, 450, T, cancel=lambda: False)  # more, narrower strips
    assert np.array_equal(plain.object_id, strips.object_id)
    assert np.nanmax(np.abs(plain.depth - strips.depth)) < 1e-4
    with pytest.raises(R.RenderCancelled):
        w.render(K, 800, 450, T, cancel=lambda: True)

    rendered: list[int] = []
    real = R._render

    def counted(*args):  # the cancel turns true once the first strip is done
        out = real(*args)
        rendered.append(1)
        return out

    monkeypatch.setattr(R, "_render", counted)
    K = w.camera_intrinsics("left", 1600, 900)
    with pytest.raises(R.RenderCancelled):
        w.render(K, 1600, 900, T, cancel=lambda: bool(rendered))
    time.sleep(0.5)  # strips already running end on their own; no new one starts
    assert len(rendered) <= R._THREADS + 1 < -(-1600 * 900 // R.CANCEL_STRIP_PIXELS)


def test_a_render_cancelled_once_every_strip_is_done_joins_none_of_them(monkeypatch) -> None:
    """Joining the strips of a large view is itself long: a cancel that comes after the last
    strip still stops the render before the layers are joined."""
    from drivers.sim import render as R

    w = World.from_scene("office")
    K = w.camera_intrinsics("left", 1600, 900)
    T = w.sensor_pose("left")
    parts = -(-1600 * 900 // R.CANCEL_STRIP_PIXELS)
    rendered: list[int] = []
    real = R._render

    def counted(*args):
        out = real(*args)
        rendered.append(1)
        return out

    joined: list[int] = []
    real_concatenate = np.concatenate

    def concatenate(arrays, *args, **kw):  # numpy's own: count only the joins of the strips
        if isinstance(arrays, list) and len(arrays) == parts:
            joined.append(1)
        return real_concatenate(arrays, *args, **kw)

    monkeypatch.setattr(R, "_render", counted)
    monkeypatch.setattr(R.np, "concatenate", concatenate)
    with pytest.raises(R.RenderCancelled):
        w.render(K, 1600, 900, T, cancel=lambda: len(rendered) == parts)
    assert len(rendered) == parts and joined == []
