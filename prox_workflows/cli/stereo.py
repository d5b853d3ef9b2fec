"""``rvs-stereo LEFT RIGHT --calib CALIB.yaml [--disparity OUT.tif] [-o CLOUD.ply]``.

The stereo step on one pair as taken (unrectified, distorted): semi-global matching with a
left-right check, speckle filter and texture mask (prox_workflows.algorithms.stereo). The texture mask
measures the left image's noise (``--texture-noise`` fixes it) and says what it found.

* ``--disparity OUT.tif``: float32 disparity in pixels, NaN where invalid, in the LEFT image's
  geometry (it overlays the left image); a PNG preview and a YAML sidecar beside it.
  ``--rectified OUT.tif`` writes the disparity in the rectified geometry instead/as well.
* ``-o CLOUD.ply`` (or ``.npy``): the points in the left camera frame (OpenCV optical: x right,
  y down, z forward, metres), written by prox_workflows.pointcloud; the PLY carries the left
  grey value as intensity and colour. Each point's depth sigma follows from its z by the noise
  model sigma_z = z^2 sigma_d / (b f), whose sigma_d, b and f the sidecar records.

The calibration file is YAML with image_size [w, h], K1 D1 K2 D2 R T (OpenCV stereoCalibrate
names, T in metres from the left camera frame to the right's). ``rvs-calib stereo`` makes one
from checkerboard pairs, ``rvs-calib sim-truth`` from the simulator.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from rvs_params import SettingError, assignments
from rvs_params.cli import ToolParser

from ..algorithms.stereo import (
    DEFAULT_SIGMA_D,
    SgbmParams,
    read_image,  # noqa: F401 - the reader tests and tools use
)
from ..engine import WorkflowError, run_workflow

MADE_BY = "rvs-stereo (prox_workflows.algorithms.stereo)"


def build_parser() -> argparse.ArgumentParser:
    ap = ToolParser(
        prog="rvs-stereo",
        description="Disparity and 3D points of one stereo pair (SGBM with left-right check, speckle filter "
                    "and texture mask). Disparity in pixels in the left image's geometry, points in the left "
                    "camera frame.",
    )
    ap.add_argument("left", type=Path, help="left image (TIFF, PNG, PGM, .npy; mono8, mono16 or RGB)")
    ap.add_argument("right", type=Path, help="right image, same size")
    ap.add_argument("--calib", type=Path, required=True,
                    help="YAML with image_size, K1, D1, K2, D2, R, T (T in metres, left -> right frame)")
    ap.add_argument("--disparity", type=Path, help="float32 TIFF: disparity (px) per left pixel, NaN invalid")
    ap.add_argument("--rectified", type=Path, help="float32 TIFF: disparity in the rectified left geometry")
    ap.add_argument("-o", "--output", type=Path, help="point cloud, left camera frame: .ply or .npy (N x 3)")
    ap.add_argument("--max-depth", type=float, default=None, help="drop points farther than this (m)")
    ap.add_argument("--scale", type=float, help="match at this fraction of the resolution (0.5: 4x faster)")
    ap.add_argument("--min-depth", type=float, help="nearest depth to search (sets the disparity range), m")
    ap.add_argument("--num-disparities", type=int, help="disparity search range at full resolution (px)")
    ap.add_argument("--block-size", type=int, help="SGBM block size (odd)")
    ap.add_argument("--mode", choices=("sgbm_3way", "sgbm", "hh", "hh4"), help="SGBM variant")
    ap.add_argument("--no-lr-check", action="store_true", help="skip the left-right consistency check")
    ap.add_argument("--texture-noise", type=float, default=None, metavar="SCALE",
                    help="the texture mask's image noise as a fraction of the PIKE model's (default: measured "
                         "on the left image; 1 restores the model)")
    ap.add_argument("--sigma-d", type=float, default=None,
                    help=f"disparity noise (px) for the depth sigma (default {DEFAULT_SIGMA_D} / sqrt(scale))")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="any SgbmParams field, e.g. --set uniqueness=15 --set texture_threshold=3")
    ap.add_argument("-q", "--quiet", action="store_true")
    return ap


def main(argv: list[str] | None = None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    try:
        values: dict[str, Any] = {k: yaml.safe_load(v) for k, v in assignments(args.set).items()}
    except SettingError as exc:
        ap.error(exc.message)
    for key in ("scale", "min_depth", "num_disparities", "block_size", "mode", "texture_noise"):
        if getattr(args, key) is not None:
            values[key] = getattr(args, key)
    if args.no_lr_check:
        values["lr_max_diff"] = 0.0
    try:
        params = SgbmParams.from_dict(values)
        t0 = time.perf_counter()
        ws, log = run_workflow("stereo", None, {
            "left_path": args.left, "right_path": args.right, "calib_path": args.calib, "sgbm": params.to_dict(),
            "disparity_path": args.disparity, "rectified_path": args.rectified, "cloud_path": args.output,
            "sigma_d": args.sigma_d, "max_depth": args.max_depth, "made_by": MADE_BY,
            "inputs": [str(args.left), str(args.right), str(args.calib)]})
    except (OSError, ValueError, WorkflowError) as exc:
        print(f"rvs-stereo: {exc}", file=sys.stderr)
        return 2
    elapsed = next((e["seconds"] for e in log.entries if e["step"] == "stereo_disparity"), time.perf_counter() - t0)
    disp, left = ws["disparity"], ws["left"]
    valid = np.isfinite(disp.left)
    lines = [
        f"pair {left.shape[1]}x{left.shape[0]}, baseline {disp.rect.baseline:.4f} m, f {disp.rect.focal:.1f} px, "
        f"{params.disparities_for(disp.rect)} disparities at scale {params.scale:g}",
        f"valid {valid.mean():.1%} of the left image; matched in {elapsed:.2f} s",
    ]
    if valid.any():
        lines.append(f"disparity {np.nanmin(disp.left):.1f} .. {np.nanmax(disp.left):.1f} px")
    if disp.noise_scale is not None:
        how = "set" if params.texture_noise is not None else "measured on the left image"
        lines.append(f"texture mask: image noise {disp.noise_scale:.2f} x the PIKE model's ({how})")
    lines += ws["files"]["lines"]
    if not args.quiet:
        print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
