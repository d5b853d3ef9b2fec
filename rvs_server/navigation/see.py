"""Drive while seeing (issue 12, item 2): the rover drives a leg in cycles (the simulated rover
with -auto; the GNC otherwise, each pose it reports while driving being a cycle); each cycle
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

Kept out of navigation.py so that the scan-only loop there stays as it was, and the two can be
compared side by side (``python -m tools.bench.navigate``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from drivers.tof.constants import FOV_V_DEG
from prox_workflows.steps.arcs import arc_poses
from prox_workflows.steps.dem2hazard import HAZARDOUS, SAFE
from prox_workflows.steps.hazard_monitor import rover_points
from prox_workflows.steps.planner import NavMaps
from prox_workflows.steps.replan import Replanner
from prox_workflows.steps.rolling_map import (
    MapMemory,
    RollingMap,
    RollingParams,
    mark_unseen,
    path_poses,
    sweep_check,
)
from prox_workflows.steps.safety import in_footprint
from prox_workflows.steps.transforms import HeadCalibration, T_global_from_rover

from .commands.awareness import look_at
from .commands.hardware import device_call
from .commands.navigation import follow_rover, goal_stand_in, wait_for_rover
from .localisation import pose_fields
from .maps import ground_height
from .protocol import Fixed, Reply, Rows

if TYPE_CHECKING:
    from .app import App
    from .jobs import Job
    from .localisation import Localiser


STALL_CYCLES = 20  # a leg driven this many cycles without getting STALL_PROGRESS closer to its end is stalled
STALL_PROGRESS = 0.05  # m


@dataclass
class LoopStats:
    """What the see loop did in one navigate: reported in its OK line and read by the benchmark."""

    scans: int = 0
    replans: int = 0
    stops: int = 0
    looks: int = 0  # frames taken standing at unseen ground ahead (see_unseen)
    cycles: int = 0
    cycle_ms: list[float] = field(default_factory=list)  # rolling map + hazard + check, wall ms
    frame_ms: list[float] = field(default_factory=list)  # the ToF frame (the simulator's render), wall ms
    replan_ms: list[float] = field(default_factory=list)  # A* on the merged maps, wall ms

    def fields(self) -> dict[str, Any]:
        """The OK line's keys."""
        def mean(v: list[float]) -> float:
            return float(np.mean(v)) if v else 0.0

        return {"scans": self.scans, "replans": self.replans, "stops": self.stops, "looks": self.looks,
                "cycles": self.cycles,
                "cycle_ms": Fixed(mean(self.cycle_ms), 1),
                "cycle_ms_max": Fixed(max(self.cycle_ms, default=0.0), 1),
                "frame_ms": Fixed(mean(self.frame_ms), 1), "replan_ms": Fixed(mean(self.replan_ms), 1)}


