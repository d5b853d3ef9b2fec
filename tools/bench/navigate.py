"""Benchmark: navigate -auto's two loops, stop-and-go (``-loop scan``: a 360-degree scan at every
leg's end) and driving while seeing (``-loop see``), side by side on the same seeded missions,
judged by the vehicle itself (docs/NAVIGATE_BENCH.md).

The yardstick is the rover's own body (``drivers.sim.rover.RoverBody``, declared in the scene's
``rover: body:`` block): at every true pose of the track (the simulator's truth, interpolated to
2 cm, turns on the spot included, headings from the track's ``heading`` column), on the
simulator's 1 cm surface, :mod:`prox_workflows.algorithms.vehicle` checks each wheel's relief against
the climb limit, the ground under the belly against its clearance and the tilt against its limit.
Consecutive unsafe poses are one **event**, with its kind and worst excess; one event fails the
mission. A mission is **feasible** when a perfect-knowledge plan (navigate's planner and
footprint, on the true 1 cm surface's hazard map, thresholds at the body's capability) reaches the
goal and passes the same check. Per mission: events, reached, the stop's reason when the rover
halted by itself (a **safe stop**: not reached, no event), efficiency beside the perfect-knowledge
efficiency, and the old score: true hazard cells (Dem2Hazard of the true DEM at 5 cm) under the
0.51 x 0.40 m box swept along the track, counted once per 5 cm chord.

Traverse efficiency = goal distance / (simulated time x top speed): 1.0 is a rover that drives
straight at full speed and never stops. Simulated time is the world's clock (``sim.time_scale=0``);
the see loop's cycle latency and the replanning times are wall milliseconds, apart.

``--budget`` measures the error budget the margins come from: each sensor's DEM (dem-full-tof,
dem-full) at 5 and 2.5 cm from mission starts, against the true surface: how much lower than the
true top a rock cell reads (p50, p99); with the missions' path-tracking error (the true track's
distance from the planned waypoint legs) it prints the margin table.

    python -m tools.bench.navigate --missions 10 --scenes marsyard hirise --modes see --jobs 2
    python -m tools.bench.navigate --missions 4 --modes scan --jobs 2
    python -m tools.bench.navigate --budget --scenes marsyard hirise
    python -m tools.bench.navigate --ceiling --footprint body --scenes hirise   # perfect maps, 35 s
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import socket
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
from scipy import ndimage

from drivers.sim.rover import RoverBody
from drivers.sim.world import World
from prox_workflows.algorithms.dem2hazard import HazardParams, classify, dem2hazard
from prox_workflows.algorithms.safety import check_move
from prox_workflows.algorithms.vehicle import Event, Margins, check_poses, densify, track_poses, unsafe_events
from prox_workflows.grid import GridGeometry
from rvs_params.hazard import HAZARDOUS, SAFE, UNDEFINED
from rvs_server.client.session import ServerThread
from rvs_server.protocol import Reply, parse_reply
from tools.global_maps import write_global_maps

TOP_SPEED = 0.1  # m/s: the scenes' rover speed
AREA = {"marsyard": (-5.5, -9.5, 13.5, 9.5), "hirise": (-14.0, -14.0, 14.0, 14.0), "dense": (-14.0, -14.0, 14.0, 14.0)}
ORBITAL = {"hirise", "dense"}  # scenes built on an orbital DTM (tools.global_maps writes it)
ROVER = (0.51, 0.40)  # config/head.yaml rover_length, rover_width
# both loops plan with the rover's circle by default: in hirise 6 of the 10 missions have no
# circle path even on the true maps, the body footprint (half width along straight stretches,
# --footprint body) has one for all 10, but the see loop's body then crosses ground its rolling
# map never saw, and its check (see_margin) must not be stricter than the plan's band
FOOTPRINT = {"scan": "circle", "see": "circle"}


class _Server(ServerThread):
    """The real server in a thread (as the tests run it), simulated time instant, PTU on the clock."""

    def __init__(self, data: Path, scene: str, sets: list[str] | None = None) -> None:
        super().__init__([f"server.data={data}", "server.port=0", "sim.time_scale=0", "server.web_port=0",
                          f"server.scene={scene}", *(sets or [])], log_level="warning")
        self.start(120)

    def request(self, line: str, timeout: float = 7200.0) -> Reply:
        with socket.create_connection(("127.0.0.1", self.port), timeout=timeout) as sock:
            f = sock.makefile("rb")
            f.readline()  # greeting
            sock.sendall(line.encode() + b"\n")
            job = None
            while True:
                r = parse_reply(f.readline().decode().rstrip("\r\n"))
                if r.status == "ACK":
                    job = r.fields["job"]
                elif r.status in ("OK", "ERROR") and (job is None or r.fields.get("job") == job):
                    return r


def true_maps(world: World, bounds: tuple[float, float, float, float]) -> tuple[dict[str, np.ndarray],
                                                                               GridGeometry]:
    """The simulator's true DEM through Dem2Hazard at 5 cm: all its layers."""
    g = GridGeometry.covering(*bounds, 0.05)
    dem = world.true_dem(g.cell, g.bounds, include_target=False)
    return dem2hazard(dem, g.cell, HazardParams()), g


