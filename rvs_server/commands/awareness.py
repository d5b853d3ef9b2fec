"""Awareness commands: hazard-start / hazard-stop (dynamic hazard detection, seed 000 sect. 6.2)
and track3d-detect / track3d-start / track3d-stop (target tracking, appendix C).

hazard-start and track3d-start run background monitors; the rules those follow (they yield to
jobs, one holder of the PTU, break pauses them) are the monitor framework's, in
``rvs_server/monitors.py``. This module holds the commands and the two concrete monitors.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import structlog

from drivers.stereo.modes import RESOLUTIONS
from drivers.tof import constants as tof_k
from prox_workflows.algorithms import hazard_monitor as hm
from prox_workflows.algorithms import tracking as tr
from prox_workflows.algorithms.transforms import HeadCalibration, T_global_from_rover, invert
from prox_workflows.steps.scan import get_ptu_positions

from ..app import Context
from ..config import ModuleConfig, param
from ..jobs import Job, device_call
from ..maps import current_pose
from ..monitors import Monitor
from ..protocol import Fixed, ProtocolError
from ..table import HARDWARE, command

if TYPE_CHECKING:
    from ..app import App

log = structlog.get_logger("rvs.awareness")

TOF_SHAPE = (tof_k.HEIGHT, tof_k.WIDTH)


def _fov(K: np.ndarray, shape: tuple[int, int]) -> tuple[float, float]:
    h, w = shape
    return (math.degrees(2 * math.atan(w / 2 / K[0, 0])), math.degrees(2 * math.atan(h / 2 / K[1, 1])))


def _limits(ptu: Any) -> tuple[float, float, float, float]:
    lim = ptu.limits()
    return (lim["pan"]["min_deg"], lim["pan"]["max_deg"], lim["tilt"]["min_deg"], lim["tilt"]["max_deg"])


# ------------------------------------------------------------------ hazard-start / hazard-stop


@dataclass
class HazardStartConfig(ModuleConfig):
    module: ClassVar[str] = "hazard_start"
    period: float = param(0.3, "time from one cycle's start to the next (shorter cycles wait)", unit="s",
                          min=0.0, max=60.0)
    tilt: float = param(-45.0, "PTU tilt while monitoring (down is negative)", unit="deg", min=-90.0, max=30.0)
    heading: float = param(0.0, "direction of motion in the rover frame (CCW from forward); the PTU pans to it",
                           unit="deg", min=-180.0, max=180.0)
    width: float = param(0.0, "corridor width (0: the rover's width plus both margins, config head)",
                         unit="m", min=0.0, max=10.0)
    lookahead: float = param(2.0, "corridor length past the rover's front", unit="m", min=0.2, max=10.0)
    stop_distance: float = param(0.5, "level stop when a hazard is this close to the rover's front", unit="m",
                                 min=0.0, max=10.0, at_most="warn_distance")
    warn_distance: float = param(1.0, "level warning when a hazard is this close", unit="m", min=0.0, max=10.0)
    cell: float = param(0.05, "coarse DEM cell", unit="m", min=0.01, max=0.5, option=False)
    subsample: int = param(2, "use every n-th ToF pixel in both directions", min=1, max=8, option=False)
    integrate: int = param(1, "ToF frames per cycle", min=1, max=20, option=False)
    max_range: float = param(tof_k.USABLE_RANGE, "ignore ToF points farther than this", unit="m", min=0.5,
                             max=30.0, option=False)
    min_reflectivity: float = param(0.1, "drop ToF returns weaker than this share of the frame's median "
                                    "amplitude x range^2 (phase-wrapped far surfaces)", min=0.0, max=1.0,
                                    option=False)
    hysteresis: float = param(0.1, "a level is left only this far past its threshold", unit="m", min=0.0,
                              max=2.0, option=False)


class HazardMonitor(Monitor):
    """The per-cycle loop of sect. 6.2: ToF forward, coarse DEM, corridor, level events."""

    name = "hazard"

    def __init__(self, app: App, cfg: HazardStartConfig, log_context: dict[str, Any] | None = None) -> None:
        super().__init__(app, cfg.period, log_context)
        self.cfg = cfg
        head = app.config.get("head")
        width = cfg.width or head.rover_width + 2 * head.rover_margin
        self.params = hm.MonitorParams(
            width=width, lookahead=cfg.lookahead, heading=cfg.heading, stop_distance=cfg.stop_distance,
            warn_distance=cfg.warn_distance, cell=cfg.cell, rover_length=head.rover_length,
            rover_width=head.rover_width, hysteresis=cfg.hysteresis,
            hazard=app.config.get("dem2hazard").as_dict())
        self.memory = hm.HazardMemory(cfg.cell)
        self.levels = hm.LevelTracker(self.params)
        self.level = "none"  # last level sent
        self.last: dict[str, Any] = {}
        self.pointing = (cfg.heading, cfg.tilt)
        self._pose_seen: tuple[int, Any] | None = None
        self._pose_v: tuple[float, float] | None = None  # (speed, monotonic time it was measured)

    def cycle(self) -> None:
        cfg, app = self.cfg, self.app
        pan, tilt = self.point(cfg.heading, cfg.tilt)
        tof = app.devices.get("tof")
        t0 = time.monotonic()
        xyz, amplitude = self.call(tof.grab_xyz, cfg.integrate, 0.0)
        t_grab = t0  # the frame is exposed at the start of the call, then read out
        T = self.head().T_rover_from_sensor("tof", pan, tilt)
        points = hm.rover_points(xyz, T, cfg.subsample, cfg.max_range, amplitude, cfg.min_reflectivity)
        check = hm.check_corridor(points, self.params)
        pose = app.pose
        planar = (pose.x, pose.y, pose.heading)
        self.memory.update(check, planar)
        nearest = self.memory.nearest(planar, self.params)
        speed = self.pose_speed(pose, app.pose_version)
        # The next verdict comes one cycle interval after this one; the rover closes in on the
        # hazard from this exposure until then. The interval is the longest of the last few, so
        # a loaded machine stops the rover earlier rather than later.
        lead = (time.monotonic() - t_grab) + max(self.period, time.monotonic() - t0, *self.intervals())
        level, expected = self.levels.update(None if nearest is None else nearest[0], t_grab, lead, speed)
        self.last = {"distance": None if nearest is None else nearest[0],
                     "bearing": None if nearest is None else nearest[1], "observed": check.observed,
                     "blind": check.blind, "seen": check.distance is not None}
        if level != self.level:
            self.level = level
            fields: dict[str, Any] = {"kind": "hazard", "level": level}
            if nearest is not None and level != "clear":
                fields.update(distance=Fixed(nearest[0], 2), bearing=Fixed(nearest[1], 1),
                              x=Fixed(nearest[2], 2), y=Fixed(nearest[3], 2),
                              seen="true" if check.distance is not None else "remembered")
            fields["cycle"] = self.cycles + 1
            self.emit(fields)
            log.info("hazard_level", level=level, distance=self.last["distance"], expected=expected,
                     speed=round(self.levels.speed, 3), speed_from="pose" if speed is not None else "readings")

    def pose_speed(self, pose: Any, version: int) -> float | None:
        """The rover's speed along the corridor from the poses the GNC reported since the last
        cycle; None when it has reported none for a second (then the readings tell)."""
        now = time.monotonic()
        seen = self._pose_seen
        self._pose_seen = (version, pose)
        if seen is not None and version != seen[0] and pose.time > seen[1].time:
            direction = math.radians(pose.heading + self.cfg.heading)
            along = (pose.x - seen[1].x) * math.cos(direction) + (pose.y - seen[1].y) * math.sin(direction)
            self._pose_v = (max(0.0, along / (pose.time - seen[1].time)), now)
        if self._pose_v is not None and now - self._pose_v[1] <= 1.0:
            return self._pose_v[0]
        return None

    def on_pause(self, reason: dict[str, Any]) -> None:
        self.level = "paused"
        self.levels.speed = 0.0
        self.emit({"kind": "hazard", "level": "paused", **reason})

    def status_fields(self) -> dict[str, Any]:
        out: dict[str, Any] = {"hazard_monitor": self.shown_state(), "hazard_level": self.level,
                               "hazard_cycles": self.cycles}
        out.update(self.timing_fields())
        d = self.last.get("distance")
        if d is not None:
            out["hazard_distance"] = Fixed(d, 2)
        return out

    def failure_fields(self) -> dict[str, Any]:
        return {"kind": "hazard", "level": "error"}


@command("hazard-start", klass=HARDWARE, config=HazardStartConfig,
         help="start dynamic hazard detection: ToF forward at -tilt, coarse DEM of the corridor (-width, "
              "-heading, -lookahead) every -period; EVENT kind=hazard level=warning|stop|clear on changes")
async def hazard_start(ctx: Context, cfg: HazardStartConfig) -> dict[str, Any]:
    app = ctx.app
    app.monitors.refuse_other_holder("hazard")
    for dev in ("ptu", "tof"):
        app.devices.get(dev)  # E_DEVICE now rather than a failing thread
    lim = _limits(app.devices.get("ptu"))
    if not (lim[0] <= cfg.heading <= lim[1] and lim[2] <= cfg.tilt <= lim[3]):
        raise ProtocolError("E_ARG", f"-heading {cfg.heading:g} / -tilt {cfg.tilt:g} is outside the PTU's limits "
                                     f"pan [{lim[0]:.1f}, {lim[1]:.1f}], tilt [{lim[2]:.1f}, {lim[3]:.1f}] deg")
    restarted = await app.monitors.stop("hazard") is not None
    monitor = HazardMonitor(app, cfg, ctx.log_context())
    app.monitors.start(monitor)
    p = monitor.params
    return {"period": Fixed(cfg.period, 3), "tilt": Fixed(cfg.tilt, 2), "heading": Fixed(cfg.heading, 2),
            "width": Fixed(p.width, 3), "lookahead": Fixed(p.lookahead, 3),
            "stop_distance": Fixed(p.stop_distance, 3), "warn_distance": Fixed(p.warn_distance, 3),
            "state": "paused" if monitor._pause_reason() else "running", "restarted": restarted}


@command("hazard-stop", help="stop dynamic hazard detection")
async def hazard_stop(ctx: Context, cfg: None) -> dict[str, Any]:
    monitor = await ctx.app.monitors.stop("hazard")
    if monitor is None:
        return {"stopped": False, "cycles": 0}
    return {"stopped": True, "cycles": monitor.cycles, "level": monitor.level, **monitor.timing_fields()}


# ------------------------------------------------------------------ track3d


@dataclass
class TrackConfig(ModuleConfig):
    """What detection and tracking share: the sensor and the target's description."""

    module: ClassVar[str] = "track3d"
    sensor: str = param("tof", "tof: astronaut-sized objects in ToF points; stereo: ArUco markers",
                        choices=("tof", "stereo"))
    height: float = param(1.8, "size prior: the target's height", unit="m", min=0.3, max=5.0, option=False)
    width: float = param(0.5, "size prior: the target's width", unit="m", min=0.1, max=3.0, option=False)
    marker_id: int = param(-1, "ArUco 6x6 marker id of the target (-1: any)", min=-1, max=249, option=False)
    marker_box: float = param(0.4, "side of the cube carrying the marker (the position is its foot point)",
                              unit="m", min=0.0, max=5.0, option=False)
    max_range: float = param(4.8, "ignore ToF points farther than this", unit="m", min=0.5, max=30.0, option=False)
    resolution: str = param("high", "stereo resolution", choices=tuple(RESOLUTIONS),
                            option=False)


