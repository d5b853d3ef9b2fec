"""``rvs-dem-import INPUT... --cell M [--bounds xmin,ymin,xmax,ymax] -o DEM.tif``: DemImport of point
clouds into a GeoTIFF DEM; a front-end to the ``dem_import`` workflow script.

Inputs: PLY (ascii or binary), PCD (ascii or binary), LAS/LAZ (``--classes 2`` keeps the ground; a
file in feet is converted to metres), ``.npy`` (N x 3 or N x 4), x y z [i] text, and the 4-channel
coordinate images AcquireTofCoordImages writes (x, y, z, intensity; NaN pixels undefined). All
inputs go into one DEM. Per-point variances (``--noise``): ``recorded`` (the default) takes the
ones a DEM job recorded beside its views (the server's own noise model), ``tof`` computes them
with the ToF noise model (range from the sensor position - read from the image's ``.cal`` file
beside it, or ``--sensor`` - and the intensity as amplitude), ``none`` gives none. With
variances the DEM is the information-weighted mean height of each cell, as the server's (and
``--height max`` gives the thesis's greatest height), and the ``measurement_variance`` and
``wmean`` layers are added that ``rvs-dem-mosaik --rule fuse`` weighs by.

Files (the layer registry's naming, prox_workflows/layers.py): ``-o site_dem.tif`` writes
``site_dem.tif`` and its companions ``site_mean.tif``, ``site_min.tif``, ``site_count.tif``,
``site_variance.tif`` ...; an output not ending in ``_dem`` (``-o DEM.tif``) keeps its name and
prefixes the companions with its stem (``DEM_count.tif`` ...). Each GeoTIFF has a YAML sidecar
(``site_dem.yaml`` lists every layer file); ``--preview`` adds the PNG previews.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from rvs_params import SettingError
from rvs_params.cli import ToolParser

from ..algorithms.dem_import import cells_from_bounds
from ..engine import WorkflowError, run_workflow
from ..grid import parse_crs
from ..layers import layer_path as _layer_path
from ..layers import prefix_of, read_layers, write_layers  # noqa: F401 - the readers and writers of DEM files
from ..parameters import DemImportParams

MADE_BY = "rvs-dem-import (prox_workflows.algorithms.dem_import)"
# What prox_workflows.pointcloud.read_points reads, by extension: the --help names every one.
INPUT_FORMATS = ("PLY (.ply, ascii or binary), PCD (.pcd, ascii or binary), LAS/LAZ (.las, .laz), .npy "
                 "(N x 3 or N x 4), x y z [i] text (.txt .xyz .csv .asc .pts) or a 4-channel coordinate TIFF "
                 "(.tif, .tiff)")


def layer_path(dem_path: Path, layer: str) -> Path:
    return Path(dem_path) if layer == "dem" else _layer_path(prefix_of(dem_path), layer)


# ------------------------------------------------------------------------- inputs


def _numbers(text: str, what: str, shape: str, example: str) -> list[float]:
    """A comma list of finite numbers, or the option and the shape it wants: an operator who typed
    ``--range a,b`` learns which option and what to type, not Python's conversion message."""
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        vals = []
    if not vals or not all(np.isfinite(vals)):
        raise ValueError(f"{what} {text!r}: give {shape} as numbers, e.g. {what} {example}")
    return vals


def _parse_triplet(text: str, what: str) -> np.ndarray:
    vals = _numbers(text, what, "x,y,z", "0,0,1.2")
    if len(vals) != 3:
        raise ValueError(f"{what}: need x,y,z")
    return np.array(vals)


def _range(text: str) -> list[float]:
    vals = _numbers(text, "--range", "min,max", "0.3,4")
    if len(vals) != 2 or not 0 <= vals[0] < vals[1]:
        raise ValueError(f"--range {text!r}: need min,max with 0 <= min < max (metres from the sensor)")
    return vals


def _rover_mask(text: str | None) -> np.ndarray | None:
    """``xmin,ymin,xmax,ymax`` or ``x1,y1,x2,y2,x3,y3,...`` (a polygon) or a file of x y rows."""
    if text is None:
        return None
    if Path(text).is_file():
        return np.loadtxt(Path(text).read_text().replace(",", " ").splitlines(), ndmin=2)[:, :2]
    vals = _numbers(text, "--rover-mask", "xmin,ymin,xmax,ymax", "-0.5,-0.4,0.5,0.4")
    if len(vals) == 4:
        return np.array(vals)
    if len(vals) >= 6 and len(vals) % 2 == 0:
        return np.array(vals).reshape(-1, 2)
    raise ValueError("--rover-mask: xmin,ymin,xmax,ymax or x1,y1,x2,y2,x3,y3,... or a file")


