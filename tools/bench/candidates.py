"""Benchmark: the ENav-style candidate search (:mod:`prox_workflows.algorithms.candidates`) per
call, on 8 x 8 m windows of 5 cm bounds cut from a scene's true surface, with the real vehicle
check on them.

Each trial puts the rover at a random pose of the scene whose own ground is truly safe, with a
goal 15 m away in a random direction (off the window: reached through the window's border), and
makes the bounds a map would hold of the window: each 5 cm cell's lowest and highest true height
(1 cm surface) ``spread`` out, spread over ``dilate`` neighbouring cells (as the bounds map spreads
a return over the cells its horizontal error may reach). Two maps: ``tight`` (0.5 cm, not spread:
about what a many-frame look gives on open ground) and ``wide`` (2 cm, one cell: about what the
bounds map holds today, with its worst cases stacked). The ground within 0.5 m of the rover is known to 3 mm (its
own pose and attitude: proprioceptive set-down); ground the mast has not seen is unknown:
everything outside the wedge +-``--fov`` deg about the heading to ``--range`` m, except the disc
of 1 m the rover stands on. Timed per trial: the coarse cost and the cost to go (once per
replan), and :func:`choose` (ranking and the lazy check); printed p50 / p95 of both and of their
sum, the statuses, candidates and poses checked, and the call's time outside the vehicle check (the
ranking and the bookkeeping).

The cycle's other work (fusing frames, the gate) is not in these figures.

``--check chance`` judges the sections as the see loop does (:func:`posterior_check`: the chance
constraint, 64 draws, ``verdict_only``; the look-aheads on the posterior's best estimate,
``--ahead best`` as ``navigate.see_ahead`` by default, or with the chance constraint too,
``--ahead chance``), on a
posterior made from the same window: each cell's top its highest true height, a sigma of the
map's spread over 2.5, the rock-top error common to the body (``rock_sigma`` x the cell's relief);
``--check bounds`` (the default) is the worst case on the bounds. ``--digest`` prints, per trial,
the status, candidate, rank and poses checked: the verdicts, to compare two versions of the check.

    python -m tools.bench.candidates [--scenes marsyard dense] [--maps tight wide] [--trials 40] [--max-poses N]
    python -m tools.bench.candidates --check chance --trials 10 [--ahead chance] [--digest] [--every-pose]
"""

from __future__ import annotations

import argparse
import math
import time
from collections import Counter

import numpy as np
from scipy import ndimage

from drivers.sim.world import World
from prox_workflows.algorithms.candidates import (
    CandidateParams,
    best_check,
    bounds_check,
    choose,
    coarse_costs,
    cost_to_go,
    posterior_check,
)
from prox_workflows.algorithms.chance import ChanceParams, Posterior, relief, rock_top_sigma
from prox_workflows.algorithms.vehicle import check_poses
from prox_workflows.grid import GridGeometry
from rvs_truth.surface import area

WINDOW = 8.0  # m
MAPS = {"tight": (0.005, 0), "wide": (0.02, 1)}  # bounds spread (m) and dilation (cells)


def window(world: World, pose: tuple[float, float, float], spread: float, fov: float, reach: float,
           dilate: int = 1) -> tuple[tuple[np.ndarray, np.ndarray], GridGeometry, np.ndarray, GridGeometry]:
    x, y, h = pose
    g = GridGeometry.covering(x - WINDOW / 2, y - WINDOW / 2, x + WINDOW / 2, y + WINDOW / 2, 0.05)
    truth = world.true_dem(0.01, g.bounds, include_target=False).astype(np.float64)
    blocks = truth[:g.height * 5, :g.width * 5].reshape(g.height, 5, g.width, 5)
    low, high = blocks.min(axis=(1, 3)), blocks.max(axis=(1, 3))
    lower = ndimage.minimum_filter(low, 2 * dilate + 1) - spread
    upper = ndimage.maximum_filter(high, 2 * dilate + 1) + spread
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    r = np.hypot(X - x, Y - y)
    # the ground the rover stands on, known from its own pose and attitude (proprioceptive set-down)
    home = r <= 0.5
    lower[home], upper[home] = low[home] - 0.003, high[home] + 0.003
    bearing = (np.degrees(np.arctan2(Y - y, X - x)) - h + 180.0) % 360.0 - 180.0
    seen = (r <= 1.0) | ((np.abs(bearing) <= fov) & (r <= reach))
    lower[~seen], upper[~seen] = np.nan, np.nan
    tg = GridGeometry(0.01, g.xmin, g.ymax, truth.shape[1], truth.shape[0])
    return (lower, upper), g, truth, tg


def window_posterior(heights: tuple[np.ndarray, np.ndarray], g: GridGeometry, spread: float,
                     chance: ChanceParams) -> Posterior:
    """A posterior a map of the window might hold: the top at the cell's highest true height (the
    upper bound less its spread), a sigma of the spread over 2.5, the rock-top error common to the
    cells under a body; unseen where the window has no bound."""
    lower, upper = heights
    top = upper - spread
    seen = np.isfinite(top)
    var = np.where(seen, (spread / 2.5) ** 2 + chance.top_sigma**2, np.nan)
    common = np.where(seen, rock_top_sigma(relief(top, g), chance), 0.0)
    return Posterior(np.where(seen, top, np.nan), var, np.full(top.shape, np.inf), common)


