"""The simulator's true surface of a scene: its hazard maps at 5 cm, the missions drawn on them,
the 1 cm surface, and the maps a perfect sensor would make of it."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy import ndimage

from drivers.sim.scene import load_scene_spec
from drivers.sim.world import World
from prox_workflows.algorithms.dem2hazard import HazardParams, dem2hazard
from prox_workflows.algorithms.vehicle import (
    PoseChecks,
    VehicleBody,
    check_poses,
    densify,
    reach,
    unsafe_events,
)
from prox_workflows.grid import GridGeometry
from rvs_params.hazard import HAZARDOUS, SAFE, UNDEFINED

# m: each scene's area (xmin, ymin, xmax, ymax) in the world frame for its missions
# (:func:`missions`) and for the 3.5-5 m ones (:func:`pick_start_goal`)
NEAR_AREA = {"office": (-2.5, -3.0, 5.5, 3.0), "quarry": (-3.0, -4.0, 7.0, 4.0), "marsyard": (-4.0, -6.0, 8.0, 6.0)}
AREA = {"marsyard": (-5.5, -9.5, 13.5, 9.5), "hirise": (-14.0, -14.0, 14.0, 14.0), "dense": (-14.0, -14.0, 14.0, 14.0),
        "marsyard_long": (-5.5, -7.5, 205.5, 7.5)}


def area(scene: str) -> tuple[float, float, float, float]:
    """The scene's mission area (:data:`AREA`); a scene that extends another (another draw of its
    rocks) has that scene's."""
    while scene not in AREA:
        base = load_scene_spec(scene).get("extends")
        if base is None:
            raise KeyError(f"scene {scene!r} has no mission area (rvs_truth.surface.AREA)")
        scene = base
    return AREA[scene]


# m: how far apart a scene's mission start and goal are (min, max); the others' 15-20 m
SPAN = {"marsyard_long": (199.0, 201.0)}
MISSION_SPAN = (15.0, 20.0)
# 1 cm cells of a mission area's true surface built whole (marsyard 3.6 M, hirise and dense 7.8 M:
# 0.5 GB at the peak of building one); a larger area (marsyard_long: 32 M, several GB) is judged
# in tiles built along the poses (:func:`truth_checks`)
WHOLE_TRUTH_CELLS = 16_000_000
TILE = 10.0  # m: the most a tile's poses spread along x or y (a straight 10 m: 1,000 x 100 cells)


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
    """``count`` seeded (start, goal) pairs the scene's :data:`SPAN` apart (15-20 m unless it
    declares one), both >= 1 m from every true hazard,
    each start one the rover can be set down on and turn on the spot at (:func:`set_down_safe`).

    The hazard map's 15 cm step limit is above the body's own limits, so a start 1 m from its
    hazards can still put a wheel on a step or the belly on a rock; a loop that takes the ground
    it is set down on as clear (as navigate does) would then be blamed for the start."""
    world = World.from_scene(scene)
    hazard, g = true_hazard(world, area(scene))
    clear = (ndimage.distance_transform_edt(hazard != HAZARDOUS) * g.cell >= 1.0) & (hazard == SAFE)
    rows, cols = np.nonzero(clear)
    xs, ys = g.centers()
    rng = np.random.default_rng(seed)
    low, high = SPAN.get(scene, MISSION_SPAN)
    out = []
    while len(out) < count:
        i, j = rng.integers(len(rows), size=2)
        s = (round(float(xs[cols[i]]), 2), round(float(ys[rows[i]]), 2))
        e = (round(float(xs[cols[j]]), 2), round(float(ys[rows[j]]), 2))
        if low <= math.hypot(e[0] - s[0], e[1] - s[1]) <= high and set_down_safe(world, scene, s):
            out.append((s, e))
    return out


def set_down_safe(world: World, scene: str, xy: tuple[float, float]) -> bool:
    """Whether the rover set down at ``xy`` can stand there at every heading, turning on the spot
    (the first thing a mission does), within the body's four limits (step, belly, stability,
    grade) on the true 1 cm surface."""
    turn = densify(np.array([(xy[0], xy[1], h) for h in (0.0, 90.0, 180.0, 270.0, 360.0)]), 0.02, world.body)
    return not unsafe_events(truth_checks(world, scene, turn, world.body), turn, world.body)


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
        _TRUTH[scene] = surface_over(world, area(scene))
    return _TRUTH[scene]


