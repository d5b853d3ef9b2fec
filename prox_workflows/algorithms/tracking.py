"""Target detection and tracking (track3d-detect / track3d-start, seed 000 appendix C).

Two detectors, both on arrays:

- :func:`detect_standing` finds astronaut-sized objects in an organised ToF point image: pixels
  standing above the ground (the per-cell lowest points, opened so that a body cannot raise
  them, with a RANSAC plane where only floating returns were seen) and bright enough for their
  range are split into smooth surfaces at range discontinuities in the image, and a surface
  counts when it stands on the ground and its height and its torso's width across the line of
  sight match the size prior (1.8 m tall, 0.5 m wide by default). Its position is the axis of
  the body: a circle fitted to the torso in plan view, since a sensor sees only the near half of
  a round body and the plain centroid would sit some 0.17 m too close. The image, not 3-D
  proximity, separates objects because the SR4000's phase wrap puts far slopes beyond 5 m as
  faint sheets floating right beside a body at its range.
- :func:`detect_markers` finds ArUco markers (6x6 dictionary) in both images of a stereo pair
  and triangulates their corners, so the marker's 3-D pose needs no size prior.

Positions are the target's *foot point*: its vertical axis where it meets the ground, in the
frame the points were given in (the caller passes global points).

:class:`Tracker` is the constant-velocity (alpha-beta) filter the tracking loop runs: predict,
gate the detections to a window around the prediction, update, and count misses into *lost*.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from rvs_params.deferred import deferred

ndimage = deferred("scipy.ndimage")


@dataclass(frozen=True)
class SizePrior:
    """What an astronaut looks like to the detector (metres)."""

    height: float = 1.8
    width: float = 0.5
    height_tolerance: float = 0.45  # accepted: height +- this
    width_range: tuple[float, float] = (0.2, 0.9)  # apparent width across the line of sight
    min_height: float = 0.25  # a point stands on the ground when this far above it
    foot_height: float = 0.6  # a standing object has points this low (a floating sheet does not)
    reflectivity: float = 1.0  # at least this times the ground's amplitude x range^2 (see detect_standing)
    torso: tuple[float, float] = (0.3, 0.75)  # share of the height where width and axis are measured
    min_points: int = 25
    cell: float = 0.1  # clustering grid
    ground_cell: float = 0.2  # grid of the ground surface
    ground_window: float = 1.4  # opening window: wider than any body, so a body never lifts the ground
    ground_tolerance: float = 0.3  # the local ground may leave the fitted plane by this much


@dataclass
class Detection:
    """One object matching the prior (positions in the frame of the input points)."""

    x: float
    y: float
    z: float  # ground under the axis
    height: float  # top above the ground
    width: float  # extent across the line of sight
    radius: float  # fitted body radius
    points: int
    score: float = 0.0  # 0 perfect match of the prior; larger is worse
    marker_id: int | None = None  # ArUco id when a marker was seen


def _nan_filter(a: np.ndarray, k: int, op: str) -> np.ndarray:
    """Min (erode) or max (dilate) filter over a k x k window that ignores NaN."""
    kernel = np.ones((k, k), np.uint8)
    if op == "min":
        out = cv2.erode(np.where(np.isfinite(a), a, np.inf).astype(np.float32), kernel,
                        borderType=cv2.BORDER_CONSTANT, borderValue=np.inf)
        return np.where(np.isinf(out), np.nan, out)
    out = cv2.dilate(np.where(np.isfinite(a), a, -np.inf).astype(np.float32), kernel,
                     borderType=cv2.BORDER_CONSTANT, borderValue=-np.inf)
    return np.where(np.isinf(out), np.nan, out)


def point_image(xyz_cam: np.ndarray, T_frame_cam: np.ndarray, max_range: float = 4.8,
                amplitude: np.ndarray | None = None, min_reflectivity: float = 0.0) -> np.ndarray:
    """A ToF XYZ image (camera frame, -1/NaN undefined) moved into another frame, kept
    organised (H x W x 3, NaN where undefined) so neighbours in the image stay neighbours.

    ``min_reflectivity`` drops returns whose amplitude x range^2 is below that share of the
    frame's median (phase-wrapped far surfaces read close but faint), as the DEM views do.
    """
    xyz = np.asarray(xyz_cam, dtype=np.float64)
    rng = np.linalg.norm(xyz, axis=2)
    ok = np.isfinite(rng) & (xyz[..., 2] > 0) & (rng <= max_range)
    if amplitude is not None and min_reflectivity > 0 and ok.any():
        refl = np.asarray(amplitude, dtype=np.float64) * rng ** 2
        ok &= refl >= min_reflectivity * float(np.median(refl[ok]))
    out = xyz @ T_frame_cam[:3, :3].T + T_frame_cam[:3, 3]
    out[~ok] = np.nan
    return out


def ground_plane(cells: np.ndarray, rng: np.random.Generator | None = None, iterations: int = 64,
                 tolerance: float = 0.08) -> np.ndarray | None:
    """z = a x + b y + c through the most per-cell minima (RANSAC, then least squares on the
    inliers); None when there are too few cells."""
    if len(cells) < 3:
        return None
    rng = rng or np.random.default_rng(0)
    A = np.column_stack([cells[:, 0], cells[:, 1], np.ones(len(cells))])
    best, best_n = None, -1
    for _ in range(iterations):
        idx = rng.choice(len(cells), 3, replace=False)
        try:
            coef = np.linalg.solve(A[idx], cells[idx, 2])
        except np.linalg.LinAlgError:
            continue
        if math.hypot(coef[0], coef[1]) > 0.6:  # steeper than ~30 degrees: not the ground
            continue
        n = int((np.abs(A @ coef - cells[:, 2]) < tolerance).sum())
        if n > best_n:
            best, best_n = coef, n
    if best is None:
        return None
    inl = np.abs(A @ best - cells[:, 2]) < tolerance
    coef, *_ = np.linalg.lstsq(A[inl], cells[inl, 2], rcond=None)
    return coef


def ground_under(points: np.ndarray, prior: SizePrior = SizePrior()) -> np.ndarray:
    """Ground height under each point.

    The lowest point of each ``ground_cell`` cell, opened (min then max filter over
    ``ground_window``) so that anything narrower than that, a body, is cut away; where that local
    surface is missing or strays more than ``ground_tolerance`` from the ground plane (cells that
    hold only floating returns, such as phase-wrapped far slopes, have no ground to see), the
    plane fitted by RANSAC to the cell minima stands in.
    """
    p = np.asarray(points, dtype=np.float64)
    c = prior.ground_cell
    ij = np.floor(p[:, :2] / c).astype(np.int64)
    lo = ij.min(axis=0)
    ij -= lo
    shape = tuple(int(v) + 1 for v in ij.max(axis=0))
    zmin = np.full(shape, np.inf)
    np.minimum.at(zmin, (ij[:, 0], ij[:, 1]), p[:, 2])
    zmin[np.isinf(zmin)] = np.nan
    k = max(3, int(round(prior.ground_window / c)) | 1)
    local = _nan_filter(_nan_filter(zmin, k, "min"), k, "max")[ij[:, 0], ij[:, 1]]
    have = np.isfinite(zmin)
    ci, cj = np.nonzero(have)
    cells = np.column_stack([(ci + lo[0] + 0.5) * c, (cj + lo[1] + 0.5) * c, zmin[have]])
    coef = ground_plane(cells)
    if coef is None:
        return local
    plane = coef[0] * p[:, 0] + coef[1] * p[:, 1] + coef[2]
    bad = ~np.isfinite(local) | (np.abs(local - plane) > prior.ground_tolerance)
    return np.where(bad, plane, local)


def fit_circle(xy: np.ndarray, toward: np.ndarray | None = None, radius_range: tuple[float, float] = (0.05, 0.6),
               fallback: float = 0.22) -> tuple[float, float, float]:
    """Centre and radius of the circle through plan-view points of a round body's visible side.

    Algebraic (Kasa) fit refined by Gauss-Newton on the geometric distances. A visible half-arc
    with centimetres of noise can bend the free fit far off; when its radius leaves
    ``radius_range`` the radius is held at ``fallback`` and only the centre is fitted, started
    behind the centroid, away from ``toward`` (the sensor), where a body's axis lies.
    """
    xy = np.asarray(xy, dtype=np.float64)
    m = xy.mean(axis=0)
    d = xy - m
    lo, hi = radius_range
    A = np.column_stack([d, np.ones(len(d))])
    b = (d ** 2).sum(axis=1)
    try:
        sol, *_ = np.linalg.lstsq(A, b, rcond=None)
        c = sol[:2] / 2
        r = math.sqrt(max(sol[2] + c @ c, 1e-12))
    except np.linalg.LinAlgError:
        c, r = np.zeros(2), 0.0
    if lo <= r <= hi:
        c, r = _refine(d, c, r, fixed=False)
        if lo <= r <= hi:
            return float(c[0] + m[0]), float(c[1] + m[1]), float(r)
    away = np.zeros(2)
    if toward is not None:
        v = m - np.asarray(toward, dtype=np.float64)[:2]
        away = v / max(np.hypot(*v), 1e-9)
    c0 = away * fallback * math.pi / 4  # the visible half's mean sits r*pi/4 in front of the axis
    c, r = _refine(d, c0, fallback, fixed=True)
    return float(c[0] + m[0]), float(c[1] + m[1]), float(r)


def _refine(d: np.ndarray, c: np.ndarray, r: float, fixed: bool, iterations: int = 10
            ) -> tuple[np.ndarray, float]:
    c = np.array(c, dtype=np.float64)
    for _ in range(iterations):
        v = d - c
        dist = np.maximum(np.hypot(v[:, 0], v[:, 1]), 1e-9)
        res = dist - r
        J = -v / dist[:, None]
        if not fixed:
            J = np.column_stack([J, -np.ones(len(d))])
        step, *_ = np.linalg.lstsq(J, -res, rcond=None)
        c = c + step[:2]
        if not fixed:
            r = r + float(step[2])
        if np.abs(step).max() < 1e-5:
            break
    return c, r


def segment_image(points: np.ndarray, sensor: np.ndarray, mask: np.ndarray, jump: float = 0.12,
                  jump_per_m: float = 0.03) -> tuple[np.ndarray, int]:
    """Label the ``mask`` pixels of an organised point image into smooth surfaces.

    Neighbouring pixels belong together unless their ranges differ by more than ``jump`` +
    ``jump_per_m`` x range: a body's silhouette is a range discontinuity, so a body is separated
    from what lies beside it in the image even where the two touch in space (phase-wrapped far
    slopes, whose returns float in the air at the body's range, or mixed pixels at its edge).
    """
    rng = np.linalg.norm(points - np.asarray(sensor, dtype=np.float64), axis=2)
    rng = np.where(mask, rng, np.nan)
    tol = jump + jump_per_m * np.nan_to_num(rng, nan=0.0)
    edge = np.zeros(mask.shape, bool)
    with np.errstate(invalid="ignore"):
        dv = np.abs(np.diff(rng, axis=0)) > np.minimum(tol[1:], tol[:-1])
        dh = np.abs(np.diff(rng, axis=1)) > np.minimum(tol[:, 1:], tol[:, :-1])
    # The nearer pixel of a jump keeps its place; the farther one is cut, which separates them.
    far_v = dv & (rng[1:] > rng[:-1])
    edge[1:] |= far_v
    edge[:-1] |= dv & ~far_v
    far_h = dh & (rng[:, 1:] > rng[:, :-1])
    edge[:, 1:] |= far_h
    edge[:, :-1] |= dh & ~far_h
    labels, n = ndimage.label(mask & ~edge, structure=np.ones((3, 3), bool))
    return labels, n


def detect_standing(points: np.ndarray, sensor: np.ndarray, prior: SizePrior = SizePrior(),
                    amplitude: np.ndarray | None = None, ground: np.ndarray | None = None) -> list[Detection]:
    """Objects standing on the ground that match the size prior, best first.

    ``points`` an organised H x W x 3 image of points (z up, NaN where undefined) as a ToF camera
    gives them, moved into the output frame; ``sensor`` the sensor's position in that frame (for
    ranges and the line of sight); ``amplitude`` the ToF amplitude image, with which pixels
    standing above the ground must look at least ``prior.reflectivity`` times as bright as the
    ground (amplitude x range^2): a suit is white, while phase-wrapped returns of far surfaces,
    which float in the air at a wrong range, are faint for the range they claim. ``ground`` the
    ground height under each pixel if known (else :func:`ground_under`).
    """
    img = np.asarray(points, dtype=np.float64)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"detect_standing wants an H x W x 3 point image, not {img.shape}")
    defined = np.all(np.isfinite(img), axis=2)
    if defined.sum() < prior.min_points:
        return []
    h = np.full(defined.shape, np.nan)
    g = np.full(defined.shape, np.nan)
    g[defined] = ground_under(img[defined], prior) if ground is None else np.asarray(ground)[defined]
    h[defined] = img[defined][:, 2] - g[defined]
    with np.errstate(invalid="ignore"):
        up = defined & (h > prior.min_height)
    if amplitude is not None and prior.reflectivity > 0:
        refl = np.asarray(amplitude, dtype=np.float64) * np.sum((img - np.asarray(sensor, float)) ** 2, axis=2)
        low = defined & ~up
        if low.any():
            up &= refl >= prior.reflectivity * float(np.median(refl[low]))
    if up.sum() < prior.min_points:
        return []
    labels, n = segment_image(img, sensor, up)
    sizes = np.bincount(labels.ravel(), minlength=n + 1)
    out: list[Detection] = []
    for k in np.flatnonzero(sizes >= prior.min_points):
        if k == 0:
            continue
        sel = labels == k
        pts, hh = img[sel], h[sel]
        top = float(np.percentile(hh, 99))
        if abs(top - prior.height) > prior.height_tolerance or hh.min() > prior.foot_height:
            continue  # too short or too tall, or floating (not standing on the ground)
        # Width and axis from the torso only: at the feet a body may merge with a rock or a box
        # it stands by, and the head is narrower.
        body = (hh > prior.torso[0] * prior.height) & (hh < prior.torso[1] * prior.height)
        if body.sum() < prior.min_points // 2:
            continue
        torso = pts[body, :2]
        centroid = np.median(torso, axis=0)
        los = centroid - np.asarray(sensor, dtype=np.float64)[:2]
        los /= max(np.hypot(*los), 1e-9)
        across = (torso - centroid) @ np.array([-los[1], los[0]])
        width = float(np.percentile(across, 98) - np.percentile(across, 2))
        if not prior.width_range[0] <= width <= prior.width_range[1]:
            continue
        # Fit the torso's core: what lies within a body width of its median (a stray sheet of
        # returns that joined the segment lies to one side and would drag the fit).
        core = np.hypot(*(torso - centroid).T) <= 0.8 * prior.width
        if core.sum() < prior.min_points // 2:
            continue
        torso = torso[core]
        cx, cy, r = fit_circle(torso, toward=np.asarray(sensor)[:2], radius_range=(0.25 * prior.width,
                                                                                   0.75 * prior.width),
                               fallback=max(width, 0.5 * prior.width) / 2)
        # The ground height at the foot: the median of the ground returns around it (the
        # per-cell minimum that found the ground reads low by about two noise sigmas).
        near = defined & (h < 0.4 * prior.min_height) & \
            (np.hypot(img[..., 0] - cx, img[..., 1] - cy) < prior.ground_window / 2)
        gz = float(np.median(img[..., 2][near])) if near.sum() >= 10 else float(np.median(g[sel]))
        score = abs(top - prior.height) / prior.height + abs(width - prior.width) / prior.width
        out.append(Detection(cx, cy, gz, top, width, r, int(sel.sum()), score))
    out.sort(key=lambda d: d.score)
    return out


def merge_detections(detections: list[Detection], radius: float = 0.5) -> list[Detection]:
    """One detection per object when overlapping views saw it twice: the best-scored one."""
    out: list[Detection] = []
    for d in sorted(detections, key=lambda d: d.score):
        if all(math.hypot(d.x - o.x, d.y - o.y) > radius for o in out):
            out.append(d)
    return out


# ------------------------------------------------------------------ ArUco markers in stereo


@dataclass
class MarkerSighting:
    """One marker seen in both images: its id, 3-D corners and face centre and normal (left
    camera frame, metres), and the rectified pixel corners in the left image."""

    marker_id: int
    corners: np.ndarray  # 4 x 3
    centre: np.ndarray  # 3
    normal: np.ndarray  # 3, out of the marker face, towards the camera
    pixels: np.ndarray  # 4 x 2


def aruco_detector() -> cv2.aruco.ArucoDetector:
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250)
    return cv2.aruco.ArucoDetector(dictionary, cv2.aruco.DetectorParameters())


def detect_markers(left: np.ndarray, right: np.ndarray, K1: np.ndarray, D1: np.ndarray, K2: np.ndarray,
                   D2: np.ndarray, R: np.ndarray, T: np.ndarray, marker_id: int | None = None,
                   max_error_px: float = 3.0) -> list[MarkerSighting]:
    """ArUco 6x6 markers found in both images of a stereo pair, triangulated.

    ``R``, ``T`` as cv2.stereoCalibrate gives them (X_right = R X_left + T). Corners are found in
    the raw images and undistorted as points, so no image is resampled.
    """
    det = aruco_detector()
    found: list[list[tuple[int, np.ndarray]]] = []
    for img in (left, right):
        gray = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
        if gray.dtype != np.uint8:
            gray = cv2.normalize(gray, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
        corners, ids, _ = det.detectMarkers(gray)
        found.append([] if ids is None else
                     [(int(i), c.reshape(4, 2)) for i, c in zip(ids.ravel(), corners, strict=True)])
    P1 = np.hstack([np.eye(3), np.zeros((3, 1))])
    P2 = np.hstack([np.asarray(R, float), np.asarray(T, float).reshape(3, 1)])
    out: list[MarkerSighting] = []
    used: set[int] = set()
    for mid, cl in found[0]:
        if marker_id is not None and mid != marker_id:
            continue
        ul = cv2.undistortPoints(cl.reshape(-1, 1, 2).astype(np.float64), K1, D1).reshape(-1, 2)
        best: tuple[float, int, np.ndarray] | None = None
        # One id may show on several faces of a marker box: pair each left sighting with the
        # right one whose triangulation reprojects best (the epipolar match), not the first.
        for j, (rid, cr) in enumerate(found[1]):
            if rid != mid or j in used:
                continue
            ur = cv2.undistortPoints(cr.reshape(-1, 1, 2).astype(np.float64), K2, D2).reshape(-1, 2)
            X = cv2.triangulatePoints(P1, P2, ul.T, ur.T)
            pts = (X[:3] / X[3]).T
            if not np.all(np.isfinite(pts)) or np.any(pts[:, 2] <= 0):
                continue
            p2 = pts @ P2[:, :3].T + P2[:, 3]
            if np.any(p2[:, 2] <= 0):
                continue
            err = float(np.abs(pts[:, :2] / pts[:, 2:] - ul).max() + np.abs(p2[:, :2] / p2[:, 2:] - ur).max())
            err *= float(K1[0, 0])  # in pixels
            if err <= max_error_px and (best is None or err < best[0]):
                best = (err, j, pts)
        if best is None:
            continue
        used.add(best[1])
        pts = best[2]
        centre = pts.mean(axis=0)
        normal = np.cross(pts[1] - pts[0], pts[3] - pts[0])
        normal /= max(np.linalg.norm(normal), 1e-12)
        if normal @ centre > 0:  # make it face the camera
            normal = -normal
        out.append(MarkerSighting(mid, pts, centre, normal, cl))
    return out


def marker_box_foot(centre: np.ndarray, normal: np.ndarray, box: float) -> np.ndarray:
    """Foot point of a cube of side ``box`` carrying the marker on a vertical face (z up):
    half a side behind the face centre, and half a side down."""
    n = np.array([normal[0], normal[1], 0.0])
    n /= max(np.linalg.norm(n), 1e-12)
    axis = np.asarray(centre, float) - n * box / 2
    return np.array([axis[0], axis[1], axis[2] - box / 2])


# ------------------------------------------------------------------ tracking filter


@dataclass
class Tracker:
    """Constant-velocity alpha-beta filter over the target's foot point (x, y; z follows)."""

    alpha: float = 0.85
    beta: float = 0.5
    gate: float = 1.0  # m: detections farther than this (plus speed x dt) from the prediction are ignored
    lost_after: int = 2  # misses in a row before the target counts as lost
    max_speed: float = 3.0
    position: np.ndarray | None = None  # x, y, z
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(2))
    time: float | None = None
    misses: int = 0
    lost: bool = True

    def reset(self, position: np.ndarray | None, t: float | None = None) -> None:
        self.position = None if position is None else np.asarray(position, dtype=np.float64).copy()
        self.velocity = np.zeros(2)
        self.time = t
        self.misses = 0
        self.lost = position is None

    def predict(self, t: float) -> np.ndarray | None:
        """Where the target should be at ``t`` (constant velocity; it stops extrapolating once
        lost, so a search stays where the target was last seen)."""
        if self.position is None:
            return None
        if self.lost or self.time is None:
            return self.position.copy()
        out = self.position.copy()
        out[:2] += self.velocity * max(0.0, t - self.time)
        return out

    def window(self, t: float) -> float:
        """Gate radius around the prediction at ``t``."""
        if self.position is None or self.lost:
            return math.inf
        dt = 0.0 if self.time is None else max(0.0, t - self.time)
        return self.gate + min(float(np.hypot(*self.velocity)), self.max_speed) * dt * 0.5

    def choose(self, detections: list[Detection], t: float) -> Detection | None:
        """The detection the track continues with: nearest to the prediction inside the gate
        (any, best-scored, while lost)."""
        pred = self.predict(t)
        if not detections:
            return None
        if pred is None or self.lost:
            return detections[0]
        d = [math.hypot(x.x - pred[0], x.y - pred[1]) for x in detections]
        i = int(np.argmin(d))
        return detections[i] if d[i] <= self.window(t) else None

    def update(self, detection: Detection | None, t: float) -> bool:
        """Fold in one cycle's detection (None: a miss); returns True when the target was just
        re-acquired after being lost."""
        if detection is None:
            self.misses += 1
            if self.misses >= self.lost_after:
                self.lost = True
                self.velocity = np.zeros(2)
            return False
        z = np.array([detection.x, detection.y, detection.z])
        reacquired = self.lost
        if self.position is None or self.lost or self.time is None:
            self.position, self.velocity = z, np.zeros(2)
        else:
            dt = max(t - self.time, 1e-3)
            pred = self.position[:2] + self.velocity * dt
            r = z[:2] - pred
            self.position = np.array([*(pred + self.alpha * r), z[2]])
            v = self.velocity + self.beta * r / dt
            s = float(np.hypot(*v))
            self.velocity = v if s <= self.max_speed else v * self.max_speed / s
        self.time = t
        self.misses = 0
        self.lost = False
        return reacquired
