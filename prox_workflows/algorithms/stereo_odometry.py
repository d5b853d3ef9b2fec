"""Visual odometry from files: a stereo pair A and the next left image (or pair) B.

The server's orient machinery (:mod:`prox_workflows.algorithms.odometry`: Shi-Tomasi/Harris points
where A has depth, pyramidal Lucas-Kanade with a forward-backward check, PnP inside RANSAC,
two-way weighted refinement) is run here on frames made from image files, so that the same
estimate can be checked on recorded data without a server, a PTU or a rover model.

A's depth comes from the stereo step (:func:`prox_workflows.algorithms.stereo.disparity`, the
calibration of rvs-stereo). B needs no depth: PnP uses A's 3D points and B's pixels; B's right
image, when given, adds B's depth to the refinement (the B -> A residuals).

The result is the motion of camera B in camera A's frame (OpenCV optical axes: x right, y down,
z forward, metres), as a translation and a rotation vector in degrees, with a 6 x 6 covariance
in that order (tx ty tz m, rx ry rz deg) from the reprojection Jacobian at the solution. Each
pixel residual is weighted by the tracking noise plus what the stereo depth noise of its point
(sigma_z = z^2 sigma_d / (b f)) moves it in B's image: without that term the covariance of a
forward translation would be several times too small, since depth noise, not pixel noise,
dominates stereo odometry beyond a few metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from . import odometry as od
from .stereo import (
    SgbmParams,
    StereoCalibration,
    depth_sigma,
    disparity,
    load_calibration,
    sigma_d_for,
)
from .transforms import invert

ORDER = ("tx", "ty", "tz", "rx", "ry", "rz")


@dataclass
class CameraMotion:
    """Camera B's pose in camera A's frame (``T_a_b``: X_A = T_a_b X_B) and how well it is known."""

    T_a_b: np.ndarray
    covariance: np.ndarray  # 6 x 6, ORDER; metres and degrees
    inliers: int
    matches: int
    points: int
    rms_px: float
    spread: float
    b_depth: bool  # B's right image was used
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def translation(self) -> np.ndarray:
        return self.T_a_b[:3, 3].copy()

    @property
    def rotation_deg(self) -> np.ndarray:
        """Rotation vector of B's orientation in A (axis times angle, degrees)."""
        return np.degrees(cv2.Rodrigues(np.ascontiguousarray(self.T_a_b[:3, :3]))[0].ravel())

    def as_dict(self) -> dict[str, Any]:
        """The YAML keys: tx ty tz (m), rx ry rz (deg), inliers, covariance (6 x 6), and the
        counts that say how much the estimate rests on."""
        t, r = self.translation, self.rotation_deg
        out: dict[str, Any] = {k: float(v) for k, v in zip(ORDER, [*t, *r], strict=True)}
        out.update({
            "inliers": int(self.inliers),
            "covariance": [[float(v) for v in row] for row in self.covariance],
            "covariance_order": list(ORDER),
            "units": "m, deg (rotation vector); camera axes x right, y down, z forward",
            "matches": int(self.matches), "points": int(self.points),
            "rms_px": float(self.rms_px), "spread": float(self.spread), "b_depth": bool(self.b_depth),
        })
        return out


def depth_frame(left: np.ndarray, right: np.ndarray | None, calib: StereoCalibration,
                sgbm: SgbmParams | None = None) -> tuple[od.DepthFrame, np.ndarray | None]:
    """A frame for :mod:`odometry` from the left image (and the pair's depth when ``right`` is
    given; all NaN otherwise), in the left camera's own frame (no rover: identity mount).
    Returns the frame and the per-pixel depth sigma (None without depth)."""
    w, h = calib.image_size
    if left.shape[:2] != (h, w):
        raise ValueError(f"image is {left.shape[1]}x{left.shape[0]} but the calibration is for {w}x{h}; "
                         "use the calibration made for these images (rvs-calib)")
    sigma = None
    if right is None:
        points = np.full((h, w, 3), np.nan, np.float32)
    else:
        if right.shape[:2] != left.shape[:2]:
            raise ValueError(f"left is {left.shape[1]}x{left.shape[0]}, right {right.shape[1]}x{right.shape[0]}: "
                             "a stereo pair has two images of one size")
        disp = disparity(left, right, calib, sgbm or SgbmParams())
        points = disp.points()
        sigma = disp.sigma_z()
    return od.DepthFrame(left, points, calib.K1, calib.D1, np.eye(4)), sigma


