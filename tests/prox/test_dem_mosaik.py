"""DemMosaik: union extents, resampling between cell sizes, the max / newest / fuse rules, the
Mahalanobis gate, and the ToF noise model the fuse rule weighs by."""

from __future__ import annotations

import numpy as np
import pytest

from prox_workflows.algorithms.dem_import import dem_import
from prox_workflows.algorithms.dem_mosaik import dem_mosaik, input_variance, union_geometry
from prox_workflows.algorithms.noise import tof_height_variance, tof_sigma
from prox_workflows.grid import GridGeometry, Layers


def flat(g: GridGeometry, z: float | np.ndarray, var: float | None = None) -> Layers:
    layers = Layers(g)
    layers["dem"] = np.broadcast_to(np.asarray(z, np.float32), g.shape).copy()
    layers["count"] = np.where(np.isfinite(layers["dem"]), 1, 0).astype(np.int32)
    if var is not None:
        layers["measurement_variance"] = np.full(g.shape, var, np.float32)
    return layers


A = GridGeometry(0.1, 0.0, 1.0, 10, 10)  # (0, 0) - (1, 1), 10 cm
B = GridGeometry(0.05, 0.5, 1.5, 30, 20)  # (0.5, 0.5) - (2, 1.5), 5 cm


def at(layers: Layers, x: float, y: float, name: str = "dem") -> float:
    r, c = layers.geometry.cell_of(np.array([x]), np.array([y]))
    return float(layers[name][r[0], c[0]])


def test_union_extent_and_max_across_cell_sizes() -> None:
    m = dem_mosaik([flat(A, 1.0), flat(B, 2.0)], rule="max")
    g = m.geometry
    assert g.cell == 0.05
    assert g.bounds == pytest.approx((0.0, 0.0, 2.0, 1.5))
    assert g == union_geometry([A, B])
    assert at(m, 0.2, 0.2) == 1.0  # A only
    assert at(m, 0.7, 0.7) == 2.0  # both: the greater
    assert at(m, 1.5, 1.2) == 2.0  # B only
    assert np.isnan(at(m, 0.2, 1.2))  # neither
    assert at(m, 0.2, 0.2, "source") == 0 and at(m, 0.7, 0.7, "source") == 1
    assert at(m, 0.7, 0.7, "count") == 2 and at(m, 0.2, 0.2, "count") == 1
    assert np.isfinite(m["dem"]).sum() == 20 * 20 + 30 * 20 - 10 * 10
    # and the other way round the max is the same
    assert np.array_equal(dem_mosaik([flat(B, 2.0), flat(A, 1.0)], rule="max")["dem"], m["dem"], equal_nan=True)


def test_newest_overwrites_where_defined() -> None:
    b = flat(B, 2.0)
    b["dem"][10:15, :5] = np.nan  # a hole in the newer DEM (x 0.5-0.75, y 0.75-1) keeps the older value
    m = dem_mosaik([flat(A, 3.0), b], rule="newest")
    assert at(m, 0.7, 0.7) == 2.0
    assert at(m, 0.55, 0.95) == 3.0  # B's hole over A
    m2 = dem_mosaik([b, flat(A, 3.0)], rule="newest")
    assert at(m2, 0.7, 0.7) == 3.0


def test_downsampling_keeps_the_greatest_height_and_its_variance() -> None:
    fine = GridGeometry(0.05, 0.0, 1.0, 20, 20)
    z = np.arange(400, dtype=np.float32).reshape(20, 20)
    src = flat(fine, z, var=0.0)
    src["measurement_variance"] = (z / 1000.0).astype(np.float32)
    m = dem_mosaik([src], rule="max", cell=0.1)
    assert m.geometry == GridGeometry(0.1, 0.0, 1.0, 10, 10)
    expect = z.reshape(10, 2, 10, 2).max(axis=(1, 3))
    assert np.array_equal(m["dem"], expect)
    assert np.allclose(m["variance"], expect / 1000.0)
    assert np.all(m["count"] == 4)