@dataclass
class TrackDetectConfig(TrackConfig):
    module: ClassVar[str] = "track3d_detect"
    range: list[float] = param([-90.0, 90.0, -20.0, 0.0], "view range pan_min,pan_max,tilt_min,tilt_max",
                               unit="deg", length=4, min=-360.0, max=360.0, ordered=True)
    overlap: float = param(0.2, "share of the field of view that neighbouring views overlap", min=0.0, max=0.9)


@dataclass
class TrackStartConfig(TrackConfig):
    module: ClassVar[str] = "track3d_start"
    period: float = param(0.0, "time from one cycle's start to the next (0: as fast as it goes)", unit="s",
                          min=0.0, max=60.0)
    aim: float = param(0.9, "the PTU aims this high above the target's foot point", unit="m", min=0.0, max=5.0,
                       option=False)
    lost_after: int = param(2, "missed cycles before the target counts as lost", min=1, max=100, option=False)
    resolution: str = param("low", "stereo resolution (low: ~0.5 s cycles in the simulator, high: ~2 s)",
                            choices=tuple(RESOLUTIONS), option=False)


def _prior(cfg: TrackConfig) -> tr.SizePrior:
    return tr.SizePrior(height=cfg.height, width=cfg.width, height_tolerance=0.25 * cfg.height,
                        width_range=(0.4 * cfg.width, 1.8 * cfg.width))


