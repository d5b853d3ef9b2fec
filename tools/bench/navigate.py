"""Benchmark: traverse efficiency of navigate -auto, today's stop-and-go loop (``-loop scan``: a
360-degree scan at every leg's end) against driving while seeing (``-loop see``), side by side on
the same seeded missions (issue 12, "Show").

Traverse efficiency = goal distance / (simulated time x top speed): 1.0 is a rover that drives
straight at full speed and never stops; Perseverance's ENav averages ~0.73, Curiosity's AutoNav
~0.12. Simulated time is the world's clock: the PTU moves at the D46's speed, each ToF frame
takes its exposure, the rover turns and drives at its scene speed (0.1 m/s, 15 deg/s); the
server's CPU time is not on it (``sim.time_scale=0``), so the figures do not depend on this
machine's load. What does depend on it is reported apart, in wall milliseconds: the see loop's
per-cycle latency (rolling map + Dem2Hazard + footprint check; target < 100 ms) and the
replanning time (A* on the merged maps as navigate runs it; and, on the same maps, D* Lite's
repair after the cells the drive changed against a fresh A*).

Missions: start and goal 15-20 m apart, both at least 1 m from every true hazard, seeded, in
``marsyard`` and in ``hirise`` (15 % rock cover). Per mission and mode: reached, efficiency (and
``ideal_efficiency``, the ceiling: the straight line over the plan on the true maps),
legs, scans, stops, and whether the rover crossed a true hazard: its true track (5 cm steps, the
simulator's ground truth), the rover body swept along it, over the true hazard map (Dem2Hazard of
the simulator's true DEM at 5 cm), with the worst crossed cell's true step and slope. Each ToF
frame and scan is rendered: 10 marsyard missions in both modes took 35 min here (a scan mission
~2.5 min, a see mission ~1 min); hirise's take longer: ``--missions N``.

    python -m tools.bench.navigate [--missions 2] [--scenes marsyard hirise] [--modes scan see]
    python -m tools.bench.navigate --scenes hirise --modes see --footprint body --set navigate.see_margin=0
    python -m tools.bench.navigate --ceiling --footprint body   # what perfect maps would do, in a minute
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import socket
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy import ndimage

from drivers.sim.world import World
from prox_workflows.grid import GridGeometry
from prox_workflows.steps.dem2hazard import HAZARDOUS, SAFE, UNDEFINED, HazardParams, classify, dem2hazard
from prox_workflows.steps.safety import check_move
from rvs_server.client.session import ServerThread
from rvs_server.protocol import Reply, parse_reply
from tools.global_maps import write_global_maps

TOP_SPEED = 0.1  # m/s: the scenes' rover speed
AREA = {"marsyard": (-5.5, -9.5, 13.5, 9.5), "hirise": (-14.0, -14.0, 14.0, 14.0)}
ORBITAL = {"hirise"}  # scenes built on an orbital DTM (tools.global_maps writes it)
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
    from prox_workflows.steps.planner import PlannerParams

    return PlannerParams(grid=cell, rover_radius=math.hypot(*ROVER) / 2, border=0.0,
                         half_width=ROVER[1] / 2 if footprint == "body" else None)


def ideal_efficiency(maps: dict[str, np.ndarray], g: GridGeometry, start: tuple[float, float],
                     goal: tuple[float, float], footprint: str) -> float:
    """The efficiency of a rover that knows the true maps and never stops: goal distance over
    the length of the plan's waypoints on them (navigate's planner and footprint; turns on the
    spot not counted): about what a mission can reach at best (hirise's rock field makes some
    missions detour to three times the straight line). 0 when the true maps show no way."""
    from prox_workflows.steps.planner import NavMaps, PlanningError, plan_path

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
    from prox_workflows.steps.planner import NavMaps, PlanningError, plan_path

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
    """One navigate -auto in a fresh server; the figures of the issue's table. A scene built on an
    orbital DTM gets it as navigate's global maps (issue 12 item 5), as a rover team would load
    its orbital map: the planner then knows the terrain's extent and its slopes beyond the scans."""
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
            track_file = Path(tmp) / "nav" / "bench_track.csv"
            if track_file.exists():
                with open(track_file) as fh:
                    track = np.array([[float(row["x"]), float(row["y"])] for row in csv.DictReader(fh)])
            else:  # navigate leaves its track whenever the rover moved
                track = np.array([start])
            maps, g = true_maps(world, AREA[scene])
            out["ideal_efficiency"] = ideal_efficiency(maps, g, start, goal, FOOTPRINT[mode])
            out["crossed_cells"], worst_step, worst_slope = crossed(track, maps, g)
            if out["crossed_cells"]:
                out["crossed_step_m"], out["crossed_slope_deg"] = round(worst_step, 3), round(worst_slope, 1)
            return out
        finally:
            srv.stop()


