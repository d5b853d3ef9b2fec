"""Benchmark: the body hazard cameras' stereo, measured where drivers.hazcam declares it.

**Disparity noise** (what ``drivers.hazcam.sigma_d`` declares): the simulated pairs' matched
disparity (the server's matcher, ``rvs_server.devices.stereo_points``'s ``disparity`` with the
hazcams' settings) against the disparity of the renderer's true depth for the left camera
(f b / z: the pairs are ideal, rectification is the identity), over the matched pixels within
``max_range``, front and rear pairs at three rover poses per scene; and the same matcher
settings on the real Middlebury 2014 Motorcycle pair (quarter size, scikit-image's copy with its
ground truth; the Bicycle1 pair in ../shared/realdata has none) against its true disparity.
Columns: matched pixels, mean error (bias), rms, robust sigma (1.4826 x the median absolute
deviation), rms of the matches within 2 px of the truth (the Gaussian core), shares more than
1 and 2 px off.

**Grab time**: ``Hazcam.grab`` on the simulated world, median over ``--grabs`` grabs per pair at
each ``--sizes``: the capture (the simulator's render of both cameras and their image
formation; a real camera renders nothing) and the matching (disparity, points, rover frame).

**The start's ring** (``--ring``): at the first ``--missions`` starts of the navigate bench's
draws per scene, facing the goal, both pairs grabbed at the headings of the see loop's start turn
(``navigate.see_start_turn``: 0, 60 and 120 deg) and fused into a bounds map as the see loop
fuses them (``--sensor stereo``; ``tof``: as independent returns). Of the ring between the body
(its rectangle, wheels included, at the last heading) and the mast's blind disc (its radius plus
the edge the mast's rays graze, round the pan axis's foot): the cells a pair bounded, those past
the disc the body turns in, and against the true surface (0.5 cm samples pooled per 2.5 cm
cell): the true top over the upper bound, the true bottom under the lower, and the cell mean's
error in its own sigmas.

**A pair fused** (``--fuse``): the front pair's frame at each of the first ``--missions`` starts
per scene, fused into a bounds map the size of the see loop's window as the see loop fuses it,
by the compiled per-cell sums and by the numpy reduction (``tools.bench.choice.reference``)
alternately in one process, ``--grabs`` times each: the median of each and their ratio, beside
the real Motorcycle pair's cloud (the bounds bench's ``motorcycle_cloud``) fused both ways.

    python -m tools.bench.hazcam                     # marsyard hirise dense, the declared size
    python -m tools.bench.hazcam --sizes 640x480 480x360 320x240 --grabs 5
    python -m tools.bench.hazcam --ring --missions 4 [--sensor tof]
    python -m tools.bench.hazcam --fuse --missions 3 --grabs 7
"""

from __future__ import annotations

import argparse
import contextlib
import time
from typing import Any

import cv2
import numpy as np

import drivers.hazcam as hazcam
from drivers.sim.world import World
from prox_workflows.algorithms import stereo as st
from rvs_server.devices import stereo_points

POSES = ((0.0, 0.0, 0.0), (1.0, 0.5, 30.0), (2.0, -0.5, -60.0))  # x, y, heading: rover poses per scene
MOTORCYCLE_ND = 80  # Middlebury's ndisp 270 at full size, quarter size, SGBM's multiple of 16


def stats(name: str, err: np.ndarray) -> dict[str, Any]:
    core = np.abs(err) < 2.0
    return {"pair": name, "n": int(err.size), "mean": float(err.mean()), "rms": float(np.sqrt(np.mean(err**2))),
            "robust": float(1.4826 * np.median(np.abs(err - np.median(err)))),
            "core": float(np.sqrt(np.mean(err[core] ** 2))), "over1": float(np.mean(np.abs(err) > 1.0)),
            "over2": float(np.mean(np.abs(err) > 2.0))}


