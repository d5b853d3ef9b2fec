"""Visual odometry (seed 000 sect. 3.1.5, seed 003 sect. 4.4): the rover's motion between two
acquisitions from interest points tracked across them and the depth the sensor measured there.

Per pair of acquisitions A (earlier) and B (later), both looking roughly the same way:

1. interest points in A's image (Shi-Tomasi by default, or Harris as the thesis names it),
   only where A has a depth and the point is not on the rover's own body;
2. a coarse motion: the points tracked into B with pyramidal Lucas-Kanade, kept when tracking
   back lands on the start (forward-backward check), or, when that finds too little, ORB
   descriptor matches (any scale, any distance), or a motion the caller expects;
3. twice: B's image warped into A's view with the current motion (through A's depth), and A's
   points tracked into it; the patches then differ only by what the motion got wrong, not by
   the change of scale and perspective a metre of driving makes near the rover;
4. the tracked points lifted to 3D (bilinear in the point image, dropped at depth edges) and the
   motion found by PnP inside RANSAC (A's 3D points, B's pixels): pixel residuals treat near
   and far points alike, while a 3D-3D threshold would have to grow with the square of range;
5. refined by least squares over the inliers in both directions (A's points into B's image and
   B's points into A's), each residual weighted by what the depth noise of its point moves it in
   the image, so far points (noisy depth) do not pull the translation;
6. expressed as the rover's motion with the two sensor poses on the rover (mount calibration at
   the PTU angles of each acquisition): ``T_roverA_roverB``.

How well it holds on each sensor is measured by tests/prox/test_odometry.py,
tests/server/commands/test_orient.py and ``tools.bench.odometry`` (docs/BENCHMARKS.md): the
stereo pairs far better than the ToF camera, whose small image and own moving light lose track
over longer steps.

Everything is arrays in, arrays out; the server grabs and passes the frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from .transforms import invert

DETECTORS = ("shi-tomasi", "harris")
TOF_GREY_PER_LOG = 200.0  # grey levels per unit of log amplitude: +-0.64 (a factor 1.9) spans 0..255


class OdometryError(ValueError):
    """Too little in common between the two acquisitions to trust a motion; carries the counts."""

    def __init__(self, message: str, points: int, matches: int, inliers: int) -> None:
        super().__init__(message)
        self.points = points
        self.matches = matches
        self.inliers = inliers


@dataclass
class DepthFrame:
    """One acquisition: an image to find and track points in, and the 3D point of each pixel.

    ``points`` is H x W x 3 in the sensor's optical frame (x right, y down, z forward), NaN or
    z <= 0 where undefined; ``image`` is in the same (raw, distorted) pixel geometry as
    ``points``, described by ``K`` and ``dist``. ``T_rover_sensor`` is the sensor's pose on the
    rover when the frame was taken; ``mask`` (optional, H x W bool) marks usable pixels.
    """

    image: np.ndarray
    points: np.ndarray
    K: np.ndarray
    dist: np.ndarray
    T_rover_sensor: np.ndarray
    mask: np.ndarray | None = None
    # 8-bit image for the detector and tracker, made once (a frame serves as B, then as A)
    gray: np.ndarray | None = field(default=None, repr=False)


@dataclass
class OdometryParams:
    """Detector, tracker and estimator settings; the defaults suit 640 x 480 stereo and the
    176 x 144 ToF camera alike (windows in pixels of the image at hand)."""

    detector: str = "shi-tomasi"
    max_points: int = 1200
    quality: float = 0.005  # of the strongest corner response
    min_distance: float = 6.0  # px between interest points
    block_size: int = 5
    harris_k: float = 0.04
    window: int = 11  # LK window side, px: small, so a patch stays planar and rigid
    levels: int = 4  # LK pyramid levels above the image
    fb_max: float = 0.5  # px: forward-backward disagreement that rejects a track
    min_range: float = 0.3  # m
    max_range: float = 15.0  # m: farther points carry little but noise
    edge_spread: float = 0.03  # relative range spread of the 4 neighbours that marks a depth edge
    reprojection: float = 1.5  # px: PnP RANSAC inlier threshold
    ransac_iterations: int = 3000
    pixel_sigma: float = 0.3  # px: tracking noise
    depth_sigma: float = 0.01  # relative depth noise at 1 m ...
    depth_sigma_growth: float = 1.0  # ... growing as range^growth (stereo: 1 -> sigma_z ~ z^2)
    guided: bool = True  # second tracking pass started from the first pass's motion
    warp: bool = True  # guided pass tracks against the new image warped into the old view
    orb_features: int = 1500  # descriptor matching when blind tracking finds too little
    orb_ratio: float = 0.8
    min_matches: int = 20
    min_inliers: int = 12
    seed: int = 0  # OpenCV's RANSAC sampling, for repeatable results

    def check(self) -> None:
        if self.detector not in DETECTORS:
            raise ValueError(f"detector {self.detector!r} is not one of {', '.join(DETECTORS)}")
        if self.window < 3 or self.window % 2 == 0:
            raise ValueError("window must be odd and >= 3")
        if not 0 < self.min_range < self.max_range:
            raise ValueError("need 0 < min_range < max_range")


@dataclass
class Motion:
    """The rover's motion from acquisition A to B, expressed in A's rover frame.

    ``T`` (4 x 4) is rover B's pose in rover A's frame; ``T_sensor`` is X_B = T_sensor X_A for a
    point in the two sensor frames. dx forward, dy left, dz up (m); droll, dpitch, dyaw (deg,
    yaw counter-clockwise).
    """

    T: np.ndarray
    T_sensor: np.ndarray
    points: int
    matches: int
    inliers: int
    rms_px: float
    spread: float  # share of the image (4 x 4 cells) the inliers cover
    used: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    @property
    def dx(self) -> float:
        return float(self.T[0, 3])

    @property
    def dy(self) -> float:
        return float(self.T[1, 3])

    @property
    def dz(self) -> float:
        return float(self.T[2, 3])

    @property
    def dyaw(self) -> float:
        return math.degrees(math.atan2(self.T[1, 0], self.T[0, 0]))

    @property
    def dpitch(self) -> float:
        return math.degrees(math.asin(float(np.clip(-self.T[2, 0], -1.0, 1.0))))

    @property
    def droll(self) -> float:
        return math.degrees(math.atan2(self.T[2, 1], self.T[2, 2]))

    def as_dict(self) -> dict[str, Any]:
        return {"dx": self.dx, "dy": self.dy, "dz": self.dz, "droll": self.droll, "dpitch": self.dpitch,
                "dyaw": self.dyaw, "points": self.points, "matches": self.matches, "inliers": self.inliers,
                "rms_px": self.rms_px, "spread": self.spread}


# -- helpers ----------------------------------------------------------------------------------------


def to_gray(image: np.ndarray) -> np.ndarray:
    """8-bit grey for the detector and the tracker. Camera images (8-bit) are used as they are.
    ToF amplitudes (float) fall with the square of the range and the incidence angle, so the
    same ground gets brighter as the rover approaches it: their logarithm minus its local mean
    (a high-pass over ~1/10 of the image) keeps the albedo texture and drops the falloff."""
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY if img.shape[2] == 3 else cv2.COLOR_RGBA2GRAY)
    if img.dtype == np.uint8:
        return img
    data = img.astype(np.float32)
    ok = np.isfinite(data) & (data > 0)
    if not ok.any():
        return np.zeros(data.shape, np.uint8)
    log = np.log(np.where(ok, data, np.median(data[ok])))
    sigma = max(data.shape) / 10.0
    weight = cv2.GaussianBlur(ok.astype(np.float32), (0, 0), sigma)
    mean = cv2.GaussianBlur(np.where(ok, log, 0.0).astype(np.float32), (0, 0), sigma) / np.maximum(weight, 1e-3)
    high = np.where(ok, log - mean, 0.0)
    # a fixed scale (log units are relative contrast already): two frames must map the same
    # surface to the same grey, or the tracker sees a change of gain a percentile stretch
    # would make whenever a few dark far pixels come or go
    return np.clip(128.0 + high * TOF_GREY_PER_LOG, 0, 255).astype(np.uint8)


def usable(frame: DepthFrame, params: OdometryParams) -> np.ndarray:
    """Pixels with a depth in range (and inside the frame's own mask)."""
    pts = np.asarray(frame.points, dtype=np.float32)
    z = pts[..., 2]
    rng = np.linalg.norm(np.nan_to_num(pts, nan=0.0), axis=2)
    ok = np.isfinite(z) & (z > 0) & (rng >= params.min_range) & (rng <= params.max_range)
    if frame.mask is not None:
        ok &= frame.mask
    return ok


def detect(frame: DepthFrame, params: OdometryParams) -> np.ndarray:
    """N x 2 float32 interest points (x, y) where the frame has a usable depth."""
    params.check()
    gray = _gray(frame)
    mask = usable(frame, params)
    # keep the corner window off the depth border, where lifting would fail anyway
    mask = cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8))
    pts = cv2.goodFeaturesToTrack(
        gray, maxCorners=params.max_points, qualityLevel=params.quality, minDistance=params.min_distance,
        mask=mask, blockSize=params.block_size, useHarrisDetector=params.detector == "harris", k=params.harris_k,
    )
    if pts is None:
        return np.zeros((0, 2), np.float32)
    pts = pts.reshape(-1, 2)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)
    cv2.cornerSubPix(gray, pts, (3, 3), (-1, -1), criteria)
    return pts.astype(np.float32)


