"""The scan strategy (``navigate -loop scan``, seed 000 sect. 4.4.4): stop and go. Every leg is
planned on a fresh 360-degree scan with the plan_leg script (as rvs-path-planner runs it), and
the rover drives it to its end: the simulated rover turning on the spot toward each waypoint and
then straight to it, or the GNC, whose leg ends when its pose stands still."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from drivers.rover import Motion
from prox_workflows.engine import run_workflow

from ..protocol import ProtocolError
from .planning import goal_stand_in

if TYPE_CHECKING:
    from prox_workflows.algorithms.planner import PlanningError

    from .mission import Mission
    from .track import Track


class WaypointPilot:
    """One scan leg for :meth:`drivers.rover.Rover.drive`: to each waypoint in turn, steering by
    the rover's odometry, so wheel slip and heading drift leave the true rover short of and
    beside the waypoints; ``reached(k)`` once the rover believes it is at waypoint k. With the
    GNC steering, its reports only make the track."""

    def __init__(self, waypoints: np.ndarray, track: Track, reached: Any, steers: bool) -> None:
        self.wps = np.asarray(waypoints, dtype=np.float64)[:, :2]
        self.track = track
        self.reached = reached
        self.steers = steers
        self.k = 0  # the waypoint the last motion went to

    def moved(self, truth: tuple[float, float, float], end: bool) -> None:
        self.track.add(truth, end)

    def next(self, pose: tuple[float, float, float]) -> Motion | None:
        if not self.steers:
            return None
        if self.k > 0:
            self.reached(self.k)
        if self.k + 1 >= len(self.wps):
            return None
        self.k += 1
        return Motion.toward(*self.wps[self.k])


class ScanStrategy:
    """Plan each leg on the scan just made and drive it to its end."""

    def __init__(self, mission: Mission) -> None:
        self.mission = mission
        self.max_plans = mission.cfg.max_legs

    def arrived(self, left: float) -> bool:
        """An arrival on dead reckoning is checked by one more scan and match first."""
        return not self.mission.loc.wants_fix(self.mission.app.pose)

    def drive_on(self, leg: int) -> bool:
        return False  # every leg starts with a scan

    def scanned(self, leg: int, local: Any) -> None:
        """Plan the leg on the scan's maps (toward a stand-in where the goal cannot be planned
        to) and drive it."""
        from prox_workflows.algorithms.planner import PlanningError

        m = self.mission
        app, cfg, goal = m.app, m.cfg, m.goal
        pose = app.pose
        here = (pose.x, pose.y)
        distance = math.hypot(goal[0] - pose.x, goal[1] - pose.y)
        judged: PlanningError | None = None  # the goal's verdict from too far to be final
        prefix = app.data_path("nav", f"{m.name}_leg{leg}")
        maps = app.maps.layers
        inputs = {"local": local, "global_maps": m.global_maps, "ortho": (maps["ortho"], maps.geometry),
                  "start": list(here), "start_heading": pose.heading, "rover_radius": m.params.rover_radius,
                  "rover_half_width": app.config.get("head").rover_width / 2,
                  "critical_slope": m.params.critical_slope, "prefix": prefix, "made_by": "navigate"}

        def plan_leg(to: tuple[float, float]) -> Any:
            """The leg's plan and its products: the plan_leg script, as rvs-path-planner runs it."""
            ws, _ = run_workflow("plan_leg", cfg.plan.as_dict(), {**inputs, "goal": list(to)})
            return ws["plan"]

        def progress(done: int, total: int, message: str, phase: str = "") -> None:
            m.progress(leg, done, total, message, phase)

        try:
            plan = plan_leg(goal)
        except PlanningError as exc:
            toward = goal_stand_in(local, m.global_maps, here, goal, m.params, exc, distance, cfg)
            if toward is None:
                raise ProtocolError("E_DATA", f"goal unreachable ({exc.reason}): {exc.message}") from None
            try:
                plan = plan_leg(toward)
            except PlanningError:
                raise ProtocolError("E_DATA", f"goal unreachable ({exc.reason}): {exc.message}") from None
            if math.hypot(toward[0] - goal[0], toward[1] - goal[1]) <= cfg.tolerance:
                progress(0, 1, f"goal {exc.reason}: planning to ({toward[0]:.2f}, {toward[1]:.2f}) instead, "
                               f"within the {cfg.tolerance:g} m tolerance", "plan")
            else:  # drive toward the goal, as close as the maps allow, and judge it again from there
                judged = exc
                progress(0, 1, f"goal judged unreachable ({exc.reason}) from {distance:.2f} m, farther than "
                               f"{cfg.judge_range:g} m: driving toward it to ({toward[0]:.2f}, {toward[1]:.2f}) "
                               "to judge it again from closer", "plan")
        if plan.stands_still():
            if judged is not None:  # it cannot get closer: the verdict from here stands
                raise ProtocolError("E_DATA", f"goal unreachable ({judged.reason}): {judged.message}; judged from "
                                              f"{distance:.2f} m, and the rover can get no closer")
            raise ProtocolError("E_DATA", f"no progress on leg {leg}: the path leaves the locally seen ground at once "
                                          f"({'; '.join(plan.warnings) or 'nothing to drive'})")
        segments = len(plan.waypoints) - 1
        end = (float(plan.waypoints.xy[-1][0]), float(plan.waypoints.xy[-1][1]))
        progress(1, 1, f"{segments} segments to ({end[0]:.2f}, {end[1]:.2f})", "plan")
        m.record(plan.path[: plan.cut], plan.waypoints.xy)
        since = m.announce(leg, plan.waypoints, app.rel(prefix.with_name(prefix.name + "_waypoints.csv")))
        progress(0, segments, f"waiting for the rover to drive {segments} segments to ({end[0]:.2f}, {end[1]:.2f})",
                 "drive")
        steers = m.rover.steers
        pilot = WaypointPilot(plan.waypoints.xy, m.track, lambda k: progress(k, segments, f"segment {k}/{segments} "
                                                                                           "driven", "drive"), steers)
        stopped = m.drive(pilot, since, end)
        if steers:  # the rover's belief, not the simulator's truth: with slip they differ, as on Mars
            m.loc.after_drive(m.job, plan.waypoints.xy)
        else:
            there = math.hypot(stopped[0] - end[0], stopped[1] - end[1]) <= cfg.tolerance
            progress(segments, segments, f"rover {'arrived' if there else 'stopped'} at ({stopped[0]:.2f}, "
                                         f"{stopped[1]:.2f})", "drive")

    def leave(self) -> None:
        """Nothing is kept: each leg is planned on its own scans."""

    def fields(self) -> dict[str, Any]:
        return {"scans": self.mission.scans}
