"""Values YAML's safe dumper takes: every sidecar, manifest and console listing goes through
:func:`rvs_params.plain.plain`."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from prox_workflows.products import write_yaml_atomic
from rvs_params.plain import plain


def test_numpy_paths_tuples_and_nan_become_plain_yaml(tmp_path: Path) -> None:
    data = {"k": np.float32(0.5), 3: (np.int64(2), Path("/d/x.tif")), "m": np.eye(2) / 3, "nan": float("nan")}
    written = yaml.safe_load(write_yaml_atomic(tmp_path / "s.yaml", data).read_text())
    assert written == {"k": 0.5, "3": [2, "/d/x.tif"], "m": [[1 / 3, 0.0], [0.0, 1 / 3]], "nan": None}
    assert plain(np.array([[0.1234567891]]), decimals=6) == [[0.123457]]
