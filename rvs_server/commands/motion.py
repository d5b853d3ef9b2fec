"""Rover motion commands: orient (visual odometry, seed 000 sect. 3.1.5 and appendix C) and
ground-align (the sensor head's attitude from the ground plane, seed 003 sect. 4.3.1).

Both are thin: they point the PTU, grab through the drivers and hand arrays to
``prox_workflows.algorithms.odometry`` / ``ground_plane``; what they keep between requests (the
orient reference) is the app's ``odometry`` field, and what they correct (the mounts) in the ``head`` config
module that every transform reads.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from drivers.stereo.modes import RESOLUTIONS
from prox_workflows.algorithms import ground_plane as gp
from prox_workflows.algorithms import odometry as od
from prox_workflows.algorithms.stereo import disparity, load_calibration
from prox_workflows.algorithms.transforms import HeadCalibration
from prox_workflows.products import write_yaml_atomic

from ..app import OrientReference
from ..config import ModuleConfig, param
from ..jobs import Job, device_call
from ..protocol import Fixed, ProtocolError
from ..table import HARDWARE, command
from .hardware import check_ptu_angles

if TYPE_CHECKING:
    from ..app import App

DEFAULT_TILT = {"stereo": -20.0, "tof": -30.0}


# ------------------------------------------------------------------ acquisition


def _point_ptu(job: Job, app: App, pan: float, tilt: float) -> tuple[float, float]:
    ptu = app.devices.get("ptu")
    reached = device_call(job, ptu.move, pan, tilt, True)
    return float(reached[0]), float(reached[1])


def _grab_frame(job: Job, app: App, sensor: str, pan: float, tilt: float, head: HeadCalibration, *,
                resolution: str, integrate: int, confidence: float) -> od.DepthFrame:
    """One acquisition as the odometry and the ground fit need it: an image, the 3D point of
    each of its pixels (sensor frame) and the sensor's pose on the rover."""
    if sensor == "stereo":
        cams = app.devices.get("stereo")
        left, right = device_call(job, cams.grab_stereo, resolution, "mono8")
        job.check()
        cal = load_calibration(cams.calibration(resolution))
        points = disparity(left, right, cal).points()
        return od.DepthFrame(left, points, cal.K1, cal.D1, head.T_rover_from_sensor("left", pan, tilt))
    tof = app.devices.get("tof")
    xyz, amplitude = device_call(job, tof.grab_xyz, integrate, confidence)
    points = np.asarray(xyz, dtype=np.float32).copy()
    points[~(points[..., 2] > 0)] = np.nan  # the camera's -1 / 0 codes
    K, dist = tof.intrinsics()
    return od.DepthFrame(amplitude, points, K, dist, head.T_rover_from_sensor("tof", pan, tilt))


def _head(app: App) -> HeadCalibration:
    return HeadCalibration.from_dict(app.config.get("head").as_dict())


# ------------------------------------------------------------------ orient


@dataclass
class OrientConfig(ModuleConfig):
    module: ClassVar[str] = "orient"
    sensor: str = param("stereo", "sensor whose image and depth are tracked", choices=("stereo", "tof"))
    pan: float = param(0.0, "PTU pan while acquiring: 0 looks along the rover's forward direction (180: "
                       "reversing)", unit="deg", min=-360.0, max=360.0)
    tilt: float = param(float("nan"), "PTU tilt while acquiring (default -20 stereo, -30 tof)", unit="deg",
                        min=-90.0, max=90.0)
    min_matches: int = param(20, "fewer points tracked into the new image than this is E_DATA", min=3, max=100000)
    min_inliers: int = param(12, "fewer tracked points agreeing on one motion than this is E_DATA", min=3,
                             max=100000)
    reset: bool = param(False, "take a new reference here (zero motion, pose unchanged)")
    detector: str = param("shi-tomasi", "interest operator", choices=od.DETECTORS)
    resolution: str = param("low", "stereo resolution mode", choices=tuple(RESOLUTIONS))
    integrate: int = param(4, "ToF frames averaged per acquisition", min=1, max=100)
    confidence: float = param(0.3, "discard ToF pixels below this confidence", min=0.0, max=1.0)
    max_points: int = param(1200, "interest points per image", min=10, max=20000, option=False)
    max_range: float = param(15.0, "ignore points farther than this", unit="m", min=0.5, max=200.0, option=False)
    window: int = param(11, "tracking window side (odd)", unit="px", min=3, max=101, option=False)
    reprojection: float = param(1.5, "RANSAC inlier threshold", unit="px", min=0.1, max=20.0, option=False)


def _orient_params(cfg: OrientConfig) -> od.OdometryParams:
    window = cfg.window if cfg.window % 2 else cfg.window + 1
    return od.OdometryParams(detector=cfg.detector, max_points=cfg.max_points, window=window,
                             max_range=cfg.max_range, reprojection=cfg.reprojection,
                             min_matches=cfg.min_matches, min_inliers=cfg.min_inliers)


