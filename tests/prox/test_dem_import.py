"""DemImport (direct reconstruction) against a brute-force per-cell loop, cell borders, clipping
and the rover mask - every test for each implementation (numba's one pass, on one thread and
split over two, and the numpy fallback) - and the implementations against each other."""

from __future__ import annotations

import numpy as np
import pytest

import prox_workflows.algorithms.dem_import as dem_import_module
from prox_workflows.algorithms.dem_import import dem_import, geometry_for
from prox_workflows.grid import GridGeometry

IMPLS = ["numba", "numba-threads", "numpy"]


def use_impl(monkeypatch: pytest.MonkeyPatch, impl: str) -> None:
    """Run dem_import with ``impl``: the compiled pass on one thread, the compiled pass split over
    two threads whatever the size, or the numpy fallback."""
    if impl.startswith("numba"):
        pytest.importorskip("numba")
    monkeypatch.setattr(dem_import_module, "IMPL", impl.split("-")[0])
    monkeypatch.setattr(dem_import_module, "THREADS", 2 if impl == "numba-threads" else 1)
    monkeypatch.setattr(dem_import_module, "THREAD_MIN_POINTS", 0)
    monkeypatch.setattr(dem_import_module, "_core_free", lambda: True)


@pytest.fixture(autouse=True, params=IMPLS)
def impl(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    use_impl(monkeypatch, request.param)
    return request.param


def brute(points: np.ndarray, g: GridGeometry, var: np.ndarray | None = None) -> dict[tuple[int, int], dict]:
    rows, cols = g.cell_of(points[:, 0], points[:, 1])
    cells: dict[tuple[int, int], list[int]] = {}
    for i, (r, c) in enumerate(zip(rows.tolist(), cols.tolist(), strict=True)):
        if 0 <= r < g.height and 0 <= c < g.width:
            cells.setdefault((r, c), []).append(i)
    out = {}
    for key, members in cells.items():
        z = points[members, 2].astype(np.float64)
        stats = {"dem": z.max(), "min": z.min(), "mean": z.mean(), "count": len(z), "variance": z.var()}
        if var is not None:
            w = 1.0 / var[members]
            stats["measurement_variance"] = 1.0 / w.sum()
            stats["wmean"] = (w * z).sum() / w.sum()
        if points.shape[1] == 4:
            stats["intensity"] = points[members, 3].astype(np.float64).mean()
        out[key] = stats
    return out


def check(layers, expected: dict, g: GridGeometry) -> None:
    assert layers.geometry == g
    defined = np.isfinite(layers["dem"])
    assert defined.sum() == len(expected)
    assert (layers["count"] > 0).sum() == len(expected)
    for (r, c), stats in expected.items():
        for name, value in stats.items():
            got = float(layers[name][r, c])
            if name == "count":
                assert got == value
            elif name in ("dem", "min"):
                assert got == np.float32(value), (name, r, c)
            elif name in ("variance", "measurement_variance"):
                assert got == pytest.approx(value, rel=1e-5, abs=1e-12), (name, r, c)
            else:
                assert got == pytest.approx(value, rel=1e-6, abs=1e-6), (name, r, c)
    for name in ("dem", "mean", "min", "variance"):
        assert layers[name].dtype == np.float32
        assert np.all(np.isnan(layers[name][~defined]))
    assert layers["count"].dtype == np.int32
    assert np.all(layers["count"][~defined] == 0)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("chunk", [7, 1 << 16])
def test_matches_brute_force(dtype, chunk) -> None:
    rng = np.random.default_rng(1)
    n = 3000
    pts = np.column_stack([rng.uniform(-1.3, 0.7, n), rng.uniform(2.0, 2.9, n),
                           rng.normal(1.5, 0.3, n), rng.uniform(0, 4000, n)]).astype(dtype)
    var = rng.uniform(1e-6, 4e-4, n)
    layers = dem_import(pts, cell=0.1, point_variance=var, chunk=chunk)
    g = layers.geometry
    # every point is inside the grid the step chose, and the grid is aligned to the cell
    assert brute(pts, g).keys() == brute(pts, GridGeometry(g.cell, g.xmin, g.ymax, g.width + 5, g.height + 5)).keys()
    assert g.xmin / 0.1 == pytest.approx(round(g.xmin / 0.1)) and g.ymax / 0.1 == pytest.approx(round(g.ymax / 0.1))
    check(layers, brute(pts, g, var), g)


def test_millimetre_spread_on_metre_terrain_keeps_its_variance() -> None:
    # 1 mm noise on cells whose heights differ by metres: a naive float32 sum of squares loses it
    rng = np.random.default_rng(2)
    xs = np.repeat(np.arange(20) * 0.05 + 0.025, 200)
    base = np.repeat(rng.uniform(-30, 30, 20), 200)
    pts = np.column_stack([xs, np.full_like(xs, 0.025), base + rng.normal(0, 0.001, len(xs))]).astype(np.float32)
    layers = dem_import(pts, cell=0.05)
    for i in range(20):
        z = pts[i * 200:(i + 1) * 200, 2].astype(np.float64)
        assert layers["variance"][0, i] == pytest.approx(z.var(), rel=1e-4)
        assert layers["mean"][0, i] == pytest.approx(z.mean(), abs=2e-6)


def test_points_on_cell_borders_follow_cell_of() -> None:
    g = GridGeometry(0.02, -0.1, 0.1, 10, 10)
    k = np.arange(-5, 6)
    xs, ys = np.meshgrid(k * 0.02, k * 0.02)  # exactly on the grid lines (as floats can be)
    for dtype in (np.float64, np.float32):
        pts = np.column_stack([xs.ravel(), ys.ravel(), np.arange(xs.size, dtype=float)]).astype(dtype)
        layers = dem_import(pts, geometry=g)
        rows, cols = g.cell_of(pts[:, 0], pts[:, 1])
        inside = g.inside(rows, cols)
        assert inside.sum() == layers["count"].sum()
        for r, c, z in zip(rows[inside], cols[inside], pts[inside, 2], strict=True):
            assert layers["min"][r, c] <= z <= layers["dem"][r, c]
        counts = np.zeros(g.shape, int)
        np.add.at(counts, (rows[inside], cols[inside]), 1)
        assert np.array_equal(counts, layers["count"])


def test_grid_from_points_holds_points_on_its_far_edges() -> None:
    pts = np.array([[0.0, 0.0, 1.0], [1.0, 1.0, 2.0], [0.06, 0.5, 3.0]])
    layers = dem_import(pts, cell=0.02)
    assert layers["count"].sum() == 3
    assert np.nanmax(layers["dem"]) == 3.0
    g = geometry_for(pts, 0.02)
    assert g == layers.geometry


def test_bounds_clip_and_geometry() -> None:
    rng = np.random.default_rng(3)
    pts = np.column_stack([rng.uniform(-5, 5, 5000), rng.uniform(-5, 5, 5000), rng.normal(0, 1, 5000)])
    layers = dem_import(pts, cell=0.25, bounds=(-1.0, -2.0, 2.0, 1.0))
    g = layers.geometry
    assert (g.xmin, g.ymax, g.width, g.height) == (-1.0, 1.0, 12, 12)
    rows, cols = g.cell_of(pts[:, 0], pts[:, 1])
    assert layers["count"].sum() == g.inside(rows, cols).sum()
    check(layers, brute(pts, g), g)


def test_nan_points_are_ignored() -> None:
    pts = np.array([[0.01, 0.01, 1.0], [np.nan, 0.01, 5.0], [0.01, 0.01, np.nan], [0.03, 0.01, 2.0]])
    layers = dem_import(pts, cell=0.02)
    assert layers["count"].sum() == 2
    assert np.nanmax(layers["dem"]) == 2.0


def test_rover_mask_drops_the_body_but_keeps_ground() -> None:
    rng = np.random.default_rng(4)
    ground = np.column_stack([rng.uniform(-3, 3, 20000), rng.uniform(-3, 3, 20000), rng.normal(0, 0.002, 20000)])
    body = np.column_stack([rng.uniform(-0.5, 0.7, 3000), rng.uniform(-0.4, 0.4, 3000), rng.uniform(0.2, 1.2, 3000)])
    pts = np.concatenate([ground, body])
    g = geometry_for(pts, 0.05)
    footprint = np.array([[-0.6, -0.5], [0.8, -0.5], [0.8, 0.5], [-0.6, 0.5]])
    unmasked = dem_import(pts, geometry=g)
    assert np.nanmax(unmasked["dem"]) > 1.0
    masked = dem_import(pts, geometry=g, rover_mask=footprint, rover_ground_z=0.05)
    assert np.nanmax(masked["dem"]) < 0.02
    # ground points under the footprint are kept, body points are gone
    inside = (ground[:, 0] > -0.6) & (ground[:, 0] < 0.8) & (np.abs(ground[:, 1]) < 0.5)
    assert masked["count"].sum() == len(ground)
    assert inside.sum() > 100
    # without a ground height everything inside the footprint goes; a box works like its polygon
    boxed = dem_import(pts, geometry=g, rover_mask=(-0.6, -0.5, 0.8, 0.5))
    assert boxed["count"].sum() == len(ground) - inside.sum()
    # a triangle: only points inside the triangle go
    tri = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 2.0]])
    cut = dem_import(ground, geometry=g, rover_mask=tri)
    in_tri = (ground[:, 0] > 0) & (ground[:, 1] > 0) & (ground[:, 0] + ground[:, 1] < 2)
    assert cut["count"].sum() == len(ground) - in_tri.sum()


