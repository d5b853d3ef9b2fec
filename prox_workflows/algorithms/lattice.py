"""A state lattice over (x, y, heading) and an A* on it whose edges a caller judges.

The lattice is a grid of ``res`` cells with ``n`` headings (16 by default: the directions of the
cell offsets (1, 0), (2, 1), (1, 1), (1, 2), ... so that every straight motion ends on a cell
centre; their angles are 0, 26.6, 45, 63.4, 90 ... degrees, not evenly spaced). From every state
three kinds of motion primitive leave, each ending on a lattice state:

- a **straight** one direction offset long (5 cm along an axis, 7 cm on a diagonal, 11 cm between);
- an **arc** to each neighbouring heading, ending on the sum of the two headings' offsets, along a
  cubic Bezier whose tangents are the two headings (a smooth curve a skid steer follows);
- a **turn on the spot** to each neighbouring heading.

Each primitive carries its dense poses: consecutive poses no farther apart than ``step`` at any
point of a body of ``reach`` (the same spacing :func:`prox_workflows.algorithms.vehicle.densify`
gives a track), so a caller judges a motion by its poses alone.

:func:`search` is A* over the states with the straight-line distance to the goal as its heuristic
(admissible and consistent: every primitive's cost is at least its chord; a turn on the spot costs
``turn_cost`` >= 0). Edges are judged lazily, in batches: a state's successors go on the open list
unjudged, and an entry is judged only when it comes to the top; then the next ``batch`` unjudged
entries are judged with it, in one call of the edge check, and put back (a lookahead that keeps
the search exact: an entry closes its state only when it is popped judged safe). Verdicts are
cached per (state, primitive) and the end pose's per state, so a re-search with the same cache
judges nothing twice.

With ``judge_every`` k > 1 the search judges a motion by every k-th of its dense poses (counted
back from its end) and its end state's pose: a subset, so a motion it refuses is unsafe, and a
path it finds has every motion judged on all its poses afterwards; a motion that fails there is
refused and the search runs again with what it has learnt, until its path passes in full (lazy
search: the result is the same shortest path as judging every pose, for a fraction of the
poses, since most motions never lie on a candidate path). ``weight`` > 1 inflates the heuristic
(weighted A*: at most ``weight`` times the shortest path's cost, far fewer expansions); 1 is exact.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Primitive", "LatticePath", "EdgeCache", "directions", "primitives", "search"]

EdgeCheck = Callable[[np.ndarray], np.ndarray]  # (M, 3) poses x, y, heading deg -> (M,) bool safe


def directions(n: int = 16) -> np.ndarray:
    """(n, 2) integer cell offsets of the lattice's headings, counter-clockwise from +x: 8 gives
    the grid's 8 neighbours, 16 adds the knight moves between them."""
    if n == 8:
        base = [(1, 0), (1, 1)]
    elif n == 16:
        base = [(1, 0), (2, 1), (1, 1), (1, 2)]
    else:
        raise ValueError(f"{n} headings: the lattice has 8 or 16 (cell-aligned directions)")
    out = []
    for q in range(4):  # each quadrant: the first quadrant's offsets rotated by 90 degrees
        for dx, dy in base:
            for _ in range(q):
                dx, dy = -dy, dx
            out.append((dx, dy))
    return np.array(out, int)


@dataclass(frozen=True)
class Primitive:
    """One motion from heading ``start`` to heading ``end``, ending ``cells`` away (dx, dy in cells):
    its ``poses`` relative to the start state's cell centre (K, 3: x, y m, heading deg; the last is
    the end state's), its driven ``length`` (m) and its search ``cost``."""

    kind: str  # straight, arc, turn
    start: int
    end: int
    cells: tuple[int, int]
    poses: np.ndarray
    length: float
    cost: float


def _resample(curve: np.ndarray, step: float, reach: float) -> np.ndarray:
    """Poses of a finely sampled ``curve`` (x, y, heading rad) kept so that no point of a body
    of ``reach`` moves more than ``step`` between two: the motion measure is the distance plus
    the turn at the reach, and the poses are spaced evenly by it."""
    d = np.hypot(*np.diff(curve[:, :2], axis=0).T) + reach * np.abs(np.diff(curve[:, 2]))
    s = np.concatenate([[0.0], np.cumsum(d)])
    k = max(1, math.ceil(s[-1] / step - 1e-9))
    at = np.arange(1, k + 1) * s[-1] / k
    return np.column_stack([np.interp(at, s, curve[:, i]) for i in range(3)])


