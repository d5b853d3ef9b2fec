"""The same product from every entry point: the server's dem job, the workflow engine
on the job's recorded views (``rvs-prox dem_views``) and the toolbox CLIs make byte-identical
GeoTIFF data from the same inputs and parameters, layer by layer. Cheap: one small ToF scan
(few views, 5 cm cells) shared by the module; a stereo scan is the long variant."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import tifffile
from support.marks import long_only
from support.server import ServerThread

from prox_workflows.cli import dem2hazard as cli_dem2hazard
from prox_workflows.cli import dem_import as cli_dem_import
from prox_workflows.cli import dem_mosaik as cli_dem_mosaik
from prox_workflows.cli.prox import main as rvs_prox
from prox_workflows.engine import run_workflow

DEM_LAYERS = ("dem", "variance", "count", "filled", "ortho", "slope", "step", "roughness", "hazard",
              "traversability")
HAZARD_LAYERS = ("slope", "roughness", "step", "hazard", "traversability")


def same_data(a: Path, b: Path) -> bool:
    """The GeoTIFF's pixels, dtype and shape byte for byte (sidecars differ in time, made_by)."""
    x, y = tifffile.imread(a), tifffile.imread(b)
    return x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes()


def scan_of(tmp: Path, command: str) -> dict[str, Any]:
    srv = ServerThread(tmp / "data", ["server.scene=office"]).start()
    try:
        r = srv.client().request(f"{command} -range -20,20,-50,-30 -cell 0.05 -name site -mesh false", timeout=300)
        assert r.status == "OK", r.fields
        hazard = srv.app.config.get("dem2hazard").as_dict()
    finally:
        srv.stop()
    return {"data": srv.data, "fields": r.fields, "hazard": hazard}


