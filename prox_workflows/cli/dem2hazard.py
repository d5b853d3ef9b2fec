"""``rvs-dem2hazard DEM.tif -o PREFIX``: the Dem2Hazard toolbox step on a GeoTIFF DEM.

Writes PREFIX_{slope,roughness,step,hazard,traversability}.tif on the DEM's grid (GDAL and QGIS
open them in place), a YAML sidecar and a PNG preview with colour bar or legend for each, and
prints the shares of safe, hazardous and undefined cells. Thresholds come from
config/dem2hazard.yaml (or ``--config``), then ``--set key=value`` and the threshold options.
"""

from __future__ import annotations

import sys
import time
from dataclasses import fields
from pathlib import Path
from typing import Any

import yaml

from rvs_params import SettingError
from rvs_params.cli import ToolParser

from ..algorithms.dem2hazard import HazardParams, load_params
from ..engine import WorkflowError, run_workflow
from ..grid import GridGeometry, parse_crs
from ..steps.read import read_dem as _read_dem

MADE_BY = "rvs-dem2hazard (prox_workflows.algorithms.dem2hazard)"


def read_dem(path: Path, nodata: float | None = None) -> tuple[Any, GridGeometry]:
    """The DEM as float32 with NaN where undefined (the file's GDAL nodata value, or ``nodata``)."""
    layers = _read_dem(path, nodata)
    return layers["dem"], layers.geometry


def main(argv: list[str] | None = None) -> int:
    ap = ToolParser(
        prog="rvs-dem2hazard",
        description="Slope, roughness, step, hazard and traversability maps of a GeoTIFF DEM (seed 000 sect. 3.1.6).")
    ap.add_argument("dem", type=Path, help="DEM GeoTIFF (float, NaN or its nodata value where undefined)")
    ap.add_argument("-o", "--output", required=True, help="prefix of the outputs: PREFIX_slope.tif ...")
    ap.add_argument("--config", type=Path, help="parameter YAML (default config/dem2hazard.yaml)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a parameter")
    specs = HazardParams.specs()
    for f in fields(HazardParams):
        ap.add_argument("--" + f.name.replace("_", "-"), type=float, dest=f.name, default=None,
                        help=f"{specs[f.name].help} ({specs[f.name].describe()})")
    ap.add_argument("--nodata", type=float, help="DEM value meaning undefined (default: the file's nodata tag)")
    ap.add_argument("--crs", help="the CRS of the inputs' x and y, as an EPSG code (e.g. EPSG:32611 for UTM 11N), written into every GeoTIFF and sidecar; default: the inputs' own CRS, else the rover's local frame")
    ap.add_argument("--no-preview", action="store_true", help="skip the PNG previews")
    args = ap.parse_args(argv)

    prefix = Path(args.output)
    try:
        overrides = HazardParams.parse_assignments(args.set)
        overrides.update({f.name: getattr(args, f.name) for f in fields(HazardParams)
                          if getattr(args, f.name) is not None})
        params = load_params(args.config, **overrides)
        t0 = time.perf_counter()
        ws, _ = run_workflow("dem2hazard", params.as_dict(), {
            "path": str(args.dem), "nodata": args.nodata, "out_dir": prefix.parent, "name": prefix.name,
            "crs": parse_crs(args.crs),
            "preview": not args.no_preview, "made_by": MADE_BY, "parameters": params.as_dict()})
        seconds = time.perf_counter() - t0
    except (OSError, ValueError, TypeError, yaml.YAMLError, WorkflowError, SettingError) as exc:
        sys.stderr.write(f"rvs-dem2hazard: {exc}\n")
        return 2
    maps = ws["maps"]
    geometry = maps.geometry
    info = maps.meta["dem2hazard"]
    n, shares = info["window_cells"], info["summary"]
    print(f"rvs-dem2hazard: {args.dem} {geometry.width} x {geometry.height} cells of {geometry.cell:g} m, "
          f"window {n} x {n} cells ({n * geometry.cell:.3g} m), {seconds * 1e3:.0f} ms")
    print(f"  thresholds: step {params.step_max:g} m, slope {params.slope_max:g} deg, "
          f"roughness {params.roughness_max:g} m, min_fraction {params.min_fraction:g}")
    print(f"  hazard: safe {100 * shares['safe']:.1f} %, hazardous {100 * shares['hazardous']:.1f} %, "
          f"undefined {100 * shares['undefined']:.1f} %")
    for path in ws["files"].values():
        print(f"  wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
