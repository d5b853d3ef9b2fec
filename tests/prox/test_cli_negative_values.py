"""Toolbox programs take negative numbers and lists as option values (``--bounds -2,-3,4,5``),
which plain argparse reads as unknown options; through each program's main and one installed
console script."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from prox_workflows.cli import dem_import, dem_mosaik
from prox_workflows.cli.dem_import import read_layers


@pytest.fixture
def cloud(tmp_path: Path) -> Path:
    rng = np.random.default_rng(3)
    pts = np.column_stack([rng.uniform(-2, 4, 3000), rng.uniform(-3, 5, 3000), rng.normal(0, 0.01, 3000)])
    np.save(tmp_path / "pts.npy", pts.astype(np.float32))
    return tmp_path / "pts.npy"


def test_dem_import_takes_negative_bounds_sensor_and_mask(cloud: Path, tmp_path: Path) -> None:
    out = tmp_path / "a_dem.tif"
    rc = dem_import.main([str(cloud), "--cell", "0.5", "--bounds", "-2,-3,4,5", "--noise", "tof",
                          "--sensor", "-1,-0.5,1.2", "--rover-mask", "-.3,-0.2,0.3,0.2", "-o", str(out)])
    assert rc == 0
    dem = read_layers(out)
    assert dem.geometry.bounds == pytest.approx((-2, -3, 4, 5))
    assert (dem.geometry.width, dem.geometry.height) == (12, 16)
    assert "measurement_variance" in dem.layers  # --sensor was read as the sensor position


def test_dem_mosaik_takes_negative_bounds(cloud: Path, tmp_path: Path) -> None:
    assert dem_import.main([str(cloud), "--cell", "0.5", "-o", str(tmp_path / "a_dem.tif")]) == 0
    out = tmp_path / "m_dem.tif"
    assert dem_mosaik.main([str(tmp_path / "a_dem.tif"), "--bounds", "-1,-2.5,1,0", "-o", str(out)]) == 0
    assert read_layers(out).geometry.bounds == pytest.approx((-1, -2.5, 1, 0))


def test_options_are_still_options(cloud: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:  # a missing value is not filled with the next option
        dem_import.main([str(cloud), "--cell", "0.5", "--bounds", "-o", str(tmp_path / "x.tif")])
    assert exc.value.code == 2 and "--bounds: expected one argument" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        dem_import.main([str(cloud), "--cell", "0.5", "-x", "-o", str(tmp_path / "x.tif")])
    assert "unrecognized arguments: -x" in capsys.readouterr().err


def test_the_installed_program(cloud: Path, tmp_path: Path) -> None:
    exe = Path(sys.executable).with_name("rvs-dem-import")
    out = tmp_path / "s_dem.tif"
    run = subprocess.run([str(exe), str(cloud), "--cell", "1", "--bounds", "-2,-3,4,5", "-o", str(out)],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert read_layers(out).geometry.bounds == pytest.approx((-2, -3, 4, 5))