def test_upsampling_is_nearest_cell() -> None:
    coarse = GridGeometry(0.2, 0.0, 0.4, 2, 2)
    z = np.array([[1.0, 2.0], [3.0, 4.0]], np.float32)
    m = dem_mosaik([flat(coarse, z)], rule="max", cell=0.05)
    assert m.geometry.shape == (8, 8)
    assert np.array_equal(m["dem"], np.kron(z, np.ones((4, 4))))


def test_max_mosaic_of_views_equals_one_import_of_all_points() -> None:
    rng = np.random.default_rng(5)
    pts = np.column_stack([rng.uniform(0, 2, 6000), rng.uniform(0, 2, 6000), rng.normal(0, 0.2, 6000)])
    g = GridGeometry(0.05, 0.0, 2.0, 40, 40)
    views = [dem_import(pts[i::3], cell=0.05) for i in range(3)]  # each on its own extent
    m = dem_mosaik(views, rule="max", geometry=g)
    whole = dem_import(pts, geometry=g)
    assert np.array_equal(m["dem"], whole["dem"], equal_nan=True)
    assert np.array_equal(m["count"], whole["count"])


def scan(surface, sensor: np.ndarray, g: GridGeometry, rng: np.random.Generator) -> Layers:
    """One point per cell of a known surface seen from ``sensor``, noise from the ToF model."""
    xs, ys = g.centers()
    x, y = np.meshgrid(xs, ys)
    x = x.ravel() + rng.uniform(-0.4, 0.4, x.size) * g.cell
    y = y.ravel() + rng.uniform(-0.4, 0.4, y.size) * g.cell
    z = surface(x, y)
    rngm = np.sqrt((x - sensor[0]) ** 2 + (y - sensor[1]) ** 2 + (z - sensor[2]) ** 2)
    sigma = tof_sigma(rngm).astype(np.float64)
    pts = np.column_stack([x, y, z + rng.normal(0, 1, z.size) * sigma])
    return dem_import(pts, geometry=g, point_variance=sigma**2)


def test_fusing_two_noisy_scans_beats_either() -> None:
    rng = np.random.default_rng(6)

    def surface(x, y):
        return 0.2 * np.sin(x) + 0.1 * np.cos(2 * y)

    g = GridGeometry(0.05, 0.0, 3.0, 60, 60)
    a = scan(surface, np.array([-0.5, 1.5, 1.0]), g, rng)  # from the west
    b = scan(surface, np.array([3.5, 1.5, 1.0]), g, rng)  # from the east
    xs, ys = g.centers()
    truth = np.array([[surface(x, y) for x in xs] for y in ys])

    def rmse(layers):
        return float(np.sqrt(np.nanmean((layers["dem"] - truth) ** 2)))

    fused = dem_mosaik([a, b], rule="fuse")
    assert fused.geometry == g
    assert np.isfinite(fused["dem"]).all()
    assert rmse(fused) < 0.8 * min(rmse(a), rmse(b))
    # the estimate's variance is the Kalman one, below both inputs', except where the 3-sigma
    # gate met a 1-in-370 outlier and inflated the prior instead
    below = fused["variance"] <= np.minimum(a["measurement_variance"], b["measurement_variance"]) + 1e-12
    assert (~below).sum() == fused.meta["rejected_cells"] < 0.01 * below.size
    # each side weighs more where it is nearer: the fused error tracks the better scan
    west, east = slice(0, 20), slice(40, 60)
    err = np.abs(fused["dem"] - truth)
    assert np.mean(err[:, west]) < np.mean(np.abs(b["dem"] - truth)[:, west])
    assert np.mean(err[:, east]) < np.mean(np.abs(a["dem"] - truth)[:, east])
    # newest / max do not average: fuse is what removes the noise
    assert rmse(fused) < rmse(dem_mosaik([a, b], rule="newest"))


