"""``rvs-calib``: the calibration tools (seed 000 sect. 3.1.8, seed 004 sect. 2.2).

Verbs:

* ``control-points POINTS.csv|yaml --image-size W H -o CAMERA.cal``: the 3 x 4 camera
  calibration matrix from 3D control points and their image positions (linear DLT, then
  non-linear refinement of the reprojection error), decomposed into K, R, t, with the RMS.
  CSV columns x y z u v (a header naming them, an extra ``id``/``name`` column, or five bare
  numeric columns); YAML either ``{world: [[x,y,z]...], image: [[u,v]...]}`` or a list of
  ``{world: [x,y,z], image: [u,v]}``. Writes the ``.cal`` of prox_workflows.algorithms.transforms.
* ``stereo (DIR | --left L... --right R...) --pattern 8x6 --square 0.05 -o CALIB.yaml``:
  intrinsics and stereo extrinsics from checkerboard pairs, with the RMS. In DIR, a file whose
  name contains ``left`` pairs with the one where ``left`` reads ``right``.
* ``tof-stereo DIR --calib CALIB.yaml --pattern 6x4 -o TOF_LEFT.yaml``: ToF-to-left-camera
  extrinsics. Per board pose, DIR holds ``<stem>_left.*``, ``<stem>_right.*``, ``<stem>_xyz.*``
  (the ToF coordinate image, H x W x 3, as grab-tof -type xyz writes it) and
  ``<stem>_amplitude.*`` (the raw amplitude, same geometry).
* ``sim-truth -o CALIB.yaml [--scene office] [--resolution high] [--tof TOF_LEFT.yaml]``: the
  simulator's true stereo calibration (and ToF -> left transform) in the same formats. A tool
  for tests and demos: it imports ``drivers`` lazily, inside the verb only.

``--pattern`` counts inner corners: (corners per row)x(rows), e.g. 8x6 for a board of 9 x 7
squares. YAML outputs carry their provenance (made_by, time, inputs) inside.
"""

from __future__ import annotations

import argparse
import csv
import re
import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from rvs_params.cli import ToolParser

from ..algorithms.calibration import (
    TofStereoView,
    calibrate_control_points,
    calibrate_stereo_checkerboard,
    calibrate_tof_stereo,
)
from ..algorithms.stereo import load_calibration, save_calibration
from ..algorithms.transforms import write_cal
from ..products import write_yaml_atomic
from .stereo import read_image

IMAGE_EXT = (".tif", ".tiff", ".png", ".pgm", ".ppm", ".bmp", ".jpg", ".jpeg", ".npy")


def _provenance(verb: str, inputs: list[str], **parameters: Any) -> dict[str, Any]:
    return {
        "made_by": f"rvs-calib {verb} (prox_workflows.algorithms.calibration)",
        "time": datetime.now(UTC).isoformat(timespec="seconds"),
        "inputs": inputs,
        "parameters": parameters,
    }


