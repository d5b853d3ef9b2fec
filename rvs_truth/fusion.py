"""ToF-stereo fusion scored against the simulated truth: one fused scan of a scene through a real
server with the world's true DEM on its grid, the DEM chain's ToF-only, stereo-only and fused DEMs
made from the very same views, and their RMSE per 1 m band of distance from the rover on terrain
cells (cells within 3 cells of an object's edge are left out: a cell's height there is a matter of
where in the cell the edge falls, not of a sensor's noise)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from scipy import ndimage

from prox_workflows.algorithms.dem_mosaik import resample_nearest
from prox_workflows.algorithms.stereo import rectification
from prox_workflows.engine import parameters_of
from prox_workflows.grid import GridGeometry
from prox_workflows.steps.dem import (
    PointCorrelation,
    SensorFusion,
    SpikeRemoval,
    mosaic,
    remove_spikes_layers,
    view_dem,
)
from prox_workflows.steps.read import read_views
from prox_workflows.steps.scan import scan_rule
from rvs_server.client.session import ServerThread, Session

RANGE = "-60,60,-50,-20"


CELL = 0.02


BANDS = (0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0)


def scan_scene(scene: str, folder: Path, view_range: str = RANGE) -> Path:
    """One fused scan of ``scene`` by a server in this process; ``folder``/scan holds its data
    (views under dem/fused_views) and truth.npz the world's DEM on the scan's grid, its bare
    terrain and the rover's position. Kept: a second call with the same folder reads it back."""
    done = folder / "truth.npz"
    if done.is_file():
        return folder
    data = folder / "scan"
    srv = ServerThread([f"server.data={data}", "server.port=0", "drivers.ptu.time_scale=0", "sim.time_scale=0",
                        "server.warm_up=false", f"server.scene={scene}"], log_level="warning").start(120)
    try:
        with Session(port=srv.port) as session:
            session.connect()
            # the GNC reports the true pose, its attitude too: the scan's placement is not what
            # this measures (an IMU's 0.1 deg is 2.6 mm 1.5 m out, common to both sensors)
            t = srv.app.world.truth()
            session.request(f"pose -x {t['x']:.4f} -y {t['y']:.4f} -heading {t['heading']:.3f} "
                            f"-roll {t['roll']:.4f} -pitch {t['pitch']:.4f}")
            r = session.request(f"dem-full -sensor fused -range {view_range} -name fused -mesh false", timeout=1800)
            if not r.ok:
                raise RuntimeError(r.final.text if r.final else f"dem-full: {r.outcome}")
        app = srv.app
        world = app.world
        rect = rectification(app.devices.get("stereo").calibration("low"))
        x, y, _ = world.rover_pose()
        bounds = (x - 7.0, y - 7.0, x + 7.0, y + 7.0)
        np.savez(done, truth=world.true_dem(CELL, bounds), bare=world.true_dem(CELL, bounds, include_objects=False),
                 bounds=np.array(bounds), rover=np.array([x, y]),
                 stereo=np.array([rect.baseline, rect.focal]))
    finally:
        srv.stop()
    return folder


def load_scan(folder: Path) -> dict[str, Any]:
    """The recorded views of a :func:`scan_scene` folder, its rover mask and the truth."""
    rec = read_views(folder / "scan" / "dem" / "fused_views")
    t = np.load(folder / "truth.npz")
    ref = GridGeometry.covering(*[float(b) for b in t["bounds"]], CELL)
    return {"views": rec["views"], "rover_mask": rec["rover_mask"], "truth": t["truth"], "bare": t["bare"],
            "ref": ref, "rover": t["rover"], "stereo": t["stereo"]}


def sensor_dems(views: list[Any], rover_mask: Any, ref: Any, params: Any = None,
                layers: tuple[str, ...] = ("dem",), names: tuple[str, ...] = ("tof", "stereo", "fused")
                ) -> dict[str, dict[str, np.ndarray]]:
    """The DEM chain's layers (after DemMosaik and spike removal; holes are not filled, so
    every defined cell was seen) from the ToF views alone, the stereo views alone and all of
    them, each resampled onto ``ref``; ``params`` (default the dem script's) gives the chain's
    parameters."""
    p = params if params is not None else parameters_of("dem")()
    out = {}
    for name, keep in (("tof", {"tof"}), ("stereo", {"left"}), ("fused", {"tof", "left"})):
        if name not in names:
            continue
        vs = [v for v in views if v.sensor in keep]
        dems = [view_dem(v, CELL, rover_mask, "mean", PointCorrelation.picked_from(p)) for v in vs]
        m = mosaic(dems, None, "fuse", CELL, scan_rule(vs), SensorFusion.picked_from(p))
        m = remove_spikes_layers(m, SpikeRemoval.picked_from(p))
        out[name] = {k: resample_nearest(m[k], m.geometry, ref) for k in layers}
    return out


def evaluation_cells(scan: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """Terrain cells (3 cells away from any object's edge, up to 6 m from the rover) and each
    cell's horizontal distance from the rover."""
    truth, bare, ref = scan["truth"], scan["bare"], scan["ref"]
    edge = ~np.isclose(bare, truth, atol=1e-6) | ~np.isfinite(truth)
    terrain = ~ndimage.binary_dilation(edge, iterations=3)
    xs, ys = ref.centers()
    dist = np.hypot(xs[None, :] - scan["rover"][0], ys[:, None] - scan["rover"][1])
    return terrain & (dist <= BANDS[-1]), dist


def band_rmse(dems: dict[str, np.ndarray], truth: np.ndarray, cells: np.ndarray, dist: np.ndarray
              ) -> list[dict[str, float]]:
    """Per 1 m band, on the cells every one of ``dems`` defines: cell count and RMSE (m) of each."""
    both = cells.copy()
    for d in dems.values():
        both &= np.isfinite(d)
    rows = []
    for lo, hi in zip(BANDS[:-1], BANDS[1:], strict=True):
        sel = both & (dist >= lo) & (dist < hi)
        row: dict[str, float] = {"lo": lo, "hi": hi, "cells": float(sel.sum())}
        for name, d in dems.items():
            row[name] = float(np.sqrt(np.mean((d[sel] - truth[sel]) ** 2))) if sel.any() else float("nan")
        rows.append(row)
    sel = both
    row = {"lo": BANDS[0], "hi": BANDS[-1], "cells": float(sel.sum())}
    for name, d in dems.items():
        row[name] = float(np.sqrt(np.mean((d[sel] - truth[sel]) ** 2))) if sel.any() else float("nan")
    rows.append(row)
    return rows
