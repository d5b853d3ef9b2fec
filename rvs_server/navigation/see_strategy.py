"""The see strategy (``navigate -loop see``), drive while seeing: :class:`SeeStrategy` keeps for
one mission the seeing driver (:mod:`.see`), its maps and the localiser's fixes, and drives on
without a 360-degree scan while the maps show a way. With the bounds map (``see_gate bounds``,
the default) every section is chosen by the vehicle check itself, ENav's way (:mod:`.sections`);
with ``see_gate off`` each leg is planned on the scans' 5 cm maps with the rolling map laid over
them and driven by :class:`~.see_pilot.SeePilot`.

The scan strategy (:mod:`.scan`) and this one are driven by the same mission (:mod:`.mission`),
so the two compare side by side (``python -m tools.bench.navigate``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import TYPE_CHECKING, Any

import numpy as np

from prox_workflows.algorithms.bounds_map import BoundsMap, contact_plane
from prox_workflows.algorithms.planner import NavMaps
from prox_workflows.algorithms.replan import Replanner
from prox_workflows.algorithms.rolling_map import MapMemory, RollingParams, mark_unseen
from prox_workflows.algorithms.set_down import set_down
from prox_workflows.algorithms.transforms import HeadCalibration
from rvs_params.hazard import HAZARDOUS, SAFE

from ..maps import ground_height
from ..protocol import ProtocolError
from .loop_stats import LoopStats
from .planning import goal_stand_in
from .sections import GUIDE_CELL, Chooser, window_half
from .see import BLIND_EDGE, RING_WIDTH, SeeingDriver
from .see_pilot import DriveOutcome, SeePilot

if TYPE_CHECKING:
    from ..app import App
    from .mission import Mission


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
            bounds = BoundsMap.around(self.cover[0], half, GUIDE_CELL)
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
