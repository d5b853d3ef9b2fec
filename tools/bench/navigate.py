"""Benchmark: navigate -auto's two loops, stop-and-go (``-loop scan``: a 360-degree scan where it
starts and 3 m on from each, the chooser's sections between; ``--set navigate.scan_plan=circle``
for the thesis's legs, each planned on its scan's hazard map) and driving while seeing (``-loop
see``), side by side on the same seeded missions,
judged by the vehicle itself (docs/NAVIGATE_BENCH.md).

The yardstick is the rover's own body (``drivers.sim.rover.RoverBody``, declared in the scene's
``rover: body:`` block): at every true pose of the track (the simulator's truth, interpolated to
2 cm, turns on the spot included, headings from the track's ``heading`` column), on the
simulator's 1 cm surface, :mod:`prox_workflows.algorithms.vehicle` checks the four physical limits:
each wheel's step edge against the climb, the ground under the belly against its clearance, the
resting plane's tilt against the tip-over angle over the safety factor (stability) and the plane
fitted under the body against the grade. Consecutive unsafe poses are one **event**, with its kind,
worst excess and severity band; one event fails the mission. A mission is **feasible** when a search with the body finds a way
(:mod:`rvs_truth.oracle`: a lattice over x, y and heading on the true 1 cm surface, every motion
judged by the same check, its path verified by the truth check; cached per mission under
``--oracle-cache``); its efficiency there is the **oracle efficiency**. The window-step
feasibility (navigate's planner on the true surface's hazard map, thresholds at the body's
capability and looser, a plan that passes the check) stays beside it once, for comparison: it
is a lower bound on what the body can do. Per mission: events, reached, the stop's reason when the rover
halted by itself (a **safe stop**: not reached, no event), efficiency beside the perfect-knowledge
efficiency, and the old score: true hazard cells (Dem2Hazard of the true DEM at 5 cm) under the
0.51 x 0.40 m box swept along the track, counted once per 5 cm chord.

Traverse efficiency = goal distance / (simulated time x top speed): 1.0 is a rover that drives
straight at full speed and never stops. Simulated time is the world's clock (``sim.time_scale=0``),
and where it went is each row's ``time_split`` (``SimClock.spent``: driving, reversing, turning on
the spot, the PTU's moves awaited, the frames taken standing), printed per scene as shares: what
the efficiency lost goes to. The see loop's cycle latency and the replanning times are wall
milliseconds, apart.

``--budget`` measures the error budget the margins come from: each sensor's DEM (dem-full-tof,
dem-full) at 5 and 2.5 cm from mission starts, against the true surface: how much lower than the
true top a rock cell reads (p50, p99); with the missions' path-tracking error (the true track's
distance from the planned waypoint legs) it prints the margin table.

    python -m tools.bench.navigate --missions 10 --scenes marsyard hirise --modes see --jobs 2
    python -m tools.bench.navigate --missions 4 --modes scan --jobs 2
    python -m tools.bench.navigate --budget --scenes marsyard hirise
    python -m tools.bench.navigate --ceiling --footprint body --scenes hirise   # perfect maps, 35 s
    python -m tools.bench.navigate --oracle --missions 5 --scenes marsyard hirise dense --jobs 2
    python -m tools.bench.navigate --missions 3 --scenes marsyard --modes see --jobs 1 --slip 0.05,2
    python -m tools.bench.navigate --missions 5 --scenes dense --modes see --noise-seeds 0 1 2
    python -m tools.bench.navigate --missions 6 --scenes dense_fresh hirise_fresh --modes see --live-risk

``dense_fresh`` and ``hirise_fresh`` are dense's and hirise's ground under rock draws no setting
was tuned on. ``--live-risk`` judges every pose the see loop's chance check judged against the
truth (:mod:`tools.bench.live_risk`), per scene: the stated risk on the loop's own judgements.

``--slip SHARE,DEG_PER_M`` runs every mission with the simulated rover's wheels slipping
(``sim slip``: it covers 1 - SHARE of what its odometry counts and its heading drifts DEG_PER_M
per metre to one side, seeded per mission) and no GNC pose: navigate -auto's pose is the
rover's dead reckoning, so the loop steers, places its frames and judges its arrival by a
pose that parts from the truth. The row then holds, beside ``true_miss`` (the true distance
from the goal where the rover stopped: the simulator's pose, never the loop's), the loop's own
``believed_miss`` and ``true_reached`` (the true distance within navigate's tolerance).
``--noise-seeds 0 1 2`` runs every mission under each sensor noise draw (the simulated ToF's,
pairs' and hazard cameras' seed; the world, the mission and every setting the same) and prints
each mission's reach over the draws: a mission turns on single refusals, and one run of it
flips with any change to the frames.
``--localise MODE`` gives navigate ``-localise MODE`` with the scene's true DEM at 0.5 m as its
orbital map (``-global``, a UTM GeoTIFF, as ``tools.bench.localise`` gives it): the fixes that
can bring the true pose back within the tolerance.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import dataclasses
import json
import math
import socket
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from drivers.registry import DEVICE_KINDS, registry
from drivers.sim.rover import RoverBody
from drivers.sim.world import World
from prox_workflows.algorithms.dem2hazard import HazardParams, dem2hazard
from prox_workflows.algorithms.vehicle import Margins, densify, unsafe_events
from prox_workflows.grid import GridGeometry
from rvs_server.client.session import ServerThread
from rvs_server.protocol import Reply, parse_reply
from rvs_truth.ceiling import perception_ceiling
from rvs_truth.oracle import default_cache_dir, mission_oracle
from rvs_truth.orbital import ORIGIN, from_orbit, orbital_geotiff, write_global_maps
from rvs_truth.surface import CEILING_MAPS, area, missions, true_maps, truth_checks, truth_surface
from rvs_truth.vehicle import (
    ROVER,
    TRACK_STEP,
    capability_hazard,
    cross_track,
    crossed,
    feasibility,
    mission_hazard,
    perfect_plan,
    read_track,
    stop_reason,
)
from tools.bench.live_risk import Recorder, lines, live_risk, summed
from tools.bench.rows import streamed


def drive_time(poses: np.ndarray, speed: float, turn_rate: float) -> float:
    """The least time (s) the rover takes along ``poses`` (x, y, heading in deg) as the simulated
    rover drives: each step at ``speed``, or slower where its heading change needs it at
    ``turn_rate`` (deg/s: an arc no faster than the turn rate drives its curvature, a turn on the
    spot at the turn rate). A path's own time, without looks or stops: the oracle's path timed so
    that its efficiency and a mission's are the same measure."""
    p = np.asarray(poses, float).reshape(-1, 3)
    ds = np.hypot(np.diff(p[:, 0]), np.diff(p[:, 1]))
    dh = np.abs((np.diff(p[:, 2]) + 180.0) % 360.0 - 180.0)
    return float(np.maximum(ds / speed, dh / turn_rate).sum())
