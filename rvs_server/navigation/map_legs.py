"""The see loop's legs on the 5 cm maps (``see_gate off``): :class:`MapLegs` plans each leg on
the scans' maps with the rolling map laid over them, :class:`SeePilot` drives its waypoints by
pure pursuit, one frame and the check of the next metres a cycle, and stops on a hazard or
unseen ground ahead; :class:`DriveOutcome` says how the leg ended. With the bounds map
(``see_gate bounds``, the default) the chooser chooses and drives each section instead
(:mod:`.sections`)."""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from drivers.rover import Motion
from prox_workflows.algorithms.planner import NavMaps
from prox_workflows.algorithms.replan import Replanner
from prox_workflows.algorithms.rolling_map import mark_unseen
from rvs_params.hazard import HAZARDOUS, SAFE

from ..protocol import ProtocolError
from .planning import goal_stand_in
from .pursuit import arc_rate, motion_poses, nearest_stretch, passed, pursuit_point

if TYPE_CHECKING:
    from ..app import App
    from .see import SeeingDriver
    from .see_strategy import SeeStrategy

STALL_CYCLES = 20  # a leg driven this many cycles without getting STALL_PROGRESS closer to its end is stalled
STALL_PROGRESS = 0.05  # m


@dataclass
class DriveOutcome:
    """How a leg driven while seeing ended."""

    kind: str  # done (last waypoint reached) | hazard (stopped) | unseen (stopped: ground no map has seen
    # ahead, a look did not show it) | ahead (close to the leg's end: replan on the move) | stalled (the
    # rover got no closer to the leg's end for STALL_CYCLES cycles)
    segments_done: int
    hazard: dict[str, Any] | None = None



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


class MapLegs:
    """The see strategy's legs on the 5 cm maps (``see_gate off``): each planned from the
    rover's believed pose on the scans' maps with the rolling map laid over them (D* Lite
    repairing the mission's last search, or A*), and driven by a :class:`SeePilot`; the
    strategy is asked for a 360-degree scan (``need_scan``) only when the rolling map shows no
    way on, or when replans in a row drive nowhere."""

    def __init__(self, strategy: SeeStrategy) -> None:
        self.s = strategy
        self.mission = strategy.mission
        self.job = strategy.job
        self.app: App = strategy.app
        self.cfg = strategy.cfg
        self.p = strategy.p
        self.stats = strategy.stats
        self.driver = strategy.driver
        self.cover = strategy.cover
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
        self.stalled = 0  # replans in a row after which the rover had not moved

    def drive_on(self, leg: int) -> bool:
        """Replan from the scans and the rolling map and drive; False: a 360-degree scan first."""
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
                self.s.need_scan = True
            return True
        if self.fresh_scan:  # the 360-degree scan just made shows no way either
            raise ProtocolError("E_DATA", f"no way on from ({pose.x:.2f}, {pose.y:.2f}) after a 360-degree scan: "
                                          f"{self.why}")
        self.s.need_scan = True  # the rolling map shows no way: scan 360 degrees from here
        return False

    def scanned(self, local: Any) -> None:
        """A 360-degree scan made the maps ``local`` (the scans so far, merged): the next plan is
        made from them and what the rover sees next."""
        self.scan = local
        self.mast_foot = self.driver.blind_disc()
        self.scan_frame = self.driver.map.frames
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
                if plan.stands_still(max(MIN_LEG, 0.1)):
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
        self.s.localise(leg, mission.track.xy(start_of_leg))
