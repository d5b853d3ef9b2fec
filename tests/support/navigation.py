"""The navigation tests' ground truth: the true hazard map of a simulated scene, and missions
drawn on it whose start and goal are both well clear of any true hazard."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from drivers.sim.world import World
from prox_workflows.algorithms.dem2hazard import HazardParams, dem2hazard
from prox_workflows.grid import GridGeometry

AREA = {"office": (-2.5, -3.0, 5.5, 3.0), "quarry": (-3.0, -4.0, 7.0, 4.0), "marsyard": (-4.0, -6.0, 8.0, 6.0)}


def true_hazard(world: World, bounds) -> tuple[np.ndarray, GridGeometry]:
    g = GridGeometry.covering(*bounds, 0.05)
    dem = world.true_dem(g.cell, g.bounds, include_target=False)
    return dem2hazard(dem, g.cell, HazardParams())["hazard"], g


def pick_start_goal(world: World, scene: str, seed: int) -> tuple[tuple[float, float], tuple[float, float]]:
    """A start and a goal 3.5-5 m apart, both at least 1 m from any true hazard."""
    hazard, g = true_hazard(world, AREA[scene])
    clear = ndimage.distance_transform_edt(hazard != 255) * g.cell >= 1.0
    clear &= hazard == 0
    rows, cols = np.nonzero(clear)
    xs, ys = g.centers()
    rng = np.random.default_rng(seed)
    for _ in range(1000):
        i, j = rng.integers(len(rows), size=2)
        s = (float(xs[cols[i]]), float(ys[rows[i]]))
        e = (float(xs[cols[j]]), float(ys[rows[j]]))
        if 3.5 <= np.hypot(e[0] - s[0], e[1] - s[1]) <= 5.0:
            return s, e
    raise AssertionError("no start/goal pair found")