# m: where the see loop is set down it takes the ground round the mast's foot that no tilt shows
# (0.72 m) as clear; a body at its edge reaches a little further. Events only there come from that
# assumption, not from ground the loop judged.
SET_DOWN_REACH = 1.0
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


def scene_server(data: Path, scene: str, sets: tuple[str, ...] | list[str] = ()) -> _Server:
    """The server for a mission in ``scene`` with its data in ``data``, the target hidden. A scene
    built on an orbital DTM gets it as navigate's global maps, as a rover team would load its
    orbital map."""
    sets = list(sets)
    if from_orbit(scene):
        write_global_maps(scene, data / "global")
        sets.append(f"navigate.global_maps={data / 'global'}")
    srv = _Server(data, scene, sets)
    srv.app.world.set_target_visible(False)
    return srv


def slip_lines(slip: tuple[float, float] | None, seed: int, mission: int) -> list[str]:
    """The requests that make a mission's wheels slip (``sim slip``), seeded by the draw and the
    mission so a rerun slips the same way; none without ``slip`` (share, deg per m)."""
    if slip is None:
        return []
    return [f"sim slip -distance {slip[0]:g} -heading {slip[1]:g} -seed {seed * 1000 + mission}"]


def noise_sets(noise: int) -> list[str]:
    """The settings that give every simulated sensor with a noise generator (the device kinds whose
    settings declare ``seed``) the noise draw ``noise``: the same world and mission, other frames.
    A mission's outcome turns on single refusals, so one run of it says little of a change worth
    one mission in ten; its reach over several draws does."""
    kinds = [k for k in DEVICE_KINDS if "seed" in {f.name for f in dataclasses.fields(registry(k).settings_class())}]
    return [f"drivers.{kind}.seed={noise}" for kind in kinds]


