"""Sensor calibration (seed 000 sect. 3.1.8; seed 004 sect. 2.2): three problems, one module.

* **Control points** (what JR's CalWin did): 3D world points and their 2D image positions give
  the 3 x 4 camera calibration matrix P. A linear DLT on Hartley-normalised coordinates gives a
  start that does not depend on any guess; a non-linear least-squares refinement of the
  reprojection error (over K, R, t: 11 parameters, P's degrees of freedom) then minimises what
  is actually measured, pixels. P is decomposed into K, R, t by an RQ decomposition.
* **Stereo from a checkerboard**: OpenCV's corner finder, ``calibrateCamera`` per camera, then
  ``stereoCalibrate`` for the pair (intrinsics refined together with R, T).
* **ToF to stereo** (seed 004 sect. 2.2.4): board corners found in the ToF amplitude image
  and lifted to 3D with the ToF's own coordinates, the same corners triangulated by the
  calibrated stereo pair, and the rigid motion between the two point sets by Horn's closed
  form (Umeyama's SVD variant) inside RANSAC, since a single flying pixel or multipath corner
  would otherwise pull the whole estimate (their calibration without RANSAC was 2.6 cm off).

Conventions: pixel (0, 0) is the centre of the top-left pixel (OpenCV); camera frames are
OpenCV optical (x right, y down, z forward); rigid motions map source to destination,
``dst = R src + t``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from scipy.linalg import rq
from scipy.optimize import least_squares

from .stereo import StereoCalibration, load_calibration, to_gray8

# -- control points: DLT, refinement, decomposition ----------------------------------------------------


def hartley_normalisation(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(normalised N x d points, (d+1) x (d+1) similarity T): centroid at the origin, mean distance
    sqrt(d). Without it the DLT's design matrix mixes pixels (1e3) with ones and metres, and
    its SVD answers the conditioning rather than the geometry (Hartley 1997)."""
    pts = np.asarray(points, dtype=np.float64)
    d = pts.shape[1]
    centroid = pts.mean(axis=0)
    mean_dist = np.mean(np.linalg.norm(pts - centroid, axis=1))
    s = np.sqrt(d) / mean_dist if mean_dist > 0 else 1.0
    T = np.eye(d + 1)
    T[:d, :d] *= s
    T[:d, d] = -s * centroid
    return (pts - centroid) * s, T


def dlt(world: np.ndarray, image: np.ndarray) -> np.ndarray:
    """Linear 3 x 4 P from >= 6 non-coplanar correspondences, scaled so K[2, 2] = 1 and the points
    lie in front of the camera."""
    X = np.asarray(world, dtype=np.float64).reshape(-1, 3)
    x = np.asarray(image, dtype=np.float64).reshape(-1, 2)
    n = len(X)
    if n != len(x):
        raise ValueError(f"{n} world points but {len(x)} image points")
    if n < 6:
        raise ValueError(f"the DLT needs at least 6 control points, got {n}")
    sv = np.linalg.svd(X - X.mean(axis=0), compute_uv=False)
    if sv[2] < 1e-6 * sv[0]:
        raise ValueError("the control points are coplanar (or collinear): P is not determined by them; "
                         "spread them in depth, or calibrate the intrinsics first")
    Xn, TX = hartley_normalisation(X)
    xn, Tx = hartley_normalisation(x)
    A = np.zeros((2 * n, 12))
    Xh = np.column_stack([Xn, np.ones(n)])
    A[0::2, 0:4] = Xh
    A[0::2, 8:12] = -xn[:, [0]] * Xh
    A[1::2, 4:8] = Xh
    A[1::2, 8:12] = -xn[:, [1]] * Xh
    _, _, vt = np.linalg.svd(A)
    Pn = vt[-1].reshape(3, 4)
    P = np.linalg.inv(Tx) @ Pn @ TX
    return _normalise_P(P, X)


def _normalise_P(P: np.ndarray, world: np.ndarray | None = None) -> np.ndarray:
    """Scale P so that its left 3x3 has a unit third row and the camera looks at the points."""
    M = P[:, :3]
    P = P / np.linalg.norm(M[2])
    if world is not None:
        depth = np.column_stack([world, np.ones(len(world))]) @ P[2]
        if np.median(depth) < 0:
            P = -P
    elif np.linalg.det(P[:, :3]) < 0:
        P = -P
    return P


