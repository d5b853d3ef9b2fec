"""Render timings of the simulated world: one ToF frame (176 x 144) and one 1920 x 1080
stereo pair (two renders), median of several runs, per scene.

    python -m tools.bench.render [--scenes office marsyard] [--runs 5] [--tilt -20]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

from drivers.sim.world import World


def _median_time(fn, runs: int) -> tuple[float, float]:
    """Median wall and CPU (all threads of this process) seconds; on a shared machine the
    CPU time is the steadier figure."""
    fn()  # warm-up: thread pool, caches
    wall, cpu = [], []
    for _ in range(runs):
        t, c = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return statistics.median(wall), statistics.median(cpu)


def bench(scene: str, runs: int, tilt: float) -> dict[str, tuple[float, float] | float]:
    t0 = time.perf_counter()
    world = World.from_scene(scene)
    build = time.perf_counter() - t0
    world.set_ptu(0.0, tilt)
    tof = _median_time(lambda: world.render_sensor("tof", 176, 144), runs)

    def pair() -> None:
        world.render_sensor("left", 1920, 1080)
        world.render_sensor("right", 1920, 1080)

    stereo = _median_time(pair, max(1, runs // 2))
    return {"build_s": build, "tof_s": tof, "stereo_pair_s": stereo}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["office", "marsyard"])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--tilt", type=float, default=-20.0, help="PTU tilt in degrees (negative looks down)")
    args = ap.parse_args(argv)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"cpus: {os.cpu_count()}  load: {load:.2f}  runs: {args.runs}  pan 0, tilt {args.tilt}  (median wall, cpu)")
    for scene in args.scenes:
        r = bench(scene, args.runs, args.tilt)
        (tw, tc), (sw, sc) = r["tof_s"], r["stereo_pair_s"]
        print(f"{scene:10s} build {r['build_s']:.2f} s   ToF 176x144 {tw * 1000:6.1f} ms (cpu {tc * 1000:6.1f})   "
              f"stereo pair 2x1920x1080 {sw:5.2f} s (cpu {sc:5.2f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