def trial_poses(world: World, scene: str, n: int, rng: np.random.Generator) -> list[tuple[float, float, float]]:
    xmin, ymin, xmax, ymax = area(scene)
    out: list[tuple[float, float, float]] = []
    while len(out) < n:
        p = (float(rng.uniform(xmin + 5, xmax - 5)), float(rng.uniform(ymin + 5, ymax - 5)),
             float(rng.uniform(-180, 180)))
        g = GridGeometry.covering(p[0] - 0.6, p[1] - 0.6, p[0] + 0.6, p[1] + 0.6, 0.01)
        truth = world.true_dem(0.01, g.bounds, include_target=False).astype(np.float64)
        if check_poses(truth, g, np.array([p]), world.body).safe[0]:
            out.append(p)
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", nargs="+", default=["marsyard", "dense"])
    ap.add_argument("--trials", type=int, default=40)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--maps", nargs="+", default=list(MAPS), choices=list(MAPS))
    ap.add_argument("--max-poses", type=int, default=0, help="CandidateParams.max_poses (0: no budget)")
    ap.add_argument("--fov", type=float, default=60.0, help="half-width of the seen wedge (deg)")
    ap.add_argument("--range", type=float, default=4.5, help="how far the seen wedge reaches (m)")
    ap.add_argument("--check", choices=["bounds", "chance"], default="bounds",
                    help="the sections' check: the worst case on bounds, or the chance constraint (as the see loop)")
    ap.add_argument("--every-pose", action="store_true",
                    help="with --check chance: draw for every pose sent (no runs: a section is not read to its first "
                         "refusal only), for comparison")
    ap.add_argument("--ahead", choices=["chance", "best"], default="best",
                    help="with --check chance: the look-aheads judged on the posterior's best estimate (the see "
                         "loop's navigate.see_ahead default) or with the chance constraint")
    ap.add_argument("--digest", action="store_true", help="print each trial's verdict (status, candidate, rank, poses)")
    ap.add_argument("--verify-step", type=float, default=CandidateParams().verify_step,
                    help="CandidateParams.verify_step: the chosen candidate judged between its poses this far apart "
                         "(0: not; for comparison)")
    args = ap.parse_args(argv)
    params = CandidateParams(max_poses=args.max_poses, verify_step=args.verify_step)
    chance = ChanceParams()
    digests: list[str] = []
    print(f"check: {args.check}{' (every pose drawn)' if args.every_pose else ''}"
          f"{f', look-aheads {args.ahead}' if args.check == 'chance' else ''}")
    print("| scene | map | trials | field ms p50 / p95 | choose ms p50 / p95 | total ms p50 / p95 | drive / look / blocked "
          "| candidates checked p50 / max | poses checked p50 / p95 | choose less the check ms p50 / p95 |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for scene, kind in ((s, m) for s in args.scenes for m in args.maps):
        world = World.from_scene(scene, seed=1)
        body = world.body
        rng = np.random.default_rng(args.seed)
        t_field, t_choose, t_rank, statuses, checked, poses = [], [], [], Counter(), [], []
        for pose in trial_poses(world, scene, args.trials, rng):
            heights, g, _, _ = window(world, pose, *MAPS[kind][:1], args.fov, args.range, MAPS[kind][1])
            b = math.radians(float(rng.uniform(-180, 180)))
            goal = (pose[0] + 15 * math.cos(b), pose[1] + 15 * math.sin(b))
            lookahead = None
            if args.check == "chance":
                post = window_posterior(heights, g, MAPS[kind][0], chance)
                vehicle = posterior_check(post, g, body, chance)
                if args.every_pose:
                    vehicle = (lambda f: lambda poses: f(poses))(vehicle)
                lookahead = best_check(post, g, body) if args.ahead == "best" else None
            else:
                vehicle = bounds_check(heights, g, body)
            in_check = [0.0]

            def check(poses: np.ndarray, runs: np.ndarray | None = None, vehicle=vehicle,
                      in_check=in_check) -> np.ndarray:
                t = time.perf_counter()
                out = vehicle(poses) if runs is None else vehicle(poses, runs)
                in_check[0] += time.perf_counter() - t
                return out

            check.by_runs = getattr(vehicle, "by_runs", False)  # type: ignore[attr-defined]

            t0 = time.perf_counter()
            cost, cg = coarse_costs(heights, g, body, **params.coarse)
            ctg = cost_to_go(cost, cg, goal)
            t1 = time.perf_counter()
            c = choose(pose, heights, g, body, ctg, check, params, lookahead)
            t2 = time.perf_counter()
            digests.append(f"{scene} {kind} {c.status} {c.candidate} {c.rank} {c.checked} {c.poses_checked} "
                           f"{sorted(c.reasons.items())}")
            t_field.append(1000 * (t1 - t0))
            t_choose.append(1000 * (t2 - t1))
            t_rank.append(1000 * (t2 - t1 - in_check[0]))
            statuses[c.status] += 1
            checked.append(c.checked)
            poses.append(c.poses_checked)
        total = np.add(t_field, t_choose)

        def pp(a: list[float] | np.ndarray) -> str:
            return f"{np.percentile(a, 50):.0f} / {np.percentile(a, 95):.0f}"

        print(f"| {scene} | {kind} | {len(total)} | {pp(t_field)} | {pp(t_choose)} | {pp(total)} | "
              f"{statuses['drive']} / {statuses['look']} / {statuses['blocked']} | "
              f"{np.percentile(checked, 50):.0f} / {max(checked)} | {pp(poses)} | {pp(t_rank)} |")
    if args.digest:
        print("\n".join(digests))


if __name__ == "__main__":
    main()
