"""The pilot of a leg planned on the 5 cm maps (``see_gate off``): :class:`SeePilot` drives the
leg's waypoints by pure pursuit, one frame and the check of the next metres a cycle, and stops
on a hazard or unseen ground ahead; :class:`DriveOutcome` says how the leg ended. With the
bounds map (``see_gate bounds``, the default) the chooser's own pilot drives each section
(:mod:`.sections`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from drivers.rover import Motion

from .pursuit import arc_rate, motion_poses, nearest_stretch, passed, pursuit_point

if TYPE_CHECKING:
    from .see import SeeingDriver

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

