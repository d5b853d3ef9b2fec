"""Trace the see loop's refusals against the truth: one ``navigate -auto -loop see`` mission of
:mod:`tools.bench.navigate`'s seeded draws, with every pose the vehicle check refused on the
bounds map (in a choice of the next section, or re-judging the section being driven) checked
again at that pose on the simulator's true 1 cm surface (:mod:`rvs_truth.vehicle`): was it truly
unsafe, and by which limit.

    python -m tools.bench.gate_trace --scene marsyard --mission 0 --out m0.json
    python -m tools.bench.gate_trace --mission 0 --set navigate.see_set_down=attitude [--hang 0]  # the IMU's
    python -m tools.bench.gate_trace --mission 0 --set navigate.see_vehicle=bounds      # the worst case

It hooks the checks the chooser builds (:mod:`rvs_server.navigation.sections`), so it measures the
loop as it runs; docs/NAVIGATE_BENCH.md has what it showed. A refused pose of a choice is one
the chooser's check said no to, not necessarily one the rover would have driven: most candidates
are refused far from the rover's way.
"""

from __future__ import annotations

import argparse
import json
import time
from collections import Counter
from typing import Any

import numpy as np

import rvs_server.navigation.sections as sections
from drivers.sim.world import World
from prox_workflows.algorithms import bounds_map, vehicle
from prox_workflows.algorithms.candidates import verdict_name
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
    if args.hang is not None:
        init = bounds_map.BoundsMap.__init__

        def with_hang(self: Any, geometry: Any, params: Any = None) -> None:
            init(self, geometry, params)
            self.params.hang = args.hang

        bounds_map.BoundsMap.__init__ = with_hang

    refusals: list[dict[str, Any]] = []
    where = {"now": "choose"}

    def traced(make: Any) -> Any:
        def build(*a: Any, **k: Any) -> Any:
            check = make(*a, **k)

            def run(poses: np.ndarray) -> np.ndarray:
                codes = np.asarray(check(poses))
                for p, code in zip(np.atleast_2d(poses)[codes > 0], codes[codes > 0], strict=True):
                    refusals.append({"pose": [round(float(v), 3) for v in p], "verdict": verdict_name(int(code)),
                                     "where": where["now"]})
                return codes

            return run

        return build

    recheck = sections.SectionPilot._recheck

    def driving(self: Any, pose: Any) -> Any:
        where["now"] = "drive"
        try:
            return recheck(self, pose)
        finally:
            where["now"] = "choose"

    sections.posterior_check = traced(sections.posterior_check)
    sections.bounds_check = traced(sections.bounds_check)
    sections.SectionPilot._recheck = driving

    start, goal = missions(args.scene, args.mission + 1, 0)[args.mission]
    t0 = time.monotonic()
    row = bench.run_mission(args.scene, "see", start, goal, [], tuple(args.set))
    world = World.from_scene(args.scene)
    fine, g, _ = bench.truth_surface(world, args.scene)
    if refusals:
        c = vehicle.check_poses(fine, g, np.array([r["pose"] for r in refusals]), world.body)
        for i, r in enumerate(refusals):
            r["truth"] = {"unsafe": bool(c.unsafe[i]), "tilt": round(float(c.tilt[i]), 2),
                          "belly": round(float(c.intrusion[i]), 4)}
    row.update(refusals=refusals, trace_wall_s=round(time.monotonic() - t0, 1))
    if args.out:
        with open(args.out, "w") as fh:
            json.dump(row, fh, indent=1, default=str)
    print(f"{args.scene} mission {args.mission}: reached {row['reached']}, events {len(row['events'])}, "
          f"progress {row['distance'] - row['true_miss']:.2f} of {row['distance']:.2f} m, "
          f"stop: {row.get('message', '')[:90]}")
    for part in ("choose", "drive"):
        rs = [r for r in refusals if r["where"] == part]
        if not rs:
            print(f"{part}: no refusals")
            continue
        unsafe = sum(r["truth"]["unsafe"] for r in rs)
        by = Counter(r["verdict"] for r in rs)
        truly = Counter(r["verdict"] for r in rs if r["truth"]["unsafe"])
        print(f"{part}: {len(rs)} refused poses, truly unsafe {unsafe} ({100 * unsafe / len(rs):.0f} %); by limit "
              + ", ".join(f"{k} {n} (truly {truly.get(k, 0)})" for k, n in by.most_common()))


if __name__ == "__main__":
    main()
