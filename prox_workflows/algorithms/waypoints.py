"""From an A* path to rover waypoints (seed 000 sect. 3.3.1, 4.4.2, 5.4).

1. :func:`cut_at_border`: the rover drives only over ground its own (local) maps have seen, and
   not nearer than ``border`` to the local map's outer edge, so each leg ends where the next
   scan still overlaps the last (seed 000 sect. 4.4.2, the distance-to-border map).
2. :func:`simplify`: the straight-line approximation of seed 000 eq. 12-14. From a waypoint, the
   line is stretched to the following path points one by one; as soon as some path point in
   between lies farther than ``max_deviation`` from the line (eq. 14, point to line, here to the
   *segment*, which is the same where it matters and never smaller), or the line would cross a
   blocked cell, the previous end point becomes the next waypoint. Fewer, longer straight legs
   mean fewer manoeuvres.
3. :func:`make_waypoints`: each waypoint gets the heading of the leg that leaves it and the turn
   on the spot that the rover makes there (seed 000 sect. 5.4: the rover moves along straight
   lines and turns at the waypoints).

Headings are in degrees, counter-clockwise from the world x axis (x forward at the start pose,
y left), in (-180, 180]; turns are positive to the left.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..grid import GridGeometry


def cut_at_border(border_distance: np.ndarray, border: float) -> int:
    """How many path points to keep, given each point's distance to the local map's border.

    The path is cut at its first point closer than ``border`` to the border. When the start
    itself is that close (the rover stands at the edge of its map, or in the blind spot of a
    single forward scan), the cut is the first such point *after* the path has reached ground
    at least ``border`` inside; if it never does, only the start is kept."""
    d = np.asarray(border_distance, dtype=np.float64)
    inside = d >= border
    if not inside.any():
        return 1
    first_in = int(np.argmax(inside))
    after = ~inside[first_in:]
    if not after.any():
        return len(d)
    return first_in + int(np.argmax(after))


def segment_cells(p0: np.ndarray, p1: np.ndarray, geometry: GridGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Every cell (row, col) the segment p0-p1 passes through (exactly: split at each grid line
    it crosses; a cell it only touches at a corner is not included)."""
    x0, y0 = float(p0[0]), float(p0[1])
    dx, dy = float(p1[0]) - x0, float(p1[1]) - y0
    ts = [np.array([0.0, 1.0])]
    cell = geometry.cell
    for origin, delta, sign in ((geometry.xmin, dx, 1.0), (geometry.ymax, dy, -1.0)):
        if delta == 0.0:
            continue
        a = sign * ((x0 if sign > 0 else y0) - origin) / cell  # start in cell units
        b = a + sign * delta / cell
        lo, hi = (a, b) if a < b else (b, a)
        lines = np.arange(np.floor(lo) + 1, np.ceil(hi))
        ts.append((lines - a) / (b - a))
    t = np.unique(np.clip(np.concatenate(ts), 0.0, 1.0))
    mid = (t[:-1] + t[1:]) / 2 if len(t) > 1 else t
    mid = np.concatenate([[0.0], mid, [1.0]])
    return geometry.cell_of(x0 + mid * dx, y0 + mid * dy)


def segment_clear(p0: np.ndarray, p1: np.ndarray, blocked: np.ndarray, geometry: GridGeometry) -> bool:
    """Whether the segment stays on the grid and crosses no blocked cell."""
    rows, cols = segment_cells(p0, p1, geometry)
    if not geometry.inside(rows, cols).all():
        return False
    return not bool(blocked[rows, cols].any())


