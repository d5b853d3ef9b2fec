"""The planning step: the path planner with the script's plan settings and the caller's rover."""

from __future__ import annotations

from collections.abc import Sequence

from ..algorithms.planner import NavMaps, PlannerParams, PlanParams, PlanResult, plan_path
from ..engine import step


@step("plan_path", outputs={"plan": "PlanResult"}, settings=PlanParams)
def plan_step(local: NavMaps, global_maps: NavMaps | None, start: Sequence[float], goal: Sequence[float],
              rover_radius: float, critical_slope: float, start_heading: float | None = None,
              unknown_cost: float | None = None, rover_half_width: float | None = None,
              settings: PlanParams | None = None) -> PlanResult:
    """:func:`plan_path` with the operator's plan settings and the caller's rover."""
    params = PlannerParams.of(settings or PlanParams(), rover_radius=rover_radius, half_width=rover_half_width,
                              critical_slope=critical_slope, unknown_cost=unknown_cost)
    return plan_path(local, global_maps, start, goal, params, start_heading=start_heading)
