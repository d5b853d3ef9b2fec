"""What an orbiter saw of a simulated scene, and what the rover's own DEM looks like against it:
the scene's orbital DTM with navigate's global maps, the true DEM as a projected GeoTIFF, and a
360-degree patch placed with a known pose error, for the map matcher.

A scene with a ``dtm`` terrain primitive (``hirise``) is a real orbital DTM with rover-scale
detail (roughness, rocks) added on top; the orbiter saw only the DTM. :func:`write_global_maps`
writes that DTM at its own cell size (1.01 m for HiRISE) in the simulated world's frame (the frame
the server's poses are in: origin on the ground under the rover's start) with the slope and hazard
maps navigate's ``global_maps`` folder needs: ``dem.tif`` (heights, m), ``slope.tif`` (deg),
``hazard.tif`` (0 safe, 128 undefined, 255 too steep), each with a YAML sidecar. At 1 m the orbital
map cannot see steps or roughness the rover cares about (rocks are smaller than a cell), so the
hazard is the slope criterion only; the rover's own scans judge the rest.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from drivers.sim.scene import load_scene_spec
from drivers.sim.terrain import dtm_crop
from drivers.sim.world import World
from prox_workflows.algorithms.dem2hazard import load_params
from prox_workflows.algorithms.global_map import orbital_hazard
from prox_workflows.grid import GridGeometry, write_geotiff
from prox_workflows.products import write_text_atomic
from rvs_params.hazard import UNDEFINED


def from_orbit(scene: str) -> bool:
    """Whether the scene's ground is built on an orbital DTM (a ``dtm`` primitive), which a rover
    team would have as its global maps."""
    return any(p.get("type") == "dtm" for p in load_scene_spec(scene)["terrain"].get("primitives", []))


def scene_dtm(scene: str, world: World | None = None) -> tuple[np.ndarray, GridGeometry, dict[str, Any], dict[str, Any]]:
    """The scene's whole ``dtm`` primitive as the simulated ground has it: north-up float32
    heights in the world frame (``world``'s height shift applied: the ground under the rover's
    start is z = 0), DTM nodes as cell centres (pixel-is-area, as every map the server writes);
    its grid, the primitive and the scene's spec."""
    spec = load_scene_spec(scene)
    prims = [p for p in spec["terrain"].get("primitives", []) if p.get("type") == "dtm"]
    if not prims:
        raise ValueError(f"scene {spec['name']!r} has no dtm primitive: nothing seen from orbit to write")
    p = prims[0]
    z, x_nw, y_nw, cell = dtm_crop(p, Path(spec["_dir"]))
    shift = (world or World.from_scene(scene, clock_scale=0.0)).z_shift
    heights = (float(p.get("scale", 1.0)) * z + float(spec["terrain"].get("base_height", 0.0)) - shift)
    geom = GridGeometry(cell, x_nw - cell / 2.0, y_nw + cell / 2.0, z.shape[1], z.shape[0])
    return heights.astype(np.float32), geom, p, spec


def orbital_dem(scene: str) -> tuple[np.ndarray, GridGeometry, dict[str, Any]]:
    """The scene's DTM (north-up, float32) on its own grid in the world frame, and its source:
    cells that reach past the scene's terrain are dropped (the simulator has no ground there,
    where a real orbital map would, and the planner takes the map's edge for where the rover may
    go)."""
    heights, g, p, spec = scene_dtm(scene)
    x0, y1, cell = g.xmin, g.ymax, g.cell
    bx0, by0, bx1, by1 = (float(v) for v in spec["terrain"]["bounds"])
    cols = np.nonzero((x0 + np.arange(heights.shape[1]) * cell >= bx0 - 1e-9)
                      & (x0 + np.arange(1, heights.shape[1] + 1) * cell <= bx1 + 1e-9))[0]
    rows = np.nonzero((y1 - np.arange(1, heights.shape[0] + 1) * cell >= by0 - 1e-9)
                      & (y1 - np.arange(heights.shape[0]) * cell <= by1 + 1e-9))[0]
    if len(rows) == 0 or len(cols) == 0:
        raise ValueError(f"scene {spec['name']!r}: no cell of its dtm lies within the terrain's bounds")
    heights = heights[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1]
    geom = GridGeometry(cell, x0 + cols[0] * cell, y1 - rows[0] * cell, len(cols), len(rows))
    return heights.astype(np.float32), geom, {"scene": spec["name"], "file": str(p["file"]),
                                               "crop": list(p.get("crop", [])), "cell": cell}