def true_hazard(world: World, bounds: tuple[float, float, float, float]) -> tuple[np.ndarray, np.ndarray,
                                                                                  GridGeometry]:
    """The simulator's true hazard and traversability at 5 cm."""
    out, g = true_maps(world, bounds)
    return out["hazard"], out["traversability"], g


def missions(scene: str, count: int, seed: int = 0) -> list[tuple[tuple[float, float], tuple[float, float]]]:
    """``count`` seeded (start, goal) pairs 15-20 m apart, both >= 1 m from every true hazard."""
    world = World.from_scene(scene)
    hazard, _, g = true_hazard(world, AREA[scene])
    clear = (ndimage.distance_transform_edt(hazard != HAZARDOUS) * g.cell >= 1.0) & (hazard == SAFE)
    rows, cols = np.nonzero(clear)
    xs, ys = g.centers()
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < count:
        i, j = rng.integers(len(rows), size=2)
        s = (round(float(xs[cols[i]]), 2), round(float(ys[rows[i]]), 2))
        e = (round(float(xs[cols[j]]), 2), round(float(ys[rows[j]]), 2))
        if 15.0 <= math.hypot(e[0] - s[0], e[1] - s[1]) <= 20.0:
            out.append((s, e))
    return out


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


def ideal_efficiency(maps: dict[str, np.ndarray], g: GridGeometry, start: tuple[float, float],
                     goal: tuple[float, float], footprint: str) -> float:
    """The efficiency of a rover that knows the true maps and never stops: goal distance over
    the length of the plan's waypoints on them (navigate's planner and footprint; turns on the
    spot not counted): about what a mission can reach at best (hirise's rock field makes some
    missions detour to three times the straight line). 0 when the true maps show no way."""
    from prox_workflows.algorithms.planner import NavMaps, PlanningError, plan_path

    params = plan_params(g.cell, footprint)
    try:
        plan = plan_path(NavMaps(maps["hazard"], maps["slope"], g), None, start, goal, params)
    except PlanningError:
        return 0.0
    length = float(np.sum(np.hypot(*np.diff(plan.waypoints.xy, axis=0).T)))  # the simplified path, as driven
    return round(math.hypot(goal[0] - start[0], goal[1] - start[1]) / length, 3)


# The maps a perfect sensor could make of the true surface, for the ceiling: the step each reads
# over Dem2Hazard's window, from the 1 cm surface averaged over this many centimetres (0: 5 cm cell
# means, what the rolling map's cells are: means of the points in them).
CEILING_MAPS = {"cell_mean": 0, "mean_3cm": 3, "surface_1cm": 1}


def fine_surface(world: World, bounds: tuple[float, float, float, float]) -> tuple[np.ndarray, GridGeometry]:
    """The true surface sampled every centimetre over the 5 cm grid of ``bounds`` (each 5 cm
    cell's centre is its sample (2, 2)), and that grid."""
    g = GridGeometry.covering(*bounds, 0.05)
    return world.true_dem(0.01, g.bounds, include_target=False).astype(np.float32), g


def ceiling_layers(fine: np.ndarray, g: GridGeometry, box: int) -> dict[str, np.ndarray]:
    """Slope, roughness and step at 5 cm as a perfect sensor would map them (:data:`CEILING_MAPS`):
    Dem2Hazard's of the 5 cm cell means, whose step is, with ``box`` > 0, replaced by the greatest
    minus the least height within the same window (each cell's centre +- 15 cm) of the 1 cm
    surface averaged over ``box`` centimetres. That step is never below the true map's (which
    takes the same window's 5 cm centre samples) when ``box`` is 1. None depends on the limits."""
    import cv2

    params = HazardParams()
    mean = fine.reshape(g.height, 5, g.width, 5).mean(axis=(1, 3)).astype(np.float32)
    out = dem2hazard(mean, g.cell, params)
    layers = {"slope": out["slope"], "roughness": out["roughness"], "step": out["step"], "valid": out["hazard"] != UNDEFINED}
    if box > 0:
        half = params.window_cells(g.cell) // 2 * 5
        kernel = np.ones((2 * half + 1, 2 * half + 1), np.uint8)
        surface = cv2.blur(fine, (box, box), borderType=cv2.BORDER_REPLICATE) if box > 1 else fine
        layers["step"] = (cv2.dilate(surface, kernel, borderType=cv2.BORDER_REPLICATE)
                          - cv2.erode(surface, kernel, borderType=cv2.BORDER_REPLICATE))[2::5, 2::5]
    return layers



