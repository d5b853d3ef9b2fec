"""Choosing the next drive the way Perseverance's ENav does: rank a tree of candidate paths by
what they are estimated to cost, then run the vehicle check down that list until one passes.

Why this shape
    A planner that searches a hazard map and a gate that can only say no afterwards disagree:
    the map's thresholds are not the body's limits, so the plan runs where the gate refuses, or
    the map closes gaps the body fits through. ENav (Toupet et al. 2020, "Enhanced AutoNav" on
    Mars 2020) makes the safety check itself the search's last word: it builds about 1,700
    paths from the rover's pose (turns on the spot, then arcs), sorts them by a cheap estimate
    (driving cost, a terrain cost from the height map, and the cost to go from the global
    planner at the path's end), and runs ACE (Otsu et al. 2020: the wheel-and-belly check on
    the rover's own geometry, on worst-case bounds) down the sorted list; the first path that
    passes is driven. Most paths are never checked: on easy ground the first few pass, and the
    check, the costly part, runs on a few hundred poses instead of tens of thousands.

What this module holds (plain functions on arrays; the loops that call them live in
``rvs_server.navigation``)
    - :func:`arc_tree`: the candidates in the rover's frame, built once per parameter set: a
      turn on the spot to one of ``headings`` headings, then a first arc (the *section*, the
      most a cycle commits to), then a second arc (the look-ahead to the horizon), each arc one
      of ``arcs`` curvatures. 16 x 9 x 9 = 1,296 paths by default, 2.5 m deep. The tree shares
      prefixes: 16 turns, 144 sections, 1,296 leaves, and a verdict on a prefix is a verdict on
      every path through it.
    - :func:`coarse_costs` and :func:`cost_to_go`: the global guidance. A coarse grid (25 cm)
      from the map: ground the map proves impassable is a wall, unseen ground a cost (a reason
      to go and look, never a wall), and Dijkstra from the goal over it gives every cell its
      cost to go. It is recomputed whole once per replan (a few milliseconds on a mission's
      grid with scipy's compiled Dijkstra); an incremental D* Lite repair
      (:class:`.replan.IncrementalPlanner`) would only pay on grids far larger than this.
    - :func:`choose`: the ranking and the lazy check. Candidates are checked in rank order in
      batches (the top four first, the batch doubling as they fail), the dense poses of every
      prefix not yet judged sent to the pluggable ``check``: the first batch whole in one call
      (on open ground it passes, and a call costs as much as a hundred poses), each later one
      in two, the turns and sections first, then the look-aheads of the sections that passed,
      so that a refused section spares its nine leaves. No pose is judged twice. Nothing is remembered
      between calls: a refusal concerns the map it was made on, and expires with it. The tree's
      poses are ``step`` apart at the body's farthest point; the candidate about to be chosen
      has its turn and section judged again between them, ``verify_step`` apart (the spacing
      the vehicle yardstick judges a track at), and fails if a pose there does: turning 7 deg
      between two of the tree's headings, a wheel's corner passes over a post no judged pose put
      it on.
    - The checks it takes (:data:`Check`): :func:`bounds_check` (the worst case on bounds, or the
      check on one height grid), :func:`posterior_check` (the chance constraint on the cells'
      posteriors, :mod:`.chance`, each call drawing only the cells round its poses) and
      :func:`best_check` (the posterior's best estimate, one check per pose: for the look-aheads,
      which only rank).

The rules on unseen ground (a cost and a reason to look, never driven on)
    - A section (the turn and the first arc) is driven only if every pose of it is judged safe.
      One whose ground is unseen fails as ``unknown``.
    - Beyond the section, unseen ground adds ``unknown_cost`` per metre to the estimate: the
      rover will look there before it gets there. A look-ahead pose judged over a limit refuses
      the path (``ahead_cost`` 0), or prices it, ``ahead_cost`` per metre of the look-ahead from
      that pose on, the path ranked again with that price. The look-ahead is judged 1-2.5 m out
      on ground seen from afar, where three in four of its refusals stand on truly safe ground
      (marsyard, traced against the truth); priced, the rover no longer bends round rocks its
      section never meets (marsyard's efficiency up by a quarter), but on hirise's slopes it
      drove into places it found no way on from (docs/NAVIGATE_BENCH.md), so the veto is the
      default. Priced, a look-ahead failing within ``ahead_min`` of the section's end still
      refuses its path (that section would end at the edge of ground the map already calls over
      a limit), and a priced path is driven only if some look-ahead from its section's end
      passes: a section with no way on from its end is a pocket.
    - Looking has a price, ``look_cost`` (in metres of driving): a path whose section crosses
      unseen ground ranks with that price added, and if it still ranks before every path that
      passes, the answer is *look* (at the first unseen pose of it), not a worse drive. With no
      path passing, the answer is *look* if any failed on unseen ground, *blocked* if all failed
      on the body's limits.
    - Ground only a ray bounds (a ray passed over it, no return met it) is judged at the ray's
      ceiling, its highest possible; most such ground is in the mast's sight from where the rover
      stands, only no frame looked at it (frames taken on the way passed over it). A path refused
      on a limit there that ranks before every passing path by more than ``ray_look_cost`` (a
      frame's price, not a look round's) asks for a look at that ground, once from each place
      the rover stands (:func:`over_rays`, ``ray_looks``): without it the rover turned
      away from ground it could have seen was safe, and spent a fifth of its time turning on the
      spot (docs/NAVIGATE_BENCH.md).

Costs are metres: the path's length, ``turn_cost`` per radian turned on the spot,
``curve_cost`` per radian of arc (a gentle preference for straight), ``terrain_cost`` times the
relief under the wheels relative to the body's climb (mean heights, a 15 cm window, capped) per
metre, plus the cost to go from the path's end (or, for a path passing the goal, none after it).

Time: the vehicle check is most of a call (``python -m tools.bench.candidates``; figures in
docs/BENCHMARKS.md); the ranking itself reads the map at a probe every 20 cm of the tree.
"""

from __future__ import annotations

import heapq
import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from rvs_params import Settings, param
from rvs_params.deferred import deferred

from ..grid import GridGeometry
from .arcs import arc_poses, default_curvatures
from .chance import ChanceParams, Posterior, chance_check
from .vehicle import LIMITS, VehicleBody, check_poses, densify, reach

ndimage = deferred("scipy.ndimage")
sparse = deferred("scipy.sparse")
csgraph = deferred("scipy.sparse.csgraph")

__all__ = ["CandidateParams", "ArcTree", "CostToGo", "Choice", "Failure", "Check", "arc_tree", "coarse_costs",
           "cost_to_go", "bounds_check", "posterior_check", "best_check", "over_rays", "LOOK_GROUND", "crop", "choose", "SAFE", "UNKNOWN", "verdict_name", "UNKNOWN_COST"]

# A check's per-pose verdicts: SAFE, UNKNOWN, or 1 + the index in LIMITS of the limit exceeded worst.
SAFE = 0
UNKNOWN = -1
Check = Callable[[np.ndarray], np.ndarray]  # (N, 3) poses x, y, heading deg -> (N,) int verdicts
_PARTS = ("turn", "section", "beyond")
PROBE = 0.2  # m between the poses where the ranking reads the map
# what a look is for (Choice.look_for), as the progress lines and reasons name it
LOOK_GROUND = {"unseen": "unseen ground", "ray": "ground only a ray bounds"}


