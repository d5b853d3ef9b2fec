"""The see strategy (``navigate -loop see``), drive while seeing.

With its bounds map (``see_gate bounds``, the default) every section is chosen by the vehicle
check itself, ENav's way (:mod:`.sections`); this module keeps what that shares with the plan on
the 5 cm maps (``see_gate off``): the frames, their fusion, the looks, the stop EVENT, the
set-down and the localiser's fixes. On the 5 cm maps the rover drives a leg in
cycles (the simulated rover: every ``see_period`` of driving; the GNC: each pose it reports
while driving); each cycle
one forward ToF frame feeds the rolling local elevation map, Dem2Hazard updates the window the
frame touched, and the rover's footprint is swept over the next metres of its path. A hazard
there stops the rover (an ``EVENT kind=hazard level=stop`` shaped as the hazard monitor's) and
navigate replans from the scan maps with the rolling map laid over them, instead of stopping
for a 360-degree scan at the end of every leg (seed 000 sect. 6.2; Perseverance's ENav
"thinking while driving").

Why the cycle looks as it does
    - The rover drives ``see_period`` of simulated time, then the ToF takes its frame, then the
      check runs; the check's CPU time is measured as the cycle latency (target < 100 ms). The
      frame is exposed while the rover rolls (``World.under_way``): it costs no standing time,
      as on a rover whose camera works while it drives; a frame taken standing (a look round
      before a 360-degree scan) costs its time on the clock.
    - The rover steers by pure pursuit: small heading changes are driven as arcs, only large
      ones are turned on the spot, so replanning on the move costs no stop.
    - The check looks ``see_lookahead`` metres ahead along the remaining waypoints, so a hazard
      is met while still farther than ``stop_distance`` plus one cycle's travel: the stop comes
      before the rover is within its stopping distance.
    - Only ``not_traversable`` stops the rover: the plan was made on the scan maps, which the
      rolling map only refines; unseen cells (the blind patch under the view) are the plan's,
      unless ``see_unseen`` says to look at them first (and with ``keep``, to plan round them).

The scan strategy (:mod:`.scan`) and this one are driven by the same mission (:mod:`.mission`),
so the two compare side by side (``python -m tools.bench.navigate``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from drivers.rover import Motion
from drivers.tof.constants import FOV_H_DEG, FOV_V_DEG
from prox_workflows.algorithms.bounds_map import BoundsMap, contact_plane
from prox_workflows.algorithms.hazard_monitor import ground_pixels, rover_points
from prox_workflows.algorithms.looks import View, blind_radius, on_body, standing_look
from prox_workflows.algorithms.noise import pair_sigmas, tof_spread
from prox_workflows.algorithms.planner import NavMaps
from prox_workflows.algorithms.replan import Replanner
from prox_workflows.algorithms.rolling_map import (
    MapMemory,
    RollingMap,
    RollingParams,
    mark_unseen,
    path_poses,
    sweep_check,
)
from prox_workflows.algorithms.safety import in_footprint
from prox_workflows.algorithms.set_down import set_down
from prox_workflows.algorithms.transforms import HeadCalibration, T_global_from_rover
from rvs_params.hazard import HAZARDOUS, SAFE

from ..jobs import device_call
from ..maps import ground_height
from ..protocol import Fixed, ProtocolError, Reply
from .planning import goal_stand_in
from .pursuit import arc_rate, in_rover_frame, motion_poses, nearest_stretch, passed, pursuit_point
from .sections import GUIDE_CELL, WINDOW_SLACK, Chooser, window_half

if TYPE_CHECKING:
    from ..app import App
    from ..jobs import Job
    from .config import SeeConfig
    from .mission import Mission


GAZE_NEAR, GAZE_FAR = 0.9, 1.8  # m along the path: where the near and the far frames of the gaze look
GAZE_PAN = 60.0  # deg: the gaze pans along the path at most this far off the heading
# a PTU move stops the drive for about 0.8 s of its 1 s cycle: the gaze holds where it points for
# GAZE_HOLD frames (near, then far), and between re-aims pans again only where the path's bearing
# has moved more than GAZE_SLACK off the pan (a turn), well inside the ToF's field of view
GAZE_HOLD = 3
GAZE_SLACK = 15.0  # deg
EDGE_JUMP = 0.02  # share of the range: a bigger jump to a neighbouring pixel marks a depth edge's mixed pixel
BODY_MARGIN = 0.06  # m round the rover's box and wheels whose returns are its own
BLIND_EDGE = 0.1  # m past the mast's blind disc that its rays only graze (bounded by a ray, seldom by returns)
RING_WIDTH = 0.5  # m past the blind disc: the seen ground whose plane see_set_down ring takes
STALL_CYCLES = 20  # a leg driven this many cycles without getting STALL_PROGRESS closer to its end is stalled
STALL_PROGRESS = 0.05  # m


@dataclass
class LoopStats:
    """What the see loop did in one navigate: reported in its OK line and read by the benchmark."""

    scans: int = 0
    replans: int = 0
    stops: int = 0
    looks: int = 0  # frames taken standing at unseen ground ahead (see_unseen)
    retreats: int = 0  # dead ends the chooser backed out of (sections.Chooser)
    cycles: int = 0
    cycle_ms: list[float] = field(default_factory=list)  # rolling map + hazard + check, wall ms
    # the same in the process's CPU ms: on a shared machine the wall time also counts the waits
    # for a core, which the cycle's own cost does not include (the rest of the process, status
    # replies included, counts in it: an upper bound)
    cycle_cpu_ms: list[float] = field(default_factory=list)
    frame_ms: list[float] = field(default_factory=list)  # the ToF frame (the simulator's render), wall ms
    replan_ms: list[float] = field(default_factory=list)  # A* on the merged maps (the chooser: a choice), wall ms
    replan_cpu_ms: list[float] = field(default_factory=list)  # the same, process CPU ms

    def cycle(self, wall0: float, cpu0: float) -> None:
        """One cycle ended that started at ``wall0`` (monotonic) and ``cpu0`` (process time)."""
        self.cycles += 1
        self.cycle_ms.append((time.monotonic() - wall0) * 1000)
        self.cycle_cpu_ms.append((time.process_time() - cpu0) * 1000)

    def replanned(self, wall0: float, cpu0: float) -> None:
        """One plan (or choice) made that started at ``wall0`` (monotonic) and ``cpu0`` (process time)."""
        self.replan_ms.append((time.monotonic() - wall0) * 1000)
        self.replan_cpu_ms.append((time.process_time() - cpu0) * 1000)

    def fields(self) -> dict[str, Any]:
        """The OK line's keys."""
        def mean(v: list[float]) -> float:
            return float(np.mean(v)) if v else 0.0

        def p95(v: list[float]) -> float:
            return float(np.percentile(v, 95)) if v else 0.0

        return {"scans": self.scans, "replans": self.replans, "stops": self.stops, "looks": self.looks,
                "retreats": self.retreats, "cycles": self.cycles,
                "cycle_ms": Fixed(mean(self.cycle_ms), 1),
                "cycle_ms_max": Fixed(max(self.cycle_ms, default=0.0), 1),
                "cycle_ms_p95": Fixed(p95(self.cycle_ms), 1), "cycle_cpu_ms_p95": Fixed(p95(self.cycle_cpu_ms), 1),
                "frame_ms": Fixed(mean(self.frame_ms), 1), "replan_ms": Fixed(mean(self.replan_ms), 1),
                "replan_ms_p95": Fixed(p95(self.replan_ms), 1), "replan_cpu_ms_p95": Fixed(p95(self.replan_cpu_ms), 1)}


