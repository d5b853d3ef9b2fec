"""Benchmark: what the ground round a rover set down at a mission's start does that no frame
shows, on the simulator's true 1 cm surface (docs/NAVIGATE_BENCH.md, "The start's blind disc").

Per start of :func:`rvs_truth.surface.missions`: the ring round the mast's blind disc fitted as
:func:`prox_workflows.algorithms.set_down.ring_plane` fits the map's (its spread about the plane,
rocks included), how far the disc's ground past the turn stands off that plane (per cell and
over 10 cm patches, a wheel's), and where the wheels' resting plane meets the rover's centre (the
rover frame's origin, which the simulator renders every frame from) against the ground there
(what a map's height at the centre reads), with the wheel a rigid body does not rest on.

    python -m tools.bench.set_down --scene dense --missions 8
"""

from __future__ import annotations

import argparse
import math
from types import SimpleNamespace

import numpy as np
from scipy.ndimage import uniform_filter

from drivers.sim.rover import resting_plane
from drivers.sim.world import World
from prox_workflows.algorithms.set_down import ring_plane
from prox_workflows.algorithms.vehicle import reach
from rvs_truth.surface import missions, truth_surface

BLIND = 0.72  # m: the mast's blind disc round its foot (looks.blind_radius of the default head)
FOOT = 0.10  # m: the pan axis's foot ahead of the rover's centre
EDGE, WIDTH = 0.1, 0.5  # m: the ring past the disc (see.BLIND_EDGE, see.RING_WIDTH)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="dense")
    ap.add_argument("--missions", type=int, default=8)
    args = ap.parse_args()
    world = World.from_scene(args.scene)
    fine, g, _ = truth_surface(world, args.scene)
    truth = SimpleNamespace(geometry=g, mean=fine, stamp=np.ones(fine.shape, np.int32))
    turn = reach(world.body) + 0.05
    xs, ys = g.centers()
    for i, (s, e) in enumerate(missions(args.scene, args.missions)):
        h = math.atan2(e[1] - s[1], e[0] - s[0])
        fx, fy = s[0] + FOOT * math.cos(h), s[1] + FOOT * math.sin(h)
        ring = ring_plane(truth, (fx, fy), BLIND + EDGE, BLIND + WIDTH, s)
        c0, c1 = max(0, int((fx - 1.5 - g.xmin) / g.cell)), min(g.width, int((fx + 1.5 - g.xmin) / g.cell))
        r0, r1 = max(0, int((g.ymax - fy - 1.5) / g.cell)), min(g.height, int((g.ymax - fy + 1.5) / g.cell))
        X, Y = np.meshgrid(xs[c0:c1], ys[r0:r1])
        off = fine[r0:r1, c0:c1] - ring.height(X, Y)
        disc = (np.hypot(X - fx, Y - fy) <= BLIND + EDGE) & (np.hypot(X - s[0], Y - s[1]) > turn)
        patch = uniform_filter(off, 10)[disc]
        centre, _, _, hang = resting_plane(world.body, world.terrain.sample, (s[0], s[1], math.degrees(h)))
        datum = float(world.terrain.sample(s[0], s[1]))
        print(f"{args.scene} {i}: ring off its plane {ring.spread * 100:.1f} cm (sd); the disc past the turn "
              f"{np.percentile(off[disc], 1) * 100:+.1f} / {np.percentile(off[disc], 99) * 100:+.1f} cm (p1 / p99), "
              f"10 cm patches {patch.min() * 100:+.1f} / {patch.max() * 100:+.1f} cm; the wheels' plane at the "
              f"centre {100 * (centre - datum):+.1f} cm over the ground there, the fourth wheel's {100 * hang:+.1f} cm",
              flush=True)


if __name__ == "__main__":
    main()