def covariance(motion: od.Motion, calib: StereoCalibration, params: od.OdometryParams,
               sigma_d: float) -> np.ndarray:
    """6 x 6 covariance of (tx ty tz rx ry rz) of T_a_b, from the weighted A -> B reprojection
    residuals of the inliers: (J^T J)^-1, inflated by the reduced chi-square when the
    residuals are larger than the noise model says (a model too optimistic never shrinks it)."""
    Xa, pb = motion.used["X_a"], motion.used["b"]
    frame = od.DepthFrame(np.zeros((1, 1), np.uint8), np.zeros((1, 1, 3)), calib.K1, calib.D1, np.eye(4))
    nb = od.normalised(frame, pb)
    focal = float(math.sqrt(calib.K1[0, 0] * calib.K1[1, 1]))
    T_ab = invert(motion.T_sensor)
    rvec0 = cv2.Rodrigues(np.ascontiguousarray(T_ab[:3, :3]))[0].ravel()
    x0 = np.concatenate([T_ab[:3, 3], np.degrees(rvec0)])
    sz = depth_sigma(Xa[:, 2], calib.baseline, focal, sigma_d)

    def project(x: np.ndarray, X: np.ndarray) -> np.ndarray:
        R = cv2.Rodrigues(np.radians(x[3:]).reshape(3, 1))[0]
        P = (X - x[:3]) @ R  # R^T (X - t): A's points in B's frame
        return P[:, :2] / P[:, 2:3]

    ray = Xa / np.linalg.norm(Xa, axis=1, keepdims=True)
    slide = np.linalg.norm(project(x0, Xa + ray * 0.01) - project(x0, Xa), axis=1) * 100.0 * sz * focal
    weight = 1.0 / np.sqrt(params.pixel_sigma ** 2 + slide ** 2)

    def residuals(x: np.ndarray) -> np.ndarray:
        return ((project(x, Xa) - nb) * focal * weight[:, None]).ravel()

    r0 = residuals(x0)
    steps = np.array([1e-4, 1e-4, 1e-4, 1e-3, 1e-3, 1e-3])
    J = np.empty((r0.size, 6))
    for i, hstep in enumerate(steps):
        dx = np.zeros(6)
        dx[i] = hstep
        J[:, i] = (residuals(x0 + dx) - residuals(x0 - dx)) / (2 * hstep)
    dof = max(1, r0.size - 6)
    chi2 = float(r0 @ r0) / dof
    cov = np.linalg.pinv(J.T @ J) * max(1.0, chi2)
    return (cov + cov.T) / 2


def stereo_odometry(left_a: np.ndarray, right_a: np.ndarray, left_b: np.ndarray, right_b: np.ndarray | None,
                    calib: Any, params: od.OdometryParams | None = None,
                    sgbm: SgbmParams | None = None) -> CameraMotion:
    """Camera B's motion in camera A's frame from A's pair and B's left image (or pair).

    :class:`prox_workflows.algorithms.odometry.OdometryError` (a ValueError carrying the counts)
    when too few points are found or agree on one motion; ValueError for images that do not
    fit the calibration."""
    cal = load_calibration(calib)
    p = params or od.OdometryParams()
    sg = sgbm or SgbmParams()
    a, _ = depth_frame(left_a, right_a, cal, sg)
    b, _ = depth_frame(left_b, right_b, cal, sg)
    if not np.isfinite(a.points[..., 2]).any():
        raise od.OdometryError("the stereo step found no depth in pair A (no texture, or a calibration that "
                               "does not belong to these images)", 0, 0, 0)
    motion = od.estimate_motion(a, b, p)
    cov = covariance(motion, cal, p, sigma_d_for(sg.scale))
    return CameraMotion(invert(motion.T_sensor), cov, motion.inliers, motion.matches, motion.points,
                        motion.rms_px, motion.spread, right_b is not None)


