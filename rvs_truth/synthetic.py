"""Inputs whose truth is known by construction: a ToF scan of an analytic terrain, and a recorded
scan moved elsewhere (what the same scan taken there would have recorded)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import tifffile
import yaml

from prox_workflows.algorithms.transforms import camera_matrix

SIDE = 10.0


def terrain(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Rolling ground with a few rocks (m)."""
    z = 0.15 * np.sin(0.9 * x) * np.cos(0.7 * y) + 0.05 * np.sin(3.1 * x + 1.3 * y)
    for cx, cy, r, h in ((2.0, 3.0, 0.3, 0.25), (7.5, 6.0, 0.5, 0.4), (4.0, 8.0, 0.2, 0.15)):
        d2 = (x - cx) ** 2 + (y - cy) ** 2
        z = z + h * np.exp(-d2 / (r * r))
    return z


def tof_scan(n: int, seed: int = 0) -> np.ndarray:
    """About ``n`` points (N x 3 float32) of a 24-view scan from a sensor at the centre, 1 m up:
    12 pan sectors x 2 tilt bands, each view a pixel raster (rows = range, cols = azimuth),
    in pixel order, so consecutive points are neighbours on the ground as in a real image."""
    rng = np.random.default_rng(seed)
    views = []
    per_view = int(n * 1.35 / 24) + 1  # about a quarter of the far band falls outside the square
    for k in range(24):
        pan = (k % 12) * (2 * np.pi / 12)
        near = k < 12
        r0, r1 = (0.6, 3.0) if near else (2.8, 7.2)
        rows = int(np.sqrt(per_view * 0.8))
        cols = per_view // rows
        t = np.linspace(0.0, 1.0, rows)[:, None]
        # pixels at equal angles below the horizon: range grows faster than linearly with the row
        r = r0 * (r1 / r0) ** t
        a = pan + np.linspace(-0.32, 0.32, cols)[None, :]
        x = SIDE / 2 + r * np.cos(a)
        y = SIDE / 2 + r * np.sin(a)
        z = terrain(x, y) + rng.normal(0, 0.004, x.shape) * (r / 2)
        views.append(np.stack([x, y, z], -1).reshape(-1, 3))
    pts = np.concatenate(views)
    inside = (pts[:, 0] >= 0) & (pts[:, 0] < SIDE) & (pts[:, 1] >= 0) & (pts[:, 1] < SIDE)
    pts = pts[inside][:n].astype(np.float32)
    return pts


def shifted_copy(views: Path, dest: Path, name: str, dx: float, dy: float) -> Path:
    """A recorded job copied to ``dest`` as ``name``, moved by (dx, dy) in the global frame: what
    the same scan taken elsewhere would have recorded (points, camera poses, rover pose and mask)."""
    src_name = views.name[: -len("_views")]
    out = dest / f"{name}_views"
    out.mkdir(parents=True, exist_ok=True)
    shift = np.array([dx, dy], np.float64)
    for p in views.iterdir():
        target = out / p.name.replace(src_name, name, 1)
        if p.name.endswith(".aux.tiff"):
            shutil.copyfile(p, target)
        elif p.suffix == ".tif":
            img = tifffile.imread(p)
            img[..., :2] = (img[..., :2].astype(np.float64) + shift).astype(np.float32)
            tifffile.imwrite(target, img, photometric="minisblack")
        elif p.suffix == ".cal":
            cal = yaml.safe_load(p.read_text())
            T = np.asarray(cal["T_global_camera"], float)
            T[:2, 3] += shift
            cal["T_global_camera"] = T.tolist()
            cal["P"] = camera_matrix(np.asarray(cal["K"], float), T).tolist()
            target.write_text(yaml.safe_dump(cal, sort_keys=False))
        elif p.name.endswith("_scan.yaml"):
            scan = yaml.safe_load(p.read_text())
            scan["pose"][0] += dx
            scan["pose"][1] += dy
            if scan.get("rover_mask") is not None:
                scan["rover_mask"] = (np.asarray(scan["rover_mask"]) + shift).tolist()
            target.write_text(yaml.safe_dump(scan, sort_keys=False))
        elif p.suffix == ".csv":
            target.write_text(p.read_text().replace(src_name, name))
    sidecar = views.parent / f"{src_name}_dem.yaml"
    if sidecar.is_file():  # the parameters the job recorded: what a re-run reads
        info = yaml.safe_load(sidecar.read_text())
        info["parameters"]["name"] = name
        (dest / f"{name}_dem.yaml").write_text(yaml.safe_dump(info, sort_keys=False))
    return out
