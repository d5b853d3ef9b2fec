"""The chooser's coarse guidance over a whole mission, kept while its bounds map is a window.

The see loop's bounds map follows the rover (:meth:`.bounds_map.BoundsMap.around`): a 2.5 cm
map over a 200 m mission's box is 267 MB, and a choice that reads it all costs 6x a 20 m one.
The cost to go that ranks the candidates must still see the whole way to the goal: so the
mission's box is kept at the coarse grid's resolution only (25 cm: a 212 x 16 m strip is 54 k
cells, 0.4 MB), and each choice writes what the window now says of its coarse cells into it.
Cells the window left keep what it last said (a wall the rover turned away from stays a wall);
cells no window has seen cost :func:`.candidates.coarse_costs`' unknown cost, as an unseen cell
of the window does.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..grid import GridGeometry
from .candidates import UNKNOWN_COST, CostToGo, coarse_costs, cost_to_go

__all__ = ["CoarseMemory"]


class CoarseMemory:
    """The coarse cost grid (per metre; NaN: never seen) over a mission's box."""

    def __init__(self, geometry: GridGeometry) -> None:
        self.geometry = geometry
        self.cost = np.full(geometry.shape, np.nan)

    @classmethod
    def covering(cls, points: Any, pad: float, cell: float = 0.25) -> CoarseMemory:
        """The box of ``points`` (x, y) grown by ``pad`` metres, on multiples of ``cell`` from the
        frame's origin (where a window of :meth:`.bounds_map.BoundsMap.around` with that ``align``
        puts its coarse cells)."""
        xy = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        x0 = math.floor((xy[:, 0].min() - pad) / cell) * cell
        y1 = math.ceil((xy[:, 1].max() + pad) / cell) * cell
        w = math.ceil((xy[:, 0].max() + pad - x0) / cell - 1e-9)
        h = math.ceil((y1 - xy[:, 1].min() + pad) / cell - 1e-9)
        return cls(GridGeometry(cell, x0, y1, max(1, w), max(1, h)))

    def update(self, heights: tuple[np.ndarray, np.ndarray], geom: GridGeometry, body: Any, **costs: float) -> None:
        """What the window's bounds (``heights``: lower, upper over ``geom``, whose origin lies on
        this grid's) say of its coarse cells, written over what was kept where the window saw them."""
        cell = self.geometry.cell
        window, cg = coarse_costs(heights, geom, body, cell=cell, unknown_cost=np.nan, **costs)
        g = self.geometry
        c0, r0 = round((cg.xmin - g.xmin) / cell), round((g.ymax - cg.ymax) / cell)
        rows = slice(max(0, r0), min(g.height, r0 + cg.height))
        cols = slice(max(0, c0), min(g.width, c0 + cg.width))
        if rows.start >= rows.stop or cols.start >= cols.stop:
            return
        part = window[rows.start - r0:rows.stop - r0, cols.start - c0:cols.stop - c0]
        held = self.cost[rows, cols]
        self.cost[rows, cols] = np.where(np.isnan(part), held, part)

    def costs(self) -> tuple[np.ndarray, GridGeometry]:
        """The kept grid with never-seen cells at the unknown cost, as :func:`.candidates.coarse_costs`
        gives a map's."""
        return np.where(np.isnan(self.cost), UNKNOWN_COST, self.cost), self.geometry

    def cost_to_go(self, goal: tuple[float, float]) -> CostToGo:
        """The cost to go to ``goal`` over the kept grid."""
        return cost_to_go(*self.costs(), goal)