def _gray(frame: DepthFrame) -> np.ndarray:
    if frame.gray is None:
        frame.gray = to_gray(frame.image)
    return frame.gray


def track(a: DepthFrame, b: DepthFrame, pts: np.ndarray, params: OdometryParams,
          guess: np.ndarray | None = None, levels: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Where ``pts`` of A are in B (N x 2) and which tracks passed the forward-backward check."""
    if len(pts) == 0:
        return np.zeros((0, 2), np.float32), np.zeros(0, bool)
    ga, gb = _gray(a), _gray(b)
    win = (params.window, params.window)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 40, 0.01)
    p0 = pts.reshape(-1, 1, 2).astype(np.float32)
    flags = 0
    p1 = None
    if guess is not None:
        p1 = guess.reshape(-1, 1, 2).astype(np.float32).copy()
        flags = cv2.OPTFLOW_USE_INITIAL_FLOW
    lv = params.levels if levels is None else levels
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(ga, gb, p0, p1, winSize=win, maxLevel=lv,
                                          criteria=criteria, flags=flags)
    back = p0.copy()
    p0b, st2, _ = cv2.calcOpticalFlowPyrLK(gb, ga, p1, back, winSize=win, maxLevel=lv,
                                           criteria=criteria, flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
    fb = np.linalg.norm((p0b - p0).reshape(-1, 2), axis=1)
    h, w = gb.shape[:2]
    q = p1.reshape(-1, 2)
    inside = (q[:, 0] >= 0) & (q[:, 1] >= 0) & (q[:, 0] <= w - 1) & (q[:, 1] <= h - 1)
    ok = (st1.ravel() == 1) & (st2.ravel() == 1) & (fb <= params.fb_max) & inside
    return q.astype(np.float32), ok


def lift(frame: DepthFrame, pts: np.ndarray, params: OdometryParams) -> np.ndarray:
    """N x 3 sensor-frame points at sub-pixel ``pts``: bilinear between the four neighbouring
    pixels, NaN where one of them is undefined or their ranges differ by more than
    ``edge_spread`` of the range (a depth edge, where interpolating makes a flying point)."""
    out = np.full((len(pts), 3), np.nan)
    if len(pts) == 0:
        return out
    img = np.asarray(frame.points, dtype=np.float64).copy()
    img[~usable(frame, params)] = np.nan
    h, w = img.shape[:2]
    c = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
    x0 = np.floor(c[:, 0]).astype(int)
    y0 = np.floor(c[:, 1]).astype(int)
    inside = (x0 >= 0) & (y0 >= 0) & (x0 + 1 < w) & (y0 + 1 < h)
    x0, y0 = np.clip(x0, 0, w - 2), np.clip(y0, 0, h - 2)
    fx = (c[:, 0] - x0)[:, None]
    fy = (c[:, 1] - y0)[:, None]
    n00, n10, n01, n11 = img[y0, x0], img[y0, x0 + 1], img[y0 + 1, x0], img[y0 + 1, x0 + 1]
    bil = n00 * (1 - fx) * (1 - fy) + n10 * fx * (1 - fy) + n01 * (1 - fx) * fy + n11 * fx * fy
    r4 = np.linalg.norm(np.stack([n00, n10, n01, n11], axis=1), axis=2)  # NaN if any is undefined
    rng = np.linalg.norm(bil, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        spread = (r4.max(axis=1) - r4.min(axis=1)) / rng
    keep = inside & np.isfinite(bil).all(axis=1) & (spread <= params.edge_spread)
    out[keep] = bil[keep]
    return out


def normalised(frame: DepthFrame, pts: np.ndarray) -> np.ndarray:
    """Undistorted normalised image coordinates (N x 2) of raw pixel positions."""
    if len(pts) == 0:
        return np.zeros((0, 2))
    und = cv2.undistortPoints(np.asarray(pts, np.float64).reshape(-1, 1, 2), np.asarray(frame.K, np.float64),
                              np.asarray(frame.dist, np.float64))
    return und.reshape(-1, 2)


def _rodrigues(rvec: np.ndarray) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(rvec, np.float64).reshape(3, 1))[0]


def _pose_T(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = _rodrigues(rvec)
    T[:3, 3] = np.asarray(tvec, np.float64).ravel()
    return T


def _coverage(pts: np.ndarray, shape: tuple[int, ...], cells: int = 4) -> float:
    if len(pts) == 0:
        return 0.0
    h, w = shape[:2]
    cx = np.clip((pts[:, 0] / w * cells).astype(int), 0, cells - 1)
    cy = np.clip((pts[:, 1] / h * cells).astype(int), 0, cells - 1)
    return len(set(zip(cx.tolist(), cy.tolist(), strict=True))) / float(cells * cells)


# -- estimation ------------------------------------------------------------------------------------


def _depth_sigma(z: np.ndarray, params: OdometryParams) -> np.ndarray:
    return params.depth_sigma * np.power(np.maximum(z, 1e-3), 1.0 + params.depth_sigma_growth)


def refine(X_a: np.ndarray, n_b: np.ndarray, X_b: np.ndarray, n_a: np.ndarray, T0: np.ndarray,
           focal: float, params: OdometryParams) -> np.ndarray:
    """Least-squares motion X_B = R X_A + t over the inliers, in both directions.

    Each residual is a reprojection error in pixels, divided by its expected spread: the
    tracking noise plus what the depth noise of the 3D point shifts its projection by (the
    point slides along A's viewing ray, which in B's image is a line whose length grows with
    the baseline between the views and shrinks with the range). A Huber loss keeps the few
    wrong tracks the RANSAC let through from pulling the solution.
    """
    rvec0 = cv2.Rodrigues(T0[:3, :3])[0].ravel()
    x0 = np.concatenate([rvec0, T0[:3, 3]])
    both = np.isfinite(X_b).all(axis=1)
    Xa, nb = X_a, n_b
    Xb, na = X_b[both], n_a[both]
    sa = _depth_sigma(Xa[:, 2], params)
    sb = _depth_sigma(Xb[:, 2], params)

    def project(X: np.ndarray) -> np.ndarray:
        return X[:, :2] / X[:, 2:3]

    def residuals(x: np.ndarray) -> np.ndarray:
        R = _rodrigues(x[:3])
        t = x[3:]
        # A -> B
        P = Xa @ R.T + t
        ub = project(P)
        # shift of the projection per metre along A's ray, times that point's depth sigma
        ray = Xa / np.linalg.norm(Xa, axis=1, keepdims=True)
        P2 = (Xa + ray * 0.01) @ R.T + t
        slide = np.linalg.norm(project(P2) - ub, axis=1) * 100.0 * sa * focal
        wa = 1.0 / np.sqrt(params.pixel_sigma ** 2 + slide ** 2)
        ra = (ub - nb) * focal * wa[:, None]
        # B -> A
        Q = (Xb - t) @ R  # R^T (Xb - t)
        ua = project(Q)
        rayb = Xb / np.linalg.norm(Xb, axis=1, keepdims=True)
        Q2 = (Xb + rayb * 0.01 - t) @ R
        slideb = np.linalg.norm(project(Q2) - ua, axis=1) * 100.0 * sb * focal
        wb = 1.0 / np.sqrt(params.pixel_sigma ** 2 + slideb ** 2)
        rb = (ua - na) * focal * wb[:, None]
        return np.concatenate([ra.ravel(), rb.ravel()])

    # imported here: the server and the CLIs start without scipy.optimize (0.2-0.3 s)
    from scipy.optimize import least_squares

    sol = least_squares(residuals, x0, loss="huber", f_scale=2.0, method="trf", x_scale="jac", max_nfev=100)
    return _pose_T(sol.x[:3], sol.x[3:])


def project_points(frame: DepthFrame, X: np.ndarray) -> np.ndarray:
    """Raw (distorted) pixel positions of sensor-frame points (N x 2)."""
    if len(X) == 0:
        return np.zeros((0, 2), np.float32)
    uv, _ = cv2.projectPoints(np.asarray(X, np.float64).reshape(-1, 1, 3), np.zeros(3), np.zeros(3),
                              np.asarray(frame.K, np.float64), np.asarray(frame.dist, np.float64))
    return uv.reshape(-1, 2).astype(np.float32)


def _solve(a: DepthFrame, b: DepthFrame, pa: np.ndarray, pb: np.ndarray, Xa: np.ndarray, p: OdometryParams,
           counts: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(T, inliers, X_b) from tracked pairs: PnP RANSAC, then weighted two-way refinement."""
    n_points, matches = counts
    Xb = lift(b, pb, p)
    K_b = np.asarray(b.K, np.float64)
    cv2.setRNGSeed(p.seed)
    ok_pnp, rvec, tvec, inl = cv2.solvePnPRansac(
        Xa.astype(np.float64), pb.astype(np.float64), K_b, np.asarray(b.dist, np.float64),
        iterationsCount=p.ransac_iterations, reprojectionError=p.reprojection, confidence=0.999,
        flags=cv2.SOLVEPNP_AP3P,
    )
    if not ok_pnp or inl is None or len(inl) < p.min_inliers:
        n = 0 if inl is None else len(inl)
        raise OdometryError(f"only {n} of {matches} tracked points agree on one motion (need {p.min_inliers})",
                            n_points, matches, n)
    inliers = np.zeros(len(pa), bool)
    inliers[inl.ravel()] = True
    na_all = normalised(a, pa)
    nb_all = normalised(b, pb)
    focal = float(np.sqrt(K_b[0, 0] * K_b[1, 1]))
    T = _pose_T(rvec, tvec)
    for _ in range(3):  # refine, then re-select the inliers with the better motion
        T = refine(Xa[inliers], nb_all[inliers], Xb[inliers], na_all[inliers], T, focal, p)
        P = Xa @ T[:3, :3].T + T[:3, 3]
        with np.errstate(invalid="ignore", divide="ignore"):
            err = np.linalg.norm((P[:, :2] / P[:, 2:3] - nb_all) * focal, axis=1)
        new = np.isfinite(err) & (err <= p.reprojection) & (P[:, 2] > 0)
        if np.array_equal(new, inliers) or new.sum() < p.min_inliers:
            break
        inliers = new
    return T, inliers, Xb


def warp_into(a: DepthFrame, b: DepthFrame, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """B's image as A would see it if the motion were ``T`` (X_B = T X_A), and for each A pixel
    the B pixel it was taken from (H x W x 2, NaN where A has no depth or B does not see it).

    Each A pixel's 3D point is moved into B and projected there; sampling B at that spot undoes
    the change of scale and perspective between the views, so the tracker only has to correct
    what the coarse motion got wrong, with patches that look alike."""
    pts = np.asarray(a.points, dtype=np.float64)
    h, w = pts.shape[:2]
    ok = np.isfinite(pts).all(axis=2) & (pts[..., 2] > 0)
    X = pts[ok] @ T[:3, :3].T + T[:3, 3]
    front = X[:, 2] > 1e-3
    uv = np.full((len(X), 2), np.nan, np.float32)
    if front.any():
        uv[front] = project_points(b, X[front])
    src = np.full((h, w, 2), np.nan, np.float32)
    src[ok] = uv
    gb = _gray(b)
    hb, wb = gb.shape[:2]
    inside = np.isfinite(src).all(axis=2) & (src[..., 0] >= 0) & (src[..., 1] >= 0) & \
        (src[..., 0] <= wb - 1) & (src[..., 1] <= hb - 1)
    src[~inside] = np.nan
    mx = np.where(inside, src[..., 0], -1.0).astype(np.float32)
    my = np.where(inside, src[..., 1], -1.0).astype(np.float32)
    warped = cv2.remap(gb, mx, my, cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return warped, src


def track_warped(a: DepthFrame, b: DepthFrame, pts: np.ndarray, T: np.ndarray,
                 p: OdometryParams) -> tuple[np.ndarray, np.ndarray]:
    """Where A's points ``pts`` are in B (N x 2) and which were found, by tracking them from A
    into B's image warped into A's view with the coarse motion ``T`` (forward-backward
    checked), then carrying each tracked position through the warp into B."""
    warped, src = warp_into(a, b, T)
    valid = np.isfinite(src).all(axis=2)
    wf = DepthFrame(warped, a.points, a.K, a.dist, a.T_rover_sensor)
    wf.gray = warped
    q, ok = track(a, wf, pts, p, guess=pts, levels=1)
    # a window that straddles the warp's holes or borders compares against black
    k = max(1, p.window // 2)
    core = cv2.erode(valid.astype(np.uint8), np.ones((2 * k + 1, 2 * k + 1), np.uint8)).astype(bool)
    qi = np.clip(np.rint(q).astype(int), 0, [valid.shape[1] - 1, valid.shape[0] - 1])
    ok &= core[qi[:, 1], qi[:, 0]]
    mx = np.nan_to_num(src[..., 0], nan=-1e6).astype(np.float32)
    my = np.nan_to_num(src[..., 1], nan=-1e6).astype(np.float32)
    qx = q[:, 0].reshape(-1, 1).astype(np.float32)
    qy = q[:, 1].reshape(-1, 1).astype(np.float32)
    ub = cv2.remap(mx, qx, qy, cv2.INTER_LINEAR).ravel()
    vb = cv2.remap(my, qx, qy, cv2.INTER_LINEAR).ravel()
    ok &= (ub >= 0) & (vb >= 0)
    return np.stack([ub, vb], axis=1).astype(np.float32), ok


def match_descriptors(a: DepthFrame, b: DepthFrame, p: OdometryParams) -> tuple[np.ndarray, np.ndarray]:
    """Coarse correspondences (A pixels, B pixels) from ORB descriptors with the ratio test:
    found at any scale and any image distance, so they bridge motions too large for the
    tracker to search (a narrow sensor driven a metre towards the ground it looks at)."""
    ga, gb = _gray(a), _gray(b)
    size = min(ga.shape[:2])
    edge = max(8, min(31, size // 8))
    orb = cv2.ORB_create(nfeatures=p.orb_features, scaleFactor=1.2, nlevels=8, edgeThreshold=edge,
                         patchSize=edge, fastThreshold=5)
    mask_a = usable(a, p).astype(np.uint8)
    ka, da = orb.detectAndCompute(ga, mask_a)
    kb, db = orb.detectAndCompute(gb, None)
    if da is None or db is None or len(ka) < 2 or len(kb) < 2:
        return np.zeros((0, 2), np.float32), np.zeros((0, 2), np.float32)
    pairs = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(da, db, k=2)
    good = [m[0] for m in pairs if len(m) == 2 and m[0].distance < p.orb_ratio * m[1].distance]
    pa = np.array([ka[m.queryIdx].pt for m in good], np.float32).reshape(-1, 2)
    pb = np.array([kb[m.trainIdx].pt for m in good], np.float32).reshape(-1, 2)
    return pa, pb


def estimate_motion(a: DepthFrame, b: DepthFrame, params: OdometryParams | None = None,
                    prior: np.ndarray | None = None) -> Motion:
    """The rover's motion from A to B; :class:`OdometryError` (with the best counts reached)
    when too few points are tracked or agree on one motion.

    A coarse motion first: blind pyramidal tracking, or ORB descriptor matching when that
    finds too little (or ``prior``, rover B in rover A, when the caller knows roughly how the
    rover moved). Then, twice, B's image is warped into A's view with the current motion and
    A's points are tracked into it: the patches then differ only by what the motion got wrong,
    not by the change of scale and perspective a metre of driving makes near the rover, so
    far more points are found and each to a fraction of a pixel.
    """
    p = params or OdometryParams()
    p.check()
    pts_a = detect(a, p)
    X_a = lift(a, pts_a, p)
    has = np.isfinite(X_a).all(axis=1)
    pts_a, X_a = pts_a[has], X_a[has]
    n_points = int(len(pts_a))
    best: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
    most = [0, 0]  # matches, inliers: the best counts seen, for the error

    def attempt(pts_b: np.ndarray, ok: np.ndarray) -> np.ndarray | None:
        nonlocal best
        n = int(ok.sum())
        most[0] = max(most[0], n)
        if n < p.min_matches:
            return None
        try:
            T, inl, Xb = _solve(a, b, pts_a[ok], pts_b[ok], X_a[ok], p, (n_points, n))
        except OdometryError as exc:
            most[1] = max(most[1], exc.inliers)
            return None
        most[1] = max(most[1], int(inl.sum()))
        if best is None or inl.sum() >= best[3].sum():
            best = (pts_b, ok, T, inl, Xb)
        return T

    coarse: np.ndarray | None = None
    if prior is not None:
        # X_B = T X_A with T = T_sB_rB T_rB_rA T_rA_sA
        coarse = invert(b.T_rover_sensor) @ invert(np.asarray(prior, np.float64)) @ a.T_rover_sensor
    else:
        coarse = attempt(*track(a, b, pts_a, p))
        if coarse is None or best is None or best[3].sum() < 2 * p.min_inliers:
            da, db = match_descriptors(a, b, p)
            Xd = lift(a, da, p)
            keep = np.isfinite(Xd).all(axis=1)
            if keep.sum() >= p.min_matches:
                try:
                    coarse = _solve(a, b, da[keep], db[keep], Xd[keep], p, (n_points, int(keep.sum())))[0]
                except OdometryError:
                    pass
    if coarse is not None and p.guided:
        for _ in range(2):
            if p.warp:
                refined = attempt(*track_warped(a, b, pts_a, coarse, p))
            else:
                P = X_a @ coarse[:3, :3].T + coarse[:3, 3]
                front = P[:, 2] > p.min_range
                guess = project_points(b, np.where(front[:, None], P, 1.0))
                pts_g, ok_g = track(a, b, pts_a, p, guess=guess, levels=1)
                refined = attempt(pts_g, ok_g & front)
            if refined is None:
                break
            coarse = refined
    if best is None:
        if most[0] < p.min_matches:
            msg = f"only {most[0]} of {n_points} interest points were tracked into the new image (need {p.min_matches})"
        else:
            msg = f"only {most[1]} of {most[0]} tracked points agree on one motion (need {p.min_inliers})"
        raise OdometryError(msg, n_points, most[0], most[1])
    pts_b, ok, T, inliers, Xb = best
    matches = int(ok.sum())
    pa, pb, Xa = pts_a[ok][inliers], pts_b[ok][inliers], X_a[ok][inliers]
    K_b = np.asarray(b.K, np.float64)
    focal = float(np.sqrt(K_b[0, 0] * K_b[1, 1]))
    P = Xa @ T[:3, :3].T + T[:3, 3]
    err = np.linalg.norm((P[:, :2] / P[:, 2:3] - normalised(b, pb)) * focal, axis=1)
    # X_B = T X_A in the sensor frames; rover B in rover A: T_rA_sA T_sA_sB T_sB_rB
    T_rover = a.T_rover_sensor @ invert(T) @ invert(b.T_rover_sensor)
    return Motion(T_rover, T, n_points, matches, int(inliers.sum()), float(np.sqrt(np.mean(err ** 2))),
                  _coverage(pb, _gray(b).shape), used={"a": pa, "b": pb, "X_a": Xa, "X_b": Xb[inliers]})


def compose_pose(x: float, y: float, heading: float, motion: Motion) -> tuple[float, float, float]:
    """The global pose after ``motion`` (in the rover frame at x, y, heading): planar part only,
    as the server's pose is x, y, heading."""
    c, s = math.cos(math.radians(heading)), math.sin(math.radians(heading))
    nx = x + c * motion.dx - s * motion.dy
    ny = y + s * motion.dx + c * motion.dy
    nh = (heading + motion.dyaw + 180.0) % 360.0 - 180.0
    return nx, ny, nh


def rover_body_mask(points: np.ndarray, T_rover_sensor: np.ndarray, length: float, width: float,
                    margin: float, height: float = 2.0) -> np.ndarray:
    """True where a pixel's point is NOT on the rover itself (a box around the body): points
    that ride with the rover would vote for "no motion"."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    r = pts @ T_rover_sensor[:3, :3].T + T_rover_sensor[:3, 3]
    inside = (np.abs(r[:, 0]) <= length / 2 + margin) & (np.abs(r[:, 1]) <= width / 2 + margin) & \
             (r[:, 2] <= height)
    return ~inside.reshape(np.asarray(points).shape[:-1])
