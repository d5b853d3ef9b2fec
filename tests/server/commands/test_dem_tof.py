"""dem-full-tof and dem-update-tof through the server, against the simulated world's truth."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import rasterio
import yaml
from scipy import ndimage
from support.marks import long_only, long_test

from prox_workflows.algorithms.dem_mosaik import resample_nearest
from prox_workflows.grid import GridGeometry, read_geotiff

RANGE = "-90,90,-50,-15"


def terrain_truth(world, g: GridGeometry) -> tuple[np.ndarray, np.ndarray]:
    """True heights and a mask of plain terrain (no walls or boxes, whose tops no scan sees)."""
    truth = world.true_dem(g.cell, g.bounds)
    bare = world.true_dem(g.cell, g.bounds, include_objects=False)
    objects = ~np.isclose(bare, truth, atol=1e-6) | ~np.isfinite(truth)
    return truth, ~ndimage.binary_dilation(objects, iterations=3)


def visible_cells(world, data, name: str, g: GridGeometry, max_range: float) -> np.ndarray:
    """Cells the sensor could see from the views it took (ground truth render of each view)."""
    seen = np.zeros(g.shape, bool)
    with open(data / "dem" / f"{name}_views" / f"{name}_images.csv") as fh:
        rows = list(csv.DictReader(fh))
    K = world.camera_intrinsics("tof", 176, 144)
    T_wr = world.T_world_rover()
    for row in rows:
        T = T_wr @ world.head.T_rover_from_sensor("tof", float(row["pan"]), float(row["tilt"]))
        r = world.render(K, 176, 144, T)
        ok = np.isfinite(r.range) & (r.range <= max_range) & (r.object_id == 0)
        pts = r.points[ok]
        rr, cc = g.cell_of(pts[:, 0], pts[:, 1])
        inside = g.inside(rr, cc)
        seen[rr[inside], cc[inside]] = True
    return seen


@pytest.fixture
def scan(server_factory):
    def run(scene: str, name: str = "site", extra: str = "", overrides: list[str] | None = None):
        srv = server_factory([f"server.scene={scene}", *(overrides or [])])
        c = srv.client()
        r = c.request(f"dem-full-tof -range {RANGE} -name {name} {extra}", timeout=300)
        assert r.status == "OK", r.fields
        return srv, c, r

    return run


@pytest.mark.parametrize("scene", [pytest.param("office", marks=long_only()), "quarry"])
def test_dem_matches_ground_truth(scan, scene: str) -> None:
    srv, c, r = scan(scene)
    dem, g = read_geotiff(srv.data / r.fields["dem"])
    world = srv.app.world
    truth, terrain = terrain_truth(world, g)
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    rx, ry, _ = world.rover_pose()
    near = np.hypot(X - rx, Y - ry) <= 4.0
    ok = np.isfinite(dem) & terrain & near
    err = dem[ok] - truth[ok]
    rmse = float(np.sqrt(np.mean(err**2)))
    assert ok.sum() > 5000 and rmse <= 0.02, (rmse, float(np.median(err)))
    seen = visible_cells(world, srv.data, "site", g, 4.0) & terrain & near
    coverage = (np.isfinite(dem) & seen).sum() / seen.sum()
    assert coverage >= 0.80, coverage
    assert int(r.fields["cells"]) == int(np.isfinite(dem).sum())


def test_products_open_in_gdal_and_the_recovery_set_loads_them_back(scan, server_factory) -> None:
    srv, c, r = scan("office", name="prod")
    dem_path = srv.data / r.fields["dem"]
    _, g = read_geotiff(dem_path)
    for layer in ("dem", "variance", "count", "ortho", "slope", "step", "roughness", "hazard", "traversability"):
        path = srv.data / "dem" / f"prod_{layer}.tif"
        with rasterio.open(path) as ds:
            assert ds.res == (g.cell, g.cell)
            assert (ds.bounds.left, ds.bounds.top) == pytest.approx((g.xmin, g.ymax))
            assert (ds.width, ds.height) == (g.width, g.height)
            band = ds.read(1)
        assert path.with_suffix(".png").stat().st_size > 1000
        side = yaml.safe_load(path.with_suffix(".yaml").read_text())
        assert side["made_by"] == "dem-full-tof" and side["layer"] == layer and side["cell"] == g.cell
        if layer == "hazard":
            assert set(np.unique(band)) <= {0, 128, 255}
        if layer == "traversability":
            finite = band[np.isfinite(band)]
            assert finite.min() >= 0 and finite.max() <= 1
    ortho = read_geotiff(srv.data / "dem/prod_ortho.tif")[0]
    dem = read_geotiff(dem_path)[0]
    assert (ortho[np.isfinite(dem)] > 0).mean() > 0.9  # what the DEM has, the ortho-image shows
    mesh = (srv.data / "dem/prod_mesh.ply").read_bytes()[:300].decode("ascii", "replace")
    assert "element face" in mesh
    views = list((srv.data / "dem/prod_views").glob("*.tif"))
    assert len(views) == int(r.fields["views"])
    assert (srv.data / "dem/prod_views/prod_images.csv").is_file()

    # a break writes the recovery set: the maps and the pose, which a new server on the same data
    # directory reports and loads back
    c.request("pose -x 0.5 -y 0.25 -heading 10")
    r = c.request("break")
    rec = srv.data / r.fields["recovery"]
    assert (rec / "maps" / "prod_dem.tif").is_file() and (rec / "maps" / "prod_traversability.tif").is_file()
    srv.stop()
    srv2 = server_factory(["server.scene=office"], data=srv.data)
    c2 = srv2.client()
    assert c2.request("status").fields["recovery"] == r.fields["recovery"]
    assert c2.request("check-move -dx 0.2").fields["code"] == "E_DATA"
    loaded = c2.request("recover")
    assert loaded.status == "OK" and loaded.fields["recovery"] == r.fields["recovery"]
    assert loaded.fields["pose"] == "0.500,0.250,10.00"
    assert c2.request("check-move -dx 0.2").status == "OK"
    assert c2.request("recover -set nosuch").fields["code"] == "E_DATA"


@long_test  # 7-9 s of scans: CI's long suite runs it; the DEM against the truth runs by default
def test_update_fuses_lowers_noise_and_extends(scan) -> None:
    srv, c, r1 = scan("office", name="a")
    dem1, g1 = read_geotiff(srv.data / r1.fields["dem"])
    r2 = c.request("dem-update-tof -range 60,180,-50,-15 -name b", timeout=300)
    assert r2.status == "OK", r2.fields
    dem2, g2 = read_geotiff(srv.data / r2.fields["dem"])
    # the update covers what the first scan covered and more
    assert g2.xmin <= g1.xmin + 1e-9 and g2.ymax >= g1.ymax - 1e-9
    assert int(r2.fields["cells"]) > int(r1.fields["cells"])
    assert (srv.data / r1.fields["dem"]).is_file()  # earlier products intact


@long_test  # three scans; the default run's test_update_fuses_lowers_noise_and_extends fuses two
def test_fusing_two_scans_beats_either(server_factory) -> None:
    srv = server_factory(["server.scene=office"])
    c = srv.client()
    # the GNC reports the rover's true attitude (level on the office floor): what is measured is
    # the fusion, not the two scans' placement (the simulated IMU's 0.1 deg, drawn per read, put
    # the two apart by about that, 5 mm three metres out)
    assert c.request("pose -x 0 -y 0 -heading 0 -roll 0 -pitch 0").status == "OK"
    for line in (f"dem-full-tof -range {RANGE} -name alone1 -integrate 1",
                 f"dem-full-tof -range {RANGE} -name alone2 -integrate 1",
                 f"dem-update-tof -range {RANGE} -name fused -integrate 1"):
        assert c.request(line, timeout=300).status == "OK"
    world = srv.app.world
    ref = GridGeometry.covering(0.3, -2.5, 3.0, 2.5, 0.02)
    truth, terrain = terrain_truth(world, ref)
    xs, ys = ref.centers()
    X, Y = np.meshgrid(xs, ys)
    common = terrain & (np.hypot(X, Y) <= 3.0)
    dems = {}
    for name in ("alone1", "alone2", "fused"):
        dem, g = read_geotiff(srv.data / "dem" / f"{name}_dem.tif")
        dems[name] = resample_nearest(dem, g, ref)
        common &= np.isfinite(dems[name])
    assert common.sum() > 5000
    rmse = {n: float(np.sqrt(np.mean((d[common] - truth[common]) ** 2))) for n, d in dems.items()}
    # alone2 is the scan the update fused into: the fusion of alone2 with a new scan beats both
    assert rmse["fused"] < min(rmse["alone1"], rmse["alone2"]), rmse


def test_update_without_a_dem_is_e_data(server) -> None:
    c = server.client()
    r = c.request("dem-update-tof -range 0,10,-40,-30")
    assert r.fields["code"] == "E_DATA" and "dem-full-tof" in r.fields["message"]


def test_dem_arguments(server) -> None:
    c = server.client()
    assert c.request("dem-full-tof -range 1,2,3").fields["code"] == "E_ARG"
    assert c.request("dem-full-tof -name ../x").fields["code"] == "E_ARG"
    assert c.request("dem-full-tof -cell 0").fields["code"] == "E_ARG"
    r = c.request("help dem-full-tof")
    assert "-range" in r.fields["usage"] and "opt_range" in r.fields


@long_test  # the default run's time; break and continue during dem-update-tof run there (test_break_continue)
def test_break_keeps_views_for_the_next_update(server_factory) -> None:
    srv = server_factory()
    c, other = srv.client(), srv.client()
    assert c.request(f"dem-full-tof -range {RANGE} -name first", timeout=300).status == "OK"
    # the simulated clock (PTU moves) at half the real speed from here (applies live): the break finds the scan running
    assert c.request("config -module sim -set time_scale=0.5").status == "OK"
    job = c.start_job(f"dem-full-tof -range {RANGE} -name second")
    while True:  # wait until a view or two are in
        line = c.reply(timeout=60)
        if line.status == "PROGRESS" and line.fields["message"].startswith("view 2/"):
            break
    assert other.request("break").fields["interrupted"] == job
    final = c.until_final(job=job)[-1]
    assert final.fields["code"] == "E_INTERRUPTED" and "views kept" in final.fields["message"]
    assert (srv.data / "dem/first_dem.tif").is_file() and not (srv.data / "dem/second_dem.tif").exists()
    assert other.request("continue").status == "OK"
    r = c.request("dem-update-tof -range 0,20,-50,-40 -name third", timeout=300)
    assert r.status == "OK"
    assert int(r.fields["views"]) >= 3  # the kept views and the new one


@long_test  # the default run's time; check-move's sweep is tested on maps in tests/prox/test_safety.py
def test_check_move_on_a_real_scan(scan) -> None:
    srv, c, _ = scan("office", name="gate")
    blind = c.request("check-move -dx 0.5")  # the ground under and right around the rover: unseen
    assert blind.fields["verdict"] == "unknown"
    c.request("pose -x 0.8 -y -1.3 -heading 0")  # on floor the scan saw
    ok = c.request("check-move -dx 0.5")
    assert ok.status == "OK" and ok.fields["verdict"] == "ok", ok.fields
    rock = c.request("check-move -to 2.3,-0.45")  # the 0.20 m rock
    assert rock.fields["verdict"] == "not_traversable"
    behind = c.request("check-move -to -2,-1.2")  # the scan looked forward only (pan -90..90)
    assert behind.fields["verdict"] == "unknown"
    assert c.request("check-move -dx 1 -to 1,1").fields["code"] == "E_ARG"
