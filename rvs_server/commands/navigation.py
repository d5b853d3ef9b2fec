"""Navigation commands: check-move (the safety gate) and navigate (seed 000 sect. 4.4.4, appendix F)."""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from prox_workflows.engine import run_workflow
from prox_workflows.parameters import PlanParams
from prox_workflows.params import reuse
from prox_workflows.steps.safety import MAX_SWEEP_CELLS, check_move, sweep_cells

from ..app import Context
from ..config import ModuleConfig, param
from ..jobs import Interrupted, Job
from ..localisation import Localiser, pose_fields
from ..protocol import Fixed, ProtocolError, Reply, Rows
from ..table import HARDWARE, command
from .hardware import default_stem

if TYPE_CHECKING:
    from pathlib import Path

    from prox_workflows.steps.planner import NavMaps, PlannerParams, PlanningError

    from ..app import App, Pose


@dataclass
class CheckMoveConfig(ModuleConfig):
    module: ClassVar[str] = "check_move"
    dx: float = param(0.0, "forward motion in the rover frame", unit="m", min=-50.0, max=50.0)
    dy: float = param(0.0, "leftward motion in the rover frame", unit="m", min=-50.0, max=50.0)
    dyaw: float = param(0.0, "turn, counter-clockwise", unit="deg", min=-360.0, max=360.0)
    to: list[float] = param([], "target x,y[,heading] in the global frame instead of -dx -dy -dyaw",
                            unit="m,m,deg", length=(2, 3), min=-1e6, max=1e6)
    min_score: float = param(0.0, "traversability at or below this blocks the move", min=0.0, max=1.0,
                             option=False)
    margin: float = param(0.05, "added around the rover body", unit="m", min=0.0, max=2.0, option=False)


@command("check-move", config=CheckMoveConfig,
         help="safety gate: is the rover's footprint swept along -dx -dy -dyaw (or -to x,y[,h]) traversable? "
              f"(the box around the sweep spans at most {MAX_SWEEP_CELLS:,} map cells)")
def check_move_cmd(ctx: Context, cfg: CheckMoveConfig) -> Awaitable[dict[str, Any]]:
    app = ctx.app
    given = {k for k, _ in ctx.request.options}
    if "to" in given and given & {"dx", "dy", "dyaw"}:
        raise ProtocolError("E_ARG", "give either -to x,y[,heading] or -dx/-dy/-dyaw, not both")
    maps = app.maps.layers
    if maps is None or "traversability" not in maps:
        raise ProtocolError("E_DATA", "no traversability map yet; run dem-full-tof (or dem-full) first")
    p = app.pose
    start = (p.x, p.y, p.heading)
    if cfg.to:
        end = (cfg.to[0], cfg.to[1], cfg.to[2] if len(cfg.to) == 3 else p.heading)
    else:
        c, s = math.cos(math.radians(p.heading)), math.sin(math.radians(p.heading))
        end = (p.x + cfg.dx * c - cfg.dy * s, p.y + cfg.dx * s + cfg.dy * c, p.heading + cfg.dyaw)
    head = app.config.get("head")
    length, width = head.rover_length + 2 * cfg.margin, head.rover_width + 2 * cfg.margin
    cells = sweep_cells(start, end, length, width, maps.geometry.cell)
    if cells > MAX_SWEEP_CELLS:
        raise ProtocolError("E_ARG", f"the move from ({start[0]:.2f}, {start[1]:.2f}) to ({end[0]:.3g}, {end[1]:.3g}) "
                                     f"sweeps a box of {cells:.3g} cells of {maps.geometry.cell:g} m; a check spans at "
                                     f"most {MAX_SWEEP_CELLS:,} cells, so check a shorter move")
    return _check_move_off_loop(ctx, maps, start, end, length, width, cfg.min_score)


async def _check_move_off_loop(ctx: Context, maps: Any, start: tuple[float, float, float],
                               end: tuple[float, float, float], length: float, width: float,
                               min_score: float) -> dict[str, Any]:
    """The sweep runs in a worker thread: a long move is tens of milliseconds of geometry, and
    status, break and the other connections must not wait for it."""
    result = await ctx.app.loop.run_in_executor(
        None, check_move, maps["traversability"], maps.geometry, start, end, length, width, min_score)
    return {
        "verdict": result.verdict,
        "worst": Fixed(result.worst_score, 3) if math.isfinite(result.worst_score) else "unknown",
        "worst_x": Fixed(result.worst_x, 3),
        "worst_y": Fixed(result.worst_y, 3),
        "cells": result.cells,
        "unknown_cells": result.unknown_cells,
        "blocked_cells": result.blocked_cells,
        "to": [Fixed(end[0], 3), Fixed(end[1], 3), Fixed((end[2] + 180) % 360 - 180, 2)],
    }


