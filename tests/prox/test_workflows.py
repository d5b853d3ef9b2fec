"""Offline and distributed reprocessing: ``rvs-prox dem --from``, the
server's ``prox`` command, ``rvs-prox batch`` on Dask and the tiled campaign mosaic. Cheap: one
small ToF scan (one view, 5 cm cells) recorded by a real server, shared by the module; the
batch's other inputs are that scan shifted (rvs_truth.synthetic.shifted_copy)."""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import tifffile
import yaml
from support.server import ServerThread

from prox_workflows.batch import (
    close_client,
    find_inputs,
    make_client,
    mosaic_campaign,
    mosaic_in_memory,
    run_batch,
)
from prox_workflows.cli.batch import main as batch_main
from prox_workflows.cli.prox import main as rvs_prox
from rvs_truth.synthetic import shifted_copy

DEM_LAYERS = ("dem", "variance", "count", "filled", "ortho", "slope", "step", "roughness", "hazard",
              "traversability")


def same_data(a: Path, b: Path) -> bool:
    x, y = tifffile.imread(a), tifffile.imread(b)
    return x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes()


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerThread]:
    """A server that has made one DEM job, dem/site (kept running for the prox command)."""
    srv = ServerThread(tmp_path_factory.mktemp("wf") / "data", ["server.scene=office"]).start()
    try:
        r = srv.client().request("dem-full-tof -range -20,20,-50,-30 -cell 0.05 -name site -mesh false", timeout=300)
        assert r.status == "OK", r.fields
        yield srv
    finally:
        srv.stop()