@dataclass
class SeeParams:
    """The see loop's settings (navigate's config declares them, with units and ranges)."""

    period: float
    lookahead: float
    stop_distance: float
    tilt: float
    subsample: int
    max_range: float
    margin: float
    replan_ahead: float
    pursuit: float  # m: the point of the path the rover steers at lies this far ahead
    arc_turn: float  # deg: a larger heading error is turned on the spot, a smaller one driven as an arc
    blind: float = 0.0  # m of path ahead whose sweep is to lie on seen ground
    unseen: str = "off"  # what the rover does about unseen ground there: off | look | keep (navigate.see_unseen)
    auto: bool = True  # the simulated rover drives (odometry is the pose); False: the GNC drives and reports pose


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

    def __init__(self, job: Job, params: SeeParams, stats: LoopStats, memory: MapMemory | None = None) -> None:
        self.job = job
        self.app: App = job.app
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

    def pose(self) -> tuple[float, float, float]:
        """The rover's belief: the simulated rover's odometry while it drives itself, else the
        GNC's last pose report."""
        if self.p.auto:
            return self.app.world.odometry()
        p = self.app.pose
        return p.x, p.y, p.heading

    def see(self, pan_tilt: tuple[float, float]) -> tuple[tuple[float, float, float], float]:
        """One ToF frame into the rolling map; returns the rover's pose and the wall time
        (monotonic) the fusion started."""
        job, app = self.job, self.app
        t0 = time.monotonic()
        xyz, amplitude = device_call(job, app.devices.get("tof").grab_xyz, 1, 0.0)
        t1 = time.monotonic()
        x, y, heading = self.pose()
        T_rc = self.head.T_rover_from_sensor("tof", *pan_tilt)
        pts = rover_points(xyz, T_rc, self.p.subsample, self.p.max_range, amplitude, 0.1)
        ranges = np.linalg.norm(pts - T_rc[:3, 3].astype(np.float32), axis=1)
        z = self.map.ground_height(x, y)
        T = T_global_from_rover(x, y, heading, ground_height(app.maps.layers, x, y) if z is None else z)
        world_pts = pts.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
        self.map.follow(x, y)
        self.map.fuse(world_pts, ranges)
        self.stats.frame_ms.append((t1 - t0) * 1000)
        return (x, y, heading), t1

    def cycle(self, remaining: np.ndarray) -> tuple[Any, Any, tuple[float, float, float]]:
        """One frame into the rolling map and the check of the next metres; returns the check,
        the unseen check (:meth:`judge`) and the pose."""
        pose, t1 = self.see(self.pan_tilt)
        check, unseen = self.judge(pose, remaining)
        self.stats.cycles += 1
        self.stats.cycle_ms.append((time.monotonic() - t1) * 1000)
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
        bx, by, bz = self.head.ptu_base
        radius = (bz + self.head.tilt_offset) / math.tan(math.radians(FOV_V_DEG / 2 - self._lowest_tilt()))
        c, s = math.cos(math.radians(heading)), math.sin(math.radians(heading))
        return x + bx * c - by * s, y + bx * s + by * c, radius

    def look_at(self, x: float, y: float, pose: tuple[float, float, float]) -> bool:
        """One frame, standing, toward ground point (x, y), tilted to it but no lower than the PTU
        goes: the frame then shows the ground along that bearing from the mast's blind disc out
        (:meth:`blind_disc`), which holds the point unless it lies inside that disc. False (no
        frame) when the rover looked from about here already: what that look did not show,
        another from the same place will not."""
        last = self.looked_from
        if last is not None and math.hypot(pose[0] - last[0], pose[1] - last[1]) < 0.3 and \
                abs((pose[2] - last[2] + 180.0) % 360.0 - 180.0) < 20.0:
            return False
        self.looked_from = pose
        self.stats.looks += 1
        self.job.progress(0, 1, f"looking at unseen ground ({x:.2f}, {y:.2f}) before driving onto it", phase="drive")
        pan, tilt = look_at(self.head, np.array([*_in_rover_frame(pose, x, y), 0.0]))
        self._point(max(-150.0, min(150.0, pan)), max(self._lowest_tilt(), min(self.p.tilt, tilt)))
        self.see(self.pan_tilt)
        self.job.check()
        return True

    def look(self, bearing: float, spread: float = 40.0) -> None:
        """Frames panned to ``bearing`` (deg from the rover's heading) and ``spread`` either side,
        the rover standing: the rolling map's view round the forward one."""
        for pan in (bearing - spread, bearing, bearing + spread):
            self._point(max(-150.0, min(150.0, pan)))
            self.see(self.pan_tilt)
            self.job.check()

    def drive(self, waypoints: np.ndarray, track: list[tuple[float, float, float]], progress: Any,
              allow_ahead: bool, strict: bool = True) -> DriveOutcome:
        """Drive ``waypoints`` (k x 2, the first is where the rover is) steering by odometry,
        checking every cycle. The rover steers at the point ``pursuit`` metres ahead on the path
        (pure pursuit): a heading error up to ``arc_turn`` is driven out as an arc at full speed
        when the turn rate allows that arc, a larger one is turned on the spot, so a replanned
        path or a waypoint's corner costs no stop (MER's and Perseverance's drive arcs; the
        stop-and-go loop turns on the spot at every waypoint). With ``allow_ahead`` the drive
        hands back ``ahead`` once the leg's end is ``replan_ahead`` away, so navigate extends the
        path from what the rolling map has seen, on the move. Ground no map has seen under the
        next ``blind`` metres (:meth:`judge`): the rover stops and looks at it; with ``strict``
        (the plan kept the body to seen ground) it ends the leg (``unseen``) when the look does
        not show it, else it drives on."""
        app, job = self.app, self.job
        world = app.world
        model = world.drive_model
        stop = job.cancel.is_set
        follow = follow_rover(app, track)
        self.point_forward()
        wps = np.asarray(waypoints, dtype=np.float64)[:, :2]
        segments = len(wps) - 1
        k = 1  # the waypoint the rover is heading for
        best, since_best = math.inf, 0  # the least path left to the leg's end, and cycles since

        with world.under_way():
            while True:
                pose, t1 = self.see(self.pan_tilt)
                job.check()
                while k <= segments and _passed(pose, wps[k - 1], wps[k]):
                    progress(k, segments, f"segment {k}/{segments} driven", "drive")
                    k += 1
                if k > segments:
                    return DriveOutcome("done", segments)
                nearest = _nearest_stretch(pose, wps, k)
                while k < nearest:
                    progress(k, segments, f"segment {k}/{segments} driven", "drive")
                    k += 1
                left = math.hypot(wps[k][0] - pose[0], wps[k][1] - pose[1])
                to_end = left + float(np.sum(np.hypot(*np.diff(wps[k:], axis=0).T)))
                if allow_ahead and to_end <= self.p.replan_ahead:
                    return DriveOutcome("ahead", k - 1)
                # a watchdog: steering that swings about a point it cannot settle on (10 cm forward,
                # a turn on the spot, 10 cm back: a marsyard mission did so for 5 simulated hours)
                # ends the leg, and navigate replans from where the rover is
                best, since_best = (to_end, 0) if to_end < best - STALL_PROGRESS else (best, since_best + 1)
                if since_best >= STALL_CYCLES:
                    progress(1, 1, f"stopped: {to_end:.2f} m from the leg's end, no closer in {STALL_CYCLES} "
                                   "cycles", "stop")
                    return DriveOutcome("stalled", k - 1)
                tx, ty = _pursuit_point(pose, wps, k, self.p.pursuit)
                w = arc_rate(pose, (tx, ty), model.speed, model.turn_rate, self.p.arc_turn)
                dt = min(self.p.period, to_end / model.speed)
                motion = motion_poses(pose, (tx, ty), w, model.speed, dt)
                check, unseen = self.judge(pose, wps[k:], motion)
                self.stats.cycles += 1
                self.stats.cycle_ms.append((time.monotonic() - t1) * 1000)
                if check.verdict == "not_traversable":
                    return DriveOutcome("hazard", k - 1, self._stop_event(check, pose))
                self._clear()
                # unseen ground ahead: the rover stops and looks (a turn on the spot comes first,
                # after which that ground lies ahead and the look is a tilt, not a pan)
                if unseen is not None and w is not None and self.look_at(unseen.worst_x, unseen.worst_y, pose):
                    check, unseen = self.judge(pose, wps[k:], motion)
                    self.point_forward()
                    if check.verdict == "not_traversable":
                        return DriveOutcome("hazard", k - 1, self._stop_event(check, pose))
                if unseen is not None and w is not None and strict:
                    progress(1, 1, f"stopped: ground {unseen.unknown_cells} cells under the next "
                                   f"{self.p.blind:g} m unseen", "stop")
                    return DriveOutcome("unseen", k - 1)
                if w is None:
                    world.turn_toward(tx, ty, stop, on_step=follow)
                else:
                    world.drive(model.speed, w, dt, stop, on_step=follow)
                job.check()
                world.record_track(track, 0.0, 0.0)

    def watch(self, waypoints: np.ndarray, track: list[tuple[float, float, float]], progress: Any, version: int,
              cfg: Any) -> DriveOutcome:
        """The GNC drives ``waypoints`` and streams its pose: each report is a cycle (a forward
        frame fused at the reported pose, the footprint checked along the rest of the leg). A
        hazard in the corridor is an ``EVENT kind=hazard level=stop`` for the GNC to stop on;
        the leg ends once the GNC's pose stands still (wherever it is), and navigate replans from
        there. Frames are taken at pose reports because a frame is only placed in the map at a
        known pose."""
        self.point_forward()
        wps = np.asarray(waypoints, dtype=np.float64)[:, :2]
        segments = len(wps) - 1
        end = (float(wps[-1][0]), float(wps[-1][1]))
        k = 1  # the waypoint the rover is heading for
        hazard: dict[str, Any] | None = None

        def on_pose(p: Any) -> None:
            nonlocal k, hazard
            track.append((p.x, p.y, p.heading))
            while k < segments and _passed((p.x, p.y, p.heading), wps[k - 1], wps[k]):
                progress(k, segments, f"segment {k}/{segments} driven", "drive")
                k += 1
            check, _, pose = self.cycle(wps[k:])
            if check.verdict == "not_traversable":
                if hazard is None:  # once per leg: the GNC is stopping
                    hazard = self._stop_event(check, pose)
            elif hazard is None:
                self._clear()

        arrived = wait_for_rover(self.app, self.job, version, end, cfg, on_pose)
        track.append((arrived.x, arrived.y, arrived.heading))
        if hazard is not None:
            return DriveOutcome("hazard", k - 1, hazard)
        progress(segments, segments, f"rover stopped at ({arrived.x:.2f}, {arrived.y:.2f})", "drive")
        return DriveOutcome("done", segments)

    def _stop_event(self, check: Any, pose: tuple[float, float, float]) -> dict[str, Any]:
        """The stop EVENT, shaped as the hazard monitor's (distance from the rover's front to the
        hazard, bearing CCW from the heading, x and y in the rover frame)."""
        rx, ry = _in_rover_frame(pose, check.worst_x, check.worst_y)
        distance = max(0.0, rx - self.app.config.get("head").rover_length / 2 - self.map.params.cell / 2)
        self.stats.stops += 1
        fields = {"kind": "hazard", "level": "stop", "distance": Fixed(distance, 2),
                  "bearing": Fixed(math.degrees(math.atan2(ry, rx)), 1), "x": Fixed(rx, 2), "y": Fixed(ry, 2),
                  "seen": "true", "cycle": self.stats.cycles, "job": self.job.id, "source": "navigate"}
        self.level = "stop"
        self.app.broadcast_threadsafe(Reply("RVS", "EVENT", fields))
        return {"distance": distance, "x": rx, "y": ry}

    def _clear(self) -> None:
        if self.level != "clear":
            self.level = "clear"
            self.app.broadcast_threadsafe(Reply("RVS", "EVENT", {
                "kind": "hazard", "level": "clear", "cycle": self.stats.cycles, "job": self.job.id,
                "source": "navigate"}))


