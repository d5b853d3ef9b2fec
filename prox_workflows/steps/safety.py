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

    A cell with traversability <= ``min_score`` blocks the move.
    """
    g = geometry
    poses = sweep_poses(start, end, step=max(g.cell, min(length, width) / 4))
    radius = math.hypot(length, width) / 2
    xmin, xmax = poses[:, 0].min() - radius, poses[:, 0].max() + radius
    ymin, ymax = poses[:, 1].min() - radius, poses[:, 1].max() + radius
    # the window of cells (possibly partly off the map) around the whole sweep
    c0 = math.floor((xmin - g.xmin) / g.cell)
    c1 = math.floor((xmax - g.xmin) / g.cell)
    r0 = math.floor((g.ymax - ymax) / g.cell)
    r1 = math.floor((g.ymax - ymin) / g.cell)
    rows = np.arange(r0, r1 + 1)
    cols = np.arange(c0, c1 + 1)
    # Cell centres and poses relative to the grid's corner: on a georeferenced map (eastings
    # ~5e5 m, northings ~5e6 m) the footprint test then compares metres, not the last bits of
    # two large coordinates, and gives the same cells as the same map at the origin.
    cx = (cols + 0.5) * g.cell
    cy = -(rows + 0.5) * g.cell
    X, Y = np.meshgrid(cx, cy)
    covered = np.zeros(X.shape, bool)
    for x, y, heading in poses:
        covered |= in_footprint(X - (x - g.xmin), Y - (y - g.ymax), heading, length, width, g.cell)
    R, C = np.meshgrid(rows, cols, indexing="ij")
    inside = (R >= 0) & (R < g.height) & (C >= 0) & (C < g.width)
    values = np.full(X.shape, np.nan, np.float32)
    values[inside] = traversability[R[inside], C[inside]]
    under = values[covered]
    xs, ys = X[covered] + g.xmin, Y[covered] + g.ymax
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
    return MoveCheck(verdict, worst[0], worst[1], worst[2], int(covered.sum()), int(unknown.sum()),
                     int(blocked.sum()))