def parse_slip(text: str) -> tuple[float, float]:
    """``--slip``'s SHARE,DEG_PER_M (0.05,2: 5 % short, 2 deg per metre): ValueError that says
    what to give otherwise."""
    parts = text.split(",")
    try:
        share, drift = (float(v) for v in parts)
    except ValueError:
        raise ValueError(f"--slip {text!r}: give SHARE,DEG_PER_M, e.g. 0.05,2 (5 % slip, 2 deg per metre)") from None
    if not (0.0 <= share <= 0.9 and 0.0 <= drift <= 90.0):
        raise ValueError(f"--slip {text!r}: the share is 0 to 0.9 and the drift 0 to 90 deg per metre (sim slip's "
                         "ranges)")
    return share, drift


def arrival(world: World, believed: tuple[float, float], goal: tuple[float, float], tolerance: float
            ) -> dict[str, Any]:
    """Where a mission ended against its goal: the true distance (the simulator's pose), the
    distance the loop believes (its pose: dead reckoning without a GNC) and whether the true
    one is within navigate's ``tolerance``."""
    truth = world.truth()
    miss = math.hypot(truth["x"] - goal[0], truth["y"] - goal[1])
    return {"true_miss": round(miss, 3),
            "believed_miss": round(math.hypot(believed[0] - goal[0], believed[1] - goal[1]), 3),
            "true_reached": bool(miss <= tolerance)}


def localise_options(world: World, folder: Path, mode: str) -> str:
    """navigate's options for ``-localise mode``: the world's true DEM at 0.5 m written into
    ``folder`` as the orbital map it matches on (``-global``, placed by ``-global-origin``); ""
    for none."""
    if mode == "none":
        return ""
    orbit = orbital_geotiff(world, folder / "orbit.tif")
    return f"-localise {mode} -global {orbit} -global-origin {ORIGIN[0]},{ORIGIN[1]}"


