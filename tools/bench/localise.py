"""Pose error at the end of seeded slipping missions: dead reckoning, VO, map matching, both.

Each mission is a real server (an in-process ServerThread, simulated time at scale 0)
with wheel slip 5 % and heading drift 2 deg/m (``sim slip``) and no GNC pose (``navigate
-auto``), from a start to a goal 3.5-5 m away, both clear of true hazards (the seeded pick of
rvs_truth.surface.pick_start_goal). The global map is the scene's true DEM sampled at 0.5 m (what an
orbiter's DTM would show), written as a GeoTIFF in UTM zone 33N coordinates and given to
navigate with ``-global FILE -global-origin E,N``. For every mission and ``-localise`` mode it
prints the end pose error (believed vs true) and the true distance to the goal; then a table,
with the matcher's median time per match.

    python -m tools.bench.localise [--scene quarry] [--seeds 1 2 3] [--modes none vo map both]
    python -m tools.bench.localise --matcher 20 [--tilt 0.1]   (only the matcher on HiRISE: error and time per
        match, with its tilt term and without, the patches tilted as an IMU bias of that 1-sigma would)
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from rvs_server.client.session import ServerThread, Session
from rvs_truth.orbital import ORIGIN, orbital_geotiff, rover_patch, scene_dtm
from rvs_truth.surface import missions, pick_start_goal

# the tests' server settings: simulated time and the PTU instant, no warm-up
SETS = ("drivers.ptu.time_scale=0", "sim.time_scale=0", "server.warm_up=false")


def run_mission(srv: Any, start: tuple[float, float], goal: tuple[float, float], mode: str, seed: int,
                global_file: Path, tolerance: float = 0.3, loop: str = "scan") -> dict[str, Any]:
    """One navigate -auto mission with slip; the end pose, the truth and the fixes."""
    with Session(port=srv.port) as c:
        c.connect()
        r = c.request(f"sim slip -distance 0.05 -heading 2 -seed {seed}", timeout=60)
        assert r.ok, r
        heading = math.degrees(math.atan2(goal[1] - start[1], goal[0] - start[0]))
        t0 = time.perf_counter()
        nav = c.request(f"navigate -start {start[0]:.3f},{start[1]:.3f},{heading:.1f} -goal {goal[0]:.3f},{goal[1]:.3f} "
                        f"-auto -loop {loop} -localise {mode} -tolerance {tolerance} -global {global_file} "
                        f"-global-origin {ORIGIN[0]},{ORIGIN[1]} -name m{seed}_{mode}", timeout=1800)
        wall = time.perf_counter() - t0
        final = nav.final.reply
        fixes = [line.reply for line in nav.own if line.status == "EVENT" and line.reply.fields.get("kind") == "localised"]
        truth = c.request("sim truth", timeout=60).final.reply.fields
        status = c.request("status", timeout=60).final.reply.fields
    px, py, ph = (float(v) for v in status["pose"].split(","))
    tx, ty, th = float(truth["x"]), float(truth["y"]), float(truth["heading"])
    return {"mode": mode, "seed": seed, "ok": final.status == "OK", "message": final.fields.get("message", ""),
            "legs": final.fields.get("legs", "-"), "pose_error": math.hypot(px - tx, py - ty),
            "heading_error": (ph - th + 180.0) % 360.0 - 180.0, "goal_true": math.hypot(goal[0] - tx, goal[1] - ty),
            "source": status.get("pose_source"), "sigma": float(status.get("pose_sigma", "nan")), "wall": wall,
            "match_ms": {m: [float(r.fields["match_ms"]) for r in fixes if r.fields.get("method") == m]
                         for m in ("vo", "map")},
            "fixes": len(fixes), "taken": sum(r.fields.get("found") == "true" for r in fixes)}


def matcher_timing(trials: int, tilt: float = 0.0, seed: int = 0) -> None:
    """The map matcher alone: ``trials`` 360-degree DEM patches of the hirise scene (2 cm
    heights with rocks and roughness, the ToF's 1-4.5 m ring, 30 % holes) placed up to 0.6 m and
    5 deg off, and tilted as an IMU's bias of ``tilt`` deg (1-sigma per axis) would place them,
    matched on the orbital HiRISE DTM (1.01 m cells): error and time per match, with the tilt
    term (the matcher's default) and without it, side by side on the same patches."""
    from drivers.sim.world import World
    from prox_workflows.algorithms.map_match import TILT_SIGMA, match_dem

    world = World.from_scene("hirise", clock_scale=0.0)
    dem, geom, _, _ = scene_dtm("hirise", world)
    rng, tilts = np.random.default_rng(seed), np.random.default_rng([seed, 1])
    rows: dict[str, dict[str, list[float]]] = {name: {"err": [], "yaw": [], "ms": [], "ok": []}
                                               for name in ("tilt term", "no tilt term")}
    for _ in range(trials):
        tx, ty = rng.uniform(-8.0, 8.0, 2)
        e = (float(rng.uniform(-0.6, 0.6)), float(rng.uniform(-0.6, 0.6)), float(rng.uniform(-5.0, 5.0)))
        local, lg, pivot = rover_patch(world, (float(tx), float(ty), 0.0), e, rng)
        a, b = np.tan(np.radians(tilts.normal(0.0, tilt, 2))) if tilt > 0 else (0.0, 0.0)
        xs, ys = lg.centers()
        local = local + (a * (xs[None, :] - pivot[0]) + b * (ys[:, None] - pivot[1])).astype(np.float32)
        for name, sigma in (("tilt term", TILT_SIGMA), ("no tilt term", 0.0)):
            m = match_dem(local, lg, dem, geom, pivot, tilt_sigma=sigma)
            r = rows[name]
            r["ok"].append(m.ok)
            r["err"].append(math.hypot(m.dx + e[0], m.dy + e[1]))
            r["yaw"].append(abs(m.dyaw + e[2]))
            r["ms"].append(m.seconds * 1000.0)
    q = np.percentile
    print(f"matcher on HiRISE (1.01 m cells), {trials} patches 0-0.85 m / 0-5 deg off, tilted {tilt:g} deg (1-sigma "
          "per axis):")
    for name, r in rows.items():
        print(f"  {name:>12}: ok {sum(r['ok'])}/{trials}; position error median {q(r['err'], 50):.3f} m, p90 "
              f"{q(r['err'], 90):.3f} m, max {max(r['err']):.3f} m; yaw error median {q(r['yaw'], 50):.2f} deg, p90 "
              f"{q(r['yaw'], 90):.2f} deg; time per match median {q(r['ms'], 50):.0f} ms, p90 {q(r['ms'], 90):.0f} ms")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tools.bench.localise", description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="quarry", choices=("quarry", "marsyard"))
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--modes", nargs="+", default=["none", "vo", "map", "both"])
    ap.add_argument("--tolerance", type=float, default=0.3)
    ap.add_argument("--loop", default="scan", choices=("scan", "see"), help="navigate's loop (-loop)")
    ap.add_argument("--far", action="store_true",
                    help="the traverse benchmark's seeded 15-20 m missions (tools.bench.navigate; seed n is its "
                         "mission n) instead of 3.5-5 m ones")
    ap.add_argument("--matcher", type=int, default=0, metavar="N", help="only time the matcher on N HiRISE patches")
    ap.add_argument("--tilt", type=float, default=0.0, metavar="DEG",
                    help="with --matcher: tilt each patch as an IMU bias of this 1-sigma (deg per axis) would")
    args = ap.parse_args(argv)
    if args.matcher:
        matcher_timing(args.matcher, args.tilt)
        return 0
    rows = []
    far = missions(args.scene, max(args.seeds) + 1) if args.far else []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            for mode in args.modes:
                srv = ServerThread([f"server.data={Path(tmp) / f'd{seed}{mode}'}", "server.port=0", *SETS,
                                    f"server.scene={args.scene}"], log_level="warning").start()
                try:
                    world = srv.app.world
                    world.set_target_visible(False)
                    start, goal = far[seed] if far else pick_start_goal(world, args.scene, seed)
                    orbit = orbital_geotiff(world, Path(tmp) / f"orbit{seed}{mode}.tif")
                    row = run_mission(srv, start, goal, mode, seed, orbit, args.tolerance, args.loop)
                finally:
                    srv.stop()
                rows.append(row)
                print(f"seed {seed} {mode:>4}: {'OK ' if row['ok'] else 'ERR'} legs {row['legs']} pose error "
                      f"{row['pose_error']:.3f} m ({row['heading_error']:+.2f} deg), true distance to goal "
                      f"{row['goal_true']:.3f} m, source {row['source']} sigma {row['sigma']:.3f}, fixes "
                      f"{row['taken']}/{row['fixes']}, {row['wall']:.0f} s wall {row['message']}", flush=True)
    print()
    print(f"{args.scene}, -loop {args.loop}, {'15-20' if far else '3.5-5'} m missions, slip 5 % / 2 deg per m, no "
          f"GNC pose, tolerance {args.tolerance} m, seeds {args.seeds}")
    print(f"{'localise':>9} {'pose err mean':>14} {'max':>7} {'goal dist mean':>15} {'max':>7} "
          f"{'within tol':>10} {'vo ms':>7} {'map ms':>7}")
    for mode in args.modes:
        rs = [r for r in rows if r["mode"] == mode]
        within = sum(r["ok"] and r["goal_true"] <= args.tolerance for r in rs)
        med = {m: [x for r in rs for x in r["match_ms"][m]] for m in ("vo", "map")}
        print(f"{mode:>9} {statistics.mean(r['pose_error'] for r in rs):>14.3f} "
              f"{max(r['pose_error'] for r in rs):>7.3f} {statistics.mean(r['goal_true'] for r in rs):>15.3f} "
              f"{max(r['goal_true'] for r in rs):>7.3f} {within:>7}/{len(rs):<2} "
              + " ".join(f"{statistics.median(v):>7.0f}" if v else f"{'-':>7}" for v in med.values()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
