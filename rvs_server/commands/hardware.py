"""Hardware commands: move-ptu, grab-stereo, grab-tof."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import cv2
import numpy as np

from drivers.stereo.modes import PIXEL_FORMATS, RESOLUTIONS
from prox_workflows.products import preview, product_set, write_png, write_sidecar, write_tiff

from ..config import ModuleConfig, param
from ..jobs import Job, default_stem, device_call
from ..protocol import Fixed, ProtocolError
from ..table import HARDWARE, command

if TYPE_CHECKING:
    from ..app import App


def acquisition_context(app: App) -> dict[str, Any]:
    """Where the rover and the PTU were: goes into every image's sidecar."""
    pose = app.pose
    ptu = app.ptu_position()
    out: dict[str, Any] = {"pose": {"x": pose.x, "y": pose.y, "heading": pose.heading}}
    if ptu is not None:
        out["ptu"] = {"pan": ptu[0], "tilt": ptu[1]}
    return out


def check_ptu_angles(app: App, pan: float | None, tilt: float | None) -> None:
    """Angles outside the PTU's limits (read from the unit when it opened) are E_ARG before any
    ACK. An unopened PTU is left to the job, which says E_DEVICE."""
    dev = app.devices.devices.get("ptu")
    if dev is None:
        return
    try:
        limits = dev.limits()
    except Exception:  # noqa: BLE001 - no limits known yet: the unit answers for itself
        return
    for axis, value in (("pan", pan), ("tilt", tilt)):
        lim = limits.get(axis)
        if value is not None and lim and not lim["min_deg"] <= value <= lim["max_deg"]:
            raise ProtocolError(
                "E_ARG", f"-{axis} {value:g} is outside the PTU's limits [{lim['min_deg']:.2f}, {lim['max_deg']:.2f}] deg"
            )


# ------------------------------------------------------------------ move-ptu


@dataclass
class MovePtuConfig(ModuleConfig):
    """No declared range: the unit reports its own limits when it opens, and those are what help
    shows (``ptu_ranges``) and the check refuses beyond (``check_ptu_angles``); a fixed range
    here would be a second, different answer."""

    module: ClassVar[str] = "move_ptu"
    pan: float = param(float("nan"), "pan angle (default: keep), within the PTU's limits", unit="deg")
    tilt: float = param(float("nan"), "tilt angle (default: keep), within the PTU's limits", unit="deg")


def ptu_ranges(app: App) -> dict[str, tuple[float, float]]:
    """-pan and -tilt ranges as the open PTU reported them (none while it is not open), to the
    hundredth of a degree, as the check's E_ARG states them. From its status, which never waits
    for the serial line: help is answered at once, even while a job moves the PTU."""
    dev = app.devices.devices.get("ptu")
    if dev is None:
        return {}
    try:
        limits = dev.status().get("limits") or {}
    except Exception:  # noqa: BLE001 - status never fails because a device does
        return {}
    return {axis: (round(lim["min_deg"], 2), round(lim["max_deg"], 2))
            for axis, lim in limits.items() if axis in ("pan", "tilt") and lim}


def _axes(cfg: MovePtuConfig) -> tuple[float | None, float | None]:
    return (None if math.isnan(cfg.pan) else cfg.pan, None if math.isnan(cfg.tilt) else cfg.tilt)


def _check_move_ptu(app: App, cfg: MovePtuConfig) -> None:
    # neither axis given is no move: the job answers where the PTU stands, as an axis not given
    # keeps its position
    check_ptu_angles(app, *_axes(cfg))


@command("move-ptu", job=True, klass=HARDWARE, config=MovePtuConfig, check=_check_move_ptu, ranges=ptu_ranges,
         help="move the PTU to -pan, -tilt")
def move_ptu(job: Job, cfg: MovePtuConfig) -> dict[str, Any]:
    app = job.app
    ptu = app.devices.get("ptu")
    pan, tilt = _axes(cfg)
    job.progress(0, 1, f"moving to pan={_deg(pan)} tilt={_deg(tilt)}")
    reached = device_call(job, ptu.move, pan, tilt, True)
    return {"pan": Fixed(reached[0], 3), "tilt": Fixed(reached[1], 3)}


def _deg(value: float | None) -> str:
    return "keep" if value is None else f"{value:.3f}"


# ------------------------------------------------------------------ grab-tof