# ------------------------------------------------------------------ navigate


@dataclass
class NavigateConfig(ModuleConfig):
    module: ClassVar[str] = "navigate"
    goal: list[float] = param([], "goal x,y in the global frame", unit="m", length=2, min=-1e6, max=1e6,
                              required=True)
    start: list[float] = param([], "start x,y[,heading] (default: the current pose)", unit="m,m,deg",
                               length=(2, 3), min=-1e6, max=1e6)
    sensor: str = param("tof", "sensor for the 360-degree DEMs", choices=("tof", "stereo", "fused"))
    auto: bool = param(False, "simulated rover only: drive the waypoints without waiting for pose")
    tolerance: float = param(0.3, "the goal is reached within this distance", unit="m", min=0.05, max=10.0)
    max_legs: int = param(12, "give up after this many legs", min=1, max=200)
    name: str = param("", "stem of the products (default nav_<UTC time>)", stem=True)
    # the planner's parameters are declared once, in prox_workflows.parameters.PlanParams (the
    # plan_leg script and rvs-path-planner read the same declarations)
    weight: float = reuse(PlanParams, "weight")
    heuristic: str = reuse(PlanParams, "heuristic")
    grid: float = reuse(PlanParams, "grid")
    margin: float = reuse(PlanParams, "margin")
    max_deviation: float = reuse(PlanParams, "max_deviation")
    border: float = reuse(PlanParams, "border")
    footprint: str = reuse(PlanParams, "footprint")
    range: list[float] = param([-180.0, 180.0, -50.0, -10.0], "view range of each leg's DEM", unit="deg",
                               length=4, min=-360.0, max=360.0, option=False, ordered=True)
    overlap: float = param(0.3, "view overlap of each leg's DEM", min=0.0, max=0.9, option=False)
    wait_timeout: float = param(0.0, "seconds to wait for the GNC's pose after a leg (0: forever)", unit="s",
                                min=0.0, max=86400.0, option=False)
    pose_settle: float = param(2.0, "a leg's wait for the GNC ends when its pose holds still this long (reported "
                               "again or not), or at pose -stopped true; a pose near the leg's end while moving "
                               "does not end it", unit="s", min=0.05, max=600.0, option=False)
    pose_still: list[float] = param([0.01, 1.0], "pose reports within this distance and heading of the first of "
                                    "them hold still", unit="m,deg", length=2, min=0.0, max=10.0, option=False)
    judge_range: float = param(3.0, "a goal judged unreachable (goal_in_hazard, enclosed) from farther than this "
                               "is driven toward and judged again from closer, where the ToF sees it densely and "
                               "reliably (its returns thin out and get noisier toward the 4.5 m it keeps)", unit="m",
                               min=0.0, max=50.0, option=False)
    min_progress: float = param(0.1, "a leg that starts closer than this to the previous leg's start made no "
                                "progress; the second such leg in a row ends the job", unit="m", min=0.0, max=5.0,
                                option=False)
    global_maps: str = param("", "folder with global hazard.tif and slope.tif, and dem.tif for map matching "
                             "(empty: blank maps, or -global)", option=False)
    # Localisation and global maps (issue 12 items 4-5): rvs_server.localisation, steps.map_match
    global_: str = param("", "global DEM (or 0/128/255 hazard map) GeoTIFF from orbit, in any CRS in metres; "
                         "its hazard and slope come from Dem2Hazard, its heights serve map matching (instead of "
                         "navigate.global_maps)")
    global_origin: list[float] = param([0.0, 0.0], "the rover frame's origin (the start) in the global map's CRS",
                                       unit="m", length=2, min=-1e8, max=1e8)
    localise: str = param("none", "correct the dead-reckoned pose after each leg: vo (the leg's DEM on the last "
                          "one), map (on the global DEM), both, or none", choices=("none", "vo", "map", "both"))
    drift: float = param(0.05, "dead reckoning's position error per metre driven (1 sigma, share of distance)",
                         min=0.0, max=1.0, option=False)
    heading_drift: float = param(2.0, "dead reckoning's heading error per metre driven (1 sigma)", unit="deg/m",
                                 min=0.0, max=90.0, option=False)
    # drive while seeing (issue 12 item 2; rvs_server/autonomy.py)
    # scan stays the default: in the benchmark's dense hirise scene the see loop's rover body crossed
    # true hazards the rolling map had left unseen (tools.bench.navigate; docs/PROTOCOL.md)
    loop: str = param("scan", "scan stops for a 360-degree scan at every leg's end; see checks the next metres "
                      "with the forward ToF while the rover drives (-auto: every cycle; the GNC: at every pose "
                      "report) and replans from what it sees (a 360-degree scan first and when that shows no "
                      "way)", choices=("see", "scan"))
    see_period: float = param(1.0, "see loop: simulated time driven between two forward ToF frames (1 s: 10 cm "
                              "at 0.1 m/s; each simulated frame is rendered, which costs CPU)", unit="s",
                              min=0.05, max=10.0, option=False)
    see_lookahead: float = param(1.5, "see loop: the footprint is checked this far along the path ahead", unit="m",
                                 min=0.2, max=5.0, option=False)
    see_tilt: float = param(-35.0, "see loop: PTU tilt of the forward ToF", unit="deg", min=-90.0, max=0.0,
                            option=False)
    see_subsample: int = param(2, "see loop: use every n-th ToF pixel in both directions", min=1, max=8,
                               option=False)
    see_margin: float = param(0.05, "see loop: added around the rover body in the check", unit="m", min=0.0,
                              max=1.0, option=False)
    see_max_range: float = param(3.0, "see loop: ignore ToF points farther than this (a single frame's returns "
                                 "beyond 3 m are sparse and noisy enough to make phantom steps near the goal)",
                                 unit="m", min=0.5, max=30.0, option=False)
    replan_ahead: float = param(1.0, "see loop: extend the path from the rolling map once the leg's end is this "
                                "close, without stopping", unit="m", min=0.0, max=5.0, option=False)
    see_pursuit: float = param(0.3, "see loop: the rover steers at the point of its path this far ahead (pure "
                               "pursuit; shorter follows the waypoints' corners closer)", unit="m", min=0.05, max=3.0,
                               option=False)
    see_arc_turn: float = param(45.0, "see loop: a heading error up to this is driven out as an arc at full speed, "
                                "a larger one is turned on the spot", unit="deg", min=0.0, max=180.0, option=False)
    see_unseen: str = param("off", "see loop: ground no map has seen under the rover's sweep over the next "
                            "see_blind metres (the forward ToF sees from about a metre ahead of the rover, so it "
                            "will not see that ground before the body is on it): look stops and looks at it, then "
                            "drives on; keep also ends the leg when the look does not show it and keeps plans off "
                            "such ground that close (plus half the body) as off a rock (experimental: it can stall "
                            "where a scan leaves the way on unseen); off drives on (docs/PROTOCOL.md)",
                            choices=("look", "keep", "off"), option=False)
    see_blind: float = param(0.8, "see loop: the stretch of path ahead that see_unseen judges", unit="m", min=0.0,
                             max=3.0, option=False)
    see_memory: float = param(0.0, "see loop: keep what the rolling map saw for the whole mission, over the box of "
                              "start and goal grown by this (8 is a fair box), so a dead end driven out of is not "
                              "planned into again once it scrolls off the 8 m rolling map; experimental, its false "
                              "hazards are kept too (docs/PROTOCOL.md); 0: not kept", unit="m", min=0.0, max=100.0,
                              option=False)
    see_border: float = param(0.3, "see loop: plans stop this far inside the seen ground (the forward ToF sees "
                              "the ground ahead before the rover gets there; a scan leg keeps navigate.border)",
                              unit="m", min=0.0, max=5.0, option=False)
    see_search: str = param("dstar", "see loop: the search of a replan: dstar repairs the mission's last search "
                            "with the cells that changed (D* Lite, the same path cost as astar), astar searches "
                            "again", choices=("dstar", "astar"), option=False)
    see_localise_every: float = param(2.0, "see loop with -localise map or both: match the rolling map on the global "
                                      "DEM after every this many metres driven, and after every leg closer than "
                                      "this to the goal", unit="m", min=0.1, max=1000.0, option=False)
    see_arrival_spread: float = param(120.0, "see loop with -localise map or both: on arriving, the rover looks "
                                      "round standing (three ToF frames, this far either side of ahead: the "
                                      "ground behind too, which a goal near the map's edge needs) and matches "
                                      "what they saw on the global DEM", unit="deg", min=0.0, max=150.0,
                                      option=False)
    max_replans: int = param(100, "see loop: give up after this many plans in all", min=1, max=10000,
                             option=False)


