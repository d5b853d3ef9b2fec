"""What a simulated SR4000 pixel measures: the signal and error model, as pure array functions.

A ToF pixel measures the phase of the returned modulated light, so the model works with phasors
(amplitude * exp(i * phase)): everything that reaches a pixel adds up as complex numbers and the
camera reports the magnitude (amplitude) and the angle (range, modulo c/2f). This one idea gives
the known SR4000 errors their shape:

* phase ambiguity: the range wraps at c / (2 f) (5 m at 30 MHz, 10 m at 15 MHz);
* mixed ("flying") pixels: a pixel straddling a depth edge sums fore- and background phasors
  and reports a range in between (the renderer supersamples each pixel);
* multipath: light bouncing off a wall onto the floor arrives later, so near concave wall-floor
  corners ranges come out too long (seed 000 sect. 5.2.3: the office floor "sinks" toward the
  walls); modelled as one Lambertian inter-reflection between coarse patches.

Amplitude (counts) = amplitude_gain * albedo * cos(incidence) / range^2 * integration_ms, clipped
at ``saturation``; a saturated pixel's range is unusable and its confidence is 0.

Range noise is Gaussian with sigma = sqrt(noise_floor^2 + (noise_k * (30 MHz / f) / amplitude)^2)
(metres): inversely proportional to amplitude as in the ORF noise model of seed 004 sect. 2.3.3,
and proportional to the unambiguous range, because the same phase noise spans twice the
distance at 15 MHz. With the defaults, the office floor (albedo 0.45) 1.5 m from the sensor head
(incidence about 55 degrees, default integration: register 30, 3.3 ms) returns about 4500 counts
and sigma = 1.0 cm; a mid-albedo (0.5) wall 1.5 m straight ahead returns 7300 counts, 6 mm.

Confidence = 1 - exp(-amplitude / confidence_amplitude), 0 when saturated.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import cv2
import numpy as np

from rvs_params import Settings

from .constants import SPEED_OF_LIGHT


@dataclass(frozen=True)
class SignalModel:
    amplitude_gain: float = 10000.0  # counts per (albedo * cos / m^2 * ms)
    saturation: float = 30000.0  # counts: a brighter pixel saturates (range unusable)
    noise_k: float = 45.0  # m * counts at 30 MHz
    noise_floor: float = 0.0005  # m: sigma never falls below this
    amplitude_noise: float = 1.0  # amplitude sigma = amplitude_noise * sqrt(amplitude) counts
    confidence_amplitude: float = 1500.0  # counts where confidence reaches 1 - 1/e
    fixed_pattern_sigma: float = 0.02  # m: per-pixel offsets left when fix-pattern correction is off
    multipath_gain: float = 0.3  # scales the Lambertian one-bounce estimate; 0 = off
    multipath_block: int = 8  # native pixels per side of one inter-reflection source patch
    multipath_step: int = 4  # multipath evaluated on every n-th pixel, interpolated between
    supersample: int = 2  # sub-pixels per pixel side; 1 = no mixed pixels at depth edges
    conv_gray_reference_m: float = 2.0  # AM_CONV_GRAY scales amplitude by (range / this)^2

    @classmethod
    def from_config(cls, config: Settings) -> SignalModel:
        """Model parameters from the typed drivers.tof settings (keys prefixed ``sim_``, e.g. sim_noise_k)."""
        given = config.as_dict()
        model = cls(**{f.name: type(f.default)(given[f"sim_{f.name}"]) for f in fields(cls)})
        if model.supersample < 1 or model.multipath_block < 1 or model.multipath_step < 1:
            raise ValueError("sim_supersample, sim_multipath_block and sim_multipath_step must be at least 1")
        if model.amplitude_gain <= 0 or model.saturation <= 0 or model.confidence_amplitude <= 0:
            raise ValueError("sim_amplitude_gain, sim_saturation and sim_confidence_amplitude must be positive")
        return model

    def amplitude(self, albedo: np.ndarray, cos_incidence: np.ndarray, range_m: np.ndarray, integration_ms: float) -> np.ndarray:
        """Expected amplitude in counts before saturation (0 where nothing was hit)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            a = self.amplitude_gain * albedo * np.clip(cos_incidence, 0.0, 1.0) / np.square(range_m) * integration_ms
        return np.where(np.isfinite(a), a, 0.0).astype(np.float64)

    def range_sigma(self, amplitude: np.ndarray, frequency_mhz: float) -> np.ndarray:
        """Standard deviation (m) of one frame's range at this amplitude and frequency."""
        a = np.maximum(np.asarray(amplitude, dtype=np.float64), 1e-3)
        shot = self.noise_k * (30.0 / frequency_mhz) / a
        return np.sqrt(self.noise_floor**2 + shot**2)

    def confidence(self, amplitude: np.ndarray, saturated: np.ndarray) -> np.ndarray:
        """Confidence 0..1 from amplitude; 0 for saturated pixels."""
        conf = 1.0 - np.exp(-np.maximum(amplitude, 0.0) / self.confidence_amplitude)
        return np.where(saturated, 0.0, conf)


