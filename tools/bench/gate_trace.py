"""Trace the see loop's gate refusals against the truth: one ``navigate -auto -loop see``
mission of :mod:`tools.bench.navigate`'s seeded draws, with every refusal of the vehicle gate
(the first pose it would not pass, in a replan or while driving) checked again at that pose on
the simulator's true 1 cm surface (:mod:`rvs_truth.vehicle`): was it truly unsafe, and how far
did the bounds put the tilt, the belly and the wheel relief from the true values.

    python -m tools.bench.gate_trace --scene marsyard --mission 0 --out m0.json
    python -m tools.bench.gate_trace --mission 0 --set navigate.see_set_down=attitude   # the IMU's set-down
    python -m tools.bench.gate_trace --mission 0 --set navigate.see_set_down=attitude --hang 0

It hooks the see loop's own functions (the gate, the replan's gated tries, the drive's stop, the
re-judging of standing refusals), so it measures the loop as it runs; docs/NAVIGATE_BENCH.md has
what it showed.
"""

from __future__ import annotations

import argparse
import json
import time
from collections import Counter
from typing import Any

import numpy as np

import rvs_server.navigation.see as see
from drivers.sim.world import World
from prox_workflows.algorithms import bounds_map, vehicle
from rvs_truth.surface import missions
from tools.bench import navigate as bench


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="marsyard")
    ap.add_argument("--mission", type=int, default=0, help="index in the bench's seeded draws (seed 0)")
    ap.add_argument("--out", default="", help="also write the mission's row and every refusal as JSON here")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a server setting")
    ap.add_argument("--hang", type=float, default=None, help="bounds_map hang (m) instead of its default")
    args = ap.parse_args()

    refusals: list[dict[str, Any]] = []
    where = {"now": "drive"}
    expiry = {"judged": 0, "dropped": 0}
    gate_poses, gated, gate_stop, refused = see.gate_poses, see.SeeStrategy._gated, see.SeeingDriver.gate_stop, \
        see.SeeingDriver.refused

    def traced(lower: np.ndarray, upper: np.ndarray, geom: Any, poses: np.ndarray, body: Any) -> Any:
        g = gate_poses(lower, upper, geom, poses, body)
        if g.verdict != "safe" and where["now"] != "rejudge":
            p = np.atleast_2d(np.asarray(poses, float))[g.index]
            c = vehicle.check_poses((lower, upper), geom, p[None], body)
            refusals.append({"pose": [round(float(v), 3) for v in p], "verdict": g.verdict, "kind": g.kind,
                             "blame": [round(g.x, 3), round(g.y, 3)], "where": where["now"],
                             "bounds": {"tilt": round(float(c.tilt[0]), 2), "belly": round(float(c.intrusion[0]), 4),
                                        "relief": round(float(c.relief[0].max()), 4)}})
        return g

    def in_replan(self: Any, *a: Any, **k: Any) -> Any:
        where["now"] = "replan"
        try:
            return gated(self, *a, **k)
        finally:
            where["now"] = "drive"

    def stopped(self: Any, gate: Any, pose: Any) -> Any:
        if refusals:
            refusals[-1]["stopped"] = True
        return gate_stop(self, gate, pose)

    def rejudged(self: Any) -> Any:
        where["now"] = "rejudge"
        before = len(self.refusals)
        try:
            out = refused(self)
        finally:
            where["now"] = "drive"
        expiry["judged"] += before
        expiry["dropped"] += before - len(out)
        return out

    see.gate_poses, see.SeeStrategy._gated, see.SeeingDriver.gate_stop, see.SeeingDriver.refused = \
        traced, in_replan, stopped, rejudged
    if args.hang is not None:
        init = bounds_map.BoundsMap.__init__

        def with_hang(self: Any, geometry: Any, params: Any = None) -> None:
            init(self, geometry, params)
            self.params.hang = args.hang

        bounds_map.BoundsMap.__init__ = with_hang

    start, goal = missions(args.scene, args.mission + 1, 0)[args.mission]
    t0 = time.monotonic()
    row = bench.run_mission(args.scene, "see", start, goal, [], tuple(args.set))
    world = World.from_scene(args.scene)
    fine, g, _ = bench.truth_surface(world, args.scene)
    for r in refusals:
        c = vehicle.check_poses(fine, g, np.array([r["pose"]]), world.body)
        r["truth"] = {"tilt": round(float(c.tilt[0]), 2), "belly": round(float(c.intrusion[0]), 4),
                      "relief": round(float(c.relief[0].max()), 4), "unsafe": bool(c.unsafe[0])}
    row.update(refusals=refusals, expiry=expiry, trace_wall_s=round(time.monotonic() - t0, 1))
    if args.out:
        with open(args.out, "w") as fh:
            json.dump(row, fh, indent=1, default=str)
    near = sum(1 for r in refusals if np.hypot(r["pose"][0] - start[0], r["pose"][1] - start[1]) < 0.82)
    print(f"{args.scene} mission {args.mission}: reached {row['reached']}, events {len(row['events'])}, "
          f"progress {row['distance'] - row['true_miss']:.2f} of {row['distance']:.2f} m, "
          f"stop: {row.get('message', '')[:90]}")
    print(f"refusals {len(refusals)} ({sum(1 for r in refusals if r.get('stopped'))} stops, {near} within 0.82 m "
          f"of the start), truly unsafe {sum(r['truth']['unsafe'] for r in refusals)}, kinds "
          f"{dict(Counter(r['kind'].split()[0] for r in refusals))}; re-judged {expiry['judged']}, "
          f"dropped {expiry['dropped']}")
    if refusals:
        for key, unit, scale in (("tilt", "deg", 1.0), ("belly", "cm", 100.0)):
            over = np.array([r["bounds"][key] - r["truth"][key] for r in refusals]) * scale
            print(f"  {key}: bounds over truth p50 {np.median(over):.1f} {unit} (bounds "
                  f"{min(r['bounds'][key] for r in refusals) * scale:.1f}-{max(r['bounds'][key] for r in refusals) * scale:.1f}"
                  f", truth {min(r['truth'][key] for r in refusals) * scale:.1f}-"
                  f"{max(r['truth'][key] for r in refusals) * scale:.1f})")


if __name__ == "__main__":
    main()
