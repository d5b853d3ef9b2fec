"""``rvs-prox`` as a user meets it: the help names the campaign commands, a bad --scheduler or
mosaic option is one ``error:`` line (exit 2) and never a traceback, and ``mosaic-campaign -o``
is a folder, as ``rvs-prox dem --from -o`` is. Cheap: no cluster starts, the sites are two tiny
GeoTIFFs."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import tifffile

from prox_workflows.cli.prox import main as rvs_prox
from prox_workflows.grid import GridGeometry, write_geotiff

ROOT = Path(__file__).resolve().parents[2]


def run_prox(cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    """The real command line in a process of its own, so a traceback is seen as the user sees it."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    code = "import sys; from prox_workflows.cli.prox import main; sys.exit(main())"
    return subprocess.run([sys.executable, "-c", code, *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=60)


def one_error_line(err: str, prefix: str) -> str:
    """The last stderr line, checked to be the error (argparse prints its usage above it)."""
    assert "Traceback" not in err, err
    last = err.strip().splitlines()[-1]
    assert last.startswith(prefix), err
    return last


@pytest.fixture
def recorded_job(tmp_path: Path) -> Path:
    """What a batch finds as a DEM job (a views folder with its images list), so the batch gets
    as far as asking Dask for a client."""
    views = tmp_path / "campaign" / "a" / "dem" / "a_views"
    views.mkdir(parents=True)
    (views / "a_images.csv").write_text("view,file\n")
    return views


def test_help_lists_the_campaign_commands(capsys: pytest.CaptureFixture[str]) -> None:
    assert rvs_prox(["--help"]) == 0
    out = capsys.readouterr().out
    assert "rvs-prox batch SCRIPT --inputs GLOB" in out
    assert "rvs-prox mosaic-campaign --inputs GLOB -o DIR" in out


@pytest.mark.parametrize("address", ["local", "tcp://somehost", "foo://somehost:8786", "tcp://somehost:0"])
def test_a_malformed_scheduler_is_one_error_line(recorded_job: Path, tmp_path: Path, address: str) -> None:
    r = run_prox(tmp_path, "batch", "dem", "--inputs", str(recorded_job), "--scheduler", address)
    assert r.returncode == 2, r.stderr
    line = one_error_line(r.stderr, "rvs-prox batch: argument --scheduler:")
    assert repr(address) in line and "tcp://HOST:PORT" in line


def test_bad_batch_and_mosaic_values_are_one_error_line(tmp_path: Path) -> None:
    for args, what in ((["batch", "dem", "--inputs", "x", "--workers", "0"], "--workers"),
                       (["mosaic-campaign", "--inputs", "x", "-o", "m", "--tile", "7"], "--tile"),
                       (["mosaic-campaign", "--inputs", "x", "-o", "m", "--cell", "0"], "--cell"),
                       (["mosaic-campaign", "--inputs", "x", "-o", "m", "--name", "a/b"], "--name")):
        r = run_prox(tmp_path, *args)
        assert r.returncode == 2, (args, r.stderr)
        one_error_line(r.stderr, f"rvs-prox {args[0]}: argument {what}:")


def _site(path: Path, x0: float, height: float) -> Path:
    g = GridGeometry(0.5, x0, 4.0, 8, 8)
    write_geotiff(path, np.full(g.shape, height, np.float32), g)
    return path


def test_mosaic_campaign_out_is_a_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    sites = tmp_path / "sites"
    sites.mkdir()
    _site(sites / "a_dem.tif", 0.0, 1.0)
    _site(sites / "b_dem.tif", 2.0, 1.0)
    out = tmp_path / "campaign" / "mosaic"
    assert rvs_prox(["mosaic-campaign", "--inputs", str(sites / "*_dem.tif"), "-o", str(out), "--tile", "16"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["mosaic_count.tif", "mosaic_dem.tif", "mosaic_dem.yaml",
                                                     "mosaic_variance.tif"]
    assert f"dem: {out / 'mosaic_dem.tif'}" in capsys.readouterr().out
    dem = tifffile.imread(out / "mosaic_dem.tif")
    assert dem.shape == (8, 12) and np.all(dem == 1.0)
    # --name names the files; an existing file is no folder
    assert rvs_prox(["mosaic-campaign", "--inputs", str(sites / "*_dem.tif"), "-o", str(out), "--name", "c1"]) == 0
    assert (out / "c1_dem.tif").is_file()
    with pytest.raises(SystemExit) as exc:
        rvs_prox(["mosaic-campaign", "--inputs", str(sites / "*_dem.tif"), "-o", str(sites / "a_dem.tif")])
    assert exc.value.code == 2 and "not a folder" in capsys.readouterr().err
    assert "-o DIR" in subprocess_help(tmp_path)


def subprocess_help(cwd: Path) -> str:
    r = run_prox(cwd, "mosaic-campaign", "--help")
    assert r.returncode == 0
    return " ".join(r.stdout.split())


def test_an_unreadable_site_is_one_error_line(tmp_path: Path) -> None:
    (tmp_path / "x_dem.tif").write_text("not a tiff")
    r = run_prox(tmp_path, "mosaic-campaign", "--inputs", "*_dem.tif", "-o", "m")
    assert r.returncode == 2
    one_error_line(r.stderr, "rvs-prox mosaic-campaign: ")


def test_a_missing_script_or_bad_value_exits_2(tmp_path: Path) -> None:
    r = run_prox(tmp_path, "nosuch")
    assert r.returncode == 2 and one_error_line(r.stderr, "rvs-prox: no workflow script nosuch")
    r = run_prox(tmp_path, "dem", "--validate", "--set", "cell=abc")
    assert r.returncode == 2 and one_error_line(r.stderr, "rvs-prox: --set cell takes a number")


def test_no_script_or_a_log_in_no_folder_is_one_error_line(tmp_path: Path) -> None:
    r = run_prox(tmp_path)
    assert r.returncode == 2 and r.stdout == ""
    one_error_line(r.stderr, "rvs-prox: name a script to run (or batch, mosaic-campaign)")
    r = run_prox(tmp_path, "dem", "--validate", "--log", str(tmp_path / "no" / "run.yaml"))
    assert r.returncode == 2
    one_error_line(r.stderr, f"rvs-prox: --log {tmp_path / 'no' / 'run.yaml'}: no folder")