def phase_factor(frequency_mhz: float) -> float:
    """Radians of modulation phase per metre of total light path."""
    return 2.0 * math.pi * frequency_mhz * 1e6 / SPEED_OF_LIGHT


def phasor_range(phasor: np.ndarray, frequency_mhz: float) -> np.ndarray:
    """Range in [0, c/2f) from a return phasor (the angle of a round trip of 2 * range)."""
    angle = np.mod(np.angle(phasor), 2.0 * math.pi)
    return angle / (2.0 * phase_factor(frequency_mhz))


def direct_phasor(amplitude: np.ndarray, range_m: np.ndarray, frequency_mhz: float) -> np.ndarray:
    r = np.where(np.isfinite(range_m), range_m, 0.0)
    return amplitude * np.exp(1j * 2.0 * phase_factor(frequency_mhz) * r)


def block_mean(a: np.ndarray, s: int) -> np.ndarray:
    """Mean over non-overlapping s x s blocks of the first two axes (supersampled -> native)."""
    if s == 1:
        return a
    h, w = a.shape[0] // s, a.shape[1] // s
    return a[: h * s, : w * s].reshape(h, s, w, s, *a.shape[2:]).mean(axis=(1, 3))


def pixel_solid_angle(K: np.ndarray, width: int, height: int) -> np.ndarray:
    """Solid angle (sr) one pixel of a pinhole camera subtends: cos^3(off-axis) / (fx fy)."""
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    x = (u - K[0, 2]) / K[0, 0]
    y = (v - K[1, 2]) / K[1, 1]
    cos3 = (1.0 + x * x + y * y) ** -1.5
    return cos3 / (K[0, 0] * K[1, 1])