def test_kalman_update_is_eq_6_1() -> None:
    g = GridGeometry(0.1, 0.0, 0.1, 1, 1)
    m = dem_mosaik([flat(g, 1.00, var=0.0004), flat(g, 1.03, var=0.0001)], rule="fuse")
    assert m["dem"][0, 0] == pytest.approx((0.0001 * 1.00 + 0.0004 * 1.03) / 0.0005, abs=1e-6)
    assert m["variance"][0, 0] == pytest.approx(0.0004 * 0.0001 / 0.0005, rel=1e-5)


def test_gate_rejects_an_outlier_layer_and_inflates_variance() -> None:
    g = GridGeometry(0.1, 0.0, 1.0, 10, 10)
    prior = flat(g, 1.0, var=1e-4)
    z = np.full(g.shape, 1.005, np.float32)
    z[:, 5:] = 1.5  # half the new layer is 0.5 m off: 35 sigma
    new = flat(g, z, var=1e-4)
    m = dem_mosaik([prior, new], rule="fuse", inflation=0.0025)
    assert np.allclose(m["dem"][:, :5], 1.0025, atol=1e-6)  # consistent half fused
    assert np.allclose(m["variance"][:, :5], 5e-5)
    assert np.all(m["dem"][:, 5:] == 1.0)  # outliers rejected
    assert np.allclose(m["variance"][:, 5:], 1e-4 + 0.0025)  # and the prior inflated
    assert m.meta["rejected_cells"] == 50
    assert np.all(m["source"][:, 5:] == 0) and np.all(m["source"][:, :5] == 1)
    # a change that persists is taken once the inflated prior admits it
    # (0.5 m / sqrt(2e-4 + k * 0.01) <= 3 from the 3rd rejection on: the 4th scan is accepted)
    assert np.all(dem_mosaik([prior] + [new] * 3, rule="fuse", inflation=0.01)["dem"][:, 5:] == 1.0)
    later = dem_mosaik([prior] + [new] * 4, rule="fuse", inflation=0.01)
    assert np.all(later["dem"][:, 5:] > 1.49)
    # inside one scan the higher wins outright
    higher = dem_mosaik([prior, new], rule="fuse", on_conflict="higher")
    assert np.all(higher["dem"][:, 5:] == 1.5)
    lower = dem_mosaik([new, prior], rule="fuse", on_conflict="higher")
    assert np.all(lower["dem"][:, 5:] == 1.5)


def test_input_variance_sources() -> None:
    g = GridGeometry(0.1, 0.0, 0.1, 2, 1)
    plain = flat(g, 1.0)
    assert np.allclose(input_variance(plain, sigma=0.02), 0.0004)
    plain["variance"] = np.array([[0.0001, np.nan]], np.float32)
    assert np.allclose(input_variance(plain, sigma=0.02), [[0.0005, 0.0004]])
    measured = flat(g, 1.0, var=0.0009)
    assert np.allclose(input_variance(measured, sigma=0.02), 0.0009)
    est = dem_mosaik([measured], rule="fuse")
    assert est.meta["variance"] == "estimate"
    assert np.allclose(input_variance(est, sigma=0.02), 0.0009)


def test_bad_arguments() -> None:
    with pytest.raises(ValueError):
        dem_mosaik([flat(A, 1.0)], rule="mean")
    with pytest.raises(ValueError):
        dem_mosaik([])
    with pytest.raises(ValueError):
        dem_mosaik([flat(A, 1.0)], rule="fuse", on_conflict="lower")