def verdict_name(code: int) -> str:
    """``safe``, ``unknown`` or the limit's name (``step``, ``belly``, ``stability``, ``grade``)."""
    return "safe" if code == SAFE else "unknown" if code == UNKNOWN else LIMITS[code - 1]


@dataclass
class CandidateParams(Settings):
    """The candidate tree and the costs that rank it."""

    headings: int = param(16, "headings the rover may turn to on the spot before it drives (evenly spaced, "
                              "straight ahead among them)", min=1, max=72)
    arcs: int = param(9, "curvatures of each arc, evenly spaced from the tightest left to the tightest right",
                      min=1, max=31)
    max_curvature: float = param(2.4, "the tightest arc's curvature (1 / radius)", unit="1/m", min=0.0, max=10.0)
    section: float = param(1.0, "length of the first arc: the most one cycle commits to driving", unit="m",
                           min=0.1, max=5.0)
    beyond: float = param(1.5, "length of the second arc, the look-ahead to the horizon", unit="m", min=0.0,
                          max=10.0)
    rough_cost: float = param(3.0, "the coarse guidance: a coarse cell costs 1 plus this times its roughness, per "
                                   "metre: the share of the poses centred on it that the check refuses "
                                   "(rough_headings), else its relief over the body's climb (capped at 1)",
                              min=0.0, max=100.0)
    rough_headings: int = param(4, "the coarse guidance: headings over a half turn at which the poses centred on a "
                                   "coarse cell are judged on the map's mean surface; 0: the cell's relief instead, "
                                   "most of which is the slope under it. Measured on hirise and dense 0-4 under two "
                                   "sensor noise draws against the relief (docs/NAVIGATE_BENCH.md)", min=0, max=36)
    step: float = param(0.05, "the section's poses are this far apart at the body's farthest point", unit="m",
                        min=0.005, max=0.5)
    beyond_step: float = param(0.10, "the look-ahead's poses are this far apart (it is judged again, closer, "
                                     "before it is driven)", unit="m", min=0.005, max=1.0)
    turn_cost: float = param(0.15, "cost of a turn on the spot per radian", unit="m", min=0.0, max=10.0)
    curve_cost: float = param(0.05, "cost per radian of heading an arc turns through", unit="m", min=0.0, max=10.0)
    terrain_cost: float = param(2.0, "cost per metre of ground whose relief under a wheel reaches the body's "
                                     "climb (less in proportion; capped at twice)", unit="m", min=0.0, max=100.0)
    unknown_cost: float = param(1.0, "extra cost per metre of unseen ground beyond the section", unit="m",
                                min=0.0, max=100.0)
    ahead_cost: float = param(0.0, "0: a look-ahead over a limit refuses its candidate, as a section's pose over "
                                   "a limit does; above 0, the extra cost per metre of the look-ahead from its first "
                                   "pose judged over a limit to its end: a blocked continuation ranks its section "
                                   "down, and the section is still driven only if it passes", unit="m", min=0.0,
                              max=100.0)
    ahead_min: float = param(0.5, "a look-ahead over a limit within this far of its section's end refuses its "
                                  "candidate: a section that ends facing ground the map already calls over a limit "
                                  "puts the body's last poses at that ground's edge", unit="m", min=0.0, max=10.0)
    verify_step: float = param(0.02, "a candidate about to be chosen has its turn and section judged again between "
                                     "their poses, this far apart at the body's farthest point (0: not): a rock's "
                                     "crest under the box's edge can rise over the belly within a few degrees of a "
                                     "turn (docs/NAVIGATE_BENCH.md, dense mission 8's event traced)", unit="m",
                                min=0.0, max=0.5)
    look_cost: float = param(1.5, "the price of stopping to look, in metres of driving: a path through unseen "
                                  "ground that ranks better than every passing path by more than this asks "
                                  "for a look", unit="m", min=0.0, max=100.0)
    ray_looks: bool = param(True, "a path refused on a limit over ground only a ray bounds (a ray passed over "
                                  "it, no return met it) asks for a look there, once from where the rover stands, "
                                  "if it ranks before every passing path by more than ray_look_cost: the ray's "
                                  "ceiling is the ground's highest possible, and a frame from here shows most "
                                  "such ground")
    ray_look_cost: float = param(0.3, "the price of that look, in metres of driving: one frame toward that ground, "
                                      "the mast's slew and the frames averaged (a few seconds), never a look round", unit="m", min=0.0, max=100.0)
    batch: int = param(4, "candidates in the first batch sent to the check; each later batch doubles, up to 64",
                       min=1, max=1024)
    max_poses: int = param(0, "the most poses one call sends to the check before it gives up with 'blocked' "
                              "(0: no limit, every candidate is checked if need be)", min=0, max=10_000_000)
    goal_tolerance: float = param(0.1, "a path passing this close to the goal (and half the ranking's probe "
                                       "spacing) ranks by its cost to the goal, and its section stops at its "
                                       "pose nearest the goal", unit="m", min=0.0, max=5.0)

    @property
    def coarse(self) -> dict[str, float]:
        """The coarse guidance's keywords for :func:`coarse_costs`."""
        return {"rough_cost": self.rough_cost, "rough_headings": self.rough_headings}


@dataclass(frozen=True)
class ArcTree:
    """The candidates in the rover's frame (the rover at the origin, heading 0 deg).

    Nodes are the tree's segments: ``nodes[k]`` poses are ``poses[start[k]:start[k + 1]]`` (the
    segment's poses after its first, which is its parent's last), ``part[k]`` 0 turn, 1 section
    arc, 2 look-ahead arc, ``parent[k]`` (-1 for a turn). ``paths[c]`` are candidate c's three
    nodes; ``base[c]`` its cost that does not depend on the map (length, turning)."""

    poses: np.ndarray  # (P, 3)
    start: np.ndarray  # (K + 1,)
    part: np.ndarray  # (K,)
    parent: np.ndarray  # (K,)
    length: np.ndarray  # (K,) m driven (0 for a turn)
    paths: np.ndarray  # (C, 3) node indices: turn, section, beyond
    base: np.ndarray  # (C,)
    probe: np.ndarray  # (Q,) indices into poses where the map's terrain and unseen ground are read
    probe_node: np.ndarray  # (Q,) the node of each probe
    probe_ds: np.ndarray  # (Q,) the metres each probe stands for (a turn's: its swept arc at the reach)
    probe_s: np.ndarray  # (Q,) metres driven along its node to the probe (0 on a turn)

    def node(self, k: int) -> np.ndarray:
        return self.poses[self.start[k]:self.start[k + 1]]


def arc_tree(params: CandidateParams, body: VehicleBody) -> ArcTree:
    """The candidate tree for ``params`` and ``body`` (cached: the same arguments give the same
    tree object)."""
    return _tree(params.headings, params.arcs, params.max_curvature, params.section, params.beyond, params.step,
                 params.beyond_step, params.turn_cost, params.curve_cost, round(reach(body), 6))


