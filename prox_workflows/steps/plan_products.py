"""A plan's products: its summary (the plan YAML), the path and waypoint tables, and its
drawings, each with a sidecar; and the ``write_plan`` step that writes them."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..engine import step
from ..grid import GridGeometry
from ..mapview import Marks
from .plan_drawing import LEGEND, draw_plan, ortho_figure, plan_map_rgb
from .planner import PlanResult


def plan_summary(result: PlanResult) -> dict[str, Any]:
    """YAML-ready plan: parameters, path and waypoints."""
    wp = result.waypoints
    return {
        "start": list(result.start),
        "goal": list(result.goal),
        "cost": result.cost,
        "cost_driven": float(result.cost_so_far[result.cut - 1]),
        "reaches_goal": result.reaches_goal,
        "expanded_cells": result.expanded,
        "grid": {"cell": result.image.geometry.cell, "xmin": result.image.geometry.xmin,
                 "ymax": result.image.geometry.ymax, "width": result.image.geometry.width,
                 "height": result.image.geometry.height},
        "parameters": result.params.as_dict(),
        "warnings": list(result.warnings),
        "path": [[float(x), float(y), float(g), int(i < result.cut)]
                 for i, ((x, y), g) in enumerate(zip(result.path, result.cost_so_far, strict=True))],
        "path_columns": ["x", "y", "cost_so_far", "drive"],
        "waypoints": wp.rows(),
        "waypoint_columns": list(wp.COLUMNS),
    }


def write_plan(result: PlanResult, prefix: str, ortho: tuple[np.ndarray, GridGeometry] | None = None,
               made_by: str = "rvs-path-planner", inputs: Sequence[str] = ()) -> list[str]:
    """PREFIX_path.csv, PREFIX_waypoints.csv, PREFIX_plan.yaml, PREFIX_plan_map.png and, with an
    ortho-image, PREFIX_plan_ortho.png (each product with its YAML sidecar). Returns the paths."""
    from pathlib import Path

    from ..products import write_png, write_sidecar, write_text_atomic, write_yaml_atomic

    base = Path(prefix)
    params = result.params.as_dict()
    written: list[str] = []
    drive = (np.arange(len(result.path)) < result.cut).astype(int)
    lines = ["x,y,cost_so_far,drive"] + [f"{x:.4f},{y:.4f},{g:.6f},{d}" for (x, y), g, d
                                          in zip(result.path, result.cost_so_far, drive, strict=True)]
    p = write_text_atomic(base.with_name(base.name + "_path.csv"), "\n".join(lines) + "\n")
    written.append(str(p))
    write_sidecar(p, made_by, params, list(inputs), columns={
        "x, y": "world coordinates of the planning cells' centres (exact start and goal at the ends), m",
        "cost_so_far": "A* G from the start (w * distance + (1 - w) * environmental cost), m",
        "drive": "1 for the part the rover drives (before the cut at the local map's border)"})
    wp = result.waypoints
    lines = [",".join(wp.COLUMNS)] + [",".join(f"{v:.4f}" if np.isfinite(v) else "nan" for v in row)
                                      for row in wp.table()]
    p = write_text_atomic(base.with_name(base.name + "_waypoints.csv"), "\n".join(lines) + "\n")
    written.append(str(p))
    write_sidecar(p, made_by, params, list(inputs), columns={
        "x, y": "waypoint, world coordinates, m",
        "heading_deg": "heading of the leg leaving the waypoint (the last: arrival heading), deg CCW from x",
        "turn_deg": "turn on the spot at the waypoint before its leg, deg, left positive (NaN: heading unknown)",
        "leg_length": "length of the leg leaving the waypoint, m"})
    p = write_yaml_atomic(base.with_name(base.name + "_plan.yaml"),
                          {"made_by": made_by, "inputs": list(inputs), **plan_summary(result)})
    written.append(str(p))
    img = result.image
    rgb = draw_plan(plan_map_rgb(img), img.geometry, result.path, wp.xy, result.cut, img.local)
    p = write_png(base.with_name(base.name + "_plan_map.png"), rgb)
    written.append(str(p))
    write_sidecar(p, made_by, params, list(inputs), legend=list(LEGEND))
    if ortho is not None:
        o_img, o_geom = ortho
        rgb = ortho_figure(o_img, o_geom, "plan over the ortho-image", Marks(
            path=result.path, driven=result.cut, waypoints=wp.xy, goal=(float(result.goal[0]), float(result.goal[1]))))
        p = write_png(base.with_name(base.name + "_plan_ortho.png"), rgb)
        written.append(str(p))
        write_sidecar(p, made_by, params, list(inputs))
    return written


@step("write_plan", outputs={"files": "list[str]"})
def write_plan_step(plan: PlanResult, prefix: str, ortho: tuple[np.ndarray, GridGeometry] | None = None,
                    made_by: str | None = None, inputs: Sequence[str] | None = None) -> list[str]:
    """The plan's products (:func:`write_plan`): path, waypoints, summary and drawings."""
    return write_plan(plan, str(prefix), ortho=ortho, made_by=made_by or "rvs-prox", inputs=inputs or ())