@dataclass
class DriveOutcome:
    """How a leg driven while seeing ended."""

    kind: str  # done (last waypoint reached) | hazard (stopped) | unseen (stopped: ground no map has seen
    # ahead, a look did not show it) | ahead (close to the leg's end: replan on the move) | stalled (the
    # rover got no closer to the leg's end for STALL_CYCLES cycles)
    segments_done: int
    hazard: dict[str, Any] | None = None


class SeeingDriver:
    """One navigate's see loop: the rolling map lives for the whole mission."""

    def __init__(self, job: Job, rover: Any, params: SeeConfig, stats: LoopStats,
                 memory: MapMemory | None = None, bounds: BoundsMap | None = None) -> None:
        self.job = job
        self.app: App = job.app
        self.rover = rover
        self.body = rover.body()
        # the chooser's map (see_gate bounds): every frame's bounds over a window that follows the rover
        self.bounds = bounds
        self.set_down_pending = False  # see_set_down ring: the set-down waits for the first look round
        # the body's hazard cameras switched on (drivers.hazcam.cameras): each frame feeds the bounds
        self.hazcams: list[str] = []
        if bounds is not None and "hazcam" in self.app.devices.devices:
            self.hazcams = list(self.app.devices.get("hazcam").cameras())
        self.p = params
        self.stats = stats
        head = self.app.config.get("head")
        self.length = head.rover_length + 2 * params.margin
        self.width = head.rover_width + 2 * params.margin
        self.head = HeadCalibration.from_dict(head.as_dict())
        here = self.pose()
        self.map = RollingMap(RollingParams(), self.app.config.get("dem2hazard"), (here[0], here[1]), memory)
        # the body turning on the spot, with the cells its corners touch
        self.radius = math.hypot(head.rover_length, head.rover_width) / 2 + self.map.params.cell
        self.level = "clear"
        self.pan_tilt = (0.0, params.tilt)  # where the ToF points (what the PTU reached)
        self.frame_no = 0  # frames taken while driving (the gaze alternates far and near)
        self.cpu1 = 0.0  # the process time the last frame's fusion started (a cycle's CPU is counted from it)
        # the maps the leg was planned on (the scans and the rolling map then) on the rolling map's
        # grid, as traversability: the check counts the ground they saw as seen
        self.known: NavMaps | None = None
        self.seen: tuple[Any, Any, np.ndarray] | None = None  # (known, geometry, layer) of the last resampling
        self.looked_from: tuple[float, float, float] | None = None  # the pose of the last look at unseen ground

    def point_forward(self) -> None:
        """The PTU to pan 0 (the rover's forward), tilted down: the ToF looks where the rover goes."""
        self._point(0.0)

    def _point(self, pan: float, tilt: float | None = None) -> None:
        reached = device_call(self.job, self.app.devices.get("ptu").move, pan,
                              self.p.tilt if tilt is None else tilt, True)
        self.pan_tilt = (float(reached[0]), float(reached[1]))

    def gaze(self, pose: tuple[float, float, float], remaining: np.ndarray) -> None:
        """Where the ToF looks for this cycle's frame (``see_gaze path``): the mast pans along the
        path, not the heading, so the ground a turn will put under the wheels is seen before the
        turn; ``GAZE_HOLD`` frames in turn it looks at the path ``GAZE_NEAR`` m ahead at the PTU's
        lowest tilt, where the next section is judged (closer, so with a third of the range noise),
        and at the point ``GAZE_FAR`` m ahead at ``see_tilt``; within a hold the mast pans only
        where the path's bearing has moved ``GAZE_SLACK`` off its pan. Off, or without the bounds
        map (which the near frames feed): pan 0, ``see_tilt``, and no PTU move between frames
        (each move costs the drive its time)."""
        if self.p.gaze == "off" or self.bounds is None:
            return
        self.frame_no += 1
        near = (self.frame_no // GAZE_HOLD) % 2 == 1
        ahead = path_poses(pose, remaining, GAZE_NEAR if near else GAZE_FAR, step=0.05)[-1]
        pan, _ = self.head.look_at(np.array([*in_rover_frame(pose, ahead[0], ahead[1]), 0.0]))
        pan = max(-GAZE_PAN, min(GAZE_PAN, round(pan / 5.0) * 5.0))  # 5-degree steps: fewer moves
        tilt = self._lowest_tilt() if near else self.p.tilt
        due = self.frame_no % GAZE_HOLD == 0 or abs(pan - self.pan_tilt[0]) > GAZE_SLACK
        if due and (pan, tilt) != self.pan_tilt:
            self._point(pan, tilt)

    def pose(self) -> tuple[float, float, float]:
        """The rover's belief: the simulated rover's odometry, the GNC's last pose report."""
        return self.rover.pose()

    def see(self, pan_tilt: tuple[float, float], cameras: tuple[str, ...] = ("front",), frames: int = 1
            ) -> tuple[tuple[float, float, float], float]:
        """One ToF frame (the camera's average of ``frames``) into the rolling map, and into the
        bounds map (if kept) with a frame of each of the hazard ``cameras`` switched on (driving:
        the front pair, which sees the ground the wheels meet next); returns the rover's pose and
        the wall time (monotonic) the fusion started. Each return's sigma is the ToF's noise
        model's at its own amplitude (as the device says the noise goes with it) over the frames
        averaged, its horizontal error along its ray."""
        job, app = self.job, self.app
        t0 = time.monotonic()
        tof = app.devices.get("tof")
        xyz, amplitude = device_call(job, tof.grab_xyz, frames, 0.0)
        t1 = time.monotonic()
        self.cpu1 = time.process_time()  # the cycle's CPU from here (LoopStats.cycle)
        x, y, heading = self.pose()
        T_rc = self.head.T_rover_from_sensor("tof", *pan_tilt)
        pts = rover_points(xyz, T_rc, self.p.subsample, self.p.max_range, amplitude, 0.1)
        ranges = np.linalg.norm(pts - T_rc[:3, 3].astype(np.float32), axis=1)
        T = T_global_from_rover(x, y, heading, self.datum(x, y))
        world_pts = pts.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
        self.map.follow(x, y)
        self.map.fuse(world_pts, ranges)
        if self.bounds is not None:
            self.bounds.follow(x, y, WINDOW_SLACK)
            # every pixel: a rock's top is read by the few returns on it, which a subsample drops
            keep = ground_pixels(xyz, 1, self.p.max_range, amplitude, 0.1, EDGE_JUMP)
            cam = xyz[keep].astype(np.float64)
            full = cam @ T_rc[:3, :3].T + T_rc[:3, 3]
            ground = ~self.on_body(full)
            full = full[ground] @ T[:3, :3].T + T[:3, 3]
            origin = T[:3, :3] @ T_rc[:3, 3] + T[:3, 3]
            raw, mhz = tof.noise_amplitude(amplitude[keep][ground], np.linalg.norm(cam[ground], axis=1))
            sigma, along, across = tof_spread(full, origin, raw, frames=frames, frequency_mhz=mhz)
            self.bounds.fuse(full, sigma, origin, self.p.max_range, along, sigma_across=across)
            for camera in (c for c in self.hazcams if c in cameras):
                self._fuse_hazcam(camera, T)
            if not self.set_down_pending:
                self.bounds.stood((x, y, heading), float(T[2, 3]), self.body, self.attitude())
            app.bus.publish("bounds", bounds=self.bounds)  # Foxglove and recordings (their hub throttles)
        self.stats.frame_ms.append((t1 - t0) * 1000)
        return (x, y, heading), t1

    def cycle(self, remaining: np.ndarray) -> tuple[Any, Any, tuple[float, float, float]]:
        """One frame into the rolling map and the check of the next metres; returns the check,
        the unseen check (:meth:`judge`) and the pose."""
        pose, t1 = self.see(self.pan_tilt)
        check, unseen = self.judge(pose, remaining)
        self.stats.cycle(t1, self.cpu1)
        return check, unseen, pose

    def judge(self, pose: tuple[float, float, float], remaining: np.ndarray,
              motion: np.ndarray | None = None) -> tuple[Any, Any]:
        """The footprint swept along the motion the rover executes next (``motion``, poses from
        ``pose``: this cycle's arc or turn on the spot; by default the turn from its heading to
        the path's) and on along the path for the next ``lookahead`` metres (blocked anywhere
        stops the rover), and for the next ``blind`` metres: the check of that stretch when it
        covers ground no map has seen, else None. The executed arc cuts the path's corners and
        a turn on the spot swings the body's corners wide: the planned polyline alone leaves
        that ground unchecked. The forward view starts about a metre ahead of the rover (1.1 m
        from its centre at tilt -35 deg), so ground that close and still unseen will not be
        seen before the body is on it: a rock the rover turned to face, or one round the corner
        of its path."""
        trav, g = self._check_layer(pose), self.map.geometry
        lead = np.asarray([pose] if motion is None else motion, dtype=np.float64).reshape(-1, 3)

        def along(distance: float) -> np.ndarray:
            return np.vstack([lead, path_poses(tuple(lead[-1]), remaining, distance)])

        check = sweep_check(trav, g, along(self.p.lookahead), self.length, self.width)
        if self.p.unseen == "off" or self.p.blind <= 0.0:
            return check, None
        near = sweep_check(trav, g, along(self.p.blind), self.length, self.width)
        return check, near if near.verdict == "unknown" else None

    def _fuse_hazcam(self, camera: str, T: np.ndarray) -> None:
        """One body hazard camera's pair into the bounds map (with the rover at ``T``): the ground
        from about 0.1 m past the body's end, where the mast never sees. Each point's range sigma
        is the disparity noise's (it grows with the range squared), and the frame is fused as a
        stereo frame: a cell's pixels share the matcher's window, so their errors are one error.
        Fused as independent returns, 60 % of the cells' means round the body at mission starts
        lay more than 3 sigma off the true surface and 7-16 % of the cells had the truth under
        their lower bound; as stereo about 1 % and at most 0.2 % (``python -m tools.bench.hazcam
        --ring``).
        Where a pair bounded a cell its bounds stand alone (``stereo_first``): they replace the
        set-down's prior there."""
        device = self.app.devices.get("hazcam")
        frame = device_call(self.job, device.grab, camera)
        ground = ~self.on_body(frame.points)
        pts = frame.points[ground] @ T[:3, :3].T + T[:3, 3]
        origin = T[:3, :3] @ frame.origin + T[:3, 3]
        sigma, sigma_xy = pair_sigmas(pts, origin, frame.sigma_range[ground], device.rig(camera).focal)
        self.bounds.fuse(pts, sigma, origin, device.config.max_range, sigma_xy, sensor="stereo")

    def on_body(self, pts: np.ndarray) -> np.ndarray:
        """Rover-frame points on the rover itself (its box and wheels, a few centimetres grown):
        the mast looking down and back sees its own deck and wheels, which are not ground."""
        return on_body(pts, self.body, BODY_MARGIN)

    def datum(self, x: float, y: float) -> float:
        """The height the frames take the rover's own ground at (x, y): the rolling map's there,
        else the global maps'. The rover frame's origin: where its wheels' plane meets its centre."""
        z = self.map.ground_height(x, y)
        return ground_height(self.app.maps.layers, x, y) if z is None else z

    def imu(self) -> tuple[float, float, float] | None:
        """Roll, pitch and their sigma (deg) from the rover's IMU where it stands, or None (the
        rover gives none: a GNC whose pose reports carry no roll and pitch)."""
        attitude = getattr(self.rover, "attitude", None)
        return attitude() if attitude is not None else None

    def attitude(self) -> tuple[float, float, float] | None:
        """The IMU's attitude (:meth:`imu`) for the ground under the wheels while driving, or None
        (``see_set_down`` other than attitude: the wheels' ground is then the frames' and, where
        none, level within 5 mm of the datum)."""
        return self.imu() if self.p.set_down == "attitude" else None

    def _check_layer(self, pose: tuple[float, float, float]) -> np.ndarray:
        """The traversability the check sweeps: the rolling map's, lowered to 0 where the maps the
        leg was planned on say hazardous, and theirs where the rolling map has none (resampled
        when either changes); the ground under the body counts as seen: it stands there. Never
        less cautious than the rolling map alone (a scan's verdict does not clear what the
        rolling map saw, as it does in the plan: a marsyard mission then drove over a 20.0 deg
        cell the scan had judged safe). Only the body's own rectangle, not the disc it sweeps
        turning on the spot: that disc holds ground beside the body the forward ToF never
        showed, a rock's flank the rover turned beside (hirise mission 4 drove over 364 such
        cells); unseen, see_unseen looks at it before the body goes there."""
        g = self.map.geometry
        if self.known is None:
            layer = self.map.traversability.copy()
        else:
            if self.seen is None or self.seen[0] is not self.known or self.seen[1] != g:
                self.seen = (self.known, g, self.map.seen_by(self.known))
            layer = np.fmin(self.map.traversability, self.seen[2])
        xs, ys = g.centers()
        under = in_footprint(xs[None, :] - pose[0], ys[:, None] - pose[1], pose[2], self.length, self.width, g.cell)
        layer[under & np.isnan(layer)] = 1.0
        return layer

    def _lowest_tilt(self) -> float:
        return float(self.app.devices.get("ptu").limits()["tilt"]["min_deg"])

    def blind_disc(self) -> tuple[float, float, float]:
        """The ground round the mast's foot that no frame shows, even at the PTU's lowest tilt:
        (x, y) of the pan axis's foot and the radius, by the head's calibration."""
        x, y, heading = self.pose()
        bx, by, _ = self.head.ptu_base
        c, s = math.cos(math.radians(heading)), math.sin(math.radians(heading))
        return x + bx * c - by * s, y + bx * s + by * c, blind_radius(self.head, self.view())

    def view(self) -> View:
        """The ToF's field of view and the PTU's reach, for the look planner."""
        limits = self.app.devices.get("ptu").limits()
        pan = min(-float(limits["pan"]["min_deg"]), float(limits["pan"]["max_deg"]))
        return View(FOV_H_DEG, FOV_V_DEG, float(limits["tilt"]["min_deg"]), pan)

    def look_at(self, x: float, y: float, pose: tuple[float, float, float]) -> bool:
        """One frame (``see_look_frames`` averaged), standing, toward ground point (x, y), tilted to
        it but no lower than the PTU goes: the frame then shows the ground along that bearing from
        the mast's blind disc out (:meth:`blind_disc`), which holds the point unless it lies inside
        that disc. False (no frame) when the rover looked from about here already: what that look
        did not show, another from the same place will not."""
        last = self.looked_from
        if last is not None and math.hypot(pose[0] - last[0], pose[1] - last[1]) < 0.3 and \
                abs((pose[2] - last[2] + 180.0) % 360.0 - 180.0) < 20.0:
            return False
        self.looked_from = pose
        self.stats.looks += 1
        self.job.progress(0, 1, f"looking at unseen ground ({x:.2f}, {y:.2f}) before driving onto it", phase="drive")
        pan, tilt = self.head.look_at(np.array([*in_rover_frame(pose, x, y), 0.0]))
        self._point(max(-150.0, min(150.0, pan)), max(self._lowest_tilt(), min(self.p.tilt, tilt)))
        self.see(self.pan_tilt, (), self.p.look_frames)  # the body's cameras saw this cycle's ground already
        self.job.check()
        return True

    def look_round(self, toward: float | None = None) -> None:
        """A standing look (:func:`looks.standing_look`): frames at the PTU's lowest tilt and at
        ``see_tilt`` over the pans that show the ground the body covers driving ``see_look_drive``
        in a fan of +-60 deg about ``toward`` (deg from the heading; None: all round, as a turn on
        the spot may face any way) and as far again,
        from the mast's blind disc out, leaving out ground the bounds map already holds within half
        the lower of the body's climb and clearance (wider bounds are what refuse a safe pose);
        each position ``see_look_frames`` frames averaged. After a scan: the scan's views make
        the 5 cm maps only."""
        pose = self.pose()
        judged = None
        if self.bounds is not None:
            reach = 2 * self.p.look_drive + self.body.length
            lower, upper, g = self.bounds.window(pose[0] - reach, pose[1] - reach, pose[0] + reach, pose[1] + reach)
            with np.errstate(invalid="ignore"):
                judged = (upper - lower <= min(self.body.climb, self.body.clearance) / 2, g)
        fan = np.arange(-60.0, 60.1, 15.0) + toward if toward is not None else np.arange(-180.0, 180.0, 15.0)
        positions = standing_look(pose, self.head, self.view(), self.body.length, self.body.width, self.p.look_drive,
                                  bearings=fan, far_tilt=self.p.tilt, judged=judged)
        if not positions:
            return
        self.stats.looks += 1
        self.job.progress(0, 1, f"looking standing: {len(positions)} positions of {self.p.look_frames} frames, the "
                                f"ground the next {self.p.look_drive:g} m need", phase="drive")
        cameras = tuple(self.hazcams)  # the body's cameras do not pan: one frame of each
        for pan, tilt in positions:
            self._point(pan, tilt)
            self.see(self.pan_tilt, cameras, self.p.look_frames)
            cameras = ()
            self.job.check()
        self.point_forward()

    def look(self, bearing: float, spread: float = 40.0) -> None:
        """Frames panned to ``bearing`` (deg from the rover's heading) and ``spread`` either side,
        the rover standing (each ``see_look_frames`` averaged): the rolling map's view round the
        forward one."""
        cameras = tuple(self.hazcams)
        for pan in (bearing - spread, bearing, bearing + spread):
            self._point(max(-150.0, min(150.0, pan)))
            self.see(self.pan_tilt, cameras, self.p.look_frames)
            cameras = ()
            self.job.check()

    def _stop_event(self, x: float, y: float, pose: tuple[float, float, float],
                    reason: str = "hazard") -> dict[str, Any]:
        """The stop EVENT, shaped as the hazard monitor's (distance from the rover's front to the
        hazard at global (x, y), bearing CCW from the heading, x and y in the rover frame), with
        why: ``hazard`` (the 5 cm maps' hazard), ``vehicle`` (the vehicle check on the bounds map:
        the body would exceed a limit at a pose ahead), ``unknown`` (ground no frame bounded
        under a pose ahead)."""
        rx, ry = in_rover_frame(pose, x, y)
        distance = max(0.0, rx - self.app.config.get("head").rover_length / 2 - self.map.params.cell / 2)
        self.stats.stops += 1
        fields = {"kind": "hazard", "level": "stop", "reason": reason, "distance": Fixed(distance, 2),
                  "bearing": Fixed(math.degrees(math.atan2(ry, rx)), 1), "x": Fixed(rx, 2), "y": Fixed(ry, 2),
                  "seen": "false" if reason == "unknown" else "true", "cycle": self.stats.cycles,
                  "job": self.job.id, "source": "navigate"}
        self.level = "stop"
        self.app.broadcast_threadsafe(Reply("RVS", "EVENT", fields))
        return {"distance": distance, "x": rx, "y": ry, "reason": reason}

    def _clear(self) -> None:
        if self.level != "clear":
            self.level = "clear"
            self.app.broadcast_threadsafe(Reply("RVS", "EVENT", {
                "kind": "hazard", "level": "clear", "cycle": self.stats.cycles, "job": self.job.id,
                "source": "navigate"}))


class SeePilot:
    """One leg driven while seeing, for :meth:`drivers.rover.Rover.drive`: every cycle one
    forward frame and the check. With the simulated rover each cycle also steers: the rover
    steers at the point ``pursuit`` metres ahead on the path (pure pursuit): a heading error up
    to ``arc_turn`` is driven out as an arc at full speed when the turn rate allows that arc, a
    larger one is turned on the spot, so a replanned path or a waypoint's corner costs no stop
    (MER's and Perseverance's drive arcs; the stop-and-go loop turns on the spot at every
    waypoint). With ``allow_ahead`` the leg ends ``ahead`` once its end is ``replan_ahead``
    away, so navigate extends the path from what the rolling map has seen, on the move. Ground
    no map has seen under the next ``blind`` metres (:meth:`SeeingDriver.judge`): the rover
    stops and looks at it; with ``strict`` (the plan kept the body to seen ground) it ends the
    leg (``unseen``) when the look does not show it, else it drives on.

    With the GNC steering, each pose it reports while driving is a cycle (a frame is only placed
    in the map at a known pose): a hazard in the corridor is an ``EVENT kind=hazard level=stop``
    for the GNC to stop on, and the leg ends once the GNC's pose stands still."""

    def __init__(self, driver: SeeingDriver, waypoints: np.ndarray, progress: Any, track: Any, allow_ahead: bool,
                 strict: bool) -> None:
        self.d = driver
        self.wps = np.asarray(waypoints, dtype=np.float64)[:, :2]
        self.segments = len(self.wps) - 1
        self.progress = progress
        self.track = track
        self.allow_ahead = allow_ahead
        self.strict = strict
        self.k = 1  # the waypoint the rover is heading for
        self.best, self.since_best = math.inf, 0  # the least path left to the leg's end, and cycles since
        self.outcome: DriveOutcome | None = None  # how the leg ended, when the pilot ended it
        self.hazard: dict[str, Any] | None = None  # the GNC was told to stop (once per leg)

    def moved(self, truth: tuple[float, float, float], end: bool) -> None:
        self.track.add(truth, end)

    def next(self, pose: tuple[float, float, float]) -> Motion | None:
        return self._steer() if self.d.rover.steers else self._watch(pose)

    def _advance(self, pose: tuple[float, float, float], last: int) -> None:
        while self.k <= last and passed(pose, self.wps[self.k - 1], self.wps[self.k]):
            self.progress(self.k, self.segments, f"segment {self.k}/{self.segments} driven", "drive")
            self.k += 1

    def _watch(self, pose: tuple[float, float, float]) -> None:
        self._advance(pose, self.segments - 1)
        check, _, seen_at = self.d.cycle(self.wps[self.k:])
        if self.hazard is not None:  # once per leg: the GNC is stopping
            return
        if check.verdict == "not_traversable":
            self.hazard = self.d._stop_event(check.worst_x, check.worst_y, seen_at)
        else:
            self.d._clear()

    def _end(self, kind: str, done: int, hazard: dict[str, Any] | None = None) -> None:
        self.outcome = DriveOutcome(kind, done, hazard)

    def _steer(self) -> Motion | None:
        d, wps, segments, p = self.d, self.wps, self.segments, self.d.p
        speed, turn_rate = d.rover.speeds()
        d.gaze(d.pose(), wps[self.k:])
        pose, t1 = d.see(d.pan_tilt)
        d.job.check()
        self._advance(pose, segments)
        if self.k > segments:
            return self._end("done", segments)
        nearest = nearest_stretch(pose, wps, self.k)
        while self.k < nearest:
            self.progress(self.k, segments, f"segment {self.k}/{segments} driven", "drive")
            self.k += 1
        k = self.k
        left = math.hypot(wps[k][0] - pose[0], wps[k][1] - pose[1])
        to_end = left + float(np.sum(np.hypot(*np.diff(wps[k:], axis=0).T)))
        if self.allow_ahead and to_end <= p.replan_ahead:
            return self._end("ahead", k - 1)
        # a watchdog: steering that swings about a point it cannot settle on (10 cm forward, a
        # turn on the spot, 10 cm back: a marsyard mission did so for 5 simulated hours) ends the
        # leg, and navigate replans from where the rover is
        if to_end < self.best - STALL_PROGRESS:
            self.best, self.since_best = to_end, 0
        else:
            self.since_best += 1
        if self.since_best >= STALL_CYCLES:
            self.progress(1, 1, f"stopped: {to_end:.2f} m from the leg's end, no closer in {STALL_CYCLES} cycles",
                          "stop")
            return self._end("stalled", k - 1)
        tx, ty = pursuit_point(pose, wps, k, p.pursuit)
        w = arc_rate(pose, (tx, ty), speed, turn_rate, p.arc_turn)
        dt = min(p.period, to_end / speed)
        motion = motion_poses(pose, (tx, ty), w, speed, dt)
        check, unseen = d.judge(pose, wps[k:], motion)
        d.stats.cycle(t1, d.cpu1)
        if check.verdict == "not_traversable":
            return self._end("hazard", k - 1, d._stop_event(check.worst_x, check.worst_y, pose))
        # unseen ground ahead: the rover stops and looks (a turn on the spot comes first, after
        # which that ground lies ahead and the look is a tilt, not a pan)
        if unseen is not None and w is not None and d.look_at(unseen.worst_x, unseen.worst_y, pose):
            check, unseen = d.judge(pose, wps[k:], motion)
            d.point_forward()
            if check.verdict == "not_traversable":
                return self._end("hazard", k - 1, d._stop_event(check.worst_x, check.worst_y, pose))
        if unseen is not None and w is not None and self.strict:
            self.progress(1, 1, f"stopped: ground {unseen.unknown_cells} cells under the next {p.blind:g} m unseen",
                          "stop")
            return self._end("unseen", k - 1)
        d._clear()
        return Motion.face(tx, ty) if w is None else Motion.arc(speed, w, dt)


class SeeStrategy:
    """The see strategy of a mission: keeps the last scan's maps, replans on them with the
    rolling map laid over them, and drives each leg with a :class:`SeePilot`; it asks for a
    360-degree scan only when the rolling map shows no way on."""

    def __init__(self, mission: Mission) -> None:
        self.mission = mission
        self.job = mission.job
        self.app: App = mission.app
        self.cfg = mission.cfg
        self.p = self.cfg.see
        self.localiser = mission.loc
        self.max_plans = self.p.max_replans
        self.need_scan = True  # the see loop scans first, then only when the rolling map shows no way
        self.stalled = 0  # replans in a row after which the rover had not moved
        self.since_fix = 0.0  # metres driven since the rolling map was last matched on the global DEM
        self.fixed_at = 0  # the rolling map's frame count then: a fix matches and moves what came after
        self.bounds_fixed_at = 0  # the bounds map's frame count then: a fix moves what came after
        self.reapproached = False  # drove on once after a fix near the goal (closer)
        self.stats = LoopStats()
        # the mission's start and goal: the planning grid keeps them (and the blank ground between,
        # as a plan from the start would have it) so that it changes only where the maps grow
        self.cover = [(self.app.pose.x, self.app.pose.y), mission.goal]
        memory = MapMemory.covering(self.cover, self.p.memory, RollingParams().cell) if self.p.memory > 0 else None
        bounds = None
        if self.p.gate == "bounds":
            head = HeadCalibration.from_dict(self.app.config.get("head").as_dict())
            half = window_half(self.p, mission.rover.body(), head)
            bounds = BoundsMap.around(self.cover[0], half, GUIDE_CELL, self.p.bounds)
        self.driver = SeeingDriver(self.job, mission.rover, self.p, self.stats, memory, bounds)
        if bounds is not None and self.p.set_down == "ring":
            self.driver.set_down_pending = True  # (Chooser.drive_on: after the first look round)
        elif bounds is not None:
            # the rover was set down here: the ground round the mast's foot, which no tilt shows,
            # and the disc its body turns in are taken as clear, within 1 cm of level or (see_set_down
            # attitude) of the plane the rover's attitude says it stands on: the one place the chooser
            # assumes what it has not seen. Under the box the same assumption holds (a rock there
            # is not felt; the operators set the rover down where it can stand and turn); under
            # the wheels the attitude says more (BoundsMap.stood)
            x, y, heading = self.app.pose.x, self.app.pose.y, self.app.pose.heading
            z = ground_height(self.app.maps.layers, x, y)
            fx, fy, radius = self.driver.blind_disc()
            attitude = self.driver.attitude()
            plane = None if attitude is None else (x, y, *contact_plane(heading, attitude[0], attitude[1]))
            bounds.set_down((fx, fy), radius + BLIND_EDGE, z, plane=plane)
            bounds.set_down((x, y), self.driver.radius, z, plane=plane)
            # the wheels' own ground is known from the pose and the attitude, not assumed
            bounds.stood((x, y, heading), z, self.driver.body, attitude)
        head = self.app.config.get("head")
        # how far round the rover unseen ground cannot be seen before the body is on it: the
        # checked stretch plus the half body ahead of the rover's centre
        self.reach = self.p.blind + head.rover_length / 2
        self.strict = False  # the last plan kept the body to seen ground
        self.mast_foot: tuple[float, float, float] | None = None  # x, y, radius: the last scan's blind disc
        self.scan: Any = None  # NavMaps of the scans so far
        self.scan_frame = 0  # the rolling map's frame count at the last scan: older cells yield to the scan's
        self.looked: tuple[float, float] | None = None  # where the rover last looked round for a way
        self.fresh_scan = False  # no plan has been made since the last 360-degree scan
        self.why = ""  # why the last replan found no way
        self.last_end: tuple[float, float] | None = None
        self.search: Replanner | None = None  # D* Lite across replans (see_search dstar)
        # with the bounds map, the candidates' chooser plans every section (sections.py); it needs
        # no 360-degree scan (its map is what the ToF shows at the PTU's lowest tilt and while
        # driving), unless the localiser matches the scans
        self.chooser = Chooser(self) if bounds is not None else None
        if self.chooser is not None and not self.localiser.active:
            self.need_scan = False

    def set_down_on_ring(self) -> str:
        """``see_set_down ring``, after the first look round: what the rover knows of the ground it
        was set down on that no frame shows, each part from what shows it
        (:func:`prox_workflows.algorithms.set_down.set_down`): the wheels' contacts from the pose
        and the IMU, the disc the body turns in on their plane, the rest of the mast's blind disc
        on the ring's plane within the ring's own spread. Returns what it took."""
        d = self.driver
        x, y, heading = d.pose()
        said = set_down(d.bounds, (x, y, heading), d.datum(x, y), d.body, d.imu(), d.blind_disc(), d.radius,
                        BLIND_EDGE, RING_WIDTH)
        d.set_down_pending = False
        return said

    def arrived(self, left: float) -> bool:
        """The goal is within the tolerance by the believed pose: an arrival on dead reckoning
        is checked by the loop's own map match first, and a fix that moved the pose far from the
        goal drives on once (:meth:`closer`)."""
        checked = self.localiser.wants_fix(self.app.pose) and self.localiser.uses_map
        return not checked and not self.closer(left)

    def drive_on(self, leg: int) -> bool:
        """Replan from the scans and the rolling map and drive; False: a 360-degree scan first."""
        if self.need_scan:
            return False
        if self.chooser is not None:
            return self.chooser.drive_on(leg)
        pose = self.app.pose
        plan = self.replan(leg)
        if plan is not None:
            self.mission.record(plan.path[: plan.cut], plan.waypoints.xy)
            before = (pose.x, pose.y)
            self.drive_leg(leg, plan)
            moved = math.hypot(self.app.pose.x - before[0], self.app.pose.y - before[1]) >= self.cfg.min_progress
            self.stalled = 0 if moved else self.stalled + 1
            if self.stalled >= 3:  # replans that drive nowhere (stopped at once, or no way the body fits)
                self.stalled = 0
                self.need_scan = True
            return True
        if self.fresh_scan:  # the 360-degree scan just made shows no way either
            raise ProtocolError("E_DATA", f"no way on from ({pose.x:.2f}, {pose.y:.2f}) after a 360-degree scan: "
                                          f"{self.why}")
        self.need_scan = True  # the rolling map shows no way: scan 360 degrees from here
        return False

    def scanned(self, leg: int, local: Any) -> None:
        """A 360-degree scan made the maps ``local`` (the scans so far, merged): the next plan is
        made from them and what the rover sees next."""
        self.need_scan = False
        self.scan = local
        if self.chooser is not None:
            self.chooser.scanned()
        self.mast_foot = self.driver.blind_disc()
        self.scan_frame = self.driver.map.frames
        self.stats.scans += 1
        self.fresh_scan = True

    def merged(self) -> Any:
        """The scan maps with what the rolling map has seen since laid over them (all it saw in
        the mission, with its memory)."""
        from prox_workflows.algorithms.rolling_map import merge_nav_maps

        m = self.driver.map
        if m.frames == 0:
            return self.scan
        m.remember()
        seen = m if m.memory is None else m.memory
        return merge_nav_maps(self.scan, seen.nav_maps(), seen.stamp <= self.scan_frame)

    def replan(self, leg: int) -> Any:
        """A plan from the rover's believed pose on the merged maps (D* Lite repairing the
        mission's last search, or A*; timed); None when that shows no way to drive (then
        navigate scans).

        Before giving up, the rover looks: three forward ToF frames panned toward the goal (a
        few seconds of PTU motion) often show the way a 360-degree scan (half a minute) would,
        when the way on lies outside the forward view (round an obstacle, the goal behind)."""
        pose = self.app.pose
        goal = self.mission.goal
        plan, why = self._plan()
        if plan is None and self.looked != (round(pose.x, 1), round(pose.y, 1)):
            self.looked = (round(pose.x, 1), round(pose.y, 1))
            bearing = math.degrees(math.atan2(goal[1] - pose.y, goal[0] - pose.x)) - pose.heading
            self.job.progress(0, 1, f"{why}; looking toward the goal", phase="plan", leg=leg)
            self.driver.look((bearing + 180.0) % 360.0 - 180.0)
            plan, why = self._plan()
        self.why = why
        if plan is None:  # fresh_scan stays: navigate ends the job when the scan just made shows no way either
            if not self.fresh_scan:
                self.job.progress(0, 1, f"{why}; scanning 360 degrees", phase="plan", leg=leg)
            return None
        self.fresh_scan = False
        self.stats.replans += 1
        return plan

    def _plan(self) -> tuple[Any, str]:
        """(plan, "") or (None, why there is none) on the merged maps."""
        from prox_workflows.algorithms.planner import MIN_LEG, PlanningError, plan_path

        pose = self.app.pose
        here = (pose.x, pose.y)
        goal, global_maps = self.mission.goal, self.mission.global_maps
        params = dataclasses.replace(self.mission.params, border=min(self.mission.params.border, self.p.border))
        if self.search is None and self.p.search == "dstar":
            self.search = Replanner(params.heuristic, params.weight)
        t0, c0 = time.monotonic(), time.process_time()
        # the ground round the mast's foot that no tilt shows is taken as seen after a scan there
        # (the rover stands where it drove, or was set down); the check counts it too
        merged = self.merged()
        if self.mast_foot is not None and self.p.unseen != "off":
            merged = mark_unseen(merged, self.mast_foot[:2], 0.0, self.mast_foot[2], SAFE)
        self.driver.known = merged

        def attempt(maps: NavMaps) -> Any:
            try:
                return plan_path(maps, global_maps, here, goal, params, start_heading=pose.heading,
                                 search=self.search, cover=self.cover)
            except PlanningError as exc:
                # as navigate's scan legs do: a stand-in within the tolerance, or from farther
                # than judge_range a point toward the goal, to judge it again from closer
                toward = goal_stand_in(maps, global_maps, here, goal, params, exc,
                                       math.hypot(goal[0] - here[0], goal[1] - here[1]), self.cfg)
                if toward is None:
                    raise
                return plan_path(maps, global_maps, here, toward, params, start_heading=pose.heading,
                                 search=self.search, cover=self.cover)

        # Ground no map has seen within reach of the rover is kept out of the plan as a rock is,
        # but for the body's own disc (it stands there). A 360-degree scan just made has shown all
        # that can be seen from here: what it left unseen so close is the blind ground round the
        # mast, and then the plan may cross it, as it must to leave.
        keep = self.p.unseen == "keep" and self.p.blind > 0
        tries = ([True] if keep else []) + ([False] if self.fresh_scan or not keep else [])
        why = ""
        try:
            for strict in tries:
                maps = mark_unseen(merged, here, self.driver.radius, self.reach, HAZARDOUS) if strict else merged
                try:
                    plan = attempt(maps)
                except PlanningError as exc:
                    why = f"replan from the rolling map: {exc.reason}"
                    continue
                driven = plan.path[: plan.cut]
                if len(plan.waypoints) < 2 or math.hypot(*(driven[-1] - driven[0])) < max(MIN_LEG, 0.1):
                    why = "the rolling map shows no way on"
                    continue
                self.strict = strict
                return plan, ""
            return None, why
        finally:
            self.stats.replanned(t0, c0)

    def drive_leg(self, leg: int, plan: Any) -> None:
        """Drive one leg's waypoints while seeing (the simulated rover steers by its odometry,
        which is the pose afterwards; the GNC's pose reports are the cycles)."""
        mission, driver = self.mission, self.driver
        segments = len(plan.waypoints) - 1
        end = (float(plan.waypoints.xy[-1][0]), float(plan.waypoints.xy[-1][1]))

        def progress(done: int, total: int, message: str, phase: str = "") -> None:
            mission.progress(leg, done, total, message, phase)

        progress(1, 1, f"planned from the scan and the rolling map: {segments} segments to ({end[0]:.2f}, "
                       f"{end[1]:.2f})", "plan")
        since = mission.announce(leg, plan.waypoints, "none")
        progress(0, segments, f"driving {segments} segments to ({end[0]:.2f}, {end[1]:.2f}) while seeing", "drive")
        start_of_leg = len(mission.track)
        extends = self.last_end is None or math.hypot(end[0] - self.last_end[0], end[1] - self.last_end[1]) > 0.25
        self.last_end = end
        pilot = SeePilot(driver, plan.waypoints.xy, progress, mission.track,
                         allow_ahead=extends and not plan.reaches_goal, strict=self.strict)
        driver.point_forward()
        stopped = mission.drive(pilot, since, end)
        outcome = pilot.outcome
        if outcome is None:  # the GNC stood still: wherever it is, the leg is over
            if pilot.hazard is None:
                progress(segments, segments, f"rover stopped at ({stopped[0]:.2f}, {stopped[1]:.2f})", "drive")
            outcome = DriveOutcome("done", segments) if pilot.hazard is None else \
                DriveOutcome("hazard", pilot.k - 1, pilot.hazard)
        if outcome.kind in ("hazard", "unseen", "stalled"):  # the next leg replans from here
            self.last_end = None
        self.localise(leg, mission.track.xy(start_of_leg))

    def localise(self, leg: int, driven: np.ndarray) -> None:
        """Dead reckoning's sigma grows with the leg, whatever -localise says. With ``map`` or
        ``both``, every ``see_localise_every`` metres and after every leg closer than that to the
        goal, what the rolling map saw since the last fix is matched on the global DEM, and a
        fix moves the pose and that part of the map with it (those frames were placed with the
        pose that drifted; earlier ones with a pose the last fix already corrected), and the
        same part of the bounds map the chooser decides on. The see
        loop's scans are matched as the scan loop's legs are.

        On arriving (the goal within the tolerance by the believed pose) the rover first looks
        round standing and only what that look saw is matched: frames taken while driving were
        placed along a pose that drifted frame by frame, and their match says where the strip
        lies on average, a decimetre or more from where the rover stands after two metres of
        slip; frames taken at one pose share one error, which the match measures whole. Where the
        look shows too little relief to match, the strip is matched as on the way."""
        loc = self.localiser
        dist = loc.after_drive(self.job, driven)
        if not loc.uses_map:
            return
        self.since_fix += dist
        p = self.app.pose
        left = math.hypot(self.mission.goal[0] - p.x, self.mission.goal[1] - p.y)
        # near the goal every leg ends with a fix: the last approach and the arrival are judged
        # on a fresh one, not on the drift of the last few metres
        near = left <= self.p.localise_every
        if self.since_fix < self.p.localise_every and not (near and loc.grown > 0):
            return
        m = self.driver.map
        fix = None
        if left <= self.cfg.tolerance:
            first = m.frames
            self.driver.look(0.0, spread=self.p.arrival_spread)
            fix = loc.while_seeing(self.job, leg, m.since(first), m.geometry, standing=True)
        if fix is None:  # on the way, or the look alone shows too little relief to match
            fix = loc.while_seeing(self.job, leg, m.since(self.fixed_at), m.geometry)
        if fix is not None:
            m.move((p.x, p.y), *fix, since=self.fixed_at)
            self.since_fix, self.fixed_at = 0.0, m.frames
            bounds = self.driver.bounds
            if bounds is not None:  # the chooser's map: its frames were placed with the same pose
                bounds.move((p.x, p.y), *fix, since=self.bounds_fixed_at)
                self.bounds_fixed_at = bounds.frames

    def closer(self, left: float) -> bool:
        """Whether to drive on although the goal is ``left`` metres away, within the tolerance:
        once, when a map fix has just moved the believed pose more than half the tolerance from
        the goal (the rover stopped on the goal by its drifted pose; the fix says where it is,
        and the tolerance would otherwise absorb the matcher's error on top of that)."""
        if self.reapproached or not self.localiser.uses_map or self.app.pose.source != "map":
            return False
        self.reapproached = left > self.cfg.tolerance / 2
        return self.reapproached

    def fields(self) -> dict[str, Any]:
        """The OK line's keys of the see loop."""
        searched = {"searches": self.search.searches, "repairs": self.search.repairs} if self.search else {}
        return {**self.stats.fields(), "scans": self.mission.scans, "search": self.p.search, **searched}
