"""The movement safety gate (seed 003 sect. 7: OK / NOT_TRAVERSABLE / ERROR): the rover's
footprint swept along a planned motion over the traversability map.

Unknown ground is never called safe: a cell the map has not seen (NaN, or off the map) makes the
verdict ``unknown`` unless a cell the map has seen is already impassable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..grid import GridGeometry


@dataclass
class MoveCheck:
    verdict: str  # ok | not_traversable | unknown
    worst_score: float  # lowest traversability under the sweep (nan if nothing seen)
    worst_x: float
    worst_y: float
    cells: int  # cells under the sweep
    unknown_cells: int
    blocked_cells: int


def sweep_poses(start: tuple[float, float, float], end: tuple[float, float, float], step: float,
                yaw_step: float = 5.0) -> np.ndarray:
    """Poses (x, y, heading deg) from start to end, close enough that footprints overlap."""
    dist = math.hypot(end[0] - start[0], end[1] - start[1])
    dyaw = (end[2] - start[2] + 180.0) % 360.0 - 180.0
    n = max(1, math.ceil(dist / step), math.ceil(abs(dyaw) / yaw_step))
    t = np.linspace(0.0, 1.0, n + 1)
    return np.stack([start[0] + t * (end[0] - start[0]), start[1] + t * (end[1] - start[1]),
                     start[2] + t * dyaw], axis=1)


def in_footprint(dx: np.ndarray, dy: np.ndarray, heading: float, length: float, width: float,
                 cell: float) -> np.ndarray:
    """Which cells, at offsets (dx, dy) m from the rover's centre, its ``length`` x ``width``
    rectangle at ``heading`` (deg) touches: a cell counts when its centre is within half a cell
    of the rectangle, so no cell the body rests on is left out."""
    c, s = math.cos(math.radians(heading)), math.sin(math.radians(heading))
    return (np.abs(dx * c + dy * s) <= length / 2 + cell / 2) & (np.abs(dy * c - dx * s) <= width / 2 + cell / 2)


# The most cells check_move's sweep may span (its box, seen or not): one byte each, and the
# poses' footprints are laid into it one by one. 16 million cells is a 200 m square of 5 cm
# cells, far beyond any move a rover makes between two checks, and about 0.2 s of work.
MAX_SWEEP_CELLS = 16_000_000


def sweep_cells(start: tuple[float, float, float], end: tuple[float, float, float], length: float, width: float,
                cell: float) -> int:
    """How many cells the box around a sweep spans: what :func:`check_move` allocates, known
    before it does (the server refuses a move over :data:`MAX_SWEEP_CELLS` before any work)."""
    radius = math.hypot(length, width) / 2
    nx = (abs(end[0] - start[0]) + 2 * radius) / cell + 2
    ny = (abs(end[1] - start[1]) + 2 * radius) / cell + 2
    return int(min(nx * ny, 2**62))


def check_move(
    traversability: np.ndarray,
    geometry: GridGeometry,
    start: tuple[float, float, float],
    end: tuple[float, float, float],
    length: float,
    width: float,
    min_score: float = 0.0,
) -> MoveCheck:
    """Sweep a ``length`` x ``width`` rectangle (centred on the rover) from ``start`` to ``end``.

    A cell with traversability <= ``min_score`` blocks the move. Each pose's footprint is laid
    only into the cells around it, so the work grows with the sweep's length, not with its box's
    area; the box itself (one byte a cell) is bounded by :data:`MAX_SWEEP_CELLS`.
    """
    g = geometry
    need = sweep_cells(start, end, length, width, g.cell)
    if need > MAX_SWEEP_CELLS:
        raise ValueError(f"the move sweeps a box of {need:.3g} cells of {g.cell:g} m, over the {MAX_SWEEP_CELLS:,} "
                         "cells a check may span; check a shorter move")
    poses = sweep_poses(start, end, step=max(g.cell, min(length, width) / 4))
    radius = math.hypot(length, width) / 2
    xmin, xmax = poses[:, 0].min() - radius, poses[:, 0].max() + radius
    ymin, ymax = poses[:, 1].min() - radius, poses[:, 1].max() + radius
    # the window of cells (possibly partly off the map) around the whole sweep
    c0 = math.floor((xmin - g.xmin) / g.cell)
    c1 = math.floor((xmax - g.xmin) / g.cell)
    r0 = math.floor((g.ymax - ymax) / g.cell)
    r1 = math.floor((g.ymax - ymin) / g.cell)
    # Cell centres and poses relative to the grid's corner: on a georeferenced map (eastings
    # ~5e5 m, northings ~5e6 m) the footprint test then compares metres, not the last bits of
    # two large coordinates, and gives the same cells as the same map at the origin.
    cx = (np.arange(c0, c1 + 1) + 0.5) * g.cell
    cy = -(np.arange(r0, r1 + 1) + 0.5) * g.cell
    covered = np.zeros((r1 - r0 + 1, c1 - c0 + 1), bool)
    reach = radius + g.cell  # a footprint's cells lie within this of its pose (centres within half a cell)
    for x, y, heading in poses:
        px, py = x - g.xmin, y - g.ymax
        ca = max(math.floor((px - reach) / g.cell) - c0, 0)
        cb = min(math.floor((px + reach) / g.cell) - c0 + 1, covered.shape[1])
        ra = max(math.floor(-(py + reach) / g.cell) - r0, 0)
        rb = min(math.floor(-(py - reach) / g.cell) - r0 + 1, covered.shape[0])
        covered[ra:rb, ca:cb] |= in_footprint(cx[None, ca:cb] - px, cy[ra:rb, None] - py, heading, length, width,
                                              g.cell)
    ri, ci = np.nonzero(covered)
    R, C = ri + r0, ci + c0
    inside = (R >= 0) & (R < g.height) & (C >= 0) & (C < g.width)
    under = np.full(R.shape, np.nan, np.float32)
    under[inside] = traversability[R[inside], C[inside]]
    xs, ys = cx[ci] + g.xmin, cy[ri] + g.ymax
    unknown = ~np.isfinite(under)
    blocked = np.isfinite(under) & (under <= min_score)
    if np.isfinite(under).any():
        k = int(np.nanargmin(under))
        worst = (float(under[k]), float(xs[k]), float(ys[k]))
    else:
        k = 0
        worst = (float("nan"), float(xs[0]) if len(xs) else start[0], float(ys[0]) if len(ys) else start[1])
    if blocked.any():
        verdict = "not_traversable"
    elif unknown.any():
        verdict = "unknown"
        k = int(np.nonzero(unknown)[0][0])
        worst = (float("nan"), float(xs[k]), float(ys[k]))
    else:
        verdict = "ok"
    return MoveCheck(verdict, worst[0], worst[1], worst[2], len(under), int(unknown.sum()), int(blocked.sum()))