def test_from_reproduces_the_jobs_products_and_set_cell_changes_them(site: ServerThread, tmp_path: Path,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    dem = site.data / "dem"
    assert rvs_prox(["dem", "--from", str(dem / "site"), "-o", str(tmp_path / "same")]) == 0
    for layer in DEM_LAYERS:
        assert same_data(dem / f"site_{layer}.tif", tmp_path / "same" / f"site_{layer}.tif"), layer
    assert not [p for p in (tmp_path / "same").iterdir() if p.name.startswith(".")]  # no staging left
    # the recorded parameters, one overridden: a coarser grid, recorded as such
    assert rvs_prox(["dem", "--from", str(dem / "site_views"), "--set", "cell=0.1", "-o", str(tmp_path / "coarse")]) == 0
    a, b = tifffile.imread(dem / "site_dem.tif"), tifffile.imread(tmp_path / "coarse" / "site_dem.tif")
    assert b.shape[0] < a.shape[0] * 0.6 and b.shape[1] < a.shape[1] * 0.6
    info = yaml.safe_load((tmp_path / "coarse" / "site_dem.yaml").read_text())
    assert info["parameters"]["cell"] == 0.1 and info["parameters"]["range"] == [-20.0, 20.0, -50.0, -30.0]
    assert info["cell"] == 0.1
    # refused: an unknown parameter, a folder that is no job
    assert rvs_prox(["dem", "--from", str(dem / "site"), "--set", "cel=0.1", "-o", str(tmp_path / "x")]) == 2
    assert rvs_prox(["dem", "--from", str(tmp_path), "-o", str(tmp_path / "x")]) == 2
    assert "known: range" in capsys.readouterr().err


def test_the_prox_command_reprocesses_as_a_job_over_tcp(site: ServerThread) -> None:
    c = site.client(timeout=120)
    c.send('@p prox -script dem -from dem/site -set "cell=0.05 mesh=false"')
    replies = c.until_final(timeout=120)
    assert replies[0].status == "ACK"
    progress = [r for r in replies if r.status == "PROGRESS"]
    assert {r.fields["phase"] for r in progress} == {"process", "write"}
    ok = replies[-1]
    assert ok.status == "OK", ok.fields
    assert ok.fields["dem"] == "dem/reprocessed/site_dem.tif" and int(ok.fields["views"]) == 1
    out = site.data / "dem" / "reprocessed"
    for layer in DEM_LAYERS:  # the job's parameters: the job's products, byte for byte
        assert same_data(out / f"site_{layer}.tif", site.data / "dem" / f"site_{layer}.tif"), layer
    assert yaml.safe_load((out / "site_dem.yaml").read_text())["made_by"] == "prox"
    assert yaml.safe_load((site.data / "dem" / "site_dem.yaml").read_text())["made_by"] == "dem-full-tof"


def test_prox_refuses_paths_outside_the_data_directory_before_the_ack(site: ServerThread, tmp_path: Path) -> None:
    outside = tmp_path / "outside"
    shutil.copytree(site.data / "dem" / "site_views", outside / "evil_views")
    os.symlink(outside / "evil_views", site.data / "dem" / "link_views")
    c = site.client()
    for raw in ("../../etc", "/etc/passwd", "dem/../../x", str(outside / "evil_views"), "dem/link_views", "dem/link"):
        r = c.request(f'prox -from "{raw}"')
        assert r.status == "ERROR" and r.fields["code"] == "E_ARG", (raw, r)
        assert "outside the data directory" in r.fields["message"], r
    r = c.request("prox -from dem/nothing")
    assert r.status == "ERROR" and r.fields["code"] == "E_DATA" and str(site.data) not in r.fields["message"], r
    r = c.request('prox -from dem/site -set "cell=5"')
    assert r.status == "ERROR" and r.fields["code"] == "E_ARG", r
    assert not (outside / "reprocessed").exists()
    (site.data / "dem" / "link_views").unlink()


def test_break_interrupts_prox(site: ServerThread) -> None:
    c = site.client(timeout=120)
    for _ in range(8):  # a one-view job may end before the break is dispatched: try until caught
        c.send("@job prox -from dem/site -set cell=0.02\n@brk break")
        finals: dict[str, Any] = {}
        while len(finals) < 2:
            r = c.reply(120)
            if r.status in ("OK", "ERROR") and r.tag in ("job", "brk"):
                finals[r.tag] = r
        assert c.request("continue").status == "OK"
        if finals["job"].status == "ERROR":
            assert finals["job"].fields["code"] == "E_INTERRUPTED", finals["job"]
            assert finals["brk"].fields["interrupted"] == finals["job"].fields["job"]
            break
    else:
        pytest.fail("prox always ended before the break reached it")


@pytest.fixture(scope="module")
def campaign(site: ServerThread, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two sites (the scan, and the scan moved 1 m: they overlap) and a broken third."""
    root = tmp_path_factory.mktemp("campaign")
    views = site.data / "dem" / "site_views"
    shifted_copy(views, root / "a" / "dem", "a", 0.0, 0.0)
    shifted_copy(views, root / "b" / "dem", "b", 1.0, 0.5)
    broken = shifted_copy(views, root / "c" / "dem", "c", 2.0, 0.0)
    for p in broken.glob("*.aux.tiff"):
        p.unlink()
    return root


def test_batch_reports_a_failing_input_runs_the_others_and_skips_them_on_a_rerun(
        campaign: Path, capsys: pytest.CaptureFixture[str]) -> None:
    inputs, ignored = find_inputs([str(campaign / "*" / "dem" / "*")])  # views folders and sidecars: each job once
    assert [p.name for p in inputs] == ["a_views", "b_views", "c_views"] and ignored == []
    client = make_client(workers=1, processes=False, threads_per_worker=2)
    seen: list[tuple[int, int]] = []
    try:
        first = run_batch("dem", inputs, client=client, progress=lambda d, t, m: seen.append((d, t)))
        assert [r.status for r in first] == ["done", "done", "failed"], [r.error for r in first]
        assert "aux.tiff" in first[2].error
        for r in first[:2]:
            dem = Path(r.files["dem"])
            assert dem.parent.name == "reprocessed" and dem.is_file()
        assert seen[-1] == (3, 3) and all(t == 3 for _, t in seen)
        again = run_batch("dem", inputs, client=client)
        assert [r.status for r in again] == ["skipped", "skipped", "failed"]
        # an input newer than its products is done again
        dem = Path(first[0].files["dem"])
        older = next(inputs[0].glob("*_scan.yaml")).stat().st_mtime - 10
        os.utime(dem, (older, older))
        third = run_batch("dem", inputs[:2], client=client)
        assert [r.status for r in third] == ["done", "skipped"]
    finally:
        close_client(client)
    # the command line: everything up to date, so no cluster is even started
    assert batch_main(["batch", "dem", "--inputs", str(campaign / "[ab]" / "dem" / "*")]) == 0
    assert "2 jobs: 0 done, 2 skipped, 0 failed" in capsys.readouterr().out


def test_the_tiled_campaign_mosaic_equals_the_mosaic_in_memory(campaign: Path, tmp_path: Path) -> None:
    sites = []
    for name in ("a", "b"):
        assert rvs_prox(["dem", "--from", str(campaign / name / "dem" / name), "-o", str(tmp_path / name)]) == 0
        sites.append(tmp_path / name / f"{name}_dem.tif")
    files = mosaic_campaign(sites, tmp_path / "m" / "campaign", tile=16)
    whole = mosaic_in_memory(sites)
    with tifffile.TiffFile(files["dem"]) as tif:
        assert tif.pages[0].is_tiled and tif.pages[0].shape == whole.geometry.shape
    for layer in ("dem", "variance", "count"):
        tiled = tifffile.imread(files[layer])
        assert tiled.dtype == whole[layer].dtype and np.array_equal(tiled, whole[layer], equal_nan=True), layer
    # both sites fused where they overlap: more cells than either, counts summed
    a = tifffile.imread(sites[0])
    assert np.isfinite(whole["dem"]).sum() > np.isfinite(a).sum()
    from prox_workflows.layers import read_layers

    back = read_layers(files["dem"])  # GDAL-style georeferencing: the reader places it
    assert back.geometry == whole.geometry
    import rasterio

    with rasterio.open(files["dem"]) as ds:  # GDAL reads the tiled GeoTIFF in place
        assert ds.block_shapes[0] == (16, 16)
        assert tuple(ds.bounds) == pytest.approx(whole.geometry.bounds)
        assert np.array_equal(ds.read(1), whole["dem"], equal_nan=True)
    # the command line makes the same mosaic, in the folder -o names
    assert rvs_prox(["mosaic-campaign", "--inputs", str(tmp_path / "[ab]" / "*_dem.tif"), "-o",
                     str(tmp_path / "cli"), "--name", "campaign", "--tile", "32"]) == 0
    assert np.array_equal(tifffile.imread(tmp_path / "cli" / "campaign_dem.tif"), whole["dem"], equal_nan=True)
