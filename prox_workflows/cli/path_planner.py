"""``rvs-path-planner``: the path planning application (seed 000 sect. 4.4.1) on GeoTIFF maps.

    rvs-path-planner --hazard H.tif --slope S.tif [--global-hazard G.tif --global-slope GS.tif]
                     [--global DEM.tif [--global-origin E,N]]
                     [--ortho O.tif] --start x,y --goal x,y [--weight 0.5]
                     [--heuristic euclidean|manhattan|octile] [--grid M] [--margin M]
                     [--rover-radius M] [--max-deviation M] [--border M] -o PREFIX

Start, goal and every output are in the maps' world coordinates (their GeoTIFF transform).
Without global maps, blank ones are made to cover the local map, the start and the goal.
``--global`` takes a global DEM (or 0/128/255 hazard map) from orbit in any CRS in metres, moved
to the maps' frame by ``--global-origin`` (the frame's origin in the file's CRS); its hazard and
slope come from Dem2Hazard (prox_workflows.algorithms.global_map, as navigate -global) and are written
as PREFIX_global_hazard.tif and PREFIX_global_slope.tif, which the plan then reads. Writes
PREFIX_path.csv, PREFIX_waypoints.csv, PREFIX_plan.yaml and PREFIX_plan_map.png (plus
PREFIX_plan_ortho.png with ``--ortho``); prints the path cost and the waypoints. Exit status 1
with the reason when there is no path, 2 for bad arguments or unreadable maps.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from rvs_params import SettingError
from rvs_params.cli import ToolParser
from rvs_params.hazard import UNDEFINED

from ..algorithms.planner import PlannerParams, PlanningError
from ..engine import WorkflowError, parameters_of, run_workflow
from ..params import show_value

MADE_BY = "rvs-path-planner (prox_workflows.algorithms.planner)"
SCRIPT = "path_planner"


def _point(text: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected x,y in metres, got {text!r}") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise argparse.ArgumentTypeError(f"expected finite x,y, got {text!r}")
    return x, y


def _global_maps(path: Path, origin: tuple[float, float], prefix: str) -> tuple[Path, Path]:
    """Hazard and slope of a global DEM in the maps' frame, written beside the outputs (the plan
    reads maps from files, and the products say what they were planned on)."""
    from ..algorithms.global_map import load_global
    from ..grid import write_geotiff

    g = load_global(path, origin)
    out = Path(prefix)
    out.parent.mkdir(parents=True, exist_ok=True)
    hz = write_geotiff(out.with_name(out.name + "_global_hazard.tif"), g.hazard, g.geometry, nodata=UNDEFINED)
    sl = write_geotiff(out.with_name(out.name + "_global_slope.tif"), g.slope, g.geometry)
    return Path(hz), Path(sl)


def build_parser() -> argparse.ArgumentParser:
    d = PlannerParams()
    specs = parameters_of(SCRIPT).specs()
    ap = ToolParser(prog="rvs-path-planner", description=__doc__.split("\n\n")[0])
    ap.add_argument("--hazard", type=Path, required=True, help="local hazard map GeoTIFF (0/128/255)")
    ap.add_argument("--slope", type=Path, required=True, help="local slope map GeoTIFF (degrees)")
    ap.add_argument("--global-hazard", type=Path, help="global hazard map GeoTIFF")
    ap.add_argument("--global-slope", type=Path, help="global slope map GeoTIFF")
    ap.add_argument("--global", dest="global_dem", type=Path,
                    help="global DEM (or hazard map) GeoTIFF in any CRS in metres, instead of --global-hazard/slope")
    ap.add_argument("--global-origin", type=_point, default=(0.0, 0.0),
                    help="E,N: the maps' frame origin in the --global file's CRS (default 0,0)")
    ap.add_argument("--ortho", type=Path, help="ortho-image GeoTIFF to draw the plan on")
    ap.add_argument("--start", type=_point, required=True, help="x,y in metres")
    ap.add_argument("--goal", type=_point, required=True, help="x,y in metres")
    ap.add_argument("--start-heading", type=float, help="the rover's heading at the start, degrees")
    for spec in specs.values():  # declared once, beside the plan_path step (navigate's options are the same)
        ap.add_argument("--" + spec.name.replace("_", "-"), dest=spec.name, default=str(spec.default),
                        help=f"{spec.help} ({spec.describe()}; default {show_value(spec.default)})")
    ap.add_argument("--rover-radius", type=float, default=d.rover_radius, help=f"m (default {d.rover_radius:g})")
    ap.add_argument("--rover-half-width", type=float, default=0.2,
                    help="m: half the rover's width, for --footprint body (default 0.2)")
    ap.add_argument("--critical-slope", type=float, default=d.critical_slope,
                    help=f"slope (deg) whose cost equals unknown ground's at --unknown-cost 1 (default "
                         f"{d.critical_slope:g})")
    ap.add_argument("--unknown-cost", type=float, default=d.unknown_cost,
                    help=f"environmental cost of unknown ground (inf: never enter it; default {d.unknown_cost:g})")
    ap.add_argument("-o", "--output", required=True, help="output prefix (PREFIX_path.csv ...)")
    return ap


def main(argv: list[str] | None = None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    if (args.global_hazard is None) != (args.global_slope is None):
        print("rvs-path-planner: --global-hazard and --global-slope go together", file=sys.stderr)
        return 2
    if args.global_dem is not None:
        if args.global_hazard is not None:
            print("rvs-path-planner: give --global or --global-hazard/--global-slope, not both", file=sys.stderr)
            return 2
        try:
            args.global_hazard, args.global_slope = _global_maps(args.global_dem, args.global_origin, args.output)
        except (OSError, ValueError) as exc:
            print(f"rvs-path-planner: --global {args.global_dem}: {exc}", file=sys.stderr)
            return 2
    specs = parameters_of(SCRIPT).specs()
    try:
        params = {name: spec.parse(str(getattr(args, name)), spec.cli_flag) for name, spec in specs.items()}
    except SettingError as exc:
        print(f"rvs-path-planner: {exc}", file=sys.stderr)
        return 2
    inputs = [str(p) for p in (args.hazard, args.slope, args.global_hazard, args.global_slope, args.ortho) if p]
    t0 = time.perf_counter()
    try:
        ws, log = run_workflow(SCRIPT, params, {
            "hazard": args.hazard, "slope": args.slope, "global_hazard": args.global_hazard,
            "global_slope": args.global_slope, "ortho_path": args.ortho, "start": list(args.start),
            "goal": list(args.goal), "start_heading": args.start_heading, "rover_radius": args.rover_radius,
            "rover_half_width": args.rover_half_width,
            "critical_slope": args.critical_slope, "unknown_cost": args.unknown_cost, "prefix": args.output,
            "made_by": MADE_BY, "inputs": inputs})
    except PlanningError as exc:
        print(f"rvs-path-planner: no path ({exc.reason}): {exc.message}", file=sys.stderr)
        return 1
    except (OSError, ValueError, WorkflowError) as exc:
        print(f"rvs-path-planner: {exc}", file=sys.stderr)
        return 2
    result, written = ws["plan"], ws["files"]
    elapsed = sum(e["seconds"] for e in log.entries if e["step"] == "plan_path") or time.perf_counter() - t0
    geom = result.image.geometry
    print(f"planning grid {geom.height} x {geom.width} cells of {geom.cell:g} m, {result.expanded} expanded, "
          f"{elapsed * 1000:.0f} ms")
    print(f"path cost {result.cost:.3f} over {len(result.path)} points to the goal; the rover drives "
          f"{result.cut} points (cost {float(result.cost_so_far[result.cut - 1]):.3f})"
          + ("" if result.reaches_goal else ", cut at the local map's border"))
    for note in result.warnings:
        print(f"note: {note}")
    wp = result.waypoints
    print(f"{len(wp)} waypoints:")
    print(f"{'#':>3} {'x':>10} {'y':>10} {'heading':>9} {'turn':>8} {'leg':>8}")
    for i, (x, y, hd, tn, leg) in enumerate(wp.table()):
        print(f"{i:>3} {x:>10.3f} {y:>10.3f} {hd:>9.1f} {tn:>8.1f} {leg:>8.3f}")
    for p in written:
        print(p)
    return 0


if __name__ == "__main__":
    sys.exit(main())
