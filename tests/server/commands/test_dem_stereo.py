"""dem-full / dem-update with the stereo pair, and -sensor fused, against the simulated truth."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage
from support.marks import long_only
from support.server import ServerThread

from prox_workflows.algorithms.dem_mosaik import resample_nearest
from prox_workflows.grid import GridGeometry, read_geotiff

RANGE = "-60,60,-50,-20"
REF = GridGeometry.covering(-1.0, -4.0, 7.0, 4.0, 0.02)


def truth_on(world) -> tuple[np.ndarray, np.ndarray]:
    truth = world.true_dem(REF.cell, REF.bounds)
    bare = world.true_dem(REF.cell, REF.bounds, include_objects=False)
    terrain = ~ndimage.binary_dilation(~np.isclose(bare, truth, atol=1e-6) | ~np.isfinite(truth), iterations=3)
    xs, ys = REF.centers()
    X, Y = np.meshgrid(xs, ys)
    return truth, terrain & (np.hypot(X, Y) <= 6.0)


def rmse(dem: np.ndarray, truth: np.ndarray, cells: np.ndarray) -> float:
    sel = cells & np.isfinite(dem)
    return float(np.sqrt(np.mean((dem[sel] - truth[sel]) ** 2)))


# in the long suite only (the default run's time: three DEMs a scene, 12 s of CPU; there
# tests/prox/test_fusion_bands.py checks the fused office DEM band by band, tests/prox/test_stereo.py
# the quarry's disparities against the rendered truth)
@pytest.fixture(scope="module", params=[pytest.param("office", marks=long_only()),
                                        pytest.param("quarry", marks=long_only())])
def three_dems(request, tmp_path_factory):
    """One scan each with stereo, ToF and both fused, from the same pose."""
    srv = ServerThread(tmp_path_factory.mktemp(request.param), [f"server.scene={request.param}"]).start()
    try:
        c = srv.client()
        dems = {}
        for name, line in (("stereo", f"dem-full -range {RANGE} -name stereo"),
                           ("tof", f"dem-full-tof -range {RANGE} -name tof"),
                           ("fused", f"dem-full -sensor fused -range {RANGE} -name fused")):
            r = c.request(line, timeout=600)
            assert r.status == "OK", r.fields
            dem, g = read_geotiff(srv.data / r.fields["dem"])
            dems[name] = resample_nearest(dem, g, REF)
        yield request.param, dems, truth_on(srv.app.world)
    finally:
        srv.stop()


def test_stereo_dem_within_5_cm_up_to_6_m(three_dems) -> None:
    scene, dems, (truth, cells) = three_dems
    assert (cells & np.isfinite(dems["stereo"])).sum() > 20000
    assert rmse(dems["stereo"], truth, cells) <= 0.05


def test_fused_beats_each_sensor_on_its_own_cells(three_dems) -> None:
    scene, dems, (truth, cells) = three_dems
    for single in ("tof", "stereo"):
        own = cells & np.isfinite(dems[single])
        assert rmse(dems["fused"], truth, own) < rmse(dems[single], truth, own), (scene, single)
    best = max(np.isfinite(dems["tof"]).sum(), np.isfinite(dems["stereo"]).sum())
    assert np.isfinite(dems["fused"]).sum() >= best


def test_dem_update_with_stereo_and_arguments(server_factory) -> None:
    srv = server_factory()
    c = srv.client()
    assert c.request("dem-update -range 0,10,-40,-30").fields["code"] == "E_DATA"
    assert c.request("dem-full -sensor sonar").fields["code"] == "E_ARG"
    r1 = c.request("dem-full -range -20,20,-45,-30 -name a", timeout=300)
    r2 = c.request("dem-update -range 20,60,-45,-30 -name b", timeout=300)
    assert r1.status == r2.status == "OK"
    assert int(r2.fields["cells"]) > int(r1.fields["cells"])
