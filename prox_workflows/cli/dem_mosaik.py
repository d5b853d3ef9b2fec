"""``rvs-dem-mosaik A.tif B.tif ... --rule fuse -o M.tif``: DemMosaik - DEMs of different extents
and cell sizes merged onto one grid (the union of their extents at the finest cell, or ``--cell``
/ ``--bounds``), by the rule ``max``, ``newest`` (later inputs win) or ``fuse`` (Kalman update
with a Mahalanobis gate; see prox_workflows.steps.dem_mosaik).

Each input is read with the companion layers beside it (``A_count.tif``, ``A_variance.tif``,
``A_measurement_variance.tif`` ... as rvs-dem-import writes them). For ``fuse`` an input's cell
variance is its measurement variance layer if present, else ``--sigma``^2 plus the spread of its
heights; a mosaic's own variance (its sidecar says so) is taken as it is.

Writes the DEM with ``<prefix>_variance.tif``, ``<prefix>_count.tif`` and ``<prefix>_source.tif``
(the index of the input that set each cell) beside it, named as rvs-dem-import names them, and
YAML sidecars; ``--fill R`` also fills holes narrower than a disk of R metres (``_filled.tif``
marks them).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from ..grid import GridGeometry
from ..steps.dem_import import cells_from_bounds
from ..steps.dem_mosaik import RULES, dem_mosaik
from ..steps.holes import fill_layers
from .dem_import import read_layers, write_layers
from .parser import ToolParser

MADE_BY = "rvs-dem-mosaik (prox_workflows.steps.dem_mosaik)"


def main(argv: list[str] | None = None) -> int:
    ap = ToolParser(prog="rvs-dem-mosaik", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("inputs", nargs="+", type=Path, help="DEM GeoTIFFs, oldest first")
    ap.add_argument("--rule", choices=RULES, default="max", help="merge rule (default max)")
    ap.add_argument("-o", "--output", type=Path, required=True, help="the mosaic DEM GeoTIFF")
    ap.add_argument("--cell", type=float, help="output cell size (m); default: the finest input's")
    ap.add_argument("--bounds", help="xmin,ymin,xmax,ymax of the output; default: the union of the inputs")
    ap.add_argument("--sigma", type=float, default=0.01,
                    help="fuse: height sigma (m) of inputs without a measurement variance layer (default 0.01)")
    ap.add_argument("--gate", type=float, default=3.0, help="fuse: Mahalanobis gate (default 3)")
    ap.add_argument("--inflation", type=float, default=0.0025,
                    help="fuse: variance (m^2) added to the prior when a measurement is rejected (default 0.0025)")
    ap.add_argument("--on-conflict", choices=["inflate", "higher"], default="inflate",
                    help="fuse: reject and inflate (separate scans) or let the higher win (views of one scan)")
    ap.add_argument("--fill", type=float, default=0.0, help="fill holes narrower than a disk of this radius (m)")
    args = ap.parse_args(argv)
    try:
        t0 = time.perf_counter()
        dems = [read_layers(p) for p in args.inputs]
        geometry = None
        if args.bounds:
            cell = args.cell if args.cell else min(d.geometry.cell for d in dems)
            geometry = GridGeometry.covering(*cells_from_bounds(args.bounds), cell)
        t1 = time.perf_counter()
        mosaic = dem_mosaik(dems, rule=args.rule, geometry=geometry, cell=args.cell, sigma=args.sigma,
                            gate=args.gate, inflation=args.inflation, on_conflict=args.on_conflict)
        if args.fill > 0:
            mosaic = fill_layers(mosaic, args.fill)
        t2 = time.perf_counter()
        params = {"rule": args.rule, "cell": mosaic.geometry.cell, "bounds": args.bounds, "sigma": args.sigma,
                  "gate": args.gate, "inflation": args.inflation, "on_conflict": args.on_conflict,
                  "fill": args.fill}
        meanings = {"dem": f"merged height (m, z up, global frame), rule {args.rule}",
                    "variance": "variance of the merged height (m^2)",
                    "count": "points behind the cell, all inputs"}
        files = write_layers(args.output, mosaic, MADE_BY, params, [str(p) for p in args.inputs],
                             meanings=meanings)
    except (OSError, ValueError) as exc:
        sys.stderr.write(f"rvs-dem-mosaik: {exc}\n")
        return 1
    g = mosaic.geometry
    defined = int(np.isfinite(mosaic["dem"]).sum())
    print(f"{len(dems)} DEMs -> {g.width} x {g.height} cells of {g.cell} m ({args.rule}), {defined} defined; "
          f"read {t1 - t0:.2f} s, merge {t2 - t1:.3f} s")
    if "rejected_cells" in mosaic.meta:
        print(f"  gate rejected a measurement in {mosaic.meta['rejected_cells']} cells")
    for name, path in files.items():
        print(f"  {name}: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