def run_mission(scene: str, mode: str, start: tuple[float, float], goal: tuple[float, float],
                extra: list[str], sets: tuple[str, ...] = (), seed: int = 0,
                oracle_cache: Path | None = None, localise: str = "none") -> dict[str, Any]:
    """One navigate -auto in a fresh server (:func:`scene_server`), judged by the vehicle check;
    with ``localise`` other than none, navigate matches on the scene's true DEM at 0.5 m."""
    with tempfile.TemporaryDirectory() as tmp:
        srv = scene_server(Path(tmp), scene, sets)
        try:
            world = srv.app.world
            for line in extra:
                srv.request(line)
            heading = math.degrees(math.atan2(goal[1] - start[1], goal[0] - start[0]))
            fixes = localise_options(world, Path(tmp), localise)
            t_sim0, t_wall0, spent0 = world.clock.now(), time.monotonic(), world.clock.spent.copy()
            r = srv.request(f"navigate -start {start[0]},{start[1]},{heading:.1f} -goal {goal[0]},{goal[1]} "
                            f"-auto -loop {mode} -footprint {FOOTPRINT[mode]} -name bench -max-legs 30 {fixes}".rstrip())
            sim_s = world.clock.now() - t_sim0
            spent = world.clock.spent - spent0
            wall_s = time.monotonic() - t_wall0
            dist = math.hypot(goal[0] - start[0], goal[1] - start[1])
            out: dict[str, Any] = {"scene": scene, "mode": mode, "start": start, "goal": goal,
                                   "distance": round(dist, 2), "status": r.status, "sim_s": round(sim_s, 1),
                                   "wall_s": round(wall_s, 1),
                                   "time_split": {what: round(t, 1) for what, t in spent.most_common()},
                                   **arrival(world, (srv.app.pose.x, srv.app.pose.y), goal,
                                             srv.app.config.get("navigate").tolerance)}
            if world.slip.active:
                out["slip"] = [world.slip.distance, world.slip.heading]
            if localise != "none":
                out["localise"] = localise
            out["reached"] = r.status == "OK" and r.fields.get("reached") == "true"
            speed, turn_rate = world.drive_model.speed, world.drive_model.turn_rate
            out["efficiency"] = round(dist / (sim_s * speed), 3) if out["reached"] else 0.0
            for key in ("legs", "scans", "replans", "stops", "looks", "retreats", "cycles", "cycle_ms", "cycle_ms_max", "cycle_ms_p95",
                        "cycle_cpu_ms_p95", "frame_ms", "replan_ms", "replan_ms_p95", "replan_cpu_ms_p95", "searches",
                        "repairs"):
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
            dense = densify(poses, TRACK_STEP, body)  # judged under every pose, wherever the track went
            events, checked = unsafe_events(truth_checks(world, scene, dense, body), dense, body), len(dense)
            out["events"] = [{"kind": e.kind, "excess": e.excess, "band": e.band, "x": round(e.x, 2), "y": round(e.y, 2),
                              "heading": round(e.heading, 1)} for e in events]
            out["poses_checked"] = checked
            driven = float(np.hypot(*np.diff(poses[:, :2], axis=0).T).sum())
            out["path_efficiency"] = round(dist / driven, 3) if out["reached"] and driven > 0 else 0.0
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
            maps, g = true_maps(world, area(scene))
            out["crossed_cells"], worst_step, worst_slope = crossed(poses[:, :2], maps, g)
            if out["crossed_cells"]:
                out["crossed_step_m"], out["crossed_slope_deg"] = round(worst_step, 3), round(worst_slope, 1)
            found = mission_oracle(scene, seed, start, goal, body, oracle_cache)
            out["feasible"], out["perfect_efficiency"] = found["feasible"], found["efficiency"]
            out["oracle_reason"] = found["reason"]
            out["oracle_time_efficiency"] = (round(dist / (speed * drive_time(np.array(found["path"]), speed, turn_rate)), 3)
                                             if found["feasible"] else 0.0)
            feas = feasibility(surface, body, start, goal, FOOTPRINT[mode])
            out["window_feasible"], out["window_efficiency"] = feas["feasible"], feas["efficiency"]
            out["window_step_max"] = feas["step_max"]
            today = perfect_plan(surface, body, start, goal, FOOTPRINT[mode], mission_hazard(sets))
            out["today_plan"] = {"reached": today["reached"], "efficiency": today["efficiency"],
                                 "events": [f"{e.kind} +{e.excess:.3f}" for e in today["events"]]}
            return out
        finally:
            srv.stop()


def _pct(values: list[float], q: float) -> float | None:
    return round(float(np.percentile(values, q)), 3) if values else None


def _mean(values: list[float | None]) -> float | None:
    """The mean of the values a row has (rows from before a field was measured lack it)."""
    known = [v for v in values if v is not None]
    return round(float(np.mean(known)), 3) if known else None


