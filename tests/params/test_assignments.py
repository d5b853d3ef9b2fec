"""``key=value`` words, as ``--set``, ``config -set``, ``rvs-prox --input``, reprocess's ``-set``
and the device consoles take them: split once by :func:`rvs_params.assignment`, typed and checked
by the keys' own ParamSpecs where the tool has a settings class."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from prox_workflows.algorithms.dem2hazard import HazardParams
from prox_workflows.cli import dem2hazard as cli
from prox_workflows.grid import GridGeometry, write_geotiff
from rvs_params import SettingError, assignments


def test_words_split_at_the_first_equals_with_option_spelling() -> None:
    assert assignments("step-max=0.2 crs=EPSG:32611 note=a=b") == {
        "step_max": "0.2", "crs": "EPSG:32611", "note": "a=b"}
    assert assignments(None) == {} and assignments(["x="]) == {"x": ""}
    for bad in ("window", "=0.3", " =1"):
        with pytest.raises(SettingError, match=r"-set '.*': write key=value"):
            assignments([bad], flag="-set")


def test_a_settings_class_types_and_checks_each_value() -> None:
    assert HazardParams.parse_assignments(["slope-max=20", "window=0.5"]) == {"slope_max": 20.0, "window": 0.5}
    with pytest.raises(SettingError, match=r"^--set window takes a number in \[0.02, 5\] m, not 'wide'"):
        HazardParams.parse_assignments(["window=wide"])
    with pytest.raises(SettingError, match=r"--set nonsense: unknown key; known: window, step_max"):
        HazardParams.parse_assignments(["nonsense=1"])


def test_rvs_dem2hazard_refuses_a_set_value_its_parameter_refuses(tmp_path: Path, capsys) -> None:
    g = GridGeometry(0.0, 1.0, 0.05, 20, 20)
    src = Path(write_geotiff(tmp_path / "dem.tif", np.zeros((20, 20), np.float32), g))
    assert cli.main([str(src), "-o", str(tmp_path / "out"), "--set", "step_max=9"]) == 2
    assert "rvs-dem2hazard: --set step_max is 9, out of range [0.001, 2] m" in capsys.readouterr().err
    assert not list(tmp_path.glob("out_*"))