def decompose_projection(P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """K (upper triangular, positive diagonal, K[2, 2] = 1), R (a rotation) and t with
    P ~ K [R | t]. P's overall sign is chosen so R is proper (det +1): the camera centre and
    depths then come out as for a camera in front of its points."""
    P = np.asarray(P, dtype=np.float64)
    M = P[:, :3]
    if np.linalg.det(M) < 0:
        P = -P
        M = P[:, :3]
    K, R = rq(M)
    signs = np.sign(np.diag(K))  # RQ's signs are arbitrary: make K's diagonal positive
    signs[signs == 0] = 1.0
    S = np.diag(signs)
    K = K @ S
    R = S @ R  # S @ S = I keeps K R unchanged
    scale = K[2, 2]
    t = np.linalg.solve(K, P[:, 3])
    K = K / scale
    if np.linalg.det(R) < 0:  # cannot happen with det(M) > 0, kept as a guard
        R = -R
        t = -t
    return K, R, t


def compose_projection(K: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    return np.asarray(K, float) @ np.column_stack([np.asarray(R, float), np.asarray(t, float).reshape(3)])


def project_points(P: np.ndarray, world: np.ndarray) -> np.ndarray:
    X = np.asarray(world, dtype=np.float64).reshape(-1, 3)
    hom = X @ P[:, :3].T + P[:, 3]
    return hom[:, :2] / hom[:, 2:3]


def reprojection_errors(P: np.ndarray, world: np.ndarray, image: np.ndarray) -> np.ndarray:
    """Pixel distance between each measured image point and its control point projected by P."""
    return np.linalg.norm(project_points(P, world) - np.asarray(image, dtype=np.float64).reshape(-1, 2), axis=1)


def reprojection_rms(P: np.ndarray, world: np.ndarray, image: np.ndarray) -> float:
    e = reprojection_errors(P, world, image)
    return float(np.sqrt(np.mean(e * e)))


def refine_projection(P: np.ndarray, world: np.ndarray, image: np.ndarray, zero_skew: bool = False,
                      loss: str = "linear") -> np.ndarray:
    """Minimise the reprojection error over K (fx, fy, cx, cy[, skew]), the rotation vector and t,
    starting from ``P`` (the DLT minimises an algebraic error, not pixels). ``loss`` is scipy's
    (``"huber"`` or ``"soft_l1"`` against a few mis-clicked points)."""
    X = np.asarray(world, dtype=np.float64).reshape(-1, 3)
    x = np.asarray(image, dtype=np.float64).reshape(-1, 2)
    K, R, t = decompose_projection(P)
    rvec = cv2.Rodrigues(R)[0].ravel()
    p0 = np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], 0.0 if zero_skew else K[0, 1], *rvec, *t])
    scale = max(K[0, 0], 1.0)

    def unpack(p: np.ndarray) -> np.ndarray:
        Kp = np.array([[p[0], 0.0 if zero_skew else p[4], p[2]], [0.0, p[1], p[3]], [0.0, 0.0, 1.0]])
        Rp = cv2.Rodrigues(p[5:8].reshape(3, 1))[0]
        return compose_projection(Kp, Rp, p[8:11])

    def residuals(p: np.ndarray) -> np.ndarray:
        return (project_points(unpack(p), X) - x).ravel()

    method = "lm" if loss == "linear" and 2 * len(X) >= len(p0) else "trf"
    sol = least_squares(residuals, p0, method=method, loss=loss, f_scale=1.0,
                        x_scale=np.r_[scale, scale, scale, scale, scale, 1, 1, 1, np.abs(t).max() + 1e-3,
                                      np.abs(t).max() + 1e-3, np.abs(t).max() + 1e-3],
                        xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=2000)
    return _normalise_P(unpack(sol.x), X)


@dataclass
class ControlPointCalibration:
    """The camera calibration matrix from control points, its parts and how well it fits."""

    P: np.ndarray  # 3 x 4, world -> pixel, K[2,2] = 1 scaling
    K: np.ndarray
    R: np.ndarray  # world -> camera rotation
    t: np.ndarray  # world -> camera translation
    rms: float  # px, of the final P
    rms_linear: float  # px, of the DLT alone
    residuals: np.ndarray  # px per point
    n_points: int

    @property
    def T_global_camera(self) -> np.ndarray:
        """The camera's pose in the world (control point) frame, 4 x 4."""
        T = np.eye(4)
        T[:3, :3] = self.R.T
        T[:3, 3] = -self.R.T @ self.t
        return T

    @property
    def centre(self) -> np.ndarray:
        return self.T_global_camera[:3, 3]


