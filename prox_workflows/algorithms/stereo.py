"""Stereo to 3D (seed 000 sect. 3.1.3): rectification, semi-global matching, reprojection, noise.

The thesis's RVS matched with JR's HFVM; this step uses OpenCV's semi-global matcher instead,
wrapped so that what leaves it can be trusted point by point: a left-right consistency check
(each left match must be found again when matching from the right), speckle filtering (small
islands of disparity are mismatches more often than small objects) and a texture mask (a
patch without intensity variation has no match to find, whatever the cost function says). The
mask measures texture against the noise of the image at hand (:func:`noise_scale`), not against
one camera's noise model, and leaves small blank gaps in textured ground to the matcher, which
carries the disparity across them; what it takes out are wide blank surfaces in a noisy image.

Two geometries, both float32 disparity in pixels with NaN where invalid:

* **rectified**: the left image after ``cv2.stereoRectify`` (alpha 0, same size as the input):
  rows are epipolar lines, ``x_right = x_left - d`` and ``Z = f * b / d``. This is where the
  matcher works and where ``cv2.reprojectImageTo3D(d, Q)`` applies.
* **left**: the left camera's original (distorted) image. Each left pixel gets the rectified
  disparity of the spot it sees (sampled at its rectified position), so the disparity image
  overlays the left image a user looks at, and the 3D point of every left pixel is exact
  (the rectified position, not a resampled one, goes into Q).

Points leave in the left camera's original frame (OpenCV optical: x right, y down, z forward):
the rectified frame is rotated by R1, which :func:`reproject_rectified` undoes.

The calibration is OpenCV's ``stereoCalibrate`` naming: K1 D1 K2 D2 R T image_size, with
``x_right = R x_left + T`` in metres (a right camera 0.2 m to the right has T = [-0.2, 0, 0]).
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import tifffile
import yaml

from ..products import write_yaml_atomic

CALIB_KEYS = ("image_size", "K1", "D1", "K2", "D2", "R", "T")
MODES = {
    "sgbm": cv2.StereoSGBM_MODE_SGBM,
    "sgbm_3way": cv2.StereoSGBM_MODE_SGBM_3WAY,
    "hh": cv2.StereoSGBM_MODE_HH,
    "hh4": cv2.StereoSGBM_MODE_HH4,
}
# px (full resolution): disparity noise of the matcher. On the simulated pairs the error of the
# LR-consistent matches has a standard deviation of 0.19 px at full scale and 0.30 px at half
# scale (SGBM's sub-pixel step locks towards whole pixels); 0.25 / sqrt(scale) covers both.
DEFAULT_SIGMA_D = 0.25
# The sensor noise the texture mask measures texture against (:func:`noise_dn`): electrons per
# 8-bit DN when 255 is the full well (PIKE F-210B class CCD: 20,000 e-, at 0 dB; the simulator's
# drivers.stereo.imaging.SensorModel) and the read noise. Shot noise then is sqrt(DN / 78) DN:
# 1.6 DN at 200, 0.6 DN at 30.
NOISE_E_PER_DN = 20000.0 / 255.0
NOISE_READ_E = 12.0
# The 1st percentile of :func:`_local_noise_ratio` over an image of pure model noise (any level
# from 20 to 230 DN, 7 x 7 windows: 0.617-0.625): what :func:`noise_scale` divides by, so that an
# image whose flattest windows hold exactly the model's noise measures 1.0.
NOISE_RATIO_P1 = 0.62
# What :func:`noise_scale` measures on a noiseless 8-bit image (its quantisation: 0.21): the least
# noise the texture mask's reach assumes (:func:`texture_reach_for`).
NOISE_SCALE_FLOOR = 0.25
# The discrete Laplacian whose response to white noise of sigma has a standard deviation of 6 sigma
# and to a linear intensity ramp none: the noise estimator's high-pass (Immerkaer 1996).
_NOISE_KERNEL = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)


def sigma_d_for(scale: float) -> float:
    """Disparity noise (full-resolution px) of matching at ``scale``."""
    return DEFAULT_SIGMA_D / math.sqrt(scale)


# -- calibration file -------------------------------------------------------------------------------
@dataclass(frozen=True)
class StereoCalibration:
    """Intrinsics and distortion of both cameras and the right camera's pose in the left frame."""

    K1: np.ndarray
    D1: np.ndarray
    K2: np.ndarray
    D2: np.ndarray
    R: np.ndarray
    T: np.ndarray
    image_size: tuple[int, int]  # (width, height)

    @property
    def baseline(self) -> float:
        return float(np.linalg.norm(self.T))

    def key(self) -> bytes:
        """Identity for caches: equal calibrations share their rectification maps."""
        parts = [np.ascontiguousarray(a, np.float64).tobytes() for a in (self.K1, self.D1, self.K2, self.D2, self.R, self.T)]
        return b"|".join(parts) + repr(tuple(self.image_size)).encode()

    def to_dict(self) -> dict[str, Any]:
        return {
            "image_size": [int(self.image_size[0]), int(self.image_size[1])],
            "K1": self.K1.tolist(), "D1": self.D1.tolist(),
            "K2": self.K2.tolist(), "D2": self.D2.tolist(),
            "R": self.R.tolist(), "T": self.T.tolist(),
        }