@dataclass
class GrabTofConfig(ModuleConfig):
    module: ClassVar[str] = "grab_tof"
    output: str = param("", "file stem (default tof_<UTC time>)", stem=True)
    type: str = param("distance", "image type", choices=("amplitude", "distance", "confidence", "z", "xyz"))
    integrate: int = param(1, "frames to integrate", min=1, max=100)
    confidence: float = param(0.0, "discard pixels below this confidence", min=0.0, max=1.0)


@command("grab-tof", job=True, klass=HARDWARE, config=GrabTofConfig,
         help="acquire a ToF image (-type) integrating -integrate frames above -confidence, store it as -output")
def grab_tof(job: Job, cfg: GrabTofConfig) -> dict[str, Any]:
    app = job.app
    tof = app.devices.get("tof")
    stem = cfg.output or default_stem("tof")
    job.progress(0, 2, f"grabbing {cfg.integrate} {cfg.type} frame(s)")
    image = device_call(job, tof.grab, cfg.type, cfg.integrate, cfg.confidence)
    job.check()
    job.progress(1, 2, "writing")
    path = app.data_path("tof", f"{stem}_{cfg.type}.tif")
    write_tiff(path, np.asarray(image, dtype=np.float32))
    if cfg.type == "xyz":
        z = np.where(image[..., 2] > 0, image[..., 2], np.nan)
        view = preview(z, cv2.COLORMAP_JET)
    else:
        view = preview(image, cv2.COLORMAP_JET if cfg.type in ("distance", "z") else None)
    write_png(path.with_suffix(".png"), view)
    units = {"distance": "m", "z": "m", "xyz": "m (x, y, z camera frame; -1 undefined)",
             "amplitude": "counts", "confidence": "0..1"}[cfg.type]
    write_sidecar(path, "grab-tof", cfg.as_dict(), units=units, nan="undefined pixel",
                  device=_device_info(tof), **acquisition_context(app))
    valid = np.isfinite(image) if cfg.type != "xyz" else image[..., 2] > 0
    return {"file": app.rel(path), "valid": Fixed(float(valid.mean()), 3)}


def _device_info(dev: Any) -> dict[str, Any]:
    """The device's own account of its settings (modulation, integration, corrections...), read
    right after the grab: the job holds the devices and config -set cannot change them meanwhile,
    so it is what the image was measured with, whatever the configuration says by now."""
    try:
        st = dev.status()
    except Exception:  # noqa: BLE001
        return {}
    return {k: v for k, v in st.items() if _scalar(v) or (isinstance(v, list) and all(map(_scalar, v)))}


def _scalar(value: Any) -> bool:
    return isinstance(value, str | int | float | bool)


# ------------------------------------------------------------------ grab-stereo


@dataclass
class GrabStereoConfig(ModuleConfig):
    module: ClassVar[str] = "grab_stereo"
    output: str = param("", "file stem (default stereo_<UTC time>)", stem=True)
    resolution: str = param("high", "resolution mode", choices=tuple(RESOLUTIONS))
    format: str = param("mono8", "pixel format", choices=PIXEL_FORMATS)


@command("grab-stereo", job=True, klass=HARDWARE, config=GrabStereoConfig,
         help="grab a triggered stereo pair and store it as -output")
def grab_stereo(job: Job, cfg: GrabStereoConfig) -> dict[str, Any]:
    app = job.app
    cams = app.devices.get("stereo")
    stem = cfg.output or default_stem("stereo")
    job.progress(0, 2, f"grabbing a {cfg.resolution} {cfg.format} pair")
    left, right = device_call(job, cams.grab_stereo, cfg.resolution, cfg.format)
    job.check()
    job.progress(1, 2, "writing")
    out: dict[str, Any] = {}
    with product_set(app.data_path("stereo")):  # a pair is never one new image beside an old one
        for side, image in (("left", left), ("right", right)):
            path: Path = app.data_path("stereo", f"{stem}_{side}.tif")
            # each write of a 2-megapixel image takes a good share of a second on a busy machine: a
            # break between them ends the job and keeps none of them (the set is all or nothing)
            job.check()
            write_tiff(path, image)
            job.check()
            write_png(path.with_suffix(".png"), image)
            write_sidecar(path, "grab-stereo", cfg.as_dict(), side=side, device=_device_info(cams),
                          **acquisition_context(app))
            out[side] = app.rel(path)
    return out
