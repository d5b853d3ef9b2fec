"""Calibration: DLT and decomposition, absolute orientation with RANSAC, and the three rvs-calib
verbs end to end against the simulator's true calibration."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml
from support import stereo_rig as rig

from prox_workflows.algorithms import calibration as cb
from prox_workflows.algorithms.stereo import load_calibration
from prox_workflows.algorithms.transforms import read_cal
from prox_workflows.cli.calib import main as calib_main
from prox_workflows.products import write_tiff


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    return cv2.Rodrigues(rng.normal(0, 1.0, 3))[0]


def angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1))))


# -- DLT and decomposition ------------------------------------------------------------------------------
def test_decomposition_recovers_K_R_t_whatever_the_scale_and_sign() -> None:
    rng = np.random.default_rng(4)
    for _ in range(20):
        K = np.array([[rng.uniform(300, 2000), rng.uniform(-2, 2), rng.uniform(200, 900)],
                      [0, rng.uniform(300, 2000), rng.uniform(200, 600)], [0, 0, 1]])
        R = random_rotation(rng)
        t = rng.normal(0, 3, 3)
        P = cb.compose_projection(K, R, t)
        for scale in (1.0, -3.7, 1e-4):
            K2, R2, t2 = cb.decompose_projection(scale * P)
            np.testing.assert_allclose(K2, K, rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(R2, R, atol=1e-9)
            np.testing.assert_allclose(t2, t, atol=1e-9)
            assert np.linalg.det(R2) == pytest.approx(1.0)


@pytest.fixture(scope="module")
def sim_camera() -> dict[str, Any]:
    """The left camera of the simulated head at 640 x 480: true K and pose in the world."""
    world = rig.make_world("office", pan=10.0, tilt=-15.0)
    truth = world.true_calibration("left", 640, 480)
    T_cam_world = np.linalg.inv(truth.T_world_cam)
    P = truth.K @ T_cam_world[:3, :]
    return {"world": world, "K": truth.K, "T_world_cam": truth.T_world_cam, "P": P}


def control_points(cam: dict[str, Any], n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """World points spread 2-8 m in front of the camera inside its view, and their pixels."""
    z = rng.uniform(2.0, 8.0, n)
    u = rng.uniform(20, 620, n)
    v = rng.uniform(20, 460, n)
    rays = np.linalg.inv(cam["K"]) @ np.vstack([u, v, np.ones(n)])
    pc = (rays * z).T
    pw = pc @ cam["T_world_cam"][:3, :3].T + cam["T_world_cam"][:3, 3]
    return pw, np.column_stack([u, v])


def test_dlt_recovers_the_true_camera_matrix(sim_camera: dict[str, Any]) -> None:
    rng = np.random.default_rng(0)
    world, image = control_points(sim_camera, 30, rng)
    res = cb.calibrate_control_points(world, image)
    assert res.rms < 1e-6 and res.rms_linear < 1e-6  # noise-free: both exact
    np.testing.assert_allclose(res.K, sim_camera["K"], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(res.T_global_camera, sim_camera["T_world_cam"], atol=1e-6)
    np.testing.assert_allclose(res.P / res.P[2, 3], sim_camera["P"] / sim_camera["P"][2, 3], rtol=1e-6, atol=1e-9)


def test_dlt_with_noisy_clicks_refinement_lowers_the_rms(sim_camera: dict[str, Any]) -> None:
    rng = np.random.default_rng(1)
    world, image = control_points(sim_camera, 40, rng)
    noisy = image + rng.normal(0, 0.3, image.shape)
    res = cb.calibrate_control_points(world, noisy)
    assert res.rms < 0.5
    assert res.rms <= res.rms_linear
    K = sim_camera["K"]
    assert abs(res.K[0, 0] / K[0, 0] - 1) < 0.01 and abs(res.K[1, 1] / K[1, 1] - 1) < 0.01
    assert np.abs(res.K[:2, 2] - K[:2, 2]).max() < 0.01 * K[0, 0]
    assert np.linalg.norm(res.centre - sim_camera["T_world_cam"][:3, 3]) < 0.02
    # a few grossly mis-clicked points: the robust loss keeps the answer
    bad = noisy.copy()
    bad[:3] += 25.0
    robust = cb.calibrate_control_points(world, bad, loss="soft_l1")
    assert abs(robust.K[0, 0] / K[0, 0] - 1) < 0.01


def test_dlt_rejects_degenerate_input() -> None:
    rng = np.random.default_rng(2)
    plane = np.column_stack([rng.uniform(-1, 1, 10), rng.uniform(-1, 1, 10), np.full(10, 3.0)])
    with pytest.raises(ValueError, match="coplanar"):
        cb.dlt(plane, rng.uniform(0, 100, (10, 2)))
    with pytest.raises(ValueError, match="at least 6"):
        cb.dlt(rng.normal(size=(5, 3)), rng.normal(size=(5, 2)))


def test_control_points_from_rendered_boards_and_the_cli(sim_camera: dict[str, Any], tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    """CalWin's procedure on rendered images: board corners (known world positions, found in
    the image) at three placements give a non-coplanar control point set."""
    world = sim_camera["world"]
    cam = rig.stereo_pair(world, "low", sim_distortion=[0.0, 0.0, 0.0, 0.0, 0.0])
    rows, cols, sq = 7, 9, 0.08
    pts_w, pts_i = [], []
    for centre, angles in (((-0.3, 0.0, 2.0), (0, 20, 25)), ((0.35, 0.1, 3.0), (10, -15, -30)),
                           ((0.0, -0.2, 4.5), (-5, 10, 5))):
        rig.place(world, centre, angles, rows, cols, sq)
        left, _ = cam.grab_stereo_direct()
        corners = cb.find_corners(left, (cols - 1, rows - 1))
        assert corners is not None
        pts_w.append(world.checkerboard_corners())
        pts_i.append(corners)
    world.remove_checkerboard()
    W, Im = np.concatenate(pts_w), np.concatenate(pts_i)
    with open(tmp_path / "points.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["id", "x", "y", "z", "u", "v"])
        for k, (p, q) in enumerate(zip(W, Im, strict=True)):
            w.writerow([k, *p, *q])
    rc = calib_main(["control-points", str(tmp_path / "points.csv"), "--image-size", "640", "480",
                     "-o", str(tmp_path / "left.cal")])
    assert rc == 0
    assert "reprojection RMS" in capsys.readouterr().out
    cal = read_cal(tmp_path / "left.cal")
    doc = yaml.safe_load((tmp_path / "left.cal").read_text())
    K = sim_camera["K"]
    # measured: RMS 0.10 px, fx +0.12 %, cx +1.4 px, centre 2.4 mm off, rotation 0.16 deg
    assert doc["rms_px"] < 0.5 and doc["n_points"] == len(W) and cal["image_size"] == [640, 480]
    assert abs(cal["K"][0, 0] / K[0, 0] - 1) < 0.01 and abs(cal["K"][1, 1] / K[1, 1] - 1) < 0.01
    assert np.abs(cal["K"][:2, 2] - K[:2, 2]).max() < 3.0
    assert np.linalg.norm(cal["T_global_camera"][:3, 3] - sim_camera["T_world_cam"][:3, 3]) < 0.01
    assert angle_deg(cal["T_global_camera"][:3, :3], sim_camera["T_world_cam"][:3, :3]) < 0.3
    P, Pt = cal["P"], sim_camera["P"]
    proj = cb.project_points(P, W)
    assert np.sqrt(np.mean(np.sum((proj - cb.project_points(Pt, W)) ** 2, axis=1))) < 0.5
    # the YAML form and a file with too few points
    (tmp_path / "points.yaml").write_text(yaml.safe_dump({"world": W.tolist(), "image": Im.tolist()}))
    assert calib_main(["control-points", str(tmp_path / "points.yaml"), "--image-size", "640", "480",
                       "-o", str(tmp_path / "b.cal"), "-q"]) == 0
    np.testing.assert_allclose(read_cal(tmp_path / "b.cal")["P"], P, rtol=1e-6, atol=1e-6)
    (tmp_path / "few.csv").write_text("1,2,3,4,5\n2,3,4,5,6\n")
    assert calib_main(["control-points", str(tmp_path / "few.csv"), "--image-size", "640", "480",
                       "-o", str(tmp_path / "c.cal")]) == 2
    assert "at least 6" in capsys.readouterr().err


# -- absolute orientation -----------------------------------------------------------------------------------
def test_absolute_orientation_is_exact_on_noise_free_points() -> None:
    rng = np.random.default_rng(5)
    for _ in range(10):
        R, t = random_rotation(rng), rng.normal(0, 2, 3)
        src = rng.normal(0, 1, (20, 3))
        Rh, th, s = cb.absolute_orientation(src, src @ R.T + t)
        np.testing.assert_allclose(Rh, R, atol=1e-10)
        np.testing.assert_allclose(th, t, atol=1e-10)
        assert s == 1.0
        Rs, ts, ss = cb.absolute_orientation(src, 2.5 * src @ R.T + t, with_scale=True)
        assert ss == pytest.approx(2.5) and np.allclose(Rs, R) and np.allclose(ts, t)
    # coplanar points (a board): still a proper rotation, never a reflection
    src = np.column_stack([rng.normal(size=(12, 2)), np.zeros(12)])
    R = random_rotation(rng)
    Rh, _, _ = cb.absolute_orientation(src, src @ R.T)
    assert np.linalg.det(Rh) == pytest.approx(1.0) and np.allclose(Rh, R)


def test_ransac_absolute_orientation_survives_30_percent_outliers() -> None:
    rng = np.random.default_rng(6)
    R, t = random_rotation(rng), np.array([0.1, -0.05, 0.02])
    src = rng.uniform(-0.5, 0.5, (200, 3)) + [0, 0, 2]
    dst = src @ R.T + t + rng.normal(0, 0.003, src.shape)
    out = rng.choice(200, 60, replace=False)
    dst[out] += rng.uniform(0.05, 0.5, (60, 3)) * rng.choice([-1, 1], (60, 3))
    res = cb.ransac_absolute_orientation(src, dst, threshold=0.015, rng=1)
    truly_in = np.ones(200, bool)
    truly_in[out] = False
    oracle_R, oracle_t, _ = cb.absolute_orientation(src[truly_in], dst[truly_in])  # knows the outliers
    assert angle_deg(res.R, R) < 0.2 and np.linalg.norm(res.t - t) < 0.005  # 3 mm noise, 2 m lever arm
    assert angle_deg(res.R, oracle_R) < 0.01 and np.linalg.norm(res.t - oracle_t) < 0.0003
    assert (res.inliers == truly_in).mean() > 0.97
    assert res.rms < 0.008
    plain_R, plain_t, _ = cb.absolute_orientation(src, dst)
    assert np.linalg.norm(plain_t - t) > 10 * np.linalg.norm(res.t - t)  # the outliers pull a plain fit
    nan_src = src.copy()
    nan_src[:5] = np.nan  # undefined points are skipped, reported as NaN residuals
    res2 = cb.ransac_absolute_orientation(nan_src, dst, threshold=0.015, rng=1)
    assert np.isnan(res2.residuals[:5]).all() and not res2.inliers[:5].any()


# -- stereo from checkerboard pairs -------------------------------------------------------------------------
def test_stereo_checkerboard_calibration_recovers_the_pair(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    world = rig.make_world("office")
    cam = rig.stereo_pair(world, "low")
    rows, cols, sq = 7, 9, 0.05
    rng = np.random.default_rng(1)
    folder = tmp_path / "boards"
    folder.mkdir()
    for i in range(10):
        z = rng.uniform(0.8, 1.6)
        centre = (0.1 + rng.uniform(-0.3, 0.3) * z, rng.uniform(-0.25, 0.25) * z, z)  # seen by both cameras
        angles = (rng.uniform(-20, 20), rng.uniform(-35, 35), rng.uniform(-35, 35))
        rig.place(world, centre, angles, rows, cols, sq)
        left, right = cam.grab_stereo_direct()
        cv2.imwrite(str(folder / f"b{i:02d}_left.png"), left)
        cv2.imwrite(str(folder / f"b{i:02d}_right.png"), right)
    rc = calib_main(["stereo", str(folder), "--pattern", f"{cols - 1}x{rows - 1}", "--square", str(sq),
                     "-o", str(tmp_path / "calib.yaml")])
    assert rc == 0
    assert "stereo RMS" in capsys.readouterr().out
    doc = yaml.safe_load((tmp_path / "calib.yaml").read_text())
    cal = load_calibration(tmp_path / "calib.yaml")
    truth = rig.true_stereo_calibration(cam)
    # measured: RMS 0.12 px, baseline +0.18 %, fx +0.005 %, R 0.06 deg off
    assert doc["pairs_used"] == 10 and doc["rms_px"] < 0.5
    assert abs(cal.baseline / np.linalg.norm(truth["T"]) - 1) < 0.01
    assert cal.T[0] < 0 and abs(cal.T[0]) > 0.99 * cal.baseline  # right camera to the right
    assert angle_deg(cal.R, truth["R"]) < 0.1
    for K, Kt in ((cal.K1, truth["K1"]), (cal.K2, truth["K2"])):
        assert abs(K[0, 0] / Kt[0, 0] - 1) < 0.01 and abs(K[1, 1] / Kt[1, 1] - 1) < 0.01
    # the distortion model reproduces the true lens where the boards were: undistorted corners agree
    pts = np.array([[60.0, 50.0], [600.0, 420.0], [320.0, 240.0], [100.0, 400.0]]).reshape(-1, 1, 2)
    mine = cv2.undistortPoints(pts, cal.K1, cal.D1).reshape(-1, 2) * truth["K1"][0, 0]
    true = cv2.undistortPoints(pts, truth["K1"], truth["D1"]).reshape(-1, 2) * truth["K1"][0, 0]
    assert np.abs(mine - true).max() < 3.0
    # too few usable pairs is an error that says so
    assert calib_main(["stereo", "--left", str(folder / "b00_left.png"), "--right", str(folder / "b00_right.png"),
                       "--pattern", "8x6", "--square", "0.05", "-o", str(tmp_path / "x.yaml")]) == 2
    assert "at least 3" in capsys.readouterr().err


# -- ToF to stereo ----------------------------------------------------------------------------------------------
TOF_BOARD = (5, 7, 0.10)  # rows, cols, square: big squares for the 176 x 144 ToF
TOF_POSES = [((0, 0, 1.3), (0, 0, 0)), ((0.25, 0.1, 1.6), (5, 15, -20)), ((-0.25, -0.1, 1.6), (-5, -15, 20)),
             ((0.1, -0.15, 2.0), (10, -20, 10)), ((-0.15, 0.15, 2.2), (-10, 20, -15)), ((0, 0, 1.8), (30, 0, 25)),
             ((0.2, 0.2, 1.4), (0, 25, 0)), ((-0.2, 0.0, 1.5), (15, 0, -30))]


@pytest.fixture(scope="module")
def tof_views(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Eight board poses seen by the simulated ToF and stereo pair, saved as grab-tof / grab-stereo
    would (``<stem>_xyz.tif``, ``<stem>_amplitude.tif``, ``<stem>_left.png``, ``<stem>_right.png``)."""
    folder = tmp_path_factory.mktemp("tof_stereo")
    world = rig.make_world("office")
    cam = rig.stereo_pair(world, "low")
    tof = rig.tof_camera(world)
    rows, cols, sq = TOF_BOARD
    views = []
    for i, (centre, angles) in enumerate(TOF_POSES):
        rig.place(world, centre, angles, rows, cols, sq)
        left, right = cam.grab_stereo_direct()
        xyz, amp = tof.grab_xyz()
        stem = folder / f"board{i}"
        write_tiff(Path(f"{stem}_xyz.tif"), xyz)  # as grab-tof writes them
        write_tiff(Path(f"{stem}_amplitude.tif"), amp)
        cv2.imwrite(f"{stem}_left.png", left)
        cv2.imwrite(f"{stem}_right.png", right)
        views.append(cb.TofStereoView(xyz, amp, left, right, f"board{i}"))
    # the board moved between the ToF and the stereo grab of one pose (seed 004's "bad capture")
    rig.place(world, (0.05, 0.03, 1.7), (0, 10, 10), rows, cols, sq)
    moved_xyz, moved_amp = tof.grab_xyz()
    calib = rig.true_stereo_calibration(cam)
    from prox_workflows.algorithms.stereo import save_calibration

    save_calibration(folder / "calib.yaml", calib)
    return {"folder": folder, "views": views, "calib": calib, "truth": rig.T_left_tof(world),
            "moved": (moved_xyz, moved_amp), "pattern": (cols - 1, rows - 1)}