# What a navigate leg puts in the plan_leg script's workspace (checked at server start).
PLAN_INPUTS = ("local", "global_maps", "ortho", "start", "goal", "start_heading", "rover_radius", "rover_half_width",
               "critical_slope", "prefix", "made_by")


def validate_scripts() -> None:
    """Validate the per-leg plan script against navigate's parameters and inputs."""
    from prox_workflows.engine import validate

    validate("plan_leg", workspace=PLAN_INPUTS, param_cls=NavigateConfig)


def _load_global(folder: str) -> Any:
    from pathlib import Path

    from prox_workflows.grid import read_geotiff
    from prox_workflows.steps.planner import NavMaps

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


def _load_global_maps(cfg: NavigateConfig) -> tuple[Any, Any]:
    """The planner's global maps and the global map with its DEM (for map matching), from
    -global FILE or navigate.global_maps; (None, None) without either (blank maps)."""
    from pathlib import Path

    from prox_workflows.steps.global_map import GlobalMap, load_global
    from prox_workflows.steps.planner import NavMaps

    origin = (cfg.global_origin[0], cfg.global_origin[1])
    if cfg.global_:
        try:
            g = load_global(cfg.global_, origin)
        except (OSError, ValueError) as exc:
            raise ProtocolError("E_DATA", f"global map {cfg.global_} unusable ({exc})") from None
        return NavMaps(g.hazard, g.slope, g.geometry), g
    maps = _load_global(cfg.global_maps)
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


