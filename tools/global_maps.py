"""Global maps from orbit for navigate: the DTM a scene is built on, as GeoTIFFs in the rover frame.

The scene's DTM at its own cell size in the simulated world's frame, with the slope and hazard
maps navigate's ``global_maps`` folder needs (rvs_truth.orbital says what each file holds):

    python -m tools.global_maps hirise data/global/hirise
    rvs-server --scene hirise --set navigate.global_maps=data/global/hirise
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rvs_truth.orbital import write_global_maps


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