# ----------------------------------------------------------------------------- the vehicle yardstick

TRACK_STEP = 0.02  # m: the truth check's pose spacing (no point of the body moves farther between two)


_TRUTH: dict[str, tuple[np.ndarray, GridGeometry, GridGeometry]] = {}


def truth_surface(world: World, scene: str) -> tuple[np.ndarray, GridGeometry, GridGeometry]:
    """The scene's true 1 cm surface over its mission area, its grid, and the 5 cm grid it
    refines (computed once per process and scene)."""
    if scene not in _TRUTH:
        fine, g = fine_surface(world, AREA[scene])
        _TRUTH[scene] = (fine, GridGeometry(0.01, g.xmin, g.ymax, g.width * 5, g.height * 5), g)
    return _TRUTH[scene]


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
    planner's footprint keeps a hazard from either), a slope no steeper than the tilt."""
    return {"step_max": min(body.climb, body.clearance), "slope_max": body.tilt}


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
# A window's step (max - min over 30 cm, slopes included) is not a wheel's relief nor the ground
# under the belly: a plan at a looser threshold that passes the vehicle check proves the mission
# feasible as well, and at the capability itself most missions find no plan (docs/NAVIGATE_BENCH.md).
FEASIBLE_STEPS = (0.08, 0.09, 0.10, 0.11, 0.12, 0.13, 0.14, 0.15)


def feasibility(surface: tuple[np.ndarray, GridGeometry, GridGeometry], body: RoverBody,
                start: tuple[float, float], goal: tuple[float, float], footprint: str) -> dict[str, Any]:
    """Whether a perfect-knowledge plan reaches the goal and passes the vehicle check: the plan at
    each of :data:`FEASIBLE_STEPS` (at most the body's step capability to begin with, the slope at its
    tilt) until one passes. The first passing plan's efficiency and threshold (None: infeasible)."""
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
    truth, g = true_maps(world, AREA[scene])
    params = plan_params(g.cell, footprint)
    fine, _ = fine_surface(world, AREA[scene])
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


def run_mission(scene: str, mode: str, start: tuple[float, float], goal: tuple[float, float],
                extra: list[str], sets: tuple[str, ...] = ()) -> dict[str, Any]:
    """One navigate -auto in a fresh server, judged by the vehicle check. A scene built on an
    orbital DTM gets it as navigate's global maps, as a rover team would load its orbital map."""
    with tempfile.TemporaryDirectory() as tmp:
        sets = list(sets)
        if scene in ORBITAL:
            write_global_maps(scene, Path(tmp) / "global")
            sets.append(f"navigate.global_maps={Path(tmp) / 'global'}")
        srv = _Server(Path(tmp), scene, sets)
        try:
            world = srv.app.world
            world.set_target_visible(False)
            for line in extra:
                srv.request(line)
            heading = math.degrees(math.atan2(goal[1] - start[1], goal[0] - start[0]))
            t_sim0, t_wall0 = world.clock.now(), time.monotonic()
            r = srv.request(f"navigate -start {start[0]},{start[1]},{heading:.1f} -goal {goal[0]},{goal[1]} "
                            f"-auto -loop {mode} -footprint {FOOTPRINT[mode]} -name bench -max-legs 30")
            sim_s = world.clock.now() - t_sim0
            wall_s = time.monotonic() - t_wall0
            truth = world.truth()
            dist = math.hypot(goal[0] - start[0], goal[1] - start[1])
            out: dict[str, Any] = {"scene": scene, "mode": mode, "start": start, "goal": goal,
                                   "distance": round(dist, 2), "status": r.status, "sim_s": round(sim_s, 1),
                                   "wall_s": round(wall_s, 1),
                                   "true_miss": round(math.hypot(truth["x"] - goal[0], truth["y"] - goal[1]), 3)}
            out["reached"] = r.status == "OK" and r.fields.get("reached") == "true"
            out["efficiency"] = round(dist / (sim_s * TOP_SPEED), 3) if out["reached"] else 0.0
            for key in ("legs", "scans", "replans", "stops", "looks", "cycles", "cycle_ms", "cycle_ms_max", "frame_ms",
                        "replan_ms", "searches", "repairs"):
                if key in r.fields:
                    out[key] = float(r.fields[key])
            if r.status != "OK":
                out["message"] = r.fields.get("message", "")
            nav = Path(tmp) / "nav"
            track_file = nav / "bench_track.csv"
            # navigate leaves its track whenever the rover moved
            poses = read_track(track_file) if track_file.exists() else np.array([(*start, heading)])
            out["track_heading"] = bool(track_file.exists() and "heading" in track_file.read_text().split("\n", 1)[0])
            body = world.body
            surface = truth_surface(world, scene)
            events, checked = vehicle_check(poses, surface, body)
            out["events"] = [{"kind": e.kind, "excess": e.excess, "x": round(e.x, 2), "y": round(e.y, 2),
                              "heading": round(e.heading, 1)} for e in events]
            out["poses_checked"] = checked
            if not out["reached"] and not events:
                out["safe_stop"] = stop_reason(out.get("message", "stopped"))
            wfile = nav / "bench_waypoints.csv"
            if wfile.exists():
                with open(wfile) as fh:
                    rows = list(csv.DictReader(fh))
                if rows:
                    wps = np.array([[float(w["x"]), float(w["y"])] for w in rows])
                    err = cross_track(poses, wps, np.array([int(w["leg"]) for w in rows]))
                    out["cross_track_p50"], out["cross_track_p99"] = (round(float(np.percentile(err, q)), 3)
                                                                      for q in (50, 99))
            maps, g = true_maps(world, AREA[scene])
            out["crossed_cells"], worst_step, worst_slope = crossed(poses[:, :2], maps, g)
            if out["crossed_cells"]:
                out["crossed_step_m"], out["crossed_slope_deg"] = round(worst_step, 3), round(worst_slope, 1)
            feas = feasibility(surface, body, start, goal, FOOTPRINT[mode])
            out["feasible"], out["perfect_efficiency"] = feas["feasible"], feas["efficiency"]
            out["perfect_step_max"] = feas["step_max"]
            today = perfect_plan(surface, body, start, goal, FOOTPRINT[mode], mission_hazard(sets))
            out["today_plan"] = {"reached": today["reached"], "efficiency": today["efficiency"],
                                 "events": [f"{e.kind} +{e.excess:.3f}" for e in today["events"]]}
            return out
        finally:
            srv.stop()


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