def multipath_phasor(
    points: np.ndarray,
    normals: np.ndarray,
    albedo: np.ndarray,
    origin: np.ndarray,
    solid_angle: np.ndarray,
    frequency_mhz: float,
    block: int,
    min_distance: float = 0.05,
    target_step: int = 2,
    chunk: int = 2048,
) -> np.ndarray:
    """One-bounce inter-reflection phasor per pixel, in units of amplitude / (gain * integration_ms).

    Light from the camera (at ``origin``) hits source patch j (a block x block group of pixels)
    with total power proportional to its solid angle, is re-emitted as a Lambertian source and
    lights target pixel i, which returns it to the camera along the direct path's last leg:

        M_i = albedo_i * sum_j albedo_j * Omega_j * cos_out_j * cos_in_i / (pi * d_ij^2)
                      * exp(i * k * (r_j + d_ij + r_i))

    Only pairs that face each other contribute (both cosines above 0.01), so a flat floor
    alone gets nothing and a concave wall-floor corner gets a delayed (too long) component.
    Mutual occlusion is ignored. Pixels without a hit (NaN) neither send nor receive. The sum
    varies slowly, so it is evaluated on every ``target_step``-th pixel and interpolated;
    albedo_i is applied per pixel.
    """
    h, w = albedo.shape
    valid = np.isfinite(points).all(axis=-1) & np.isfinite(albedo) & np.isfinite(normals).all(axis=-1)
    sel = slice(block // 2, None, block)
    src = valid[sel, sel].reshape(-1)
    out = np.zeros((h, w), dtype=np.complex128)
    if not src.any():
        return out
    ps = points[sel, sel].reshape(-1, 3)[src].astype(np.float64)
    ns = normals[sel, sel].reshape(-1, 3)[src].astype(np.float64)
    weight_s = albedo[sel, sel].reshape(-1)[src] * solid_angle[sel, sel].reshape(-1)[src] * block * block / math.pi
    origin = np.asarray(origin, dtype=np.float64)

    step = max(1, int(target_step))
    tp, tn, tv = points[::step, ::step], normals[::step, ::step], valid[::step, ::step]
    coarse = np.zeros(tv.shape, dtype=np.complex128)
    idx = np.flatnonzero(tv.reshape(-1))
    coarse.reshape(-1)[idx] = _inter_reflection(
        tp.reshape(-1, 3)[idx].astype(np.float64),
        tn.reshape(-1, 3)[idx].astype(np.float64),
        ps,
        ns,
        weight_s,
        origin,
        phase_factor(frequency_mhz),
        min_distance,
        chunk,
    )
    if step > 1:
        re = cv2.resize(coarse.real, (w, h), interpolation=cv2.INTER_LINEAR)
        im = cv2.resize(coarse.imag, (w, h), interpolation=cv2.INTER_LINEAR)
        coarse = re + 1j * im
    return np.where(valid, np.where(np.isfinite(albedo), albedo, 0.0) * coarse, 0.0)


def _inter_reflection(
    pt_all: np.ndarray,
    nt_all: np.ndarray,
    ps: np.ndarray,
    ns: np.ndarray,
    weight_s: np.ndarray,
    origin: np.ndarray,
    kf: float,
    min_distance: float,
    chunk: int,
) -> np.ndarray:
    """sum_j weight_j * cos_out_j * cos_in_i / d_ij^2 * exp(i k (r_j + d_ij + r_i)) per target."""
    result = np.zeros(pt_all.shape[0], dtype=np.complex128)
    r_s = np.linalg.norm(ps - origin, axis=-1)
    r_t = np.linalg.norm(pt_all - origin, axis=-1)
    ps_n = np.einsum("sk,sk->s", ps, ns)
    ps_sq = np.einsum("sk,sk->s", ps, ps)
    # Dense float32 over target x source blocks: cheaper than gathering the facing pairs, and
    # the exponential of the path phase is a complex matrix-vector product per block.
    ps32, ns32 = ps.astype(np.float32), ns.astype(np.float32)
    ps_sq32, ps_n32 = ps_sq.astype(np.float32), ps_n.astype(np.float32)
    w32 = weight_s.astype(np.float32)
    phase_s = (kf * r_s).astype(np.float32)
    for start in range(0, pt_all.shape[0], chunk):
        pt = pt_all[start : start + chunk].astype(np.float32)
        nt = nt_all[start : start + chunk].astype(np.float32)
        # Pairwise terms as matrix products (d = source - target): |d|^2, d.n_target, -d.n_source.
        d2 = np.maximum(ps_sq32[None, :] + np.einsum("tk,tk->t", pt, pt)[:, None] - 2.0 * (pt @ ps32.T), 0.0)
        dn_t = nt @ ps32.T - np.einsum("tk,tk->t", pt, nt)[:, None]
        dn_s = pt @ ns32.T - ps_n32[None, :]
        # Facing each other at more than grazing angles (cos > 0.01), and not too close.
        lim = 1e-4 * d2
        facing = (dn_t > 0) & (dn_s > 0) & (dn_t * dn_t > lim) & (dn_s * dn_s > lim) & (d2 >= min_distance**2)
        if not facing.any():
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            g = np.where(facing, dn_t * dn_s / (d2 * d2), 0.0).astype(np.float32) * w32[None, :]
        phase = np.sqrt(d2) * np.float32(kf) + phase_s[None, :]
        rt = (kf * r_t[start : start + pt.shape[0]]).astype(np.float64)
        acc = (g * np.cos(phase)).sum(axis=1).astype(np.float64) + 1j * (g * np.sin(phase)).sum(axis=1)
        result[start : start + pt.shape[0]] = acc * np.exp(1j * rt)
    return result