def sim_errors(scene: str, settings: dict[str, Any]) -> np.ndarray:
    """Matched minus true disparity (px) of every matched pixel within max_range, both pairs, all poses."""
    world = World.from_scene(scene, seed=1)
    dev = hazcam.create({**settings, "cameras": "front,rear"}, world)
    dev.open()
    cfg = dev.config
    errs = []
    for pose in POSES:
        world.set_rover_pose(*pose)
        for camera in dev.cameras():
            rig = dev.rig(camera)
            left, right = dev.images(camera)
            disp = st.disparity(left, right, rig.calibration, {"min_depth": cfg.min_range}).measured
            truth = world.render(rig.K, *rig.size, world.T_world_rover() @ rig.T_rover_left)
            true_d = rig.focal * rig.baseline / truth.depth
            ok = np.isfinite(disp) & np.isfinite(true_d) & (truth.range <= cfg.max_range) & (truth.object_id != 1)
            errs.append(disp[ok] - true_d[ok])
    return np.concatenate(errs)


def motorcycle_errors() -> np.ndarray | None:
    try:
        from skimage.data import stereo_motorcycle

        left, right, truth = stereo_motorcycle()
    except Exception as exc:  # the test extra (scikit-image) absent or its data missing
        print(f"Motorcycle skipped: {exc}")
        return None
    gl, gr = (cv2.cvtColor(a, cv2.COLOR_RGB2GRAY) for a in (left, right))
    disp = st.disparity_rectified(gl, gr, st.SgbmParams(), MOTORCYCLE_ND)
    truth = truth.astype(np.float32)
    ok = np.isfinite(disp) & np.isfinite(truth) & (truth > 0)
    return disp[ok] - truth[ok]


def grab_times(size: tuple[int, int], grabs: int, scene: str) -> dict[str, Any]:
    world = World.from_scene(scene, seed=1)
    dev = hazcam.create({"cameras": "front,rear", "size": list(size)}, world, stereo_points)
    dev.open()
    capture, match, points = [], [], []
    dev.grab("front")  # the first grab builds the rectification maps
    for i in range(grabs):
        for camera in dev.cameras():
            world.set_rover_pose(0.1 * i, 0.0, 0.0)
            t0 = time.perf_counter()
            frame = dev.grab(camera)
            total = time.perf_counter() - t0
            last = dev.status()["last_grab"]
            capture.append(last["capture_ms"])
            match.append(1000 * total - last["capture_ms"])
            points.append(len(frame.points))
    return {"size": f"{size[0]}x{size[1]}", "grabs": len(capture), "capture_ms": float(np.median(capture)),
            "match_ms": float(np.median(match)), "match_p90": float(np.percentile(match, 90)),
            "points": int(np.median(points))}


