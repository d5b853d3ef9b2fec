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

The DEM jobs weigh points by the calibrated per-point models further down
(:func:`tof_point_variance`, :func:`stereo_point_variance`): a sum of squared errors, one per
cause, read from the point's own image (:func:`pixel_features`), each with one coefficient
fitted to the simulator's truth by ``python -m tools.bench.fusion --calibrate`` and declared as
a parameter. The a-priori model above over-predicted the ToF's error near and under-predicted it
far (the fused DEM leaned on the wrong sensor), which is why the weights are now measured. The
edge term reads the height jump to the neighbours only up to :data:`JUMP_CAP` (a taller jump is the
edge's height, not the point's error), and the within-cell correlation that turns the points'
variances into the cell's is fitted on cells grouped by their number of points. What a point's
image cannot show - the heavy tail of the errors, a far ToF pixel on a step, a stereo mismatch -
the fusion of the two sensors' maps takes from the maps themselves: a cell off the median of its
neighbours counts as less certain (``scatter`` of dem_mosaik.fuse_sensors, fitted by the same
calibration).
"""

from __future__ import annotations

import math

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


def ray_sigmas(points: np.ndarray, sensor: np.ndarray, sigma_range: np.ndarray | float,
               sigma_lateral: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Height and horizontal sigmas (m) of global points seen from ``sensor`` (x, y, z), from their
    error along the ray (``sigma_range``) and across it (``sigma_lateral``). The range error's
    vertical share is |dz| / r, the rest lies along the ground; the lateral error the other way
    round. On a floor seen at a grazing angle the height is much better than the range, and a
    return read long lands in the next cell: a bounds map spreads each cell by the horizontal
    sigma. Any range sensor: the ToF's sigmas below, a stereo pair's from its disparity noise."""
    p = np.asarray(points, dtype=np.float64)[:, :3]
    d = p - np.asarray(sensor, dtype=np.float64)[None, :3]
    cz = np.abs(d[:, 2]) / np.maximum(np.linalg.norm(d, axis=1), 1e-9)
    s_r = np.asarray(sigma_range, dtype=np.float64)
    s_l = np.asarray(sigma_lateral, dtype=np.float64)
    sz2 = 1.0 - cz * cz
    return np.sqrt((s_r * cz) ** 2 + s_l**2 * sz2), np.sqrt(s_r**2 * sz2 + s_l**2)


