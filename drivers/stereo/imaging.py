"""Image formation for the simulated PIKE cameras: shading, lens distortion, exposure and noise.

The world renders geometry (depth, albedo, normals) for a pinhole camera; this module turns that
into what a CCD would deliver: a Lambertian sun-lit radiance, distorted by the lens with OpenCV's
radial-tangential model (so undistorting with the same K, D recovers the pinhole image), then
converted to electrons by the shutter time, with shot and read noise, a full well, the analogue
gain and 8-bit quantisation with saturation at 255.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np


@dataclass(frozen=True)
class SensorModel:
    """Radiometry of one camera; defaults give ~230 DN for a white sunlit surface at 8 ms, 0 dB."""

    full_well_e: float = 20000.0  # electrons (PIKE F-210B class CCD)
    read_noise_e: float = 12.0  # electrons rms
    white_dn_at_ref: float = 230.0  # DN of albedo 1, lambert 1 at ref_shutter_us and 0 dB
    ref_shutter_us: float = 8000.0
    noise: bool = True

    @property
    def electrons_per_us(self) -> float:
        return self.white_dn_at_ref / 255.0 * self.full_well_e / self.ref_shutter_us


@dataclass(frozen=True)
class Lighting:
    sun_azimuth_deg: float = 200.0  # CCW from +x (global frame): behind-left of the start pose
    sun_elevation_deg: float = 45.0
    ambient: float = 0.25  # fraction of light that does not depend on the surface orientation
    sky: float = 0.85  # radiance of pixels that hit nothing, relative to a white lit surface

    @property
    def sun_direction(self) -> np.ndarray:
        az, el = math.radians(self.sun_azimuth_deg), math.radians(self.sun_elevation_deg)
        return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


def radiance(albedo: np.ndarray, normal: np.ndarray, hit: np.ndarray, lighting: Lighting,
             sunlit: np.ndarray | None = None) -> np.ndarray:
    """Albedo times a Lambert term with ambient light; sky where nothing was hit (float32, HxW).

    ``sunlit`` (0..1, the render's cast-shadow share) scales the direct sun only: a shadow keeps
    the ambient (sky) light, as on real ground, so shadowed texture stays visible but dim."""
    lambert = np.clip(normal @ lighting.sun_direction.astype(np.float32), 0.0, 1.0)
    if sunlit is not None:
        lambert = lambert * sunlit
    shade = lighting.ambient + (1.0 - lighting.ambient) * lambert
    out = np.where(hit, np.nan_to_num(albedo) * shade, lighting.sky)
    return out.astype(np.float32)


@dataclass(frozen=True)
class DistortionMap:
    """Where each pixel of the distorted image lies in an undistorted render made with ``K_render``."""

    K_render: np.ndarray
    render_size: tuple[int, int]  # (width, height), larger than the image when barrel distortion needs margin
    map_x: np.ndarray | None  # None: no distortion, render directly
    map_y: np.ndarray | None


_MAPS: dict[tuple[bytes, bytes, tuple[int, int]], DistortionMap] = {}
_MAPS_KEPT = 16
_MAPS_LOCK = threading.Lock()
MAP_BAND_PIXELS = 100_000  # pixels undistorted between two looks at ``check``: some 0.1-0.2 s


def distortion_map(K: np.ndarray, D: np.ndarray, size: tuple[int, int],
                   check: Callable[[], None] | None = None) -> DistortionMap:
    """Cached per (K, D, size): the inverse of OpenCV's distortion for every output pixel.

    Made once per camera model and resolution, in seconds at the highest one: ``check`` (which
    raises to stop) is called between bands of rows, so a grab that makes it can be stopped;
    only a complete map is kept."""
    K = np.asarray(K, dtype=np.float64)
    D = np.asarray(D, dtype=np.float64).ravel()
    key = (K.tobytes(), D.tobytes(), (int(size[0]), int(size[1])))
    with _MAPS_LOCK:
        made = _MAPS.get(key)
    if made is None:
        made = _distortion_map(K, D, key[2], check)
        with _MAPS_LOCK:
            while len(_MAPS) >= _MAPS_KEPT:
                _MAPS.pop(next(iter(_MAPS)))
            _MAPS[key] = made
    return made


def _distortion_map(K: np.ndarray, D: np.ndarray, size: tuple[int, int],
                    check: Callable[[], None] | None) -> DistortionMap:
    w, h = size
    if not np.any(D):
        return DistortionMap(K.copy(), size, None, None)
    rows = max(1, MAP_BAND_PIXELS // w)
    und: np.ndarray | None = None
    for r0 in range(0, h, rows):
        # looked at before each band's pixels are laid out, the first time before anything the
        # size of the frame is (a 2-megapixel grid of coordinates is a good share of a second on
        # a busy machine, and the band's own pixels are all a band needs)
        if check is not None:
            check()
        if und is None:
            und = np.empty((h * w, 1, 2), dtype=np.float64)
        r1 = min(h, r0 + rows)
        band = np.empty((r1 - r0, w, 2), dtype=np.float64)
        band[..., 0] = np.arange(w, dtype=np.float64)
        band[..., 1] = np.arange(r0, r1, dtype=np.float64)[:, None]
        und[r0 * w:r1 * w] = _undistort_pixels(band.reshape(-1, 1, 2), K, D)
    assert und is not None
    und = und.reshape(h, w, 2)
    ux, uy = und[..., 0], und[..., 1]
    # Margins so every sample (plus the bilinear neighbour) falls inside the undistorted render.
    left = max(0, math.ceil(-ux.min()) + 2)
    top = max(0, math.ceil(-uy.min()) + 2)
    right = max(0, math.ceil(ux.max() - (w - 1)) + 2)
    bottom = max(0, math.ceil(uy.max() - (h - 1)) + 2)
    K_render = K.copy()
    K_render[0, 2] += left
    K_render[1, 2] += top
    map_x = (ux + left).astype(np.float32)
    map_y = (uy + top).astype(np.float32)
    return DistortionMap(K_render, (w + left + right, h + top + bottom), map_x, map_y)


def _undistort_pixels(pts: np.ndarray, K: np.ndarray, D: np.ndarray) -> np.ndarray:
    """OpenCV's iterative inverse of its own distortion model, converged tightly (4.x and 5.x APIs)."""
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10)
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4.x
        return cv2.undistortPointsIter(pts, K, D, None, K, criteria)
    return cv2.undistortPoints(pts, K, D, R=None, P=K, criteria=criteria)


