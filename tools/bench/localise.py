"""Pose error at the end of seeded slipping missions: dead reckoning, VO, map matching, both.

Each mission is a real server (the tests' in-process ServerThread, simulated time at scale 0)
on the ``hirise`` scene (the HiRISE DTM with rocks), wheel slip 5 % and heading drift 2 deg/m
(``sim slip``), no GNC pose (``navigate -auto``), the orbital DTM as the global map (written by
``tools.global_maps``). For every mission and ``-localise`` mode it prints the believed and true
end pose, the pose error and the true distance to the goal; then the map matcher's time per
match over the missions.

    python -m tools.bench.localise [--seeds 1 2 3] [--goal 6,2] [--modes none vo map both]
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

ROOT = Path(__file__).resolve().parents[2]


def run_mission(srv: Any, goal: tuple[float, float], mode: str, seed: int, global_dir: Path,
                slip: tuple[float, float] = (0.05, 2.0), tolerance: float = 0.3) -> dict[str, Any]:
    """One navigate -auto mission from the start pose; the end pose, the truth and the fixes."""
    c = srv.client(timeout=1200)
    try:
        r = c.request(f"sim slip -distance {slip[0]} -heading {slip[1]} -seed {seed}")
        assert r.status == "OK", r
        t0 = time.perf_counter()
        line = (f"navigate -goal {goal[0]},{goal[1]} -start 0,0,0 -auto -localise {mode} -tolerance {tolerance} "
                f"-name m{seed}_{mode}")
        c.send(line)
        lines = c.until_final(timeout=1800)
        wall = time.perf_counter() - t0
        final = lines[-1]
        fixes = [r for r in lines if r.status == "EVENT" and r.fields.get("kind") == "localised"]
        truth = c.request("sim truth").fields
        status = c.request("status").fields
    finally:
        c.close()
    px, py, ph = (float(v) for v in status["pose"].split(","))
    tx, ty, th = float(truth["x"]), float(truth["y"]), float(truth["heading"])
    return {"mode": mode, "seed": seed, "ok": final.status == "OK", "message": final.fields.get("message", ""),
            "legs": final.fields.get("legs", "-"), "pose_error": math.hypot(px - tx, py - ty),
            "heading_error": (ph - th + 180.0) % 360.0 - 180.0, "goal_true": math.hypot(goal[0] - tx, goal[1] - ty),
            "source": status.get("pose_source"), "sigma": float(status.get("pose_sigma", "nan")), "wall": wall,
            "match_ms": [float(r.fields["match_ms"]) for r in fixes],
            "methods": [r.fields.get("method") for r in fixes],
            "taken": sum(r.fields.get("found") == "true" for r in fixes)}


def main(argv: list[str] | None = None) -> int:
    sys.path.insert(0, str(ROOT / "tests"))
    from conftest import ServerThread  # the tests' real server in a thread

    from tools.global_maps import write_global_maps

    ap = argparse.ArgumentParser(prog="python -m tools.bench.localise", description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--goal", default="6,2")
    ap.add_argument("--modes", nargs="+", default=["none", "vo", "map", "both"])
    ap.add_argument("--tolerance", type=float, default=0.3)
    args = ap.parse_args(argv)
    goal = tuple(float(v) for v in args.goal.split(","))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        global_dir = Path(tmp) / "global"
        write_global_maps("hirise", global_dir)
        for seed in args.seeds:
            for mode in args.modes:
                srv = ServerThread(Path(tmp) / f"d{seed}{mode}", ["server.scene=hirise",
                                                               f"navigate.global_maps={global_dir}"]).start()
                try:
                    row = run_mission(srv, goal, mode, seed, global_dir, tolerance=args.tolerance)
                finally:
                    srv.stop()
                rows.append(row)
                print(f"seed {seed} {mode:>4}: {'OK ' if row['ok'] else 'ERR'} legs {row['legs']} pose error "
                      f"{row['pose_error']:.3f} m ({row['heading_error']:+.2f} deg), true distance to goal "
                      f"{row['goal_true']:.3f} m, source {row['source']} sigma {row['sigma']:.3f}, fixes "
                      f"{row['taken']}/{len(row['match_ms'])}, {row['wall']:.0f} s wall {row['message']}",
                      flush=True)
    print()
    print(f"goal {goal}, slip 5 % / 2 deg per m, tolerance {args.tolerance} m, seeds {args.seeds}")
    print(f"{'localise':>9} {'pose err mean':>14} {'max':>7} {'goal dist mean':>15} {'max':>7} "
          f"{'within tol':>10} {'match ms (median)':>18}")
    for mode in args.modes:
        rs = [r for r in rows if r["mode"] == mode]
        ms = [m for r in rs for m in r["match_ms"]]
        within = sum(r["ok"] and r["goal_true"] <= args.tolerance for r in rs)
        print(f"{mode:>9} {statistics.mean(r['pose_error'] for r in rs):>14.3f} "
              f"{max(r['pose_error'] for r in rs):>7.3f} {statistics.mean(r['goal_true'] for r in rs):>15.3f} "
              f"{max(r['goal_true'] for r in rs):>7.3f} {within:>7}/{len(rs):<2} "
              f"{(statistics.median(ms) if ms else float('nan')):>18.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