def calibrate_control_points(world: np.ndarray, image: np.ndarray, refine: bool = True,
                             zero_skew: bool = False, loss: str = "linear") -> ControlPointCalibration:
    """CalWin's job: P from control points, by DLT then (``refine``) non-linear least squares."""
    X = np.asarray(world, dtype=np.float64).reshape(-1, 3)
    x = np.asarray(image, dtype=np.float64).reshape(-1, 2)
    ok = np.isfinite(X).all(axis=1) & np.isfinite(x).all(axis=1)
    X, x = X[ok], x[ok]
    P_lin = dlt(X, x)
    rms_lin = reprojection_rms(P_lin, X, x)
    P = refine_projection(P_lin, X, x, zero_skew, loss) if refine else P_lin
    K, R, t = decompose_projection(P)
    P = compose_projection(K, R, t)
    res = reprojection_errors(P, X, x)
    return ControlPointCalibration(P, K, R, t, float(np.sqrt(np.mean(res * res))), rms_lin, res, len(X))


# -- checkerboards ------------------------------------------------------------------------------------


def board_points(pattern: tuple[int, int], square: float) -> np.ndarray:
    """Object points of the inner corners for ``pattern`` = (corners per row, rows), in the order
    ``cv2.findChessboardCorners`` returns them: the board frame of ``World.place_checkerboard``
    (first inner corner at (square, square), x along a row, z = 0)."""
    nx, ny = pattern
    jj, ii = np.meshgrid(np.arange(1, nx + 1), np.arange(1, ny + 1))
    return np.column_stack([jj.ravel() * square, ii.ravel() * square, np.zeros(nx * ny)]).astype(np.float32)


def find_corners(image: np.ndarray, pattern: tuple[int, int], upscale: int = 1,
                 subpix_window: float = 5.0, prefer: str = "sb") -> np.ndarray | None:
    """Sub-pixel inner corners (N x 2 float64, original pixel coordinates) or None.

    Two OpenCV detectors are tried in turn, ``prefer`` first: ``sb`` (findChessboardCornersSB,
    plain then exhaustive: robust, sub-pixel by itself) and ``classic`` (findChessboardCorners
    + cornerSubPix). Every answer must pass a regularity check (each corner near the midpoint of
    its neighbours) before it is accepted, because both detectors occasionally return a grid
    that strays off the board (onto a white wall, into floor texture) without saying so.

    ``upscale`` > 1 enlarges a low-resolution image first; ``subpix_window`` is cornerSubPix's
    half window in original pixels (under half a square). On the simulated 176 x 144 ToF
    amplitude image ``classic`` at upscale 2 is the most accurate (0.08 px RMS against the true
    corners; ``sb`` 0.2 px and it misses boards once upscaled); on the PIKE images ``sb`` is.

    The order is made canonical (the first row runs left to right in the image) so that the
    left, right and ToF views of one board list the same physical corner first even for a
    point-symmetric board.
    """
    if prefer not in ("sb", "classic"):
        raise ValueError(f"prefer must be 'sb' or 'classic', not {prefer!r}")
    img = np.asarray(image)
    gray = to_gray8(img) if img.dtype == np.uint8 or img.ndim == 3 else _stretch8(img)
    if upscale > 1:
        gray = cv2.resize(gray, None, fx=upscale, fy=upscale, interpolation=cv2.INTER_CUBIC)
    order = ("sb", "sb_exhaustive", "classic") if prefer == "sb" else ("classic", "sb", "sb_exhaustive")
    for method in order:
        corners = _detect(gray, pattern, method, max(2, int(round(subpix_window * max(upscale, 1)))))
        if corners is not None and _grid_consistent(corners, pattern):
            if upscale > 1:
                corners = (corners + 0.5) / upscale - 0.5
            return canonical_order(corners, pattern)
    return None