def whole_truth(scene: str) -> bool:
    """Whether the scene's true 1 cm surface over its mission area is built whole (else in tiles)."""
    x0, y0, x1, y1 = area(scene)
    return (x1 - x0) * (y1 - y0) * 1e4 <= WHOLE_TRUTH_CELLS


def truth_checks(world: World, scene: str, poses: np.ndarray, body: VehicleBody) -> PoseChecks:
    """The vehicle check of ``poses`` ((N, 3), in the order driven) on the true 1 cm surface under
    each body: the scene's whole surface (:func:`truth_surface`) for the poses whose body it
    covers when it is small enough (:func:`whole_truth`), else a tile per run of poses that
    spreads at most :data:`TILE` along x and y, built over that run's box grown by the body's
    reach (and a 5 cm cell). A rover may drive where its mission's area ends and the world goes
    on (hirise's area ends 1 m inside its terrain): read off the surface, that ground would be
    taken as a drop, a step of 10-14 cm at every wheel over the edge that the world does not
    have. A tile is on the same 1 cm lattice as the whole surface (both refine the 5 cm grid
    aligned to multiples of its cell), so a pose reads the same samples either way; memory stays
    that of one tile, whatever the distance driven."""
    poses = np.atleast_2d(np.asarray(poses, float)).reshape(-1, 3)
    grow = reach(body) + 0.05
    covered = np.zeros(len(poses), bool)
    if whole_truth(scene):
        x0, y0, x1, y1 = area(scene)
        covered = ((poses[:, 0] - grow >= x0) & (poses[:, 0] + grow <= x1)
                   & (poses[:, 1] - grow >= y0) & (poses[:, 1] + grow <= y1))
    parts = _tiled(world, poses, np.flatnonzero(~covered), body, grow)
    if covered.any():
        fine, g, _ = truth_surface(world, scene)
        at = np.flatnonzero(covered)
        parts.append((at, check_poses(fine, g, poses[at], body)))
    if not parts:  # no pose: an empty check of the right shapes
        return check_poses(np.zeros((1, 1), np.float32), GridGeometry(0.01, 0.0, 0.01, 1, 1), poses, body)
    out = {}
    for f in dataclasses.fields(PoseChecks):
        first = getattr(parts[0][1], f.name)
        a = np.empty((len(poses), *first.shape[1:]), first.dtype)
        for at, c in parts:
            a[at] = getattr(c, f.name)
        out[f.name] = a
    # Past the world's terrain the truth has no ground, where the simulated sensors' spread
    # returns still put some: read there it is a drop, a step of 10-14 cm at a wheel over the
    # edge that no rover could meet (dense_fresh 0, 0.9 m past its area's west edge). A pose
    # whose body reaches past it is not judged (``unknown``, its excesses NaN: never unsafe).
    x0, y0, x1, y1 = world.terrain.bounds
    r = reach(body) + 0.01  # and the 1 cm sample a bilinear read takes beside it
    off = ((poses[:, 0] - r < x0) | (poses[:, 0] + r > x1) | (poses[:, 1] - r < y0) | (poses[:, 1] + r > y1))
    out["unknown"] = out["unknown"] | off
    out["excess"][off] = np.nan
    return PoseChecks(**out)


def _tiled(world: World, poses: np.ndarray, which: np.ndarray, body: VehicleBody,
           grow: float) -> list[tuple[np.ndarray, PoseChecks]]:
    """:func:`truth_checks` of ``poses[which]`` on tiles built round runs of them (see there): per
    tile, the indices into ``poses`` it judged and its checks."""
    parts = []
    first = 0
    while first < len(which):
        lo = hi = poses[which[first], :2]
        end = first + 1
        while end < len(which):
            nlo, nhi = np.minimum(lo, poses[which[end], :2]), np.maximum(hi, poses[which[end], :2])
            if (nhi - nlo).max() > TILE:
                break
            lo, hi, end = nlo, nhi, end + 1
        fine, g, _ = surface_over(world, (lo[0] - grow, lo[1] - grow, hi[0] + grow, hi[1] + grow))
        at = which[first:end]
        parts.append((at, check_poses(fine, g, poses[at], body)))
        first = end
    return parts


def surface_over(world: World, bounds: tuple[float, float, float, float]
                 ) -> tuple[np.ndarray, GridGeometry, GridGeometry]:
    """The true 1 cm surface over ``bounds`` as the world is now (a rock added at run time
    included), its grid and the 5 cm grid it refines: what the vehicle check reads."""
    fine, g = fine_surface(world, bounds)
    return fine, GridGeometry(0.01, g.xmin, g.ymax, g.width * 5, g.height * 5), g
