"""Make the simulator's Mars albedo texture (drivers/sim/data/mars_albedo.png) from the real
navigation-camera frames in ../shared/realdata/images/mars*.png.

The texture ships with the package so a clean clone renders the harsh scenes without the shared
folder; this script is how it was made (seeded: the same frames give the same bytes).

    python -m tools.mars_albedo [--images DIR] [--out PATH] [--size 512] [--patch 64] [--seed 13]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2

from drivers.sim.albedo import encode, quilt

ROOT = Path(__file__).resolve().parents[1]
IMAGES = ROOT.parent / "shared" / "realdata" / "images"
OUT = ROOT / "drivers" / "sim" / "data" / "mars_albedo.png"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tools.mars_albedo", description=__doc__.split("\n\n")[0])
    ap.add_argument("--images", type=Path, default=IMAGES)
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--patch", type=int, default=64)
    ap.add_argument("--seed", type=int, default=13)
    args = ap.parse_args(argv)
    paths = sorted(args.images.glob("mars*.png"))
    if not paths:
        print(f"no mars*.png in {args.images}", file=sys.stderr)
        return 1
    frames = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in paths]
    tex = quilt(frames, args.size, args.patch, args.seed)
    cv2.imwrite(str(args.out), encode(tex), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    print(f"{args.out}: {args.size}x{args.size} from {', '.join(p.name for p in paths)}; relative reflectance "
          f"std {tex.std():.3f}, {args.out.stat().st_size / 1024:.0f} KB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