def _pattern(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*[xX,]\s*(\d+)\s*", text)
    if not m:
        raise argparse.ArgumentTypeError(f"pattern {text!r}: write inner corners as COLSxROWS, e.g. 8x6")
    nx, ny = int(m.group(1)), int(m.group(2))
    if nx < 2 or ny < 2:
        raise argparse.ArgumentTypeError("a pattern needs at least 2x2 inner corners")
    return nx, ny


# -- control points ---------------------------------------------------------------------------------
def read_control_points(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(N x 3 world, N x 2 image) from CSV or YAML (see the module docstring)."""
    text = Path(path).read_text()
    if Path(path).suffix.lower() in (".yaml", ".yml"):
        doc = yaml.safe_load(text)
        if isinstance(doc, dict) and "points" in doc:
            doc = doc["points"]
        if isinstance(doc, dict):
            world, image = doc.get("world"), doc.get("image")
        elif isinstance(doc, list):
            world = [p["world"] for p in doc]
            image = [p["image"] for p in doc]
        else:
            world = image = None
        if world is None or image is None:
            raise ValueError(f"{path}: expected 'world' and 'image' point lists")
        return np.asarray(world, float).reshape(-1, 3), np.asarray(image, float).reshape(-1, 2)
    rows = [r for r in csv.reader(line for line in text.splitlines() if line.strip() and not line.startswith("#"))]
    if not rows:
        raise ValueError(f"{path}: no control points")
    header = [c.strip().lower() for c in rows[0]]
    if {"x", "y", "z", "u", "v"} <= set(header):
        cols = [header.index(k) for k in ("x", "y", "z", "u", "v")]
        data = rows[1:]
    else:
        cols = None
        data = rows
    table = []
    for i, r in enumerate(data):
        try:
            if cols is not None:
                table.append([float(r[c]) for c in cols])
            else:
                nums = [float(c) for c in r[-5:]]
                if len(nums) != 5:
                    raise ValueError
                table.append(nums)
        except (ValueError, IndexError):
            raise ValueError(f"{path}: line {i + 1 + (cols is not None)}: expected x, y, z, u, v numbers") from None
    arr = np.asarray(table, float)
    return arr[:, :3], arr[:, 3:5]


def cmd_control_points(args: argparse.Namespace) -> int:
    world, image = read_control_points(args.points)
    if args.image is not None:
        img = read_image(args.image)
        size = (int(img.shape[1]), int(img.shape[0]))
    elif args.image_size is not None:
        size = (int(args.image_size[0]), int(args.image_size[1]))
    else:
        raise ValueError("give the image size: --image-size W H or --image FILE")
    result = calibrate_control_points(world, image, refine=not args.no_refine, zero_skew=args.zero_skew,
                                      loss="soft_l1" if args.robust else "linear")
    prov = _provenance("control-points", [str(args.points)], refine=not args.no_refine, zero_skew=args.zero_skew,
                       robust=args.robust)
    write_cal(args.output, result.K, result.T_global_camera, size,
              rms_px=round(result.rms, 6), rms_linear_px=round(result.rms_linear, 6), n_points=result.n_points,
              residuals_px=[round(float(r), 6) for r in result.residuals], R=result.R.round(12).tolist(),
              t=result.t.round(12).tolist(), **prov)
    if not args.quiet:
        np.set_printoptions(precision=6, suppress=True)
        print(f"{result.n_points} control points; reprojection RMS {result.rms:.4f} px "
              f"(linear DLT {result.rms_linear:.4f} px), worst {result.residuals.max():.4f} px")
        print(f"P =\n{result.P}\nK =\n{result.K}\nR =\n{result.R}\nt = {result.t}")
        print(f"camera centre (world) = {result.centre}")
        print(f"-> {args.output}")
    return 0


# -- stereo checkerboard ----------------------------------------------------------------------------
def _images_in(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXT)


def find_pairs(folder: Path) -> list[tuple[Path, Path]]:
    files = _images_in(folder)
    names = {p.name: p for p in files}
    pairs = []
    for p in files:
        if "left" in p.name:
            partner = names.get(p.name.replace("left", "right"))
            if partner is not None:
                pairs.append((p, partner))
    return pairs


def cmd_stereo(args: argparse.Namespace) -> int:
    if args.folder is not None:
        paths = find_pairs(args.folder)
        if not paths:
            raise ValueError(f"{args.folder}: no left/right image pairs (files named ...left... and ...right...)")
    else:
        if not args.left or len(args.left) != len(args.right or []):
            raise ValueError("give a folder, or as many --right images as --left images")
        paths = list(zip(args.left, args.right, strict=True))
    pairs = [(read_image(a), read_image(b)) for a, b in paths]

    def progress(i: int, n: int) -> None:
        if not args.quiet:
            print(f"\rcorners: {i}/{n}", end="" if i < n else "\n", flush=True)

    res = calibrate_stereo_checkerboard(pairs, args.pattern, args.square, fix_k3=not args.free_k3,
                                        progress=progress)
    prov = _provenance("stereo", [str(p) for pair in paths for p in pair], pattern=list(args.pattern),
                       square=args.square, fix_k3=not args.free_k3)
    save_calibration(args.output, res.calib, rms_px=round(res.rms, 6), rms_left_px=round(res.rms_left, 6),
                     rms_right_px=round(res.rms_right, 6), pairs_used=res.n_pairs, pairs_given=len(pairs),
                     per_pair_rms_px={paths[i][0].name: round(r, 6) for i, r in zip(res.used, res.per_view_rms,
                                                                                       strict=True)},
                     **prov)
    if not args.quiet:
        np.set_printoptions(precision=6, suppress=True)
        cal = res.calib
        print(f"board found in {res.n_pairs} of {len(pairs)} pairs; stereo RMS {res.rms:.4f} px "
              f"(left {res.rms_left:.4f}, right {res.rms_right:.4f})")
        print(f"baseline {cal.baseline:.5f} m, T = {cal.T}")
        print(f"K1 =\n{cal.K1}\nD1 = {cal.D1}\nK2 =\n{cal.K2}\nD2 = {cal.D2}\nR =\n{cal.R}")
        print(f"-> {args.output}")
    return 0


# -- ToF to stereo ----------------------------------------------------------------------------------
def find_tof_views(folder: Path) -> list[tuple[str, dict[str, Path]]]:
    """Group ``<stem>_{left,right,xyz,amplitude}.*`` files by stem (complete groups only)."""
    groups: dict[str, dict[str, Path]] = {}
    for p in _images_in(folder):
        m = re.fullmatch(r"(.*)_(left|right|xyz|amplitude)", p.stem)
        if m:
            groups.setdefault(m.group(1), {})[m.group(2)] = p
    return [(stem, g) for stem, g in sorted(groups.items()) if len(g) == 4]


def cmd_tof_stereo(args: argparse.Namespace) -> int:
    groups = find_tof_views(args.folder)
    if not groups:
        raise ValueError(f"{args.folder}: no complete view (<stem>_left, _right, _xyz, _amplitude files)")
    views = []
    for stem, g in groups:
        xyz = read_image(g["xyz"]).astype(np.float32)
        if xyz.ndim != 3 or xyz.shape[2] != 3:
            raise ValueError(f"{g['xyz']}: expected an H x W x 3 coordinate image, got shape {xyz.shape}")
        amp = read_image(g["amplitude"]).astype(np.float32)
        if amp.shape[:2] != xyz.shape[:2]:
            raise ValueError(f"{g['amplitude']}: size {amp.shape[:2]} differs from the XYZ image's {xyz.shape[:2]}")
        views.append(TofStereoView(xyz, amp, read_image(g["left"]), read_image(g["right"]), stem))
    stereo = load_calibration(args.calib)
    res = calibrate_tof_stereo(views, stereo, args.pattern, upscale=args.upscale, border=args.border,
                               lift=args.lift, threshold=args.threshold)
    stats = res.stats()
    T = res.T_left_tof
    inputs = [str(args.calib)] + [str(p) for _, g in groups for p in g.values()]
    data = {
        "R": T[:3, :3].round(12).tolist(),
        "T": T[:3, 3].round(12).tolist(),
        "T_left_tof": T.round(12).tolist(),
        "T_tof_left": np.linalg.inv(T).round(12).tolist(),
        "convention": "X_left = R X_tof + T (metres; OpenCV optical frames)",
        "residuals": stats,
        **_provenance("tof-stereo", inputs, pattern=list(args.pattern), upscale=args.upscale, border=args.border,
                      lift=args.lift, threshold_m=args.threshold),
    }
    write_yaml_atomic(args.output, data)
    if not args.quiet:
        np.set_printoptions(precision=6, suppress=True)
        print(f"{len(stats['views_used'])} of {len(views)} views used; {stats['inliers']} of {stats['points']} corners "
              f"inliers; residual RMS {stats['rms_m'] * 1000:.2f} mm, median {stats['median_m'] * 1000:.2f} mm, "
              f"p95 {stats['p95_m'] * 1000:.2f} mm")
        for name, why in stats["views_rejected"].items():
            print(f"  {name}: {why}")
        print(f"T_left_tof =\n{T}")
        print(f"-> {args.output}")
    return 0


# -- simulator truth --------------------------------------------------------------------------------
def cmd_sim_truth(args: argparse.Namespace) -> int:
    # A tool verb: drivers is imported here only, so prox_workflows itself never depends on it.
    import drivers.stereo as stereo_drv
    from drivers.sim.world import World

    world = World.from_scene(args.scene)
    cam = stereo_drv.create({"backend": "sim", "resolution": args.resolution}, world, None)
    cam.open()
    try:
        truth = cam.calibration(args.resolution)
    finally:
        cam.close()
    save_calibration(args.output, truth, source="simulated world (ground truth)", scene=args.scene,
                     resolution=args.resolution)
    lines = [f"true stereo calibration ({args.scene}, {args.resolution}) -> {args.output}"]
    if args.tof is not None:
        T = np.linalg.inv(world.head.mounts["left"]) @ world.head.mounts["tof"]
        write_yaml_atomic(args.tof, {
            "R": T[:3, :3].round(12).tolist(), "T": T[:3, 3].round(12).tolist(), "T_left_tof": T.round(12).tolist(),
            "T_tof_left": np.linalg.inv(T).round(12).tolist(),
            "convention": "X_left = R X_tof + T (metres; OpenCV optical frames)",
            "source": "simulated world (ground truth)", "scene": args.scene,
        })
        lines.append(f"true ToF -> left transform -> {args.tof}")
    if not args.quiet:
        print("\n".join(lines))
    return 0


# -- parser -------------------------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    ap = ToolParser(prog="rvs-calib", description="Camera, stereo and ToF-to-stereo calibration.")
    sub = ap.add_subparsers(dest="verb", required=True, metavar="VERB")

    cp = sub.add_parser("control-points", help="camera calibration matrix from 3D-2D control points (DLT + refinement)")
    cp.add_argument("points", type=Path, help="CSV (x,y,z,u,v) or YAML (world/image lists)")
    cp.add_argument("-o", "--output", type=Path, required=True, help="the .cal file to write")
    cp.add_argument("--image-size", type=int, nargs=2, metavar=("W", "H"))
    cp.add_argument("--image", type=Path, help="the calibration image (for its size)")
    cp.add_argument("--no-refine", action="store_true", help="stop after the linear DLT")
    cp.add_argument("--zero-skew", action="store_true", help="force K's skew to 0 in the refinement")
    cp.add_argument("--robust", action="store_true", help="soft-L1 loss against a few wrong points")
    cp.set_defaults(func=cmd_control_points)

    st = sub.add_parser("stereo", help="stereo intrinsics and extrinsics from checkerboard pairs")
    st.add_argument("folder", type=Path, nargs="?", help="folder with ...left... / ...right... image pairs")
    st.add_argument("--left", type=Path, nargs="+", help="left images (instead of a folder)")
    st.add_argument("--right", type=Path, nargs="+", help="right images, in the same order")
    st.add_argument("--pattern", type=_pattern, required=True, help="inner corners COLSxROWS, e.g. 8x6")
    st.add_argument("--square", type=float, required=True, help="square side in metres")
    st.add_argument("--free-k3", action="store_true", help="estimate the k3 radial term too")
    st.add_argument("-o", "--output", type=Path, required=True, help="CALIB.yaml to write")
    st.set_defaults(func=cmd_stereo)

    ts = sub.add_parser("tof-stereo", help="ToF -> left camera extrinsics (Horn/Umeyama in RANSAC)")
    ts.add_argument("folder", type=Path, help="folder with <stem>_left/_right/_xyz/_amplitude files per board pose")
    ts.add_argument("--calib", type=Path, required=True, help="the stereo CALIB.yaml")
    ts.add_argument("--pattern", type=_pattern, required=True, help="inner corners COLSxROWS")
    ts.add_argument("--lift", choices=("interp", "plane"), default="interp",
                    help="ToF corners to 3D: XYZ interpolated at the corner, or ray cut with the board plane")
    ts.add_argument("--border", type=int, default=0, help="drop this many outer rings of corners")
    ts.add_argument("--upscale", type=int, default=2, help="enlarge the ToF amplitude image before the search")
    ts.add_argument("--threshold", type=float, default=0.03, help="RANSAC inlier distance (m)")
    ts.add_argument("-o", "--output", type=Path, required=True, help="YAML with R, T (ToF -> left) and residuals")
    ts.set_defaults(func=cmd_tof_stereo)

    sim = sub.add_parser("sim-truth", help="write the simulator's true calibration (needs drivers.sim)")
    sim.add_argument("-o", "--output", type=Path, required=True, help="CALIB.yaml to write")
    sim.add_argument("--scene", default="office")
    sim.add_argument("--resolution", default="high", help="the stereo pair's resolution mode (the driver's)")
    sim.add_argument("--tof", type=Path, help="also write the true ToF -> left transform here")
    sim.set_defaults(func=cmd_sim_truth)

    for p in (cp, st, ts, sim):
        p.add_argument("-q", "--quiet", action="store_true")
    return ap


def main(argv: list[str] | None = None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    try:
        return int(args.func(args))
    except (OSError, ValueError) as exc:
        print(f"rvs-calib {args.verb}: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