def _pct(values: list[float], q: float) -> float | None:
    return round(float(np.percentile(values, q)), 3) if values else None


def summarise(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per scene and mode: feasible, reached (of feasible), failed (a mission with an event), the
    events, safe stops with their reasons, efficiency (reached missions) beside the perfect-knowledge
    efficiency of the same missions, the old crossing count, tracking error, latency."""
    out = []
    for scene in dict.fromkeys(r["scene"] for r in rows):
        for mode in dict.fromkeys(r["mode"] for r in rows):
            sel = [r for r in rows if r["scene"] == scene and r["mode"] == mode]
            if not sel:
                continue
            reached = [r for r in sel if r["reached"]]
            feasible = [r for r in sel if r["feasible"]]
            events = [e for r in sel for e in r["events"]]
            worst: dict[str, float] = {}
            for e in events:
                kind = e["kind"].split()[0]
                worst[kind] = max(worst.get(kind, 0.0), e["excess"])
            ok = [r for r in reached if r["feasible"]]
            track = [r["cross_track_p99"] for r in sel if "cross_track_p99" in r]
            s = {"scene": scene, "mode": mode, "missions": len(sel), "feasible": len(feasible),
                 "reached": len(reached), "reached_of_feasible": sum(1 for r in feasible if r["reached"]),
                 "failed": sum(1 for r in sel if r["events"]), "events": len(events),
                 "events_per_kind": {k: sum(1 for e in events if e["kind"].split()[0] == k) for k in worst},
                 "worst_excess": worst,
                 "safe_stops": sum(1 for r in sel if "safe_stop" in r),
                 "stop_reasons": dict(Counter(r["safe_stop"] for r in sel if "safe_stop" in r)),
                 "efficiency_reached": round(float(np.mean([r["efficiency"] for r in ok])), 3) if ok else None,
                 "perfect_efficiency_same": round(float(np.mean([r["perfect_efficiency"] for r in ok])), 3) if ok
                 else None,
                 "perfect_efficiency_feasible": round(float(np.mean([r["perfect_efficiency"] for r in feasible])), 3)
                 if feasible else None,
                 "crossing_missions": sum(1 for r in sel if r["crossed_cells"] > 0),
                 "crossed_cells": sum(r["crossed_cells"] for r in sel),
                 "cross_track_p99_max": max(track) if track else None,
                 "today_plans_with_events": sum(1 for r in sel if r["today_plan"]["events"]),
                 "scans_per_mission": round(float(np.mean([r.get("scans", r.get("legs", 0)) for r in sel])), 2),
                 "sim_s_mean": round(float(np.mean([r["sim_s"] for r in sel])), 1),
                 "wall_s_mean": round(float(np.mean([r["wall_s"] for r in sel])), 1)}
            if mode == "see":
                cyc = [r["cycle_ms"] for r in sel if r.get("cycles")]
                s["cycle_ms_mean"] = round(float(np.mean(cyc)), 1) if cyc else None
                s["cycle_ms_max"] = max((r.get("cycle_ms_max", 0.0) for r in sel), default=None)
                s["replan_ms_mean"] = round(float(np.mean([r.get("replan_ms", 0.0) for r in sel])), 1)
            out.append(s)
    return out


def replan_vs_astar(trials: int = 20, seed: int = 0) -> dict[str, Any]:
    """D* Lite's repair after a rock appears 3 m ahead on the path, against a fresh A*, on a
    planning image of 400 x 400 cells (20 m at 5 cm) built as navigate builds it from marsyard's
    true hazard map; the path costs must agree."""
    from prox_workflows.algorithms.planner import NavMaps, PlannerParams, astar_grid, planning_image
    from prox_workflows.algorithms.planner import warm_up as astar_warm_up
    from prox_workflows.algorithms.replan import IncrementalPlanner
    from prox_workflows.algorithms.replan import warm_up as replan_warm_up

    astar_warm_up()
    replan_warm_up()
    world = World.from_scene("marsyard")
    g = GridGeometry.covering(-6.0, -10.0, 14.0, 10.0, 0.05)
    dem = world.true_dem(g.cell, g.bounds, include_target=False)
    maps = dem2hazard(dem, g.cell, HazardParams())
    params = PlannerParams(grid=0.05, rover_radius=math.hypot(*ROVER) / 2)
    image = planning_image(NavMaps(maps["hazard"], maps["slope"], g), None, params)
    k = image.cost_per_metre(params.weight)
    rng = np.random.default_rng(seed)
    free = np.argwhere(np.isfinite(k))
    d_ms, a_ms, first_ms = [], [], []
    done = 0
    while done < trials:
        s, e = free[rng.integers(len(free))], free[rng.integers(len(free))]
        if np.hypot(*(s - e)) * g.cell < 10:
            continue
        try:
            t0 = time.perf_counter()
            dp = IncrementalPlanner(k, tuple(s), tuple(e), orth=g.cell, diag=g.cell * math.sqrt(2), h_scale=params.weight)
            path = dp.plan()
            first_ms.append((time.perf_counter() - t0) * 1000)
        except Exception:
            continue
        if len(path.cells) < 80:
            continue
        rock = path.cells[60]  # 3 m ahead at 5 cm
        rr, cc = np.mgrid[-12:13, -12:13]
        disc = (rr**2 + cc**2) * g.cell**2 <= (0.2 + params.rover_radius + params.margin) ** 2
        cells = np.stack([rr[disc] + rock[0], cc[disc] + rock[1]], axis=1)
        cells = cells[(cells[:, 0] >= 0) & (cells[:, 0] < k.shape[0]) & (cells[:, 1] >= 0) & (cells[:, 1] < k.shape[1])]
        if any(tuple(c) in {tuple(s), tuple(e)} for c in cells):
            continue
        t0 = time.perf_counter()
        dp.update(cells, np.inf)
        try:
            repaired = dp.plan()
        except Exception:
            continue
        d_ms.append((time.perf_counter() - t0) * 1000)
        k2 = k.copy()
        k2[cells[:, 0], cells[:, 1]] = np.inf
        t0 = time.perf_counter()
        fresh = astar_grid(k2, tuple(s), tuple(e), heuristic="octile", orth=g.cell, diag=g.cell * math.sqrt(2),
                           share=0.5, corner_rule=True)
        a_ms.append((time.perf_counter() - t0) * 1000)
        assert abs(fresh.cost - repaired.cost) <= 1e-6 * max(1.0, fresh.cost), (fresh.cost, repaired.cost)
        done += 1
    return {"grid": list(k.shape), "trials": trials, "dstar_repair_ms_p50": round(float(np.median(d_ms)), 2),
            "astar_fresh_ms_p50": round(float(np.median(a_ms)), 2),
            "ratio": round(float(np.median(a_ms) / np.median(d_ms)), 1),
            "dstar_first_plan_ms_p50": round(float(np.median(first_ms)), 2)}


BUDGET_RANGE = (0.6, 3.0)  # m from the rover: the ground the loops judge before driving onto it


def read_low_budget(scene: str, count: int, seed: int = 0, cells: tuple[float, ...] = (0.05, 0.025),
                    sensors: tuple[str, ...] = ("tof", "stereo")) -> list[dict[str, Any]]:
    """Per sensor and cell size, how much lower than the true top a rock cell reads: a full
    360-degree DEM (``dem-full-tof`` or ``dem-full``) from each of the first ``count`` mission
    starts, its defined cells within :data:`BUDGET_RANGE` of the rover whose centre lies on a
    rock (the simulator's rock list), true top (the greatest height of the 5 mm true surface in
    the cell) minus the DEM's value, each DEM first registered in height to the truth by the median
    of its rock-free cells (``shift_max``: the largest such shift, about 0 when the frames agree).
    ``ground_bias_p50``: the rock-free cells' true mean minus the DEM's value after it."""
    from prox_workflows.steps.read import read_dem

    out: dict[tuple[str, float], dict[str, list[np.ndarray]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        srv = _Server(Path(tmp), scene)
        try:
            world = srv.app.world
            world.set_target_visible(False)
            rocks = world.rocks()
            for k, (start, goal) in enumerate(missions(scene, count, seed)):
                heading = math.degrees(math.atan2(goal[1] - start[1], goal[0] - start[0]))
                world.set_rover_pose(start[0], start[1], heading)
                srv.request(f"pose -x {start[0]} -y {start[1]} -heading {heading:.2f}")
                ground = world.rover_z()  # the DEM's heights are over the ground under the rover
                for sensor in sensors:
                    for cell in cells:
                        name = f"{sensor}{k}_{int(round(cell * 1000))}"
                        cmd = "dem-full-tof" if sensor == "tof" else "dem-full"
                        r = srv.request(f"{cmd} -range -180,180,-50,-15 -cell {cell} -name {name} -mesh false")
                        if r.status != "OK":
                            raise RuntimeError(f"{cmd}: {r.fields.get('message')}")
                        dem = read_dem(Path(tmp) / "dem" / f"{name}_dem.tif")
                        g = dem.geometry
                        k_sub = int(round(cell / 0.005))
                        true = world.true_dem(0.005, g.bounds, include_target=False) - np.float32(ground)
                        blocks = true.reshape(g.height, k_sub, g.width, k_sub)
                        top, mean = blocks.max(axis=(1, 3)), blocks.mean(axis=(1, 3))
                        xs, ys = g.centers()
                        X, Y = np.meshgrid(xs, ys)
                        d = np.hypot(X - start[0], Y - start[1])
                        on_rock = np.zeros(g.shape, bool)
                        for rk in rocks:
                            if abs(rk["x"] - start[0]) > 4 or abs(rk["y"] - start[1]) > 4:
                                continue
                            yaw = math.radians(rk["yaw"])
                            u = (X - rk["x"]) * math.cos(yaw) + (Y - rk["y"]) * math.sin(yaw)
                            v = -(X - rk["x"]) * math.sin(yaw) + (Y - rk["y"]) * math.cos(yaw)
                            on_rock |= (u / rk["a"]) ** 2 + (v / rk["b"]) ** 2 <= 1.0
                        band = (d >= BUDGET_RANGE[0]) & (d <= BUDGET_RANGE[1]) & np.isfinite(dem["dem"]) & np.isfinite(top)
                        bucket = out.setdefault((sensor, cell), {"rock": [], "ground": [], "shift": []})
                        # a DEM's heights are over the ground the server put under the rover when
                        # it was made: each is registered to the truth by its rock-free cells
                        bias = (mean - dem["dem"])[band & ~on_rock]
                        shift = float(np.median(bias)) if bias.size else 0.0
                        bucket["rock"].append((top - dem["dem"])[band & on_rock] - shift)
                        bucket["ground"].append(bias - shift)
                        bucket["shift"].append(np.array([shift]))
        finally:
            srv.stop()
    rows = []
    for (sensor, cell), b in out.items():
        rock, ground = np.concatenate(b["rock"]), np.concatenate(b["ground"])
        rows.append({"scene": scene, "sensor": sensor, "cell": cell, "rock_cells": int(rock.size),
                     "read_low_p50": _pct(list(rock), 50), "read_low_p99": _pct(list(rock), 99),
                     "ground_bias_p50": _pct(list(ground), 50),
                     "shift_max": round(float(np.max(np.abs(np.concatenate(b["shift"])))), 3)})
    return rows


def margin_table(budget: list[dict[str, Any]], rows: list[dict[str, Any]], body: RoverBody) -> list[str]:
    """The margins the budget gives (:class:`Margins`): per scene, the step threshold = the body's
    step capability minus the ToF's p99 read-low at 5 cm (the loops map with the ToF, the rolling
    map at 5 cm), or none left; the lateral margin = the missions' worst p99 path-tracking error."""
    cap = capability_hazard(body)
    lines = [f"step capability min(climb {body.climb:.3f}, clearance {body.clearance:.3f}) = {cap['step_max']:.3f} m "
             "(today's step_max 0.150)"]
    for b in budget:
        if b["sensor"] == "tof" and b["cell"] == 0.05 and b["read_low_p99"] is not None:
            left = cap["step_max"] - b["read_low_p99"]
            lines.append(f"  {b['scene']}: ToF read-low p99 at 5 cm {b['read_low_p99']:.3f} m -> step threshold "
                         + (f"{left:.3f} m" if left > 0 else "none left"))
    lines.append(f"tilt capability {body.tilt:.1f} deg -> slope threshold {body.tilt:.1f} deg (today 20.0; the slope's "
                 "read error is not measured)")
    track = [r["cross_track_p99"] for r in rows if "cross_track_p99" in r]
    lines.append(f"path tracking p99 (worst of {len(track)} missions) "
                 + (f"{max(track):.3f} m -> lateral margin {max(track):.3f} m" if track else "not measured")
                 + " (navigate.margin, today 0.100)")
    return lines