def _time_split(rows: list[dict[str, Any]]) -> dict[str, float]:
    """Where the missions' simulated time went (the share of each thing that moved the world's
    clock on, ``SimClock.spent``), over the runs that record it."""
    rows = [r for r in rows if "time_split" in r]
    total = sum(r["sim_s"] for r in rows)
    shares: Counter[str] = Counter()
    for r in rows:
        shares.update(r["time_split"])
    return {what: round(t / total, 3) for what, t in shares.most_common()} if total > 0 else {}


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
                 "window_feasible": sum(1 for r in sel if r.get("window_feasible")),
                 "reached": len(reached), "reached_of_feasible": sum(1 for r in feasible if r["reached"]),
                 "true_reached": sum(1 for r in sel if r.get("true_reached")),
                 "true_miss_median": round(float(np.median([r["true_miss"] for r in sel])), 3),
                 "believed_miss_median": round(float(np.median([r.get("believed_miss", r["true_miss"])
                                                                for r in sel])), 3),
                 "failed": sum(1 for r in sel if r["events"]), "events": len(events),
                 "failed_at_set_down": sum(1 for r in sel if r["events"] and all(
                     math.hypot(e["x"] - r["start"][0], e["y"] - r["start"][1]) <= SET_DOWN_REACH for e in r["events"])),
                 "progress_median": round(float(np.median([r["distance"] - r["true_miss"] for r in sel])), 2),
                 "progress_best": round(float(max(r["distance"] - r["true_miss"] for r in sel)), 2),
                 "events_per_kind": {k: sum(1 for e in events if e["kind"].split()[0] == k) for k in worst},
                 "worst_excess": worst,
                 "events_per_band": dict(Counter(e.get("band", "?") for e in events)),
                 "safe_stops": sum(1 for r in sel if "safe_stop" in r),
                 "stop_reasons": dict(Counter(r["safe_stop"] for r in sel if "safe_stop" in r)),
                 "efficiency_reached": round(float(np.mean([r["efficiency"] for r in ok])), 3) if ok else None,
                 "perfect_efficiency_same": round(float(np.mean([r["perfect_efficiency"] for r in ok])), 3) if ok
                 else None,
                 "path_efficiency_reached": _mean([r.get("path_efficiency") for r in ok]),
                 "oracle_time_efficiency_same": _mean([r.get("oracle_time_efficiency") for r in ok]),
                 "perfect_efficiency_feasible": round(float(np.mean([r["perfect_efficiency"] for r in feasible])), 3)
                 if feasible else None,
                 "crossing_missions": sum(1 for r in sel if r["crossed_cells"] > 0),
                 "crossed_cells": sum(r["crossed_cells"] for r in sel),
                 "cross_track_p99_max": max(track) if track else None,
                 "today_plans_with_events": sum(1 for r in sel if r["today_plan"]["events"]),
                 "scans_per_mission": round(float(np.mean([r.get("scans", r.get("legs", 0)) for r in sel])), 2),
                 "time_split": _time_split(sel),
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
                ground = world.rover_z()  # the DEM's heights are over the rover origin (its wheels' plane)
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
    lines.append(f"grade capability {body.grade:.1f} deg -> slope threshold {body.grade:.1f} deg (today 20.0; the slope's "
                 "read error is not measured)")
    track = [r["cross_track_p99"] for r in rows if "cross_track_p99" in r]
    lines.append(f"path tracking p99 (worst of {len(track)} missions) "
                 + (f"{max(track):.3f} m -> lateral margin {max(track):.3f} m" if track else "not measured")
                 + " (navigate.margin, today 0.100)")
    return lines


