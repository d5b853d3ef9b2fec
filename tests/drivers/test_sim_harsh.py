"""The harsh simulator has what it claims: cast shadows where the terrain hides the sun, darker
vignetted corners, JPEG blocks, an albedo quilted from real Mars frames (not one frame stretched),
and stereo on a harsh pair still within a stated bound of the simulator's truth.

The world is ``config/scenes/marsyard_harsh.yaml`` (its sun, albedo and optics blocks as shipped)
cut to the 10 x 8 m in front of the start pose so it builds in about a second; pairs are 640 x 480.
The whole module runs in a few seconds.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from drivers.sim.albedo import load_texture, relative_reflectance, sample_periodic, usable_patches
from drivers.sim.scene import load_scene_spec
from drivers.sim.settings import AlbedoSettings, OpticsSettings, SceneLook, SunSettings
from drivers.sim.shadows import sunlit_map
from drivers.sim.terrain import DATA_DIR
from drivers.sim.transforms import make_T
from drivers.sim.world import World
from drivers.stereo import create
from prox_workflows.algorithms import stereo as st
from rvs_params import SettingError

FRAMES = Path(__file__).resolve().parents[3] / "shared" / "realdata" / "images"
NO_DISTORTION = [0.0, 0.0, 0.0, 0.0, 0.0]  # image pixels = render pixels, so masks line up


@pytest.fixture(scope="module")
def harsh() -> World:
    spec = load_scene_spec("marsyard_harsh")
    spec["terrain"]["bounds"] = [-2.0, -4.0, 8.0, 4.0]
    world = World(spec)
    world.set_ptu(0.0, -20.0)
    return world


def camera(world: World, **config: Any) -> Any:
    cam = create({"backend": "sim", "resolution": "low", "pixel_format": "mono8", "seed": 1, **config}, world, None)
    cam.open()
    return cam


def grab(world: World, **config: Any) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    cam = camera(world, **config)
    try:
        left, right = cam.grab_stereo_direct()
        return left, right, cam.calibration()
    finally:
        cam.close()


def grab_left(world: World, **config: Any) -> np.ndarray:
    cam = camera(world, **config)
    try:
        return cam.grab_mono_direct("left")
    finally:
        cam.close()


def sun_vector(sun: SunSettings) -> np.ndarray:
    az, el = math.radians(sun.azimuth_deg), math.radians(sun.elevation_deg)
    return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


# -- the blocks are typed settings --------------------------------------------------------------------
def test_scene_blocks_are_typed_and_default_to_the_kind_simulator() -> None:
    kind = SceneLook.from_spec(load_scene_spec("marsyard"))
    assert kind.sun == SunSettings() and not kind.sun.shadows
    assert kind.albedo.source == "procedural" and kind.optics == OpticsSettings()
    look = SceneLook.from_spec(load_scene_spec("marsyard_harsh"))
    assert look.sun.shadows and look.albedo.source == "mars"
    assert look.optics.jpeg_quality == 80 and look.optics.vignetting > 0 and look.optics.blur_sigma_px > 0
    with pytest.raises(SettingError, match="unknown key 'elevation'"):
        SceneLook.from_spec({"name": "x", "terrain": {}, "sun": {"elevation": 20}})
    with pytest.raises(SettingError, match="procedural|mars"):
        AlbedoSettings.from_mapping({"source": "moon"})


# -- shadows ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("azimuth", [0.0, 180.0, 45.0, -120.0])
def test_a_block_casts_a_shadow_of_height_over_tan_elevation_away_from_the_sun(azimuth: float) -> None:
    cell, n = 0.01, 241
    h = np.zeros((n, n), np.float32)
    c = n // 2
    h[c - 5:c + 6, c - 5:c + 6] = 0.2  # a 0.1 m block, 0.2 m high, in the middle
    lit = sunlit_map(h, cell, azimuth, 45.0)  # shadow 0.2 m long
    d = np.array([math.cos(math.radians(azimuth)), math.sin(math.radians(azimuth))])  # toward the sun
    at = lambda metres: lit[int(round(c + metres * d[1] / cell)), int(round(c + metres * d[0] / cell))]  # noqa: E731
    for behind in (0.09, 0.12, 0.15):  # beyond the block's edge, within 0.2 m of it
        assert at(-behind) < 0.1, (azimuth, behind, at(-behind))
    assert at(-0.35) > 0.9 and at(0.12) > 0.9 and at(0.3) > 0.9
    # flat ground far from the block is lit, the block's top is lit
    assert lit[5, 5] > 0.99 and lit[c, c] > 0.99


def test_shadowed_pixels_are_occluded_toward_the_sun_and_darker(harsh: World) -> None:
    left = grab_left(harsh, sim_distortion=NO_DISTORTION)
    K = harsh.camera_intrinsics("left", 640, 480)
    r = harsh.render(K, 640, 480, harsh.sensor_pose("left"))
    assert r.sunlit is not None
    s = sun_vector(harsh.sun)
    terrain = r.object_id == 0
    shade = np.clip(r.normal @ s.astype(np.float32), 0, 1)
    band = terrain & (shade > 0.3) & (shade < 0.7)  # same orientation to the sun on both sides
    dark = band & (r.sunlit < 0.05)
    bright = band & (r.sunlit > 0.95)
    assert dark.sum() > 200 and bright.sum() > 20000, (dark.sum(), bright.sum())
    # in shadow only the ambient share (0.25) is left: well under the lit grey of the same slopes
    ratio = left[dark].mean() / left[bright].mean()
    assert ratio < 0.7, ratio

    # An independent check: march from the points toward the sun over the heightfield.
    rng = np.random.default_rng(0)
    hf = harsh.terrain
    tan_el = math.tan(math.radians(harsh.sun.elevation_deg))
    dxy = s[:2] / np.linalg.norm(s[:2])
    steps = np.arange(0.02, 3.0, 0.005)

    def occluded(mask: np.ndarray) -> float:
        idx = rng.choice(np.flatnonzero(mask), 300, replace=False)
        p = r.points.reshape(-1, 3)[idx].astype(np.float64)
        x = p[:, :1] + steps[None, :] * dxy[0]
        y = p[:, 1:2] + steps[None, :] * dxy[1]
        ground = hf.sample(x, y)
        return float(np.mean(np.any(ground > p[:, 2:3] + steps[None, :] * tan_el + 0.002, axis=1)))

    assert occluded(terrain & (r.sunlit < 0.05)) > 0.9
    assert occluded(terrain & (r.sunlit > 0.95)) < 0.1

    # The big rock (x 4.0, y 1.0, half-axes 0.45 x 0.35, 0.4 high): its shadow lies on the side
    # away from the sun, the ground on the sun's side is lit.
    away = np.array([4.0, 1.0]) - dxy * 0.7
    toward = np.array([4.0, 1.0]) + dxy * 0.7
    assert hf.sample_sunlit(np.array([away[0]]), np.array([away[1]]))[0] < 0.1
    assert hf.sample_sunlit(np.array([toward[0]]), np.array([toward[1]]))[0] > 0.9


# -- optics ---------------------------------------------------------------------------------------------
def test_vignetting_darkens_the_corners_and_jpeg_leaves_8x8_blocks(harsh: World) -> None:
    plain_optics = OpticsSettings()
    shipped = harsh.optics
    try:
        harsh.optics = plain_optics
        raw = grab_left(harsh, sim_noise=False)
        harsh.optics = dataclasses.replace(plain_optics, vignetting=shipped.vignetting)
        vig = grab_left(harsh, sim_noise=False)
        harsh.optics = shipped
        full = grab_left(harsh)
    finally:
        harsh.optics = shipped
    a, b = raw.astype(np.float64), vig.astype(np.float64)
    centre = (slice(220, 260), slice(300, 340))
    assert b[centre].mean() / a[centre].mean() > 0.97
    for corner in ((slice(440, 480), slice(0, 40)), (slice(440, 480), slice(600, 640))):
        ratio = b[corner].mean() / a[corner].mean()
        assert abs(ratio - (1.0 - shipped.vignetting)) < 0.08, ratio

    def blockiness(img: np.ndarray) -> float:
        dx = np.abs(np.diff(img.astype(np.float32), axis=1))
        edge = (np.arange(dx.shape[1]) % 8) == 7  # between columns 8k+7 and 8k+8: a block boundary
        return float(dx[:, edge].mean() / dx[:, ~edge].mean())

    assert blockiness(raw) < 1.1
    assert blockiness(full) > 1.25, blockiness(full)


# -- albedo from real Mars frames -------------------------------------------------------------------------
def correlation_at(tex: np.ndarray, lag: int) -> float:
    t = tex - tex.mean()
    return float(np.mean(t * np.roll(t, lag, axis=1)) / t.var())


def fine_share(img: np.ndarray) -> float:
    """Share of the variance above 1/8 cycles per pixel: how much of the texture is fine grain."""
    p = np.abs(np.fft.fft2(img - img.mean())) ** 2
    f = np.hypot(*np.meshgrid(np.fft.fftfreq(img.shape[1]), np.fft.fftfreq(img.shape[0])))
    return float(p[f > 0.125].sum() / p.sum())


def test_the_shipped_mars_texture_is_quilted_not_one_stretched_frame() -> None:
    tex = load_texture(DATA_DIR / "mars_albedo.png")
    assert tex.shape == (512, 512)
    assert abs(float(tex.mean()) - 1.0) < 0.02 and 0.08 < float(tex.std()) < 0.35
    # seamless: across the wrap-around edge the texture changes no more than between neighbours
    inner = np.abs(np.diff(tex, axis=1)).mean()
    seam = np.abs(tex[:, 0] - tex[:, -1]).mean()
    assert seam < 1.3 * inner, (seam, inner)
    # short correlation length (patches of 64 px, blended): nothing of a frame spread over the tile
    assert correlation_at(tex, 32) < 0.2 and correlation_at(tex, 128) < 0.1
    if not FRAMES.is_dir():
        pytest.skip(f"real frames not here ({FRAMES}): the comparison with them needs the shared data")
    frames = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted(FRAMES.glob("mars*.png"))]
    patches = [relative_reflectance(f)[r:r + 64, c:c + 64] for f in frames for r, c in usable_patches(f, 64, 64)]
    real_fine = float(np.median([fine_share(p) for p in patches]))
    tiles = [tex[r:r + 64, c:c + 64] for r in range(0, 512, 64) for c in range(0, 512, 64)]
    ours = float(np.median([fine_share(t) for t in tiles]))
    # the grain of real ground is kept (within 30 %) ...
    assert abs(ours / real_fine - 1.0) < 0.3, (ours, real_fine)
    # ... where one 128 px crop stretched over the tile would lose most of it
    crop = relative_reflectance(frames[0])[384:512, 256:384]
    stretched = cv2.resize(crop, (512, 512), interpolation=cv2.INTER_LINEAR)
    worse = float(np.median([fine_share(stretched[r:r + 64, c:c + 64])
                             for r in range(0, 512, 64) for c in range(0, 512, 64)]))
    assert worse < 0.5 * real_fine and correlation_at(stretched, 32) > correlation_at(tex, 32) + 0.2


def test_the_harsh_terrain_albedo_follows_the_mars_texture(harsh: World) -> None:
    hf = harsh.terrain
    ny, nx = hf.shape
    xs = hf.x0 + np.arange(nx) * hf.cell
    ys = hf.y0 + np.arange(ny) * hf.cell
    X, Y = np.meshgrid(xs, ys)
    rel = sample_periodic(load_texture(DATA_DIR / "mars_albedo.png"), X, Y, harsh.albedo_source.texel_m)
    # rocks and the sand patch paint their own albedo over the ground: most nodes are ground
    c = np.corrcoef(rel.ravel(), hf.albedo.ravel())[0, 1]
    assert c > 0.7, c


# -- stereo on a harsh pair ----------------------------------------------------------------------------------
def test_stereo_on_a_harsh_pair_stays_within_its_bound_of_the_truth(harsh: World) -> None:
    """Bound: at most 1 % of the answered pixels more than 2 px off the simulator's disparity, and
    at least 90 % of the pixels answered (measured: 0.17 % and 92.3 % at 640 x 480; 88.6 % with
    the old absolute 2.5 DN texture mask, which threw the cast shadows away; the full-size
    figures are the README's, from python -m tools.bench.stereo)."""
    left, right, cal = grab(harsh)
    calib = {k: np.asarray(cal[k]) for k in ("image_size", "K1", "D1", "K2", "D2", "R", "T")}
    rect = st.rectification(calib)
    w, h = rect.size
    truth = harsh.render(np.asarray(rect.P1)[:, :3], w, h, harsh.sensor_pose("left") @ make_T(np.asarray(rect.R1).T))
    true = rect.focal * rect.baseline / truth.depth
    disp = st.disparity(left, right, calib, st.SgbmParams()).rectified
    has = np.isfinite(true)
    ok = has & np.isfinite(disp)
    err = np.abs(disp[ok] - true[ok])
    assert ok.sum() / has.sum() >= 0.9, ok.sum() / has.sum()
    assert (err > 2.0).mean() <= 0.01, (err > 2.0).mean()
