"""``rvs-dem2hazard DEM.tif -o PREFIX``: the Dem2Hazard toolbox step on a GeoTIFF DEM.

Writes PREFIX_{slope,roughness,step,hazard,traversability}.tif on the DEM's grid (GDAL and QGIS
open them in place), a YAML sidecar and a PNG preview with colour bar or legend for each, and
prints the shares of safe, hazardous and undefined cells. Thresholds come from
config/dem2hazard.yaml (or ``--config``), then ``--set key=value`` and the threshold options.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import fields
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import tifffile
import yaml

from ..grid import GDAL_NODATA, GridGeometry, read_geotiff, write_geotiff
from ..products import write_png, write_sidecar
from ..steps import colormaps
from ..steps.dem2hazard import UNDEFINED, UNITS, HazardParams, dem2hazard, hazard_summary, load_params
from .parser import ToolParser

MADE_BY = "rvs-dem2hazard (prox_workflows.steps.dem2hazard)"

MEANING = {
    "slope": "angle of the least-squares plane (errors in z only) fitted over the window",
    "roughness": "standard deviation of the window's cells about that plane (N - 3 degrees of freedom)",
    "step": "greatest height above the window's minimum (max - min over the window)",
    "hazard": "0 safe, 128 undefined, 255 hazardous (any criterion past its threshold)",
    "traversability": "weighted sum of 1 - value/threshold per criterion; 0 past any threshold; NaN undefined",
}


def read_dem(path: Path, nodata: float | None = None) -> tuple[np.ndarray, GridGeometry]:
    """The DEM as float32 with NaN where undefined (the file's GDAL nodata value, or ``nodata``)."""
    image, geometry = read_geotiff(path)
    if image.ndim != 2:
        raise ValueError(f"{path}: expected a single-band DEM, got shape {image.shape}")
    if nodata is None:
        with tifffile.TiffFile(path) as tif:
            tag = tif.pages[0].tags.get(GDAL_NODATA)
            if tag is not None:
                try:
                    nodata = float(str(tag.value).strip("\x00 "))
                except ValueError:
                    nodata = None
    dem = image.astype(np.float32)
    if nodata is not None and not math.isnan(nodata):
        dem[image == nodata] = np.nan
    return dem, geometry


def previews(maps: dict[str, np.ndarray], p: HazardParams, shares: dict[str, float]) -> dict[str, np.ndarray]:
    """RGB previews: the criteria on 0 .. twice their threshold with the threshold marked; the
    hazard map black / white / grey like the thesis's."""
    out = {}
    for name, crit, units, title in (("slope", p.slope_max, "deg", "slope"),
                                     ("roughness", p.roughness_max, "m", "roughness"),
                                     ("step", p.step_max, "m", "step")):
        out[name] = colormaps.layer_preview(maps[name], 0.0, 2 * crit, cv2.COLORMAP_INFERNO, title, units,
                                            marks={crit: "max"})
    out["traversability"] = colormaps.layer_preview(maps["traversability"], 0.0, 1.0, colormaps.RED_YELLOW_GREEN,
                                                    "traversability", "0..1", clipped=False)
    out["hazard"] = colormaps.classes_preview(maps["hazard"], title="hazard", shares=shares)
    return out


def _parse_set(items: list[str], ap: argparse.ArgumentParser) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        if not sep:
            ap.error(f"--set {item}: write key=value")
        out[key.strip().replace("-", "_")] = yaml.safe_load(raw)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = ToolParser(
        prog="rvs-dem2hazard",
        description="Slope, roughness, step, hazard and traversability maps of a GeoTIFF DEM (seed 000 sect. 3.1.6).")
    ap.add_argument("dem", type=Path, help="DEM GeoTIFF (float, NaN or its nodata value where undefined)")
    ap.add_argument("-o", "--output", required=True, help="prefix of the outputs: PREFIX_slope.tif ...")
    ap.add_argument("--config", type=Path, help="parameter YAML (default config/dem2hazard.yaml)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a parameter")
    for f in fields(HazardParams):
        ap.add_argument("--" + f.name.replace("_", "-"), type=float, dest=f.name, default=None,
                        help=f"override {f.name}")
    ap.add_argument("--nodata", type=float, help="DEM value meaning undefined (default: the file's nodata tag)")
    ap.add_argument("--no-preview", action="store_true", help="skip the PNG previews")
    args = ap.parse_args(argv)

    overrides = _parse_set(args.set, ap)
    overrides.update({f.name: getattr(args, f.name) for f in fields(HazardParams) if getattr(args, f.name) is not None})
    try:
        params = load_params(args.config, **overrides)
        dem, geometry = read_dem(args.dem, args.nodata)
    except (OSError, ValueError, TypeError, yaml.YAMLError) as exc:
        sys.stderr.write(f"rvs-dem2hazard: {exc}\n")
        return 1

    n = params.window_cells(geometry.cell)
    t0 = time.perf_counter()
    maps = dem2hazard(dem, geometry.cell, params)
    seconds = time.perf_counter() - t0
    shares = hazard_summary(maps["hazard"])

    prefix = args.output
    parameters = {**params.as_dict(), "window_cells": n, "cell": geometry.cell}
    grid = {"cell": geometry.cell, "bounds": list(geometry.bounds), "size": [geometry.width, geometry.height]}
    written: list[Path] = []
    pngs = {} if args.no_preview else previews(maps, params, shares)
    for name, data in maps.items():
        path = write_geotiff(Path(f"{prefix}_{name}.tif"), data, geometry,
                             nodata=float(UNDEFINED) if name == "hazard" else None)
        extra: dict[str, Any] = {"layer": name, "unit": UNITS[name], "meaning": MEANING[name], "grid": grid}
        if name == "hazard":
            extra["shares"] = {k: round(v, 6) for k, v in shares.items()}
        write_sidecar(path, MADE_BY, parameters, [str(args.dem)], **extra)
        if name in pngs:
            write_png(path.with_suffix(".png"), pngs[name])
        written.append(path)

    print(f"rvs-dem2hazard: {args.dem} {geometry.width} x {geometry.height} cells of {geometry.cell:g} m, "
          f"window {n} x {n} cells ({n * geometry.cell:.3g} m), {seconds * 1e3:.0f} ms")
    print(f"  thresholds: step {params.step_max:g} m, slope {params.slope_max:g} deg, "
          f"roughness {params.roughness_max:g} m, min_fraction {params.min_fraction:g}")
    print(f"  hazard: safe {100 * shares['safe']:.1f} %, hazardous {100 * shares['hazardous']:.1f} %, "
          f"undefined {100 * shares['undefined']:.1f} %")
    for path in written:
        print(f"  wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