def test_a_subset_of_statistics_gives_the_same_layers() -> None:
    rng = np.random.default_rng(8)
    pts = np.column_stack([rng.uniform(0, 1, 2000), rng.uniform(0, 1, 2000), rng.normal(0, 1, 2000)])
    full = dem_import(pts, cell=0.05)
    bare = dem_import(pts, cell=0.05, stats=("dem",))
    assert set(bare.layers) == {"dem"}
    assert np.array_equal(bare["dem"], full["dem"], equal_nan=True)
    some = dem_import(pts, cell=0.05, stats=("dem", "min", "variance"))
    assert set(some.layers) == {"dem", "min", "variance"}
    for name in some.layers:
        assert np.array_equal(some[name], full[name], equal_nan=True)
    with pytest.raises(ValueError):
        dem_import(pts, stats=("mean",))
    with pytest.raises(ValueError):
        dem_import(pts, stats=("dem", "median"))


def test_bad_input_is_refused() -> None:
    with pytest.raises(ValueError):
        dem_import(np.zeros((5, 2)))
    with pytest.raises(ValueError):
        dem_import(np.zeros((5, 3)), point_variance=np.zeros(5))
    with pytest.raises(ValueError):
        dem_import(np.zeros((5, 3)), point_variance=np.ones(4))
    with pytest.raises(ValueError):
        dem_import(np.zeros((5, 3)), rover_mask=np.zeros((2, 2)))