def read_image(path: str | Path) -> np.ndarray:
    """TIFF (tifffile), .npy, or anything OpenCV reads (PNG, PGM, JPEG; colour returned as RGB)."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix in (".tif", ".tiff"):
        return np.asarray(tifffile.imread(path))
    if suffix == ".npy":
        return np.load(path)
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"{path}: not an image OpenCV can read")
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    elif img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    return img



def load_calibration(source: str | os.PathLike[str] | Mapping[str, Any] | StereoCalibration) -> StereoCalibration:
    """A calibration from a YAML file (plain lists, or OpenCV FileStorage ``!!opencv-matrix``),
    a mapping with the same keys (what ``drivers.stereo`` returns), or one already loaded."""
    if isinstance(source, StereoCalibration):
        return source
    where = "calibration"
    if isinstance(source, Mapping):
        doc: Mapping[str, Any] = source
    else:
        path = Path(source)
        where = f"calibration file {path}"
        text = path.read_text()
        doc = _read_opencv_yaml(path) if text.lstrip().startswith("%YAML") else yaml.safe_load(text)
        if not isinstance(doc, Mapping):
            raise ValueError(f"{where} must be a mapping with {', '.join(CALIB_KEYS)}")
    missing = [k for k in CALIB_KEYS if k not in doc]
    if missing:
        raise ValueError(f"{where} lacks {', '.join(missing)} (keys: {', '.join(CALIB_KEYS)})")
    out: dict[str, Any] = {}
    for key, shape in (("K1", (3, 3)), ("K2", (3, 3)), ("R", (3, 3)), ("T", (3,))):
        arr = np.asarray(doc[key], dtype=np.float64)
        if arr.size != int(np.prod(shape)):
            raise ValueError(f"{where}: {key} must have {int(np.prod(shape))} values, has {arr.size}")
        out[key] = arr.reshape(shape)
    for key in ("D1", "D2"):
        arr = np.asarray(doc[key] if doc[key] is not None else [], dtype=np.float64).ravel()
        if arr.size not in (0, 4, 5, 8, 12, 14):
            raise ValueError(f"{where}: {key} must hold 4, 5, 8, 12 or 14 OpenCV distortion coefficients")
        out[key] = arr if arr.size else np.zeros(5)
    size = [int(v) for v in np.asarray(doc["image_size"]).ravel()]
    if len(size) != 2 or min(size) <= 0:
        raise ValueError(f"{where}: image_size must be [width, height]")
    if not np.isclose(np.linalg.det(out["R"]), 1.0, atol=1e-3):
        raise ValueError(f"{where}: R is not a rotation (det {np.linalg.det(out['R']):.4f})")
    if np.linalg.norm(out["T"]) <= 0:
        raise ValueError(f"{where}: T is zero: the cameras need a baseline")
    return StereoCalibration(out["K1"], out["D1"], out["K2"], out["D2"], out["R"], out["T"], (size[0], size[1]))


def _read_opencv_yaml(path: Path) -> dict[str, Any]:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        doc: dict[str, Any] = {}
        for key in CALIB_KEYS:
            node = fs.getNode(key)
            if node.empty():
                continue
            if node.isSeq():
                doc[key] = [node.at(i).real() for i in range(node.size())]
            else:
                doc[key] = node.mat()
        return doc
    finally:
        fs.release()


def save_calibration(path: str | os.PathLike[str], calib: StereoCalibration | Mapping[str, Any],
                     **extra: Any) -> Path:
    """Write the CALIB.yaml that :func:`load_calibration` and ``rvs-stereo --calib`` read."""
    data = load_calibration(calib).to_dict()
    data.update(extra)
    return write_yaml_atomic(Path(path), data)


# -- rectification ----------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Rectification:
    """The rectified pair and the maps between it and the original images (read-only arrays).

    ``left_to_rect`` holds, for every left original pixel, its (x, y) in the rectified left
    image: the map that brings rectified results back to the left image.
    """

    calib: StereoCalibration
    R1: np.ndarray
    R2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    Q: np.ndarray
    map_left: tuple[np.ndarray, np.ndarray]
    map_right: tuple[np.ndarray, np.ndarray]
    left_to_rect: np.ndarray  # H x W x 2 float32
    size: tuple[int, int]

    @property
    def focal(self) -> float:
        return float(self.P1[0, 0])

    @property
    def baseline(self) -> float:
        return float(abs(self.P2[0, 3] / self.P2[0, 0]))


def rectification(calib: StereoCalibration | Mapping[str, Any] | str | os.PathLike[str]) -> Rectification:
    """``cv2.stereoRectify`` + ``initUndistortRectifyMap`` for both cameras, cached per calibration
    (a pair of 1920 x 1080 maps costs ~0.5 s; a sequence of views reuses them)."""
    cal = load_calibration(calib)
    key = cal.key()
    with _CACHE_LOCK:
        hit = _CACHE.get(key)
        if hit is not None:
            _CACHE.move_to_end(key)
            return hit
    rect = _rectify(cal)
    with _CACHE_LOCK:
        _CACHE[key] = rect
        while len(_CACHE) > _CACHE_SIZE:
            _CACHE.popitem(last=False)
    return rect


_CACHE: OrderedDict[bytes, Rectification] = OrderedDict()
_CACHE_LOCK = threading.Lock()
_CACHE_SIZE = 4


def _rectify(cal: StereoCalibration) -> Rectification:
    size = (int(cal.image_size[0]), int(cal.image_size[1]))
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
        cal.K1, cal.D1, cal.K2, cal.D2, size, cal.R, cal.T.reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY, alpha=0.0,
    )
    if abs(P2[0, 3]) < abs(P2[1, 3]):
        raise ValueError("vertical stereo (right camera above/below the left) is not supported: "
                         "the matcher needs a horizontal baseline")
    if P2[0, 3] > 0:
        raise ValueError(f"T = {cal.T.tolist()} puts the right camera LEFT of the left one (T[0] > 0): "
                         "left and right are swapped (images, camera ids or the calibration)")
    map_left = cv2.initUndistortRectifyMap(cal.K1, cal.D1, R1, P1, size, cv2.CV_16SC2)
    map_right = cv2.initUndistortRectifyMap(cal.K2, cal.D2, R2, P2, size, cv2.CV_16SC2)
    w, h = size
    us, vs = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    pts = np.stack([us.ravel(), vs.ravel()], axis=1).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 1e-6)
    rect_pts = cv2.undistortPointsIter(pts, cal.K1, cal.D1, R1, P1, criteria) if hasattr(cv2, "undistortPointsIter") \
        else cv2.undistortPoints(pts, cal.K1, cal.D1, R=R1, P=P1, criteria=criteria)
    left_to_rect = rect_pts.reshape(h, w, 2).astype(np.float32)
    for arr in (R1, R2, P1, P2, Q, *map_left, *map_right, left_to_rect):
        arr.flags.writeable = False
    return Rectification(cal, R1, R2, P1, P2, Q, map_left, map_right, left_to_rect, size)


def to_gray8(image: np.ndarray, white: float | None = None) -> np.ndarray:
    """mono8 as it is; RGB to grey (luma); deeper images (mono16, float) scaled so ``white`` (default:
    the image's 99.9th percentile) becomes 255."""
    img = np.asarray(image)
    if img.ndim == 3:
        if img.dtype not in (np.uint8, np.uint16, np.float32):
            img = img.astype(np.float32)
        img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY if img.shape[2] == 3 else cv2.COLOR_RGBA2GRAY)
    if img.dtype == np.uint8:
        return img
    data = img.astype(np.float32)
    if white is None:
        white = _white(data)
    return np.clip(data * (255.0 / max(white, 1e-6)), 0, 255).astype(np.uint8)