def _segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of each point to the segment a-b (eq. 14 where the foot falls on the segment)."""
    ab = b - a
    ap = points - a
    denom = float(ab @ ab)
    if denom == 0.0:
        return np.hypot(ap[:, 0], ap[:, 1])
    t = np.clip((ap @ ab) / denom, 0.0, 1.0)
    foot = a + t[:, None] * ab
    return np.hypot(*(points - foot).T)


def simplify(path: np.ndarray, max_deviation: float, blocked: np.ndarray | None = None,
             geometry: GridGeometry | None = None, turnable: np.ndarray | None = None) -> np.ndarray:
    """Indices of the path points kept as waypoints (first and last always).

    ``turnable`` (one bool per path point) says where the rover may stop and turn on the spot
    (its whole body fits there at any heading): a waypoint is then put at the last such point
    before the line fails, or, if there is none, at the first one farther on that a clear line
    still reaches (it may leave the A* path by more than ``max_deviation``: the A* path kept
    only half the body's width from the hazards, which a line through blocked-free cells keeps
    too). Only where neither exists is a waypoint put where the body may not fit."""
    pts = np.asarray(path, dtype=np.float64)
    n = len(pts)
    if n <= 2:
        return np.arange(n)
    check = blocked is not None and geometry is not None
    keep = [0]
    a = 0
    e = a + 2
    while e < n:
        ok = bool((_segment_distance(pts[a + 1:e], pts[a], pts[e]) <= max_deviation).all())
        if ok and check:
            ok = segment_clear(pts[a], pts[e], blocked, geometry)
        if ok:
            e += 1
            continue
        a = _turn_point(pts, a, e, turnable, blocked if check else None, geometry)
        keep.append(a)
        e = a + 2
    if keep[-1] != n - 1:
        keep.append(n - 1)
    return np.array(keep, dtype=np.int64)


def shortcut(path: np.ndarray, keep: np.ndarray, cost: np.ndarray, cost_so_far: np.ndarray,
             geometry: GridGeometry) -> np.ndarray:
    """Drop the waypoints that a straight line between their neighbours makes unneeded: from
    each kept waypoint, the farthest later one whose line costs no more than the A* path
    between them (``cost`` per metre, the planner's, over the cells the line crosses; inf
    anywhere: blocked). An 8-connected grid path is up to 8 % longer than the straight line it
    approximates and :func:`simplify` keeps to it within ``max_deviation``; this takes the
    any-angle line wherever it is at least as good by the planner's own measure."""
    keep = np.asarray(keep, dtype=np.int64)
    out = [int(keep[0])]
    i = 0
    while i < len(keep) - 1:
        a = int(keep[i])
        nxt = i + 1
        for j in range(len(keep) - 1, i + 1, -1):
            b = int(keep[j])
            rows, cols = segment_cells(path[a], path[b], geometry)
            if not geometry.inside(rows, cols).all():
                continue
            k = cost[rows, cols]
            if not np.isfinite(k).all():
                continue
            line = float(np.mean(k)) * float(np.hypot(*(path[b] - path[a])))
            if line <= float(cost_so_far[b] - cost_so_far[a]) + 1e-9:
                nxt = j
                break
        out.append(int(keep[nxt]))
        i = nxt
    return np.array(out, dtype=np.int64)


def _turn_point(pts: np.ndarray, a: int, e: int, turnable: np.ndarray | None, blocked: np.ndarray | None,
                geometry: GridGeometry | None) -> int:
    """The next waypoint after ``a`` once the line a-e failed (see :func:`simplify`)."""
    if turnable is None or turnable[e - 1]:
        return e - 1
    back = np.flatnonzero(turnable[a + 1:e - 1])
    if back.size:
        return a + 1 + int(back[-1])
    for j in range(e, len(pts)):
        if turnable[j] or j == len(pts) - 1:
            if blocked is None or geometry is None or segment_clear(pts[a], pts[j], blocked, geometry):
                return j
    return e - 1


def _wrap(deg: np.ndarray | float) -> np.ndarray:
    """Angles into (-180, 180]."""
    return -((-np.asarray(deg, dtype=np.float64) + 180.0) % 360.0 - 180.0) + 0.0  # + 0.0: no -0


@dataclass
class Waypoints:
    """Waypoints with, for each, the heading of the leg leaving it, the turn on the spot made
    there before that leg, and the leg's length. The last waypoint's heading is the arrival
    heading (its leg length 0, its turn 0 or the turn to ``goal_heading``); the first one's turn
    is NaN when the rover's heading at the start is not known."""

    xy: np.ndarray  # (m, 2)
    heading_deg: np.ndarray
    turn_deg: np.ndarray
    leg_length: np.ndarray

    COLUMNS = ("x", "y", "heading_deg", "turn_deg", "leg_length")

    def __len__(self) -> int:
        return len(self.xy)

    def table(self) -> np.ndarray:
        return np.column_stack([self.xy, self.heading_deg, self.turn_deg, self.leg_length])

    def rows(self) -> list[dict[str, float | None]]:
        """One dict per waypoint, NaN as None (YAML null)."""
        return [{k: (None if np.isnan(v) else float(v)) for k, v in zip(self.COLUMNS, row, strict=True)}
                for row in self.table()]


def make_waypoints(points: np.ndarray, start_heading: float | None = None,
                   goal_heading: float | None = None) -> Waypoints:
    """Headings, turns and leg lengths of a polyline of waypoints (degrees, metres)."""
    xy = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    m = len(xy)
    legs = np.diff(xy, axis=0)
    length = np.hypot(legs[:, 0], legs[:, 1])
    leg_heading = np.degrees(np.arctan2(legs[:, 1], legs[:, 0]))
    heading = np.empty(m)
    turn = np.empty(m)
    if m == 1:  # no move: at most a turn to the goal heading
        heading[0] = np.nan if start_heading is None else _wrap(start_heading)
        turn[0] = 0.0 if goal_heading is None else np.nan if start_heading is None else _wrap(goal_heading - start_heading)
        return Waypoints(xy, heading, turn, np.zeros(1))
    heading[:-1] = leg_heading
    heading[-1] = leg_heading[-1]
    turn[0] = np.nan if start_heading is None else _wrap(leg_heading[0] - start_heading)
    turn[1:-1] = _wrap(np.diff(leg_heading))
    turn[-1] = 0.0 if goal_heading is None else _wrap(goal_heading - leg_heading[-1])
    return Waypoints(xy, _wrap(heading), turn, np.concatenate([length, [0.0]]))
