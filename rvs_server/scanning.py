"""The DEM scan: views from the ToF, the stereo pair or both, taken where the planned scan
points the PTU, through the dem workflow into the current maps. The dem commands run it, and so
does navigate when its scan strategy looks before a leg.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from drivers.tof import constants as tof_k
from prox_workflows.algorithms.acquire import Frame, acquire_coord_images
from prox_workflows.algorithms.noise import model_sigmas, stereo_point_variance, tof_point_variance
from prox_workflows.algorithms.ptu_positions import ORDERS, move_time
from prox_workflows.algorithms.stereo import disparity as stereo_disparity
from prox_workflows.algorithms.stereo import sigma_d_for
from prox_workflows.algorithms.transforms import HeadCalibration
from prox_workflows.engine import Cancelled, run_workflow
from prox_workflows.grid import Layers
from prox_workflows.parameters import DemParams

from .config import param
from .jobs import Interrupted, Job, default_stem, device_call
from .maps import current_pose
from .protocol import Fixed, ProtocolError

if TYPE_CHECKING:
    from .app import App


@dataclass
class ScanOptions:
    """How a DEM command's scan is taken: the server's acquisition, not the DEM chain's
    parameters (a reprocessing of the recorded views neither knows nor needs them)."""

    on_the_move: bool = param(False, "grab each view's ToF frames while the PTU arrives (half of them before "
                              "it stops) instead of at rest; refused where the head would turn a pixel or more "
                              "meanwhile (PTU speed x that time vs the ToF's pixel)")
    order: str = param("fastest", "view order: the serpentine the PTU travels soonest (rows or columns, from "
                       "the nearest corner), or rows from the lowest pan and tilt", choices=ORDERS, option=False)
    overlap_processing: bool = param(True, "process each view while the PTU moves to the next", option=False)


SCAN_OPTIONS = tuple(ScanOptions.__dataclass_fields__)


def check_update(app: App) -> None:
    """An update needs a current DEM to merge into."""
    if not app.maps.updatable():
        raise ProtocolError("E_DATA", "there is no current DEM to update; run dem-full-tof or dem-full first")


# What the server puts in the dem script's workspace (checked against the script's inputs: at
# start, so a broken script stops the server before it serves, see validate_scripts).
DEM_SCRIPT = "dem"
DEM_INPUTS = ("fov", "ptu_limits", "ptu_motion", "ptu_start", "scan_order", "pending_views", "rover_mask", "base",
              "hazard", "out_dir", "views_dir", "made_by", "parameters")


def rover_mask_polygon(app: App, pose: tuple[float, ...]) -> np.ndarray:
    """The rover body's footprint (with margin) in the global frame, to mask it out of scans."""
    head = app.config.get("head")
    half_l = head.rover_length / 2 + head.rover_margin
    half_w = head.rover_width / 2 + head.rover_margin
    corners = np.array([[half_l, half_w], [-half_l, half_w], [-half_l, -half_w], [half_l, -half_w]])
    c, s = math.cos(math.radians(pose[2])), math.sin(math.radians(pose[2]))
    R = np.array([[c, -s], [s, c]])
    return corners @ R.T + np.array(pose[:2])


def tof_sigmas(cfg: Any) -> dict[str, float]:
    """The ToF noise model's coefficients from the command's config (declared in DemParams).

    Calibrated on views integrated over the default number of frames; the phase-noise term
    scales as 1 / sqrt(frames), so other -integrate values keep it right."""
    sigmas = model_sigmas(cfg, "tof")
    sigmas["shot"] *= math.sqrt(DemParams().integrate / max(int(cfg.integrate), 1))
    return sigmas


def stereo_sigmas(cfg: Any) -> dict[str, float]:
    """The stereo noise model's coefficients from the command's config; the disparity terms
    were calibrated matching at full scale and grow as 1 / sqrt(scale) (:func:`sigma_d_for`)."""
    sigmas = model_sigmas(cfg, "stereo")
    grow = sigma_d_for(cfg.stereo_scale) / sigma_d_for(1.0)
    sigmas["disparity"] *= grow
    sigmas["texture"] *= grow
    return sigmas


