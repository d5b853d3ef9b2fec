"""Global maps from orbit for navigate: the DTM a scene is built on, as GeoTIFFs in the rover frame.

A scene with a ``dtm`` terrain primitive (``hirise``) is a real orbital DTM with rover-scale
detail (roughness, rocks) added on top; the orbiter saw only the DTM. This writes that DTM, at
its own cell size (1.01 m for HiRISE), in the simulated world's frame (the frame the server's
poses are in: origin on the ground under the rover's start), with the slope and hazard maps
navigate's ``global_maps`` folder needs:

    python -m tools.global_maps hirise data/global/hirise
    rvs-server --scene hirise --set navigate.global_maps=data/global/hirise

Files: ``dem.tif`` (heights, m), ``slope.tif`` (deg), ``hazard.tif`` (0 safe, 128 undefined,
255 too steep), each with a YAML sidecar. At 1 m the orbital map cannot see steps or roughness
the rover cares about (rocks are smaller than a cell), so the hazard is the slope criterion
only (Dem2Hazard with its step and roughness thresholds out of reach); the rover's own scans
judge the rest.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from drivers.sim.scene import load_scene_spec
from drivers.sim.terrain import dtm_crop
from drivers.sim.world import World
from prox_workflows.algorithms.dem2hazard import load_params
from prox_workflows.algorithms.global_map import orbital_hazard
from prox_workflows.grid import GridGeometry, write_geotiff
from prox_workflows.products import write_text_atomic
from rvs_params.hazard import UNDEFINED


def orbital_dem(scene: str) -> tuple[np.ndarray, GridGeometry, dict[str, Any]]:
    """The scene's DTM (north-up, float32) on its own grid in the world frame, and its source."""
    spec = load_scene_spec(scene)
    prims = [p for p in spec["terrain"].get("primitives", []) if p.get("type") == "dtm"]
    if not prims:
        raise ValueError(f"scene {spec['name']!r} has no dtm primitive: nothing seen from orbit to write")
    p = prims[0]
    z, x_nw, y_nw, cell = dtm_crop(p, Path(spec["_dir"]))
    # The world shifts the scene so the ground under the rover's start is z = 0; so does the map.
    shift = World.from_scene(scene, clock_scale=0.0).z_shift
    heights = (float(p.get("scale", 1.0)) * z + float(spec["terrain"].get("base_height", 0.0)) - shift)
    # DTM nodes become cell centres (pixel-is-area, as every map the server writes); cells that
    # reach past the scene's terrain are dropped: the simulator has no ground there, where a real
    # orbital map would, and the planner takes the map's edge for where the rover may go
    x0, y1 = x_nw - cell / 2.0, y_nw + cell / 2.0
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
    import yaml

    for name, path in paths.items():
        write_text_atomic(path.with_suffix(".yaml"), yaml.safe_dump({
            "made_by": "tools.global_maps", "layer": name, "source": source,
            "credit": "HiRISE, NASA/JPL/University of Arizona (public)" if "mars" in source["file"] else None,
            "frame": "the simulated world's: origin on the ground under the rover's start, x forward, y left, z up",
            "slope_max_deg": params.slope_max, "window_m": params.window,
        }, sort_keys=False))
    return paths


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tools.global_maps", description=__doc__.splitlines()[0])
    ap.add_argument("scene", help="scene name (config/scenes/) or path of a scene .yaml with a dtm primitive")
    ap.add_argument("out", type=Path, help="folder to write dem.tif, slope.tif, hazard.tif into")
    ap.add_argument("--slope-max", type=float, help="steepest traversable slope, deg (default: config/dem2hazard.yaml)")
    args = ap.parse_args(argv)
    try:
        paths = write_global_maps(args.scene, args.out, args.slope_max)
    except (OSError, ValueError, KeyError) as exc:
        print(f"global_maps: {exc}", file=sys.stderr)
        return 1
    for name, path in paths.items():
        print(f"{name}: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