def primitives(res: float = 0.05, n: int = 16, step: float = 0.02, reach: float = 0.4,
               turn_cost: float = 0.02) -> list[list[Primitive]]:
    """The lattice's motion primitives per start heading: a straight, an arc to each neighbouring
    heading and a turn on the spot to each, with their dense poses (``step`` apart at ``reach``).
    A turn costs ``turn_cost`` (m) per heading step: it adds nothing to the driven length, but a
    path that turns for nothing should lose to one that does not."""
    dirs = directions(n)
    ang = np.arctan2(dirs[:, 1], dirs[:, 0])
    out: list[list[Primitive]] = []
    t = np.linspace(0.0, 1.0, 201)[:, None]
    for k in range(n):
        mine: list[Primitive] = []
        d = dirs[k] * res
        line = np.column_stack([t[:, 0] * d[0], t[:, 0] * d[1], np.full(len(t), ang[k])])
        length = float(np.hypot(*d))
        mine.append(Primitive("straight", k, k, (int(dirs[k][0]), int(dirs[k][1])),
                              _as_deg(_resample(line, step, reach)), length, length))
        for e in ((k + 1) % n, (k - 1) % n):
            turn = (ang[e] - ang[k] + math.pi) % (2 * math.pi) - math.pi
            end = (dirs[k] + dirs[e]) * res
            a = float(np.hypot(*end)) / 3
            p0, p3 = np.zeros(2), end
            p1 = p0 + a * np.array([math.cos(ang[k]), math.sin(ang[k])])
            p2 = p3 - a * np.array([math.cos(ang[e]), math.sin(ang[e])])
            xy = (1 - t) ** 3 * p0 + 3 * (1 - t) ** 2 * t * p1 + 3 * (1 - t) * t ** 2 * p2 + t ** 3 * p3
            tangent = 3 * (1 - t) ** 2 * (p1 - p0) + 6 * (1 - t) * t * (p2 - p1) + 3 * t ** 2 * (p3 - p2)
            heading = np.unwrap(np.arctan2(tangent[:, 1], tangent[:, 0]))
            heading += ang[k] - heading[0]  # the curve's own tangent, anchored at the start heading
            curve = np.column_stack([xy, heading])
            curve[-1, 2] = ang[k] + turn
            arc_len = float(np.sum(np.hypot(*np.diff(xy, axis=0).T)))
            cells = dirs[k] + dirs[e]
            mine.append(Primitive("arc", k, e, (int(cells[0]), int(cells[1])), _as_deg(_resample(curve, step, reach)),
                                  arc_len, arc_len))
            spin = np.column_stack([np.zeros(len(t)), np.zeros(len(t)), ang[k] + t[:, 0] * turn])
            mine.append(Primitive("turn", k, e, (0, 0), _as_deg(_resample(spin, step, reach)), 0.0, turn_cost))
        out.append(mine)
    return out


def _as_deg(poses: np.ndarray) -> np.ndarray:
    out = poses.copy()
    out[:, 2] = (np.degrees(out[:, 2]) + 180.0) % 360.0 - 180.0
    return out


@dataclass
class EdgeCache:
    """Verdicts kept between searches on the same lattice and ground: per state (its pose) and per
    (state, primitive index) (the motion's poses)."""

    states: dict[tuple[int, int, int], bool] = field(default_factory=dict)
    edges: dict[tuple[int, int, int, int], bool] = field(default_factory=dict)
    full: set[tuple[int, int, int, int]] = field(default_factory=set)  # edges judged on every pose
    poses_checked: int = 0


@dataclass
class LatticePath:
    """A path found on the lattice: its ``states`` (cell x, cell y, heading index) from the start,
    the primitive taken into each (``-1`` for the start), its dense ``poses`` (N, 3; world x, y,
    heading deg), its driven ``length`` (m, turns on the spot add none) and search figures."""

    states: list[tuple[int, int, int]]
    prims: list[int]
    poses: np.ndarray
    length: float
    cost: float
    expanded: int


@dataclass
class SearchResult:
    """A search's outcome: the path or None, and why not (``exhausted``: no state left to reach the
    goal from; ``budget``: ``max_expansions`` met first, nothing proven)."""

    path: LatticePath | None
    reason: str
    expanded: int
    poses_checked: int
    searches: int = 1