def pose_error(T: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    return float(np.linalg.norm(T[:3, 3] - truth[:3, 3])), angle_deg(T[:3, :3], truth[:3, :3])


def test_tof_stereo_cli_reaches_5_mm_and_0_3_degrees(tof_views: dict[str, Any], tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "tof_left.yaml"
    rc = calib_main(["tof-stereo", str(tof_views["folder"]), "--calib", str(tof_views["folder"] / "calib.yaml"),
                     "--pattern", "6x4", "-o", str(out)])
    assert rc == 0
    assert "inliers" in capsys.readouterr().out
    doc = yaml.safe_load(out.read_text())
    T = np.asarray(doc["T_left_tof"])
    dt, dr = pose_error(T, tof_views["truth"])
    # measured (XYZ interpolated at the corners): 2.6 mm, 0.07 deg; residual RMS 7.7 mm over 163 corners of
    # 7 views (the eighth board leaves the ToF's narrower view)
    assert dt < 0.005 and dr < 0.3
    assert np.allclose(np.asarray(doc["R"]), T[:3, :3]) and np.allclose(doc["T"], T[:3, 3])
    assert np.allclose(np.asarray(doc["T_tof_left"]) @ T, np.eye(4), atol=1e-9)
    stats = doc["residuals"]
    assert len(stats["views_used"]) >= 7 and stats["inliers"] >= 150 and stats["rms_m"] < 0.015


def test_tof_stereo_plane_lift_and_a_moved_board(tof_views: dict[str, Any]) -> None:
    views, calib, truth, pattern = tof_views["views"], tof_views["calib"], tof_views["truth"], tof_views["pattern"]
    res = cb.calibrate_tof_stereo(views, calib, pattern, lift="plane")
    dt, dr = pose_error(res.T_left_tof, truth)
    assert dt < 0.005 and dr < 0.3  # measured 1.4 mm, 0.03 deg; residual RMS 3.8 mm
    assert res.stats()["rms_m"] < 0.008
    # one pose whose ToF frame shows the board elsewhere: RANSAC drops its corners
    bad = list(views)
    bad[3] = cb.TofStereoView(*tof_views["moved"], views[3].left, views[3].right, "moved")
    res_bad = cb.calibrate_tof_stereo(bad, calib, pattern)
    dt, dr = pose_error(res_bad.T_left_tof, truth)
    assert dt < 0.005 and dr < 0.3
    from_moved = res_bad.view_of_point == 3
    assert from_moved.any() and res_bad.ransac.inliers[from_moved].mean() < 0.2
    R, t, _ = cb.absolute_orientation(res_bad.tof_points, res_bad.stereo_points)
    T_plain = np.eye(4)
    T_plain[:3, :3], T_plain[:3, 3] = R, t
    assert pose_error(T_plain, truth)[0] > 0.02  # without RANSAC the moved board drags the fit 6 cm off


def test_tof_stereo_reports_views_without_the_board(tof_views: dict[str, Any]) -> None:
    blank = cb.TofStereoView(np.zeros((144, 176, 3), np.float32), np.zeros((144, 176), np.float32),
                             tof_views["views"][0].left, tof_views["views"][0].right, "blank")
    res = cb.calibrate_tof_stereo([*tof_views["views"][:4], blank], tof_views["calib"], tof_views["pattern"])
    assert res.views_rejected == {"blank": "board not found in the ToF amplitude image"}
    with pytest.raises(ValueError, match="no view"):
        cb.calibrate_tof_stereo([blank], tof_views["calib"], tof_views["pattern"])


def test_sim_truth_verb_writes_the_true_calibration(tmp_path: Path) -> None:
    rc = calib_main(["sim-truth", "-o", str(tmp_path / "calib.yaml"), "--resolution", "low",
                     "--tof", str(tmp_path / "tof.yaml"), "-q"])
    assert rc == 0
    cal = load_calibration(tmp_path / "calib.yaml")
    world = rig.make_world("office")
    cam = rig.stereo_pair(world, "low")
    truth = rig.true_stereo_calibration(cam)
    np.testing.assert_allclose(cal.K1, truth["K1"])
    np.testing.assert_allclose(cal.T, truth["T"])
    np.testing.assert_allclose(cal.D1, truth["D1"])
    assert cal.image_size == (640, 480) and cal.T[0] == pytest.approx(-0.2)
    tof = yaml.safe_load((tmp_path / "tof.yaml").read_text())
    np.testing.assert_allclose(np.asarray(tof["T_left_tof"]), rig.T_left_tof(world), atol=1e-12)