def follow_rover(app: App, track: list[tuple[float, float, float]]) -> Callable[[], None]:
    """What the simulated rover does at each step of a drive: its true pose goes to
    ``track`` (what the traverse is scored by) and its odometry becomes the pose the server
    believes in, as a GNC streaming its pose would make it, so status, check-move and a break's
    recovery set see where the rover is mid-drive, not where the leg began."""
    world = app.world

    def step() -> None:
        world.record_track(track)
        x, y, heading = world.odometry()
        app.set_pose(x, y, heading, source="odometry")

    return step


def drive_simulated(world: Any, waypoints: Any, track: list[tuple[float, float, float]],
                    reached: Any = None, stop: Any = None, on_step: Callable[[], None] | None = None) -> None:
    """The simulated rover drives the waypoints as its GNC would, in simulated time: from where
    its odometry says it is, turn on the spot toward the next waypoint at the rover's turn rate,
    then straight at its speed (sect. 5.4; ``world.drive_model``, a scene's ``rover:`` block),
    each on the world's clock. Steering by the dead-reckoned pose is what makes wheel slip and
    heading drift (``sim slip``) leave the true rover short of and beside the waypoints.

    ``track`` gets the true pose every 5 cm and every 5 degrees turned, on the spot too (the
    simulator's ground truth, to score the traverse against the true hazards); ``reached(k)`` is called as the rover's odometry arrives
    at waypoint k; ``stop()`` true (a break) stops the rover at its next step; ``on_step`` runs
    at every step (default: the track only; navigate's :func:`follow_rover`)."""
    model = world.drive_model
    step = on_step or (lambda: world.record_track(track))

    for k, (wx, wy) in enumerate(waypoints.xy[1:], start=1):
        dist = world.turn_toward(wx, wy, stop, on_step=step)
        if dist >= 1e-6:
            world.drive(model.speed, 0.0, dist / model.speed, stop, on_step=step)
        world.record_track(track, 0.0, 0.0)
        if stop is not None and stop():
            return
        if reached is not None:
            reached(k)


@command("navigate", job=True, klass=HARDWARE, config=NavigateConfig, check=lambda app, cfg: _check(app, cfg),
         help="navigate to -goal: 360-degree DEM, A* plan, waypoints, wait for the rover (pose), repeat")