def search(start: tuple[float, float], start_heading: float, goal: tuple[float, float],
           bounds: tuple[float, float, float, float], edge_check: EdgeCheck, *, res: float = 0.05,
           prims: list[list[Primitive]] | None = None, weight: float = 1.0, batch: int = 64,
           judge_every: int = 1, max_expansions: int = 2_000_000, max_searches: int = 50,
           cache: EdgeCache | None = None) -> SearchResult:
    """A* on the lattice from ``start`` (the lattice's origin: its cell centre) at the lattice
    heading nearest ``start_heading`` (deg) to the cell holding ``goal`` (any heading), over the
    states whose cell centre lies inside ``bounds`` (xmin, ymin, xmax, ymax). ``edge_check`` judges
    the dense poses of a batch of motions at once (see the module's docstring). ``max_expansions``
    bounds the expansions of all the lazy re-searches together, ``max_searches`` their number
    (``budget`` when either runs out: nothing proven)."""
    prims = prims if prims is not None else primitives(res)
    cache = cache if cache is not None else EdgeCache()
    checked0, expanded = cache.poses_checked, 0
    for k in range(max_searches):
        r = _search_once(start, start_heading, goal, bounds, edge_check, res, prims, weight, batch, judge_every,
                         max_expansions - expanded, cache)
        expanded += r.expanded
        if r.path is None or judge_every == 1:
            return SearchResult(r.path, r.reason, expanded, cache.poses_checked - checked0, k + 1)
        origin = np.array([start[0], start[1], 0.0])
        todo = [(*a, pi) for a, pi in zip(r.path.states[:-1], r.path.prims[1:], strict=True)
                if (*a, pi) not in cache.full]
        chunks = [prims[key[2]][key[3]].poses[:-1] + origin + np.array([key[0] * res, key[1] * res, 0.0])
                  for key in todo]
        if chunks:
            for key, safe in zip(todo, _verdicts(chunks, edge_check, cache), strict=True):
                cache.edges[key] = safe
                cache.full.add(key)
        if all(cache.edges[key] for key in todo):
            return SearchResult(r.path, r.reason, expanded, cache.poses_checked - checked0, k + 1)
    return SearchResult(None, "budget", expanded, cache.poses_checked - checked0, max_searches)


def _search_once(start: tuple[float, float], start_heading: float, goal: tuple[float, float],
                 bounds: tuple[float, float, float, float], edge_check: EdgeCheck, res: float,
                 prims: list[list[Primitive]], weight: float, batch: int, judge_every: int, max_expansions: int,
                 cache: EdgeCache) -> SearchResult:
    n = len(prims)
    dirs = directions(n)
    ang = np.degrees(np.arctan2(dirs[:, 1], dirs[:, 0]))
    h0 = int(np.argmin(np.abs((ang - start_heading + 180.0) % 360.0 - 180.0)))
    checked0 = cache.poses_checked
    sx, sy = start
    lo_i, hi_i = math.ceil((bounds[0] - sx) / res - 1e-9), math.floor((bounds[2] - sx) / res + 1e-9)
    lo_j, hi_j = math.ceil((bounds[1] - sy) / res - 1e-9), math.floor((bounds[3] - sy) / res + 1e-9)
    inside = bounds[0] <= goal[0] <= bounds[2] and bounds[1] <= goal[1] <= bounds[3]
    if not (lo_i <= 0 <= hi_i and lo_j <= 0 <= hi_j and inside):
        raise ValueError("start and goal must lie inside the search bounds")
    # a goal on the bounds' edge may sit in a cell whose centre lies outside them: its nearest state
    # inside stands for it (less than a cell away)
    gi = min(max(round((goal[0] - sx) / res), lo_i), hi_i)
    gj = min(max(round((goal[1] - sy) / res), lo_j), hi_j)
    cost_of = [[p.cost for p in row] for row in prims]
    cells_of = [[p.cells for p in row] for row in prims]
    end_of = [[p.end for p in row] for row in prims]

    def h(i: int, j: int) -> float:
        return weight * res * math.hypot(i - gi, j - gj)

    # entry: (f, -g, tie, state, parent state, primitive index, judged)
    start_state = (0, 0, h0)
    heap: list[tuple[float, float, int, tuple[int, int, int], tuple[int, int, int] | None, int, bool]] = []
    tie = 0
    heapq.heappush(heap, (h(0, 0), -0.0, tie, start_state, None, -1, False))
    closed: dict[tuple[int, int, int], tuple[tuple[int, int, int] | None, int, float]] = {}
    expanded = 0

    while heap:
        entry = heapq.heappop(heap)
        f, neg_g, _, st, parent, pi, judged = entry
        if st in closed:
            continue
        if not judged:
            group = [entry]
            held = []
            while heap and len(group) < batch:
                nxt = heapq.heappop(heap)
                if nxt[3] in closed:
                    continue
                (held if nxt[6] else group).append(nxt)
            for e, ok in zip(group, _judge(group, edge_check, cache, prims, start, res, ang, judge_every),
                             strict=True):
                if ok:
                    heapq.heappush(heap, (*e[:6], True))
            for e in held:
                heapq.heappush(heap, e)
            continue
        g = -neg_g
        closed[st] = (parent, pi, g)
        expanded += 1
        if (st[0], st[1]) == (gi, gj):
            return SearchResult(_path(closed, st, prims, (sx, sy), res, ang), "found", expanded,
                                cache.poses_checked - checked0)
        if expanded >= max_expansions:
            return SearchResult(None, "budget", expanded, cache.poses_checked - checked0)
        i, j, k = st
        for q in range(len(cost_of[k])):
            di, dj = cells_of[k][q]
            ni, nj, nk = i + di, j + dj, end_of[k][q]
            nst = (ni, nj, nk)
            if nst in closed or not (lo_i <= ni <= hi_i and lo_j <= nj <= hi_j):
                continue
            if cache.edges.get((i, j, k, q)) is False or cache.states.get(nst) is False:
                continue
            g2 = g + cost_of[k][q]
            tie += 1
            known = cache.edges.get((i, j, k, q)) is True and cache.states.get(nst) is True
            heapq.heappush(heap, (g2 + h(ni, nj), -g2, tie, nst, st, q, known))
    return SearchResult(None, "exhausted", expanded, cache.poses_checked - checked0)


