"""AcquireTofCoordImages (seed 000 sect. 4.3.1): for each PTU pointing, the sensor's XYZ image
transformed to the global frame and kept as a 4-channel image (x, y, z, intensity) with a
time-tagged name, its ``.cal`` file and an entry in the image list.

The device is reached through a ``grab`` callable the caller supplies (the server passes one
that moves its PTU and grabs from its ToF camera), so this step never imports a driver and
runs the same on recorded data.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from ..products import write_text_atomic, write_tiff
from .transforms import HeadCalibration, T_global_from_rover, apply, camera_matrix, write_cal

# variance(points N x 3 global, sensor position, amplitude N) -> height variance N (m^2)
Variance = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
# grab(pan, tilt) -> (xyz in the camera frame H x W x 3 with -1 or NaN undefined, intensity H x W,
#                     pan reached, tilt reached)
Grab = Callable[[float, float], tuple[np.ndarray, np.ndarray, float, float]]


@dataclass
class View:
    """One acquired view: where it was taken from and what it saw, in the global frame."""

    index: int
    pan: float
    tilt: float
    time: str
    points: np.ndarray  # N x 4 float32: x, y, z (global), intensity - defined pixels only
    variance: np.ndarray  # N float32: per-point height variance from the sensor's noise model
    ranges: np.ndarray  # N float32: distance from the sensor
    P: np.ndarray  # 3 x 4 global -> pixel
    intensity: np.ndarray  # H x W
    depth: np.ndarray  # H x W camera z (NaN undefined), for the ortho-image's occlusion test
    T_global_camera: np.ndarray
    files: dict[str, str] = field(default_factory=dict)


def _stamp() -> str:
    return datetime.now(UTC).strftime("%Y%m%dT%H%M%S_%f")[:-3] + "Z"


def view_from_xyz(
    index: int,
    xyz_cam: np.ndarray,
    intensity: np.ndarray,
    pan: float,
    tilt: float,
    T_global_camera: np.ndarray,
    K: np.ndarray,
    variance: Variance | None = None,
    max_range: float = np.inf,
    min_reflectivity: float = 0.0,
) -> View:
    """Transform one camera-frame XYZ image to the global frame and keep its defined points.

    ``min_reflectivity`` > 0 drops ToF returns whose amplitude is implausibly weak for their
    range: amplitude falls as 1/r^2, so amplitude * r^2 is a surface's apparent reflectivity;
    a far surface whose phase wrapped past c/(2f) shows up close by with a tiny reflectivity
    (a wall 5.5 m away read as 0.5 m). Relative to the view's median, so exposure cancels out.
    """
    xyz = np.asarray(xyz_cam, dtype=np.float32)
    z = xyz[..., 2]
    defined = np.isfinite(z) & (z > 0)
    rng = np.linalg.norm(np.where(defined[..., None], xyz, 0), axis=2)
    defined &= rng <= max_range
    if min_reflectivity > 0 and defined.any():
        refl = np.asarray(intensity, dtype=np.float64) * rng.astype(np.float64) ** 2
        defined &= refl >= min_reflectivity * float(np.median(refl[defined]))
    glob = apply(T_global_camera, xyz[defined])
    amp = np.asarray(intensity, dtype=np.float32)[defined]
    r = rng[defined].astype(np.float32)
    var = (variance(glob, T_global_camera[:3, 3], amp) if variance is not None
           else np.full(len(r), 1e-4, np.float32))
    points = np.concatenate([glob, amp[:, None]], axis=1).astype(np.float32)
    depth = np.where(defined, z, np.nan).astype(np.float32)
    P = camera_matrix(K, T_global_camera)
    return View(index, pan, tilt, _stamp(), points, np.asarray(var, np.float32), r, P,
                np.asarray(intensity, np.float32), depth, T_global_camera)


def acquire_coord_images(
    positions: list[tuple[float, float]],
    grab: Grab,
    head: HeadCalibration,
    pose: tuple[float, float, float, float],
    K: np.ndarray,
    out_dir: Path | None = None,
    stem: str = "view",
    sensor: str = "tof",
    variance: Variance | None = None,
    max_range: float = np.inf,
    min_reflectivity: float = 0.0,
    progress: Callable[[int, int, str], None] | None = None,
    cancelled: Callable[[], bool] | None = None,
    on_view: Callable[[View], None] | None = None,
) -> list[View]:
    """Acquire every pointing; ``pose`` = (x, y, heading, z) of the rover in the global frame.

    Views acquired before a cancellation are kept on disk (and in the image list), so a
    following dem-update can use them; the cancellation itself is raised by the caller's check.
    """
    T_gr = T_global_from_rover(pose[0], pose[1], pose[2], pose[3])
    views: list[View] = []
    rows: list[dict[str, Any]] = []
    for i, (pan, tilt) in enumerate(positions):
        if cancelled is not None and cancelled():
            break
        if progress is not None:
            progress(i, len(positions), f"pan={pan:.1f} tilt={tilt:.1f}")
        xyz, intensity, pan_r, tilt_r = grab(pan, tilt)
        T_gc = T_gr @ head.T_rover_from_sensor(sensor, pan_r, tilt_r)
        view = view_from_xyz(i, xyz, intensity, pan_r, tilt_r, T_gc, K, variance, max_range, min_reflectivity)
        if out_dir is not None:
            name = f"{stem}_{view.time}_v{i:02d}"
            image = np.concatenate([apply(T_gc, np.where(np.isfinite(xyz) & (xyz[..., 2:3] > 0), xyz, np.nan)),
                                    np.asarray(intensity, np.float32)[..., None]], axis=2)
            tif = write_tiff(Path(out_dir) / f"{name}.tif", image.astype(np.float32))
            cal = write_cal(Path(out_dir) / f"{name}.cal", K, T_gc, (xyz.shape[1], xyz.shape[0]),
                            sensor=sensor, pan=pan_r, tilt=tilt_r, time=view.time)
            view.files = {"image": tif.name, "cal": cal.name}
            rows.append({"file": tif.name, "cal": cal.name, "pan": round(pan_r, 4), "tilt": round(tilt_r, 4),
                         "time": view.time, "points": len(view.points)})
            _write_list(Path(out_dir) / f"{stem}_images.csv", rows)
        views.append(view)
        if on_view is not None:
            on_view(view)
        if progress is not None:
            progress(i + 1, len(positions), f"view {i + 1}/{len(positions)}: {len(view.points)} points")
    return views


def _write_list(path: Path, rows: list[dict[str, Any]]) -> None:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    write_text_atomic(path, buf.getvalue())