def navigate(job: Job, cfg: NavigateConfig) -> dict[str, Any]:
    """The legs (:func:`_navigate`); a navigate that fails part way still leaves the track the rover
    drove (the operator's first question: where did it go, and what did it cross)."""
    name = cfg.name or default_stem("nav")
    track: list[tuple[float, float, float]] = []
    try:
        return _navigate(job, cfg, name, track)
    except (ProtocolError, Interrupted) as exc:
        if len(track) < 2:
            raise
        note = f" (the track so far: {job.app.rel(_write_track(job.app, name, track))})"
        if isinstance(exc, Interrupted):
            raise Interrupted(f"{exc}{note}") from None
        raise ProtocolError(exc.code, exc.message + note) from None
    except Exception:
        if len(track) >= 2:
            _write_track(job.app, name, track)
        raise


def _write_track(app: App, name: str, track: list[tuple[float, float, float]]) -> Path:
    from prox_workflows.products import write_text_atomic

    tfile = app.data_path("nav", f"{name}_track.csv")
    write_text_atomic(tfile, "x,y,heading\n" + "".join(f"{x:.4f},{y:.4f},{h:.2f}\n" for x, y, h in track))
    return tfile


def _navigate(job: Job, cfg: NavigateConfig, name: str, track: list[tuple[float, float, float]]) -> dict[str, Any]:
    from prox_workflows.mapview import Marks
    from prox_workflows.products import write_png, write_text_atomic
    from prox_workflows.steps.planner import (
        MIN_LEG,
        NavMaps,
        PlannerParams,
        PlanningError,
        ortho_figure,
    )

    from .. import autonomy
    from .dem import run_dem

    app = job.app
    global_maps, global_map = _load_global_maps(cfg)
    loc = Localiser(cfg.localise, global_map, cfg.drift, cfg.heading_drift, auto=cfg.auto)
    if cfg.start:
        heading = cfg.start[2] if len(cfg.start) == 3 else app.pose.heading
        app.set_pose(cfg.start[0], cfg.start[1], heading, source="navigate")
        if cfg.auto:
            app.world.set_rover_pose(cfg.start[0], cfg.start[1], heading)
    goal = (cfg.goal[0], cfg.goal[1])
    head = app.config.get("head")
    params = PlannerParams(grid=cfg.grid, weight=cfg.weight, heuristic=cfg.heuristic,
                           rover_radius=math.hypot(head.rover_length, head.rover_width) / 2, margin=cfg.margin,
                           half_width=head.rover_width / 2 if cfg.footprint == "body" else None,
                           critical_slope=app.config.get("dem2hazard").slope_max,
                           max_deviation=cfg.max_deviation, border=cfg.border)
    seeing = cfg.loop == "see"
    plan_params = {n: getattr(cfg, n) for n in PlanParams.specs()}
    dem_cfg = copy.deepcopy(app.config.get("dem_full_tof" if cfg.sensor == "tof" else "dem_full"))
    dem_cfg.range, dem_cfg.overlap = list(cfg.range), cfg.overlap
    all_paths: list[Any] = []
    all_waypoints: list[Any] = []
    track.append((app.pose.x, app.pose.y, app.pose.heading))
    leg_starts: list[tuple[float, float]] = []
    stalled = 0  # legs in a row that started where the previous one did
    see_stalled = 0  # see loop: replans in a row after which the rover had not moved
    see = autonomy.start(job, cfg, loc) if seeing else None
    need_scan = True  # the see loop scans first, then only when the rolling map shows no way
    scans = 0
    for _ in range(cfg.max_replans if seeing else cfg.max_legs):
        job.check()
        leg = len(all_paths) + 1  # the leg being prepared: its scan, plan and drive carry its number
        pose = app.pose
        # an arrival on dead reckoning is checked by a match first: the see loop's own (map) or a scan's
        checked = loc.wants_fix(pose) and (see is None or loc.uses_map)
        left = math.hypot(goal[0] - pose.x, goal[1] - pose.y)
        if left <= cfg.tolerance and not checked and not (see is not None and see.closer(left)):
            break
        if see is not None and not need_scan:
            plan = see.replan(leg, global_maps, goal, params)
            if plan is not None:
                all_paths.append(plan.path[: plan.cut])
                all_waypoints.append(plan.waypoints.xy)
                before = (pose.x, pose.y)
                see.drive_leg(leg, plan, track)
                moved = math.hypot(app.pose.x - before[0], app.pose.y - before[1]) >= cfg.min_progress
                see_stalled = 0 if moved else see_stalled + 1
                if see_stalled >= 3:  # replans that drive nowhere (stopped at once, or no way the body fits)
                    see_stalled = 0
                    need_scan = True
                continue
            if see.fresh_scan:  # the 360-degree scan just made shows no way either
                raise ProtocolError("E_DATA", f"no way on from ({pose.x:.2f}, {pose.y:.2f}) after a 360-degree "
                                              f"scan: {see.why}")
            need_scan = True  # the rolling map shows no way: scan 360 degrees from here
        if scans >= cfg.max_legs:
            break
        scans += 1
        if leg_starts and math.hypot(pose.x - leg_starts[-1][0], pose.y - leg_starts[-1][1]) < cfg.min_progress:
            stalled += 1
            if stalled >= 2:
                raise ProtocolError("E_DATA", f"no progress: legs {leg - 2} to {leg} all started at ({pose.x:.2f}, "
                                              f"{pose.y:.2f}) (within {cfg.min_progress:g} m); the rover does not "
                                              "get along the waypoints, so a further scan from here would not help")
        else:
            stalled = 0
        leg_starts.append((pose.x, pose.y))
        dem_cfg.name = f"{name}_leg{leg}"

        def leg_progress(done: int, total: int, message: str, phase: str = "", leg: int = leg) -> None:
            job.progress(done, total, message, phase=phase, leg=leg)

        run_dem(job, dem_cfg, update=leg > 1 and not loc.active, sensor=cfg.sensor, progress=leg_progress,
                out_dir="nav")
        loc.after_scan(job, leg)  # VO / map matching: corrects the pose and the leg's maps
        pose = app.pose
        if math.hypot(goal[0] - pose.x, goal[1] - pose.y) <= cfg.tolerance:
            break  # (a scan to check a dead-reckoned arrival, and it holds)
        maps = app.maps.layers
        local = NavMaps(maps["hazard"], maps["slope"], maps.geometry)
        if see is not None:  # the see loop plans from the scan and what it sees next (SeeLoop.replan)
            see.scanned(local)
            need_scan = False
            continue
        here = (pose.x, pose.y)
        distance = math.hypot(goal[0] - pose.x, goal[1] - pose.y)
        judged: PlanningError | None = None  # the goal's verdict from too far to be final
        prefix = app.data_path("nav", f"{name}_leg{leg}")
        plan_inputs = {"local": local, "global_maps": global_maps, "ortho": (maps["ortho"], maps.geometry),
                       "start": list(here),
                       "start_heading": pose.heading, "rover_radius": params.rover_radius,
                       "rover_half_width": head.rover_width / 2,
                       "critical_slope": params.critical_slope, "prefix": prefix, "made_by": "navigate"}

        def plan_leg(to: tuple[float, float], inputs: dict[str, Any] = plan_inputs) -> Any:
            """The leg's plan and its products: the plan_leg script, as rvs-path-planner runs it."""
            ws, _ = run_workflow("plan_leg", plan_params, {**inputs, "goal": list(to)})
            return ws["plan"]

        try:
            plan = plan_leg(goal)
        except PlanningError as exc:
            toward = goal_stand_in(local, global_maps, here, goal, params, exc, distance, cfg)
            if toward is None:
                raise ProtocolError("E_DATA", f"goal unreachable ({exc.reason}): {exc.message}") from None
            try:
                plan = plan_leg(toward)
            except PlanningError:
                raise ProtocolError("E_DATA", f"goal unreachable ({exc.reason}): {exc.message}") from None
            if math.hypot(toward[0] - goal[0], toward[1] - goal[1]) <= cfg.tolerance:
                leg_progress(0, 1, f"goal {exc.reason}: planning to ({toward[0]:.2f}, {toward[1]:.2f}) instead, "
                                   f"within the {cfg.tolerance:g} m tolerance", "plan")
            else:  # drive toward the goal, as close as the maps allow, and judge it again from there
                judged = exc
                leg_progress(0, 1, f"goal judged unreachable ({exc.reason}) from {distance:.2f} m, farther than "
                                   f"{cfg.judge_range:g} m: driving toward it to ({toward[0]:.2f}, "
                                   f"{toward[1]:.2f}) to judge it again from closer", "plan")
        driven = plan.path[: plan.cut]
        if len(plan.waypoints) < 2 or math.hypot(*(driven[-1] - driven[0])) < MIN_LEG:
            if judged is not None:  # it cannot get closer: the verdict from here stands
                raise ProtocolError("E_DATA", f"goal unreachable ({judged.reason}): {judged.message}; judged from "
                                              f"{distance:.2f} m, and the rover can get no closer")
            raise ProtocolError("E_DATA", f"no progress on leg {leg}: the path leaves the locally seen ground at once "
                                          f"({'; '.join(plan.warnings) or 'nothing to drive'})")
        segments = len(plan.waypoints) - 1
        end = (float(plan.waypoints.xy[-1][0]), float(plan.waypoints.xy[-1][1]))
        leg_progress(1, 1, f"{segments} segments to ({end[0]:.2f}, {end[1]:.2f})", "plan")
        all_paths.append(driven)
        all_waypoints.append(plan.waypoints.xy)
        rows = Rows((Fixed(x, 3), Fixed(y, 3), Fixed(h, 2)) for x, y, h in plan.waypoints.table()[:, :3])
        version = app.pose_version  # before the event: a GNC may answer it at once
        app.broadcast_threadsafe(Reply("RVS", "EVENT", {
            "kind": "waiting", "job": job.id, "leg": leg, "waypoints": rows,
            "file": app.rel(prefix.with_name(prefix.name + "_waypoints.csv")), **pose_fields(job)}))
        leg_progress(0, segments, f"waiting for the rover to drive {segments} segments to "
                                  f"({end[0]:.2f}, {end[1]:.2f})", "drive")
        if cfg.auto:
            drive_simulated(app.world, plan.waypoints, track, reached=lambda k, n=segments: leg_progress(
                k, n, f"segment {k}/{n} driven", "drive"), stop=job.cancel.is_set, on_step=follow_rover(app, track))
            # The rover's belief, not the simulator's truth: with slip they differ, as on Mars.
            odo = app.world.odometry()
            app.set_pose(odo[0], odo[1], odo[2], source="odometry")
            job.check()
            loc.after_drive(job, plan.waypoints.xy)
        else:
            arrived = wait_for_rover(app, job, version, end, cfg)
            track.append((arrived.x, arrived.y, arrived.heading))
            there = math.hypot(arrived.x - end[0], arrived.y - end[1]) <= cfg.tolerance
            leg_progress(segments, segments, f"rover {'arrived' if there else 'stopped'} at "
                                             f"({arrived.x:.2f}, {arrived.y:.2f})", "drive")
    pose = app.pose
    reached = math.hypot(goal[0] - pose.x, goal[1] - pose.y) <= cfg.tolerance
    if not reached:
        raise ProtocolError("E_DATA", f"goal not reached after {scans} scans and {len(all_paths)} legs; the rover is at "
                                      f"({pose.x:.2f}, {pose.y:.2f}), {math.hypot(goal[0] - pose.x, goal[1] - pose.y):.2f} m away")
    maps = app.maps.layers
    path = np.concatenate(all_paths) if all_paths else np.zeros((0, 2))
    wps = np.concatenate(all_waypoints) if all_waypoints else np.zeros((0, 2))
    traverse = app.data_path("nav", f"{name}_traverse.png")
    head = app.config.get("head")
    write_png(traverse, ortho_figure(maps["ortho"], maps.geometry, f"traverse to ({goal[0]:g}, {goal[1]:g})",
                                     Marks(rover=(pose.x, pose.y, pose.heading),
                                           rover_size=(head.rover_length, head.rover_width), path=path,
                                           waypoints=wps, track=np.asarray(track)[:, :2], goal=goal)))
    wfile = app.data_path("nav", f"{name}_waypoints.csv")
    write_text_atomic(wfile, "x,y,leg\n" + "".join(
        f"{x:.4f},{y:.4f},{i + 1}\n" for i, leg_wps in enumerate(all_waypoints) for x, y in leg_wps))
    tfile = _write_track(app, name, track)
    return {"reached": True, "legs": len(all_paths), "path": app.rel(traverse), "waypoints": app.rel(wfile),
            "track": app.rel(tfile), "x": Fixed(pose.x, 3), "y": Fixed(pose.y, 3), **pose_fields(job),
            "loop": cfg.loop, **({"scans": scans} if see is None else see.stats_fields(scans))}