def _run(job: tuple[str, str, tuple[float, float], tuple[float, float], tuple[str, ...], int, str]) -> dict[str, Any]:
    """One mission (in a pool's process: the see loop's footprint comes along)."""
    scene, mode, start, goal, sets, i, footprint = job
    FOOTPRINT["see"] = footprint
    row = run_mission(scene, mode, start, goal, [], sets)
    row["mission"] = i
    return row


def print_summary(summary: list[dict[str, Any]]) -> None:
    print("\nscene     mode missions feasible reached(of feasible) failed events(worst excess)              safe stops "
          "efficiency(reached/perfect same) crossing(old, missions/cells) tracking_p99 scans sim_s wall_s cycle_ms")
    for s in summary:
        worst = ", ".join(f"{k} {v * 100:.1f} cm" if k != "tilt" else f"tilt {v:.1f} deg"
                          for k, v in s["worst_excess"].items()) or "-"
        eff = (f"{s['efficiency_reached']:.3f}/{s['perfect_efficiency_same']:.3f}"
               if s["efficiency_reached"] is not None else "-")
        print(f"{s['scene']:9} {s['mode']:4} {s['missions']:8} {s['feasible']:8} {s['reached']:3} ({s['reached_of_feasible']}/"
              f"{s['feasible']})  {s['failed']:6} {s['events']:3} ({worst:30}) {s['safe_stops']:4} {eff:>16} "
              f"{s['crossing_missions']:3}/{s['crossed_cells']:<5} {s['cross_track_p99_max']} {s['scans_per_mission']} "
              f"{s['sim_s_mean']} {s['wall_s_mean']} "
              + (f"{s['cycle_ms_mean']}/{s['cycle_ms_max']}" if s["mode"] == "see" else ""), flush=True)
        if s["stop_reasons"]:
            print(f"    safe stops: {s['stop_reasons']}; perfect-knowledge efficiency over all feasible "
                  f"{s['perfect_efficiency_feasible']}; today's-threshold perfect plans with events: "
                  f"{s['today_plans_with_events']}/{s['missions']}")
        else:
            print(f"    perfect-knowledge efficiency over all feasible {s['perfect_efficiency_feasible']}; "
                  f"today's-threshold perfect plans with events: {s['today_plans_with_events']}/{s['missions']}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--missions", type=int, default=10, help="missions per scene (10 in the issue)")
    ap.add_argument("--scenes", nargs="+", default=["marsyard", "hirise"])
    ap.add_argument("--modes", nargs="+", default=["scan", "see"], choices=["scan", "see"])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--replan-trials", type=int, default=20)
    ap.add_argument("--out", default="", help="also write the rows and the summary as JSON here")
    ap.add_argument("--footprint", choices=["circle", "body"], default=FOOTPRINT["see"],
                    help="the see loop's planning footprint")
    ap.add_argument("--ceiling", action="store_true",
                    help="only the perception ceiling: plans on perfect maps of the true surface (5 cm cell means, "
                         "3 cm means, the 1 cm surface) at step limits 16 to 12.5 cm")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a server setting for every mission (e.g. navigate.see_margin=0)")
    ap.add_argument("--jobs", type=int, default=1, choices=[1, 2], help="missions run in this many processes")
    ap.add_argument("--budget", action="store_true",
                    help="only the error budget: each sensor's DEM read-low error on rock cells (--missions starts), "
                         "and the margin table (the tracking error from --tracking-from)")
    ap.add_argument("--tracking-from", nargs="*", default=[], metavar="JSON",
                    help="with --budget: earlier runs' --out files, whose missions give the path-tracking error")
    ap.add_argument("--derived", action="store_true",
                    help="run with the thresholds the error budget gives (vehicle.Margins): dem2hazard.step_max, "
                         "dem2hazard.slope_max and navigate.margin")
    args = ap.parse_args(argv)
    missing = [f for f in args.tracking_from if not Path(f).is_file()]
    if missing:
        ap.error(f"--tracking-from: no such file {missing[0]} (a run's --out JSON)")
    body = World.from_scene(args.scenes[0]).body
    if args.derived:
        t = Margins().thresholds(body)
        args.set += [f"dem2hazard.step_max={t['step_max']}", f"dem2hazard.slope_max={t['slope_max']}",
                     f"navigate.margin={t['margin']}"]
        print("derived thresholds:", " ".join(args.set), flush=True)
    FOOTPRINT["see"] = args.footprint
    if args.ceiling:
        for scene in args.scenes:
            rows = perception_ceiling(scene, args.missions, args.seed, footprint=args.footprint,
                                      maps=tuple(CEILING_MAPS))
            print(f"\n{scene}: perfect maps of the true surface, the {args.footprint} plan on each, over the true "
                  "hazard map")
            print("map          step_max  reached  crossing  per mission (crossed cells, or x: no plan)")
            for kind, limit in dict.fromkeys((r["map"], r["step_max"]) for r in rows):
                sel = [r for r in rows if r["map"] == kind and r["step_max"] == limit]
                per = " ".join("x" if not r["reached"] else str(r["crossed_cells"]) for r in sel)
                print(f"{kind:12} {limit:8.3f} {sum(r['reached'] for r in sel):8} "
                      f"{sum(r['crossed_cells'] > 0 for r in sel):9}  {per}", flush=True)
        return
    if args.budget:
        budget = [b for scene in args.scenes for b in read_low_budget(scene, args.missions, args.seed)]
        print("\nscene     sensor cell   rock cells  read-low p50  p99 (m)   ground bias p50 (m)  height shift max (m)")
        for b in budget:
            print(f"{b['scene']:9} {b['sensor']:6} {b['cell']:.3f} {b['rock_cells']:10} {b['read_low_p50']:12} "
                  f"{b['read_low_p99']:8} {b['ground_bias_p50']:10} {b['shift_max']:10}", flush=True)
        tracked = [r for f in args.tracking_from for r in json.loads(Path(f).read_text())["rows"]]
        track = [r["cross_track_p50"] for r in tracked if "cross_track_p50" in r]
        if track:
            print(f"\npath tracking over {len(track)} missions: cross-track p50 (median of missions) "
                  f"{float(np.median(track)):.3f} m, p99 (worst mission) "
                  f"{max(r['cross_track_p99'] for r in tracked if 'cross_track_p99' in r):.3f} m")
        print("\nmargins:\n  " + "\n  ".join(margin_table(budget, tracked, body)))
        if args.out:
            Path(args.out).write_text(json.dumps({"budget": budget}, indent=1))
        return
    # scenes and modes interleaved mission by mission: a run cut short still compares them
    todo = {scene: missions(scene, args.missions, args.seed) for scene in args.scenes}
    jobs = [(scene, mode, *todo[scene][i], tuple(args.set), i, args.footprint) for i in range(args.missions)
            for scene in args.scenes for mode in args.modes]
    rows: list[dict[str, Any]] = []
    if args.jobs > 1:
        import multiprocessing

        with multiprocessing.get_context("spawn").Pool(args.jobs) as pool:
            for row in pool.imap(_run, jobs):
                rows.append(row)
                print(json.dumps(row), flush=True)
    else:
        for job in jobs:
            rows.append(_run(job))
            print(json.dumps(rows[-1]), flush=True)
    summary = summarise(rows)
    print_summary(summary)
    rep = replan_vs_astar(args.replan_trials, args.seed) if args.replan_trials > 0 else {}
    if rep:
        print(f"\nreplanning on {rep['grid'][0]} x {rep['grid'][1]} cells (a rock 3 m ahead on the path): D* Lite "
              f"repair p50 {rep['dstar_repair_ms_p50']} ms, fresh A* p50 {rep['astar_fresh_ms_p50']} ms, ratio "
              f"{rep['ratio']}x (D* Lite's first plan {rep['dstar_first_plan_ms_p50']} ms)")
    if args.out:
        Path(args.out).write_text(json.dumps({"rows": rows, "summary": summary, "replan": rep}, indent=1))


if __name__ == "__main__":
    main()