def ring(scene: str, missions: int, sensor: str) -> dict[str, Any]:
    """The start's ring seen by both pairs over a start turn, against the truth (see the module)."""
    from drivers.ptu.protocol import D46_LIMITS, D46_RESOLUTION_ARCSEC, pos_to_deg
    from drivers.tof.constants import FOV_H_DEG, FOV_V_DEG
    from prox_workflows.algorithms.bounds_map import BoundsMap
    from prox_workflows.algorithms.looks import BODY_MARGIN, View, blind_radius, on_body
    from prox_workflows.algorithms.noise import pair_sigmas
    from prox_workflows.algorithms.transforms import HeadCalibration
    from rvs_server.navigation.config import SeeConfig
    from rvs_server.navigation.see import BLIND_EDGE
    from rvs_truth.surface import missions as draws

    world = World.from_scene(scene)
    dev = hazcam.create({"cameras": "front,rear"}, world, stereo_points)
    dev.open()
    body, head = world.body, HeadCalibration()
    lowest = pos_to_deg(D46_LIMITS["tilt"][0], D46_RESOLUTION_ARCSEC)
    radius = blind_radius(head, View(FOV_H_DEG, FOV_V_DEG, lowest, 150.0)) + BLIND_EDGE
    step = SeeConfig().start_turn
    turns = step * np.arange(int(np.ceil(360.0 / (2 * step) - 1e-9)))
    spin = float(np.hypot(body.length, body.width) / 2 + 0.05)  # the disc the body turns in (see.py's radius)
    out = {"scene": scene, "sensor": sensor, "ring": 0, "seen": 0, "outer": 0, "outer_seen": 0, "over": 0,
           "under": 0}
    z = []
    for (x0, y0), goal in draws(scene, missions):
        h0 = float(np.degrees(np.arctan2(goal[1] - y0, goal[0] - x0)))
        bm = BoundsMap.covering([(x0, y0)], 1.5)
        for turn in turns:
            world.set_rover_pose(x0, y0, h0 + turn)
            T = world.T_world_rover()
            for camera in dev.cameras():
                frame = dev.grab(camera)
                ground = ~on_body(frame.points, body, BODY_MARGIN)
                pts = frame.points[ground] @ T[:3, :3].T + T[:3, 3]
                origin = T[:3, :3] @ frame.origin + T[:3, 3]
                sigma, sigma_xy = pair_sigmas(pts, origin, frame.sigma_range[ground], dev.rig(camera).focal)
                bm.fuse(pts, sigma, origin, dev.config.max_range, sigma_xy, sensor=sensor)
        g = bm.geometry
        xs, ys = g.centers()
        X, Y = np.meshgrid(xs - x0, ys - y0)
        h = np.radians(h0 + turns[-1])
        local = np.column_stack([(X * np.cos(h) + Y * np.sin(h)).ravel(), (-X * np.sin(h) + Y * np.cos(h)).ravel()])
        under = on_body(local, body, 0.0).reshape(X.shape)
        h = np.radians(h0)
        disc = np.hypot(X - head.ptu_base[0] * np.cos(h), Y - head.ptu_base[0] * np.sin(h)) <= radius
        inner = np.hypot(X, Y) <= spin
        rim = disc & ~under
        seen = rim & np.isfinite(bm.upper) & np.isfinite(bm.lower)
        fine = world.true_dem(g.cell / 5, g.bounds).reshape(g.height, 5, g.width, 5)
        out["ring"] += int(rim.sum())
        out["seen"] += int(seen.sum())
        out["outer"] += int((rim & ~inner).sum())
        out["outer_seen"] += int((seen & ~inner).sum())
        out["over"] += int((fine.max(axis=(1, 3))[seen] > bm.upper[seen]).sum())
        out["under"] += int((fine.min(axis=(1, 3))[seen] < bm.lower[seen]).sum())
        z.append((bm.mean[seen] - fine.mean(axis=(1, 3))[seen]) / np.sqrt(bm.mean_var[seen]))
    zs = np.concatenate(z)
    out.update(z_sd=float(np.std(zs)), z_over3=float(np.mean(np.abs(zs) > 3.0)), turns=turns.tolist())
    return out


def fuse_times(frames: list[tuple[np.ndarray, ...]], repeats: int) -> tuple[float, float, int]:
    """Median ms of fusing each of ``frames`` (points, sigma, sigma_xy, origin, max_range, map
    centre, half width) into a fresh bounds map, compiled and the numpy reduction alternately;
    and the points per frame (median)."""
    from prox_workflows.algorithms.bounds_map import BoundsMap
    from tools.bench.choice import reference

    times: dict[str, list[float]] = {"compiled": [], "numpy": []}
    for _ in range(repeats + 1):  # the first round compiles and warms
        for pts, sigma, sigma_xy, origin, cut, centre, half in frames:
            for path in ("compiled", "numpy"):
                bm = BoundsMap.around(centre, half, 0.025)
                with reference() if path == "numpy" else contextlib.nullcontext():
                    t0 = time.perf_counter()
                    bm.fuse(pts, sigma, origin, cut, sigma_xy, sensor="stereo")
                    times[path].append(1000 * (time.perf_counter() - t0))
    drop = len(frames)
    return (float(np.median(times["compiled"][drop:])), float(np.median(times["numpy"][drop:])),
            int(np.median([len(f[0]) for f in frames])))


