"""Dem2Hazard on synthetic DEMs with known answers, against the slow generic_filter oracle, and
the rvs-dem2hazard CLI end to end."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from prox_workflows import colormaps
from prox_workflows.algorithms import dem2hazard as d2h
from prox_workflows.algorithms.dem2hazard import (
    HazardParams,
    dem2hazard,
    dem2hazard_layers,
    dem2hazard_reference,
    hazard_summary,
    load_params,
)
from prox_workflows.cli import dem2hazard as cli
from prox_workflows.grid import GridGeometry, Layers, write_geotiff
from rvs_params.hazard import HAZARDOUS, SAFE, UNDEFINED
from rvs_truth.reference import dem2hazard_vectorised

CELL = 0.02
P = HazardParams()  # window 0.3 m -> 15 x 15 cells at 0.02 m, step 0.15 m, slope 20 deg, roughness 0.05 m


def plane(shape: tuple[int, int], degrees: float, azimuth: float = 30.0, offset: float = 5.0) -> np.ndarray:
    rows, cols = np.mgrid[0:shape[0], 0:shape[1]]
    x, y = cols * CELL, -rows * CELL
    a = math.radians(azimuth)
    return (offset + math.tan(math.radians(degrees)) * (x * math.cos(a) + y * math.sin(a))).astype(np.float32)


def window_counts(h: int, w: int, n: int) -> np.ndarray:
    """Cells of each (border-truncated) n x n window on a fully defined h x w grid."""
    r = n // 2

    def along(k: int) -> np.ndarray:
        i = np.arange(k)
        return np.minimum(i, r) + np.minimum(k - 1 - i, r) + 1

    return np.outer(along(h), along(w))


# ------------------------------------------------------------------------------ parameters


def test_defaults_come_from_the_yaml_and_overrides_apply(tmp_path: Path) -> None:
    assert load_params() == HazardParams()
    assert P.window_cells(CELL) == 15 and P.window_cells(0.05) == 7 and P.window_cells(0.04) == 9
    assert P.min_cells(CELL) == math.ceil(0.5 * 225)
    p = load_params(step_max=0.3, slope_max=25)
    assert (p.step_max, p.slope_max, p.roughness_max) == (0.3, 25.0, 0.05) and isinstance(p.slope_max, float)
    own = tmp_path / "d2h.yaml"
    own.write_text("step_max: 0.1\nwindow: 0.5\n")
    q = load_params(own, window=0.2)
    assert (q.step_max, q.window, q.slope_max) == (0.1, 0.2, 20.0)
    with pytest.raises(ValueError, match="unknown"):
        load_params(stepmax=0.1)
    for bad in ({"window": 0}, {"slope_max": 95}, {"min_fraction": 1.5}, {"weight_slope": -1},
                {"weight_slope": 0, "weight_step": 0, "weight_roughness": 0}, {"step_max": float("nan")},
                {"slope_max": "25"}):
        with pytest.raises(ValueError):
            HazardParams(**bad)


# ------------------------------------------------------------------------------ known answers


@pytest.mark.parametrize("degrees", [10.0, 25.0])
def test_tilted_plane_gives_its_slope_no_roughness_and_the_right_class(degrees: float) -> None:
    dem = plane((60, 70), degrees)
    out = dem2hazard(dem, CELL, P)
    expected_defined = window_counts(60, 70, 15) >= P.min_cells(CELL)  # corners lack half their window
    assert np.array_equal(np.isfinite(out["slope"]), expected_defined)
    s = out["slope"][expected_defined]
    assert np.abs(s - degrees).max() < 0.1
    assert np.nanmax(out["roughness"]) < 1e-4
    hazard = out["hazard"]
    assert np.all(hazard[~expected_defined] == UNDEFINED)
    assert np.all(hazard[expected_defined] == (SAFE if degrees < P.slope_max else HAZARDOUS))


def test_step_edge_is_flagged_within_half_a_window_of_the_edge() -> None:
    dem = np.zeros((40, 60), np.float32)
    dem[:, 30:] = 0.3
    out = dem2hazard(dem, CELL, P)
    rows = slice(7, 33)  # rows whose windows are complete
    band = np.zeros(60, bool)
    band[30 - 7:30 + 7] = True  # a window reaches the edge from 7 cells either side
    np.testing.assert_allclose(out["step"][rows][:, band], 0.3, atol=1e-6)
    assert np.all(out["step"][rows][:, ~band & (np.arange(60) >= 7) & (np.arange(60) < 53)] == 0)
    assert np.all(out["hazard"][rows][:, band] == HAZARDOUS)
    inner = ~band & (np.arange(60) >= 7) & (np.arange(60) < 53)
    assert np.all(out["hazard"][rows][:, inner] == SAFE)
    assert np.all(out["traversability"][rows][:, inner] == 1.0)


def _rock(dem: np.ndarray, r: int, c: int, radius: float, height: float, box: bool) -> np.ndarray:
    rows, cols = np.mgrid[0:dem.shape[0], 0:dem.shape[1]]
    d2 = ((rows - r) ** 2 + (cols - c) ** 2) * CELL**2
    if box:
        inside = (np.abs(rows - r) * CELL <= radius) & (np.abs(cols - c) * CELL <= radius)
        dem[inside] += height
    else:
        inside = d2 < radius**2
        dem[inside] += height * np.sqrt(1 - d2[inside] / radius**2)
    return inside


def test_every_rock_taller_than_the_step_threshold_is_flagged_and_the_floor_is_safe() -> None:
    rng = np.random.default_rng(7)
    size = 300
    dem = rng.normal(0.0, 0.003, (size, size)).astype(np.float32)
    rocks = []
    for k in range(16):  # a 4 x 4 field of rocks, 1.2 m apart
        r, c = 38 + 75 * (k // 4), 38 + 75 * (k % 4)
        height = rng.uniform(0.16, 0.4)
        radius = rng.uniform(0.04, 0.2)
        rocks.append(_rock(dem, r, c, radius, height, box=bool(k % 2)))
    small = _rock(dem, 150, 112, 0.08, 0.04, box=True)  # between the tall ones
    out = dem2hazard(dem, CELL, P)
    hazard = out["hazard"]
    # A rock is flagged when the rover cannot get onto it: its whole rim (the cells either side
    # of its outline) is hazardous. (A flat top wider than the window is rightly safe inside.)
    k3 = np.ones((3, 3), np.uint8)
    rims = [cv2.dilate(i.astype(np.uint8), k3).astype(bool) & ~cv2.erode(i.astype(np.uint8), k3).astype(bool)
            for i in rocks]
    flagged = [bool(np.all(hazard[rim] == HAZARDOUS)) for rim in rims]
    assert all(flagged), f"rocks missed: {[i for i, f in enumerate(flagged) if not f]}"  # recall 1.0
    around_small = cv2.dilate(small.astype(np.uint8), np.ones((17, 17), np.uint8)).astype(bool)
    assert np.all(hazard[around_small] == SAFE)  # a 4 cm rock is no hazard
    near = cv2.dilate(np.any(rocks, axis=0).astype(np.uint8), np.ones((17, 17), np.uint8)).astype(bool)
    floor = ~near & (hazard != UNDEFINED)
    assert floor.sum() > 0.5 * size * size
    assert np.mean(hazard[floor] == SAFE) >= 0.95


def test_flat_noisy_floor_is_safe() -> None:
    rng = np.random.default_rng(1)
    dem = rng.normal(0.2, 0.005, (200, 200)).astype(np.float32)
    hazard = dem2hazard(dem, CELL, P)["hazard"]
    defined = hazard != UNDEFINED
    assert np.mean(hazard[defined] == SAFE) >= 0.95


@pytest.mark.parametrize("sigma,degrees", [(0.01, 0.0), (0.02, 15.0)])
def test_roughness_recovers_the_noise_sigma(sigma: float, degrees: float) -> None:
    rng = np.random.default_rng(3)
    dem = plane((200, 200), degrees) + rng.normal(0, sigma, (200, 200)).astype(np.float32)
    out = dem2hazard(dem, CELL, P)
    rough = np.nanmedian(out["roughness"])
    assert abs(rough - sigma) < 0.1 * sigma
    assert abs(np.nanmedian(out["slope"]) - degrees) < 1.0


# ------------------------------------------------------------------------------ undefined cells


def test_undefined_cells_and_windows_with_too_few_cells() -> None:
    dem = plane((60, 60), 5.0)
    dem[30, 30] = np.nan
    out = dem2hazard(dem, CELL, P)
    assert out["hazard"][30, 30] == UNDEFINED
    assert np.isnan(out["traversability"][30, 30]) and np.isnan(out["slope"][30, 30])
    assert np.all(out["hazard"][29:32, 29:32][np.isfinite(dem[29:32, 29:32])] == SAFE)

    # Left half undefined: a cell on the edge sees 8 of 15 columns (120 cells), one further in 9 (135).
    half = plane((60, 60), 5.0)
    half[:, :30] = np.nan
    strict = dem2hazard(half, CELL, load_params(min_fraction=0.6))  # needs 135 of 225
    assert np.all(strict["hazard"][7:53, 30] == UNDEFINED)
    assert np.all(strict["hazard"][7:53, 31] == SAFE)
    lax = dem2hazard(half, CELL, P)  # needs 113
    assert np.all(lax["hazard"][7:53, 30] == SAFE)
    assert np.all(lax["hazard"][:, :30] == UNDEFINED)

    sparse = np.full((60, 60), np.nan, np.float32)
    sparse[::3, ::3] = 0.0  # a ninth of every window
    out = dem2hazard(sparse, CELL, P)
    assert np.all(out["hazard"] == UNDEFINED) and np.all(np.isnan(out["traversability"]))

    line = np.full((40, 40), np.nan, np.float32)
    line[20, :] = np.linspace(0, 1, 40)  # collinear: no plane however few cells are needed
    out = dem2hazard(line, CELL, load_params(min_fraction=0.01))
    assert np.all(out["hazard"] == UNDEFINED)

    empty = dem2hazard(np.full((20, 30), np.nan, np.float32), CELL, P)
    assert np.all(empty["hazard"] == UNDEFINED) and np.all(np.isnan(empty["step"]))
    assert hazard_summary(empty["hazard"]) == {"safe": 0.0, "hazardous": 0.0, "undefined": 1.0}


# ------------------------------------------------------------------------------ the oracle


@pytest.mark.parametrize("seed", range(5))
def test_equals_the_generic_filter_reference_on_random_crops(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    cell = [0.02, 0.05, 0.02, 0.04, 0.03][seed]
    params = load_params(window=rng.uniform(0.1, 0.35), min_fraction=rng.uniform(0.3, 0.8))
    h, w = rng.integers(25, 45, 2)
    dem = np.cumsum(np.cumsum(rng.normal(0, 0.01, (h, w)), 0), 1) + rng.normal(0, 0.01, (h, w))
    dem += [0.0, 2000.0, -50.0, 0.0, 7.0][seed]  # large absolute heights must not cost precision
    dem[rng.random((h, w)) < rng.uniform(0.0, 0.3)] = np.nan
    dem = dem.astype(np.float32)
    ours = dem2hazard(dem, cell, params)
    ref = dem2hazard_reference(dem, cell, params)
    for name in ("slope", "roughness", "step"):
        assert np.array_equal(np.isnan(ours[name]), np.isnan(ref[name])), name
    assert np.isfinite(ours["slope"]).sum() > 0.3 * h * w
    np.testing.assert_allclose(ours["slope"], ref["slope"], atol=1e-3, equal_nan=True)
    np.testing.assert_allclose(ours["roughness"], ref["roughness"], rtol=1e-3, atol=2e-6, equal_nan=True)
    np.testing.assert_allclose(ours["step"], ref["step"], atol=1e-6, equal_nan=True)


# ------------------------------------------------------------------------------ the vectorised peer


def assert_same_layers(ours: dict[str, np.ndarray], other: dict[str, np.ndarray]) -> None:
    """Equal as the oracle test means it: the same undefined cells, values within float rounding."""
    for name in ("slope", "roughness", "step", "traversability"):
        assert ours[name].dtype == np.float32 and ours[name].shape == other[name].shape, name
        assert np.array_equal(np.isnan(ours[name]), np.isnan(other[name])), name
    np.testing.assert_array_equal(ours["hazard"], other["hazard"])
    np.testing.assert_allclose(ours["slope"], other["slope"], atol=1e-3, equal_nan=True)
    np.testing.assert_allclose(ours["roughness"], other["roughness"], rtol=1e-3, atol=2e-6, equal_nan=True)
    np.testing.assert_allclose(ours["step"], other["step"], atol=1e-6, equal_nan=True)
    np.testing.assert_allclose(ours["traversability"], other["traversability"], atol=1e-5, equal_nan=True)


def holey_dem(rng: np.random.Generator, h: int, w: int, holes: float, offset: float) -> np.ndarray:
    """Rough rolling ground with single-cell and blob holes (NaN, some +-inf), at ``offset`` m."""
    dem = np.cumsum(np.cumsum(rng.normal(0, 0.01, (h, w)), 0), 1) + rng.normal(0, 0.005, (h, w)) + offset
    dem[rng.random((h, w)) < holes] = np.nan
    for _ in range(int(rng.integers(0, 4))):
        r, c = rng.integers(0, h), rng.integers(0, w)
        dem[r:r + rng.integers(1, 12), c:c + rng.integers(1, 12)] = rng.choice([np.nan, np.inf, -np.inf])
    return dem


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), h=st.integers(1, 300), w=st.integers(1, 60),
       cell=st.sampled_from([0.02, 0.03, 0.05]), window=st.floats(0.05, 0.4),
       min_fraction=st.floats(0.05, 1.0), holes=st.sampled_from([0.0, 0.05, 0.3, 0.7]),
       offset=st.sampled_from([0.0, -50.0, 2000.0]), dtype=st.sampled_from([np.float32, np.float64]),
       order=st.sampled_from(["C", "F"]))
def test_equals_the_vectorised_peer_on_random_dems_with_holes(
        seed: int, h: int, w: int, cell: float, window: float, min_fraction: float, holes: float,
        offset: float, dtype: type, order: str) -> None:
    # up to 300 rows: several strips (and their halos) and both the threaded and the serial path
    rng = np.random.default_rng(seed)
    dem = np.asarray(holey_dem(rng, h, w, holes, offset), dtype=dtype, order=order)
    params = load_params(window=window, min_fraction=min_fraction)
    assert_same_layers(dem2hazard(dem, cell, params), dem2hazard_vectorised(dem, cell, params))


@pytest.mark.parametrize("shape", [(700, 23), (40, 5000)])
def test_strips_of_tall_and_wide_grids_equal_the_vectorised_peer(shape: tuple[int, int]) -> None:
    rng = np.random.default_rng(11)
    dem = holey_dem(rng, *shape, holes=0.1, offset=3.0).astype(np.float32)
    assert_same_layers(dem2hazard(dem, CELL, P), dem2hazard_vectorised(dem, CELL, P))


def test_the_kernels_arctangent_is_within_an_ulp_or_two_of_numpys() -> None:
    kern = pytest.importorskip("prox_workflows.algorithms._dem2hazard_kernel")
    # both sides of the reductions at 0.66 and tan(3 pi / 8), tiny and huge slopes
    x = np.concatenate([np.linspace(0, 3, 301), [0.66, np.nextafter(0.66, 1), 2.414213562373095, 1e-300,
                                                 1e-8, 1e3, 1e12, 1e300]])
    ours = np.array([kern._atan(v) for v in x])
    np.testing.assert_allclose(ours, np.arctan(x), rtol=5e-16, atol=0)
    assert kern._atan(np.inf) == math.pi / 2 and math.isnan(kern._atan(np.nan))


def test_the_compiled_kernel_equals_the_whole_array_fallback(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(12)
    dem = holey_dem(rng, 300, 90, holes=0.05, offset=-20.0)
    compiled = dem2hazard(dem, CELL, P)
    monkeypatch.setattr(d2h, "IMPL", "numpy")
    assert_same_layers(compiled, dem2hazard(dem, CELL, P))


# ------------------------------------------------------------------------------ traversability


def test_traversability_is_the_weighted_sum_and_zero_past_any_threshold() -> None:
    rng = np.random.default_rng(5)
    dem = (np.cumsum(np.cumsum(rng.normal(0, 0.004, (120, 120)), 0), 1)).astype(np.float32)
    for params in (P, load_params(weight_slope=2.0, weight_step=0.0, weight_roughness=1.0)):
        out = dem2hazard(dem, CELL, params)
        t, haz = out["traversability"], out["hazard"]
        defined = haz != UNDEFINED
        assert np.array_equal(np.isfinite(t), defined)
        assert np.nanmin(t) >= 0.0 and np.nanmax(t) <= 1.0
        assert np.any(haz == HAZARDOUS) and np.any(haz == SAFE)
        assert np.all(t[haz == HAZARDOUS] == 0.0)
        safe = haz == SAFE
        scores = (params.weight_slope * (1 - out["slope"] / params.slope_max)
                  + params.weight_step * (1 - out["step"] / params.step_max)
                  + params.weight_roughness * (1 - out["roughness"] / params.roughness_max))
        scores /= params.weight_slope + params.weight_step + params.weight_roughness
        np.testing.assert_allclose(t[safe], scores[safe], atol=1e-5)
    steep = dem2hazard(plane((40, 40), 25.0), CELL, P)["traversability"]
    assert np.nanmax(steep) == 0.0  # the step and roughness scores alone would be well above 0


def test_workflow_step_adds_layers_on_the_same_grid() -> None:
    g = GridGeometry(CELL, -1.0, 2.0, 50, 40)
    layers = Layers(g, {"dem": plane((40, 50), 25.0)})
    out = dem2hazard_layers(layers, {"slope_max": 30.0, "step_max": 0.3})
    assert out.geometry == g and "dem" in out
    for name in ("slope", "roughness", "step", "hazard", "traversability"):
        assert out[name].shape == (40, 50)
    assert out["hazard"].dtype == np.uint8 and out["slope"].dtype == np.float32
    assert set(np.unique(out["hazard"])) == {SAFE, UNDEFINED}  # 25 deg is fine with these limits
    assert out.meta["dem2hazard"]["slope_max"] == 30.0 and out.meta["dem2hazard"]["window_cells"] == 15
    assert "slope" not in layers  # the input is left alone


# ------------------------------------------------------------------------------ previews and CLI


def test_previews_say_what_the_colours_mean() -> None:
    hazard = np.array([[0, 128], [255, 0]], np.uint8)
    rgb = colormaps.classes_rgb(hazard)
    assert rgb[0, 0].tolist() == [0, 0, 0] and rgb[1, 0].tolist() == [255, 255, 255]
    assert rgb[0, 1].tolist() == [128, 128, 128]
    values = np.array([[0.0, 1.0], [np.nan, 0.5]], np.float32)
    img, lo, hi = colormaps.colorize(values, 0.0, 1.0, cv2.COLORMAP_INFERNO)
    lut = cv2.applyColorMap(np.arange(256, dtype=np.uint8).reshape(256, 1), cv2.COLORMAP_INFERNO)[:, 0, ::-1]
    assert img[0, 0].tolist() == lut[0].tolist() and img[0, 1].tolist() == lut[255].tolist()
    assert img[1, 0].tolist() == list(colormaps.UNDEFINED)
    big = colormaps.layer_preview(values, 0.0, 1.0, title="slope", units="deg", marks={0.5: "max"})
    assert big.shape[0] >= 400 and big.shape[1] == 400 + 150 and big.dtype == np.uint8
    legend = colormaps.classes_preview(hazard, shares={"safe": 0.5})
    assert legend.shape[1] == 400 + 150
    assert np.any(np.all(legend[:, 400:] == 0, axis=2))  # the black "safe" swatch and text in the panel


def test_cli_end_to_end(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rasterio = pytest.importorskip("rasterio")
    g = GridGeometry(CELL, -1.3, 2.46, 90, 70)
    rng = np.random.default_rng(2)
    dem = plane((70, 90), 8.0) + rng.normal(0, 0.003, (70, 90)).astype(np.float32)
    _rock(dem, 35, 45, 0.08, 0.25, box=True)
    dem[5:15, 60:80] = -9999.0
    src = write_geotiff(tmp_path / "dem.tif", dem, g, nodata=-9999.0)
    prefix = tmp_path / "out" / "site"
    assert cli.main([str(src), "-o", str(prefix), "--set", "roughness_max=0.08"]) == 0
    printed = capsys.readouterr().out
    assert "safe" in printed and "hazardous" in printed and "undefined" in printed

    expected = dem2hazard(np.where(dem == -9999.0, np.nan, dem), CELL, load_params(roughness_max=0.08))
    with rasterio.open(src) as ds:
        transform = ds.transform
    for name in ("slope", "roughness", "step", "hazard", "traversability"):
        tif = Path(f"{prefix}_{name}.tif")
        with rasterio.open(tif) as ds:
            assert ds.transform == transform and (ds.width, ds.height) == (90, 70)
            data = ds.read(1)
        np.testing.assert_array_equal(data, expected[name])
        side = yaml.safe_load(tif.with_suffix(".yaml").read_text())
        assert side["parameters"]["roughness_max"] == 0.08 and side["inputs"] == [str(src)]
        png = cv2.imread(str(tif.with_suffix(".png")))
        assert png is not None and png.shape[0] >= 70 * 5
    assert np.all(expected["hazard"][5:15, 60:80] == UNDEFINED)
    assert np.all(expected["hazard"][33:38, 43:48] == HAZARDOUS)
    with rasterio.open(f"{prefix}_hazard.tif") as ds:
        assert ds.nodata == UNDEFINED and ds.dtypes[0] == "uint8"
    shares = yaml.safe_load(Path(f"{prefix}_hazard.yaml").read_text())["shares"]
    assert abs(sum(shares.values()) - 1.0) < 1e-5 and shares["hazardous"] > 0

    assert cli.main([str(src), "-o", str(prefix), "--set", "nonsense=1"]) == 2
    assert cli.main([str(tmp_path / "missing.tif"), "-o", str(prefix)]) == 2