@lru_cache(maxsize=8)
def _tree(headings: int, n_arcs: int, kmax: float, section: float, beyond: float, step: float, beyond_step: float,
          turn_cost: float, curve_cost: float, body_reach: float) -> ArcTree:
    turns = (np.arange(headings) * 360.0 / headings + 180.0) % 360.0 - 180.0  # 0 first, 180 last when even
    ks = default_curvatures(1.0 / kmax, n_arcs) if kmax > 0 and n_arcs > 1 else np.zeros(1)
    chunks: list[np.ndarray] = []
    part: list[int] = []
    parent: list[int] = []
    length: list[float] = []
    paths: list[tuple[int, int, int]] = []
    base: list[float] = []

    def add(poses: np.ndarray, p: int, up: int, metres: float) -> int:
        chunks.append(poses)
        part.append(p)
        parent.append(up)
        length.append(metres)
        return len(part) - 1

    def arc(pose: np.ndarray, k: float, metres: float, spacing: float) -> np.ndarray:
        # spaced so that the body's farthest point, not its centre, moves at most ``spacing``
        return arc_poses(pose, k, metres, spacing / (1.0 + body_reach * abs(k)))[1:]

    for h in turns:
        # a turn on the spot spaced as :func:`.vehicle.densify` spaces it: ``step`` of arc at the reach
        n = max(1, math.ceil(math.radians(abs(h)) * body_reach / step - 1e-9)) if h != 0 else 0
        turn = np.column_stack([np.zeros(n), np.zeros(n), h * np.arange(1, n + 1) / max(n, 1)])
        t = add(turn, 0, -1, 0.0)
        after_turn = np.array([0.0, 0.0, h])
        for k1 in ks:
            a1 = arc(after_turn, float(k1), section, step)
            s = add(a1, 1, t, section)
            for k2 in ks:
                a2 = arc(a1[-1], float(k2), beyond, beyond_step) if beyond > 0 else np.zeros((0, 3))
                b = add(a2, 2, s, beyond)
                paths.append((t, s, b))
                base.append(section + beyond + turn_cost * math.radians(abs(h))
                            + curve_cost * (abs(k1) * section + abs(k2) * beyond))
    start = np.concatenate([[0], np.cumsum([len(c) for c in chunks])])
    poses = np.concatenate(chunks)
    poses[:, 2] = (poses[:, 2] + 180.0) % 360.0 - 180.0
    # the map is read for ranking about every PROBE metres (of arc at the reach, on a turn): the
    # ranking is an estimate, and reading it at every checked pose of 1,300 paths would cost more
    # than the checks it saves
    probe, probe_node, probe_ds, probe_s = [], [], [], []
    for k, chunk in enumerate(chunks):
        m = len(chunk)
        if not m:
            continue
        metres = length[k] if part[k] else math.radians(abs(float(chunk[-1, 2]))) * body_reach
        q = max(1, min(m, round(metres / PROBE)))
        at = start[k] + np.unique(np.round(np.linspace(m - 1, 0, q, endpoint=False)[::-1]).astype(int))
        probe.append(at)
        probe_node.append(np.full(len(at), k))
        probe_ds.append(np.full(len(at), metres / len(at)))
        probe_s.append((at - start[k] + 1) / m * length[k])
    arrays = (poses, start, np.array(part), np.array(parent), np.array(length), np.array(paths), np.array(base),
              np.concatenate(probe), np.concatenate(probe_node), np.concatenate(probe_ds), np.concatenate(probe_s))
    for a in arrays:
        a.setflags(write=False)
    return ArcTree(*arrays)


@dataclass(frozen=True)
class CostToGo:
    """The cost to go to the goal (m) from each cell of a coarse grid (inf: no way there)."""

    field: np.ndarray
    geometry: GridGeometry
    goal: tuple[float, float]

    def at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """The cost to go from points: the cheapest of the four nearest cell centres' costs plus
        the way to that centre (a point beside a wall cell is not blocked by it); off the grid,
        the straight line to the goal."""
        g = self.geometry
        x, y = np.asarray(x, float), np.asarray(y, float)
        fc = (x - g.xmin) / g.cell - 0.5
        fr = (g.ymax - y) / g.cell - 0.5
        c0, r0 = np.floor(fc).astype(np.int64), np.floor(fr).astype(np.int64)
        best = np.full(x.shape, np.inf)
        for dr in (0, 1):
            for dc in (0, 1):
                r, c = r0 + dr, c0 + dc
                ok = (r >= 0) & (r < g.height) & (c >= 0) & (c < g.width)
                v = self.field[np.clip(r, 0, g.height - 1), np.clip(c, 0, g.width - 1)]
                cx, cy = g.xmin + (c + 0.5) * g.cell, g.ymax - (r + 0.5) * g.cell
                best = np.where(ok, np.minimum(best, v + np.hypot(x - cx, y - cy)), best)
        inside = (x >= g.xmin) & (x <= g.xmax) & (y >= g.ymin) & (y <= g.ymax)
        return np.where(inside, best, np.hypot(x - self.goal[0], y - self.goal[1]))