def goal_stand_in(local: NavMaps, global_maps: NavMaps | None, here: tuple[float, float], goal: tuple[float, float],
                  params: PlannerParams, exc: PlanningError, distance: float,
                  cfg: NavigateConfig) -> tuple[float, float] | None:
    """Where to plan to when the goal itself cannot be planned to (``exc``: goal_in_hazard or
    enclosed): the nearest point the rover can reach and stop on, if it lies within the goal's
    tolerance (a goal a few centimetres short of the rover's clearance from a hazard is reached
    from there, as the tolerance says), or, from farther than judge_range, to drive toward and
    judge the goal again from closer. None: the goal is unreachable."""
    from prox_workflows.steps.planner import PlanningError, nearest_reachable

    if exc.reason not in ("goal_in_hazard", "enclosed"):
        return None
    try:
        toward = nearest_reachable(local, global_maps, here, goal, params)
    except PlanningError:
        return None
    if math.hypot(toward[0] - goal[0], toward[1] - goal[1]) <= cfg.tolerance or distance > cfg.judge_range:
        return toward
    return None


def _check(app: App, cfg: NavigateConfig) -> None:
    """Refusals before the ACK: a goal so far that its plans could not be held in memory is
    refused here, not after the first 360-degree scan."""
    from prox_workflows.steps.planner import PlannerParams, blank_geometry, check_plan_size

    if cfg.auto and app.world is None:
        raise ProtocolError("E_ARG", "-auto drives the simulated rover; with real hardware the GNC sends pose")
    start = cfg.start[:2] if cfg.start else [app.pose.x, app.pose.y]
    try:
        check_plan_size(blank_geometry([start, cfg.goal], cfg.grid, PlannerParams.blank_pad),
                        f"grid from ({start[0]:g}, {start[1]:g}) to -goal {cfg.goal[0]:g},{cfg.goal[1]:g}")
    except ValueError as exc:
        raise ProtocolError("E_ARG", str(exc)) from None


