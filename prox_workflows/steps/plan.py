"""The planning step: the path planner with its parameters as a script passes them one by one."""

from __future__ import annotations

from collections.abc import Sequence

from ..algorithms.planner import NavMaps, PlannerParams, PlanResult, plan_path
from ..engine import step


@step("plan_path", outputs={"plan": "PlanResult"})
def plan_step(local: NavMaps, global_maps: NavMaps | None, start: Sequence[float], goal: Sequence[float],
              start_heading: float | None = None, weight: float = 0.5, heuristic: str = "octile",
              grid: float | None = None, margin: float = 0.1, max_deviation: float = 0.1, border: float = 0.3,
              rover_radius: float = 0.3, critical_slope: float = 20.0,
              unknown_cost: float | None = None, footprint: str | None = None,
              rover_half_width: float | None = None) -> PlanResult:
    """:func:`plan_path` with the planner's parameters as the script passes them one by one."""
    if footprint == "body" and rover_half_width is None:
        raise ValueError("footprint body needs the rover's half width (rover_half_width)")
    params = PlannerParams(grid=grid, weight=weight, heuristic=heuristic, rover_radius=rover_radius, margin=margin,
                           half_width=rover_half_width if footprint == "body" else None,
                           critical_slope=critical_slope, max_deviation=max_deviation, border=border,
                           **({} if unknown_cost is None else {"unknown_cost": unknown_cost}))
    return plan_path(local, global_maps, start, goal, params, start_heading=start_heading)