def _run(job: tuple[str, str, tuple[float, float], tuple[float, float], tuple[str, ...], int, str, int, str,
               tuple[float, float] | None, str, int, bool]) -> dict[str, Any]:
    """One mission (in a pool's process: the see loop's footprint comes along); with ``live``,
    every pose its checks judged, against the truth (:mod:`tools.bench.live_risk`)."""
    scene, mode, start, goal, sets, i, footprint, seed, cache, slip, localise, noise, live = job
    FOOTPRINT["see"] = footprint
    with Recorder().installed() if live else contextlib.nullcontext() as rec:
        row = run_mission(scene, mode, start, goal, slip_lines(slip, seed, i), (*sets, *noise_sets(noise)), seed,
                          Path(cache), localise)
    if rec is not None:
        world = World.from_scene(scene)
        row["live_risk"] = live_risk(rec.judged, lambda poses: truth_checks(world, scene, poses, world.body))
    row["mission"], row["noise"] = i, noise
    return row



def reach_over_draws(rows: list[dict[str, Any]]) -> list[str]:
    """Per scene and mode, each mission's reached draws over its runs (``m3 2/3``), and the share
    of all runs reached: what a change is weighed by when single runs flip."""
    lines = []
    for scene, mode in dict.fromkeys((r["scene"], r["mode"]) for r in rows):
        sel = [r for r in rows if r["scene"] == scene and r["mode"] == mode]
        per = {}
        for r in sel:
            per.setdefault(r["mission"], []).append(r["reached"])
        cells = " ".join(f"m{m} {sum(v)}/{len(v)}" for m, v in sorted(per.items()))
        lines.append(f"{scene} {mode}: {cells}; {sum(r['reached'] for r in sel)} of {len(sel)} runs")
    return lines


def print_summary(summary: list[dict[str, Any]]) -> None:
    print("\nscene     mode missions feasible(window) reached(of feasible) failed events(worst excess)              safe stops "
          "efficiency(reached/perfect same) crossing(old, missions/cells) tracking_p99 scans sim_s wall_s cycle_ms")
    for s in summary:
        worst = ", ".join(f"{k} {v * 100:.1f} cm" if k in ("step", "belly") else f"{k} {v:.1f} deg"
                          for k, v in s["worst_excess"].items()) or "-"
        eff = (f"{s['efficiency_reached']:.3f}/{s['perfect_efficiency_same']:.3f}"
               if s["efficiency_reached"] is not None else "-")
        print(f"{s['scene']:9} {s['mode']:4} {s['missions']:8} {s['feasible']:8}({s['window_feasible']}) {s['reached']:3} ({s['reached_of_feasible']}/"
              f"{s['feasible']})  {s['failed']:6} {s['events']:3} ({worst:30}) {s['safe_stops']:4} {eff:>16} "
              f"{s['crossing_missions']:3}/{s['crossed_cells']:<5} {s['cross_track_p99_max']} {s['scans_per_mission']} "
              f"{s['sim_s_mean']} {s['wall_s_mean']} "
              + (f"{s['cycle_ms_mean']}/{s['cycle_ms_max']}" if s["mode"] == "see" else ""), flush=True)
        print(f"    failed with every event within {SET_DOWN_REACH} m of the start: "
              f"{s['failed_at_set_down']}/{s['failed']}; progress toward the goal median "
              f"{s['progress_median']} m, best {s['progress_best']} m; reached by path length "
              f"{s['path_efficiency_reached']} (the oracle's above), by time {s['efficiency_reached']} against the "
              f"oracle's path timed {s['oracle_time_efficiency_same']}")
        if s["time_split"]:
            print("    simulated time: " + ", ".join(f"{what} {share:.1%}" for what, share in s["time_split"].items()))
        print(f"    truly within the tolerance at the end: {s['true_reached']}/{s['missions']} (reached by its own "
              f"pose: {s['reached']}); miss median true {s['true_miss_median']} m, believed "
              f"{s['believed_miss_median']} m")
        if s["stop_reasons"]:
            print(f"    safe stops: {s['stop_reasons']}; perfect-knowledge efficiency over all feasible "
                  f"{s['perfect_efficiency_feasible']}; today's-threshold perfect plans with events: "
                  f"{s['today_plans_with_events']}/{s['missions']}")
        else:
            print(f"    perfect-knowledge efficiency over all feasible {s['perfect_efficiency_feasible']}; "
                  f"today's-threshold perfect plans with events: {s['today_plans_with_events']}/{s['missions']}")


