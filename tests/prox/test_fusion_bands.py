"""ToF-stereo fusion against the simulated truth per 1 m range band: the table
``python -m tools.bench.fusion`` prints, asserted. Long: one fused scan per scene (about 40 s
each), so it runs in the long suite; the cheap checks of the same code are tests/prox/test_fusion.py
and tests/server/commands/test_dem_stereo.py's fused-beats-each-sensor test."""

from __future__ import annotations

from pathlib import Path

import pytest
from support.marks import long_test

from rvs_truth.fusion import band_rmse, evaluation_cells, load_scan, scan_scene, sensor_dems


@long_test
@pytest.mark.parametrize("scene", ["office", "quarry", "marsyard"])
def test_fused_rmse_below_each_sensor_per_range_band(scene: str, tmp_path: Path) -> None:
    scan = load_scan(scan_scene(scene, tmp_path / scene))
    dems = sensor_dems(scan["views"], scan["rover_mask"], scan["ref"])
    cells, dist = evaluation_cells(scan)
    rows = band_rmse({k: d["dem"] for k, d in dems.items()}, scan["truth"], cells, dist)
    overall = rows[-1]
    assert overall["fused"] < min(overall["tof"], overall["stereo"]), overall
    for r in rows[:-1]:
        if r["cells"] < 100:
            continue
        assert r["fused"] < min(r["tof"], r["stereo"]), (scene, r)