def _pose_fields(x: float, y: float, heading: float) -> dict[str, Any]:
    return {"x": Fixed(x, 4), "y": Fixed(y, 4), "heading": Fixed(heading, 3)}


def _orient_tilt(cfg: Any) -> float:
    return DEFAULT_TILT[cfg.sensor] if math.isnan(cfg.tilt) else cfg.tilt


@command("orient", job=True, klass=HARDWARE, config=OrientConfig,
         check=lambda app, cfg: check_ptu_angles(app, cfg.pan, _orient_tilt(cfg)),
         help="acquire in the moving direction and estimate the rover's motion since the last orient "
              "(visual odometry); the first one (or -reset) sets the reference")
def orient(job: Job, cfg: OrientConfig) -> dict[str, Any]:
    app = job.app
    tilt = _orient_tilt(cfg)
    ref = app.odometry.get()
    if ref is not None and ref.sensor != cfg.sensor and not cfg.reset:
        raise ProtocolError("E_ARG", f"the orient reference was taken with -sensor {ref.sensor}; use it again, "
                                     f"or send orient -reset -sensor {cfg.sensor} to start a new reference")
    job.progress(0, 3, f"pointing the {cfg.sensor} sensor at pan={cfg.pan:.1f} tilt={tilt:.1f}")
    pan, tilt = _point_ptu(job, app, cfg.pan, tilt)
    job.check()
    job.progress(1, 3, f"acquiring ({cfg.sensor})")
    head = _head(app)
    frame = _grab_frame(job, app, cfg.sensor, pan, tilt, head, resolution=cfg.resolution,
                        integrate=cfg.integrate, confidence=cfg.confidence)
    body = app.config.get("head")
    frame.mask = od.rover_body_mask(frame.points, frame.T_rover_sensor, body.rover_length, body.rover_width,
                                    body.rover_margin)
    job.check()
    pose = app.pose
    if ref is None or cfg.reset:
        app.odometry.set(OrientReference(cfg.sensor, frame, (pose.x, pose.y, pose.heading), time.time()))
        points = len(od.detect(frame, _orient_params(cfg)))
        return {"reference": True, "dx": Fixed(0.0, 4), "dy": Fixed(0.0, 4), "dyaw": Fixed(0.0, 3),
                **_pose_fields(pose.x, pose.y, pose.heading), "matches": 0, "inliers": 0, "points": points,
                "sensor": cfg.sensor}
    job.progress(2, 3, "tracking interest points and estimating the motion")
    try:
        motion = od.estimate_motion(ref.frame, frame, _orient_params(cfg))
    except od.OdometryError as exc:
        raise ProtocolError(
            "E_DATA", f"{exc} (points={exc.points} matches={exc.matches} inliers={exc.inliers}); the pose and the "
                      "reference are unchanged: orient again nearer the last position, or orient -reset here"
        ) from None
    job.check()
    x, y, heading = od.compose_pose(*ref.pose, motion)
    app.set_pose(x, y, heading, source="orient")
    app.odometry.set(OrientReference(cfg.sensor, frame, (x, y, heading), time.time()))
    return {"reference": False, "dx": Fixed(motion.dx, 4), "dy": Fixed(motion.dy, 4),
            "dyaw": Fixed(motion.dyaw, 3), **_pose_fields(x, y, heading),
            "matches": motion.matches, "inliers": motion.inliers, "points": motion.points,
            "dz": Fixed(motion.dz, 4), "droll": Fixed(motion.droll, 3), "dpitch": Fixed(motion.dpitch, 3),
            "rms": Fixed(motion.rms_px, 3), "coverage": Fixed(motion.spread, 3), "sensor": cfg.sensor}


# ------------------------------------------------------------------ ground-align


@dataclass
class GroundAlignConfig(ModuleConfig):
    module: ClassVar[str] = "ground_align"
    sensor: str = param("tof", "sensor whose points are fitted", choices=("tof", "stereo"))
    frames: int = param(5, "frames averaged", min=1, max=100)
    pan: float = param(0.0, "PTU pan while measuring", unit="deg", min=-360.0, max=360.0)
    tilt: float = param(-40.0, "PTU tilt while measuring (looking at the ground near the rover)", unit="deg",
                        min=-90.0, max=90.0)
    threshold: float = param(0.02, "RANSAC inlier distance to the plane", unit="m", min=0.001, max=1.0)
    max_range: float = param(4.0, "ignore points farther than this from the sensor", unit="m", min=0.3, max=50.0)
    integrate: int = param(4, "ToF frames integrated per frame", min=1, max=100)
    confidence: float = param(0.3, "discard ToF pixels below this confidence", min=0.0, max=1.0)
    resolution: str = param("low", "stereo resolution mode", choices=tuple(RESOLUTIONS))
    apply: bool = param(True, "store the corrected mount in the head calibration (false: measure only)")
    height: bool = param(False, "also move the PTU base so the measured ground is at the rover frame's z = 0")
    max_correction: float = param(10.0, "a plane further than this off the believed level is not the ground",
                                  unit="deg", min=0.1, max=45.0)
    min_share: float = param(0.3, "the plane must hold at least this share of the points", min=0.0, max=1.0,
                             option=False)