def write_global_maps(scene: str, out: Path, slope_max: float | None = None) -> dict[str, Path]:
    """Write dem.tif, slope.tif and hazard.tif of the scene's orbital DTM into ``out``."""
    dem, geom, source = orbital_dem(scene)
    params = load_params(window=3 * geom.cell, step_max=1e6, roughness_max=1e6,
                         **({"slope_max": slope_max} if slope_max is not None else {}))
    layers = orbital_hazard(dem, geom.cell, slope_max)  # as navigate -global derives them
    out.mkdir(parents=True, exist_ok=True)
    paths = {
        "dem": write_geotiff(out / "dem.tif", dem, geom),
        "slope": write_geotiff(out / "slope.tif", layers["slope"].astype(np.float32), geom),
        "hazard": write_geotiff(out / "hazard.tif", layers["hazard"].astype(np.uint8), geom, nodata=UNDEFINED),
    }

    for name, path in paths.items():
        write_text_atomic(path.with_suffix(".yaml"), yaml.safe_dump({
            "made_by": "rvs_truth.orbital", "layer": name, "source": source,
            "credit": "HiRISE, NASA/JPL/University of Arizona (public)" if "mars" in source["file"] else None,
            "frame": "the simulated world's: origin on the ground under the rover's start, x forward, y left, z up",
            "slope_max_deg": params.slope_max, "window_m": params.window,
        }, sort_keys=False))
    return paths


ORIGIN = (500000.0, 4000000.0)  # the rover frame's origin in the map's UTM coordinates


def orbital_geotiff(world: World, path: Path, origin: tuple[float, float] = ORIGIN, cell: float = 0.5) -> Path:
    """The world's true DEM at ``cell`` metres as a UTM GeoTIFF whose (E, N) = ``origin`` is the
    rover frame's (0, 0)."""

    g = GridGeometry.covering(*world.terrain.bounds, cell)
    dem = world.true_dem(cell, g.bounds, include_target=False).astype(np.float32)
    utm = GridGeometry(cell, g.xmin + origin[0], g.ymax + origin[1], g.width, g.height, crs="EPSG:32633")
    return Path(write_geotiff(path, dem, utm))


def rover_patch(world: World, true_pose: tuple[float, float, float], error: tuple[float, float, float],
                rng: np.random.Generator) -> tuple[np.ndarray, GridGeometry, tuple[float, float]]:
    """The rover's 360-degree DEM (rocks and roughness included, the ToF's ring from 1 to 4.5 m,
    30 % holes, its own height datum) placed with a believed pose = truth + ``error``."""
    tx, ty, _ = true_pose
    ex, ey, eyaw = error
    bx, by = tx + ex, ty + ey
    geom = GridGeometry.covering(bx - 4.6, by - 4.6, bx + 4.6, by + 4.6, 0.05)
    xs, ys = geom.centers()
    X, Y = np.meshgrid(xs, ys)
    c, s = math.cos(math.radians(-eyaw)), math.sin(math.radians(-eyaw))
    ux, uy = X - bx, Y - by
    z = world.terrain.sample(c * ux - s * uy + tx, s * ux + c * uy + ty).astype(np.float32) + 0.4
    r = np.hypot(ux, uy)
    z[(r > 4.5) | (r < 1.0) | (rng.uniform(size=z.shape) < 0.3)] = np.nan
    return z, geom, (bx, by)
