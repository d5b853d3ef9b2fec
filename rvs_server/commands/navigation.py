"""Navigation commands: check-move (the safety gate) and navigate (seed 000 sect. 4.4.4, appendix F;
the mission itself is :mod:`rvs_server.navigation`)."""

from __future__ import annotations

import math
from collections.abc import Awaitable
from dataclasses import dataclass
from typing import Any, ClassVar

from prox_workflows.algorithms.safety import MAX_SWEEP_CELLS, check_move, sweep_cells

from ..app import Context
from ..config import ModuleConfig, param
from ..jobs import Interrupted, Job, default_stem
from ..navigation.config import NavigateConfig
from ..navigation.mission import Mission, check_request
from ..navigation.planning import validate_scripts
from ..navigation.track import Track
from ..protocol import Fixed, ProtocolError
from ..table import HARDWARE, command
from ..travel import CheckedMove, Goal

__all__ = ["CheckMoveConfig", "NavigateConfig", "check_move_cmd", "navigate", "validate_scripts"]


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
    fields = {
        "verdict": result.verdict,
        "worst": Fixed(result.worst_score, 3) if math.isfinite(result.worst_score) else "unknown",
        "worst_x": Fixed(result.worst_x, 3),
        "worst_y": Fixed(result.worst_y, 3),
        "cells": result.cells,
        "unknown_cells": result.unknown_cells,
        "blocked_cells": result.blocked_cells,
        "to": [Fixed(end[0], 3), Fixed(end[1], 3), Fixed((end[2] + 180) % 360 - 180, 2)],
    }
    ctx.app.travel.checked(CheckedMove(start, fields))
    return fields


# ------------------------------------------------------------------ navigate


@command("navigate", job=True, klass=HARDWARE, config=NavigateConfig, check=check_request,
         help="navigate to -goal: 360-degree DEM, A* plan, waypoints, wait for the rover (pose), repeat")
def navigate(job: Job, cfg: NavigateConfig) -> dict[str, Any]:
    """The mission (:class:`~rvs_server.navigation.mission.Mission`); a navigate that fails part
    way still leaves the track the rover drove (the operator's first question: where did it go,
    and what did it cross)."""
    travel = job.app.travel
    if len(cfg.goal) == 2:  # the console's map shows it, whoever sent the navigate
        travel.aim(Goal(cfg.goal[0], cfg.goal[1], cfg.tolerance, job.id))
    try:
        return _mission(job, cfg)
    except BaseException:
        travel.aim(None)  # an error or a break: no goal is driven to any more
        raise


def _mission(job: Job, cfg: NavigateConfig) -> dict[str, Any]:
    name = cfg.name or default_stem("nav")
    track = Track()
    try:
        return Mission(job, cfg, name, track).run()
    except (ProtocolError, Interrupted) as exc:
        if len(track) < 2:
            raise
        note = f" (the track so far: {job.app.rel(track.write(job.app, name))})"
        if isinstance(exc, Interrupted):
            raise Interrupted(f"{exc}{note}") from None
        raise ProtocolError(exc.code, exc.message + note) from None
    except Exception:
        if len(track) >= 2:
            track.write(job.app, name)
        raise
