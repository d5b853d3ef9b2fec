"""The simulator's true surface of a scene: its hazard maps at 5 cm, the missions drawn on them,
the 1 cm surface, and the maps a perfect sensor would make of it."""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from drivers.sim.world import World
from prox_workflows.algorithms.dem2hazard import HazardParams, dem2hazard
from prox_workflows.algorithms.vehicle import check_poses, densify, unsafe_events
from prox_workflows.grid import GridGeometry
from rvs_params.hazard import HAZARDOUS, SAFE, UNDEFINED

# m: each scene's area (xmin, ymin, xmax, ymax) in the world frame for the 15-20 m missions
# (:func:`missions`) and for the 3.5-5 m ones (:func:`pick_start_goal`)
NEAR_AREA = {"office": (-2.5, -3.0, 5.5, 3.0), "quarry": (-3.0, -4.0, 7.0, 4.0), "marsyard": (-4.0, -6.0, 8.0, 6.0)}
AREA = {"marsyard": (-5.5, -9.5, 13.5, 9.5), "hirise": (-14.0, -14.0, 14.0, 14.0), "dense": (-14.0, -14.0, 14.0, 14.0)}


def true_maps(world: World, bounds: tuple[float, float, float, float]) -> tuple[dict[str, np.ndarray],
                                                                               GridGeometry]:
    """The simulator's true DEM through Dem2Hazard at 5 cm: all its layers."""
    g = GridGeometry.covering(*bounds, 0.05)
    dem = world.true_dem(g.cell, g.bounds, include_target=False)
    return dem2hazard(dem, g.cell, HazardParams()), g


def true_hazard(world: World, bounds: tuple[float, float, float, float]) -> tuple[np.ndarray, GridGeometry]:
    """The simulator's true hazard map at 5 cm."""
    out, g = true_maps(world, bounds)
    return out["hazard"], g


def missions(scene: str, count: int, seed: int = 0) -> list[tuple[tuple[float, float], tuple[float, float]]]:
    """``count`` seeded (start, goal) pairs 15-20 m apart, both >= 1 m from every true hazard,
    each start one the rover can be set down on and turn on the spot at (:func:`set_down_safe`).

    The hazard map's 15 cm step limit is above the body's own limits, so a start 1 m from its
    hazards can still put a wheel on a step or the belly on a rock; a loop that takes the ground
    it is set down on as clear (as navigate does) would then be blamed for the start."""
    world = World.from_scene(scene)
    hazard, g = true_hazard(world, AREA[scene])
    clear = (ndimage.distance_transform_edt(hazard != HAZARDOUS) * g.cell >= 1.0) & (hazard == SAFE)
    rows, cols = np.nonzero(clear)
    xs, ys = g.centers()
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < count:
        i, j = rng.integers(len(rows), size=2)
        s = (round(float(xs[cols[i]]), 2), round(float(ys[rows[i]]), 2))
        e = (round(float(xs[cols[j]]), 2), round(float(ys[rows[j]]), 2))
        if 15.0 <= math.hypot(e[0] - s[0], e[1] - s[1]) <= 20.0 and set_down_safe(world, scene, s):
            out.append((s, e))
    return out


def set_down_safe(world: World, scene: str, xy: tuple[float, float]) -> bool:
    """Whether the rover set down at ``xy`` can stand there at every heading, turning on the spot
    (the first thing a mission does), within the body's four limits (step, belly, stability,
    grade) on the true 1 cm surface."""
    fine, g, _ = truth_surface(world, scene)
    turn = densify(np.array([(xy[0], xy[1], h) for h in (0.0, 90.0, 180.0, 270.0, 360.0)]), 0.02, world.body)
    return not unsafe_events(check_poses(fine, g, turn, world.body), turn, world.body)


def pick_start_goal(world: World, scene: str, seed: int) -> tuple[tuple[float, float], tuple[float, float]]:
    """A start and a goal 3.5-5 m apart in ``NEAR_AREA[scene]``, both at least 1 m from any true
    hazard."""
    hazard, g = true_hazard(world, NEAR_AREA[scene])
    clear = ndimage.distance_transform_edt(hazard != HAZARDOUS) * g.cell >= 1.0
    clear &= hazard == SAFE
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


# The maps a perfect sensor could make of the true surface, for the ceiling: the step each reads
# over Dem2Hazard's window, from the 1 cm surface averaged over this many centimetres (0: 5 cm cell
# means, what the rolling map's cells are: means of the points in them).
CEILING_MAPS = {"cell_mean": 0, "mean_3cm": 3, "surface_1cm": 1}


def fine_surface(world: World, bounds: tuple[float, float, float, float]) -> tuple[np.ndarray, GridGeometry]:
    """The true surface sampled every centimetre over the 5 cm grid of ``bounds`` (each 5 cm
    cell's centre is its sample (2, 2)), and that grid."""
    g = GridGeometry.covering(*bounds, 0.05)
    return world.true_dem(0.01, g.bounds, include_target=False).astype(np.float32), g


def ceiling_layers(fine: np.ndarray, g: GridGeometry, box: int) -> dict[str, np.ndarray]:
    """Slope, roughness and step at 5 cm as a perfect sensor would map them (:data:`CEILING_MAPS`):
    Dem2Hazard's of the 5 cm cell means, whose step is, with ``box`` > 0, replaced by the greatest
    minus the least height within the same window (each cell's centre +- 15 cm) of the 1 cm
    surface averaged over ``box`` centimetres. That step is never below the true map's (which
    takes the same window's 5 cm centre samples) when ``box`` is 1. None depends on the limits."""
    import cv2

    params = HazardParams()
    mean = fine.reshape(g.height, 5, g.width, 5).mean(axis=(1, 3)).astype(np.float32)
    out = dem2hazard(mean, g.cell, params)
    layers = {"slope": out["slope"], "roughness": out["roughness"], "step": out["step"], "valid": out["hazard"] != UNDEFINED}
    if box > 0:
        half = params.window_cells(g.cell) // 2 * 5
        kernel = np.ones((2 * half + 1, 2 * half + 1), np.uint8)
        surface = cv2.blur(fine, (box, box), borderType=cv2.BORDER_REPLICATE) if box > 1 else fine
        layers["step"] = (cv2.dilate(surface, kernel, borderType=cv2.BORDER_REPLICATE)
                          - cv2.erode(surface, kernel, borderType=cv2.BORDER_REPLICATE))[2::5, 2::5]
    return layers


_TRUTH: dict[str, tuple[np.ndarray, GridGeometry, GridGeometry]] = {}


def truth_surface(world: World, scene: str) -> tuple[np.ndarray, GridGeometry, GridGeometry]:
    """The scene's true 1 cm surface over its mission area, its grid, and the 5 cm grid it
    refines (computed once per process and scene)."""
    if scene not in _TRUTH:
        _TRUTH[scene] = surface_over(world, AREA[scene])
    return _TRUTH[scene]


def surface_over(world: World, bounds: tuple[float, float, float, float]
                 ) -> tuple[np.ndarray, GridGeometry, GridGeometry]:
    """The true 1 cm surface over ``bounds`` as the world is now (a rock added at run time
    included), its grid and the 5 cm grid it refines: what the vehicle check reads."""
    fine, g = fine_surface(world, bounds)
    return fine, GridGeometry(0.01, g.xmin, g.ymax, g.width * 5, g.height * 5), g
