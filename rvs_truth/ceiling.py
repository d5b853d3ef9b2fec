"""The perception ceiling: what a rover that mapped the terrain perfectly would plan and cross."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from drivers.sim.world import World
from prox_workflows.algorithms.dem2hazard import HazardParams, classify

from .surface import CEILING_MAPS, area, ceiling_layers, fine_surface, missions, true_maps
from .vehicle import crossed, plan_params


def perception_ceiling(scene: str, count: int, seed: int = 0, limits: tuple[float, ...] = (0.16, 0.15, 0.14, 0.135, 0.125),
                       footprint: str = "body", maps: tuple[str, ...] = ("cell_mean",)) -> list[dict[str, Any]]:
    """Per map kind (:data:`CEILING_MAPS`) and step limit, what a rover that mapped the terrain
    perfectly would do: the plan (navigate's planner and ``footprint``) on that map (reached: a
    plan exists; efficiency: the straight line over its length) and the true hazard cells the
    body swept along it crosses. Where a mission's only passages step within a centimetre of
    the limit, a 5 cm cell mean reads them 0.3-1.2 cm low (hirise), so at the limit a perfect
    cell-mean map still drives over true hazards, and with too wide a margin it finds no way:
    the window between is what any perception must hit. The finer maps show what a finer
    representation buys: with 3 cm means both scenes are clear and open at the limit itself."""
    from prox_workflows.algorithms.planner import NavMaps, PlanningError, plan_path

    world = World.from_scene(scene)
    truth, g = true_maps(world, area(scene))
    params = plan_params(g.cell, footprint)
    fine, _ = fine_surface(world, area(scene))
    todo = missions(scene, count, seed)
    rows = []
    for kind in maps:
        layers = ceiling_layers(fine, g, CEILING_MAPS[kind])
        slope = layers["slope"]
        for limit in limits:
            hazard = classify(layers["slope"], layers["roughness"], layers["step"], layers["valid"],
                              HazardParams(step_max=limit))["hazard"]
            for i, (start, goal) in enumerate(todo):
                row: dict[str, Any] = {"scene": scene, "map": kind, "step_max": limit, "mission": i}
                try:
                    plan = plan_path(NavMaps(hazard, slope, g), None, start, goal, params)
                except PlanningError:
                    rows.append({**row, "reached": False, "efficiency": 0.0, "crossed_cells": 0})
                    continue
                xy = plan.waypoints.xy
                length = float(np.sum(np.hypot(*np.diff(xy, axis=0).T)))
                track = np.concatenate([np.linspace(a, b, max(2, int(math.ceil(np.hypot(*(b - a)) / g.cell)) + 1))[:-1]
                                        for a, b in zip(xy[:-1], xy[1:], strict=True)] + [xy[-1:]])
                rows.append({**row, "reached": True,
                             "efficiency": round(math.hypot(goal[0] - start[0], goal[1] - start[1]) / length, 3),
                             "crossed_cells": crossed(track, truth, g)[0]})
    return rows
