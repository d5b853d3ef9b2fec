"""``rvs-prox batch`` and ``rvs-prox mosaic-campaign``: the campaign tools' command lines over
:mod:`prox_workflows.batch` (one script over many recorded jobs on a Dask cluster; many sites'
DEMs into one tiled mosaic)."""

from __future__ import annotations

import argparse
import glob
import math
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rvs_params.cli import ToolParser

from ..batch import (
    TILE,
    SchedulerError,
    find_inputs,
    mosaic_campaign,
    run_batch,
    scheduler_address,
)
from ..reprocess import OFFLINE_SCRIPTS, ReprocessError, parse_overrides
from .progress import show_progress


def _bar(done: int, total: int, message: str) -> None:
    show_progress(done, total, message, phase="batch")


def _argtype(check: Callable[[str], Any]) -> Callable[[str], Any]:
    """An argparse ``type`` from a checker that raises ValueError or SchedulerError, so a bad
    value ends as argparse's one ``error:`` line (exit 2) with the checker's words."""
    def parse(text: str) -> Any:
        try:
            return check(text)
        except (ValueError, SchedulerError) as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    parse.__name__ = check.__name__
    return parse


def _whole(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise ValueError(f"{text!r} is not a whole number") from None


def _positive_int(text: str) -> int:
    value = _whole(text)
    if value < 1:
        raise ValueError(f"{text} is not a positive whole number")
    return value


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{text!r} is not a number") from None
    if not math.isfinite(value) or value <= 0:
        raise ValueError(f"{text} is not a positive number")
    return value


def _tile_size(text: str) -> int:
    value = _whole(text)
    if value < 16 or value % 16:
        raise ValueError(f"{text} is not a multiple of 16 (TIFF tiles are): try {max(16, round(value / 16) * 16)}")
    return value


def _file_stem(text: str) -> str:
    if not text or text in (".", "..") or "/" in text or "\\" in text:
        raise ValueError(f"{text!r} is not a file name (no folders: those go in -o)")
    return text


def main(argv: list[str]) -> int:
    """``rvs-prox batch ...`` and ``rvs-prox mosaic-campaign ...`` (``argv[0]`` names which)."""
    if argv[0] == "mosaic-campaign":
        return _main_mosaic(argv[1:])
    ap = ToolParser(prog="rvs-prox batch", description="Re-run recorded DEM jobs on Dask.")
    ap.add_argument("script", help="the script to run on each job (dem: its offline form dem_views)")
    ap.add_argument("--inputs", action="append", required=True, metavar="GLOB",
                    help="recorded jobs: 'campaign/*/dem/*' (views folders, stems or DEMs; each job once)")
    ap.add_argument("--scheduler", type=_argtype(scheduler_address),
                    help="a Dask scheduler's address (tcp://host:8786); default a LocalCluster here")
    ap.add_argument("--workers", type=_argtype(_positive_int), default=os.cpu_count() or 2,
                    help="LocalCluster worker processes")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a recorded parameter")
    ap.add_argument("-o", "--out", help="one folder for every job's products (default <job dir>/reprocessed)")
    ap.add_argument("--force", action="store_true", help="re-run jobs whose products are up to date")
    args = ap.parse_args(argv[1:])
    if args.script not in OFFLINE_SCRIPTS:
        ap.error(f"script {args.script!r} does not run on recorded DEM jobs; use one of {', '.join(OFFLINE_SCRIPTS)}")
    try:
        overrides = parse_overrides(args.set)
    except ReprocessError as exc:
        ap.error(str(exc))
    inputs, ignored = find_inputs(args.inputs)
    if ignored:
        sys.stderr.write(f"rvs-prox batch: {len(ignored)} match(es) are no DEM job, left out "
                         f"(first: {ignored[0]})\n")
    if not inputs:
        sys.stderr.write("rvs-prox batch: no recorded DEM job matches\n")
        return 2
    t0 = time.perf_counter()
    try:
        results = run_batch(args.script, inputs, overrides, scheduler=args.scheduler, workers=args.workers,
                            out_dir=args.out, force=args.force, progress=_bar)
    except SchedulerError as exc:
        sys.stderr.write(f"\nrvs-prox batch: {exc}\n")
        return 2
    sys.stderr.write("\n")
    counts = {s: sum(r.status == s for r in results) for s in ("done", "skipped", "failed")}
    for r in results:
        if r.status == "failed":
            print(f"FAILED {r.input}: {r.error}")
        elif r.status == "done":
            print(f"done {r.input} ({r.seconds:.2f} s): {r.files.get('dem', '')}")
        else:
            print(f"skipped {r.input} (up to date)")
    print(f"{len(results)} jobs: {counts['done']} done, {counts['skipped']} skipped, {counts['failed']} failed "
          f"in {time.perf_counter() - t0:.1f} s")
    return 1 if counts["failed"] else 0


def _main_mosaic(argv: list[str]) -> int:
    ap = ToolParser(
        prog="rvs-prox mosaic-campaign",
        description="Fuse site DEMs into one campaign mosaic, tile by tile. -o is a folder, as for "
                    "'rvs-prox dem --from': the mosaic is OUT/NAME_dem.tif (its YAML sidecar beside it), "
                    "OUT/NAME_variance.tif and OUT/NAME_count.tif.")
    ap.add_argument("--inputs", action="append", required=True, metavar="GLOB",
                    help="site DEMs: 'campaign/*/dem/reprocessed/*_dem.tif' (fused in this order)")
    ap.add_argument("-o", "--out", required=True, metavar="DIR",
                    help="the folder the mosaic's files go in (made if missing)")
    ap.add_argument("--name", default="mosaic", type=_argtype(_file_stem),
                    help="the files' name: NAME_dem.tif, NAME_variance.tif, NAME_count.tif (default %(default)s)")
    ap.add_argument("--cell", type=_argtype(_positive_float), help="cell size in m (default: the finest site's)")
    ap.add_argument("--tile", type=_argtype(_tile_size), default=TILE,
                    help="tile size in cells, a multiple of 16 (default %(default)s)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        ap.error(f"-o {out}: not a folder (the mosaic's files go in a folder)")
    paths = [Path(p) for pattern in args.inputs for p in sorted(glob.glob(pattern, recursive=True))
             if p.endswith("_dem.tif")]
    if not paths:
        sys.stderr.write("rvs-prox mosaic-campaign: no *_dem.tif matches\n")
        return 2
    try:
        files = mosaic_campaign(paths, out / args.name, cell=args.cell, tile=args.tile, progress=_bar)
    except (OSError, ValueError) as exc:  # an unreadable site, an unwritable folder
        sys.stderr.write(f"\nrvs-prox mosaic-campaign: {exc}\n")
        return 2
    sys.stderr.write("\n")
    for name, p in files.items():
        print(f"{name}: {p}")
    return 0

