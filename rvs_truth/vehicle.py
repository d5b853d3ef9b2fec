"""The vehicle's own yardstick of a driven track: its true poses densified and checked wheel by
wheel on the true 1 cm surface (:mod:`prox_workflows.algorithms.vehicle`), perfect-knowledge plans
on the window-step hazard map judged the same way (a lower bound on what the body can do; whether
it can at all is :mod:`rvs_truth.oracle`'s search with the body), the old score (true hazard cells
under the swept box), the tracking error and a stop's reason."""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import numpy as np

from drivers.sim.rover import RoverBody
from prox_workflows.algorithms.dem2hazard import HazardParams, classify
from prox_workflows.algorithms.safety import check_move
from prox_workflows.algorithms.vehicle import Event, check_poses, densify, track_poses, unsafe_events
from prox_workflows.grid import GridGeometry

from .surface import ceiling_layers

ROVER = (0.51, 0.40)  # config/head.yaml rover_length, rover_width


def crossed(track: np.ndarray, maps: dict[str, np.ndarray], g: GridGeometry) -> tuple[int, float, float]:
    """Hazardous true cells under the rover body swept along its true track (0: clean), and the
    true step and slope of the worst of them (how far past the limits: 15.4 cm against 15 cm is
    not a 40 cm rock)."""
    blocked, step, slope = 0, 0.0, 0.0
    for a, b in zip(track[:-1], track[1:], strict=True):
        h = math.degrees(math.atan2(b[1] - a[1], b[0] - a[0]))
        m = check_move(maps["traversability"], g, (a[0], a[1], h), (b[0], b[1], h), ROVER[0], ROVER[1])
        if m.blocked_cells:
            blocked += m.blocked_cells
            r, c = g.cell_of(np.array(m.worst_x), np.array(m.worst_y))
            step, slope = max(step, float(maps["step"][r, c])), max(slope, float(maps["slope"][r, c]))
    return blocked, step, slope


def plan_params(cell: float, footprint: str) -> Any:
    """navigate's planner as the bench's ideal and ceiling plans run it: the rover's circle or,
    with ``footprint`` body, its half width along straight stretches; no border (all is known)."""
    from prox_workflows.algorithms.planner import PlannerParams

    return PlannerParams(grid=cell, rover_radius=math.hypot(*ROVER) / 2, border=0.0,
                         half_width=ROVER[1] / 2 if footprint == "body" else None)


TRACK_STEP = 0.02  # m: the truth check's pose spacing (no point of the body moves farther between two)


def read_track(path: Path) -> np.ndarray:
    """(N, 3) true poses of a navigate track CSV: x, y and its ``heading`` column, or, in a
    track written without one, the heading of the track's own direction."""
    with open(path) as fh:
        rows = list(csv.DictReader(fh))
    xy = np.array([[float(r["x"]), float(r["y"])] for r in rows]).reshape(-1, 2)
    heading = np.array([float(r["heading"]) for r in rows]) if rows and "heading" in rows[0] else None
    return track_poses(xy, heading)


def vehicle_check(poses: np.ndarray, surface: tuple[np.ndarray, GridGeometry, GridGeometry],
                  body: RoverBody) -> tuple[list[Event], int]:
    """The distinct unsafe events of ``poses`` densified to :data:`TRACK_STEP`, and how many poses
    were checked."""
    dense = densify(poses, TRACK_STEP, body)
    checks = check_poses(surface[0], surface[1], dense, body)
    return unsafe_events(checks, dense, body), len(dense)


def plan_poses(xy: np.ndarray, start_heading: float) -> np.ndarray:
    """A waypoint path as the rover drives it: at each waypoint it turns on the spot toward the
    next, then drives straight."""
    out = [(xy[0, 0], xy[0, 1], start_heading)]
    for a, b in zip(xy[:-1], xy[1:], strict=True):
        if np.hypot(*(b - a)) < 1e-9:
            continue
        h = math.degrees(math.atan2(b[1] - a[1], b[0] - a[0]))
        if abs((h - out[-1][2] + 180.0) % 360.0 - 180.0) > 1e-9:
            out.append((a[0], a[1], h))
        out.append((b[0], b[1], h))
    return np.array(out)


def capability_hazard(body: RoverBody) -> dict[str, float]:
    """Dem2Hazard thresholds at the body's own limits: a step no higher than both the climb and
    the belly (a rock under the box must pass beneath it, one under a wheel must be climbed; the
    planner's footprint keeps a hazard from either), a slope no steeper than the grade."""
    return {"step_max": min(body.climb, body.clearance), "slope_max": body.grade}