def _store_mount(app: App, sensor: str, mount: dict[str, list[float]]) -> None:
    """Through ConfigStore.set, as ``config -module head -set mounts.tof.rpy=...`` would."""
    for key in ("xyz", "rpy"):
        app.config.set("head", f"mounts.{sensor}.{key}", ",".join(repr(float(v)) for v in mount[key]))


@command("ground-align", job=True, klass=HARDWARE, config=GroundAlignConfig,
         check=lambda app, cfg: check_ptu_angles(app, cfg.pan, cfg.tilt),
         help="with the rover still on level ground, fit the ground plane over -frames frames and correct the "
              "sensor mount's tilt and roll in the head calibration")
def ground_align(job: Job, cfg: GroundAlignConfig) -> dict[str, Any]:
    app = job.app
    total = cfg.frames + 2
    job.progress(0, total, f"pointing the {cfg.sensor} sensor at pan={cfg.pan:.1f} tilt={cfg.tilt:.1f}")
    pan, tilt = _point_ptu(job, app, cfg.pan, cfg.tilt)
    head = _head(app)
    mount = "left" if cfg.sensor == "stereo" else "tof"
    if mount not in head.mounts:
        raise ProtocolError("E_DATA", f"the head calibration has no mount for '{mount}'")
    planes: list[gp.Plane] = []
    for i in range(cfg.frames):
        job.check()
        job.progress(1 + i, total, f"frame {i + 1} of {cfg.frames}: fitting the ground plane")
        frame = _grab_frame(job, app, cfg.sensor, pan, tilt, head, resolution=cfg.resolution,
                            integrate=cfg.integrate, confidence=cfg.confidence)
        pts = frame.points.reshape(-1, 3)
        pts = pts[np.isfinite(pts).all(axis=1)]
        pts = pts[np.linalg.norm(pts, axis=1) <= cfg.max_range]
        if len(pts) < 100:
            raise ProtocolError("E_DATA", f"frame {i + 1} has only {len(pts)} points within {cfg.max_range:g} m; "
                                          "point the sensor at the ground near the rover (-tilt)")
        plane = gp.fit_plane(pts, cfg.threshold, rng=i)
        if plane.share < cfg.min_share:
            raise ProtocolError("E_DATA", f"the largest plane in frame {i + 1} holds only {plane.share:.0%} of the "
                                          "points: no level ground in view (-tilt, or move the rover)")
        planes.append(plane)
    job.check()
    job.progress(cfg.frames + 1, total, "solving the mount's tilt and roll")
    mean, spread = gp.average_planes(planes)
    followers = ("right",) if cfg.sensor == "stereo" and "right" in head.mounts else ()
    result = gp.align_mount(head, mount, pan, tilt, mean, followers, stats=(mean.inliers, spread))
    if result.misalignment > cfg.max_correction:
        raise ProtocolError("E_DATA", f"the largest plane in view is {result.misalignment:.1f} deg off the level the "
                                      f"head calibration expects (over -max-correction {cfg.max_correction:g}): "
                                      "not the ground (a wall, a slope?); nothing was stored")
    base_z = None
    if cfg.apply:
        for name, values in result.mounts.items():
            _store_mount(app, name, values)
        if cfg.height:
            base = list(app.config.get("head").ptu_base)
            base_z = base[2] - result.ground_z
            base[2] = base_z
            app.config.set("head", "ptu_base", ",".join(repr(float(v)) for v in base))
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%S_%f")[:-3]
    record = app.data_path("calibration", f"ground_align_{stamp}.yaml")
    write_yaml_atomic(record, {
        "made_by": "ground-align", "time": datetime.now(UTC).isoformat(), "parameters": cfg.as_dict(),
        "ptu": {"pan": pan, "tilt": tilt}, "applied": cfg.apply, "ptu_base_z": base_z,
        "planes": [{"normal": p.normal.tolist(), "d": p.d, "inliers": p.inliers, "rms": p.rms} for p in planes],
        **{k: v for k, v in result.as_dict().items()},
    })
    job.progress(total, total, "done")
    out: dict[str, Any] = {
        "tilt": Fixed(result.tilt, 3), "roll": Fixed(result.roll, 3), "height": Fixed(result.height, 4),
        "residual": Fixed(result.residual, 4), "points": result.points, "sensor": cfg.sensor,
        "d_tilt": Fixed(-result.d_pitch, 3), "d_roll": Fixed(result.d_roll, 3),
        "mount_rpy": [Fixed(v, 3) for v in result.rpy_after], "misalignment": Fixed(result.misalignment, 3),
        "spread": Fixed(result.spread, 3), "ground_z": Fixed(result.ground_z, 4), "applied": cfg.apply,
        "file": app.rel(record),
    }
    return out
