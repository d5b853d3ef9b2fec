"""Georeferenced inputs give the same products as the same data at the origin.

Why: a laser scan or an orbital map in a projected CRS has eastings near 500,000 m and northings
near 5,000,000 m. float32 steps there are 0.03-0.5 m, so binning, plane fits or a GeoTIFF
transform that passes through float32 (or subtracts two large numbers late) moves points to the
wrong cell and bends slopes. The chain (rvs-dem-import -> rvs-dem2hazard -> rvs-path-planner) runs
on one cloud at the origin and on the same cloud shifted by the Kootenai reach's UTM origin, and
the products must agree: heights within float tolerance, identical hazard classes, the same path
shifted. The cloud is synthetic (deterministic) so the test runs where ../shared is absent (CI).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from prox_workflows.algorithms.safety import check_move
from prox_workflows.cli import dem2hazard as cli_hazard
from prox_workflows.cli import dem_import as cli_import
from prox_workflows.cli import dem_mosaik as cli_mosaik
from prox_workflows.cli import path_planner as cli_planner
from prox_workflows.grid import read_geotiff

SHIFT = np.array([556440.0, 5394932.0])  # the Kootenai DEM's UTM origin (zone 11N), metres
EPSG = "EPSG:32611"  # WGS 84 / UTM zone 11N, the Kootenai reach's zone
SIZE = 24.0  # metres of terrain on a side
CELL = 0.25


def terrain_cloud(n: int = 40_000, seed: int = 3) -> np.ndarray:
    """N x 3 float64 points of a gentle surface with a ridge and two boulders, z near 543 m.

    Points are drawn away from cell edges by 1 cm so that the binning of a correct float64
    implementation cannot depend on the last ulp of a shifted coordinate."""
    rng = np.random.default_rng(seed)
    cells = int(SIZE / CELL)
    ij = rng.integers(0, cells, size=(n, 2))
    frac = rng.uniform(0.04, 0.96, size=(n, 2))
    xy = (ij + frac) * CELL
    x, y = xy[:, 0], xy[:, 1]
    z = 543.0 + 0.05 * x + 0.3 * np.sin(y / 3.0)
    z += 0.5 * np.exp(-((x - 8.0) ** 2 + (y - 16.0) ** 2) / 1.5)  # a boulder
    z += 0.4 * np.exp(-((x - 16.0) ** 2 + (y - 9.0) ** 2) / 1.0)  # another
    z += np.where(np.abs(x - 12.0) < 0.4, np.where(y > 12.0, 0.6, 0.0), 0.0)  # a wall on half the width
    z += rng.normal(0.0, 0.01, n)
    return np.column_stack([x, y, z])


def _chain(tmp: Path, pts: np.ndarray, offset: np.ndarray, tag: str, crs: str | None = None) -> dict[str, object]:
    """The toolbox chain on ``pts`` shifted by ``offset``; ``crs`` is given to rvs-dem-import only,
    so the mosaic, the hazard maps and the planner must carry it on from their input GeoTIFFs."""
    cloud = pts.copy()
    cloud[:, :2] += offset
    # two overlapping halves, imported on their own grids and mosaicked (DemMosaik's resampling)
    halves = []
    for k, (lo, hi) in enumerate(((0.0, 14.0), (10.0, SIZE))):
        part = cloud[(pts[:, 0] >= lo) & (pts[:, 0] < hi)]
        src = tmp / f"{tag}_{k}.npy"
        np.save(src, part)
        bounds = ",".join(repr(float(v)) for v in (offset[0] + lo, offset[1], offset[0] + hi, offset[1] + SIZE))
        assert cli_import.main([str(src), "--cell", str(CELL), "--bounds", bounds, "--noise", "none",
                                *(["--crs", crs] if crs else []), "-o", str(tmp / f"{tag}{k}_dem.tif")]) == 0
        halves.append(str(tmp / f"{tag}{k}_dem.tif"))
    dem = tmp / f"{tag}_dem.tif"
    assert cli_mosaik.main([*halves, "-o", str(dem)]) == 0
    assert cli_hazard.main([str(dem), "-o", str(tmp / tag), "--no-preview"]) == 0
    start, goal = offset + (2.0, 2.0), offset + (22.0, 22.0)
    assert cli_planner.main(["--hazard", str(tmp / f"{tag}_hazard.tif"), "--slope", str(tmp / f"{tag}_slope.tif"),
                             "--start", f"{float(start[0])!r},{float(start[1])!r}", "--goal", f"{float(goal[0])!r},{float(goal[1])!r}",
                             "-o", str(tmp / f"{tag}_plan")]) == 0
    out: dict[str, object] = {}
    for layer in ("dem", "slope", "step", "roughness", "hazard", "traversability"):
        image, geom = read_geotiff(tmp / f"{tag}_{layer}.tif")
        out[layer], out[layer + "_geom"] = image, geom
    path = np.loadtxt(tmp / f"{tag}_plan_path.csv", delimiter=",", skiprows=1, ndmin=2)
    out["path"] = path
    out["dir"] = tmp
    return out


@pytest.fixture(scope="module")
def products(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict[str, object], dict[str, object]]:
    tmp = tmp_path_factory.mktemp("georef")
    pts = terrain_cloud()
    return _chain(tmp, pts, np.zeros(2), "origin"), _chain(tmp, pts, SHIFT, "utm", EPSG)


def test_the_grid_is_the_same_grid_shifted(products) -> None:
    a, b = products
    ga, gb = a["dem_geom"], b["dem_geom"]
    assert (ga.width, ga.height, ga.cell) == (gb.width, gb.height, gb.cell)
    assert gb.xmin - ga.xmin == pytest.approx(SHIFT[0], abs=1e-6)
    assert gb.ymax - ga.ymax == pytest.approx(SHIFT[1], abs=1e-6)


def test_dem_cells_agree(products) -> None:
    a, b = products
    da, db = a["dem"], b["dem"]
    assert np.array_equal(np.isfinite(da), np.isfinite(db)), "different cells defined"
    diff = np.nanmax(np.abs(da.astype(np.float64) - db))
    assert diff <= 1e-4, f"max abs DEM difference origin vs UTM {diff:.3g} m"


@pytest.mark.parametrize("layer,tol", [("slope", 0.05), ("step", 1e-3), ("roughness", 1e-3)])
def test_hazard_layers_agree(products, layer: str, tol: float) -> None:
    a, b = products
    la, lb = a[layer].astype(np.float64), b[layer].astype(np.float64)
    assert np.array_equal(np.isfinite(la), np.isfinite(lb))
    assert np.nanmax(np.abs(la - lb)) <= tol


def test_hazard_classes_identical(products) -> None:
    a, b = products
    assert (a["hazard"] == 255).any() and (a["hazard"] == 0).any(), "the terrain should have both classes"
    assert np.array_equal(a["hazard"], b["hazard"])


def test_path_is_the_same_path_shifted(products) -> None:
    a, b = products
    pa, pb = a["path"], b["path"]
    assert pa.shape == pb.shape
    shifted = pb[:, :2] - SHIFT
    assert np.max(np.abs(shifted - pa[:, :2])) <= 1e-3


def test_check_move_is_the_same_shifted(products) -> None:
    a, b = products
    moves = [((3.0, 3.0, 0.0), (20.0, 3.0, 0.0)), ((12.0, 2.0, 90.0), (12.0, 20.0, 90.0)),
             ((6.0, 14.0, 30.0), (10.0, 18.0, 45.0))]
    verdicts = set()
    for (x0, y0, h0), (x1, y1, h1) in moves:
        ra = check_move(a["traversability"], a["traversability_geom"], (x0, y0, h0), (x1, y1, h1), 1.0, 0.8)
        rb = check_move(b["traversability"], b["traversability_geom"], (x0 + SHIFT[0], y0 + SHIFT[1], h0),
                        (x1 + SHIFT[0], y1 + SHIFT[1], h1), 1.0, 0.8)
        verdicts.add(ra.verdict)
        assert (ra.verdict, ra.cells, ra.unknown_cells, ra.blocked_cells) == (
            rb.verdict, rb.cells, rb.unknown_cells, rb.blocked_cells)
    assert "not_traversable" in verdicts


PRODUCTS = ("0_dem", "1_dem", "_dem", "_mean", "_count", "_filled", "_slope", "_step", "_roughness", "_hazard",
            "_traversability")


def test_every_product_carries_the_crs(products) -> None:
    """rasterio (GDAL, as QGIS reads them) finds the EPSG code and the UTM origin in every
    GeoTIFF of the UTM chain, though only rvs-dem-import was told the CRS; the sidecars say it."""
    rasterio = pytest.importorskip("rasterio")
    _, b = products
    tmp: Path = b["dir"]
    files = [tmp / f"utm{suffix}.tif" for suffix in PRODUCTS if (tmp / f"utm{suffix}.tif").is_file()]
    assert len(files) >= 8, files
    for f in files:
        with rasterio.open(f) as ds:
            assert ds.crs == rasterio.crs.CRS.from_string(EPSG), f.name
            assert ds.crs.to_epsg() == 32611
            x0 = SHIFT[0] + (10.0 if f.name.startswith("utm1_") else 0.0)  # the eastern half starts at 10 m
            assert ds.transform.c == pytest.approx(x0, abs=1e-6), f.name
            assert ds.transform.f == pytest.approx(SHIFT[1] + SIZE, abs=1e-6), f.name
            assert ds.transform.a == CELL and ds.transform.e == -CELL
        assert yaml.safe_load(f.with_suffix(".yaml").read_text())["crs"] == EPSG, f.name


def test_the_local_frame_stays_the_default(products) -> None:
    """Without --crs the products keep the rover's local engineering frame (no EPSG code)."""
    rasterio = pytest.importorskip("rasterio")
    a, _ = products
    with rasterio.open(a["dir"] / "origin_hazard.tif") as ds:
        assert ds.crs is None or ds.crs.to_epsg() is None
        assert (ds.transform.c, ds.transform.f) == (0.0, SIZE)
    assert a["dem_geom"].crs is None