def perfect_plan(surface: tuple[np.ndarray, GridGeometry, GridGeometry], body: RoverBody,
                 start: tuple[float, float], goal: tuple[float, float], footprint: str,
                 hazard: dict[str, float]) -> dict[str, Any]:
    """navigate's planner with ``footprint`` on the hazard map of the true 1 cm surface
    (:func:`ceiling_layers`, thresholds ``hazard``), driven as :func:`plan_poses` and judged by the
    vehicle check: reached (a plan exists), its efficiency (straight line over its length),
    its events."""
    from prox_workflows.algorithms.planner import NavMaps, PlanningError, plan_path

    fine, _, g = surface
    key = (id(fine), tuple(sorted(hazard.items())))
    if key not in _HAZARD:
        layers = ceiling_layers(fine, g, 1)
        _HAZARD[key] = (classify(layers["slope"], layers["roughness"], layers["step"], layers["valid"],
                                 HazardParams(**hazard))["hazard"], layers["slope"])
    hz, slope = _HAZARD[key]
    try:
        plan = plan_path(NavMaps(hz, slope, g), None, start, goal, plan_params(g.cell, footprint))
    except PlanningError as exc:
        return {"reached": False, "efficiency": 0.0, "events": [], "why": exc.reason}
    xy = plan.waypoints.xy
    length = float(np.sum(np.hypot(*np.diff(xy, axis=0).T)))
    heading = math.degrees(math.atan2(goal[1] - start[1], goal[0] - start[0]))
    events, _ = vehicle_check(plan_poses(xy, heading), surface, body)
    return {"reached": True, "efficiency": round(math.hypot(goal[0] - start[0], goal[1] - start[1]) / length, 3),
            "events": events}


_HAZARD: dict[tuple[Any, ...], tuple[np.ndarray, np.ndarray]] = {}


# m: the step thresholds a perfect-knowledge plan is tried at, the body's step capability first.
# A window's step (max - min over 30 cm, slopes included) is not a wheel's step edge nor the ground
# under the belly: a plan at a looser threshold that passes the vehicle check proves the mission
# feasible as well, and at the capability itself most missions find no plan (docs/NAVIGATE_BENCH.md).
FEASIBLE_STEPS = (0.08, 0.09, 0.10, 0.11, 0.12, 0.13, 0.14, 0.15)


def feasibility(surface: tuple[np.ndarray, GridGeometry, GridGeometry], body: RoverBody,
                start: tuple[float, float], goal: tuple[float, float], footprint: str) -> dict[str, Any]:
    """Whether a perfect-knowledge plan on the window-step map reaches the goal and passes the
    vehicle check: the plan at each of :data:`FEASIBLE_STEPS` (at most the body's step capability to
    begin with, the slope at its grade) until one passes. The first passing plan's efficiency and
    threshold (None: none passed). A window's step is not what the body meets, so this is a lower
    bound on feasibility; the benchmark's verdict is :func:`rvs_truth.oracle.mission_oracle`."""
    cap = capability_hazard(body)
    for step in sorted({min(cap["step_max"], FEASIBLE_STEPS[0]), *FEASIBLE_STEPS}):
        hazard = {**cap, "step_max": step}
        plan = perfect_plan(surface, body, start, goal, footprint, hazard)
        if plan["reached"] and not plan["events"]:
            return {"feasible": True, "efficiency": plan["efficiency"], "step_max": step}
    return {"feasible": False, "efficiency": 0.0, "step_max": None}


def cross_track(track: np.ndarray, waypoints: np.ndarray, legs: np.ndarray) -> np.ndarray:
    """Each true track point's distance from the nearest stretch of the planned waypoint legs
    (consecutive waypoints of one leg)."""
    segs = [(a, b) for k in np.unique(legs) for a, b in zip(waypoints[legs == k][:-1], waypoints[legs == k][1:],
                                                             strict=True)]
    if not segs or len(track) == 0:
        return np.zeros(0)
    a = np.array([s[0] for s in segs])[None]  # (1, M, 2)
    b = np.array([s[1] for s in segs])[None]
    p = track[:, None, :2]
    ab = b - a
    t = np.clip(np.sum((p - a) * ab, axis=2) / np.maximum(np.sum(ab * ab, axis=2), 1e-12), 0.0, 1.0)
    return np.min(np.hypot(*(p - (a + t[..., None] * ab)).transpose(2, 0, 1)), axis=1)


def stop_reason(message: str) -> str:
    """The short reason of a navigate ERROR: its message up to the first detail."""
    m = message.strip()
    for cut in (":", ";", " after ", " ("):
        if cut in m[:60]:
            m = m[:m.index(cut)]
    return m[:60] or "error"


def mission_hazard(sets: list[str] | tuple[str, ...]) -> dict[str, float]:
    """The Dem2Hazard thresholds a mission's server runs with: the defaults under its
    ``dem2hazard.*`` settings."""
    base = HazardParams()
    out = {"step_max": base.step_max, "slope_max": base.slope_max}
    for item in sets:
        key, _, value = item.partition("=")
        if key in ("dem2hazard.step_max", "dem2hazard.slope_max"):
            out[key.split(".", 1)[1]] = float(value)
    return out
