"""``rvs-odometry LEFT_A RIGHT_A LEFT_B [RIGHT_B] --calib CALIB.yaml [-o motion.yaml]``.

Visual odometry on files: camera B's motion in camera A's frame from A's stereo pair and B's
left image (or pair), by the server's orient machinery
(:func:`prox_workflows.algorithms.stereo_odometry.stereo_odometry_files`, a registered step). This
program only parses the command line, prints, and writes the YAML atomically: the estimate is
the step's, so a script, a test and this CLI get the same numbers.

Printed and written: ``tx ty tz`` (m; camera axes x right, y down, z forward), ``rx ry rz``
(deg, rotation vector), ``inliers``, ``covariance`` (6 x 6 in that order, m and deg). Exit 0 on
success, 2 for missing or unreadable inputs or a bad calibration, 3 when the images have too
little in common (too few features, tracks or inliers) to give a motion.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import yaml

from rvs_params.cli import ToolParser

from ..algorithms.odometry import OdometryError
from ..products import write_yaml_atomic
from ..steps.stereo import stereo_odometry_files


def build_parser() -> argparse.ArgumentParser:
    ap = ToolParser(prog="rvs-odometry", description="Motion of camera B in camera A's frame from a stereo "
                                                      "pair A and the next left image (or pair) B.")
    ap.add_argument("left_a", type=Path, help="left image of pair A")
    ap.add_argument("right_a", type=Path, help="right image of pair A")
    ap.add_argument("left_b", type=Path, help="left image B (the later one)")
    ap.add_argument("right_b", type=Path, nargs="?", help="right image B (optional: adds B's depth)")
    ap.add_argument("--calib", type=Path, required=True, help="stereo calibration YAML, as rvs-stereo's")
    ap.add_argument("-o", "--output", type=Path, help="write the motion here (YAML)")
    ap.add_argument("--detector", choices=("shi-tomasi", "harris"), default="shi-tomasi")
    ap.add_argument("--max-points", type=int, default=None, help="interest points in A (default 1200)")
    ap.add_argument("-q", "--quiet", action="store_true")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    params: dict[str, Any] = {"detector": args.detector}
    if args.max_points is not None:
        params["max_points"] = args.max_points
    try:
        motion = stereo_odometry_files(args.left_a, args.right_a, args.left_b, args.right_b, args.calib, params)
    except OdometryError as exc:
        print(f"rvs-odometry: no motion: {exc} ({exc.points} interest points, {exc.matches} tracked, "
              f"{exc.inliers} agreeing); the images need overlapping textured ground: take B closer to A "
              "(a shorter step) or check that both are of the same scene", file=sys.stderr)
        return 3
    except (OSError, ValueError) as exc:
        print(f"rvs-odometry: {exc}", file=sys.stderr)
        return 2
    if args.output is not None:
        write_yaml_atomic(args.output, motion)
    if not args.quiet:
        shown = {k: motion[k] for k in ("tx", "ty", "tz", "rx", "ry", "rz", "inliers")}
        print(yaml.safe_dump(shown, sort_keys=False).rstrip())
        if args.output is not None:
            print(f"written {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
