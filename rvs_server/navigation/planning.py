"""The planning helpers navigate's legs share: the planner's parameters for this rover, the
global maps, the plan_leg script's inputs, and where to plan when the goal itself cannot be
planned to."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

from prox_workflows.algorithms.planner import PlanParams

from ..protocol import ProtocolError

if TYPE_CHECKING:
    from prox_workflows.algorithms.planner import NavMaps, PlannerParams, PlanningError

    from ..app import App
    from .config import NavigateConfig

# What a navigate leg puts in the plan_leg script's workspace (checked at server start).
PLAN_INPUTS = ("local", "global_maps", "ortho", "start", "goal", "start_heading", "rover_radius", "rover_half_width",
               "critical_slope", "prefix", "made_by")


def validate_scripts() -> None:
    """Validate the per-leg plan script against navigate's planner parameters and inputs."""
    from prox_workflows.engine import validate

    validate("plan_leg", workspace=PLAN_INPUTS, param_cls=PlanParams)


def planner_params(app: App, plan: PlanParams) -> PlannerParams:
    """The planner's parameters: the ``plan`` section with this rover's body (config head) and
    the slope whose cost is 1 (dem2hazard.slope_max)."""
    from prox_workflows.algorithms.planner import PlannerParams

    head = app.config.get("head")
    return PlannerParams.of(plan, rover_radius=math.hypot(head.rover_length, head.rover_width) / 2,
                            half_width=head.rover_width / 2, critical_slope=app.config.get("dem2hazard").slope_max)


def check_plan_size(app: App, cfg: NavigateConfig) -> None:
    """A goal so far that its plans could not be held in memory is E_ARG before the ACK, not
    after the first 360-degree scan."""
    from prox_workflows.algorithms.planner import PlannerParams, blank_geometry, check_plan_size

    start = cfg.start[:2] if cfg.start else [app.pose.x, app.pose.y]
    try:
        check_plan_size(blank_geometry([start, cfg.goal], cfg.plan.grid, PlannerParams.blank_pad),
                        f"grid from ({start[0]:g}, {start[1]:g}) to -goal {cfg.goal[0]:g},{cfg.goal[1]:g}")
    except ValueError as exc:
        raise ProtocolError("E_ARG", str(exc)) from None


def load_global_folder(folder: str) -> NavMaps | None:
    """The global hazard and slope maps of a folder (navigate.global_maps); None without one."""
    from prox_workflows.algorithms.planner import NavMaps
    from prox_workflows.grid import read_geotiff

    if not folder:
        return None
    root = Path(folder)
    try:
        hazard, g = read_geotiff(root / "hazard.tif")
        slope, g2 = read_geotiff(root / "slope.tif")
    except (OSError, ValueError) as exc:
        raise ProtocolError("E_DATA", f"global maps in {folder} unusable ({exc}); fix navigate.global_maps") from None
    if g2 != g:
        raise ProtocolError("E_DATA", f"global hazard and slope maps in {folder} are on different grids")
    return NavMaps(hazard, slope, g)


def load_global_maps(cfg: NavigateConfig) -> tuple[Any, Any]:
    """The planner's global maps and the global map with its DEM (for map matching), from
    -global FILE or navigate.global_maps; (None, None) without either (blank maps)."""
    from prox_workflows.algorithms.global_map import GlobalMap, load_global
    from prox_workflows.algorithms.planner import NavMaps

    origin = (cfg.global_origin[0], cfg.global_origin[1])
    if cfg.global_:
        try:
            g = load_global(cfg.global_, origin)
        except (OSError, ValueError) as exc:
            raise ProtocolError("E_DATA", f"global map {cfg.global_} unusable ({exc})") from None
        return NavMaps(g.hazard, g.slope, g.geometry), g
    maps = load_global_folder(cfg.global_maps)
    if maps is None:
        return None, None
    dem_path = Path(cfg.global_maps) / "dem.tif"
    dem = None
    if dem_path.is_file():
        try:
            dem = load_global(dem_path, origin)
        except (OSError, ValueError) as exc:
            raise ProtocolError("E_DATA", f"global DEM {dem_path} unusable ({exc})") from None
    return maps, GlobalMap(maps.hazard, maps.slope, maps.geometry, dem.dem if dem else None, str(dem_path))


def goal_stand_in(local: NavMaps, global_maps: NavMaps | None, here: tuple[float, float], goal: tuple[float, float],
                  params: PlannerParams, exc: PlanningError, distance: float,
                  cfg: NavigateConfig) -> tuple[float, float] | None:
    """Where to plan to when the goal itself cannot be planned to (``exc``: goal_in_hazard or
    enclosed): the nearest point the rover can reach and stop on, if it lies within the goal's
    tolerance (a goal a few centimetres short of the rover's clearance from a hazard is reached
    from there, as the tolerance says), or, from farther than judge_range, to drive toward and
    judge the goal again from closer. None: the goal is unreachable."""
    from prox_workflows.algorithms.planner import PlanningError, nearest_reachable

    if exc.reason not in ("goal_in_hazard", "enclosed"):
        return None
    try:
        toward = nearest_reachable(local, global_maps, here, goal, params)
    except PlanningError:
        return None
    if math.hypot(toward[0] - goal[0], toward[1] - goal[1]) <= cfg.tolerance or distance > cfg.judge_range:
        return toward
    return None
