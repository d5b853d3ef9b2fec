"""The toolbox programs as a user meets them: the help names every input format the reader
takes, and a bad input or option value is one ``tool: message`` line on stderr, exit status 2,
never a traceback."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from prox_workflows import pointcloud
from prox_workflows.cli import dem2hazard, dem_import, dem_mosaik


def test_dem_import_help_names_every_format_it_reads(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        dem_import.main(["--help"])
    assert exc.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    for name in ("PLY", "PCD", "LAS/LAZ", ".npy", "text", "TIFF"):
        assert name in text, name
    # every extension the reader dispatches on is in the help
    source = Path(pointcloud.__file__).read_text()
    suffixes = set(re.findall(r'"(\.[a-z]+)"', source.split("def read_points", 1)[1].split("\ndef ", 1)[0]))
    assert suffixes >= {".ply", ".pcd", ".las", ".laz", ".npy", ".txt"}
    assert {s for s in suffixes if s not in text} == set()


def _one_line(capsys: pytest.CaptureFixture[str], prefix: str) -> str:
    out, err = capsys.readouterr()
    assert "Traceback" not in err and err.count("\n") == 1 and err.startswith(prefix), err
    return err


@pytest.fixture
def cloud(tmp_path: Path) -> Path:
    rng = np.random.default_rng(1)
    np.save(tmp_path / "c.npy", rng.uniform(0, 1, (200, 3)))
    return tmp_path / "c.npy"


def test_bad_inputs_are_one_line_and_exit_2(cloud: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = str(tmp_path / "x_dem.tif")
    assert dem_import.main([str(tmp_path / "missing.ply"), "--cell", "0.1", "-o", out]) == 2
    _one_line(capsys, "rvs-dem-import: ")
    assert dem_import.main([str(cloud), "--cell", "0.1", "--classes", "ground", "-o", out]) == 2
    assert "LAS class numbers" in _one_line(capsys, "rvs-dem-import: --classes 'ground'")
    assert dem_mosaik.main([str(tmp_path / "missing_dem.tif"), "-o", out]) == 2
    _one_line(capsys, "rvs-dem-mosaik: ")
    assert dem2hazard.main([str(tmp_path / "missing_dem.tif"), "-o", str(tmp_path / "h")]) == 2
    _one_line(capsys, "rvs-dem2hazard: ")


@pytest.mark.parametrize(("option", "says"), [
    (("--range", "a,b"), "--range 'a,b': give min,max as numbers, e.g. --range 0.3,4"),
    (("--range", "3,1"), "--range '3,1': need min,max with 0 <= min < max"),
    (("--range", "1,nan"), "--range '1,nan': give min,max as numbers"),
    (("--sensor", "1,x,2"), "--sensor '1,x,2': give x,y,z as numbers"),
    (("--rover-mask", "1,2,q,4"), "--rover-mask '1,2,q,4': give xmin,ymin,xmax,ymax as numbers"),
])
def test_a_bad_number_list_names_its_option_and_shape(cloud: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                      option: tuple[str, str], says: str) -> None:
    assert dem_import.main([str(cloud), "--cell", "0.1", *option, "-o", str(tmp_path / "x_dem.tif")]) == 2
    _one_line(capsys, f"rvs-dem-import: {says}")