def wait_for_rover(app: App, job: Job, version: int, end: tuple[float, float], cfg: NavigateConfig,
                   on_pose: Callable[[Pose], None] | None = None) -> Pose:
    """Until the pose reports say the rover has stopped: ``-stopped true``, or a pose that holds
    (within ``cfg.pose_still``) for ``cfg.pose_settle`` seconds, reported again or not. Where it
    stopped does not matter: a GNC streaming its pose as it drives passes the leg's end, or comes
    within the tolerance of it, while still moving, and a scan started then would start on a
    moving rover. Each report that moved goes to ``on_pose`` (the see loop's check), outside the
    pose lock, so the pose command is never kept waiting by it; the hold is timed from the end of
    that check, so a check slower than the GNC's reports does not pass for a standing rover."""
    deadline = time.monotonic() + cfg.wait_timeout if cfg.wait_timeout > 0 else math.inf
    still_m, still_deg = cfg.pose_still
    anchor: Pose | None = None  # the first report of the run of reports that hold still
    anchor_at = 0.0
    latest: Pose | None = None
    while True:
        with app.pose_changed:
            job.check()
            if app.pose_version == version:
                now = time.monotonic()
                if latest is not None and now - anchor_at >= cfg.pose_settle:
                    return latest
                if now >= deadline:
                    raise ProtocolError("E_DATA", f"no pose at the leg's end ({end[0]:.2f}, {end[1]:.2f}) within "
                                                  f"{cfg.wait_timeout:g} s; send pose -x -y -heading (with -stopped "
                                                  "true once the rover stands)")
                wake = anchor_at + cfg.pose_settle - now if latest is not None else 0.1
                app.pose_changed.wait(min(0.1, max(wake, 0.001)))
                continue
            version = app.pose_version
            p = app.pose
        if p.stopped:
            return p
        latest = p
        turned = abs((p.heading - anchor.heading + 180.0) % 360.0 - 180.0) if anchor is not None else 0.0
        if anchor is None or math.hypot(p.x - anchor.x, p.y - anchor.y) > still_m or turned > still_deg:
            anchor = p
            if on_pose is not None:  # a report that holds still shows nothing new: no cycle for it
                on_pose(p)
            anchor_at = time.monotonic()  # the hold counts from when the server took the report in