def apply_distortion(image: np.ndarray, dmap: DistortionMap) -> np.ndarray:
    if dmap.map_x is None:
        return image
    return cv2.remap(image, dmap.map_x, dmap.map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def white_balance_gains(white_balance: tuple[int, int]) -> np.ndarray:
    """RGB channel gains of the IIDC white balance registers (U/B, V/R); 512 is unity."""
    ub, vr = white_balance
    return np.array([vr / 512.0, 1.0, ub / 512.0], dtype=np.float32)


def expected_dn(rad: np.ndarray, shutter_us: float, gain_db: float, sensor: SensorModel) -> np.ndarray:
    """Noise-free DN before quantisation (full well and 255 clipping applied)."""
    electrons = np.minimum(rad * (sensor.electrons_per_us * shutter_us), sensor.full_well_e)
    dn = electrons * (255.0 / sensor.full_well_e) * 10.0 ** (gain_db / 20.0)
    return np.clip(dn, 0.0, 255.0)


def auto_shutter(rad: np.ndarray, target_grey: float, gain_db: float, sensor: SensorModel) -> float:
    """The shutter time whose mean grey matches ``target_grey`` (the PIKE's auto exposure)."""
    shutter = sensor.ref_shutter_us
    sample = rad[::4, ::4]
    for _ in range(6):  # clipping makes the response non-linear; a few proportional steps settle it
        mean = float(expected_dn(sample, shutter, gain_db, sensor).mean())
        if mean <= 0.5:
            shutter *= 8.0
            continue
        shutter *= target_grey / mean
        shutter = float(np.clip(shutter, 10.0, 1_000_000.0))
    return shutter


def expose(
    rad: np.ndarray,
    shutter_us: float,
    gain_db: float,
    sensor: SensorModel,
    rng: np.random.Generator | None,
) -> np.ndarray:
    """Radiance (HxW or HxWx3, white lit surface = 1) to uint8 counts with CCD noise."""
    electrons = rad.astype(np.float32) * np.float32(sensor.electrons_per_us * shutter_us)
    if sensor.noise and rng is not None:
        noise = rng.standard_normal(electrons.shape, dtype=np.float32)
        electrons += noise * np.sqrt(electrons + np.float32(sensor.read_noise_e**2))
    np.clip(electrons, 0.0, sensor.full_well_e, out=electrons)
    electrons *= np.float32(255.0 / sensor.full_well_e * 10.0 ** (gain_db / 20.0))
    np.clip(electrons, 0.0, 255.0, out=electrons)
    return np.rint(electrons).astype(np.uint8)


def sensor_from_config(config: Any) -> SensorModel:
    """The sensor model from the typed drivers.stereo settings (SimStereoSettings keys)."""
    return SensorModel(
        full_well_e=config.sim_full_well_e,
        read_noise_e=config.sim_read_noise_e,
        white_dn_at_ref=config.sim_white_dn,
        ref_shutter_us=SensorModel.ref_shutter_us,
        noise=config.sim_noise,
    )


def vignette(rad: np.ndarray, K: np.ndarray, strength: float) -> np.ndarray:
    """Radiance darkened toward the image corners: the natural cos^4 falloff of the off-axis
    angle, scaled so the far corner loses ``strength`` of its light (0: none), as real lenses
    show (mechanical vignetting makes it steeper than cos^4 alone)."""
    if strength <= 0.0:
        return rad
    h, w = rad.shape[:2]
    u = (np.arange(w, dtype=np.float32) - np.float32(K[0, 2])) / np.float32(K[0, 0])
    v = (np.arange(h, dtype=np.float32) - np.float32(K[1, 2])) / np.float32(K[1, 1])
    r2 = v[:, None] ** 2 + u[None, :] ** 2
    cos4 = 1.0 / (1.0 + r2) ** 2
    corner = float(cos4.min())
    gain = 1.0 - strength * (1.0 - cos4) / max(1.0 - corner, 1e-6)
    return (rad * (gain[..., None] if rad.ndim == 3 else gain)).astype(np.float32)


def lens_blur(rad: np.ndarray, sigma_px: float) -> np.ndarray:
    """The lens's point spread (defocus, diffraction) as a Gaussian of ``sigma_px``."""
    if sigma_px <= 0.0:
        return rad
    return cv2.GaussianBlur(rad, (0, 0), sigma_px, borderType=cv2.BORDER_REPLICATE)


def jpeg(image: np.ndarray, quality: int) -> np.ndarray:
    """The frame through a real JPEG encoder and decoder at ``quality`` (0: untouched): the 8 x 8
    block artefacts and lost fine texture of a compressed downlink or a webcam-grade camera."""
    if quality <= 0:
        return image
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    flag = cv2.IMREAD_GRAYSCALE if image.ndim == 2 else cv2.IMREAD_COLOR
    return cv2.imdecode(buf, flag)


def lighting_from_config(config: Any, sun: Any) -> Lighting:
    """The light from the typed drivers.stereo settings (SimStereoSettings keys); a sun direction
    left null there is the scene's ``sun`` block (``sun``: its SunSettings), so shading and cast
    shadows agree."""
    return Lighting(
        sun_azimuth_deg=sun.azimuth_deg if config.sim_sun_azimuth_deg is None else config.sim_sun_azimuth_deg,
        sun_elevation_deg=(sun.elevation_deg if config.sim_sun_elevation_deg is None
                           else config.sim_sun_elevation_deg),
        ambient=config.sim_ambient,
        sky=config.sim_sky,
    )
