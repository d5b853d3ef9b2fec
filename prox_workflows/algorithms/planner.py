"""The path planner (seed 000 sect. 3.1.7, 4.4.1-4.4.3): merge the global and local maps into one
planning image, expand the hazards by the rover's size, and find the path with A*.

The maps and their merging are in :mod:`.plan_maps`, the search in :mod:`.astar`, the
parameters in :mod:`.plan_params`, the drawings in :mod:`.plan_drawing` (the products are written by
:mod:`prox_workflows.steps.write`); the names callers use are importable from here too.

Cost model (A* G)
    A step between 8-connected neighbours u -> v of length L (``grid`` or ``grid * sqrt(2)``
    metres) costs ``L * (w + (1 - w) * (c_u + c_v) / 2)``: G = w * distance + (1 - w) * the
    environmental cost integrated along the path (trapezoid rule), both in metres, so
    w = 1 is distance only, w = 0.5 weighs them equally (seed 000 used 0.4 and 0.7). The
    per-cell factor ``k = w + (1 - w) * c`` is the cost per metre. A diagonal step is refused
    when either of the two orthogonal cells it passes between is blocked (no corner cutting).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rvs_params.deferred import deferred
from rvs_params.hazard import HAZARDOUS

from .astar import SQRT2, PlanningError, Search, astar_grid, warm_up
from .plan_drawing import ortho_figure
from .plan_maps import NavMaps, PlanningImage, blank_geometry, check_plan_size, planning_image
from .plan_params import PlannerParams, PlanParams

ndimage = deferred("scipy.ndimage")

# what callers plan with, wherever it is declared
__all__ = [
    "MIN_LEG", "NavMaps", "PlanParams", "PlanResult", "PlannerParams", "PlanningError", "astar_grid", "blank_geometry",
    "check_plan_size", "nearest_reachable", "ortho_figure", "plan_path", "planning_image", "warm_up",
]

MIN_LEG = 0.05  # m: a leg shorter than this makes no progress (navigate says E_DATA)


@dataclass
class PlanResult:
    """A plan in world coordinates: the whole A* path, where it is cut, and the waypoints."""

    image: PlanningImage
    params: PlannerParams
    start: tuple[float, float]
    goal: tuple[float, float]
    path: np.ndarray  # (n, 2) x, y: the A* path, exact start and goal at its ends
    path_cells: np.ndarray  # (n, 2) row, col on the planning grid
    cost_so_far: np.ndarray  # (n,)
    cut: int  # the rover drives path[:cut]
    waypoints: Any  # waypoints.Waypoints
    expanded: int
    warnings: list[str] = field(default_factory=list)

    @property
    def cost(self) -> float:
        """The cost of the whole A* path to the goal (metres, weighted)."""
        return float(self.cost_so_far[-1])

    @property
    def reaches_goal(self) -> bool:
        """Whether the driven part ends at the goal (not cut at the local map's border)."""
        return self.cut == len(self.path)

    def stands_still(self, least: float = MIN_LEG) -> bool:
        """Whether driving it gets the rover nowhere: fewer than two waypoints, or the driven
        part (``path[:cut]``) ends less than ``least`` metres from where it starts. navigate's
        loops end such a leg (the scan loop with E_DATA, the see loop with a look or a scan)."""
        driven = self.path[: self.cut]
        return len(self.waypoints) < 2 or math.hypot(*(driven[-1] - driven[0])) < least


def _relax_start(image: PlanningImage, cell: tuple[int, int]) -> float | None:
    """A start inside the hazard margin (not on a hazard) may leave it: unblock the cells near
    the start that are at least as far from every hazard as the start is. Returns that distance."""
    r, c = cell
    if not image.blocked[r, c] or image.hazard[r, c] == HAZARDOUS:
        return None
    d0 = float(image.hazard_distance[r, c])
    reach = int(math.ceil(image.clearance / image.geometry.cell)) + 1
    r0, r1 = max(0, r - reach), min(image.geometry.height, r + reach + 1)
    c0, c1 = max(0, c - reach), min(image.geometry.width, c + reach + 1)
    rr, cc = np.mgrid[r0:r1, c0:c1]
    near = (rr - r) ** 2 + (cc - c) ** 2 <= reach**2
    win = (slice(r0, r1), slice(c0, c1))
    free = near & image.blocked[win] & (image.hazard[win] != HAZARDOUS) & (image.hazard_distance[win] >= d0)
    image.blocked[win] &= ~free
    return d0


def plan_path(local: NavMaps, global_: NavMaps | None, start: Sequence[float], goal: Sequence[float],
              params: PlannerParams | None = None, start_heading: float | None = None,
              goal_heading: float | None = None, search: Search | None = None,
              cover: Sequence[Sequence[float]] = ()) -> PlanResult:
    """Plan from ``start`` to ``goal`` (world x, y): merge, expand, A*, cut at the local map's
    border, simplify into waypoints. Raises :class:`PlanningError` when there is no path.

    ``search`` replaces the A* on the cost grid (the see loop's D* Lite, which repairs the last
    search instead of starting again: the same graph and costs, so the same path cost); it gets
    the grid, the start and goal cells and the grid's geometry. ``cover``: points the planning
    grid must reach besides start and goal (a mission's box, so that the grid keeps its
    geometry from one replan to the next and the repair has something to repair)."""
    from .waypoints import make_waypoints, shortcut, simplify

    params = params or PlannerParams()
    start = (float(start[0]), float(start[1]))
    goal = (float(goal[0]), float(goal[1]))
    image = planning_image(local, global_, params, points=[start, goal, *cover])
    geom = image.geometry
    cells = {}
    for name, (x, y) in (("start", start), ("goal", goal)):
        r, c = geom.cell_of(np.array(x), np.array(y))
        if not geom.inside(r, c):
            raise PlanningError("outside_maps", f"{name} ({x:.3f}, {y:.3f}) is outside the maps, which cover "
                                                f"x {geom.xmin:.2f}..{geom.xmax:.2f}, y {geom.ymin:.2f}..{geom.ymax:.2f}")
        cells[name] = (int(r), int(c))
    notes: list[str] = []
    radius = params.rover_radius + params.margin
    gr, gc = cells["goal"]
    if image.hazard[gr, gc] == HAZARDOUS:
        raise PlanningError("goal_in_hazard", f"goal ({goal[0]:.3f}, {goal[1]:.3f}) is on a hazardous cell")
    if image.blocked[gr, gc] or not image.turnable[gr, gc]:  # the rover stops there: its body must fit
        raise PlanningError("goal_in_hazard", f"goal ({goal[0]:.3f}, {goal[1]:.3f}) is "
                                              f"{float(image.hazard_distance[gr, gc]):.2f} m from a hazardous "
                                              f"cell, closer than rover radius + margin ({radius:.2f} m) "
                                              f"+ half a cell diagonal")
    if not np.isfinite(image.env_cost[gr, gc]):
        raise PlanningError("goal_in_hazard", f"goal ({goal[0]:.3f}, {goal[1]:.3f}) is on unknown ground, "
                                              "which is not traversable (unknown_cost = inf)")
    sr, sc = cells["start"]
    if image.hazard[sr, sc] == HAZARDOUS:
        raise PlanningError("start_in_hazard", f"start ({start[0]:.3f}, {start[1]:.3f}) is on a hazardous cell")
    d0 = _relax_start(image, cells["start"])
    if d0 is not None:
        notes.append(f"start is {d0:.2f} m from a hazard, inside the {radius:.2f} m margin: near the start the "
                     f"margin is relaxed to {d0:.2f} m so the rover can move away")
    k = image.cost_per_metre(params.weight)
    if not np.isfinite(k[sr, sc]):
        raise PlanningError("start_in_hazard", f"start ({start[0]:.3f}, {start[1]:.3f}) is on unknown ground, "
                                               "which is not traversable (unknown_cost = inf)")
    try:
        if search is not None:
            gp = search(k, cells["start"], cells["goal"], geom)
        else:
            gp = astar_grid(k, cells["start"], cells["goal"], heuristic=params.heuristic, orth=geom.cell,
                            diag=geom.cell * SQRT2, share=0.5, corner_rule=True)
    except PlanningError as exc:
        if exc.reason != "enclosed":
            raise
        raise PlanningError("enclosed", _enclosed_message(np.isfinite(k), cells["start"], cells["goal"],
                                                          geom.cell)) from None
    xs, ys = geom.centers()
    path = np.stack([xs[gp.cells[:, 1]], ys[gp.cells[:, 0]]], axis=1)
    path[0] = start
    path[-1] = goal
    cut, border = _adaptive_cut(path, image.border_distance[gp.cells[:, 0], gp.cells[:, 1]], params.border,
                                geom.cell)
    if border < params.border:
        notes.append(f"border relaxed from {params.border:g} m to {border:g} m: the seen ground is too narrow "
                     "to stop that far inside it")
    if cut < len(path):
        notes.append(f"path cut at the local map's border: the rover drives {cut} of {len(path)} points")
    turnable = image.turnable[gp.cells[:, 0], gp.cells[:, 1]]
    if cut < len(path):  # the rover stops at the cut and turns there next leg: where its body fits
        back = np.flatnonzero(turnable[1:cut])
        if back.size:
            cut = int(back[-1]) + 2
    if cut <= 1 and len(path) > 1:
        notes.append("the path does not enter locally seen ground: no move")
    driven = path[:max(cut, 1)]
    keep = simplify(driven, params.max_deviation, blocked=~np.isfinite(k), geometry=geom,
                    turnable=turnable[:max(cut, 1)])
    keep = shortcut(driven, keep, k, gp.g, geom)
    wps = make_waypoints(driven[keep], start_heading=start_heading,
                         goal_heading=goal_heading if cut == len(path) else None)
    return PlanResult(image=image, params=params, start=start, goal=goal, path=path, path_cells=gp.cells,
                      cost_so_far=gp.g, cut=max(cut, 1), waypoints=wps, expanded=gp.expanded, warnings=notes)


def nearest_reachable(local: NavMaps, global_: NavMaps | None, start: Sequence[float], goal: Sequence[float],
                      params: PlannerParams | None = None) -> tuple[float, float]:
    """The free cell reachable from ``start`` that is nearest ``goal`` (world x, y): where to
    drive when the goal itself is judged unreachable from far, to judge it again from closer.

    Reachable as :func:`plan_path` sees it: the same planning image, the same relaxed start, and
    8-connected free cells (a diagonal between two blocked cells may make a cell look reachable
    that A* will not reach; plan_path to it then fails as enclosed, which is the honest answer).
    Raises :class:`PlanningError` (``start_in_hazard``, ``outside_maps``) as plan_path does."""
    params = params or PlannerParams()
    start = (float(start[0]), float(start[1]))
    goal = (float(goal[0]), float(goal[1]))
    image = planning_image(local, global_, params, points=[start, goal])
    geom = image.geometry
    r, c = geom.cell_of(np.array(start[0]), np.array(start[1]))
    if not geom.inside(r, c):
        raise PlanningError("outside_maps", f"start ({start[0]:.3f}, {start[1]:.3f}) is outside the maps")
    cell = (int(r), int(c))
    if image.hazard[cell] == HAZARDOUS:
        raise PlanningError("start_in_hazard", f"start ({start[0]:.3f}, {start[1]:.3f}) is on a hazardous cell")
    _relax_start(image, cell)
    free = np.isfinite(image.cost_per_metre(params.weight))
    if not free[cell]:
        raise PlanningError("start_in_hazard", f"start ({start[0]:.3f}, {start[1]:.3f}) is on unknown ground, "
                                               "which is not traversable (unknown_cost = inf)")
    labels, _ = ndimage.label(free, structure=np.ones((3, 3), bool))
    region = labels == labels[cell]
    stop = region & image.turnable  # where the rover's body fits when it stops
    rows, cols = np.nonzero(stop if stop.any() else region)
    xs, ys = geom.centers()
    d = np.hypot(xs[cols] - goal[0], ys[rows] - goal[1])
    i = int(np.argmin(d))
    return float(xs[cols[i]]), float(ys[rows[i]])


def _adaptive_cut(path: np.ndarray, border_distance: np.ndarray, border: float, cell: float) -> tuple[int, float]:
    """Cut the path ``border`` inside the seen ground, halving the border where that leaves the
    rover nothing to drive (a scan from a corner sees a narrow strip, seed 000's ~1 m border
    would stop every leg at its start); returns the cut and the border used."""
    from .waypoints import cut_at_border

    while True:
        cut = cut_at_border(border_distance, border)
        moved = float(np.hypot(*(path[max(cut, 1) - 1] - path[0])))
        if moved >= MIN_LEG or border <= 0.0:
            return cut, border
        border = border / 2 if border / 2 >= 2 * cell else 0.0


def _enclosed_message(free: np.ndarray, start: tuple[int, int], goal: tuple[int, int], cell: float) -> str:
    labels, _ = ndimage.label(free, structure=np.ones((3, 3), bool))
    ls, lg = labels[start], labels[goal]
    size_s = int((labels == ls).sum())
    size_g = int((labels == lg).sum())
    area = cell * cell
    if ls == lg:
        return ("the goal is not reachable: start and goal are separated only by hazard corners the rover "
                "may not cut")
    which = "start" if size_s <= size_g else "goal"
    return (f"the goal is not reachable: the {which} is enclosed by hazards (the start's free region is "
            f"{size_s * area:.2f} m^2, the goal's {size_g * area:.2f} m^2)")