def summarise(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per scene and mode: missions reached, efficiency (mean over all, reached count as 0 when
    not), crossings, scans per mission, latency."""
    out = []
    for scene in dict.fromkeys(r["scene"] for r in rows):
        for mode in dict.fromkeys(r["mode"] for r in rows):
            sel = [r for r in rows if r["scene"] == scene and r["mode"] == mode]
            if not sel:
                continue
            reached = [r for r in sel if r["reached"]]
            s = {"scene": scene, "mode": mode, "missions": len(sel), "reached": len(reached),
                 "efficiency_mean": round(float(np.mean([r["efficiency"] for r in sel])), 3),
                 "efficiency_reached": round(float(np.mean([r["efficiency"] for r in reached])), 3) if reached
                 else None,
                 "ideal_efficiency_mean": round(float(np.mean([r["ideal_efficiency"] for r in sel])), 3),
                 "crossing_missions": sum(1 for r in sel if r["crossed_cells"] > 0),
                 "crossed_step_max": max((r.get("crossed_step_m", 0.0) for r in sel), default=0.0),
                 "scans_per_mission": round(float(np.mean([r.get("scans", r.get("legs", 0)) for r in sel])), 2),
                 "sim_s_mean": round(float(np.mean([r["sim_s"] for r in sel])), 1),
                 "wall_s_mean": round(float(np.mean([r["wall_s"] for r in sel])), 1)}
            if mode == "see":
                cyc = [r["cycle_ms"] for r in sel if r.get("cycles")]
                s["cycle_ms_mean"] = round(float(np.mean(cyc)), 1) if cyc else None
                s["cycle_ms_max"] = max((r.get("cycle_ms_max", 0.0) for r in sel), default=None)
                s["frame_ms_mean"] = round(float(np.mean([r.get("frame_ms", 0.0) for r in sel])), 1)
                s["replan_ms_mean"] = round(float(np.mean([r.get("replan_ms", 0.0) for r in sel])), 1)
                s["stops"] = sum(int(r.get("stops", 0)) for r in sel)
            out.append(s)
    return out


def replan_vs_astar(trials: int = 20, seed: int = 0) -> dict[str, Any]:
    """D* Lite's repair after a rock appears 3 m ahead on the path, against a fresh A*, on a
    planning image of 400 x 400 cells (20 m at 5 cm) built as navigate builds it from marsyard's
    true hazard map; the path costs must agree."""
    from prox_workflows.steps.planner import NavMaps, PlannerParams, astar_grid, planning_image
    from prox_workflows.steps.planner import warm_up as astar_warm_up
    from prox_workflows.steps.replan import IncrementalPlanner
    from prox_workflows.steps.replan import warm_up as replan_warm_up

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
    args = ap.parse_args(argv)
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
    rows: list[dict[str, Any]] = []
    for scene in args.scenes:
        for i, (start, goal) in enumerate(missions(scene, args.missions, args.seed)):
            for mode in args.modes:
                row = run_mission(scene, mode, start, goal, [], tuple(args.set))
                row["mission"] = i
                rows.append(row)
                print(json.dumps(row), flush=True)
    summary = summarise(rows)
    print("\nscene     mode  missions reached efficiency(all/reached/ideal) crossing(worst step) scans/mission sim_s  "
          "wall_s  cycle_ms(mean/max) frame_ms replan_ms")
    for s in summary:
        print(f"{s['scene']:9} {s['mode']:5} {s['missions']:8} {s['reached']:7} {s['efficiency_mean']:11.3f}/"
              f"{s['efficiency_reached'] if s['efficiency_reached'] is not None else float('nan'):.3f}/"
              f"{s['ideal_efficiency_mean']:.3f}"
              f" {s['crossing_missions']:8}({s['crossed_step_max']:.3f} m) {s['scans_per_mission']:13.2f} {s['sim_s_mean']:6.1f} {s['wall_s_mean']:7.1f}"
              + (f"  {s['cycle_ms_mean']}/{s['cycle_ms_max']} {s['frame_ms_mean']} {s['replan_ms_mean']}"
                 if s["mode"] == "see" else ""), flush=True)
    rep = replan_vs_astar(args.replan_trials, args.seed) if args.replan_trials > 0 else {}
    if rep:
        print(f"\nreplanning on {rep['grid'][0]} x {rep['grid'][1]} cells (a rock 3 m ahead on the path): D* Lite "
              f"repair p50 {rep['dstar_repair_ms_p50']} ms, fresh A* p50 {rep['astar_fresh_ms_p50']} ms, ratio "
              f"{rep['ratio']}x (D* Lite's first plan {rep['dstar_first_plan_ms_p50']} ms)")
    if args.out:
        Path(args.out).write_text(json.dumps({"rows": rows, "summary": summary, "replan": rep}, indent=1))


if __name__ == "__main__":
    main()