def pair_frames(scene: str, missions: int) -> list[tuple[Any, ...]]:
    """The front pair's frame at each of ``scene``'s first ``missions`` starts, facing the goal, as
    the see loop fuses it, with the see loop's window round the rover (4 m half width)."""
    from prox_workflows.algorithms.looks import BODY_MARGIN, on_body
    from prox_workflows.algorithms.noise import pair_sigmas
    from rvs_truth.surface import missions as draws

    world = World.from_scene(scene)
    dev = hazcam.create({"cameras": "front"}, world, stereo_points)
    dev.open()
    out = []
    for (x0, y0), goal in draws(scene, missions):
        world.set_rover_pose(x0, y0, float(np.degrees(np.arctan2(goal[1] - y0, goal[0] - x0))))
        T = world.T_world_rover()
        frame = dev.grab("front")
        ground = ~on_body(frame.points, world.body, BODY_MARGIN)
        pts = frame.points[ground] @ T[:3, :3].T + T[:3, 3]
        origin = T[:3, :3] @ frame.origin + T[:3, 3]
        sigma, sigma_xy = pair_sigmas(pts, origin, frame.sigma_range[ground], dev.rig("front").focal)
        out.append((pts, sigma, sigma_xy, origin, dev.config.max_range, (x0, y0), 4.0))
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", nargs="+", default=["marsyard", "hirise", "dense"])
    ap.add_argument("--sizes", nargs="+", default=["x".join(map(str, hazcam.BACKENDS.settings().size))])
    ap.add_argument("--grabs", type=int, default=5, help="grabs per pair for the grab time")
    ap.add_argument("--ring", action="store_true", help="the start's ring seen by the pairs over a start turn")
    ap.add_argument("--missions", type=int, default=4, help="--ring: starts per scene")
    ap.add_argument("--sensor", choices=("stereo", "tof"), default="stereo",
                    help="--ring: fuse the pairs' frames as stereo (the see loop's) or as independent returns")
    ap.add_argument("--fuse", action="store_true", help="a pair's frame fused, compiled against the numpy reduction")
    args = ap.parse_args(argv)
    if args.fuse:
        from tools.bench.bounds import motorcycle_cloud

        print("| frame | points | fused ms, compiled | numpy | ratio |")
        print("|---|---|---|---|---|")
        named = [(f"{scene} front pair (sim)", pair_frames(scene, args.missions)) for scene in args.scenes]
        if (real := motorcycle_cloud()) is not None:
            pts, sigma, sigma_xy, true_pts = real
            centre = tuple(float(v) for v in np.median(true_pts[:, :2], axis=0))
            half = float(np.abs(true_pts[:, :2] - centre).max())
            named.append(("Motorcycle (real, Middlebury)", [(pts, sigma, sigma_xy, np.zeros(3), None, centre, half)]))
        for name, frames in named:
            fast, slow, n = fuse_times(frames, args.grabs)
            print(f"| {name} | {n:,} | {fast:.1f} | {slow:.1f} | {slow / fast:.2f} |")
        return
    if args.ring:
        print("| scene | fused as | headings (deg) | ring cells | seen | past the turning disc: seen | true top over "
              "upper | true bottom under lower | mean error sd (sigmas) | over 3 sigma |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for scene in args.scenes:
            r = ring(scene, args.missions, args.sensor)
            print(f"| {scene} | {r['sensor']} | {', '.join(f'{t:g}' for t in r['turns'])} | {r['ring']} | "
                  f"{100 * r['seen'] / r['ring']:.1f} % | {100 * r['outer_seen'] / r['outer']:.1f} % | "
                  f"{100 * r['over'] / r['seen']:.2f} % | {100 * r['under'] / r['seen']:.2f} % | {r['z_sd']:.2f} | "
                  f"{100 * r['z_over3']:.1f} % |")
        return
    sizes = [tuple(int(v) for v in s.lower().split("x")) for s in args.sizes]
    rows = []
    for size in sizes:
        rows += [stats(f"{scene} {size[0]}x{size[1]} (sim)", sim_errors(scene, {"size": list(size)}))
                 for scene in args.scenes]
    if (err := motorcycle_errors()) is not None:
        rows.append(stats("Motorcycle (real, Middlebury)", err))
    print("| pair | matched px | mean (px) | rms | robust sigma | rms within 2 px | > 1 px | > 2 px |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['pair']} | {r['n']} | {r['mean']:+.3f} | {r['rms']:.3f} | {r['robust']:.3f} | {r['core']:.3f} "
              f"| {100 * r['over1']:.2f} % | {100 * r['over2']:.2f} % |")
    print()
    print(f"declared drivers.hazcam.sigma_d: {hazcam.BACKENDS.settings().sigma_d} px")
    print()
    print("| size | grabs | capture ms p50 (render of both cameras) | match ms p50 / p90 | points p50 |")
    print("|---|---|---|---|---|")
    for size in sizes:
        t = grab_times(size, args.grabs, args.scenes[0])
        print(f"| {t['size']} | {t['grabs']} | {t['capture_ms']:.0f} | {t['match_ms']:.0f} / {t['match_p90']:.0f} "
              f"| {t['points']} |")


if __name__ == "__main__":
    main()