def _frame(app: App, call: Any) -> np.ndarray:
    """T_global_from_rover from the server's pose (the ground under the rover from the DEM, the
    attitude read through ``call``)."""
    return T_global_from_rover(*current_pose(app, call))


def _sense(app: App, cfg: TrackConfig, pan: float, tilt: float, call: Any
           ) -> tuple[list[tr.Detection], float, float]:
    """One view's detections in the global frame; returns them with the monotonic and wall-clock
    time of the exposure: the start of the acquisition call (the frame is exposed first, then
    read out and transferred, which is most of the call)."""
    head = HeadCalibration.from_dict(app.config.get("head").as_dict())
    T_gr = _frame(app, call)
    t0, w0 = time.monotonic(), time.time()
    if cfg.sensor == "tof":
        xyz, amplitude = call(app.devices.get("tof").grab_xyz, 1, 0.0)
        T = T_gr @ head.T_rover_from_sensor("tof", pan, tilt)
        img = tr.point_image(xyz, T, cfg.max_range)
        dets = tr.detect_standing(img, T[:3, 3], _prior(cfg), amplitude=amplitude)
    else:
        cams = app.devices.get("stereo")
        left, right = call(cams.grab_stereo, cfg.resolution, "mono8")
        cal = cams.calibration(cfg.resolution)
        sightings = tr.detect_markers(left, right, np.asarray(cal["K1"]), np.asarray(cal["D1"]),
                                      np.asarray(cal["K2"]), np.asarray(cal["D2"]), np.asarray(cal["R"]),
                                      np.asarray(cal["T"]), None if cfg.marker_id < 0 else cfg.marker_id)
        T = T_gr @ head.T_rover_from_sensor("left", pan, tilt)
        dets = []
        for s in sightings:
            centre = T[:3, :3] @ s.centre + T[:3, 3]
            normal = T[:3, :3] @ s.normal
            foot = tr.marker_box_foot(centre, normal, cfg.marker_box)
            side = float(np.mean(np.linalg.norm(np.diff(np.vstack([s.corners, s.corners[:1]]), axis=0), axis=1)))
            dets.append(tr.Detection(float(foot[0]), float(foot[1]), float(foot[2]), cfg.marker_box, side, 0.0,
                                     4, 0.0, marker_id=s.marker_id))
    return dets, t0, w0