def _detect(gray: np.ndarray, pattern: tuple[int, int], method: str, win: int) -> np.ndarray | None:
    if method == "classic":
        found, corners = cv2.findChessboardCorners(gray, pattern,
                                                   flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
        if not found or corners is None:
            return None
        criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
        return cv2.cornerSubPix(gray, corners, (win, win), (-1, -1), criteria).reshape(-1, 2).astype(np.float64)
    flags = cv2.CALIB_CB_NORMALIZE_IMAGE | (cv2.CALIB_CB_EXHAUSTIVE if method == "sb_exhaustive" else 0)
    found, corners = cv2.findChessboardCornersSB(gray, pattern, flags=flags)
    if not found or corners is None:
        return None
    return corners.reshape(-1, 2).astype(np.float64)


def _grid_consistent(corners: np.ndarray, pattern: tuple[int, int], tol: float = 0.2) -> bool:
    """A found grid is locally affine: each corner lies near the midpoint of its two neighbours
    along a row and a column (within ``tol`` of the local square size). A corner the detector put
    on the wrong spot breaks this by a good part of a square."""
    nx, ny = pattern
    g = corners.reshape(ny, nx, 2)
    size = np.median(np.linalg.norm(np.diff(g, axis=1), axis=2))
    worst = 0.0
    if nx >= 3:
        worst = max(worst, float(np.linalg.norm(g[:, :-2] - 2 * g[:, 1:-1] + g[:, 2:], axis=2).max()))
    if ny >= 3:
        worst = max(worst, float(np.linalg.norm(g[:-2] - 2 * g[1:-1] + g[2:], axis=2).max()))
    return worst <= tol * size


def canonical_order(corners: np.ndarray, pattern: tuple[int, int]) -> np.ndarray:
    nx, _ = pattern
    row = corners[nx - 1] - corners[0]
    if row[0] < 0:  # the detector started at the opposite corner: the same grid, reversed
        return corners[::-1].copy()
    return corners


def _stretch8(image: np.ndarray) -> np.ndarray:
    """A float image (ToF amplitude) to 8 bits by its 1-99 percentiles (NaN black)."""
    data = np.asarray(image, dtype=np.float32)
    ok = np.isfinite(data)
    if not ok.any():
        return np.zeros(data.shape[:2], np.uint8)
    lo, hi = np.percentile(data[ok], [1, 99])
    out = np.clip((np.nan_to_num(data, nan=lo) - lo) / max(hi - lo, 1e-9) * 255, 0, 255)
    return out.astype(np.uint8)


@dataclass
class StereoCheckerboardCalibration:
    calib: StereoCalibration
    rms: float  # px, stereoCalibrate's RMS over both cameras
    rms_left: float
    rms_right: float
    n_pairs: int
    used: list[int]  # indices of the pairs whose corners were found in both images
    per_view_rms: list[float] = field(default_factory=list)


def calibrate_stereo_checkerboard(
    pairs: Sequence[tuple[np.ndarray, np.ndarray]],
    pattern: tuple[int, int],
    square: float,
    fix_k3: bool = True,
    progress: Callable[[int, int], None] | None = None,
) -> StereoCheckerboardCalibration:
    """Intrinsics of both cameras and the right camera's pose from checkerboard pairs.

    Each camera is calibrated alone first (``calibrateCamera``: a good start), then all
    parameters are refined together by ``stereoCalibrate`` so the baseline is estimated with
    the intrinsics that produced it. ``fix_k3``: the sixth-order radial term is rarely
    observable with a 60 degree lens and only absorbs noise.
    """
    if not pairs:
        raise ValueError("no image pairs given")
    obj = board_points(pattern, square)
    objs: list[np.ndarray] = []
    lefts: list[np.ndarray] = []
    rights: list[np.ndarray] = []
    used: list[int] = []
    size: tuple[int, int] | None = None
    for i, (left, right) in enumerate(pairs):
        h, w = np.asarray(left).shape[:2]
        if size is None:
            size = (w, h)
        elif size != (w, h) or np.asarray(right).shape[:2] != (h, w):
            raise ValueError(f"pair {i}: image size {w}x{h} differs from the first pair's {size[0]}x{size[1]}")
        cl = find_corners(left, pattern)
        cr = find_corners(right, pattern) if cl is not None else None
        if progress is not None:
            progress(i + 1, len(pairs))
        if cl is None or cr is None:
            continue
        objs.append(obj)
        lefts.append(cl.astype(np.float32).reshape(-1, 1, 2))
        rights.append(cr.astype(np.float32).reshape(-1, 1, 2))
        used.append(i)
    if len(used) < 3:
        raise ValueError(f"the {pattern[0]}x{pattern[1]} inner-corner board was found in both images of only "
                         f"{len(used)} pair(s) of {len(pairs)}; at least 3 (better 10+) varied poses are needed")
    assert size is not None
    flags = cv2.CALIB_FIX_K3 if fix_k3 else 0
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-9)
    rms_l, K1, D1, _, _ = cv2.calibrateCamera(objs, lefts, size, None, None, flags=flags, criteria=crit)
    rms_r, K2, D2, _, _ = cv2.calibrateCamera(objs, rights, size, None, None, flags=flags, criteria=crit)
    out = cv2.stereoCalibrate(objs, lefts, rights, K1, D1, K2, D2, size,
                              flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS, criteria=crit)
    rms, K1, D1, K2, D2, R, T = out[:7]
    calib = StereoCalibration(np.asarray(K1, float), np.asarray(D1, float).ravel(), np.asarray(K2, float),
                              np.asarray(D2, float).ravel(), np.asarray(R, float), np.asarray(T, float).ravel(),
                              (int(size[0]), int(size[1])))
    per_view = _stereo_view_rms(calib, objs, lefts, rights)
    return StereoCheckerboardCalibration(calib, float(rms), float(rms_l), float(rms_r), len(used), used, per_view)


