"""``rvs-dem-mosaik A.tif B.tif ... --rule fuse -o M.tif``: DemMosaik - DEMs of different extents
and cell sizes merged onto one grid (the union of their extents at the finest cell, or ``--cell``
/ ``--bounds``), by the rule ``max``, ``newest`` (later inputs win) or ``fuse`` (Kalman update
with a Mahalanobis gate; see prox_workflows.algorithms.dem_mosaik).

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

from rvs_params import SettingError
from rvs_params.cli import ToolParser

from ..algorithms.dem_import import cells_from_bounds
from ..engine import WorkflowError, parameters_of, run_workflow
from ..grid import parse_crs
from ..layers import prefix_of

MADE_BY = "rvs-dem-mosaik (prox_workflows.algorithms.dem_mosaik)"


def main(argv: list[str] | None = None) -> int:
    specs = parameters_of("dem_mosaik").specs()
    ap = ToolParser(prog="rvs-dem-mosaik", description=__doc__.split("\n\n")[0],
                    formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("inputs", nargs="+", type=Path, help="DEM GeoTIFFs, oldest first")
    ap.add_argument("-o", "--output", type=Path, required=True, help="the mosaic DEM GeoTIFF")
    ap.add_argument("--bounds", help="xmin,ymin,xmax,ymax of the output; default: the union of the inputs")
    for spec in specs.values():  # the script's parameters: DemMosaikParams and its steps' settings
        ap.add_argument("--" + spec.name.replace("_", "-"), dest=spec.name, default=None,
                        help=f"{spec.help} ({spec.describe()}; default {spec.default})")
    ap.add_argument("--crs", help="the CRS of the inputs' x and y, as an EPSG code (e.g. EPSG:32611 for UTM 11N), written into every GeoTIFF and sidecar; default: the inputs' own CRS, else the rover's local frame")
    ap.add_argument("--preview", action="store_true", help="also write the PNG previews")
    args = ap.parse_args(argv)
    try:
        params = {n: specs[n].parse(str(getattr(args, n)), specs[n].cli_flag) for n in specs
                  if getattr(args, n) is not None}
        bounds = list(cells_from_bounds(args.bounds)) if args.bounds else None
        out = Path(args.output)
        t0 = time.perf_counter()
        ws, _ = run_workflow("dem_mosaik", params, {
            "paths": [str(p) for p in args.inputs], "bounds": bounds, "out_dir": out.parent,
            "crs": parse_crs(args.crs),
            "name": prefix_of(out).name, "dem_file": out.name, "preview": args.preview, "made_by": MADE_BY,
            "parameters": {**{n: s.default for n, s in specs.items()}, **params, "bounds": args.bounds}})
    except (OSError, ValueError, SettingError, WorkflowError) as exc:
        sys.stderr.write(f"rvs-dem-mosaik: {exc}\n")
        return 2
    mosaic, files = ws["dem"], ws["files"]
    g = mosaic.geometry
    defined = int(np.isfinite(mosaic["dem"]).sum())
    print(f"{len(ws['dems'])} DEMs -> {g.width} x {g.height} cells of {g.cell} m "
          f"({params.get('rule', specs['rule'].default)}), {defined} defined; {time.perf_counter() - t0:.2f} s")
    if "rejected_cells" in mosaic.meta:
        print(f"  gate rejected a measurement in {mosaic.meta['rejected_cells']} cells")
    for name, path in files.items():
        print(f"  {name}: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