def test_noise_model_grows_with_range_and_falls_with_amplitude() -> None:
    r = np.array([0.5, 1.0, 2.0, 4.0])
    s = tof_sigma(r)
    assert np.all(np.diff(s) > 0)
    amp = np.array([200.0, 1000.0, 5000.0, 20000.0])
    s_amp = tof_sigma(np.full(4, 2.0), amp)
    assert np.all(np.diff(s_amp) < 0)
    # the same amplitude farther away is still worse (range term), and never below the floor
    assert tof_sigma(4.0, 5000.0) > tof_sigma(1.0, 5000.0)
    assert tof_sigma(0.1, 1e9) >= 0.0005
    # 1 cm on the office floor 1.5 m away at about 4500 counts, as the simulated camera
    assert float(tof_sigma(1.5, 4500.0)) == pytest.approx(0.0104, abs=0.001)
    # 15 MHz doubles the shot term; 4 frames halve it
    shot30 = float(tof_sigma(1.0, 1000.0, range_coeff=0, noise_floor=0))
    assert float(tof_sigma(1.0, 1000.0, frequency_mhz=15, range_coeff=0, noise_floor=0)) == pytest.approx(2 * shot30, rel=1e-6)
    assert float(tof_sigma(1.0, 1000.0, frames=4, range_coeff=0, noise_floor=0)) == pytest.approx(shot30 / 2, rel=1e-6)
    # height variance: a floor at a grazing angle is better than its range sigma, a vertical ray not
    sensor = np.array([0.0, 0.0, 1.0])
    pts = np.array([[4.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    hv = tof_height_variance(pts, sensor)
    rs = tof_sigma(np.linalg.norm(pts - sensor, axis=1)) ** 2
    assert hv[0] < rs[0]
    assert hv[1] == pytest.approx(rs[1], rel=1e-5)


def test_cli_fuse_end_to_end(tmp_path, capsys) -> None:
    rasterio = pytest.importorskip("rasterio")
    from prox_workflows.cli.dem_import import read_layers, write_layers
    from prox_workflows.cli.dem_mosaik import main

    a = flat(A, 1.0, var=1e-4)
    b = flat(B, 1.01, var=1e-4)
    write_layers(tmp_path / "a_dem.tif", a, "test")
    write_layers(tmp_path / "b_dem.tif", b, "test")
    out = tmp_path / "m_dem.tif"
    assert main([str(tmp_path / "a_dem.tif"), str(tmp_path / "b_dem.tif"), "--rule", "fuse", "-o", str(out)]) == 0
    assert "2 DEMs" in capsys.readouterr().out
    with rasterio.open(out) as ds:
        assert (ds.width, ds.height) == (40, 30)
        assert ds.transform.a == pytest.approx(0.05)
        assert (ds.transform.c, ds.transform.f) == pytest.approx((0.0, 1.5))
    m = read_layers(out)
    assert m.meta["variance"] == "estimate"
    assert at(m, 0.7, 0.7) == pytest.approx(1.005, abs=1e-6)
    assert at(m, 0.7, 0.7, "variance") == pytest.approx(5e-5, rel=1e-4)
    assert at(m, 0.2, 0.2, "variance") == pytest.approx(1e-4, rel=1e-4)
    # fed back in, the mosaic's variance is taken as it is (not sigma^2 again)
    assert np.allclose(input_variance(m, sigma=0.5)[np.isfinite(m["dem"])], m["variance"][np.isfinite(m["dem"])])
    # without measurement variances --sigma sets them; --fill adds the filled layer
    plain = flat(A, 2.0)
    plain["dem"][4, 4] = np.nan
    write_layers(tmp_path / "p_dem.tif", plain, "test")
    assert main([str(tmp_path / "p_dem.tif"), "--rule", "fuse", "--sigma", "0.03", "--fill", "0.2",
                 "-o", str(tmp_path / "q_dem.tif")]) == 0
    q = read_layers(tmp_path / "q_dem.tif")
    assert q.geometry == A
    assert np.allclose(q["variance"][np.isfinite(plain["dem"])], 0.0009)
    assert q["filled"][4, 4] == 1 and q["dem"][4, 4] == pytest.approx(2.0)
    assert main([str(tmp_path / "missing.tif"), "-o", str(tmp_path / "z.tif")]) == 2