def _target_fields(d: tr.Detection) -> dict[str, Any]:
    out: dict[str, Any] = {"x": Fixed(d.x, 3), "y": Fixed(d.y, 3), "z": Fixed(d.z, 3)}
    if d.marker_id is not None:
        out["marker"] = d.marker_id
    else:
        out.update(height=Fixed(d.height, 2), width=Fixed(d.width, 2))
    return out


@command("track3d-detect", job=True, klass=HARDWARE, config=TrackDetectConfig,
         help="search -range for the target (an astronaut in ToF points, or an ArUco marker with -sensor stereo); "
              "OK found=true x y z (global) or found=false")
def track3d_detect(job: Job, cfg: TrackDetectConfig) -> dict[str, Any]:
    app = job.app
    ptu = app.devices.get("ptu")
    if cfg.sensor == "tof":
        K, _ = app.devices.get("tof").intrinsics()
        fov = _fov(K, TOF_SHAPE)
    else:
        cal = app.devices.get("stereo").calibration(cfg.resolution)
        w, h = cal["image_size"]
        fov = _fov(np.asarray(cal["K1"]), (int(h), int(w)))
    positions = get_ptu_positions(cfg.range, fov, cfg.overlap, _limits(ptu))
    found: list[tr.Detection] = []
    for i, (pan, tilt) in enumerate(positions):
        job.check()
        job.progress(i, len(positions), f"pan={pan:.1f} tilt={tilt:.1f}")
        reached = device_call(job, ptu.move, pan, tilt, True)
        dets, _, _ = _sense(app, cfg, float(reached[0]), float(reached[1]), lambda fn, *a: device_call(job, fn, *a))
        found += dets
    job.progress(len(positions), len(positions), f"{len(found)} sighting(s)")
    merged = tr.merge_detections(found)
    if not merged:
        app.track_target.set(None)
        return {"found": False, "views": len(positions)}
    best = merged[0]
    app.track_target.set(best)
    return {"found": True, **_target_fields(best), "views": len(positions), "candidates": len(merged)}