def _classes(text: str | None) -> list[int] | None:
    if not text:
        return None
    try:
        return [int(c) for c in text.split(",")]
    except ValueError:
        raise ValueError(f"--classes {text!r}: LAS class numbers, e.g. 2 (ground) or 2,9") from None


def main(argv: list[str] | None = None) -> int:
    specs = DemImportParams.specs()
    ap = ToolParser(prog="rvs-dem-import", description=__doc__.split("\n\n")[0],
                    formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("inputs", nargs="+", type=Path, metavar="INPUT", help=f"point clouds: {INPUT_FORMATS}")
    ap.add_argument("--cell", required=True, help=f"cell size: {specs['cell'].describe()}")
    ap.add_argument("--height", default=specs["height"].default,
                    help=f"{specs['height'].help} ({specs['height'].describe()}; default {specs['height'].default})")
    ap.add_argument("--bounds", help="xmin,ymin,xmax,ymax (m); default: the extent of the points")
    ap.add_argument("-o", "--output", type=Path, required=True, help="the DEM GeoTIFF (e.g. site_dem.tif)")
    ap.add_argument("--noise", choices=["recorded", "none", "tof"], default="recorded",
                    help="per-point variances: recorded beside a DEM job's views (default), the ToF noise model, none")
    ap.add_argument("--sensor", help="x,y,z of the sensor for --noise tof when no .cal file is beside an input")
    ap.add_argument("--frequency", type=float, default=30.0, help="ToF modulation frequency (MHz) for --noise tof")
    ap.add_argument("--classes", help="LAS/LAZ classes to keep, e.g. 2 (ground) or 2,9; default all")
    ap.add_argument("--range", help="min,max distance (m) from the sensor (--sensor or a .cal beside an input) "
                                    "of the points kept")
    ap.add_argument("--min-reflectivity", type=float, default=0.0,
                    help="drop returns whose intensity x range^2 is below this share of the input's median "
                         "(the server's phase-wrap filter; needs intensity and the sensor position; 0: off)")
    ap.add_argument("--rover-mask", help="the rover's footprint: xmin,ymin,xmax,ymax or a polygon x1,y1,x2,y2,...")
    ap.add_argument("--rover-ground-z", type=float, help="keep points in the footprint below this height")
    ap.add_argument("--crs", help="the CRS of the inputs' x and y, as an EPSG code (e.g. EPSG:32611 for UTM 11N), written into every GeoTIFF and sidecar; default: the inputs' own CRS, else the rover's local frame")
    ap.add_argument("--preview", action="store_true", help="also write the PNG previews")
    args = ap.parse_args(argv)
    try:
        params = {n: specs[n].parse(getattr(args, n), specs[n].cli_flag) for n in ("cell", "height")}
        bounds = list(cells_from_bounds(args.bounds)) if args.bounds else None
        sensor = [float(v) for v in _parse_triplet(args.sensor, "--sensor")] if args.sensor else None
        mask = _rover_mask(args.rover_mask)
        classes = _classes(args.classes)
        rng = _range(args.range) if args.range else None
        out = Path(args.output)
        prefix = prefix_of(out)
        t0 = time.perf_counter()
        ws, log = run_workflow("dem_import", params, {
            "paths": [str(p) for p in args.inputs], "noise": args.noise, "sensor": sensor,
            "frequency": args.frequency, "bounds": bounds, "rover_mask": mask, "rover_ground_z": args.rover_ground_z,
            "out_dir": out.parent, "name": prefix.name, "dem_file": out.name, "preview": args.preview,
            "crs": parse_crs(args.crs), "classes": classes, "range": rng,
            "min_reflectivity": args.min_reflectivity,
            "made_by": MADE_BY, "parameters": {**params, "bounds": bounds, "noise": args.noise, "rover_mask": mask,
                                               "rover_ground_z": args.rover_ground_z, "classes": classes,
                                               "range": rng, "crs": args.crs}})
    except (OSError, ValueError, SettingError, WorkflowError) as exc:
        sys.stderr.write(f"rvs-dem-import: {exc}\n")
        return 2
    layers, files, points = ws["dem"], ws["files"], ws["points"]
    g = layers.geometry
    defined = int(np.isfinite(layers["dem"]).sum())
    seconds = {e["step"]: e["seconds"] for e in log.entries}
    print(f"{len(points)} points -> {g.width} x {g.height} cells of {g.cell} m, {defined} defined "
          f"({100.0 * defined / max(g.width * g.height, 1):.1f} %); read {seconds.get('read_points', 0):.2f} s, "
          f"DemImport {seconds.get('dem_import', 0):.3f} s, {time.perf_counter() - t0:.2f} s in all")
    for name, path in files.items():
        print(f"  {name}: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