def ray_spread(points: np.ndarray, sensor: np.ndarray, sigma_range: np.ndarray | float,
               sigma_lateral: np.ndarray | float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`ray_sigmas` with the horizontal error split by direction: (height, along the ray's
    horizontal direction, across it) sigmas (m). A range error moves a return along its ray, so
    on the ground it moves it toward or away from the sensor only; across the ray only the
    lateral error (pixel footprint, angular calibration) moves it. A bounds map spreads a cell's
    bounds by these two, an ellipse along the ray, not a disc of the larger."""
    p = np.asarray(points, dtype=np.float64)[:, :3]
    d = p - np.asarray(sensor, dtype=np.float64)[None, :3]
    cz = np.abs(d[:, 2]) / np.maximum(np.linalg.norm(d, axis=1), 1e-9)
    s_r = np.asarray(sigma_range, dtype=np.float64)
    s_l = np.broadcast_to(np.asarray(sigma_lateral, dtype=np.float64), cz.shape)
    sz2 = 1.0 - cz * cz
    return (np.sqrt((s_r * cz) ** 2 + s_l**2 * sz2), np.sqrt(s_r**2 * sz2 + (s_l * cz) ** 2), s_l.copy())


def tof_spread(points: np.ndarray, sensor: np.ndarray, amplitude: np.ndarray | None = None, *,
               frames: int = 1, frequency_mhz: float = 30.0, lateral_sigma_per_m: float = 0.0015
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`ray_spread` of ToF returns: the range sigma from :func:`tof_sigma` with each
    return's own (raw) ``amplitude`` (the shot noise falls as 1 / A) and the ``frames`` the
    camera averaged (the shot noise falls as 1 / sqrt(frames); the range term, calibration and
    scattering, is the same in every frame and does not); across the ray ``lateral_sigma_per_m``
    of the range, which averaging does not narrow either."""
    r = np.linalg.norm(np.asarray(points, dtype=np.float64)[:, :3] - np.asarray(sensor, dtype=np.float64)[None, :3],
                       axis=1)
    sigma_range = tof_sigma(r, amplitude, frequency_mhz=frequency_mhz, frames=frames).astype(np.float64)
    sigma_z, along, across = ray_spread(points, sensor, sigma_range, lateral_sigma_per_m * r)
    return np.maximum(sigma_z, NOISE_FLOOR), along, across


def tilt_spread(points: np.ndarray, centre: np.ndarray, sigma_deg: float) -> np.ndarray:
    """The height sigma an error of ``sigma_deg`` in the rover's roll and pitch (its IMU's, the
    GNC's) puts on ground points: the frame turns with the body about its centre, so the error
    grows with the distance from it (2 m out, 0.1 deg is 3.5 mm)."""
    pts = np.asarray(points, dtype=np.float64)
    lever = np.hypot(pts[:, 0] - centre[0], pts[:, 1] - centre[1])
    return lever * math.tan(math.radians(sigma_deg))


def pair_sigmas(points: np.ndarray, sensor: np.ndarray, sigma_range: np.ndarray, focal: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`ray_sigmas` of a stereo pair's points: its range sigma from the disparity noise, half
    a pixel across the ray (``focal`` in pixels)."""
    r = np.linalg.norm(np.asarray(points, dtype=np.float64)[:, :3] - np.asarray(sensor, dtype=np.float64)[None, :3],
                       axis=1)
    return ray_sigmas(points, sensor, sigma_range, r / (2.0 * focal))


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
    r = np.linalg.norm(np.asarray(points, dtype=np.float64)[:, :3] - np.asarray(sensor, dtype=np.float64)[None, :3],
                       axis=1)
    sigma, _ = ray_sigmas(points, sensor, tof_sigma(r, amplitude, **model), lateral_sigma_per_m * r)
    floor = model.get("noise_floor", NOISE_FLOOR)
    return np.maximum(sigma**2, floor**2).astype(np.float32)



def tof_horizontal_sigma(
    points: np.ndarray,
    sensor: np.ndarray,
    amplitude: np.ndarray | None = None,
    *,
    lateral_sigma_per_m: float = 0.0015,
    **model: float,
) -> np.ndarray:
    """Horizontal position sigma (m, float32) of global points seen from ``sensor``: the range
    error's share along the ground (sqrt(1 - (dz/r)^2): nearly all of it at a grazing angle) and
    the lateral error. A return read long or short lands in another cell; on a rock's flank that
    is a height error :func:`tof_height_variance` cannot show, so a map of bounds spreads each
    cell's returns by this much."""
    r = np.linalg.norm(np.asarray(points, dtype=np.float64)[:, :3] - np.asarray(sensor, dtype=np.float64)[None, :3],
                       axis=1)
    _, sigma_xy = ray_sigmas(points, sensor, tof_sigma(r, amplitude, **model), lateral_sigma_per_m * r)
    return sigma_xy.astype(np.float32)

# -- per-pixel features of a view: what a point's neighbours in its own image say about it ------------
SLOPE_CAP = 5.0  # rise over run: steeper is a depth edge, which ``jump`` measures
# a larger height jump to a neighbour is the depth edge's height, not the point's error: a pixel on the
# floor beside a rock sees the rock's top as its neighbour, and a mixed pixel's error stays of the order
# of a centimetre however tall the edge (tools/bench/fusion.py --calibrate prints the points' measured
# error per band of jump against the model's: uncapped, the edge term predicted a ToF point beside a
# 10 cm step 4x worse than it is, and the fusion leaned on the stereo pair there)
JUMP_CAP = 0.02  # m


def coord_image(points: np.ndarray, pixels: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The H x W x 3 image of a view's global points (NaN where the view kept none), so that
    the features below see each point's image neighbours - online from the frame, offline from
    a recorded view alike."""
    img = np.full((shape[0] * shape[1], 3), np.nan, np.float64)
    img[np.asarray(pixels)] = np.asarray(points, np.float64)[:, :3]
    return img.reshape(shape[0], shape[1], 3)


def pixel_features(coords: np.ndarray, sensor: np.ndarray, image: np.ndarray | None = None,
                   wall_window: int = 15, texture_window: int = 5) -> dict[str, np.ndarray]:
    """Per pixel of an H x W x 3 global coordinate image seen from ``sensor``:

    ``slope``  the height difference to a defined 4-neighbour over their horizontal distance
              (largest of the four, at most :data:`SLOPE_CAP`): the height a cell's sampling
              misses on steep ground, free of the sensor's pixel spacing (a coarse ToF pixel
              jumps more on the same slope than a fine stereo pixel);
    ``jump``  the largest height difference (m) to a defined 4-neighbour, at most
              :data:`JUMP_CAP`: on a depth edge
              (a rock's rim, a flying pixel between fore- and background) a point's height
              depends on where the edge falls, and a ToF pixel there mixes both; on smooth
              ground it is the sensor's own noise showing (a far ToF pixel differs from its
              neighbours by about its error);
    ``cos_incidence``  |cos| of the angle between the ray and the surface normal (from the
              neighbours): grazing rays spread a pixel's footprint along the surface;
    ``wall``  the share of vertical-surface pixels (|n_z| < 0.5) within ``wall_window`` pixels:
              ToF light bouncing off a wall onto the ground near it arrives late (multipath);
    ``texture``  the grey-level standard deviation in ``texture_window`` pixels of ``image``
              (the stereo matcher's evidence; flat grey matches badly).
    """
    from scipy import ndimage

    c = np.asarray(coords, np.float64)
    z = c[..., 2]
    defined = np.isfinite(z)
    jump = np.zeros(z.shape)
    slope = np.zeros(z.shape)
    for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        nb = np.full(c.shape, np.nan)
        rs = slice(max(dr, 0), z.shape[0] + min(dr, 0))
        rd = slice(max(-dr, 0), z.shape[0] + min(-dr, 0))
        cs = slice(max(dc, 0), z.shape[1] + min(dc, 0))
        cd = slice(max(-dc, 0), z.shape[1] + min(-dc, 0))
        nb[rd, cd] = c[rs, cs]
        d = np.abs(z - nb[..., 2])
        with np.errstate(invalid="ignore", divide="ignore"):
            s = d / np.maximum(np.hypot(c[..., 0] - nb[..., 0], c[..., 1] - nb[..., 1]), 1e-3)
        slope = np.fmax(slope, np.where(np.isfinite(s), np.minimum(s, SLOPE_CAP), 0.0))
        jump = np.fmax(jump, np.where(np.isfinite(d), np.minimum(d, JUMP_CAP), 0.0))
    gu = np.gradient(c, axis=1)
    gv = np.gradient(c, axis=0)
    n = np.cross(gu, gv)
    norm = np.linalg.norm(n, axis=2)
    with np.errstate(invalid="ignore", divide="ignore"):
        n = n / norm[..., None]
        ray = c - np.asarray(sensor, np.float64)[:3]
        ray = ray / np.linalg.norm(ray, axis=2)[..., None]
        cos_inc = np.abs(np.sum(n * ray, axis=2))
    ok = np.isfinite(cos_inc)
    cos_inc = np.where(ok, cos_inc, 1.0)
    vertical = (ok & (np.abs(np.where(ok, n[..., 2], 1.0)) < 0.5)).astype(np.float64)
    wall = ndimage.uniform_filter(vertical, wall_window, mode="constant")
    out = {"jump": jump, "slope": slope, "cos_incidence": cos_inc, "wall": wall}
    if image is not None:
        g = np.asarray(image, np.float64)
        m = ndimage.uniform_filter(g, texture_window)
        m2 = ndimage.uniform_filter(g * g, texture_window)
        out["texture"] = np.sqrt(np.maximum(m2 - m * m, 0.0))
    for k in out:
        out[k] = np.where(defined, out[k], np.nan)
    return out


# -- the per-point noise models the ToF-stereo fusion weighs by ----------------------------------------
# Each is a sum of independent height variances, one per cause, each with one coefficient that
# tools/bench/fusion.py --calibrate fits against the simulator's truth (a robust least-squares fit of
# the squared height errors of the points, per sensor); the fitted values are the defaults of the
# ``tof_noise_*`` / ``stereo_noise_*`` parameters (prox_workflows/parameters.py), and nothing here
# has a default of its own, so a model is only ever evaluated with declared values.
TOF_TERMS = ("floor", "shot", "range", "incidence", "edge", "slope", "multipath")
STEREO_TERMS = ("floor", "disparity", "texture", "incidence", "edge", "slope", "multipath")


def _ray(points: np.ndarray, sensor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    d = np.asarray(points, np.float64)[:, :3] - np.asarray(sensor, np.float64)[None, :3]
    r = np.linalg.norm(d, axis=1)
    return r, np.abs(d[:, 2]) / np.maximum(r, 1e-9)


def _tan_incidence(features: dict[str, np.ndarray], n: int) -> np.ndarray:
    c = np.clip(np.asarray(features.get("cos_incidence", np.ones(n)), np.float64), 0.1, 1.0)
    return np.sqrt(1.0 - c * c) / c


def tof_basis(points: np.ndarray, sensor: np.ndarray, amplitude: np.ndarray,
              features: dict[str, np.ndarray]) -> np.ndarray:
    """N x 7 squared-error shapes of the ToF model, one column per :data:`TOF_TERMS` entry:

    floor 1; shot (cz / A)^2 - the phase noise falls with the amplitude A (seed 004 sect. 2.3.3)
    and reaches the height by the ray's vertical share cz; range (cz r)^2 - calibration and
    scattering grow with the range r; incidence (r tan i)^2 - a grazing ray's footprint smears
    along the surface; edge jump^2 - mixed (flying) pixels between fore- and background on a
    depth edge; slope slope^2 - the cell's sampling of steep ground (the coefficient is a
    length: the height missed per unit of slope); multipath (wall r)^2 - light from a nearby wall arrives late on the ground near it."""
    r, cz = _ray(points, sensor)
    a = np.maximum(np.asarray(amplitude, np.float64), 1.0)
    jump = np.asarray(features.get("jump", np.zeros(len(r))), np.float64)
    slope = np.asarray(features.get("slope", np.zeros(len(r))), np.float64)
    wall = np.asarray(features.get("wall", np.zeros(len(r))), np.float64)
    return np.stack([np.ones_like(r), (cz / a) ** 2, (cz * r) ** 2, (r * _tan_incidence(features, len(r))) ** 2,
                     jump**2, slope**2, (wall * r) ** 2], axis=1)


def stereo_basis(points: np.ndarray, sensor: np.ndarray, features: dict[str, np.ndarray], *,
                 baseline: float, focal: float) -> np.ndarray:
    """N x 7 squared-error shapes of the stereo model, one column per :data:`STEREO_TERMS` entry:

    floor 1; disparity (cz z^2 / (b f))^2 - a disparity error of one pixel moves the depth by
    z^2 / (b f), so the error grows with the depth squared; texture (cz z^2 / (b f t))^2 - the
    matcher's disparity error grows where the grey-level spread t is small; incidence, edge,
    slope and multipath as :func:`tof_basis` (a stereo edge is an occlusion boundary; near walls the
    matcher is fooled by the wall's repeated texture)."""
    r, cz = _ray(points, sensor)
    sz = cz * r * r / (baseline * focal)
    tex = np.maximum(np.asarray(features.get("texture", np.full(len(r), 1e3)), np.float64), 0.5)
    jump = np.asarray(features.get("jump", np.zeros(len(r))), np.float64)
    slope = np.asarray(features.get("slope", np.zeros(len(r))), np.float64)
    wall = np.asarray(features.get("wall", np.zeros(len(r))), np.float64)
    return np.stack([np.ones_like(r), sz**2, (sz / tex) ** 2, (r * _tan_incidence(features, len(r))) ** 2,
                     jump**2, slope**2, (wall * r) ** 2], axis=1)


def model_variance(basis: np.ndarray, sigmas: dict[str, float], terms: tuple[str, ...]) -> np.ndarray:
    """The height variance (m^2, float32) of each point: the basis weighted by each term's
    coefficient squared (the coefficients are standard deviations per unit of their shape)."""
    coef = np.array([float(sigmas[t]) ** 2 for t in terms])
    return np.maximum(basis @ coef, NOISE_FLOOR**2).astype(np.float32)


def tof_point_variance(points: np.ndarray, sensor: np.ndarray, amplitude: np.ndarray,
                       features: dict[str, np.ndarray], **sigmas: float) -> np.ndarray:
    """Height variance (m^2, float32) of ToF points by the calibrated model (see :func:`tof_basis`);
    ``sigmas`` names one coefficient per :data:`TOF_TERMS` entry."""
    return model_variance(tof_basis(points, sensor, amplitude, features), sigmas, TOF_TERMS)


def stereo_point_variance(points: np.ndarray, sensor: np.ndarray, amplitude: np.ndarray,
                          features: dict[str, np.ndarray], *, baseline: float, focal: float,
                          **sigmas: float) -> np.ndarray:
    """Height variance (m^2, float32) of stereo points by the calibrated model (see
    :func:`stereo_basis`); ``sigmas`` names one coefficient per :data:`STEREO_TERMS` entry."""
    return model_variance(stereo_basis(points, sensor, features, baseline=baseline, focal=focal), sigmas,
                          STEREO_TERMS)


def model_sigmas(params: object, sensor: str) -> dict[str, float]:
    """The coefficients of one sensor's model from a parameter object (``tof_noise_<term>`` /
    ``stereo_noise_<term>`` fields, declared in prox_workflows/parameters.py)."""
    prefix, terms = ("tof_noise_", TOF_TERMS) if sensor == "tof" else ("stereo_noise_", STEREO_TERMS)
    return {t: float(getattr(params, prefix + t)) for t in terms}