def _oracle_job(job: tuple[str, int, int, tuple[float, float], tuple[float, float], str]) -> dict[str, Any]:
    """One mission's oracle and, for comparison, its window-step feasibility (in a pool's process)."""
    scene, seed, i, start, goal, cache = job
    world = World.from_scene(scene)
    row = mission_oracle(scene, seed, start, goal, world.body, Path(cache))
    row.pop("path", None)
    t0 = time.perf_counter()
    feas = feasibility(truth_surface(world, scene), world.body, start, goal, "circle")
    row.update(mission=i, window_feasible=feas["feasible"], window_efficiency=feas["efficiency"],
               window_seconds=round(time.perf_counter() - t0, 1))
    return row


def oracle_table(scenes: list[str], count: int, seed: int, jobs: int, cache: Path, out: str) -> list[dict[str, Any]]:
    """The oracle's table: per scene, feasible missions (and why not: no way, or the budget met),
    the oracle efficiency of the feasible ones, the time per mission (computed, not read from the
    cache), beside the window-step feasibility (navigate's circle planner)."""
    todo = [(scene, seed, i, *m, str(cache)) for scene in scenes for i, m in enumerate(missions(scene, count, seed))]
    rows = streamed(_oracle_job, todo, jobs)
    print("\nscene     missions feasible (no way / budget / refused)  oracle efficiency mean (per mission)   "
          "s/mission mean max  window-step feasible, efficiency")
    for scene in scenes:
        sel = sorted((r for r in rows if r["scene"] == scene), key=lambda r: r["mission"])
        ok = [r for r in sel if r["feasible"]]
        why = Counter(r["reason"] for r in sel if not r["feasible"])
        fresh = [r["seconds"] for r in sel if not r["cached"]] or [r["seconds"] for r in sel]
        win = [r for r in sel if r["window_feasible"]]
        per = " ".join(f"{r['efficiency']:.3f}" if r["feasible"] else "x" for r in sel)
        eff = f"{np.mean([r['efficiency'] for r in ok]):.3f}" if ok else "-"
        weff = f"{np.mean([r['window_efficiency'] for r in win]):.3f}" if win else "-"
        print(f"{scene:9} {len(sel):8} {len(ok):8} ({why['exhausted']} / {why['budget']} / "
              f"{why['refused by the truth check']})  {eff:>8} ({per})  {np.mean(fresh):7.1f} {max(fresh):6.1f}  "
              f"{len(win)}, {weff}", flush=True)
    if out:
        Path(out).write_text(json.dumps({"oracle": rows}, indent=1))
    return rows


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--missions", type=int, default=10, help="missions per scene (10 in the issue)")
    ap.add_argument("--first", type=int, default=0,
                    help="the first mission to run: a long run split across processes or resumed runs "
                         "missions --first to --missions - 1 of the same draw")
    ap.add_argument("--scenes", nargs="+", default=["marsyard", "hirise"])
    ap.add_argument("--modes", nargs="+", default=["scan", "see"], choices=["scan", "see"])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--noise-seeds", type=int, nargs="+", default=[0], metavar="N",
                    help="run every mission under each of these sensor noise draws (the simulated sensors' seed): "
                         "its reach over several draws, where one run turns on single refusals")
    ap.add_argument("--replan-trials", type=int, default=20)
    ap.add_argument("--live-risk", action="store_true",
                    help="also judge every pose the see loop's chance check judged against the truth: the live "
                         "check's false-safe rate per judged pose, choosing and driving (tools.bench.live_risk)")
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
    ap.add_argument("--oracle", action="store_true",
                    help="only the feasibility oracle: per scene, the missions the body can drive (a lattice search "
                         "with the vehicle check on the true 1 cm surface), their oracle efficiency and its time per "
                         "mission, beside the window-step feasibility")
    ap.add_argument("--oracle-cache", default=str(default_cache_dir()),
                    help="where the oracle keeps its verdicts per mission, body and code (default: %(default)s)")
    ap.add_argument("--slip", default="", metavar="SHARE,DEG_PER_M",
                    help="every mission with the wheels slipping (sim slip, seeded per mission) and no GNC pose: "
                         "0.05,2 is 5 %% slip and 2 deg of heading drift per metre; the rows add the loop's "
                         "believed_miss and true_reached (the true distance within navigate's tolerance)")
    ap.add_argument("--localise", default="none", choices=["none", "vo", "map", "both"],
                    help="navigate -localise for every mission, the scene's true DEM at 0.5 m as its orbital map "
                         "(-global): with --slip, what brings the true pose back")
    ap.add_argument("--derived", action="store_true",
                    help="run with the thresholds the error budget gives (vehicle.Margins): dem2hazard.step_max, "
                         "dem2hazard.slope_max and navigate.margin")
    args = ap.parse_args(argv)
    try:
        slip = parse_slip(args.slip) if args.slip else None
    except ValueError as e:
        ap.error(str(e))
    missing = [f for f in args.tracking_from if not Path(f).is_file()]
    if missing:
        ap.error(f"--tracking-from: no such file {missing[0]} (a run's --out JSON)")
    # the noise draw's settings come after --set's, so a seed given there would be overridden
    seeded = {s.split("=", 1)[0] for s in noise_sets(0)}
    clash = [s for s in args.set if s.split("=", 1)[0].strip() in seeded]
    if clash:
        ap.error(f"--set {clash[0]}: the simulated sensors' noise draw is --noise-seeds N (it sets "
                 f"{', '.join(sorted(seeded))}); give the draw there")
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
    if args.oracle:
        oracle_table(args.scenes, args.missions, args.seed, args.jobs, Path(args.oracle_cache), args.out)
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
    jobs = [(scene, mode, *todo[scene][i], tuple(args.set), i, args.footprint, args.seed, args.oracle_cache, slip,
             args.localise, noise, args.live_risk)
            for noise in args.noise_seeds for i in range(args.first, args.missions)
            for scene in args.scenes for mode in args.modes]
    rows = streamed(_run, jobs, args.jobs)
    summary = summarise(rows)
    print_summary(summary)
    for scene in dict.fromkeys(r["scene"] for r in rows if "live_risk" in r):
        live = summed([r["live_risk"] for r in rows if r["scene"] == scene and "live_risk" in r])
        print(f"\n{scene}: " + f"\n{scene}: ".join(lines(live)))
    if len(args.noise_seeds) > 1:
        print("\nreached per mission over the noise draws " + " ".join(map(str, args.noise_seeds)) + ":")
        for line in reach_over_draws(rows):
            print("  " + line)
    rep = replan_vs_astar(args.replan_trials, args.seed) if args.replan_trials > 0 else {}
    if rep:
        print(f"\nreplanning on {rep['grid'][0]} x {rep['grid'][1]} cells (a rock 3 m ahead on the path): D* Lite "
              f"repair p50 {rep['dstar_repair_ms_p50']} ms, fresh A* p50 {rep['astar_fresh_ms_p50']} ms, ratio "
              f"{rep['ratio']}x (D* Lite's first plan {rep['dstar_first_plan_ms_p50']} ms)")
    if args.out:
        Path(args.out).write_text(json.dumps({"rows": rows, "summary": summary, "replan": rep}, indent=1))


if __name__ == "__main__":
    main()
