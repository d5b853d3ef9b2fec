"""Benchmark: the stereo step (prox_workflows.steps.stereo) on a 1920 x 1080 simulated PIKE pair,
side by side in one run with OpenCV's block matcher StereoBM at matching settings (the peer:
same rectified mono8 pair, same numDisparities, block size and uniqueness, its own speckle
filter at the same window and range).

Both are scored against the disparity the simulator renders for the rectified left camera
(f b / z): the share of valid pixels more than 2 px off, the share within 0.5 px, and the
coverage (valid pixels with a true disparity / pixels with one). The target is at most 2 s
per pair on this 2-core machine; the pipeline runs at full resolution and at half scale
(matching a 960 x 540 pair, disparity scaled back up).

    python -m tools.bench.stereo [--scene quarry] [--tilt -20] [--repeat 3] [--cache /tmp/pair.npz]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from prox_workflows.steps import stereo as st


def simulated_pair(scene: str, tilt: float, cache: Path | None) -> dict[str, Any]:
    """Left, right (mono8, as the sim driver takes them), the true calibration and the true
    rectified disparity; rendered once, optionally cached in an .npz."""
    if cache is not None and cache.exists():
        data = dict(np.load(cache))
        calib = {k: data[k] for k in ("image_size", "K1", "D1", "K2", "D2", "R", "T")}
        return {"left": data["left"], "right": data["right"], "calib": calib, "true": data["true"]}
    from drivers.sim.transforms import make_T
    from drivers.sim.world import World
    from drivers.stereo import create

    world = World.from_scene(scene)
    world.set_ptu(0.0, tilt)
    cam = create({"backend": "sim", "resolution": "highest", "pixel_format": "mono8", "seed": 1}, world, None)
    cam.open()
    try:
        left, right = cam.grab_stereo_direct()
        cal = cam.calibration()
    finally:
        cam.close()
    calib = {k: np.asarray(cal[k]) for k in ("image_size", "K1", "D1", "K2", "D2", "R", "T")}
    rect = st.rectification(calib)
    w, h = rect.size
    render = world.render(np.asarray(rect.P1)[:, :3], w, h, world.sensor_pose("left") @ make_T(np.asarray(rect.R1).T))
    with np.errstate(divide="ignore", invalid="ignore"):
        true = (rect.focal * rect.baseline / render.depth).astype(np.float32)
    if cache is not None:
        np.savez_compressed(cache, left=left, right=right, true=true, **calib)
    return {"left": left, "right": right, "calib": calib, "true": true}


def score(disp: np.ndarray, true: np.ndarray) -> dict[str, float]:
    has = np.isfinite(true)
    ok = has & np.isfinite(disp)
    err = np.abs(disp[ok] - true[ok])
    return {
        "coverage": float(ok.sum() / max(has.sum(), 1)),
        "bad2": float((err > 2.0).mean()) if err.size else float("nan"),
        "within05": float((err <= 0.5).mean()) if err.size else float("nan"),
    }


def timed(fn: Any, repeat: int) -> tuple[Any, float]:
    times = []
    out = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return out, statistics.median(times)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tools.bench.stereo", description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="quarry")
    ap.add_argument("--tilt", type=float, default=-20.0, help="PTU tilt in degrees (negative looks down)")
    ap.add_argument("--repeat", type=int, default=3, help="timed runs per method (median reported)")
    ap.add_argument("--cache", type=Path, help="save/load the rendered pair here (.npz)")
    args = ap.parse_args(argv)

    t0 = time.perf_counter()
    pair = simulated_pair(args.scene, args.tilt, args.cache)
    print(f"pair: {args.scene}, tilt {args.tilt:g} deg, {pair['left'].shape[1]}x{pair['left'].shape[0]} mono8 "
          f"(rendered/loaded in {time.perf_counter() - t0:.1f} s); OpenCV {cv2.__version__}, "
          f"{cv2.getNumThreads()} threads")
    left, right, calib, true = pair["left"], pair["right"], pair["calib"], pair["true"]
    st.rectification(calib)  # maps are built once per calibration; not part of a pair's cost
    params = st.SgbmParams()
    rect = st.rectification(calib)
    nd = params.disparities_for(rect)
    bs = params.block_size
    rows: list[tuple[str, float, dict[str, float]]] = []

    full, t_full = timed(lambda: st.disparity(left, right, calib, params), args.repeat)
    rows.append((f"rvs SGBM 3-way + LR + speckle + texture, full ({nd} disp, block {bs})", t_full,
                 score(full.rectified, true)))
    half_p = st.SgbmParams(scale=0.5)
    half, t_half = timed(lambda: st.disparity(left, right, calib, half_p), args.repeat)
    rows.append((f"rvs SGBM, half scale ({half_p.disparities_for(rect)} disp at 960x540, x2)", t_half,
                 score(half.rectified, true)))
    no_lr = st.SgbmParams(lr_max_diff=0.0)
    plain, t_plain = timed(lambda: st.disparity(left, right, calib, no_lr), args.repeat)
    rows.append(("rvs SGBM without the LR check (one matcher run)", t_plain, score(plain.rectified, true)))

    def bm() -> np.ndarray:
        rl, rr = st.rectify_pair(left, right, rect)
        matcher = cv2.StereoBM_create(numDisparities=nd, blockSize=bs)
        matcher.setUniquenessRatio(params.uniqueness)
        matcher.setSpeckleWindowSize(params.speckle_window)
        matcher.setSpeckleRange(int(round(params.speckle_range * 16)))
        d = matcher.compute(rl, rr).astype(np.float32) / 16.0
        d[d < 0] = np.nan  # BM marks invalid pixels (minDisparity - 1)
        return d

    bm_disp, t_bm = timed(bm, args.repeat)
    rows.append((f"peer: OpenCV StereoBM (rectify + match; {nd} disp, block {bs})", t_bm, score(bm_disp, true)))

    print(f"{'method':<66} {'s/pair':>7} {'cover':>6} {'>2px':>7} {'<=0.5px':>8}")
    for name, t, s in rows:
        print(f"{name:<66} {t:7.3f} {s['coverage']:6.1%} {s['bad2']:7.2%} {s['within05']:8.1%}")
    print(f"ratio full-scale pipeline / StereoBM time: {t_full / t_bm:.2f}; half-scale / StereoBM: {t_half / t_bm:.2f}")
    print("stages (full scale, last run): " + ", ".join(f"{k} {v:.3f}" for k, v in full.timings.items()))
    verdict = "meets" if t_full <= 2.0 else "misses"
    print(f"target <= 2 s per pair: full scale {verdict} it ({t_full:.2f} s); half scale {t_half:.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