@pytest.fixture(scope="module")
def tof_scan(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    return scan_of(tmp_path_factory.mktemp("tof"), "dem-full-tof")


def reprocess(scan: dict[str, Any], out: Path, extra: list[str] | None = None) -> Path:
    views = scan["data"] / "dem" / "site_views"
    assert rvs_prox(["dem_views", "--input", f"views_folder={views}", "--input", f"out_dir={out}",
                     "--set", "name=site", "--set", "cell=0.05", "--set", "mesh=false", *(extra or [])]) == 0
    return out


def test_dem_products_from_the_server_and_from_its_recorded_views_are_byte_identical(
        tof_scan: dict[str, Any], tmp_path: Path) -> None:
    out = reprocess(tof_scan, tmp_path / "again")
    server = tof_scan["data"] / "dem"
    for layer in DEM_LAYERS:
        assert same_data(server / f"site_{layer}.tif", out / f"site_{layer}.tif"), layer
    # the previews too: one layer registry, one colour map per layer
    for layer in ("traversability", "hazard", "slope"):
        assert (server / f"site_{layer}.png").read_bytes() == (out / f"site_{layer}.png").read_bytes(), layer


def test_hazard_maps_from_the_server_and_rvs_dem2hazard_are_byte_identical(
        tof_scan: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    server = tof_scan["data"] / "dem"
    assert cli_dem2hazard.main([str(server / "site_dem.tif"), "-o", str(tmp_path / "cli")]) == 0
    for layer in HAZARD_LAYERS:
        assert same_data(server / f"site_{layer}.tif", tmp_path / f"cli_{layer}.tif"), layer
        assert (server / f"site_{layer}.png").read_bytes() == (tmp_path / f"cli_{layer}.png").read_bytes(), layer


def test_dem_import_from_the_cli_and_the_engine_is_byte_identical(tof_scan: dict[str, Any], tmp_path: Path) -> None:
    views = sorted((tof_scan["data"] / "dem" / "site_views").glob("*_tof.tif"))
    assert views
    assert cli_dem_import.main([*map(str, views), "--cell", "0.05", "-o", str(tmp_path / "cli_dem.tif")]) == 0
    ws, _ = run_workflow("dem_import", {"cell": 0.05}, {
        "paths": [str(v) for v in views], "noise": "recorded", "frequency": 30.0, "rover_mask": None,
        "out_dir": tmp_path, "name": "eng", "preview": False})
    layers = ws["dem"]
    assert "measurement_variance" in layers  # the variances the server recorded were used
    for layer in layers.layers:
        assert same_data(tmp_path / f"cli_{layer}.tif", tmp_path / f"eng_{layer}.tif"), layer


def test_dem_mosaik_from_the_cli_and_the_engine_is_byte_identical(tof_scan: dict[str, Any], tmp_path: Path) -> None:
    dem = tof_scan["data"] / "dem" / "site_dem.tif"
    assert cli_dem_mosaik.main([str(dem), str(dem), "--rule", "fuse", "-o", str(tmp_path / "cli_dem.tif")]) == 0
    ws, _ = run_workflow("dem_mosaik", {"rule": "fuse"}, {"paths": [str(dem), str(dem)], "out_dir": tmp_path,
                                                          "name": "eng", "preview": False})
    for layer in ws["dem"].layers:
        assert same_data(tmp_path / f"cli_{layer}.tif", tmp_path / f"eng_{layer}.tif"), layer


@pytest.mark.parametrize("sensor", [pytest.param("stereo", marks=long_only()), pytest.param("fused", marks=long_only())])
def test_stereo_and_fused_dems_reprocess_byte_identically(sensor: str, tmp_path: Path) -> None:
    scan = scan_of(tmp_path, f"dem-full -sensor {sensor}")
    out = reprocess(scan, tmp_path / "again", ["--set", f"max_range={6.0}"])
    for layer in DEM_LAYERS:
        assert same_data(scan["data"] / "dem" / f"site_{layer}.tif", out / f"site_{layer}.tif"), layer


def test_rvs_prox_help_lists_the_commands_parameters_with_their_defaults(
        server: ServerThread, capsys: pytest.CaptureFixture[str]) -> None:
    c = server.client()
    r = c.request("help dem-full-tof")
    assert r.status == "OK"
    assert rvs_prox(["dem", "--help"]) == 0
    text = capsys.readouterr().out
    from rvs_server.scanning import SCAN_OPTIONS

    options = {k[4:]: v for k, v in r.fields.items() if k.startswith("opt_")}
    assert "on_the_move" in options  # how the server takes the scan: not the chain's to know
    chain = {k: v for k, v in options.items() if k not in SCAN_OPTIONS}
    assert len(chain) >= 10
    for name, described in chain.items():
        assert f"  {name}: {described}" in text, (name, described)
    assert "on_the_move" not in text


def test_recorded_views_round_trip_exactly(tof_scan: dict[str, Any]) -> None:
    from prox_workflows.steps.read import read_views

    got = read_views(tof_scan["data"] / "dem" / "site_views")
    assert len(got["views"]) == int(tof_scan["fields"]["views"]) and got["rover_mask"].shape == (4, 2)
    v = got["views"][0]
    assert v.points.dtype == np.float32 and len(v.points) == len(v.variance) == len(v.ranges)


def test_a_plan_from_a_navigate_leg_and_from_rvs_path_planner_is_byte_identical(
        tof_scan: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from prox_workflows.algorithms.planner import NavMaps
    from prox_workflows.cli import path_planner
    from prox_workflows.layers import read_layers

    dem = tof_scan["data"] / "dem"
    maps = read_layers(dem / "site_dem.tif")  # what a leg holds in memory, as it wrote it
    g = maps.geometry
    rows, cols = np.nonzero(maps["hazard"] == 0)
    xs, ys = g.centers()
    pts = np.column_stack([xs[cols], ys[rows]])
    start = pts[np.argmin(pts[:, 0])]  # the nearest and the farthest safe cells
    goal = pts[np.argmax(pts[:, 0])]
    # a navigate leg: the plan_leg script on the maps in memory, with navigate's parameters
    ws, _ = run_workflow("plan_leg", {"border": 0.1}, {
        "local": NavMaps(maps["hazard"], maps["slope"], g), "global_maps": None, "ortho": (maps["ortho"], g),
        "start": list(start), "goal": list(goal), "start_heading": 0.0, "rover_radius": 0.3, "critical_slope": 20.0,
        "prefix": tmp_path / "leg", "made_by": "navigate"})
    assert len(ws["plan"].path) > 2
    assert path_planner.main(["--hazard", str(dem / "site_hazard.tif"), "--slope", str(dem / "site_slope.tif"),
                              "--ortho", str(dem / "site_ortho.tif"), "--start", f"{start[0]},{start[1]}",
                              "--goal", f"{goal[0]},{goal[1]}", "--start-heading", "0", "--border", "0.1",
                              "-o", str(tmp_path / "cli")]) == 0
    for kind in ("path.csv", "waypoints.csv", "plan_map.png", "plan_ortho.png"):
        assert (tmp_path / f"leg_{kind}").read_bytes() == (tmp_path / f"cli_{kind}").read_bytes(), kind
