"""Real point clouds: the Autzen airborne lidar (LAS 1.2, classes 1 and 2, NAD83 HARN Lambert
conformal conic in international feet) through the LAS reader, the class filter and DemImport,
against scipy's binned_statistic_2d on the same cells; LAZ, PCD and the range filter.

Why: every DEM figure so far came from the simulator. The shared data lives outside the repository
(../shared/realdata, see its README); a clone alone (CI) skips these tests and says why.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from prox_workflows.cli import dem_import as cli_import
from prox_workflows.grid import read_geotiff
from prox_workflows.pointcloud import read_las, read_pcd, read_points
from prox_workflows.steps.read import read_points as read_points_step

REALDATA = Path(__file__).resolve().parents[2].parent / "shared" / "realdata"
AUTZEN = REALDATA / "points" / "autzen_trim.las"
FOOT = 0.3048

needs_autzen = pytest.mark.skipif(not AUTZEN.is_file(), reason=f"shared real data absent: {AUTZEN} "
                                  "(the repository's ../shared/realdata; CI clones the repository alone)")


@needs_autzen
def test_las_header_unit_and_classes() -> None:
    """Feet become metres (the file's GeoKeys say ProjLinearUnits 9002, the international foot),
    the ground class is the 26,107 points the file holds, and a CRS in feet is not claimed for
    metre coordinates (it stays in source_crs, the file's own WKT)."""
    pts, info = read_las(AUTZEN)
    ground, _ = read_las(AUTZEN, [2])
    assert info.classes == {1: 83893, 2: 26107}
    assert len(pts) == 110_000 and len(ground) == 26_107
    assert info.unit_m == FOOT and info.crs is None
    assert "Lambert_Conformal_Conic" in (info.source_crs or "")
    # the header's extent, in feet, scaled
    assert pts[:, 0].min() == pytest.approx(636001.76 * FOOT, abs=1e-3)
    assert pts[:, 2].max() == pytest.approx(520.51 * FOOT, abs=1e-3)
    assert pts.dtype == np.float64


@needs_autzen
def test_laz_reads_as_the_las(tmp_path: Path) -> None:
    laspy = pytest.importorskip("laspy")
    las = laspy.read(str(AUTZEN))
    laz = tmp_path / "autzen.laz"
    las.write(str(laz))  # compressed by lazrs
    assert laz.stat().st_size < AUTZEN.stat().st_size
    assert np.array_equal(read_points(laz), read_points(AUTZEN))


@needs_autzen
@pytest.mark.parametrize("cell", [2.0, 5.0])
def test_ground_dem_equals_binned_statistic_2d(tmp_path: Path, cell: float) -> None:
    """rvs-dem-import --classes 2 --height max|mean is scipy's binned_statistic_2d of the ground
    points on the same cell edges (max, and mean for --noise none), cell for cell."""
    stats = pytest.importorskip("scipy.stats")
    ground, _ = read_las(AUTZEN, [2])
    for height, statistic in (("max", "max"), ("mean", "mean")):
        out = tmp_path / f"{height}_{cell:g}_dem.tif"
        assert cli_import.main([str(AUTZEN), "--classes", "2", "--cell", str(cell), "--noise", "none",
                                "--height", height, "-o", str(out)]) == 0
        dem, g = read_geotiff(out)
        xedges = g.xmin + np.arange(g.width + 1) * g.cell
        yedges = g.ymin + np.arange(g.height + 1) * g.cell
        ref = stats.binned_statistic_2d(ground[:, 0], ground[:, 1], ground[:, 2], statistic,
                                        bins=[xedges, yedges]).statistic  # [x bin, y bin]
        ref = ref.T[::-1]  # north-up rows, as the GeoTIFF
        assert np.array_equal(np.isfinite(dem), np.isfinite(ref))
        assert np.nanmax(np.abs(dem - ref)) <= 1e-4 * max(1.0, np.nanmax(np.abs(ref)) / 100)


def _write_pcd(path: Path, pts: np.ndarray, binary: bool) -> None:
    head = ("# .PCD v0.7\nVERSION 0.7\nFIELDS x y z intensity\nSIZE 8 8 8 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
            f"WIDTH {len(pts)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(pts)}\n"
            f"DATA {'binary' if binary else 'ascii'}\n")
    if binary:
        rec = np.empty(len(pts), [("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("i", "<f4")])
        rec["x"], rec["y"], rec["z"], rec["i"] = pts.T
        path.write_bytes(head.encode() + rec.tobytes())
    else:
        path.write_text(head + "\n".join(" ".join(repr(float(v)) for v in row) for row in pts) + "\n")


@pytest.mark.parametrize("binary", [False, True])
def test_pcd_ascii_and_binary(tmp_path: Path, binary: bool) -> None:
    pts = np.array([[556440.125, 5394932.25, 543.5, 7.0], [556441.5, 5394933.75, np.nan, 1.0],
                    [556442.0, 5394934.0, 544.0, 3.0]])
    path = tmp_path / "c.pcd"
    _write_pcd(path, pts, binary)
    got = read_pcd(path)
    assert got.dtype == np.float64  # double fields keep UTM coordinates exact
    assert np.array_equal(got, pts[[0, 2]])


def test_range_filter_keeps_points_within_the_sensors_range(tmp_path: Path) -> None:
    pts = np.array([[1.0, 0.0, 0.0], [3.0, 0.0, 0.0], [0.0, 5.0, 0.0], [0.0, 0.0, 0.2]])
    np.save(tmp_path / "p.npy", pts)
    out = read_points_step([tmp_path / "p.npy"], noise="none", sensor=[0.0, 0.0, 1.0], range=[1.0, 4.0])
    assert np.array_equal(out["points"], pts[[0, 1]])
    with pytest.raises(ValueError, match="sensor"):
        read_points_step([tmp_path / "p.npy"], noise="none", range=[1.0, 4.0])
    with pytest.raises(ValueError, match="only LAS"):
        read_points_step([tmp_path / "p.npy"], noise="none", classes=[2])