class SeeLoop:
    """navigate's side of the see loop: keeps the last scan's maps, replans on them with the
    rolling map laid over them, and drives each leg with :class:`SeeingDriver`."""

    def __init__(self, job: Job, cfg: Any, localiser: Localiser) -> None:
        self.job = job
        self.app: App = job.app
        self.cfg = cfg
        self.localiser = localiser
        self.since_fix = 0.0  # metres driven since the rolling map was last matched on the global DEM
        self.fixed_at = 0  # the rolling map's frame count then: a fix matches and moves what came after
        self.reapproached = False  # drove on once after a fix near the goal (closer)
        self.stats = LoopStats()
        # the mission's start and goal: the planning grid keeps them (and the blank ground between,
        # as a plan from the start would have it) so that it changes only where the maps grow
        self.cover = [(self.app.pose.x, self.app.pose.y), (cfg.goal[0], cfg.goal[1])]
        memory = MapMemory.covering(self.cover, cfg.see_memory, RollingParams().cell) if cfg.see_memory > 0 else None
        self.driver = SeeingDriver(job, SeeParams(
            period=cfg.see_period, lookahead=cfg.see_lookahead, stop_distance=0.0, tilt=cfg.see_tilt,
            subsample=cfg.see_subsample, max_range=cfg.see_max_range, margin=cfg.see_margin,
            replan_ahead=cfg.replan_ahead, pursuit=cfg.see_pursuit, arc_turn=cfg.see_arc_turn, blind=cfg.see_blind,
            unseen=cfg.see_unseen, auto=cfg.auto), self.stats, memory)
        head = self.app.config.get("head")
        # how far round the rover unseen ground cannot be seen before the body is on it: the
        # checked stretch plus the half body ahead of the rover's centre
        self.reach = cfg.see_blind + head.rover_length / 2
        self.strict = False  # the last plan kept the body to seen ground
        self.mast_foot: tuple[float, float, float] | None = None  # x, y, radius: the last scan's blind disc
        self.scan: Any = None  # NavMaps of the scans so far
        self.scan_frame = 0  # the rolling map's frame count at the last scan: older cells yield to the scan's
        self.looked: tuple[float, float] | None = None  # where the rover last looked round for a way
        self.fresh_scan = False  # no plan has been made since the last 360-degree scan
        self.why = ""  # why the last replan found no way
        self.last_end: tuple[float, float] | None = None
        self.search: Replanner | None = None  # D* Lite across replans (see_search dstar)

    def scanned(self, local: Any) -> None:
        """A 360-degree scan made the maps ``local`` (the scans so far, merged)."""
        self.scan = local
        self.mast_foot = self.driver.blind_disc()
        self.scan_frame = self.driver.map.frames
        self.stats.scans += 1
        self.fresh_scan = True

    def merged(self) -> Any:
        """The scan maps with what the rolling map has seen since laid over them (all it saw in
        the mission, with its memory)."""
        from prox_workflows.steps.rolling_map import merge_nav_maps

        m = self.driver.map
        if m.frames == 0:
            return self.scan
        m.remember()
        seen = m if m.memory is None else m.memory
        return merge_nav_maps(self.scan, seen.nav_maps(), seen.stamp <= self.scan_frame)

    def replan(self, leg: int, global_maps: Any, goal: tuple[float, float], params: Any) -> Any:
        """A plan from the rover's believed pose on the merged maps (D* Lite repairing the
        mission's last search, or A*; timed); None when that shows no way to drive (then
        navigate scans).

        Before giving up, the rover looks: three forward ToF frames panned toward the goal (a
        few seconds of PTU motion) often show the way a 360-degree scan (half a minute) would,
        when the way on lies outside the forward view (round an obstacle, the goal behind)."""
        pose = self.app.pose
        plan, why = self._plan(global_maps, goal, params)
        if plan is None and self.looked != (round(pose.x, 1), round(pose.y, 1)):
            self.looked = (round(pose.x, 1), round(pose.y, 1))
            bearing = math.degrees(math.atan2(goal[1] - pose.y, goal[0] - pose.x)) - pose.heading
            self.job.progress(0, 1, f"{why}; looking toward the goal", phase="plan", leg=leg)
            self.driver.look((bearing + 180.0) % 360.0 - 180.0)
            plan, why = self._plan(global_maps, goal, params)
        self.why = why
        if plan is None:  # fresh_scan stays: navigate ends the job when the scan just made shows no way either
            if not self.fresh_scan:
                self.job.progress(0, 1, f"{why}; scanning 360 degrees", phase="plan", leg=leg)
            return None
        self.fresh_scan = False
        self.stats.replans += 1
        return plan

    def _plan(self, global_maps: Any, goal: tuple[float, float], params: Any) -> tuple[Any, str]:
        """(plan, "") or (None, why there is none) on the merged maps."""
        from prox_workflows.steps.planner import MIN_LEG, PlanningError, plan_path

        pose = self.app.pose
        here = (pose.x, pose.y)
        params = dataclasses.replace(params, border=min(params.border, self.cfg.see_border))
        if self.search is None and self.cfg.see_search == "dstar":
            self.search = Replanner(params.heuristic, params.weight)
        t0 = time.monotonic()
        # the ground round the mast's foot that no tilt shows is taken as seen after a scan there
        # (the rover stands where it drove, or was set down); the check counts it too
        merged = self.merged()
        if self.mast_foot is not None and self.cfg.see_unseen != "off":
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
        keep = self.cfg.see_unseen == "keep" and self.cfg.see_blind > 0
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
            self.stats.replan_ms.append((time.monotonic() - t0) * 1000)

    def drive_leg(self, leg: int, plan: Any, track: list[tuple[float, float, float]]) -> None:
        """Drive one leg's waypoints while seeing (the simulated rover with -auto: the pose is its
        odometry afterwards; else the GNC, whose pose reports are the cycles)."""
        job, app = self.job, self.app
        version = app.pose_version  # before the event: a GNC may answer it at once
        segments = len(plan.waypoints) - 1
        end = (float(plan.waypoints.xy[-1][0]), float(plan.waypoints.xy[-1][1]))

        def progress(done: int, total: int, message: str, phase: str = "") -> None:
            job.progress(done, total, message, phase=phase, leg=leg)

        progress(1, 1, f"planned from the scan and the rolling map: {segments} segments to ({end[0]:.2f}, "
                       f"{end[1]:.2f})", "plan")
        rows = [(Fixed(x, 3), Fixed(y, 3), Fixed(h, 2)) for x, y, h in plan.waypoints.table()[:, :3]]
        app.broadcast_threadsafe(Reply("RVS", "EVENT", {
            "kind": "waiting", "job": job.id, "leg": leg, "waypoints": Rows(rows), "file": "none", **pose_fields(job)}))
        progress(0, segments, f"driving {segments} segments to ({end[0]:.2f}, {end[1]:.2f}) while seeing", "drive")
        start_of_leg = len(track)
        extends = self.last_end is None or math.hypot(end[0] - self.last_end[0], end[1] - self.last_end[1]) > 0.25
        self.last_end = end
        if not self.cfg.auto:
            outcome = self.driver.watch(plan.waypoints.xy, track, progress, version, self.cfg)
        else:
            try:
                outcome = self.driver.drive(plan.waypoints.xy, track, progress,
                                            allow_ahead=extends and not plan.reaches_goal, strict=self.strict)
            finally:  # a break too leaves the pose where the rover's odometry says it stopped
                odo = app.world.odometry()
                app.set_pose(odo[0], odo[1], odo[2], source="odometry")
        if outcome.kind in ("hazard", "unseen", "stalled"):  # the next leg replans from here
            self.last_end = None
        self.localise(leg, track[start_of_leg:])

    def localise(self, leg: int, driven: list[tuple[float, float, float]]) -> None:
        """Dead reckoning's sigma grows with the leg, whatever -localise says. With ``map`` or
        ``both``, every ``see_localise_every`` metres and after every leg closer than that to the
        goal, what the rolling map saw since the last fix is matched on the global DEM, and a
        fix moves the pose and that part of the map with it (those frames were placed with the
        pose that drifted; earlier ones with a pose the last fix already corrected). The see
        loop's scans are matched as the scan loop's legs are.

        On arriving (the goal within the tolerance by the believed pose) the rover first looks
        round standing and only what that look saw is matched: frames taken while driving were
        placed along a pose that drifted frame by frame, and their match says where the strip
        lies on average, a decimetre or more from where the rover stands after two metres of
        slip; frames taken at one pose share one error, which the match measures whole. Where the
        look shows too little relief to match, the strip is matched as on the way."""
        loc = self.localiser
        dist = loc.after_drive(self.job, np.asarray(driven).reshape(-1, 3)[:, :2])
        if not loc.uses_map:
            return
        self.since_fix += dist
        p = self.app.pose
        left = math.hypot(self.cfg.goal[0] - p.x, self.cfg.goal[1] - p.y)
        # near the goal every leg ends with a fix: the last approach and the arrival are judged
        # on a fresh one, not on the drift of the last few metres
        near = left <= self.cfg.see_localise_every
        if self.since_fix < self.cfg.see_localise_every and not (near and loc.grown > 0):
            return
        m = self.driver.map
        fix = None
        if left <= self.cfg.tolerance:
            first = m.frames
            self.driver.look(0.0, spread=self.cfg.see_arrival_spread)
            fix = loc.while_seeing(self.job, leg, m.since(first), m.geometry, standing=True)
        if fix is None:  # on the way, or the look alone shows too little relief to match
            fix = loc.while_seeing(self.job, leg, m.since(self.fixed_at), m.geometry)
        if fix is not None:
            m.move((p.x, p.y), *fix, since=self.fixed_at)
            self.since_fix, self.fixed_at = 0.0, m.frames

    def closer(self, left: float) -> bool:
        """Whether to drive on although the goal is ``left`` metres away, within the tolerance:
        once, when a map fix has just moved the believed pose more than half the tolerance from
        the goal (the rover stopped on the goal by its drifted pose; the fix says where it is,
        and the tolerance would otherwise absorb the matcher's error on top of that)."""
        if self.reapproached or not self.localiser.uses_map or self.app.pose.source != "map":
            return False
        self.reapproached = left > self.cfg.tolerance / 2
        return self.reapproached

    def stats_fields(self, scans: int) -> dict[str, Any]:
        """The OK line's keys of the see loop."""
        searched = {"searches": self.search.searches, "repairs": self.search.repairs} if self.search else {}
        return {**self.stats.fields(), "scans": scans, "search": self.cfg.see_search, **searched}