def test_a_gdal_geotiffs_crs_is_carried_to_the_hazard_maps(tmp_path: Path) -> None:
    """A DEM GeoTIFF GDAL wrote with an EPSG code (NAD83 / UTM 11N, as a survey's DEM comes)
    gives hazard maps in that CRS, with no --crs: the input's own GeoKeys are read."""
    rasterio = pytest.importorskip("rasterio")
    z = (543.0 + 0.02 * np.add.outer(np.arange(40.0), np.arange(30.0))).astype(np.float32)
    z[10:13, 10:13] += 1.0  # a block: hazardous
    src = tmp_path / "survey.tif"
    with rasterio.open(src, "w", driver="GTiff", width=30, height=40, count=1, dtype="float32",
                       crs="EPSG:26911", transform=rasterio.Affine(1.0, 0.0, SHIFT[0], 0.0, -1.0, SHIFT[1] + 40.0),
                       nodata=float("nan")) as ds:
        ds.write(z, 1)
    assert cli_hazard.main([str(src), "-o", str(tmp_path / "h"), "--no-preview"]) == 0
    for layer in ("slope", "hazard", "traversability"):
        with rasterio.open(tmp_path / f"h_{layer}.tif") as ds:
            assert ds.crs.to_epsg() == 26911, layer
            assert (ds.transform.c, ds.transform.f) == (SHIFT[0], SHIFT[1] + 40.0)
    assert (read_geotiff(tmp_path / "h_hazard.tif")[0] == 255).any()
    # an explicit --crs wins over the file's
    assert cli_hazard.main([str(src), "-o", str(tmp_path / "k"), "--no-preview", "--crs", "EPSG:32611"]) == 0
    with rasterio.open(tmp_path / "k_hazard.tif") as ds:
        assert ds.crs.to_epsg() == 32611