def _judge(entries: list[tuple], edge_check: EdgeCheck, cache: EdgeCache, prims: list[list[Primitive]],
           origin: tuple[float, float], res: float, ang: np.ndarray, judge_every: int) -> list[bool]:
    """Verdicts of the entries' motions: first their end states' poses not yet judged, then the
    motions whose end state is safe, all in as few calls as possible."""
    sx, sy = origin
    todo_states = []
    for e in entries:
        st = e[3]
        if st not in cache.states and st not in todo_states:
            todo_states.append(st)
    if todo_states:
        poses = np.array([(sx + i * res, sy + j * res, ang[k]) for i, j, k in todo_states])
        ok = np.asarray(edge_check(poses), bool)
        cache.poses_checked += len(poses)
        for st, v in zip(todo_states, ok, strict=True):
            cache.states[st] = bool(v)
    verdict: list[bool | None] = []
    todo_edges: list[tuple[int, int, int, int]] = []
    chunks: list[np.ndarray] = []
    for e in entries:
        st, parent, pi = e[3], e[4], e[5]
        if not cache.states[st]:
            verdict.append(False)
            continue
        if parent is None:
            verdict.append(True)
            continue
        key = (*parent, pi)
        if key in cache.edges:
            verdict.append(cache.edges[key])
            continue
        verdict.append(None)
        if key not in todo_edges:
            todo_edges.append(key)
            # the end pose is the state's, judged above; of the rest every judge_every-th from the end
            p = prims[parent[2]][pi].poses[:-1][::-1][judge_every - 1::judge_every]
            chunks.append(p + np.array([sx + parent[0] * res, sy + parent[1] * res, 0.0]))
    if todo_edges:
        for key, safe in zip(todo_edges, _verdicts(chunks, edge_check, cache), strict=True):
            cache.edges[key] = safe
            if judge_every == 1:
                cache.full.add(key)
    return [v if v is not None else cache.edges[(*e[4], e[5])] for v, e in zip(verdict, entries, strict=True)]


def _verdicts(chunks: list[np.ndarray], edge_check: EdgeCheck, cache: EdgeCache) -> list[bool]:
    """Each motion's verdict (all its poses safe), its poses judged in one call of ``edge_check``
    with every other motion's: the check's fixed cost is paid once a batch."""
    poses = np.concatenate(chunks)
    ok = np.asarray(edge_check(poses), bool) if len(poses) else np.zeros(0, bool)
    cache.poses_checked += len(poses)
    ends = np.cumsum([len(c) for c in chunks])
    return [bool(ok[e - len(c):e].all()) for c, e in zip(chunks, ends, strict=True)]



def _path(closed: dict, goal: tuple[int, int, int], prims: list[list[Primitive]], origin: tuple[float, float],
          res: float, ang: np.ndarray) -> LatticePath:
    states, taken = [goal], []
    while True:
        parent, pi, _ = closed[states[-1]]
        taken.append(pi)
        if parent is None:
            break
        states.append(parent)
    states.reverse()
    taken.reverse()
    sx, sy = origin
    poses = [np.array([[sx + states[0][0] * res, sy + states[0][1] * res, ang[states[0][2]]]])]
    length = 0.0
    for a, pi in zip(states[:-1], taken[1:], strict=True):
        p = prims[a[2]][pi]
        poses.append(p.poses + np.array([sx + a[0] * res, sy + a[1] * res, 0.0]))
        length += p.length
    return LatticePath(states, taken, np.concatenate(poses), length, closed[goal][2], len(closed))
