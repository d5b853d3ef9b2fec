"""The see strategy (``navigate -loop see``), drive while seeing: :class:`SeeStrategy` keeps for
one mission the seeing driver (:mod:`.see`), its maps and the localiser's fixes, and drives on
without a 360-degree scan while the maps show a way. With the bounds map (``see_gate bounds``,
the default) every section is chosen by the vehicle check itself, ENav's way (:mod:`.sections`);
with ``see_gate off`` each leg is planned on the scans' 5 cm maps with the rolling map laid over
them (:class:`~.map_legs.MapLegs`).

It also drives the scan loop on the chooser (``navigate -loop scan -scan-plan chooser``): a
360-degree scan, then the chooser's sections until the rover stands ``navigate.scan_stretch``
from where it was made, then the next scan. The circle's scan strategy (:mod:`.scan`) and this
one are driven by the same mission (:mod:`.mission`), so the loops compare side by side
(``python -m tools.bench.navigate``).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from prox_workflows.algorithms.bounds_map import BoundsMap, contact_plane
from prox_workflows.algorithms.rolling_map import MapMemory, RollingParams
from prox_workflows.algorithms.set_down import set_down
from prox_workflows.algorithms.transforms import HeadCalibration

from ..maps import ground_height
from ..travel import KeptGround
from .loop_stats import LoopStats
from .map_legs import MapLegs
from .sections import GUIDE_CELL, Chooser, window_half
from .see import BLIND_EDGE, RING_WIDTH, SeeingDriver

if TYPE_CHECKING:
    from ..app import App
    from .mission import Mission


class SeeStrategy:
    """The see strategy of a mission: keeps the seeing driver and its maps, and drives on by the
    chooser's sections (:class:`~.sections.Chooser`) or the legs planned on the 5 cm maps
    (:class:`~.map_legs.MapLegs`); it asks for a 360-degree scan only when they show no way
    on (and, with the chooser, where the localiser matches the scans)."""

    def __init__(self, mission: Mission) -> None:
        self.mission = mission
        self.job = mission.job
        self.app: App = mission.app
        self.cfg = mission.cfg
        self.p = self.cfg.see
        self.localiser = mission.loc
        self.max_plans = self.p.max_replans
        self.need_scan = True  # the see loop scans first, then only when the rolling map shows no way
        # the scan loop on the chooser: a scan scan_stretch on from the last (the module's docstring)
        self.scan_loop = self.cfg.loop == "scan"
        self.scanned_at: tuple[float, float] | None = None  # where the last 360-degree scan was made
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
        # the settings a bounds map is made with: the next navigate takes this one's map only if
        # it would make it alike (and not where map fixes move its frames: the fixes' count is this job's)
        self.ground_key: tuple[Any, ...] | None = None
        self.kept = False  # the bounds map is the one the last navigate left
        # with that map, how far (m) the rover stands from where it was left (None: it still stands there)
        self.moved: float | None = None
        self.sets_down = False  # this navigate sets the rover down where it stands (below)
        if self.p.gate == "bounds" or self.scan_loop:
            head = HeadCalibration.from_dict(self.app.config.get("head").as_dict())
            half = window_half(self.p, mission.rover.body(), head)
            if not self.localiser.active:
                self.ground_key = (self.p.bounds, half, self.p.set_down)
                pose = self.app.pose
                here = (pose.x, pose.y, pose.heading)
                kept = self.app.travel.take(here, self.ground_key, self.p.keep_moved)
                if kept is not None:
                    bounds, self.kept = kept.bounds, True
                    self.moved = None if kept.still(here) else kept.moved(here)
            if bounds is None:
                bounds = BoundsMap.around(self.cover[0], half, GUIDE_CELL, self.p.bounds)
        self.driver = SeeingDriver(self.job, mission.rover, self.p, self.stats, memory, bounds)
        # a kept map where the rover still stands needs no set-down: the ground round it is what
        # the last navigate's frames saw and its wheels felt; moved since, it is set down again on
        # that map (the set-down fills only what no frame bounded)
        self.sets_down = bounds is not None and (not self.kept or self.moved is not None)
        if self.sets_down and self.p.set_down == "ring":
            self.driver.set_down_pending = True  # (Chooser.drive_on: after the first look round)
        elif self.sets_down:
            # the rover was set down here: the ground round the mast's foot, which no tilt shows,
            # and the disc its body turns in are taken as clear, within 1 cm of level or (see_set_down
            # attitude) of the plane the rover's attitude says it stands on: the one place the chooser
            # assumes what it has not seen. Under the box the same assumption holds (a rock there
            # is not felt; the operators set the rover down where it can stand and turn); under
            # the wheels the attitude says more (BoundsMap.stood)
            x, y, heading = self.app.pose.x, self.app.pose.y, self.app.pose.heading
            z = ground_height(self.app.maps.layers, x, y)
            fx, fy, radius = self.driver.blind_disc()
            attitude = self.driver.attitude(self.driver.imu())
            plane = None if attitude is None else (x, y, *contact_plane(heading, attitude[0], attitude[1]))
            bounds.set_down((fx, fy), radius + BLIND_EDGE, z, plane=plane)
            bounds.set_down((x, y), self.driver.radius, z, plane=plane)
            # the wheels' own ground is known from the pose and the attitude, not assumed
            bounds.stood((x, y, heading), z, self.driver.body, attitude)
        # with the bounds map, the candidates' chooser plans every section (sections.py); it needs
        # no 360-degree scan (its map is what the ToF shows at the PTU's lowest tilt and while
        # driving), unless the localiser matches the scans; without it, legs are planned on the
        # scans' 5 cm maps with the rolling map laid over them (map_legs.py)
        self.chooser = Chooser(self) if bounds is not None else None
        self.legs = MapLegs(self) if bounds is None else None
        if self.chooser is not None and not self.localiser.active and not self.scan_loop:
            self.need_scan = False

    def set_down_on_ring(self) -> str:
        """``see_set_down ring``, after the first look round: what the rover knows of the ground it
        was set down on that no frame shows, each part from what shows it
        (:func:`prox_workflows.algorithms.set_down.set_down`): the wheels' contacts from the pose
        and the IMU, the disc the body turns in on their plane, the rest of the mast's blind disc
        on the ring's plane within the ring's own spread. Returns what it took."""
        d = self.driver
        x, y, heading = d.pose()
        said = set_down(d.bounds, (x, y, heading), d.stand_height(x, y), d.body, d.imu(), d.blind_disc(), d.radius,
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
        """Choose the next section, or replan from the scans and the rolling map, and drive;
        False: a 360-degree scan first."""
        if self.need_scan:
            return False
        if self.chooser is not None:
            went = self.chooser.drive_on(leg)
            if self.scan_loop and self.scanned_at is not None:
                # the next scan once the rover stands scan_stretch from the last one: what a scan
                # shows is ground round where it was made (a way on and back out of a dead end
                # is no reason to scan the same place again)
                x, y, _ = self.driver.pose()
                self.need_scan = math.hypot(x - self.scanned_at[0], y - self.scanned_at[1]) >= self.cfg.scan_stretch
            return went
        assert self.legs is not None
        return self.legs.drive_on(leg)

    def scanned(self, leg: int, local: Any) -> None:
        """A 360-degree scan made the maps ``local`` (the scans so far, merged): the next choice
        or plan is made from them and what the rover sees next."""
        self.need_scan = False
        x, y, _ = self.driver.pose()
        self.scanned_at = (x, y)
        if self.chooser is not None:
            self.chooser.scanned()
        if self.legs is not None:
            self.legs.scanned(local)
        self.stats.scans += 1

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

    def leave(self) -> None:
        """The mission ended, however: its bounds map, where the rover stands now, is the next
        navigate's start (a GNC sends goal after goal; from a fresh map and the set-down's prior
        each would judge again the ground under and round the rover that this one saw)."""
        bounds = self.driver.bounds
        if bounds is not None and self.ground_key is not None:
            pose = self.app.pose
            self.app.travel.leave(KeptGround(bounds, (pose.x, pose.y, pose.heading), self.ground_key))

    def fields(self) -> dict[str, Any]:
        """The OK line's keys of the see loop."""
        search = self.legs.search if self.legs is not None else None
        searched = {"searches": search.searches, "repairs": search.repairs} if search else {}
        return {**self.stats.fields(), "scans": self.mission.scans, "search": self.p.search, **searched}
