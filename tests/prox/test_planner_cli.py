"""rvs-path-planner end to end on small GeoTIFFs: the outputs, their headers and content, the
printed cost and waypoints, the exit status when there is no path."""

from __future__ import annotations

import csv
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from prox_workflows.cli.path_planner import main
from prox_workflows.grid import GridGeometry, write_geotiff


@pytest.fixture()
def maps(tmp_path: Path) -> dict[str, Path]:
    geom = GridGeometry(0.05, 10.0, 20.0, 80, 60)  # x 10..14, y 17..20
    hz = np.zeros(geom.shape, np.uint8)
    hz[20:45, 38:42] = 255  # a wall at x 11.9..12.1
    hz[:, 75:] = 128  # unseen east edge
    slope = np.full(geom.shape, 6.0, np.float32)
    slope[hz == 128] = np.nan
    g_geom = GridGeometry(0.2, 8.0, 22.0, 50, 30)  # global: x 8..18, y 16..22
    g_hz = np.zeros(g_geom.shape, np.uint8)
    g_hz[20:24, 35:40] = 255  # x 15..16, y 17.2..18
    out = {"hazard": tmp_path / "h.tif", "slope": tmp_path / "s.tif", "ortho": tmp_path / "o.tif",
           "ghazard": tmp_path / "gh.tif", "gslope": tmp_path / "gs.tif"}
    write_geotiff(out["hazard"], hz, geom)
    write_geotiff(out["slope"], slope, geom)
    rng = np.random.default_rng(0)
    write_geotiff(out["ortho"], rng.integers(0, 255, (*geom.shape, 3), dtype=np.uint8), geom)
    write_geotiff(out["ghazard"], g_hz, g_geom)
    write_geotiff(out["gslope"], np.full(g_geom.shape, 3.0, np.float32), g_geom)
    return out


def test_cli_end_to_end(maps: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    prefix = tmp_path / "out" / "plan"
    rc = main(["--hazard", str(maps["hazard"]), "--slope", str(maps["slope"]), "--ortho", str(maps["ortho"]),
               "--start", "10.5,18.5", "--goal", "13.5,18.4", "--weight", "0.6", "--heuristic", "octile",
               "--grid", "0.05", "--rover-radius", "0.15", "--margin", "0.05", "--max-deviation", "0.05",
               "--border", "0.1", "--start-heading", "0", "-o", str(prefix)])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "path cost" in printed and "waypoints:" in printed
    names = ["plan_path.csv", "plan_waypoints.csv", "plan_plan.yaml", "plan_plan_map.png", "plan_plan_ortho.png"]
    for name in names:
        assert (prefix.parent / name).stat().st_size > 0
    assert (prefix.parent / "plan_path.yaml").exists()  # sidecars
    with open(prefix.parent / "plan_path.csv") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["x", "y", "cost_so_far", "drive"]
    path = np.array(rows[1:], float)
    assert path[0, :2].tolist() == [10.5, 18.5] and path[-1, :2].tolist() == [13.5, 18.4]
    assert np.all(np.diff(path[:, 2]) > 0) and path[:, 3].all()
    # it goes round the wall (rows 20..45 = y 17.75..19.0): north of it here
    crossing = path[np.argmin(np.abs(path[:, 0] - 12.0))]
    assert crossing[1] > 19.0 or crossing[1] < 17.75
    with open(prefix.parent / "plan_waypoints.csv") as fh:
        wrows = list(csv.reader(fh))
    assert wrows[0] == ["x", "y", "heading_deg", "turn_deg", "leg_length"]
    wps = np.array(wrows[1:], float)
    assert 2 < len(wps) < len(path)
    assert wps[:, 4].sum() == pytest.approx(np.hypot(*np.diff(wps[:, :2], axis=0).T).sum(), abs=1e-3)
    plan = yaml.safe_load((prefix.parent / "plan_plan.yaml").read_text())
    assert plan["reaches_goal"] is True and plan["cost"] == pytest.approx(path[-1, 2], abs=1e-5)
    assert len(plan["waypoints"]) == len(wps) and plan["parameters"]["weight"] == 0.6
    assert f"{plan['cost']:.3f}" in printed
    img = cv2.imread(str(prefix.parent / "plan_plan_map.png"))
    assert img is not None and img.shape[1] >= 400
    # the A* path is drawn in green and the waypoints in blue (BGR in the file)
    assert ((img[:, :, 1] > 150) & (img[:, :, 0] < 60) & (img[:, :, 2] < 60)).sum() > 50
    assert ((img[:, :, 0] > 200) & (img[:, :, 1] < 60) & (img[:, :, 2] < 60)).sum() > 20
    assert cv2.imread(str(prefix.parent / "plan_plan_ortho.png")) is not None


def test_cli_with_global_maps_and_cut(maps: dict[str, Path], tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    prefix = tmp_path / "g"
    rc = main(["--hazard", str(maps["hazard"]), "--slope", str(maps["slope"]),
               "--global-hazard", str(maps["ghazard"]), "--global-slope", str(maps["gslope"]),
               "--start", "10.5,18.5", "--goal", "17.0,18.0", "--grid", "0.1", "--border", "0.2",
               "-o", str(prefix)])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "cut at the local map's border" in printed
    path = np.loadtxt(tmp_path / "g_path.csv", delimiter=",", skiprows=1)
    assert path[-1, :2].tolist() == [17.0, 18.0] and not path[:, 3].all()
    wps = np.loadtxt(tmp_path / "g_waypoints.csv", delimiter=",", skiprows=1, ndmin=2)
    assert wps[-1, 0] < 13.75  # stops inside the local map (x < 14, unseen east edge, border)


def test_cli_no_path(maps: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = ["--hazard", str(maps["hazard"]), "--slope", str(maps["slope"]), "-o", str(tmp_path / "x")]
    assert main([*args, "--start", "10.5,18.5", "--goal", "12.0,18.5"]) == 1
    err = capsys.readouterr().err
    assert "goal_in_hazard" in err and "hazardous cell" in err
    assert not (tmp_path / "x_path.csv").exists()
    # negative coordinates are coordinates, not options; outside the global maps
    assert main(["--hazard", str(maps["hazard"]), "--slope", str(maps["slope"]),
                 "--global-hazard", str(maps["ghazard"]), "--global-slope", str(maps["gslope"]),
                 "--start", "10.5,18.5", "--goal", "-3.5,18.0", "-o", str(tmp_path / "y")]) == 1
    assert "outside_maps" in capsys.readouterr().err
    # bad input is exit 2
    assert main([*args, "--start", "10.5,18.5", "--goal", "13,18", "--global-hazard", str(maps["ghazard"])]) == 2
    with pytest.raises(SystemExit) as exc:
        main([*args, "--start", "10.5", "--goal", "13,18"])
    assert exc.value.code == 2
