"""Navigation commands: check-move (the safety gate)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

from prox_workflows.steps.safety import check_move

from ..app import Context
from ..config import ModuleConfig, param
from ..protocol import Fixed, ProtocolError
from ..table import command
from .dem import maps_of


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
         help="safety gate: is the rover's footprint swept along -dx -dy -dyaw (or -to x,y[,h]) traversable?")
def check_move_cmd(ctx: Context, cfg: CheckMoveConfig) -> dict[str, Any]:
    app = ctx.app
    given = {k for k, _ in ctx.request.options}
    if "to" in given and given & {"dx", "dy", "dyaw"}:
        raise ProtocolError("E_ARG", "give either -to x,y[,heading] or -dx/-dy/-dyaw, not both")
    state = maps_of(app)
    with state.lock:
        maps = state.current
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
    result = check_move(maps["traversability"], maps.geometry, start, end,
                        head.rover_length + 2 * cfg.margin, head.rover_width + 2 * cfg.margin, cfg.min_score)
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