def _stereo_frame(left: np.ndarray, right: np.ndarray, calib: dict[str, Any], cfg: Any) -> Frame:
    """The points a stereo pair triangulates per left pixel, with undistorted ortho images."""
    disp = stereo_disparity(left, right, calib, {"scale": cfg.stereo_scale})
    pts = disp.points()
    K1, D1 = np.asarray(calib["K1"], float), np.asarray(calib["D1"], float)
    h, w = left.shape[:2]
    mx, my = cv2.initUndistortRectifyMap(K1, D1, None, K1, (w, h), cv2.CV_32FC1)
    grey = left if left.ndim == 2 else cv2.cvtColor(left, cv2.COLOR_RGB2GRAY)
    depth = np.where(np.isfinite(pts[..., 2]), pts[..., 2], 0).astype(np.float32)
    return Frame(
        "left", pts, grey.astype(np.float32), K1,
        variance=partial(stereo_point_variance, baseline=disp.rect.baseline, focal=disp.rect.focal,
                         **stereo_sigmas(cfg)),
        max_range=cfg.max_range,
        ortho_intensity=cv2.remap(grey, mx, my, cv2.INTER_LINEAR).astype(np.float32),
        ortho_depth=cv2.remap(depth, mx, my, cv2.INTER_NEAREST),
    )


def view_seconds(tof: Any, cfg: Any) -> tuple[float, int]:
    """The ToF's time at one view (its frames: -integrate plus the wrap check's, each four
    phase samples of the integration time and a read-out) and the number of frames."""
    frames = int(cfg.integrate) + (1 if cfg.wrap_check else 0)
    return frames * tof_k.frame_seconds(float(tof.status()["integration_ms"])), frames


def lead_in(tof: Any, cfg: Any) -> float:
    """Seconds of a view's frames exposed before the PTU stops, with -on-the-move: the first
    half of them (the rest at rest), so the head stands still for the view's middle frame."""
    return view_seconds(tof, cfg)[0] / 2


def check_on_the_move(motion: dict[str, dict[str, float]], fov: tuple[float, float], lead: float) -> None:
    """E_ARG where the head would turn a pixel or more while the frames expose on the move."""
    pixel = (fov[0] / tof_k.WIDTH, fov[1] / tof_k.HEIGHT)
    for k, axis in enumerate(("pan", "tilt")):
        speed = motion[axis]["speed"]
        blur = speed * lead / pixel[k]
        if blur >= 1.0:
            most = 0.999 * pixel[k] / lead
            raise ProtocolError(
                "E_ARG", f"-on-the-move would blur the ToF views by {blur:.1f} px: the {axis} axis turns "
                f"{speed:.1f} deg/s for the {lead * 1000:.0f} ms of frames before it stops (pixel "
                f"{pixel[k]:.3f} deg); lower drivers.ptu.speed to at most {most:.2f} deg/s, or take fewer "
                "frames a view (-integrate), or grab at rest (leave -on-the-move out)")


