"""Target detection and tracking steps on synthetic data with known geometry."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from prox_workflows.algorithms import tracking as tr

W, H, F = 176, 144, 220.0
K = np.array([[F, 0, (W - 1) / 2], [0, F, (H - 1) / 2], [0, 0, 1.0]])
SENSOR = np.array([0.16, 0.0, 1.26])


def camera(pan: float = 0.0, tilt: float = -5.0) -> np.ndarray:
    """World rotation of the optical frame (x right, y down, z forward) for a pan/tilt head."""
    base = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # optical -> body
    p, t = math.radians(pan), math.radians(-tilt)
    Rz = np.array([[math.cos(p), -math.sin(p), 0], [math.sin(p), math.cos(p), 0], [0, 0, 1]])
    Ry = np.array([[math.cos(t), 0, math.sin(t)], [0, 1, 0], [-math.sin(t), 0, math.cos(t)]])
    return Rz @ Ry @ base


def render(objects: list[tuple], pan: float = 0.0, tilt: float = -5.0, noise: float = 0.005, seed: int = 0
           ) -> tuple[np.ndarray, np.ndarray]:
    """Ray cast the ground plane z=0 (albedo 0.5) and ``objects``: ("cylinder", cx, cy, r, h, albedo),
    ("sheet", x, y0, y1, z0, z1, albedo) (a vertical rectangle at x facing the camera). Returns the
    organised world points (NaN where nothing) and the amplitude (albedo cos / range^2)."""
    rng = np.random.default_rng(seed)
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    d_cam = np.stack([(u - K[0, 2]) / F, (v - K[1, 2]) / F, np.ones_like(u, float)], axis=-1)
    d = d_cam @ camera(pan, tilt).T
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    o = SENSOR
    best = np.full((H, W), np.inf)
    normal = np.zeros((H, W, 3))
    albedo = np.zeros((H, W))
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d[..., 2] < 0, -o[2] / d[..., 2], np.inf)
    hit = t < best
    best[hit], normal[hit], albedo[hit] = t[hit], (0, 0, 1), 0.5
    for obj in objects:
        if obj[0] == "cylinder":
            _, cx, cy, r, h, alb = obj
            ox, oy = o[0] - cx, o[1] - cy
            a = d[..., 0] ** 2 + d[..., 1] ** 2
            b = 2 * (ox * d[..., 0] + oy * d[..., 1])
            c = ox * ox + oy * oy - r * r
            disc = b * b - 4 * a * c
            with np.errstate(invalid="ignore"):
                t = (-b - np.sqrt(disc)) / (2 * a)
            z = o[2] + t * d[..., 2]
            ok = (disc > 0) & (t > 0) & (z >= 0) & (z <= h) & (t < best)
            p = o + t[..., None] * d
            n = np.stack([p[..., 0] - cx, p[..., 1] - cy, np.zeros_like(t)], axis=-1) / r
        else:
            _, x, y0, y1, z0, z1, alb = obj
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (x - o[0]) / d[..., 0]
            p = o + t[..., None] * d
            ok = (t > 0) & (p[..., 1] >= y0) & (p[..., 1] <= y1) & (p[..., 2] >= z0) & (p[..., 2] <= z1) & (t < best)
            n = np.broadcast_to(np.array([-1.0, 0.0, 0.0]), d.shape)
        best[ok], normal[ok], albedo[ok] = t[ok], n[ok], alb
    found = np.isfinite(best) & (best < 4.8)
    rng_noisy = best + rng.normal(0.0, noise, best.shape)
    pts = o + rng_noisy[..., None] * d
    pts[~found] = np.nan
    cos = np.abs(np.sum(normal * d, axis=-1))
    amplitude = np.where(found, 1e4 * albedo * cos / np.maximum(best, 0.1) ** 2, 0.0)
    return pts, amplitude


def test_an_astronaut_sized_cylinder_is_found_at_its_axis() -> None:
    pts, amp = render([("cylinder", 3.8, 0.4, 0.22, 1.8, 0.85)])
    dets = tr.detect_standing(pts, SENSOR, amplitude=amp)
    assert len(dets) == 1
    d = dets[0]
    assert math.hypot(d.x - 3.8, d.y - 0.4) < 0.03  # the axis, not the visible surface 0.17 m closer
    assert d.z == pytest.approx(0.0, abs=0.03)
    assert d.height == pytest.approx(1.8, abs=0.1)
    assert 0.3 <= d.width <= 0.5
    assert d.radius == pytest.approx(0.22, abs=0.05)


def test_nothing_standing_means_nothing_found_and_the_size_prior_rejects_rocks_and_walls() -> None:
    pts, amp = render([])
    assert tr.detect_standing(pts, SENSOR, amplitude=amp) == []
    pts, amp = render([("cylinder", 3.5, 0.0, 0.3, 0.6, 0.6)])  # a boulder: too short
    assert tr.detect_standing(pts, SENSOR, amplitude=amp) == []
    pts, amp = render([("sheet", 3.5, -0.8, 0.8, 0.0, 1.8, 0.9)])  # a door-sized panel: too wide
    assert tr.detect_standing(pts, SENSOR, amplitude=amp) == []


def test_floating_returns_neither_count_nor_drag_the_fit() -> None:
    # A faint sheet beside the body at its range (what a phase-wrapped far slope looks like) and a
    # bright one floating above the ground: neither is a target, and the body is still found.
    objects = [("cylinder", 3.8, 0.0, 0.22, 1.8, 0.85), ("sheet", 3.75, 0.25, 1.2, 1.0, 1.7, 0.03),
               ("sheet", 3.0, -1.2, -0.6, 0.9, 2.0, 0.9)]
    pts, amp = render(objects)
    dets = tr.detect_standing(pts, SENSOR, amplitude=amp)
    assert len(dets) == 1 and math.hypot(dets[0].x - 3.8, dets[0].y) < 0.04


def test_ground_under_follows_a_tilted_ground_and_ignores_the_body() -> None:
    rng = np.random.default_rng(1)
    xy = rng.uniform([1, -2], [5, 2], (4000, 2))
    z = 0.05 * xy[:, 0] + 0.02 * xy[:, 1]
    body = np.column_stack([rng.normal(3.0, 0.1, 500), rng.normal(0.0, 0.1, 500), rng.uniform(0, 1.8, 500)])
    body[:, 2] += 0.05 * body[:, 0]
    pts = np.vstack([np.column_stack([xy, z]), body])
    g = tr.ground_under(pts)
    truth = 0.05 * pts[:, 0] + 0.02 * pts[:, 1]
    assert np.abs(g - truth).max() < 0.08


@pytest.mark.parametrize("seed", range(5))
def test_fit_circle_on_the_visible_half(seed: int) -> None:
    rng = np.random.default_rng(seed)
    centre, r = np.array([4.0, 1.0]), 0.22
    toward = np.array([0.0, 0.0])
    facing = math.atan2(toward[1] - centre[1], toward[0] - centre[0])
    a = facing + rng.uniform(-1.3, 1.3, 300)
    xy = centre + r * np.column_stack([np.cos(a), np.sin(a)]) + rng.normal(0, 0.005, (300, 2))
    cx, cy, rr = tr.fit_circle(xy, toward=toward)
    assert math.hypot(cx - centre[0], cy - centre[1]) < 0.02
    assert rr == pytest.approx(r, abs=0.03)


def test_tracker_predicts_gates_loses_and_reacquires() -> None:
    f = tr.Tracker(lost_after=2)
    for k in range(10):  # walking at 1 m/s along y, a fix every 0.2 s
        t = 0.2 * k
        det = tr.Detection(4.0, -1.0 + t, 0.0, 1.8, 0.4, 0.22, 500)
        assert f.choose([det], t) is det
        assert f.update(det, t) is (k == 0)
    assert f.velocity == pytest.approx([0.0, 1.0], abs=0.05)
    pred = f.predict(2.0)
    assert pred[1] == pytest.approx(1.0, abs=0.05)
    far = tr.Detection(1.0, 3.0, 0.0, 1.8, 0.4, 0.22, 500)
    assert f.choose([far], 2.0) is None  # outside the gate
    assert f.update(None, 2.0) is False and not f.lost
    assert f.update(None, 2.2) is False and f.lost
    assert f.predict(3.0)[1] == pytest.approx(f.position[1])  # no extrapolation while lost
    back = tr.Detection(4.0, 2.5, 0.0, 1.8, 0.4, 0.22, 500)
    assert f.choose([back], 3.0) is back  # anywhere in view while lost
    assert f.update(back, 3.0) is True and not f.lost


def test_merge_detections_keeps_the_best_of_a_double_sighting() -> None:
    a = tr.Detection(1.0, 1.0, 0.0, 1.8, 0.4, 0.2, 100, score=0.2)
    b = tr.Detection(1.1, 1.0, 0.0, 1.8, 0.4, 0.2, 100, score=0.1)
    c = tr.Detection(3.0, 1.0, 0.0, 1.8, 0.4, 0.2, 100, score=0.3)
    assert tr.merge_detections([a, b, c]) == [b, c]


def _marker_view(img: np.ndarray, corners_cam: np.ndarray, Kc: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    px = (corners_cam @ Kc.T)[:, :2] / corners_cam[:, 2:]
    n = img.shape[0]
    src = np.array([[0, 0], [n, 0], [n, n], [0, n]], np.float32)
    Hm = cv2.getPerspectiveTransform(src, px.astype(np.float32))
    return cv2.warpPerspective(img, Hm, size, borderValue=200)


def test_aruco_marker_is_triangulated_in_a_stereo_pair() -> None:
    dic = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250)
    marker = cv2.aruco.generateImageMarker(dic, 7, 240)
    Kc = np.array([[800.0, 0, 320], [0, 800.0, 240], [0, 0, 1]])
    side, centre = 0.3, np.array([0.1, -0.05, 2.5])
    # corners in ArUco's order (top-left, top-right, bottom-right, bottom-left), facing the camera
    corners = centre + side / 2 * np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]])
    T = np.array([-0.2, 0.0, 0.0])  # right camera 0.2 m to the right: X_right = X_left + T
    left = _marker_view(marker, corners, Kc, (640, 480))
    right = _marker_view(marker, corners + T, Kc, (640, 480))
    found = tr.detect_markers(left, right, Kc, np.zeros(5), Kc, np.zeros(5), np.eye(3), T)
    assert len(found) == 1 and found[0].marker_id == 7
    assert np.linalg.norm(found[0].centre - centre) < 0.01
    assert found[0].normal == pytest.approx([0, 0, -1], abs=0.05)
    assert tr.detect_markers(left, right, Kc, np.zeros(5), Kc, np.zeros(5), np.eye(3), T, marker_id=3) == []


def test_marker_box_foot_is_behind_and_below_the_face() -> None:
    foot = tr.marker_box_foot(np.array([1.0, 0.0, 0.2]), np.array([-1.0, 0.0, 0.0]), 0.4)
    assert foot == pytest.approx([1.2, 0.0, 0.0])


def test_point_image_moves_points_and_marks_undefined() -> None:
    xyz = np.full((2, 2, 3), -1.0, np.float32)
    xyz[0, 1] = (0.0, 0.0, 2.0)
    xyz[1, 1] = (0.0, 0.0, 9.0)
    T = np.eye(4)
    T[:3, 3] = (1.0, 2.0, 3.0)
    img = tr.point_image(xyz, T, max_range=4.8)
    assert np.isnan(img[0, 0]).all() and np.isnan(img[1, 1]).all()
    assert img[0, 1] == pytest.approx([1.0, 2.0, 5.0])