def _stereo_view_rms(cal: StereoCalibration, objs: list[np.ndarray], lefts: list[np.ndarray],
                     rights: list[np.ndarray]) -> list[float]:
    """RMS per pair with the final calibration (a bad view stands out here)."""
    out = []
    for obj, cl, cr in zip(objs, lefts, rights, strict=True):
        ok, rvec, tvec = cv2.solvePnP(obj, cl, cal.K1, cal.D1)
        if not ok:
            out.append(float("nan"))
            continue
        pl = cv2.projectPoints(obj, rvec, tvec, cal.K1, cal.D1)[0].reshape(-1, 2)
        R_l = cv2.Rodrigues(rvec)[0]
        rvec_r = cv2.Rodrigues(cal.R @ R_l)[0]
        tvec_r = cal.R @ tvec.ravel() + cal.T
        pr = cv2.projectPoints(obj, rvec_r, tvec_r, cal.K2, cal.D2)[0].reshape(-1, 2)
        e = np.concatenate([pl - cl.reshape(-1, 2), pr - cr.reshape(-1, 2)])
        out.append(float(np.sqrt(np.mean(np.sum(e * e, axis=1)))))
    return out


# -- absolute orientation -----------------------------------------------------------------------------


def absolute_orientation(src: np.ndarray, dst: np.ndarray, with_scale: bool = False,
                         weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """(R, t, s) minimising sum w |dst - (s R src + t)|^2 in closed form: Horn's absolute
    orientation as Umeyama's SVD of the cross-covariance, with the reflection guard (a
    degenerate or noisy set must not come back as a mirror). ``s`` is 1 unless ``with_scale``."""
    A = np.asarray(src, dtype=np.float64).reshape(-1, 3)
    B = np.asarray(dst, dtype=np.float64).reshape(-1, 3)
    if len(A) != len(B) or len(A) < 3:
        raise ValueError(f"absolute orientation needs >= 3 point pairs, got {len(A)} and {len(B)}")
    w = np.ones(len(A)) if weights is None else np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    ma = w @ A
    mb = w @ B
    Ac, Bc = A - ma, B - mb
    C = (Bc * w[:, None]).T @ Ac
    U, S, Vt = np.linalg.svd(C)
    D = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        D[2, 2] = -1.0
    R = U @ D @ Vt
    s = 1.0
    if with_scale:
        var_a = float(w @ np.sum(Ac * Ac, axis=1))
        s = float(np.trace(np.diag(S) @ D) / var_a) if var_a > 0 else 1.0
    t = mb - s * R @ ma
    return R, t, s


@dataclass
class RansacOrientation:
    R: np.ndarray
    t: np.ndarray
    inliers: np.ndarray  # bool per point pair
    residuals: np.ndarray  # m, |dst - (R src + t)| per pair with the final model
    iterations: int

    @property
    def T(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = self.R
        T[:3, 3] = self.t
        return T

    @property
    def rms(self) -> float:
        r = self.residuals[self.inliers]
        return float(np.sqrt(np.mean(r * r))) if r.size else float("nan")


def ransac_absolute_orientation(src: np.ndarray, dst: np.ndarray, threshold: float = 0.03,
                                iterations: int = 500, confidence: float = 0.999,
                                rng: np.random.Generator | int | None = 0) -> RansacOrientation:
    """The rigid motion dst = R src + t that the most pairs agree with (within ``threshold``
    metres), refitted on those pairs until the inlier set settles (seed 004, algorithm 1).

    Samples are minimal (3 pairs); the number of iterations adapts to the inlier share seen so
    far (the usual 1 - (1 - w^3)^k >= confidence rule), capped by ``iterations``.
    """
    A = np.asarray(src, dtype=np.float64).reshape(-1, 3)
    B = np.asarray(dst, dtype=np.float64).reshape(-1, 3)
    ok = np.isfinite(A).all(axis=1) & np.isfinite(B).all(axis=1)
    idx = np.nonzero(ok)[0]
    n = len(idx)
    if n < 3:
        raise ValueError(f"RANSAC needs >= 3 valid point pairs, got {n}")
    gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    best: np.ndarray | None = None
    best_count = -1
    best_cost = np.inf
    needed = iterations
    k = 0
    while k < min(needed, iterations):
        k += 1
        sample = gen.choice(n, 3, replace=False)
        a, b = A[idx[sample]], B[idx[sample]]
        # a nearly collinear sample fixes no rotation about its line
        if np.linalg.norm(np.cross(a[1] - a[0], a[2] - a[0])) < 1e-9:
            continue
        R, t, _ = absolute_orientation(a, b)
        r = np.linalg.norm(B[idx] - (A[idx] @ R.T + t), axis=1)
        inl = r < threshold
        count = int(inl.sum())
        cost = float(np.sum(np.minimum(r, threshold) ** 2))  # MSAC tie-break
        if count > best_count or (count == best_count and cost < best_cost):
            best, best_count, best_cost = inl, count, cost
            share = count / n
            if share > 0:
                needed = int(np.ceil(np.log(1 - confidence) / np.log(max(1 - share**3, 1e-12)))) if share < 1 else 1
    if best is None or best_count < 3:
        raise ValueError("RANSAC found no consistent rigid motion: check the threshold and the correspondences")
    inl = best
    for _ in range(20):  # local optimisation: refit on the inliers until they stop changing
        R, t, _ = absolute_orientation(A[idx[inl]], B[idx[inl]])
        r = np.linalg.norm(B[idx] - (A[idx] @ R.T + t), axis=1)
        new = r < threshold
        if new.sum() < 3 or np.array_equal(new, inl):
            break
        inl = new
    R, t, _ = absolute_orientation(A[idx[inl]], B[idx[inl]])
    residuals = np.full(len(A), np.nan)
    residuals[idx] = np.linalg.norm(B[idx] - (A[idx] @ R.T + t), axis=1)
    inliers = np.zeros(len(A), bool)
    inliers[idx[inl]] = True
    return RansacOrientation(R, t, inliers, residuals, k)


# -- ToF to stereo --------------------------------------------------------------------------------------


def triangulate(left_pts: np.ndarray, right_pts: np.ndarray, calib: StereoCalibration | dict[str, Any]) -> np.ndarray:
    """N x 3 points in the left camera frame from corresponding raw (distorted) pixel positions:
    undistorted to normalised coordinates, then ``cv2.triangulatePoints`` with P1 = [I|0],
    P2 = [R|T]."""
    cal = load_calibration(calib)
    pl = cv2.undistortPoints(np.asarray(left_pts, np.float64).reshape(-1, 1, 2), cal.K1, cal.D1).reshape(-1, 2)
    pr = cv2.undistortPoints(np.asarray(right_pts, np.float64).reshape(-1, 1, 2), cal.K2, cal.D2).reshape(-1, 2)
    P1 = np.hstack([np.eye(3), np.zeros((3, 1))])
    P2 = np.hstack([cal.R, cal.T.reshape(3, 1)])
    X = cv2.triangulatePoints(P1, P2, pl.T, pr.T)
    return (X[:3] / X[3]).T


def lift_tof_corners(xyz: np.ndarray, corners: np.ndarray, max_spread: float = 0.05) -> np.ndarray:
    """N x 3 ToF-frame points at sub-pixel ``corners``: the XYZ image bilinearly interpolated.

    A corner is dropped (NaN) when one of its four neighbours is undefined (z <= 0 or NaN: the
    camera's -1 / 0 codes) or when their ranges differ by more than ``max_spread``: a depth
    edge, where interpolation would make a flying point.
    """
    img = np.asarray(xyz, dtype=np.float64)
    h, w = img.shape[:2]
    c = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    x0 = np.floor(c[:, 0]).astype(int)
    y0 = np.floor(c[:, 1]).astype(int)
    fx = (c[:, 0] - x0)[:, None]
    fy = (c[:, 1] - y0)[:, None]
    inside = (x0 >= 0) & (y0 >= 0) & (x0 + 1 < w) & (y0 + 1 < h)
    x0c, y0c = np.clip(x0, 0, w - 2), np.clip(y0, 0, h - 2)
    n00, n10 = img[y0c, x0c], img[y0c, x0c + 1]
    n01, n11 = img[y0c + 1, x0c], img[y0c + 1, x0c + 1]
    quad = np.stack([n00, n10, n01, n11], axis=1)  # N x 4 x 3
    defined = np.all(np.isfinite(quad).all(axis=2) & (quad[..., 2] > 0), axis=1)
    ranges = np.linalg.norm(quad, axis=2)
    smooth = (np.nanmax(ranges, axis=1) - np.nanmin(ranges, axis=1)) <= max_spread
    out = (n00 * (1 - fx) * (1 - fy) + n10 * fx * (1 - fy) + n01 * (1 - fx) * fy + n11 * fx * fy)
    out[~(inside & defined & smooth)] = np.nan
    return out


def lift_tof_corners_plane(xyz: np.ndarray, corners: np.ndarray, pattern: tuple[int, int],
                           threshold: float = 0.03) -> np.ndarray:
    """N x 3 ToF-frame points: each corner's ray cut with a plane fitted (RANSAC, then least
    squares) to all ToF points inside the corner grid. Averages hundreds of noisy ranges per
    board instead of four per corner; the rays come from the XYZ image itself (no intrinsics)."""
    img = np.asarray(xyz, dtype=np.float64)
    h, w = img.shape[:2]
    c = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    nx, ny = pattern
    hull = np.array([c[0], c[nx - 1], c[-1], c[-nx]], np.float32)
    mask = np.zeros((h, w), np.uint8)
    cv2.fillConvexPoly(mask, np.rint(hull).astype(np.int32), 1)
    mask = cv2.erode(mask, np.ones((3, 3), np.uint8))
    pts = img[mask.astype(bool)]
    pts = pts[np.isfinite(pts).all(axis=1) & (pts[:, 2] > 0)]
    out = np.full((len(c), 3), np.nan)
    if len(pts) < 10:
        return out
    normal, d = _fit_plane(pts, threshold)
    with np.errstate(invalid="ignore", divide="ignore"):
        unit = img / np.linalg.norm(img, axis=2, keepdims=True)
    rays = lift_tof_corners(unit, c, max_spread=np.inf)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        s = -d / (rays @ normal)
    return rays * s[:, None]


def _fit_plane(pts: np.ndarray, threshold: float, iterations: int = 200, seed: int = 0) -> tuple[np.ndarray, float]:
    """n . x + d = 0 with |n| = 1: RANSAC on triples, least squares on the inliers."""
    rng = np.random.default_rng(seed)
    best = np.ones(len(pts), bool)
    best_count = 0
    for _ in range(iterations):
        a, b, c = pts[rng.choice(len(pts), 3, replace=False)]
        n = np.cross(b - a, c - a)
        norm = np.linalg.norm(n)
        if norm < 1e-12:
            continue
        n /= norm
        inl = np.abs((pts - a) @ n) < threshold
        if inl.sum() > best_count:
            best, best_count = inl, int(inl.sum())
    sel = pts[best]
    centroid = sel.mean(axis=0)
    _, _, vt = np.linalg.svd(sel - centroid)
    n = vt[2]
    return n, float(-n @ centroid)


@dataclass
class TofStereoView:
    """One board pose as the three sensors saw it (raw images as the devices deliver them)."""

    tof_xyz: np.ndarray  # H x W x 3, ToF frame, <= 0 / NaN undefined
    tof_amplitude: np.ndarray  # H x W, same (raw, not undistorted) geometry as tof_xyz
    left: np.ndarray
    right: np.ndarray
    name: str = ""


@dataclass
class TofStereoCalibration:
    """T_left_tof: ToF-frame points into the left camera frame (X_left = R X_tof + T)."""

    R: np.ndarray
    T: np.ndarray
    ransac: RansacOrientation
    tof_points: np.ndarray  # N x 3, ToF frame
    stereo_points: np.ndarray  # N x 3, left frame
    view_of_point: np.ndarray  # N, index into the views
    views_used: list[str]
    views_rejected: dict[str, str]

    @property
    def T_left_tof(self) -> np.ndarray:
        return self.ransac.T

    def stats(self) -> dict[str, Any]:
        r = self.ransac.residuals
        inl = self.ransac.inliers
        ri = r[inl]
        rot_deg = float(np.degrees(np.arccos(np.clip((np.trace(self.R) - 1) / 2, -1, 1))))
        return {
            "points": int(np.isfinite(r).sum()),
            "inliers": int(inl.sum()),
            "rms_m": float(np.sqrt(np.mean(ri * ri))) if ri.size else None,
            "median_m": float(np.median(ri)) if ri.size else None,
            "p95_m": float(np.percentile(ri, 95)) if ri.size else None,
            "max_inlier_m": float(ri.max()) if ri.size else None,
            "max_all_m": float(np.nanmax(r)) if np.isfinite(r).any() else None,
            "ransac_iterations": self.ransac.iterations,
            "rotation_angle_deg": rot_deg,
            "views_used": list(self.views_used),
            "views_rejected": dict(self.views_rejected),
        }


def calibrate_tof_stereo(
    views: Sequence[TofStereoView],
    stereo: StereoCalibration | dict[str, Any],
    pattern: tuple[int, int],
    tof_pattern: tuple[int, int] | None = None,
    upscale: int = 2,
    border: int = 0,
    lift: str = "interp",
    threshold: float = 0.03,
    tof_subpix_window: float = 2.5,
    rng: np.random.Generator | int | None = 0,
) -> TofStereoCalibration:
    """ToF-to-left-camera extrinsics from several board poses seen by all three sensors.

    ``pattern`` is the board's inner corner count (per row, rows) as the stereo images show it;
    ``tof_pattern`` defaults to the same. ``border`` drops that many outer rings of corners on
    the ToF side (nearest the board edge, where mixed pixels and multipath lie). ``lift``:
    ``interp`` (XYZ interpolated at each corner, seed 004's method) or ``plane`` (corner rays cut
    with a plane fitted to the board's ToF points: less noise). ``threshold``: RANSAC inlier
    distance in metres.
    """
    cal = load_calibration(stereo)
    tof_pattern = tof_pattern or pattern
    if tuple(tof_pattern) != tuple(pattern):
        raise ValueError("the ToF and stereo views must find the same corner grid (tof_pattern == pattern)")
    if lift not in ("interp", "plane"):
        raise ValueError(f"lift must be 'interp' or 'plane', not {lift!r}")
    nx, ny = pattern
    keep = np.zeros((ny, nx), bool)
    keep[border:ny - border, border:nx - border] = True
    keep = keep.ravel()
    tof_pts, st_pts, owner = [], [], []
    used: list[str] = []
    rejected: dict[str, str] = {}
    for i, v in enumerate(views):
        name = v.name or f"view{i}"
        ct = find_corners(v.tof_amplitude, pattern, upscale=upscale, subpix_window=tof_subpix_window,
                          prefer="classic")
        if ct is None:
            rejected[name] = "board not found in the ToF amplitude image"
            continue
        cl = find_corners(v.left, pattern)
        cr = find_corners(v.right, pattern) if cl is not None else None
        if cl is None or cr is None:
            rejected[name] = "board not found in the " + ("left" if cl is None else "right") + " image"
            continue
        if lift == "plane":
            pt = lift_tof_corners_plane(v.tof_xyz, ct, pattern)
        else:
            pt = lift_tof_corners(v.tof_xyz, ct)
        ps = triangulate(cl, cr, cal)
        sel = keep & np.isfinite(pt).all(axis=1) & np.isfinite(ps).all(axis=1)
        if sel.sum() < 3:
            rejected[name] = "fewer than 3 corners with ToF depth"
            continue
        tof_pts.append(pt[sel])
        st_pts.append(ps[sel])
        owner.append(np.full(int(sel.sum()), i))
        used.append(name)
    if not used:
        raise ValueError("no view had the board in all three images: " + "; ".join(f"{k}: {m}" for k, m in rejected.items()))
    A = np.concatenate(tof_pts)
    B = np.concatenate(st_pts)
    res = ransac_absolute_orientation(A, B, threshold=threshold, rng=rng)
    return TofStereoCalibration(res.R, res.t, res, A, B, np.concatenate(owner), used, rejected)