def _mean(heights: np.ndarray | tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The mean surface and the mask of unseen cells (no upper bound)."""
    if isinstance(heights, tuple):
        lower, upper = heights
        mean = (np.where(np.isnan(lower), upper, lower) + upper) / 2
        return mean, np.isnan(upper)
    return heights, np.isnan(heights)


UNKNOWN_COST = 2.0  # per metre: a coarse cell mostly unseen (a cost, never a wall)


def coarse_costs(heights: np.ndarray | tuple[np.ndarray, np.ndarray], geom: GridGeometry, body: VehicleBody,
                 cell: float = 0.25, unknown_cost: float = UNKNOWN_COST, rough_cost: float = 1.0,
                 rough_headings: int = 0) -> tuple[np.ndarray, GridGeometry]:
    """A coarse cost grid (per metre) over ``geom``'s area for :func:`cost_to_go`, from a height
    grid or a ``(lower, upper)`` bounds pair: a coarse cell mostly unseen costs ``unknown_cost``
    (a cost, never a wall: the rover may look there); one whose ground certainly rises more than
    the body can pass (its highest lower bound over its lowest upper bound above both the climb
    and the clearance: neither a wheel nor the belly gets over it) is a wall (inf); the rest cost
    1 plus ``rough_cost`` times the mean surface's relief in it over the climb (capped at 1).
    ``rough_headings`` above 0 prices a cell by what the body meets there rather than by its
    relief, most of which is the slope under it, and over the whole body, which stands on the
    cells round it too: 1 plus ``rough_cost`` times the share of the poses centred on it (that
    many headings over a half turn) that the vehicle check refuses on the mean surface (a cell
    none of whose poses the map covers keeps its relief's cost)."""
    lower, upper = heights if isinstance(heights, tuple) else (heights, heights)
    f = max(1, round(cell / geom.cell))
    cg = GridGeometry(geom.cell * f, geom.xmin, geom.ymax, -(-geom.width // f), -(-geom.height // f))
    ph, pw = cg.height * f - geom.height, cg.width * f - geom.width

    def blocks(a: np.ndarray) -> np.ndarray:
        a = np.pad(np.asarray(a, float), ((0, ph), (0, pw)), constant_values=np.nan)
        return a.reshape(cg.height, f, cg.width, f).transpose(0, 2, 1, 3).reshape(cg.height, cg.width, f * f)

    lo, hi = blocks(lower), blocks(upper)
    mean, _ = _mean((lo, hi))
    seen = np.isfinite(hi).mean(axis=2) >= 0.5
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN blocks: unseen, handled below
        rise = np.nanmax(lo, axis=2) - np.nanmin(hi, axis=2)
        relief = np.nanmax(mean, axis=2) - np.nanmin(mean, axis=2)
    wall = seen & (np.nan_to_num(rise, nan=0.0) > max(body.climb, body.clearance))
    own = 1.0 + rough_cost * np.clip(np.nan_to_num(relief, nan=0.0) / body.climb, 0.0, 1.0)
    if rough_headings > 0:
        share = refused_share(_mean((lower, upper))[0], geom, cg, body, rough_headings, seen & ~wall)
        own = np.where(np.isnan(share), own, 1.0 + rough_cost * np.nan_to_num(share))
    out = np.where(seen, own, unknown_cost)
    out[wall] = np.inf
    return out, cg


def refused_share(surface: np.ndarray, geom: GridGeometry, cg: GridGeometry, body: VehicleBody,
                  headings: int, cells: np.ndarray | None = None) -> np.ndarray:
    """Per cell of the coarse grid ``cg``, the share of the poses centred on it (``headings``
    over a half turn: the body's footprint turned end for end covers the same ground) that the
    vehicle check refuses on ``surface`` (NaN: unseen), among those it judges; NaN where it
    judges none, and on cells off ``cells`` (a mask over ``cg``; None: all), which are not judged."""
    rr, cc = np.nonzero(np.ones(cg.shape, bool) if cells is None else cells)
    x, y = cg.xmin + (cc + 0.5) * cg.cell, cg.ymax - (rr + 0.5) * cg.cell
    h = np.arange(headings) * 180.0 / headings
    poses = np.column_stack([np.repeat(x, headings), np.repeat(y, headings), np.tile(h, x.size)])
    s = np.asarray(surface, np.float32)
    c = check_poses((s, s.copy()), geom, poses, body)
    judged = (~c.unknown).reshape(-1, headings)
    refused = (c.unsafe & ~c.unknown).reshape(-1, headings)
    out = np.full(cg.shape, np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        out[rr, cc] = np.where(judged.any(axis=1), refused.sum(axis=1) / judged.sum(axis=1), np.nan)
    return out


def cost_to_go(cost: np.ndarray, geom: GridGeometry, goal: tuple[float, float]) -> CostToGo:
    """Dijkstra from ``goal`` over the 8-connected ``cost`` grid (per metre, inf = wall; a step
    costs its length times the mean of its two cells, a diagonal is refused past a wall corner).
    A goal off the grid is reached through the grid's border cells at the straight-line distance
    from them; a goal on a wall cell is treated as free (the local check judges it)."""
    cost = np.asarray(cost, float).copy()
    h, w = cost.shape
    gr, gc = geom.cell_of(goal[0], goal[1])
    gr, gc = int(gr), int(gc)
    inside = 0 <= gr < h and 0 <= gc < w
    if inside and not np.isfinite(cost[gr, gc]):
        cost[gr, gc] = 1.0
    idx = np.arange(h * w).reshape(h, w)
    rows, cols, vals = [], [], []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        c0, c1 = max(0, -dc), w - max(0, dc)
        a = idx[0:h - dr, c0:c1]
        b = idx[dr:h, c0 + dc:c1 + dc]
        ka, kb = cost.ravel()[a], cost.ravel()[b]
        weight = math.hypot(dr, dc) * geom.cell * (ka + kb) / 2
        ok = np.isfinite(weight)
        if dr and dc:  # no diagonal past a wall corner
            ra, ca = np.divmod(a, w)
            ok &= np.isfinite(cost[ra + dr, ca]) & np.isfinite(cost[ra, ca + dc])
        rows.append(a[ok])
        cols.append(b[ok])
        vals.append(np.maximum(weight[ok], 1e-12))
    n = h * w
    if inside:
        source = int(idx[gr, gc])
    else:  # a virtual node off the grid, joined to the border at the straight-line distance
        border = np.unique(np.concatenate([idx[0], idx[-1], idx[:, 0], idx[:, -1]]))
        border = border[np.isfinite(cost.ravel()[border])]
        br, bc = np.divmod(border, w)
        xs, ys = geom.xmin + (bc + 0.5) * geom.cell, geom.ymax - (br + 0.5) * geom.cell
        rows.append(np.full(len(border), n))
        cols.append(border)
        vals.append(np.maximum(np.hypot(xs - goal[0], ys - goal[1]), 1e-12))
        source = n
        n += 1
    graph = sparse.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)).tocsr()
    dist = csgraph.dijkstra(graph, directed=False, indices=source)
    return CostToGo(dist[:h * w].reshape(h, w), geom, (float(goal[0]), float(goal[1])))


def bounds_check(heights: np.ndarray | tuple[np.ndarray, np.ndarray], geom: GridGeometry,
                 body: VehicleBody) -> Check:
    """The vehicle check (:func:`.vehicle.check_poses`) on a bounds pair or one height grid as a
    :data:`Check`: per pose SAFE, UNKNOWN (ground under the body no bound covers) or 1 + the
    index of the limit exceeded worst (relative to its own limit)."""

    def check(poses: np.ndarray) -> np.ndarray:
        c = check_poses(heights, geom, poses, body)
        k, _ = c.worst(body)
        out = np.where(c.unsafe, k + 1, SAFE)
        out[c.unknown] = UNKNOWN
        return out

    return check


def posterior_check(post: Posterior, geom: GridGeometry, body: VehicleBody,
                    params: ChanceParams | None = None) -> Check:
    """The chance-constrained vehicle check (:func:`.chance.chance_check`) on the cells'
    posteriors ``post`` over ``geom`` as a :data:`Check`: per pose SAFE (P(any limit exceeded)
    at most epsilon), UNKNOWN, or 1 + the index of the limit most likely exceeded. Each call
    reads only the cells round its poses: the surfaces it draws are as large as what it reads."""
    pad = reach(body) + 2 * geom.cell

    def check(poses: np.ndarray, runs: np.ndarray | None = None) -> np.ndarray:
        poses = np.atleast_2d(np.asarray(poses, float))
        sub, sl = crop(geom, poses[:, 0].min() - pad, poses[:, 1].min() - pad, poses[:, 0].max() + pad,
                        poses[:, 1].max() + pad)
        if sl is None:
            return np.full(len(poses), UNKNOWN)
        c = chance_check(post.window(sl), sub, poses, body, params, verdict_only=True, runs=runs)
        k, _ = c.worst()
        out = np.where(c.unsafe, k + 1, SAFE)
        out[c.unknown] = UNKNOWN
        return out

    check.by_runs = True  # type: ignore[attr-defined]
    return check


def nearest_refusal(post: Posterior, geom: GridGeometry, body: VehicleBody, pose: tuple[float, float, float],
                    failures: list[Failure], params: CandidateParams, chance: ChanceParams | None = None) -> str:
    """Of the candidates whose turn or section the chance check refused on a limit, the one that
    came nearest to passing, in a sentence: its turn and section judged whole (every pose, not
    only to the first refused one), its worst pose's limit most likely exceeded, that probability
    against epsilon and the best estimate's margin there ("" where none was refused on a limit).
    A rover walled in by rock (P about 0.5) and one in a slot its belly fits only at a risk a few
    times the declared one (hirise's stops: P 5e-4 against 3e-4, the truth 2.4 cm clear) read
    the same without it, and only the second is an operator's call."""
    tree = arc_tree(params, body)
    refused = sorted({f.candidate for f in failures if f.part in ("turn", "section") and f.verdict in LIMITS})
    if not refused:
        return ""
    # each turn and section as the chosen one is judged: its poses and those between them, verify_step apart
    prefixes = sorted({tuple(int(k) for k in tree.paths[c][:2]): c for c in refused}.items())
    runs = [densify(np.vstack([pose, *(_to_world(np.asarray(tree.node(k)), pose) for k in prefix)]),
                    params.verify_step or params.step, body) for prefix, _ in prefixes]
    poses = np.concatenate(runs)
    pad = reach(body) + 2 * geom.cell
    sub, sl = crop(geom, poses[:, 0].min() - pad, poses[:, 1].min() - pad, poses[:, 0].max() + pad,
                   poses[:, 1].max() + pad)
    if sl is None:
        return ""
    c = chance_check(post.window(sl), sub, poses, body, chance)
    p_any = np.where(c.unknown, np.inf, np.nan_to_num(c.p_any, nan=np.inf))
    ends = np.cumsum([len(r) for r in runs])
    worst = [int(a + np.argmax(p_any[a:b])) for a, b in zip([0, *ends[:-1]], ends, strict=True)]
    j = int(np.argmin(p_any[worst]))
    i = worst[j]
    if not np.isfinite(p_any[i]):
        return ""
    k = int(np.nanargmax(c.prob[i]))
    margin = -float(c.nominal.excess[i, k])
    size = f"{100 * abs(margin):.1f} cm" if LIMITS[k] in ("step", "belly") else f"{abs(margin):.1f} deg"
    rank = min(f.rank for f in failures if f.candidate == prefixes[j][1])
    return (f"the nearest to passing, ranked {rank + 1}, is "
            f"at worst at ({poses[i, 0]:.2f}, {poses[i, 1]:.2f}, {poses[i, 2]:.0f} deg): P({LIMITS[k]}) "
            f"{c.prob[i, k]:.1e} against epsilon {c.epsilon:.1e}, the best estimate {size} "
            f"{'inside' if margin >= 0 else 'over'} the limit")


def best_check(post: Posterior, geom: GridGeometry, body: VehicleBody) -> Check:
    """The vehicle check on the posterior's best estimate of the ground (a ray's ceiling where no
    return bounds a cell; unknown where neither) as a :data:`Check`: one check per pose, no draws."""
    return bounds_check(post.best().astype(np.float32), geom, body)


def over_rays(mean: np.ndarray, ceiling: np.ndarray, geom: GridGeometry, body: VehicleBody
              ) -> Callable[[np.ndarray], np.ndarray]:
    """Per pose (N, 3: x, y, heading deg), where the body's box there stands over cells that
    only a ray bounds (a finite ``ceiling``: a ray passed over; no ``mean``: no return landed):
    the (x, y) of their middle, NaN where it stands over none. A limit judged there is judged on
    the ray's ceiling, the ground's highest possible, and most such ground is not hidden from
    where the rover stands: frames taken on the way passed over it, none looked at it (marsyard
    mission 1: 2,128 of the 2,218 such cells under the poses refused before the chosen one lay in
    the mast's line of sight on the true surface, docs/NAVIGATE_BENCH.md)."""
    only = ~np.isfinite(mean) & np.isfinite(ceiling)
    half = geom.cell / 2
    along = np.arange(-body.length / 2, body.length / 2 + 1e-9, half)
    across = np.arange(-body.width / 2, body.width / 2 + 1e-9, half)
    bx, by = (a.ravel() for a in np.meshgrid(along, across))

    def over(poses: np.ndarray) -> np.ndarray:
        poses = np.asarray(poses, np.float64).reshape(-1, 3)
        h = np.radians(poses[:, 2:3])
        x = poses[:, 0:1] + np.cos(h) * bx - np.sin(h) * by
        y = poses[:, 1:2] + np.sin(h) * bx + np.cos(h) * by
        r, c = geom.cell_of(x, y)
        inside = geom.inside(r, c)
        hit = np.zeros(r.shape, bool)
        hit[inside] = only[r[inside], c[inside]]
        n = hit.sum(axis=1)
        with np.errstate(invalid="ignore"):
            return np.column_stack([(x * hit).sum(axis=1) / n, (y * hit).sum(axis=1) / n])

    return over


def crop(geom: GridGeometry, xmin: float, ymin: float, xmax: float, ymax: float
          ) -> tuple[GridGeometry, tuple[slice, slice] | None]:
    """The part of ``geom`` over a box: its grid and its rows and columns (None: it misses)."""
    c0 = max(0, int(math.floor((xmin - geom.xmin) / geom.cell)))
    c1 = min(geom.width, int(math.ceil((xmax - geom.xmin) / geom.cell)))
    r0 = max(0, int(math.floor((geom.ymax - ymax) / geom.cell)))
    r1 = min(geom.height, int(math.ceil((geom.ymax - ymin) / geom.cell)))
    if r1 <= r0 or c1 <= c0:
        return geom, None
    sub = GridGeometry(geom.cell, geom.xmin + c0 * geom.cell, geom.ymax - r0 * geom.cell, c1 - c0, r1 - r0, geom.crs)
    return sub, (slice(r0, r1), slice(c0, c1))


@dataclass(frozen=True)
class Failure:
    """Why a candidate ranked before the chosen one failed: its ``rank``, which ``part`` (turn,
    section, beyond), the ``verdict`` (``unknown`` or the limit's name) at its first failing pose
    ``x``, ``y`` (world frame). With ``ahead_cost`` above 0, a candidate whose look-ahead fails
    is still ranked, priced by it, and may be the one chosen."""

    rank: int
    candidate: int
    part: str
    verdict: str
    x: float
    y: float
    index: int = 0  # the failing pose's index in its part
    heading: float = 0.0  # deg: the failing pose's


@dataclass
class Choice:
    """What :func:`choose` decided.

    ``status``: ``drive`` (``poses``: the section to drive, from the rover's pose, turn on the
    spot first where there is one; driven backwards where ``backward`` says so), ``look``
    (``look_at``: the first unseen ground on the best path, or the ground only a ray bounds under
    its refused pose, worth a look before anything is driven) or ``blocked`` (every candidate fails on the
    body's limits, or the goal has no way to it). ``reason`` says which, in a sentence."""

    status: str
    reason: str
    poses: np.ndarray
    path: np.ndarray  # the chosen candidate's poses to the horizon (empty if none)
    candidate: int = -1
    rank: int = -1
    cost: float = math.inf
    checked: int = 0  # candidates whose poses went to the check
    poses_checked: int = 0
    total: int = 0  # candidates ranked
    failures: list[Failure] = field(default_factory=list)
    reasons: dict[str, int] = field(default_factory=dict)  # failures by (part, verdict): "section unknown"...
    look_at: tuple[float, float] | None = None
    # what the look is for: "unseen" (no frame bounded the ground) or "ray" (a limit judged on
    # ground only a ray bounds, which a frame from here shows)
    look_for: str = ""
    turn: float = 0.0  # deg: the section's turn on the spot (counter-clockwise), before its arc
    curvature: float = 0.0  # 1/m: the section's arc (counter-clockwise positive)
    length: float = 0.0  # m: the arc driven (the section's, or to its pose nearest the goal)
    # driven backwards: "track" the rover's own last arc reversed, "arc" a reverse arc (.retreat)
    backward: str = ""


def _to_world(local: np.ndarray, pose: tuple[float, float, float]) -> np.ndarray:
    x, y, h = pose
    c, s = math.cos(math.radians(h)), math.sin(math.radians(h))
    out = np.empty_like(local)
    out[:, 0] = x + c * local[:, 0] - s * local[:, 1]
    out[:, 1] = y + s * local[:, 0] + c * local[:, 1]
    out[:, 2] = (local[:, 2] + h + 180.0) % 360.0 - 180.0
    return out


def _terrain(tree: ArcTree, pose: tuple[float, float, float], heights: np.ndarray | tuple[np.ndarray, np.ndarray],
             geom: GridGeometry, body: VehicleBody, params: CandidateParams
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per node: the terrain cost (m) from the mean surface's relief under the wheels and the
    body's middle, and the metres of it over unseen ground (a pose whose body's inscribed disc
    reaches an unseen cell, or off the map), both read at the tree's probes; and the probes' poses in
    the world."""
    mean, unseen = _mean(heights)
    with np.errstate(invalid="ignore"):
        filled = np.where(unseen | np.isnan(mean), 0.0, mean)
    # a wheel-sized window (15 cm): the relief a wheel meets there, over what it climbs
    relief = ndimage.maximum_filter(filled, 3) - ndimage.minimum_filter(filled, 3)
    rough = np.minimum(relief / body.climb, 2.0)
    rough[ndimage.maximum_filter(unseen, 3)] = 0.0  # unseen ground is the unknown cost's, not a relief
    inscribed = min(body.length / 2, body.width / 2 + body.wheel_width)
    near_unseen = (ndimage.distance_transform_edt(~unseen) * geom.cell < inscribed) if unseen.any() else unseen
    world = _to_world(np.asarray(tree.poses[tree.probe]), pose)
    pts = np.vstack([np.asarray(body.wheels, float), [(0.0, 0.0)]])  # (5, 2): the hubs and the middle
    c, s = np.cos(np.radians(world[:, 2]))[:, None], np.sin(np.radians(world[:, 2]))[:, None]
    col = np.floor((world[:, 0:1] + c * pts[:, 0] - s * pts[:, 1] - geom.xmin) / geom.cell).astype(np.int64)
    row = np.floor((geom.ymax - (world[:, 1:2] + s * pts[:, 0] + c * pts[:, 1])) / geom.cell).astype(np.int64)
    ok = (row >= 0) & (row < geom.height) & (col >= 0) & (col < geom.width)
    per_pose = np.where(ok, rough[np.clip(row, 0, geom.height - 1), np.clip(col, 0, geom.width - 1)], 0.0).mean(axis=1)
    centre_ok = ok[:, -1]
    blind = ~centre_ok | near_unseen[np.clip(row[:, -1], 0, geom.height - 1), np.clip(col[:, -1], 0, geom.width - 1)]
    n = len(tree.part)
    terrain = np.bincount(tree.probe_node, per_pose * tree.probe_ds, n) * params.terrain_cost
    unknown = np.bincount(tree.probe_node, blind * tree.probe_ds, n)
    return terrain, unknown, world


def choose(pose: tuple[float, float, float], heights: np.ndarray | tuple[np.ndarray, np.ndarray],
           geom: GridGeometry, body: VehicleBody, ctg: CostToGo, check: Check,
           params: CandidateParams | None = None, lookahead: Check | None = None,
           penalty: Callable[[np.ndarray], np.ndarray] | None = None,
           rays: Callable[[np.ndarray], np.ndarray] | None = None) -> Choice:
    """The section to drive next from ``pose`` (x, y, heading deg) toward ``ctg``'s goal: the
    candidates of :func:`arc_tree` ranked on the map ``heights`` (one grid or a ``(lower,
    upper)`` pair over ``geom``: its mean surface for the terrain cost, its unseen cells for the
    unknown cost), checked lazily in rank order with ``check`` (see the module's docstring).
    ``lookahead``: the check of the look-aheads beyond the sections, where it differs (a cheaper
    one: a look-ahead only ranks, and is judged again with ``check`` before it is driven).
    ``penalty``: a further cost per metre at points (N, 2) of the world, paid by every path over
    them (a dead end's ground: the cost to go at a path's end does not see what the path crossed).
    ``rays``: per pose, the middle of the ground only a ray bounds under the body there (NaN:
    none; :func:`over_rays`): a candidate refused on a limit there is a reason to look at it, as
    one over unseen ground is, at the price of ``ray_look_cost``."""
    params = params or CandidateParams()
    tree = arc_tree(params, body)
    terrain, unknown, probes = _terrain(tree, pose, heights, geom, body, params)
    t_i, s_i, b_i = tree.paths.T
    ends = _to_world(np.asarray(tree.poses[tree.start[b_i + 1] - 1]), pose)
    togo = ctg.at(ends[:, 0], ends[:, 1])
    section_unseen = (unknown[t_i] + unknown[s_i]) > 0
    keys = (tree.base + terrain[t_i] + terrain[s_i] + terrain[b_i] + params.unknown_cost * unknown[b_i]
            + params.look_cost * section_unseen + togo)
    paid = _paid(tree, probes, penalty)
    keys = keys + paid[t_i] + paid[s_i] + paid[b_i]
    keys = np.minimum(keys, _to_goal(tree, probes, ctg.goal, terrain, params))
    order = np.argsort(keys, kind="stable")
    order = order[np.isfinite(keys[order])]
    if not len(order):
        return _none("blocked", "the goal has no way to it over the ground the map shows", len(keys))
    v = _Verdicts(tree, pose, check, lookahead, body, params.verify_step)

    failures: list[Failure] = []
    look: tuple[float, Failure, tuple[float, float]] | None = None  # its cost, its failure, where to look
    priced: list[tuple[float, int, int]] = []  # heap of (key with its look-ahead's price, rank, candidate)
    checked = 0

    def settle(bound: float) -> Choice | None:
        """The look or the priced candidate, whichever is cheaper, if it costs less than ``bound``
        (inf: the candidates are spent); else None."""
        while priced and priced[0][0] < bound and (not v.way_on(int(tree.paths[priced[0][2]][1]))
                                                    or v.fine_failure(priced[0][1], priced[0][2]) is not None):
            heapq.heappop(priced)  # a pocket (no continuation from its section's end passes), or it fails between poses
        best = priced[0] if priced else None
        if look is not None and look[0] < bound and (best is None or look[0] <= best[0]):
            return _look(look[1], look[2], checked, v.poses_checked, len(order), failures)
        if best is not None and best[0] < bound:
            choice = _drive(tree, v.world, pose, best[2], best[1], best[0], ctg.goal, params, checked,
                            v.poses_checked, len(order), failures)
            choice.reason += "; its look-ahead is over a limit, priced"
            return choice
        return None

    size = params.batch
    i = 0
    while i < len(order):
        if (done := settle(float(np.nextafter(keys[order[i]], np.inf)))) is not None:
            return done  # nothing left can rank before it
        if params.max_poses and v.poses_checked >= params.max_poses:
            if (done := settle(math.inf)) is not None and done.status == "drive":
                return done
            choice = _none("blocked", f"no candidate passes among the best {checked} of {len(order)}: the check's "
                                      f"budget of {params.max_poses} poses is spent", len(order))
            choice.checked, choice.poses_checked, choice.failures = checked, v.poses_checked, failures
            choice.reasons = _reasons(failures)
            return choice
        group = order[i:i + size]
        if i == 0:
            # the first batch whole in one call: on open ground its sections pass, and a call of
            # the check has a fixed cost of the order of a hundred poses
            v.judge([n for c in group for n in tree.paths[c]])
        # the turns and sections first (a section after a turn already refused is not sent), then
        # the look-aheads of the sections that pass: a refused prefix spares what hangs from it
        v.judge([n for c in group for n in tree.paths[c][:2]
                 if not (n == tree.paths[c][1] and tree.paths[c][0] in v.codes
                         and v.first_bad(tree.paths[c][0], False) is not None)])
        sections_ok = [c for c in group if v.first_bad(tree.paths[c][0], False) is None
                       and tree.paths[c][1] in v.codes and v.first_bad(tree.paths[c][1], False) is None]
        v.judge([tree.paths[c][2] for c in sections_ok])
        checked += len(group)
        for rank, c in enumerate(group, start=i):
            fail = v.failure(rank, int(c))
            if fail is None:
                if (done := settle(float(keys[c]))) is not None:
                    return done
                return _drive(tree, v.world, pose, int(c), rank, float(keys[c]), ctg.goal, params, checked,
                              v.poses_checked, len(order), failures)
            failures.append(fail)
            if fail.part == "beyond" and params.ahead_cost > 0:
                b = int(tree.paths[c][2])
                m = int(tree.start[b + 1] - tree.start[b])
                lost = float(tree.length[b]) * (m - fail.index) / m  # the look-ahead's metres from its failing pose
                if float(tree.length[b]) - lost >= params.ahead_min:
                    # a continuation that fails only ranks the section down by the look-ahead it loses
                    heapq.heappush(priced, (float(keys[c]) + params.ahead_cost * lost, rank, int(c)))
            elif fail.verdict == "unknown" and fail.part != "beyond":
                cost = float(keys[c]) + (0.0 if section_unseen[c] else params.look_cost)
                if look is None or cost < look[0]:
                    look = (cost, fail, (fail.x, fail.y))
            elif rays is not None and fail.verdict != "unknown":
                cost = float(keys[c]) + params.ray_look_cost
                if look is None or cost < look[0]:
                    at = rays(np.array([[fail.x, fail.y, fail.heading]]))[0]
                    if np.isfinite(at).all():
                        look = (cost, fail, (float(at[0]), float(at[1])))
        i += len(group)
        size = min(size * 2, 64)
    if (done := settle(math.inf)) is not None:
        return done
    choice = _none("blocked", f"all {len(order)} candidates fail on the body's limits over ground the map shows",
                   len(order))
    choice.checked, choice.poses_checked, choice.failures = checked, v.poses_checked, failures
    choice.reasons = _reasons(failures)
    return choice


class _Verdicts:
    """The check's verdicts on the tree's nodes from one pose, each node judged once, on demand."""

    def __init__(self, tree: ArcTree, pose: tuple[float, float, float], check: Check, lookahead: Check | None,
                 body: VehicleBody, verify: float = 0.0) -> None:
        self.tree, self.pose, self.check, self.lookahead = tree, pose, check, lookahead
        self.body, self.verify = body, verify
        self.codes: dict[int, np.ndarray] = {}
        self.poses_checked = 0
        self._world: dict[int, np.ndarray] = {}
        self._bad: dict[tuple[int, bool], tuple[int, int] | None] = {}
        self._fine: dict[int, tuple[int, np.ndarray] | None] = {}

    def world(self, k: int) -> np.ndarray:
        """Node ``k``'s poses in the world."""
        if k not in self._world:
            self._world[k] = _to_world(np.asarray(self.tree.node(k)), self.pose)
        return self._world[k]

    def judge(self, nodes: list[int]) -> None:
        """Send the poses of ``nodes`` not yet judged to the check, the look-aheads to theirs."""
        tree = self.tree
        todo = [k for k in dict.fromkeys(nodes) if k not in self.codes and tree.start[k + 1] > tree.start[k]]
        for k in dict.fromkeys(nodes):
            if tree.start[k + 1] == tree.start[k]:
                self.codes[k] = np.zeros(0, int)
        ahead = [k for k in todo if tree.part[k] == 2] if self.lookahead is not None else []
        for group, fn in ((ahead, self.lookahead), ([k for k in todo if k not in set(ahead)], self.check)):
            if not group or fn is None:
                continue
            batch = np.concatenate([self.world(k) for k in group])
            if getattr(fn, "by_runs", False):
                # a turn or section is read to its first failing pose (:meth:`first_bad`), so each
                # is a run; a look-ahead's unknown poses do not fail it, so each of its poses is one
                sizes = [int(tree.start[k + 1] - tree.start[k]) for k in group]
                at = np.cumsum([0] + sizes[:-1])
                runs = np.concatenate([[a] if tree.part[k] != 2 else a + np.arange(m)
                                       for k, a, m in zip(group, at, sizes, strict=True)]).astype(np.int64)
                codes = np.asarray(fn(batch, runs), int)
            else:
                codes = np.asarray(fn(batch), int)
            self.poses_checked += len(batch)
            at = 0
            for k in group:
                m = tree.start[k + 1] - tree.start[k]
                self.codes[k] = codes[at:at + m]
                at += m

    def first_bad(self, k: int, allow_unknown: bool) -> tuple[int, int] | None:
        """The first pose of node ``k`` that fails it (its verdict and index), or None."""
        key = (int(k), allow_unknown)
        if key not in self._bad:
            codes = self.codes[int(k)]
            bad = np.flatnonzero((codes > 0) if allow_unknown else (codes != SAFE))
            self._bad[key] = (int(codes[bad[0]]), int(bad[0])) if len(bad) else None
        return self._bad[key]

    def fine_bad(self, k: int) -> tuple[int, np.ndarray] | None:
        """The first pose between turn or section ``k``'s poses, ``verify`` apart at the body's
        farthest point, that fails (its verdict and pose), or None. The tree's poses are
        ``CandidateParams.step`` apart, and between two of them a turn sweeps the box's edge over
        ground no judged pose put it on; judged once per node, for a candidate about to be chosen."""
        if k not in self._fine:
            poses = self.world(k)
            self._fine[k] = None
            if len(poses) and self.verify > 0:
                p = int(self.tree.parent[k])
                before = self.world(p)[-1] if p >= 0 and len(self.world(p)) else np.asarray(self.pose, float)
                dense = densify(np.vstack([before, poses]), self.verify, self.body)
                judged = {tuple(q) for q in np.round(np.vstack([before, poses]), 9)}
                dense = dense[[tuple(q) not in judged for q in np.round(dense, 9)]]  # the poses between only
                if not len(dense):
                    return None
                codes = np.asarray(self.check(dense, np.zeros(1, np.int64)) if getattr(self.check, "by_runs", False)
                                   else self.check(dense), int)
                self.poses_checked += len(dense)
                bad = np.flatnonzero(codes != SAFE)
                if len(bad):
                    self._fine[k] = (int(codes[bad[0]]), dense[bad[0]])
        return self._fine[k]

    def way_on(self, s: int) -> bool:
        """Whether any look-ahead from section ``s``'s end passes (unseen ground does not fail it)."""
        ahead = [int(k) for k in np.flatnonzero(self.tree.parent == s)]
        self.judge(ahead)
        return any(self.first_bad(k, True) is None for k in ahead)

    def failure(self, rank: int, c: int) -> Failure | None:
        """Where candidate ``c`` first fails (unseen ground beyond its section does not), or None."""
        for part, k in enumerate(self.tree.paths[c]):
            bad = self.first_bad(int(k), part == 2)
            if bad is not None:
                p = self.world(int(k))[bad[1]]
                return Failure(rank, c, _PARTS[part], verdict_name(bad[0]), float(p[0]), float(p[1]), bad[1],
                               float(p[2]))
        return self.fine_failure(rank, c)

    def fine_failure(self, rank: int, c: int) -> Failure | None:
        """Where candidate ``c``'s turn or section first fails between its poses (:meth:`fine_bad`)."""
        for part, k in enumerate(self.tree.paths[c][:2]):
            fine = self.fine_bad(int(k))
            if fine is not None:
                code, p = fine
                return Failure(rank, c, _PARTS[part], verdict_name(code), float(p[0]), float(p[1]),
                               heading=float(p[2]))
        return None


def _paid(tree: ArcTree, probes: np.ndarray, penalty: Callable[[np.ndarray], np.ndarray] | None) -> np.ndarray:
    """Per node, the ``penalty`` (per metre at the probes' points) over the metres it stands for."""
    if penalty is None:
        return np.zeros(len(tree.part))
    return np.bincount(tree.probe_node, np.asarray(penalty(probes[:, :2]), float) * tree.probe_ds, len(tree.part))


def _to_goal(tree: ArcTree, probes: np.ndarray, goal: tuple[float, float], terrain: np.ndarray,
             params: CandidateParams) -> np.ndarray:
    """Per candidate, its cost if it passes the goal (within the tolerance, read at its probes):
    the turn's and the terrain's costs and the metres driven to the goal, the cost to go then 0;
    inf for a candidate that does not pass it. Without this a path ending past a near goal loses
    to one that loops round to end on it."""
    out = np.full(len(tree.paths), np.inf)
    near = np.hypot(probes[:, 0] - goal[0], probes[:, 1] - goal[1]) <= params.goal_tolerance + PROBE / 2
    if not near.any():
        return out
    first = np.full(len(tree.part), np.inf)
    np.minimum.at(first, tree.probe_node[near], tree.probe_s[near])
    t, s, b = tree.paths.T
    turn = tree.base - tree.length[s] - tree.length[b]  # the turn's and the arcs' curvature costs
    via_section = turn + first[s] + terrain[t] + terrain[s]
    via_beyond = turn + tree.length[s] + first[b] + terrain[t] + terrain[s] + terrain[b]
    return np.where(np.isfinite(first[s]), via_section, via_beyond)


def _reasons(failures: list[Failure]) -> dict[str, int]:
    out: dict[str, int] = {}
    for f in failures:
        key = f"{f.part} {f.verdict}"
        out[key] = out.get(key, 0) + 1
    return out


def _none(status: str, reason: str, total: int) -> Choice:
    return Choice(status, reason, np.zeros((0, 3)), np.zeros((0, 3)), total=total)


def _look(fail: Failure, at: tuple[float, float], checked: int, poses_checked: int, total: int,
          failures: list[Failure]) -> Choice:
    kind = "unseen" if fail.verdict == "unknown" else "ray"
    ground = LOOK_GROUND[kind] + ("" if kind == "unseen" else f" ({fail.verdict})")
    return Choice("look", f"the best way runs over {ground} at ({at[0]:.2f}, {at[1]:.2f}): look there",
                  np.zeros((0, 3)), np.zeros((0, 3)), checked=checked, poses_checked=poses_checked, total=total,
                  failures=failures, reasons=_reasons(failures), look_at=at,
                  look_for=kind)


def _drive(tree: ArcTree, node_world: Callable[[int], np.ndarray], pose: tuple[float, float, float], c: int, rank: int, cost: float,
           goal: tuple[float, float], params: CandidateParams, checked: int, poses_checked: int, total: int,
           failures: list[Failure]) -> Choice:
    t, s, b = tree.paths[c]
    start = np.array([pose], float)
    section = np.vstack([start, node_world(int(t)), node_world(int(s))])
    path = np.vstack([section, node_world(int(b))])
    near = np.hypot(section[:, 0] - goal[0], section[:, 1] - goal[1])
    n_turn = len(node_world(int(t)))
    at_goal = np.flatnonzero(near[1 + n_turn:] <= params.goal_tolerance + PROBE / 2)  # as :func:`_to_goal` reads it
    if len(at_goal):  # stop where the section comes closest to the goal
        j = 1 + n_turn + at_goal[0]
        j += int(np.argmin(near[j:])) if j < len(near) else 0
        section = section[:j + 1]
    arc = section[n_turn:]  # from the pose after the turn
    length = float(np.hypot(*np.diff(arc[:, :2], axis=0).T).sum()) if len(arc) > 1 else 0.0
    local = np.vstack([tree.node(int(t))[-1:] if n_turn else np.zeros((1, 3)), tree.node(int(s))])
    bend = math.radians((float(local[-1, 2]) - float(local[0, 2]) + 180.0) % 360.0 - 180.0)
    return Choice("drive", f"candidate {c} (rank {rank} of {total}) passes", section, path, c, rank, cost,
                  checked, poses_checked, total, failures, _reasons(failures),
                  turn=float(local[0, 2]), curvature=bend / tree.length[int(s)] if tree.length[int(s)] else 0.0,
                  length=length)