class TargetTracker(Monitor):
    """Keeps the PTU on the target and reports its position every cycle."""

    name = "track"

    def __init__(self, app: App, cfg: TrackStartConfig, start: tr.Detection | None,
                 log_context: dict[str, Any] | None = None) -> None:
        super().__init__(app, cfg.period, log_context)
        self.cfg = cfg
        self.filter = tr.Tracker(lost_after=cfg.lost_after)
        if start is not None:
            self.filter.reset(np.array([start.x, start.y, start.z]), time.monotonic())
            self.filter.lost = False
        self.fixes = 0
        self.losses = 0
        self.lost_sent = start is None
        self.last: tr.Detection | None = start

    def cycle(self) -> None:
        cfg, app = self.cfg, self.app
        now = time.monotonic()
        pred = self.filter.predict(now)
        pan_tilt = self.pointing
        if pred is not None:
            T_rg = invert(_frame(app, self.call))
            aim = T_rg[:3, :3] @ (pred + np.array([0.0, 0.0, cfg.aim])) + T_rg[:3, 3]
            pan, tilt = self.head().look_at(aim)
            lim = _limits(app.devices.get("ptu"))
            pan_tilt = (float(np.clip(pan, lim[0], lim[1])), float(np.clip(tilt, lim[2], lim[3])))
        if pan_tilt is None:
            here = app.ptu_position()
            pan_tilt = here if here is not None else (0.0, 0.0)
        pan, tilt = self.point(*pan_tilt)
        dets, t, wall = _sense(app, cfg, pan, tilt, self.call)
        det = self.filter.choose(dets, t)
        reacquired = self.filter.update(det, t)
        if det is not None:
            self.fixes += 1
            self.last = det
            self.lost_sent = False
            v = self.filter.velocity
            fields: dict[str, Any] = {"kind": "track", **_target_fields(det), "vx": Fixed(float(v[0]), 2),
                                      "vy": Fixed(float(v[1]), 2), "rate": Fixed(self.rate(), 2),
                                      "time": Fixed(wall, 3)}
            if reacquired:
                fields["reacquired"] = True
            self.emit(fields)
        elif self.filter.lost and not self.lost_sent:
            self.lost_sent = True
            self.losses += 1
            fields = {"kind": "track", "lost": True, "time": Fixed(wall, 3)}
            if self.last is not None:
                fields.update(last_x=Fixed(self.last.x, 3), last_y=Fixed(self.last.y, 3))
            self.emit(fields)

    def status_fields(self) -> dict[str, Any]:
        out: dict[str, Any] = {"track": self.shown_state(), "track_lost": self.filter.lost,
                               "track_cycles": self.cycles,
                               "track_rate": Fixed(self.rate(), 2)}
        out.update(self.timing_fields())
        return out

    def failure_fields(self) -> dict[str, Any]:
        return {"kind": "track", "lost": True, "stopped": True}


@command("track3d-start", klass=HARDWARE, config=TrackStartConfig,
         help="start tracking the target found by track3d-detect (or the first one that comes into view): the PTU "
              "follows it, EVENT kind=track x y z rate each cycle, lost=true when it is gone")
async def track3d_start(ctx: Context, cfg: TrackStartConfig) -> dict[str, Any]:
    app = ctx.app
    app.monitors.refuse_other_holder("track")
    for dev in ("ptu", cfg.sensor):
        app.devices.get(dev)
    await app.monitors.stop("track")
    start = app.track_target.get()
    tracker = TargetTracker(app, cfg, start, ctx.log_context())
    app.monitors.start(tracker)
    target = None if start is None else [Fixed(start.x, 3), Fixed(start.y, 3), Fixed(start.z, 3)]
    return {"sensor": cfg.sensor, "period": Fixed(cfg.period, 3), "target": target}


@command("track3d-stop", help="stop tracking the target")
async def track3d_stop(ctx: Context, cfg: None) -> dict[str, Any]:
    tracker = await ctx.app.monitors.stop("track")
    if tracker is None:
        return {"stopped": False, "cycles": 0}
    out: dict[str, Any] = {"stopped": True, "cycles": tracker.cycles, "fixes": tracker.fixes,
                           "losses": tracker.losses, **tracker.timing_fields()}
    if tracker.last is not None:
        out.update(_target_fields(tracker.last))
    return out
