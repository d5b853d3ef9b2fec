"""AcquireTofCoordImages (seed 000 sect. 4.3.1) and its stereo twin: for each PTU pointing,
each sensor's 3D image transformed to the global frame and kept as a 4-channel image (x, y, z,
intensity) with a time-tagged name, its ``.cal`` file and an entry in the image list.

The devices are reached through a ``grab`` callable the caller supplies (the server passes one
that moves its PTU and grabs from its ToF camera, its stereo pair, or both), so this step never
imports a driver and runs the same on recorded data.
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

from ..products import write_text_atomic, write_tiff, write_yaml_atomic
from .noise import coord_image, pixel_features
from .transforms import HeadCalibration, T_global_from_rover, apply, camera_matrix, write_cal

# beside each view's coordinate image: point variance, range, ortho intensity, ortho depth
AUX_SUFFIX = ".aux.tiff"

# variance(points N x 3 global, sensor position, amplitude N, features) -> height variance N (m^2);
# features: per point, what its image neighbours say (noise.pixel_features: jump, cos_incidence,
# wall, texture)
Variance = Callable[[np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]], np.ndarray]


@dataclass
class Frame:
    """What one sensor saw at one pointing, in its own camera frame (a ToF XYZ image, or the
    points a stereo pair triangulated per left pixel)."""

    sensor: str  # "tof" or "left": the mount in the head calibration
    xyz: np.ndarray  # H x W x 3 camera frame, NaN or z <= 0 undefined
    intensity: np.ndarray  # H x W, each point's intensity
    K: np.ndarray  # camera matrix of the ortho images below
    variance: Variance | None = None
    max_range: float = np.inf
    min_reflectivity: float = 0.0
    ortho_intensity: np.ndarray | None = None  # undistorted image for the ortho-image (default: intensity)
    ortho_depth: np.ndarray | None = None  # its camera z, for the occlusion test (default: xyz z)


# grab(pan, tilt) -> (frames, pan reached, tilt reached)
Grab = Callable[[float, float], tuple[list[Frame], float, float]]


@dataclass
class View:
    """One acquired view: where it was taken from and what it saw, in the global frame."""

    index: int
    sensor: str
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
    pixels: np.ndarray | None = None  # flat indices of the points in the H x W image (for recording)


def _stamp() -> str:
    return datetime.now(UTC).strftime("%Y%m%dT%H%M%S_%f")[:-3] + "Z"


def view_from_frame(index: int, frame: Frame, pan: float, tilt: float, T_global_camera: np.ndarray) -> View:
    """Transform one frame to the global frame and keep its defined points.

    ``frame.min_reflectivity`` > 0 drops ToF returns whose amplitude is implausibly weak for
    their range: amplitude falls as 1/r^2, so amplitude * r^2 is a surface's apparent
    reflectivity; a far surface whose phase wrapped past c/(2f) shows up close by with a tiny
    reflectivity. Relative to the view's median, so exposure cancels out.
    """
    xyz = np.asarray(frame.xyz, dtype=np.float32)
    z = xyz[..., 2]
    defined = np.isfinite(z) & (z > 0)
    rng = np.linalg.norm(np.where(defined[..., None], xyz, 0), axis=2)
    defined &= rng <= frame.max_range
    intensity = np.asarray(frame.intensity, dtype=np.float32)
    if frame.min_reflectivity > 0 and defined.any():
        refl = intensity.astype(np.float64) * rng.astype(np.float64) ** 2
        defined &= refl >= frame.min_reflectivity * float(np.median(refl[defined]))
    glob = apply(T_global_camera, xyz[defined])
    amp = intensity[defined]
    r = rng[defined].astype(np.float32)
    points = np.concatenate([glob, amp[:, None]], axis=1).astype(np.float32)
    depth = frame.ortho_depth if frame.ortho_depth is not None else np.where(defined, z, np.nan)
    ortho = frame.ortho_intensity if frame.ortho_intensity is not None else intensity
    if frame.variance is not None:
        # the features from the float32 points and the ortho image a recorded view keeps, so a
        # calibration on recorded views sees exactly what the live model saw
        pixels = np.flatnonzero(defined)
        feats = pixel_features(coord_image(points, pixels, z.shape), T_global_camera[:3, 3], ortho)
        var = frame.variance(points[:, :3], T_global_camera[:3, 3], amp, {k: f.reshape(-1)[pixels] for k, f in feats.items()})
    else:
        var = np.full(len(r), 1e-4, np.float32)
    P = camera_matrix(frame.K, T_global_camera)
    return View(index, frame.sensor, pan, tilt, _stamp(), points, np.asarray(var, np.float32), r, P,
                np.asarray(ortho, np.float32), np.asarray(depth, np.float32), T_global_camera,
                pixels=np.flatnonzero(defined))


def view_images(view: View) -> tuple[np.ndarray, np.ndarray]:
    """The two H x W images a recorded view is: the coordinate image (x, y, z global,
    intensity; NaN where the view kept no point) and its companion (point variance, range,
    ortho intensity, ortho depth). They hold exactly the float32 values processing uses, so a
    DEM made from the recorded views is byte-identical to the one the server made live."""
    h, w = view.intensity.shape[:2]
    coords = np.full((h * w, 4), np.nan, np.float32)
    aux = np.full((h * w, 4), np.nan, np.float32)
    if view.pixels is not None:
        coords[view.pixels] = view.points
        aux[view.pixels, 0] = view.variance
        aux[view.pixels, 1] = view.ranges
    coords = coords.reshape(h, w, 4)
    aux = aux.reshape(h, w, 4)
    aux[..., 2] = view.intensity
    aux[..., 3] = view.depth
    return coords, aux


def view_from_images(index: int, coords: np.ndarray, aux: np.ndarray, cal: dict[str, Any]) -> View:
    """A recorded view back (the inverse of :func:`view_images`), its ``.cal`` giving K and T."""
    flat = coords.reshape(-1, 4)
    pixels = np.flatnonzero(np.isfinite(flat[:, 2]))
    T = np.asarray(cal["T_global_camera"], float)
    K = np.asarray(cal["K"], float)
    a = aux.reshape(-1, 4)
    return View(index, str(cal.get("sensor", "tof")), float(cal.get("pan", 0.0)), float(cal.get("tilt", 0.0)),
                str(cal.get("time", "")), np.ascontiguousarray(flat[pixels]),
                np.ascontiguousarray(a[pixels, 0]), np.ascontiguousarray(a[pixels, 1]), camera_matrix(K, T),
                np.ascontiguousarray(aux[..., 2]), np.ascontiguousarray(aux[..., 3]), T, pixels=pixels)


def acquire_coord_images(
    positions: list[tuple[float, float]],
    grab: Grab,
    head: HeadCalibration,
    pose: tuple[float, ...],
    out_dir: Path | None = None,
    stem: str = "view",
    progress: Callable[[int, int, str], None] | None = None,
    cancelled: Callable[[], bool] | None = None,
    on_view: Callable[[View], None] | None = None,
    scan: dict[str, Any] | None = None,
    move_ahead: Callable[[float, float], None] | None = None,
) -> list[View]:
    """Acquire every pointing; ``pose`` = (x, y, heading, z[, roll, pitch]) of the rover in the
    global frame (:func:`~.transforms.T_global_from_rover`).

    ``move_ahead(pan, tilt)``, if given, sends the PTU on to the next pointing without waiting
    (the next ``grab`` waits for it): the PTU travels while this view is transformed, its
    noise model evaluated and its files written, so a scan lasts about as long as the PTU's
    travel and the sensor's frames.

    Each frame becomes a view: a 4-channel image (x, y, z global, intensity; NaN undefined)
    with a time-tagged name, its ``.cal`` and a row of the image list. Views acquired before a
    cancellation or a device fault are kept on disk and passed to ``on_view`` as they come, so a
    following dem-update can use them. ``scan`` (the rover pose and mask the processing uses)
    goes to ``<stem>_scan.yaml`` with the pointings in the order taken, so the folder alone is
    enough to process the views again and to see how they were taken.
    """
    T_gr = T_global_from_rover(*pose)
    if out_dir is not None:
        write_yaml_atomic(Path(out_dir) / f"{stem}_scan.yaml",
                          {"pose": list(pose), "positions": [[float(p), float(t)] for p, t in positions], **(scan or {})})
    views: list[View] = []
    rows: list[dict[str, Any]] = []
    for i, (pan, tilt) in enumerate(positions):
        if cancelled is not None and cancelled():
            break
        if progress is not None and i == 0:  # the phase's first line: its size before the first view
            progress(0, len(positions), f"view 1/{len(positions)}: pan={pan:.1f} tilt={tilt:.1f}")
        frames, pan_r, tilt_r = grab(pan, tilt)
        if move_ahead is not None and i + 1 < len(positions) and not (cancelled is not None and cancelled()):
            move_ahead(*positions[i + 1])
        for frame in frames:
            T_gc = T_gr @ head.T_rover_from_sensor(frame.sensor, pan_r, tilt_r)
            view = view_from_frame(len(views), frame, pan_r, tilt_r, T_gc)
            if out_dir is not None:
                name = f"{stem}_{view.time}_v{i:02d}_{frame.sensor}"
                xyz = np.asarray(frame.xyz, np.float32)
                coords, aux = view_images(view)
                tif = write_tiff(Path(out_dir) / f"{name}.tif", coords)
                write_tiff(Path(out_dir) / f"{name}{AUX_SUFFIX}", aux)
                cal = write_cal(Path(out_dir) / f"{name}.cal", frame.K, T_gc, (xyz.shape[1], xyz.shape[0]),
                                sensor=frame.sensor, pan=pan_r, tilt=tilt_r, time=view.time)
                view.files = {"image": tif.name, "cal": cal.name}
                rows.append({"file": tif.name, "cal": cal.name, "sensor": frame.sensor, "pan": round(pan_r, 4),
                             "tilt": round(tilt_r, 4), "time": view.time, "points": len(view.points)})
                _write_list(Path(out_dir) / f"{stem}_images.csv", rows)
            views.append(view)
            if on_view is not None:
                on_view(view)
        if progress is not None:
            progress(i + 1, len(positions), f"view {i + 1}/{len(positions)}: "
                                            f"{sum(len(v.points) for v in views[-len(frames):])} points")
    return views


def _write_list(path: Path, rows: list[dict[str, Any]]) -> None:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    write_text_atomic(path, buf.getvalue())