# -- texture and feature statistics (frames without depth or calibration) --------------------------


def _flat_frame(image: np.ndarray) -> od.DepthFrame:
    h, w = image.shape[:2]
    flat = np.zeros((h, w, 3), np.float32)
    flat[..., 2] = 1.0  # every pixel "has depth", so detect() looks everywhere
    return od.DepthFrame(image, flat, np.eye(3), np.zeros(5), np.eye(4))


def feature_stats(image_a: np.ndarray, image_b: np.ndarray | None = None,
                  params: od.OdometryParams | None = None, warp: tuple[float, float, float] = (6.0, 1.0, 1.03)
                  ) -> dict[str, Any]:
    """What the tracker has to work with in an image, with no depth needed.

    Interest points :func:`odometry.detect` finds (the whole image counted as usable), their
    spread (share of a 4 x 4 grid of cells holding one), the texture (median gradient, share of
    pixels with a usable gradient), the share of points on a hard shadow edge (corners that move
    with the sun and the rover, not with the ground), and how :func:`odometry.track` does under
    a known image motion ``warp`` (shift px, rotation deg, scale) of the same image: tracks kept
    after the forward-backward check and their median error against the known motion. With
    ``image_b``, also the tracks kept from A into B (frames of one drive; unrelated views keep
    almost none, which is the check working)."""
    p = params or od.OdometryParams()
    h, w = image_a.shape[:2]
    a = _flat_frame(image_a)
    pts = od.detect(a, p)
    gray = od.to_gray(image_a)
    g32 = gray.astype(np.float32)
    grad = np.hypot(cv2.Sobel(g32, cv2.CV_32F, 1, 0), cv2.Sobel(g32, cv2.CV_32F, 0, 1)) / 8.0
    # hard shadow: dark regions (a blurred image under a quarter of its median) and their rim
    dark = cv2.GaussianBlur(g32, (0, 0), 3) < 0.25 * float(np.median(g32))
    rim = cv2.dilate(dark.astype(np.uint8), np.ones((9, 9), np.uint8)) & ~cv2.erode(
        dark.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    ip = np.clip(np.rint(pts).astype(int), 0, [w - 1, h - 1]) if len(pts) else np.zeros((0, 2), int)
    on_rim = float(rim[ip[:, 1], ip[:, 0]].mean()) if len(pts) else 0.0
    shift, rot, scale = warp
    M = cv2.getRotationMatrix2D((w / 2, h / 2), rot, scale)
    M[:, 2] += shift
    warped = cv2.warpAffine(gray, M, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    q, ok = od.track(a, _flat_frame(warped), pts, p)
    true = pts @ M[:, :2].T + M[:, 2]
    inside = (true[:, 0] >= 0) & (true[:, 1] >= 0) & (true[:, 0] < w) & (true[:, 1] < h)
    ok &= inside
    err = np.linalg.norm(q[ok] - true[ok], axis=1)
    out: dict[str, Any] = {
        "size": f"{w}x{h}",
        "features": int(len(pts)),
        "spread": od._coverage(pts, (h, w)),
        "gradient": float(np.median(grad)),
        "textured": float((grad > 2.0).mean()),
        "shadow_edge": on_rim,
        "warp_kept": float(ok.sum() / max(1, inside.sum())),
        "warp_err_px": float(np.median(err)) if len(err) else float("nan"),
    }
    if image_b is not None:
        qb, okb = od.track(a, _flat_frame(image_b), pts, p)
        out["a_to_b_kept"] = int(okb.sum())
        out["a_to_b_spread"] = od._coverage(qb[okb], (h, w))
    return out