def test_cli_end_to_end_geotiff_opens_in_rasterio(tmp_path, capsys) -> None:
    rasterio = pytest.importorskip("rasterio")
    from prox_workflows.algorithms.transforms import write_cal
    from prox_workflows.cli.dem_import import main, read_layers
    from prox_workflows.pointcloud import write_ply
    from prox_workflows.products import write_tiff

    rng = np.random.default_rng(7)
    pts = np.column_stack([rng.uniform(1, 3, 4000), rng.uniform(-1, 1, 4000), rng.normal(0, 0.01, 4000),
                           rng.uniform(100, 900, 4000)]).astype(np.float32)
    write_ply(tmp_path / "a.ply", pts[:2000])
    np.save(tmp_path / "b.npy", pts[2000:3000])
    img = np.full((10, 100, 4), np.nan, np.float32)
    img.reshape(-1, 4)[:1000] = pts[3000:]
    write_tiff(tmp_path / "v.tif", img)
    T = np.eye(4)
    T[:3, 3] = [0.0, 0.0, 1.2]
    write_cal(tmp_path / "v.cal", np.eye(3), T, (100, 10))
    out = tmp_path / "out" / "site_dem.tif"
    rc = main([str(tmp_path / "a.ply"), str(tmp_path / "b.npy"), str(tmp_path / "v.tif"), "--cell", "0.05",
               "--bounds", "1,-1,3,1", "-o", str(out), "--noise", "tof", "--sensor", "0,0,1.2", "--preview",
               "--height", "max"])  # the thesis's rule; the default is the mean, as the server's
    assert rc == 0
    assert "4000 points" in capsys.readouterr().out
    with rasterio.open(out) as ds:
        assert ds.width == 40 and ds.height == 40
        assert ds.transform.a == pytest.approx(0.05) and ds.transform.e == pytest.approx(-0.05)
        assert (ds.transform.c, ds.transform.f) == pytest.approx((1.0, 1.0))
        band = ds.read(1)
    expect = dem_import(pts[:, :3], cell=0.05, bounds=(1, -1, 3, 1))
    assert np.array_equal(band, expect["dem"], equal_nan=True)
    for name in ("mean", "min", "count", "variance", "measurement_variance", "wmean", "intensity"):
        assert (tmp_path / "out" / f"site_{name}.tif").is_file(), name
    assert (tmp_path / "out" / "site_dem.yaml").is_file() and (tmp_path / "out" / "site_dem.png").is_file()
    back = read_layers(out)
    assert np.array_equal(back["count"], expect["count"])
    assert np.all(back["measurement_variance"][back["count"] > 0] > 0)
    # a bad input is reported, not raised
    assert main([str(tmp_path / "nope.ply"), "--cell", "0.05", "-o", str(tmp_path / "x.tif")]) == 2
    # a plain name keeps itself and prefixes its companions with its stem
    assert main([str(tmp_path / "b.npy"), "--cell", "0.1", "-o", str(tmp_path / "DEM.tif")]) == 0
    assert (tmp_path / "DEM.tif").is_file() and (tmp_path / "DEM_count.tif").is_file()
