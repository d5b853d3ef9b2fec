"""ToF noise model: how far to trust each point, so that DemMosaik's ``fuse`` can weigh scans.

A time-of-flight range is a phase measurement. Its thermal noise is Gaussian with a standard
deviation inversely proportional to the returned amplitude (seed 004 sect. 2.3.3: sigma_t is
inversely proportional to the pixel's confidence, which the SR4000 derives from the amplitude
A, sect. 2.1.4), and it scales with the unambiguous range c / 2f, since the same phase noise
spans more metres at a lower modulation frequency. Averaging N frames divides it by sqrt(N).
What amplitude cannot show grows with range: calibration and mounting errors turn into a
lateral / angular error proportional to the distance, and inter-reflection (seed 000 sect.
5.2.3: floor errors "increasing radially out from the camera") adds more far away. So

    sigma(r, A) = sqrt(floor^2 + (k * (30 MHz / f) / (A * sqrt(N)))^2 + (c_r * r)^2)

with ``floor`` and ``k`` as in the simulated SR4000 (drivers/tof/physics.py: 45 m*counts gives
1 cm on the office floor 1.5 m away) and ``c_r`` a per-metre term. Without an amplitude the
model predicts one from the range (amplitude ~ 1 / r^2 for a surface of nominal albedo), so the
shot term then grows with r^2 as well.

The range sigma bounds the height sigma (a range error moves the point along its ray, whose
vertical component is at most the whole error); :func:`tof_height_variance` projects it onto
the vertical when the ray direction is known.
"""

from __future__ import annotations

import numpy as np

NOISE_K = 45.0  # m * counts at 30 MHz
NOISE_FLOOR = 0.0005  # m
RANGE_COEFF = 0.002  # m per m of range: calibration / mounting / multipath share
NOMINAL_AMPLITUDE_1M = 12000.0  # counts a mid-albedo surface 1 m away returns at the default exposure


def tof_sigma(
    range_m: np.ndarray | float,
    amplitude: np.ndarray | float | None = None,
    *,
    frequency_mhz: float = 30.0,
    frames: int = 1,
    noise_k: float = NOISE_K,
    noise_floor: float = NOISE_FLOOR,
    range_coeff: float = RANGE_COEFF,
    nominal_amplitude_1m: float = NOMINAL_AMPLITUDE_1M,
) -> np.ndarray:
    """Standard deviation (m, float32) of a ToF range: grows with range, falls with amplitude."""
    r = np.asarray(range_m, dtype=np.float64)
    if amplitude is None:
        a = nominal_amplitude_1m / np.maximum(r, 0.05) ** 2
    else:
        a = np.asarray(amplitude, dtype=np.float64)
    a = np.maximum(a, 1e-3)  # a dark pixel has huge noise, never infinite
    shot = noise_k * (30.0 / frequency_mhz) / (a * np.sqrt(max(int(frames), 1)))
    sigma = np.sqrt(noise_floor**2 + shot**2 + (range_coeff * r) ** 2)
    return sigma.astype(np.float32)


def tof_height_variance(
    points: np.ndarray,
    sensor: np.ndarray,
    amplitude: np.ndarray | None = None,
    *,
    lateral_sigma_per_m: float = 0.0015,
    **model: float,
) -> np.ndarray:
    """Height variance (m^2, float32) of global points seen from ``sensor`` (x, y, z).

    The range error acts along the ray (its vertical share is |dz| / r); the lateral error
    (pixel footprint, angular calibration) acts across it and shows up as height on sloped
    rays, with share sqrt(1 - (dz/r)^2). On a floor seen at a grazing angle that makes the
    height much better than the range, and on a wall face-on much worse - as observed."""
    p = np.asarray(points, dtype=np.float64)[:, :3]
    d = p - np.asarray(sensor, dtype=np.float64)[None, :3]
    r = np.linalg.norm(d, axis=1)
    cz = np.abs(d[:, 2]) / np.maximum(r, 1e-9)
    s_r = tof_sigma(r, amplitude, **model).astype(np.float64)
    s_l = lateral_sigma_per_m * r
    var = (s_r * cz) ** 2 + (s_l**2) * (1.0 - cz * cz)
    floor = model.get("noise_floor", NOISE_FLOOR)
    return np.maximum(var, floor**2).astype(np.float32)


def stereo_height_variance(
    points: np.ndarray,
    sensor: np.ndarray,
    amplitude: np.ndarray | None = None,
    *,
    baseline: float,
    focal: float,
    sigma_d: float = 0.25,
    lateral_sigma_per_m: float = 0.0015,
) -> np.ndarray:
    """Height variance (m^2, float32) of stereo points seen from the left camera at ``sensor``.

    Depth noise sigma_z = z^2 sigma_d / (b f) (z taken as the range: slightly pessimistic off
    axis), projected onto the vertical like :func:`tof_height_variance`: the stereo pair loses
    to the ToF camera near and wins far, and the fusion weighs each cell accordingly."""
    p = np.asarray(points, dtype=np.float64)[:, :3]
    d = p - np.asarray(sensor, dtype=np.float64)[None, :3]
    r = np.linalg.norm(d, axis=1)
    cz = np.abs(d[:, 2]) / np.maximum(r, 1e-9)
    s_r = r * r * sigma_d / (baseline * focal)
    s_l = lateral_sigma_per_m * r
    var = (s_r * cz) ** 2 + (s_l**2) * (1.0 - cz * cz)
    return np.maximum(var, NOISE_FLOOR**2).astype(np.float32)