def start(job: Job, cfg: Any, localiser: Localiser) -> SeeLoop:
    """The see loop of one navigate -loop see."""
    return SeeLoop(job, cfg, localiser)


def arc_rate(pose: tuple[float, float, float], target: tuple[float, float], speed: float, turn_rate: float,
             arc_turn: float) -> float | None:
    """Pure pursuit: the turn rate (deg/s) of the arc at ``speed`` from ``pose`` through
    ``target``, or None when the heading error is turned on the spot instead: above
    ``arc_turn``, or when that arc is tighter than ``turn_rate`` allows. A capped arc would
    swing wide of the path, over ground neither the plan nor the check looked at (with the
    body footprint hugging rocks in hirise, onto them)."""
    dx, dy = target[0] - pose[0], target[1] - pose[1]
    error = (math.degrees(math.atan2(dy, dx)) - pose[2] + 180.0) % 360.0 - 180.0
    w = math.degrees(speed * 2.0 * math.sin(math.radians(error)) / max(math.hypot(dx, dy), 1e-6))
    return None if abs(error) > arc_turn or abs(w) > turn_rate else w


def motion_poses(pose: tuple[float, float, float], target: tuple[float, float], w: float | None, speed: float,
                 dt: float) -> np.ndarray:
    """The poses the rover passes through in one cycle of :meth:`SeeingDriver.drive`: the arc at
    turn rate ``w`` (deg/s, :func:`arc_rate`) for ``dt`` seconds at ``speed``, or, with ``w``
    None, the turn on the spot to face ``target`` (its two end poses; the check sweeps the turn
    between them in 5-degree steps)."""
    if w is None:
        bearing = math.degrees(math.atan2(target[1] - pose[1], target[0] - pose[0]))
        turn = (bearing - pose[2] + 180.0) % 360.0 - 180.0
        return np.array([pose, (pose[0], pose[1], pose[2] + turn)], dtype=np.float64)
    return arc_poses(pose, math.radians(w) / speed, speed * max(dt, 0.0), step=0.05)