def _white(image: np.ndarray) -> float:
    data = np.asarray(image, dtype=np.float32)
    ok = np.isfinite(data)
    return float(np.percentile(data[ok], 99.9)) if ok.any() else 1.0


def gray_pair(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both images as mono8 on one scale (a deeper pair keeps its equal brightness), unrectified."""
    white = None
    if np.asarray(left).dtype != np.uint8:
        white = max(_white(left), _white(right))
    return to_gray8(left, white), to_gray8(right, white)


def rectify_pair(left: np.ndarray, right: np.ndarray, rect: Rectification) -> tuple[np.ndarray, np.ndarray]:
    return _remap_pair(*_checked_gray_pair(left, right, rect), rect)


def _checked_gray_pair(left: np.ndarray, right: np.ndarray, rect: Rectification) -> tuple[np.ndarray, np.ndarray]:
    w, h = rect.size
    for name, img in (("left", left), ("right", right)):
        if img.shape[1] != w or img.shape[0] != h:
            raise ValueError(f"{name} image is {img.shape[1]}x{img.shape[0]}, the calibration is for {w}x{h}: "
                             "calibrate this resolution mode")
    return gray_pair(left, right)


def _remap_pair(gl: np.ndarray, gr: np.ndarray, rect: Rectification) -> tuple[np.ndarray, np.ndarray]:
    rl = cv2.remap(gl, *rect.map_left, cv2.INTER_LINEAR)
    rr = cv2.remap(gr, *rect.map_right, cv2.INTER_LINEAR)
    return rl, rr


# -- matching ---------------------------------------------------------------------------------------
@dataclass
class SgbmParams:
    """Matcher settings. The defaults are tuned on the simulated PIKE pair (see tools/bench/stereo.py).

    ``num_disparities`` None: enough for ``min_depth`` (f * b / min_depth, rounded up to 16).
    ``scale`` < 1 matches a downsampled pair (0.5: half resolution) and scales the disparity back
    up: ~4x faster, coarser detail. ``lr_max_diff`` <= 0 switches the left-right check off.

    ``texture_threshold``: a pixel is declared blank where the local grey-level standard deviation
    (over ``texture_window``) is below this many times the noise the image carries at the local
    mean level (:func:`noise_dn`: shot noise, read noise, quantisation; 0 switches the mask off).
    Relative to the noise, not absolute: an absolute 2.5 DN threshold threw away most shadowed
    ground (dim, so its texture is a few DN, yet well above its own noise) while a bright blank
    wall's spread is its shot noise.

    ``texture_noise``: that noise as a fraction of the PIKE model's. None (default) measures it on
    each image as taken (:func:`noise_scale`, never above the model): the simulated PIKE pairs
    measure 1.0 (their mask is the model's), Middlebury's pairs 0.3-0.6 (its quarter-size
    images are 4 x 4 averages). Judged against the PIKE's noise, those clean images' low-contrast
    ground looked blank although it matched well; it is the noise that makes a blank surface
    dangerous, which the same pair with the PIKE's noise added shows (docs/STEREO_BENCH.md).
    1.0 restores the fixed model.

    ``texture_reach`` (px at full resolution, at the PIKE's noise): a blank patch is only masked
    if it reaches farther than this from texture; narrower gaps are left to the matcher, whose
    smoothness term carries the surrounding disparity across them. The reach grows as 1 / noise^2
    (:func:`texture_reach_for`): 12 px at the model's noise, ~100 px at Motorcycle's. The office's
    blank walls and box faces reach 15-120 px from texture at 640 x 480 and stay masked (16 px
    already lets one in and costs the office DEM 0.3 cm); Motorcycle's blank gaps reach 4-10 px.

    ``uniqueness`` 5: the left-right check already rejects what an ambiguous match gets
    wrong, so the looser ratio leaves the simulated DEMs as they were and answers a few more
    pixels on real pairs, about half of them right (docs/STEREO_BENCH.md, item 3).

    What these defaults give against OpenCV's SGBM, on Middlebury and the simulated pairs, is
    measured by ``tools/bench/stereo.py --table`` and kept in docs/STEREO_BENCH.md.

    ``mode``: ``sgbm_3way`` (default) because on the PIKE's full-size pairs it is both the fastest
    and the most accurate of OpenCV's modes (tools/bench/stereo.py); block size 3 and 7 change
    neither much. The 3-way mode ignores ``disp12MaxDiff``, hence the explicit left-right check,
    which removes most of the pixels more than 2 px off.

    ``fill`` (off by default) completes the disparity where the filters rejected it
    (:func:`fill_disparity`: background-preferring scanline fill, then an edge-aware weighted
    median of radius ``fill_radius`` guided by the left image, grey-level scale ``fill_sigma``).
    On real scenes the filters reject a tenth of the pixels (occlusions, thin structures); filling
    about halves the share of pixels that are invalid or > 2 px off while the measured pixels keep
    their error (tools/bench/stereo.py, docs/STEREO_BENCH.md). The filled values stay guesses: :class:`Disparity` keeps the
    measured-only disparity beside them and the point cloud (:func:`cloud`, hence every DEM) is
    made of measured pixels only; the filled disparity is for images and dense consumers.
    """

    num_disparities: int | None = None
    min_depth: float = 1.5
    min_disparity: int = 0
    block_size: int = 5
    mode: str = "sgbm_3way"
    uniqueness: int = 5
    pre_filter_cap: int = 31
    p1_factor: int = 8
    p2_factor: int = 32
    lr_max_diff: float = 1.0
    speckle_window: int = 200
    speckle_range: float = 1.0
    texture_window: int = 7
    texture_threshold: float = 1.5  # x the image's noise (noise_dn), not DN
    texture_noise: float | None = None  # x the PIKE model's noise; None: measured per image
    texture_reach: float = 12.0  # px (full resolution, PIKE noise): narrower blank gaps are left to the matcher
    scale: float = 1.0
    pad: bool = True  # pad the left border so the first num_disparities columns are matched too
    fill: bool = False
    fill_radius: int = 3
    fill_sigma: float = 10.0

    @classmethod
    def from_dict(cls, values: Mapping[str, Any] | None) -> SgbmParams:
        known = {f for f in cls.__dataclass_fields__}
        values = dict(values or {})
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"unknown stereo parameter(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")
        # a value of the wrong type (a word where a number goes, from a --set or a YAML file) is
        # refused by name here; check() compares numbers and would fail on it with a TypeError
        defaults = cls()
        for key, value in values.items():
            default = getattr(defaults, key)
            if isinstance(default, bool) or key == "mode":
                ok = isinstance(value, type(default))
            elif value is None:
                ok = key in ("num_disparities", "texture_noise")
            else:
                ok = isinstance(value, int | float) and not isinstance(value, bool) and (
                    not isinstance(default, int) or float(value).is_integer())
            if not ok:
                what = "true or false" if isinstance(default, bool) else "a word" if key == "mode" else (
                    "an integer" if isinstance(default, int) else "a number")
                raise ValueError(f"stereo parameter {key} takes {what}, not {value!r}")
        out = cls(**values)
        out.check()
        return out

    def check(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"mode {self.mode!r} not one of {', '.join(MODES)}")
        if self.block_size < 1 or self.block_size % 2 == 0:
            raise ValueError("block_size must be odd and >= 1")
        if not 0.1 <= self.scale <= 1.0:
            raise ValueError("scale must be in [0.1, 1]")
        if self.fill_radius < 0 or self.fill_sigma <= 0:
            raise ValueError("fill_radius must be >= 0 and fill_sigma > 0")
        if self.texture_noise is not None and not 0.0 <= self.texture_noise <= 10.0:
            raise ValueError("texture_noise must be None (measured) or in [0, 10]")
        if self.texture_reach < 0 or self.texture_window < 1:
            raise ValueError("texture_reach must be >= 0 and texture_window >= 1")

    def disparities_for(self, rect: Rectification) -> int:
        """numDisparities at the matching scale (a multiple of 16)."""
        if self.num_disparities is not None:
            nd = int(self.num_disparities * self.scale)
        else:
            nd = int(math.ceil(rect.focal * rect.baseline / max(self.min_depth, 1e-3) * self.scale))
        return max(16, -(-nd // 16) * 16)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class Disparity:
    """Disparity of one pair in both geometries (float32 px, NaN invalid), with its rectification.

    With ``params.fill`` the ``left`` and ``rectified`` arrays are the filled ones and
    ``left_measured`` / ``rectified_measured`` hold the matcher's own (left-right checked,
    filtered) disparity; without it those are None and nothing is filled.
    """

    left: np.ndarray
    rectified: np.ndarray
    rect: Rectification
    params: SgbmParams
    timings: dict[str, float] = field(default_factory=dict)
    left_measured: np.ndarray | None = None
    rectified_measured: np.ndarray | None = None
    # the image noise the texture mask used, as a fraction of the PIKE model (None: mask off)
    noise_scale: float | None = None

    @property
    def measured(self) -> np.ndarray:
        """Left-geometry disparity of the matched pixels only (filled ones NaN)."""
        return self.left if self.left_measured is None else self.left_measured

    @property
    def filled_mask(self) -> np.ndarray:
        """True on left pixels whose disparity is a fill, not a measurement."""
        return np.isfinite(self.left) & ~np.isfinite(self.measured)

    def points(self, measured_only: bool = True) -> np.ndarray:
        """H x W x 3 float32 in the left camera frame, per left original pixel (NaN invalid).
        Filled disparities make no points unless ``measured_only`` is False: a DEM wants only
        points the matcher vouches for."""
        return reproject_left(self.measured if measured_only else self.left, self.rect)

    def sigma_z(self, sigma_d: float | None = None) -> np.ndarray:
        """Depth standard deviation per left pixel (m), from the noise model (``sigma_d`` None:
        the measured noise at this matching scale)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            z = self.rect.focal * self.rect.baseline / self.left
        sd = sigma_d_for(self.params.scale) if sigma_d is None else sigma_d
        return depth_sigma(z, self.rect.baseline, self.rect.focal, sd)


def _matcher(params: SgbmParams, nd: int) -> Any:
    bs = params.block_size
    return cv2.StereoSGBM_create(
        minDisparity=params.min_disparity,
        numDisparities=nd,
        blockSize=bs,
        P1=params.p1_factor * bs * bs,
        P2=params.p2_factor * bs * bs,
        disp12MaxDiff=-1,  # our own, full left-right check below
        preFilterCap=params.pre_filter_cap,
        uniquenessRatio=params.uniqueness,
        speckleWindowSize=0,  # filterSpeckles below, after the consistency check
        speckleRange=0,
        mode=MODES[params.mode],
    )


def _compute(matcher: Any, a: np.ndarray, b: np.ndarray, pad: int) -> np.ndarray:
    """Fixed-point (x16) disparity of ``a`` against ``b``; the left ``pad`` columns are padding
    that lets the matcher score the first columns of ``a`` instead of leaving them invalid."""
    if pad:
        a = cv2.copyMakeBorder(a, 0, 0, pad, 0, cv2.BORDER_REPLICATE)
        b = cv2.copyMakeBorder(b, 0, 0, pad, 0, cv2.BORDER_REPLICATE)
    d = matcher.compute(a, b)
    return d[:, pad:] if pad else d


def noise_dn(mean: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """The grey-level noise (DN rms) a pixel of mean level ``mean`` carries: shot noise of
    ``mean * NOISE_E_PER_DN`` electrons and read noise, both times ``scale`` (the image's noise
    against the PIKE model, :func:`noise_scale`), and 8-bit quantisation, which no camera escapes.
    The same at every matching scale: area averaging lowers the noise of a downsampled pair, but
    thresholding it at full-resolution noise keeps the blank walls out at half scale as well
    (with the noise scaled down, the extra matches at half scale are on the walls; the figures
    are in docs/STEREO_BENCH.md)."""
    sensor = np.maximum(mean, 0.0) / NOISE_E_PER_DN + (NOISE_READ_E / NOISE_E_PER_DN) ** 2
    return np.sqrt(scale * scale * sensor + 1.0 / 12.0)


def _local_noise_ratio(image: np.ndarray, window: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel, the rms of the Laplacian over ``window`` (an estimate of the noise there, raised
    by any texture) over the PIKE model's sensor noise at the local mean; and where that estimate
    is usable: no clipped pixel (0 or 255, which carry no noise) in the window, not at the border."""
    img = np.asarray(image)
    g = img.astype(np.float32)
    mean = cv2.boxFilter(g, -1, (window, window), borderType=cv2.BORDER_REFLECT)
    lap = cv2.filter2D(g, -1, _NOISE_KERNEL, borderType=cv2.BORDER_REFLECT)
    local = np.sqrt(cv2.boxFilter(lap * lap, -1, (window, window), borderType=cv2.BORDER_REFLECT)) / 6.0
    kernel = np.ones((window, window), np.uint8)
    usable = (cv2.erode(img, kernel) > 0) & (cv2.dilate(img, kernel) < 255)
    edge = window // 2 + 1
    usable[:edge] = usable[-edge:] = False
    usable[:, :edge] = usable[:, -edge:] = False
    model = np.sqrt(np.maximum(mean, 0.0) / NOISE_E_PER_DN + (NOISE_READ_E / NOISE_E_PER_DN) ** 2)
    return local / model, usable


def noise_scale(image: np.ndarray, window: int = 7) -> float:
    """The noise of a mono8 image as taken (before any resampling), as a fraction of the PIKE
    model's at the same brightness, capped at 1.0.

    The flattest windows of an image hold nothing but its noise, so the 1st percentile of the local
    Laplacian rms over the model noise, divided by what pure model noise gives (NOISE_RATIO_P1),
    is the image's noise against the model. Texture only raises the estimate (an image without a
    flat window measures its texture), hence the cap: above the model the mask stays the model's.
    Measure the image as the camera gave it: rectifying interpolates and smooths the noise (the
    simulated office measures 1.2-1.35 before remapping, 0.53-0.59 after). Too few usable windows
    (a saturated or tiny image) give 1.0, the model."""
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim != 2:
        img = to_gray8(img)
    ratio, usable = _local_noise_ratio(img, window)
    values = ratio[usable]
    if values.size < 1000:
        return 1.0
    k = max(int(values.size * 0.01), 1)
    p1 = float(np.partition(values, k)[k])
    return min(1.0, p1 / NOISE_RATIO_P1)


def texture_mask(image: np.ndarray, window: int, threshold: float, noise: float = 1.0,
                 reach: float = 0.0) -> np.ndarray:
    """True where the local grey-level standard deviation (over ``window``) reaches ``threshold``
    times the noise expected at the local mean level (:func:`noise_dn` at scale ``noise``):
    matchable texture is texture that stands out of the noise, so a dim but textured shadow passes
    and a bright blank wall, whose spread is the noise itself, does not.

    With ``reach`` > 0 a blank patch is only masked if some pixel of it lies farther than ``reach``
    px from texture: a narrow gap in textured ground is bridged by the matcher's smoothness term
    from both sides, a wide blank surface is not (there the noise, not the surroundings, decides
    the disparity)."""
    img = image.astype(np.float32)
    mean = cv2.boxFilter(img, -1, (window, window), borderType=cv2.BORDER_REFLECT)
    mean2 = cv2.boxFilter(img * img, -1, (window, window), borderType=cv2.BORDER_REFLECT)
    var = np.maximum(mean2 - mean * mean, 0.0)
    limit = threshold * noise_dn(mean, noise)
    textured = var >= limit * limit
    if reach <= 0 or textured.all():
        return textured
    blank = (~textured).astype(np.uint8)
    depth = cv2.distanceTransform(blank, cv2.DIST_L2, 5)  # px to the nearest textured pixel
    count, labels = cv2.connectedComponents(blank, connectivity=8)
    wide = np.zeros(count, bool)
    wide[labels[depth > reach]] = True
    wide[0] = False  # label 0 is the textured ground
    return ~wide[labels]


def disparity_rectified(rl: np.ndarray, rr: np.ndarray, params: SgbmParams, nd: int,
                        timings: dict[str, float] | None = None, noise: float | None = None) -> np.ndarray:
    """SGBM with left-right check, speckle filter and texture mask on a rectified pair at its own
    resolution; float32 px, NaN invalid.

    The texture mask's noise: ``params.texture_noise`` if set, else ``noise`` (what
    :func:`disparity` measured on the left image as taken), else measured on ``rl`` itself, which
    is right for pairs that come rectified (Middlebury's) and too low for pairs remapped here."""
    timings = {} if timings is None else timings
    t0 = time.perf_counter()
    matcher = _matcher(params, nd)
    pad = nd + max(params.min_disparity, 0) if params.pad else 0
    invalid16 = (params.min_disparity - 1) * 16
    dl16 = _compute(matcher, rl, rr, pad)
    timings["match_left"] = time.perf_counter() - t0
    valid = dl16 > invalid16
    if params.lr_max_diff > 0:
        t1 = time.perf_counter()
        # The right image's disparity: match the mirrored pair, the right image taking the left's
        # role, and mirror back. Its values are positive: right x + d = left x.
        dr16 = _compute(matcher, cv2.flip(rr, 1), cv2.flip(rl, 1), pad)[:, ::-1]
        timings["match_right"] = time.perf_counter() - t1
        h, w = dl16.shape
        xs = np.arange(w, dtype=np.int32)[None, :]
        xr = xs - np.rint(dl16.astype(np.float32) / 16.0).astype(np.int32)
        inside = valid & (xr >= 0) & (xr < w)
        back = np.take_along_axis(dr16, np.clip(xr, 0, w - 1), axis=1)
        agree = np.abs(dl16.astype(np.int32) - back.astype(np.int32)) <= params.lr_max_diff * 16
        valid &= inside & agree & (back > invalid16)
    t2 = time.perf_counter()
    if params.speckle_window > 0:
        d16 = np.where(valid, dl16, invalid16).astype(np.int16)
        cv2.filterSpeckles(d16, invalid16, params.speckle_window, int(round(params.speckle_range * 16)))
        valid &= d16 > invalid16
    if params.texture_threshold > 0:
        scale = texture_noise_for(params, rl, noise)
        valid &= texture_mask(rl, params.texture_window, params.texture_threshold, scale,
                              texture_reach_for(params, scale))
    out = dl16.astype(np.float32) / 16.0
    out[~valid] = np.nan
    timings["filters"] = time.perf_counter() - t2
    return out


def texture_noise_for(params: SgbmParams, image: np.ndarray, measured: float | None = None) -> float:
    """The noise scale the texture mask uses: the settings' fixed one, else ``measured``, else
    :func:`noise_scale` of ``image``."""
    if params.texture_noise is not None:
        return float(params.texture_noise)
    return noise_scale(image) if measured is None else float(measured)


def texture_reach_for(params: SgbmParams, noise: float) -> float:
    """How far (px at the matching scale) the matcher carries a disparity into a blank patch at
    image noise ``noise`` (x the PIKE model): ``texture_reach`` at the model's noise, growing as
    1 / noise^2. Along a path through a blank patch the cost of the disparity brought in from the
    texture against its neighbours' drifts by noise alone, as a random walk: after n pixels by
    ~noise * sqrt(n), so it outweighs the penalty of a disparity step (P1) after n ~ (P1 / noise)^2
    pixels. The noise is floored at NOISE_SCALE_FLOOR, what a noiseless 8-bit image measures.
    Matching a downsampled pair, the reach shrinks with it, so the same walls stay out at every
    scale (as the noise is kept at its full-resolution level, :func:`noise_dn`)."""
    if params.texture_reach <= 0:
        return 0.0
    return float(params.texture_reach * params.scale / max(noise, NOISE_SCALE_FLOOR) ** 2)


def _scanline_fill(disp: np.ndarray, smooth_jump: float = 1.0) -> np.ndarray:
    """Each invalid pixel from the nearest valid ones left and right on its row: interpolated
    linearly where the two agree within ``smooth_jump`` px (a hole in one surface), else the
    smaller (background) one, since a gap between two depths is mostly the background that the
    nearer object hides from the other camera (occlusion). Rows without a valid pixel stay NaN."""
    h, w = disp.shape
    valid = np.isfinite(disp)
    cols = np.arange(w, dtype=np.int64)[None, :]
    li = np.maximum.accumulate(np.where(valid, cols, -1), axis=1)
    ri = np.minimum.accumulate(np.where(valid, cols, w)[:, ::-1], axis=1)[:, ::-1]
    rows = np.arange(h)[:, None]
    dl = np.where(li >= 0, disp[rows, np.clip(li, 0, w - 1)], np.nan)
    dr = np.where(ri < w, disp[rows, np.clip(ri, 0, w - 1)], np.nan)
    with np.errstate(invalid="ignore"):
        t = (cols - li) / np.maximum(ri - li, 1)
        lin = dl + (dr - dl) * t
        smooth = np.isfinite(dl) & np.isfinite(dr) & (np.abs(dl - dr) <= smooth_jump)
    out = np.where(smooth, lin, np.fmin(dl, dr))
    return np.where(valid, disp, out).astype(np.float32)


def _weighted_median(disp: np.ndarray, targets: np.ndarray, guide: np.ndarray, radius: int,
                     sigma: float, chunk: int = 65536) -> np.ndarray:
    """Edge-aware weighted median at the ``targets`` pixels: over the (2r+1)^2 window, each
    neighbour weighs exp(-|I - I_centre| / sigma) with I the guide image, so a filled value is
    voted on by the pixels that look like the same surface (what a WLS filter does with its
    edge-aware smoothness term, without cv2.ximgproc, absent from opencv-python-headless).
    The scanline fill's horizontal streaks are replaced by the 2-D neighbourhood's verdict."""
    out = disp.copy()
    h, w = disp.shape
    ys_all, xs_all = np.nonzero(targets & np.isfinite(disp))
    if radius <= 0 or ys_all.size == 0:
        return out
    g = guide.astype(np.float32)
    offs = [(dy, dx) for dy in range(-radius, radius + 1) for dx in range(-radius, radius + 1)]
    k = len(offs)
    for start in range(0, ys_all.size, chunk):
        ys, xs = ys_all[start:start + chunk], xs_all[start:start + chunk]
        gc = g[ys, xs]
        vals = np.empty((ys.size, k), np.float32)
        wts = np.empty((ys.size, k), np.float32)
        for j, (dy, dx) in enumerate(offs):
            yy = np.clip(ys + dy, 0, h - 1)
            xx = np.clip(xs + dx, 0, w - 1)
            v = disp[yy, xx]
            ok = np.isfinite(v)
            vals[:, j] = np.where(ok, v, np.inf)
            wts[:, j] = np.where(ok, np.exp(-np.abs(g[yy, xx] - gc) / sigma), 0.0)
        order = np.argsort(vals, axis=1)
        sv = np.take_along_axis(vals, order, 1)
        cw = np.cumsum(np.take_along_axis(wts, order, 1), axis=1)
        pos = np.minimum((cw < cw[:, -1:] * 0.5).sum(axis=1), k - 1)
        out[ys, xs] = sv[np.arange(ys.size), pos]
    return out


def fill_disparity(disp: np.ndarray, guide: np.ndarray, radius: int = 3, sigma: float = 10.0) -> np.ndarray:
    """A dense disparity from a filtered one (rectified geometry, NaN invalid), guided by the
    rectified left image ``guide`` (mono8): :func:`_scanline_fill` (background at occlusions),
    then :func:`_weighted_median` over the filled pixels only; measured pixels keep their value.

    Why not a second matching pass: the pixels the left-right check rejects are mostly
    half-occluded, seen by one camera only, and no matcher finds their match; the surface behind
    them (the background) is the best guess, which the scanline fill gives; the weighted median
    then pulls the filled pixels toward their neighbours of like grey (docs/STEREO_BENCH.md).
    """
    filled = _scanline_fill(disp)
    return _weighted_median(filled, ~np.isfinite(disp), guide, radius, sigma)


def sample_disparity(disp: np.ndarray, map_xy: np.ndarray, jump: float = 1.0) -> np.ndarray:
    """``disp`` at sub-pixel positions ``map_xy`` (H x W x 2): bilinear where the four neighbours are
    valid and agree (within ``jump`` px of the nearest), else the nearest valid value, so a
    depth edge is not smeared into flying pixels."""
    mx = np.ascontiguousarray(map_xy[..., 0], np.float32)
    my = np.ascontiguousarray(map_xy[..., 1], np.float32)
    valid = np.isfinite(disp)
    d0 = np.where(valid, disp, 0.0).astype(np.float32)
    nan = float("nan")
    lin = cv2.remap(d0, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
    weight = cv2.remap(valid.astype(np.float32), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                       borderValue=0.0)
    near = cv2.remap(disp.astype(np.float32), mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                     borderValue=nan)
    use_lin = (weight > 0.999) & (np.abs(lin - near) <= jump)
    return np.where(use_lin, lin, near).astype(np.float32)


def disparity(left: np.ndarray, right: np.ndarray,
              calib: StereoCalibration | Mapping[str, Any] | str | os.PathLike[str],
              params: SgbmParams | Mapping[str, Any] | None = None) -> Disparity:
    """Disparity of an unrectified pair as taken (any of mono8, mono16, rgb8), in both geometries."""
    p = params if isinstance(params, SgbmParams) else SgbmParams.from_dict(params)
    p.check()
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    rect = rectification(calib)
    timings["rectification_maps"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    gl, gr = _checked_gray_pair(left, right, rect)
    rl, rr = _remap_pair(gl, gr, rect)
    timings["rectify"] = time.perf_counter() - t1
    noise = None
    if p.texture_threshold > 0:  # measured before the remap smooths it
        t_noise = time.perf_counter()
        noise = texture_noise_for(p, gl)
        timings["noise"] = time.perf_counter() - t_noise
    nd = p.disparities_for(rect)
    if p.scale < 1.0:
        t2 = time.perf_counter()
        w, h = rect.size
        sw, sh = max(1, int(round(w * p.scale))), max(1, int(round(h * p.scale)))
        sl = cv2.resize(rl, (sw, sh), interpolation=cv2.INTER_AREA)
        sr = cv2.resize(rr, (sw, sh), interpolation=cv2.INTER_AREA)
        timings["downsample"] = time.perf_counter() - t2
        small = disparity_rectified(sl, sr, p, nd, timings, noise)
        small_filled = _fill_timed(small, sl, p, timings)
        t3 = time.perf_counter()
        fx, fy = sw / w, sh / h
        xs = ((np.arange(w, dtype=np.float32) + 0.5) * fx - 0.5)
        ys = ((np.arange(h, dtype=np.float32) + 0.5) * fy - 0.5)
        grid = np.stack(np.meshgrid(xs, ys), axis=-1)
        rectified = sample_disparity(small, grid, jump=1.0) / np.float32(fx)
        filled = None if small_filled is None else sample_disparity(small_filled, grid, jump=1.0) / np.float32(fx)
        timings["upsample"] = time.perf_counter() - t3
    else:
        rectified = disparity_rectified(rl, rr, p, nd, timings, noise)
        filled = _fill_timed(rectified, rl, p, timings)
    t4 = time.perf_counter()
    left_disp = sample_disparity(rectified, rect.left_to_rect, jump=1.0)
    left_filled = None if filled is None else sample_disparity(filled, rect.left_to_rect, jump=1.0)
    timings["unrectify"] = time.perf_counter() - t4
    timings["total"] = time.perf_counter() - t0
    if filled is None or left_filled is None:
        return Disparity(left_disp, rectified, rect, p, timings, noise_scale=noise)
    return Disparity(left_filled, filled, rect, p, timings, left_measured=left_disp, rectified_measured=rectified,
                     noise_scale=noise)


def _fill_timed(disp: np.ndarray, guide: np.ndarray, p: SgbmParams, timings: dict[str, float]) -> np.ndarray | None:
    if not p.fill:
        return None
    t = time.perf_counter()
    out = fill_disparity(disp, guide, p.fill_radius, p.fill_sigma)
    timings["fill"] = time.perf_counter() - t
    return out


# -- 3D -------------------------------------------------------------------------------------------
def reproject_rectified(disp_rect: np.ndarray, rect: Rectification) -> np.ndarray:
    """H x W x 3 float32 points in the left camera's original frame for a rectified-geometry
    disparity (``cv2.reprojectImageTo3D`` with Q, then the rectifying rotation undone)."""
    valid = np.isfinite(disp_rect) & (disp_rect > 0)
    d = np.where(valid, disp_rect, 0).astype(np.float32)
    pts = cv2.reprojectImageTo3D(d, rect.Q.astype(np.float64), handleMissingValues=False).astype(np.float64)
    pts[~valid] = np.nan  # zero disparity reprojects to infinity
    out = (pts.reshape(-1, 3) @ np.asarray(rect.R1)).reshape(pts.shape)  # R1^T x, row-wise
    return out.astype(np.float32)


def reproject_left(disp_left: np.ndarray, rect: Rectification) -> np.ndarray:
    """H x W x 3 float32 points in the left camera frame, one per left original pixel: Q applied
    to each pixel's exact rectified position and its disparity."""
    pts, rows, cols = _left_points(disp_left, rect)
    out = np.full((*disp_left.shape, 3), np.nan, np.float32)
    out[rows, cols] = pts
    return out


def _left_points(disp_left: np.ndarray, rect: Rectification) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`reproject_left`'s points of the pixels with a disparity only (N x 3 float32, and
    their rows and columns): a frame's cloud wants them, not the image of them."""
    rows, cols = np.nonzero(np.isfinite(disp_left) & (disp_left > 0))
    xy = rect.left_to_rect[rows, cols].astype(np.float64)
    d = disp_left[rows, cols].astype(np.float64)
    hom = np.column_stack([xy, d, np.ones_like(d)]) @ np.asarray(rect.Q).T
    x_rect = hom[:, :3] / hom[:, 3:4]
    return (x_rect @ np.asarray(rect.R1)).astype(np.float32), rows, cols


def depth_sigma(z: np.ndarray | float, baseline: float, focal: float,
                sigma_d: float = DEFAULT_SIGMA_D) -> np.ndarray:
    """Stereo depth noise sigma_z = z^2 * sigma_d / (b * f): first-order propagation of the
    disparity noise through Z = f b / d. Grows with the square of the range, which is why the
    stereo pair loses to the ToF camera near and wins far (seed 000 sect. 6.1)."""
    z = np.asarray(z, dtype=np.float64)
    return (z * z * sigma_d / (baseline * focal)).astype(np.float32)


def cloud(disp: Disparity, sigma_d: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N x 3 points in the left camera frame, N depth sigmas, N x 2 int left pixel (row, col)):
    measured pixels only, filled ones never (see :attr:`SgbmParams.fill`)."""
    p, rows, cols = _left_points(disp.measured, disp.rect)
    ok = np.isfinite(p[:, 2])
    p, rows, cols = p[ok], rows[ok], cols[ok]
    sd = sigma_d_for(disp.params.scale) if sigma_d is None else sigma_d
    sig = depth_sigma(p[:, 2], disp.rect.baseline, disp.rect.focal, sd)
    return p, sig, np.stack([rows, cols], axis=1)