def run_dem(job: Job, cfg: Any, *, update: bool, sensor: str = "tof",
            progress: Any = None, out_dir: str = "dem") -> dict[str, Any]:
    """One DEM job: views from ``sensor`` (tof, stereo or fused) through the dem workflow."""
    app = job.app
    base, pending = app.maps.for_update() if update else (None, [])
    if update:
        check_update(app)
    ptu = app.devices.get("ptu")
    use_tof, use_stereo = sensor in ("tof", "fused"), sensor in ("stereo", "fused")
    tof = app.devices.get("tof") if use_tof else None
    cams = app.devices.get("stereo") if use_stereo else None
    head = HeadCalibration.from_dict(app.config.get("head").as_dict())
    pose = current_pose(app)
    lim = ptu.limits()
    limits = (lim["pan"]["min_deg"], lim["pan"]["max_deg"], lim["tilt"]["min_deg"], lim["tilt"]["max_deg"])
    if tof is not None:  # the narrower field of view sets the pointings
        K, _ = tof.intrinsics()
        size = (tof_k.WIDTH, tof_k.HEIGHT)
    else:
        calib = cams.calibration(cfg.resolution)
        K, size = np.asarray(calib["K1"], float), tuple(calib["image_size"])
    fov = (math.degrees(2 * math.atan(size[0] / 2 / K[0, 0])), math.degrees(2 * math.atan(size[1] / 2 / K[1, 1])))
    calib = cams.calibration(cfg.resolution) if cams is not None else None
    name = cfg.name or default_stem("dem")
    views_dir = app.data_dir / out_dir / f"{name}_views"  # made by its first file: a job refused earlier leaves none
    motion = ptu.motion()
    start = ptu.position()
    lead = 0.0
    if cfg.on_the_move:
        if tof is None:
            raise ProtocolError("E_ARG", "-on-the-move is for the ToF's frames; dem-full -sensor stereo grabs "
                                "its pairs at rest (leave -on-the-move out, or use -sensor fused)")
        lead = lead_in(tof, cfg)
        check_on_the_move(motion, fov, lead)
    clock = app.world.clock if app.world is not None else None
    ahead: dict[str, Any] = {}  # the move under way while the last view is processed: target, arrival

    def move_ahead(pan: float, tilt: float) -> None:
        """Send the PTU on to the next view and return at once: it travels while this view is
        processed (the next grab waits for it, or with -on-the-move until just before it stops)."""
        at = ahead.pop("at")
        device_call(job, ptu.move, pan, tilt, False)
        now = clock.now() if clock is not None else 0.0
        ahead.update(to=(pan, tilt), arrival=now + move_time(at, (pan, tilt), motion))

    def arrive(pan: float, tilt: float) -> tuple[float, float] | None:
        """Wait for the PTU at (pan, tilt); with -on-the-move only until the frames' lead-in,
        returning None (the position is read once the frames are taken)."""
        if ahead.pop("to", None) != (pan, tilt):
            return device_call(job, ptu.move, pan, tilt, True)
        arrival = ahead.pop("arrival")
        if lead > 0 and clock is not None:
            clock.sleep(arrival - lead - clock.now(), cancel=lambda: job.cancelled, what="ptu moves")
            job.check()
            return None
        return device_call(job, ptu.wait)

    def grab(pan: float, tilt: float) -> tuple[list[Frame], float, float]:
        reached = arrive(pan, tilt)
        frames: list[Frame] = []
        if tof is not None:
            xyz, amplitude = device_call(job, tof.grab_xyz, cfg.integrate, cfg.confidence,
                                        wrap_check=cfg.wrap_check)
            frames.append(Frame("tof", xyz, amplitude, K,
                                variance=partial(tof_point_variance, **tof_sigmas(cfg)),
                                max_range=min(cfg.max_range, tof_k.USABLE_RANGE),
                                min_reflectivity=cfg.min_reflectivity))
        if reached is None:  # on the move: where it stopped, the middle of the ToF's frames
            reached = device_call(job, ptu.wait)
        ahead["at"] = reached
        if cams is not None:
            left, right = device_call(job, cams.grab_stereo, cfg.resolution, "mono8")
            job.check()
            frames.append(_stereo_frame(left, right, calib, cfg))
        return frames, reached[0], reached[1]

    acquired: list[Any] = []
    rover_mask = rover_mask_polygon(app, pose)

    def acquire(positions: list[tuple[float, float]], progress: Any = None, cancelled: Any = None) -> list[Any]:
        try:
            return acquire_coord_images(positions, grab, head, pose, views_dir, name, progress, cancelled,
                                        on_view=acquired.append,
                                        scan={"rover_mask": rover_mask, "order": cfg.order, "ptu_start": list(start),
                                              "ptu_motion": motion, "on_the_move": cfg.on_the_move},
                                        move_ahead=move_ahead if cfg.overlap_processing else None)
        finally:
            if "to" in ahead and job.cancelled:  # stopped between views: the move sent ahead stops too
                with contextlib.suppress(Exception):
                    ptu.halt()

    # the parameters are the command's config values, as they are, but for how the scan is taken;
    # the rest is what only the server knows (its devices, the rover, the current DEM)
    params = {**{k: v for k, v in cfg.as_dict().items() if k not in SCAN_OPTIONS}, "name": name}
    workspace = {
        "fov": list(fov), "ptu_limits": list(limits), "ptu_motion": motion, "ptu_start": list(start),
        "scan_order": cfg.order, "pending_views": pending, "rover_mask": rover_mask,
        "base": base, "hazard": app.config.get("dem2hazard").as_dict(), "out_dir": app.data_dir / out_dir,
        "views_dir": views_dir.name, "made_by": job.command, "parameters": job.params,
    }
    report = progress or job.progress
    try:
        ws, _ = run_workflow(DEM_SCRIPT, params, workspace, steps={"acquire": acquire}, progress=report,
                             cancelled=lambda: job.cancelled, param_cls=type(cfg))
        job.check()
    except BaseException as exc:
        app.maps.keep_views(pending + acquired)  # the views acquired before a fault or a break: for the next update
        if isinstance(exc, Cancelled | Interrupted):
            raise Interrupted(f"{job.command} job {job.id} was interrupted; {len(acquired)} views kept "
                              "for dem-update") from None
        raise
    dem: Layers = ws["dem"]
    files = ws["files"]
    rel = {layer: app.rel(path) for layer, path in files.items()}
    app.maps.replace(dem, name, rel)
    defined = np.isfinite(dem["dem"])
    out: dict[str, Any] = {k: rel[k] for k in ("dem", "ortho", "hazard", "slope", "step", "roughness") if k in rel}
    out.update(cells=int(defined.sum()), coverage=Fixed(float(defined.mean()), 3), views=len(ws["views"]))
    for key in ("traversability", "mesh"):
        if key in rel:
            out[key] = rel[key]
    return out