def _in_rover_frame(pose: tuple[float, float, float], x: float, y: float) -> tuple[float, float]:
    """Global (x, y) in the frame of the rover at ``pose`` (x forward, y left)."""
    c, s = math.cos(math.radians(pose[2])), math.sin(math.radians(pose[2]))
    dx, dy = x - pose[0], y - pose[1]
    return dx * c + dy * s, -dx * s + dy * c


def _passed(pose: tuple[float, float, float], a: np.ndarray, b: np.ndarray, reach: float = 0.02) -> bool:
    """Whether the rover (by odometry) has reached waypoint ``b`` of the stretch a-b: within
    ``reach`` of it, or past the line through it square to the stretch."""
    dx, dy = float(b[0] - a[0]), float(b[1] - a[1])
    px, py = pose[0] - float(b[0]), pose[1] - float(b[1])
    if math.hypot(px, py) <= reach:
        return True
    return (dx != 0.0 or dy != 0.0) and dx * px + dy * py >= 0.0


def _nearest_stretch(pose: tuple[float, float, float], wps: np.ndarray, k: int, window: int = 3) -> int:
    """The waypoint ending the stretch nearest the rover among k-1..k and the next ones (the
    earliest of equals). :func:`_passed` alone leaves the rover on a short side stretch it drove
    beside without crossing the line square to its end; pursuit from the foot on that stretch
    aims behind the rover, which then turns about and drives where no check has looked."""
    here = np.asarray(pose[:2], dtype=np.float64)
    best, best_j = math.inf, k
    for j in range(k, min(k + window, len(wps))):
        a, b = wps[j - 1], wps[j]
        ab = b - a
        n = float(ab @ ab)
        t = 0.0 if n == 0.0 else min(1.0, max(0.0, float((here - a) @ ab) / n))
        d = float(np.hypot(*(a + t * ab - here)))
        if d < best - 1e-9:
            best, best_j = d, j
    return best_j


def _pursuit_point(pose: tuple[float, float, float], wps: np.ndarray, k: int, ahead: float) -> tuple[float, float]:
    """The point ``ahead`` metres along the path from the rover's foot on stretch k-1..k (the
    last waypoint when the path is shorter)."""
    a, b = wps[k - 1], wps[k]
    ab = b - a
    n = float(ab @ ab)
    t = 0.0 if n == 0.0 else min(1.0, max(0.0, float((np.array(pose[:2]) - a) @ ab) / n))
    here = a + t * ab
    left = ahead
    for j in range(k, len(wps)):
        seg = wps[j] - here
        d = float(np.hypot(*seg))
        if d >= left:
            p = here + seg * (left / d)
            return float(p[0]), float(p[1])
        left -= d
        here = wps[j]
    return float(wps[-1][0]), float(wps[-1][1])
