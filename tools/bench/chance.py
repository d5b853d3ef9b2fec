"""Benchmark: the chance-constrained vehicle check (prox_workflows.algorithms.chance) on a look's
bounds map, against the worst-case check on its bounds, with the check on the true 1 cm surface as
the reference; and the calibration of its rock-edge error model.

A look's frames are fused into a bounds map as ``tools.bench.bounds`` fuses them (the ToF's noise
model, one draw). Then:

- ``--calibrate``: per band of the headroom J (``chance.headroom``: how much higher the map's
  upper bound allows the ground within a cell's 3 x 3 neighbourhood), how far the true top (the
  simulator's 0.5 cm surface, highest in the cell) stands over the posterior's top without the
  edge terms: its median and 99.9th percentile. Fitted as a bias ``edge_bias * J`` (the medians,
  least squares weighted by cells), a floor ``top_sigma`` (the bands under 2 cm) and a sigma
  ``edge_sigma * J`` over it, each the least that puts every band's 99.9th percentile within 3.09
  sigmas; and the standardised residual's tail with the fit and with the declared model (every
  term, the rock top's included: whether the declared sizes hold on this look; ``--posterior map``
  as the chooser makes it);
- otherwise, at poses over the ground 1.6-4.0 m ahead (4 headings, as the bounds bench): judged
  poses, truly safe kept and false safes of the worst-case check and of the chance check at each
  epsilon, and the chance check's time per 1,000 poses.

    python -m tools.bench.chance --calibrate --look approach # marsyard, cell 2.5 cm
    python -m tools.bench.chance --epsilon 1e-2 1e-3 1e-4     # the table
    python -m tools.bench.chance --cell 0.05 --world-seed 2   # a 5 cm map, another rock draw
    python -m tools.bench.chance --time                       # 1,000 poses on a 5 cm window
    python -m tools.bench.chance --look approach --world-seed 3 --posterior map   # as the chooser judges
    python -m tools.bench.chance --risk --scenes marsyard hirise dense --world-seeds 20 21 22 23 24 25 26 27 28 29 --jobs 2

``--slack`` (with ``--scenes``, ``--world-seeds``, ``--set-down``): whether the stated probability
has slack at the pose level: the declared verdict against passing a pose whose draws' mean excess
lies t or more of their spread under every limit (:func:`slack`), false safes and kept per t.

``--risk``: the stated risk, as the issue asks it: the chance check at the declared epsilon, with
the posterior as the chooser makes it, over many looks (``--look``) on rock draws no setting was
tuned on (``--world-seeds``; the noise draw is the rock draw's), summed per scene: judged poses,
false safes and their one-sided 95 % Clopper-Pearson bound, truly safe kept (of those judged, and of
all truly safe poses: a model that leaves more poses unknown keeps no more for it). ``--bounds
KEY=VALUE``: the bounds map's parameters for every look (a map of its own, so a run of its own;
``--against`` changes only the check on the same map), e.g. ``--look approach+hazcam --bounds
stereo_first=true``: the hazard cameras' cells standing alone.

``--rock-top`` (with ``--scenes``, ``--world-seeds``): per band of a rock's height H over the
ground round it, on cells away from an edge, how far the true top stands over the map's top, and
the common sigma its 99.9th percentile needs over the cells' own at 3.09 sigmas, beside the rock
top's declared common sigma (``rock_sigma`` x H, at most ``rock_sigma_max``), and its worst 1 % of
cells split into the cell's mean read low and the relief within it the top misses. With
``--against``, each set of ChanceParams changes is tabulated too, on the same maps.

``--posterior``: ``look`` (default) makes the posterior seen from the look's mean sensor position;
``map`` as the see loop's chooser makes it, with no viewpoint (the slope's steepest direction and
the map's ``along_var``, the mean's horizontal error averaged over its returns); ``one`` the
same with one return's horizontal error in its place (``along_var`` left out).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from collections import Counter
from typing import Any

import numpy as np

from drivers.sim.rover import IMU_SIGMA_DEG, RoverBody
from drivers.sim.world import World
from prox_workflows.algorithms.bounds_map import BoundsMap, BoundsParams
from prox_workflows.algorithms.chance import (
    ChanceParams,
    Posterior,
    chance_check,
    headroom,
    posterior,
    relief,
    rock_top_sigma,
)
from prox_workflows.algorithms.set_down import set_down
from prox_workflows.algorithms.vehicle import LIMITS, check_poses
from prox_workflows.grid import GridGeometry
from rvs_params import SettingError
from rvs_truth.stats import clopper_pearson_upper
from tools.bench.bounds import LOOKS, TRUE_CELL, frames, pooled
from tools.bench.rows import streamed
from tools.bench.set_down import BLIND, EDGE, FOOT, WIDTH

JUMP_BANDS = (0.0, 0.01, 0.02, 0.04, 0.08, 0.16, np.inf)  # m
Z999 = 3.09  # a normal's 99.9th percentile
FLAT = 0.02  # m: bands of less headroom fit the floor (top_sigma), the others the share of J (edge_sigma)


def fused(scene: str, look: str, cell: float, world_seed: int, seed: int, params: BoundsParams | None = None
          ) -> tuple[World, BoundsMap, np.ndarray]:
    """The bounds map of one look, as the bounds bench makes it, and the sensor's mean position;
    ``params``: the map's (its ``cell`` replaced by ``cell``)."""
    world = World.from_scene(scene, seed=world_seed)
    x0, y0, _ = world.rover_pose()
    box = [[x0 - 1.0, y0 - 3.0], [x0 + 6.5, y0 + 3.0]]
    bounds = BoundsMap.covering(box, 0.0, dataclasses.replace(params or BoundsParams(), cell=cell))
    origins = []
    for pts, sigma, origin, sigma_xy, cut, sensor in frames(world, look, np.random.default_rng(seed)):
        bounds.fuse(pts, sigma, origin, cut, sigma_xy, sensor)
        origins.append(origin)
    return world, bounds, np.mean(origins, axis=0)


def whole(bounds: BoundsMap) -> tuple[dict[str, np.ndarray], GridGeometry]:
    g = bounds.geometry
    return bounds.statistics(g.xmin, g.ymin, g.xmin + g.width * g.cell, g.ymax)


def calibrate(scene: str, look: str, cell: float, world_seed: int, seed: int, made: str = "look") -> dict[str, Any]:
    """The fit (see the module's docstring), and each band's tail under the declared model
    (``ChanceParams()``, every term, the rock top's included): whether the declared sizes still
    hold on this look. ``made`` ``map``: the posterior as the chooser makes it (no viewpoint)."""
    world, bounds, viewpoint = fused(scene, look, cell, world_seed, seed)
    stats, g = whole(bounds)
    if made != "look":
        viewpoint = None
    bare = ChanceParams(edge_bias=0.0, edge_sigma=0.0, top_sigma=0.0, rock_sigma=0.0)
    base = posterior(stats, g, bounds.params.k, bare, viewpoint)
    fine = world.true_dem(TRUE_CELL, (g.xmin, g.ymin, g.xmin + g.width * g.cell, g.ymax))
    top = pooled(fine, g, np.max)
    seen = np.isfinite(base.mean)
    jump = headroom(stats, base.mean)
    r, j, v = (top - base.mean)[seen], jump[seen], base.var[seen]
    rows = []
    for lo, hi in zip(JUMP_BANDS[:-1], JUMP_BANDS[1:], strict=True):
        at = (j >= lo) & (j < hi)
        if at.sum() < 20:
            continue
        rows.append({"band": (lo, hi), "cells": int(at.sum()), "J": float(j[at].mean()),
                     "median": float(np.median(r[at])), "q999": float(np.percentile(r[at], 99.9)),
                     "model_sd": float(np.sqrt(v[at].mean())),
                     "z999": float(np.percentile(r[at] / np.sqrt(v[at]), 99.9)), "at": at})
    n = np.array([row["cells"] for row in rows], float)
    J = np.array([row["J"] for row in rows])
    # the bias: the bands' medians over J, least squares through the origin weighted by cells; the
    # sigma: the least share of J that puts every band's 99.9th percentile (bands of 1,000 cells
    # and more: fewer cannot show it) within 3.09 sigmas (a normal's 0.1 % tail)
    a = float(max(np.sum(n * J * np.array([row["median"] for row in rows])) / np.sum(n * J * J), 0.0))
    # the floor first, from the flat bands (J under FLAT), then the share of J over it
    extra = {id(row): ((row["q999"] - a * row["J"]) / Z999) ** 2 - row["model_sd"] ** 2 for row in rows}
    big = [row for row in rows if row["cells"] >= 1000]
    c = float(np.sqrt(max([extra[id(row)] for row in big if row["J"] < FLAT] + [0.0])))
    b = float(max(np.sqrt(max(extra[id(row)] - c * c, 0.0)) / row["J"] for row in big if row["J"] >= FLAT))
    # per cell, without the rock-top term (chosen at the pose level, on false safes: it only widens)
    fitted = posterior(stats, g, bounds.params.k, dataclasses.replace(bare, edge_bias=a, edge_sigma=b, top_sigma=c),
                       viewpoint)
    z = ((top - fitted.mean) / np.sqrt(fitted.var + fitted.common**2))[seen]
    declared = posterior(stats, g, bounds.params.k, ChanceParams(), viewpoint)
    z_declared = ((top - declared.mean) / np.sqrt(declared.var + declared.common**2 + declared.shared**2))[seen]
    for row in rows:
        at = row.pop("at")
        row["z999_fit"] = float(np.percentile(z[at], 99.9))
        row["over_fit"] = float(np.mean(z[at] > Z999))
        row["z999_declared"] = float(np.percentile(z_declared[at], 99.9))
        row["over_declared"] = float(np.mean(z_declared[at] > Z999))
    return {"rows": rows, "edge_bias": a, "edge_sigma": b, "top_sigma": c, "cells": int(seen.sum())}


def set_down_at_start(world: World, bounds: BoundsMap, body: RoverBody) -> str:
    """The see loop's ring set-down at the rover's start (``see_set_down ring``,
    :func:`prox_workflows.algorithms.set_down.set_down`): the wheels' ground from the pose and the
    true attitude (the IMU's sigma), the rest of the mast's blind disc and of the disc the body
    turns in on the ring's plane within the ring's own spread."""
    x0, y0, h0 = world.rover_pose()
    roll, pitch = world.rover_attitude()
    h = math.radians(h0)
    disc = (x0 + FOOT * math.cos(h), y0 + FOOT * math.sin(h), BLIND)
    datum = float(world.true_dem(0.01, (x0 - 0.005, y0 - 0.005, x0 + 0.005, y0 + 0.005))[0, 0])
    return set_down(bounds, (x0, y0, h0), datum, body, (roll, pitch, IMU_SIGMA_DEG), disc, 0.0, EDGE, WIDTH)


HEIGHT_BANDS = (0.02, 0.04, 0.08, 0.16, np.inf)  # m: a rock top's height over the lowest top within 0.2 m


def _rock_top_errors(job: tuple[str, str, float, int, list[dict[str, float]]]) -> list[dict[str, list[float]]]:
    """One look's rock-top cells (:func:`rock_top`), per setting (the declared, then each of
    ``against``), in a pool's process."""
    scene, look, cell, world_seed, against = job
    world, bounds, _ = fused(scene, look, cell, world_seed, world_seed)
    stats, g = whole(bounds)
    fine = world.true_dem(TRUE_CELL, (g.xmin, g.ymin, g.xmin + g.width * g.cell, g.ymax))
    top, true_mean = pooled(fine, g, np.max), pooled(fine, g, np.mean)
    out = []
    for changed in [{}, *against]:
        bare = dataclasses.replace(ChanceParams(**changed), edge_bias=0.0, edge_sigma=0.0, top_sigma=0.0,
                                   rock_sigma=0.0)
        base = posterior(stats, g, bounds.params.k, bare, None)
        height = relief(base.mean, g)
        at = np.isfinite(base.mean) & stats["framed"] & (headroom(stats, base.mean) < 2 * FLAT) & \
            (height >= HEIGHT_BANDS[0])
        out.append({"error": (top - base.mean)[at].tolist(), "height": height[at].tolist(),
                    "own": np.sqrt(base.var[at]).tolist(), "mean": (true_mean - stats["mean"])[at].tolist()})
    return out


def rock_top(scenes: list[str], look: str, cell: float, world_seeds: list[int], jobs: int,
             against: list[dict[str, float]] | None = None) -> list[dict[str, Any]]:
    """Per scene and band of a rock top's height H over the ground round it, on cells away from an
    edge (J under 4 cm): how far the true top stands over the map's top (the posterior's best
    estimate without the edge and rock terms), and the common sigma a band's 99.9th percentile
    needs over the cells' own sigma at 3.09 sigmas, beside what ``rock_top_sigma`` declares. What
    ``rock_sigma`` and ``rock_sigma_max`` are weighed against: the first grows with H, the second
    holds where the error stops growing. The worst 1 % of a band's cells split the error in two:
    the cell's mean read low (the true ground's mean over the cell over the map's mean:
    ``worst_mean``), and the relief within the cell the top misses (the rest: ``worst_relief``).
    Rows for the declared settings (``setting`` 0), then for each set of ``against`` (ChanceParams
    changes; ``setting`` i) on the same maps."""
    against = against or []
    todo = [(scene, look, cell, ws, against) for scene in scenes for ws in world_seeds]
    found = streamed(_rock_top_errors, todo, jobs, show=False)
    rows = []
    for i, changed in enumerate([{}, *against]):
        declared = ChanceParams(**changed)
        for scene in scenes:
            got = [f[i] for f, job in zip(found, todo, strict=True) if job[0] == scene]
            e, h, own, low = (np.concatenate([np.asarray(f[key]) for f in got])
                              for key in ("error", "height", "own", "mean"))
            for lo, hi in zip(HEIGHT_BANDS[:-1], HEIGHT_BANDS[1:], strict=True):
                at = (h >= lo) & (h < hi)
                if at.sum() < 20:
                    continue
                q999 = float(np.percentile(e[at], 99.9))
                sd = float(np.sqrt(np.mean(own[at] ** 2)))
                worst = at & (e >= np.percentile(e[at], 99))
                rows.append({"setting": i, "scene": scene, "band": (lo, hi), "cells": int(at.sum()),
                             "median": float(np.median(e[at])), "q99": float(np.percentile(e[at], 99)), "q999": q999,
                             "max": float(e[at].max()), "own_sd": sd,
                             "needed": math.sqrt(max((q999 / Z999) ** 2 - sd**2, 0.0)),
                             "declared": float(np.mean(rock_top_sigma(h[at], declared))),
                             "worst_mean": float(low[worst].mean()), "worst_relief": float((e - low)[worst].mean())})
    return rows


def evaluate(scene: str, look: str, cell: float, world_seed: int, seed: int, epsilons: list[float],
             samples: int, body: RoverBody, rock_sigma: float = ChanceParams().rock_sigma,
             made: str = "look", start: bool = False, models: list[ChanceParams] | None = None,
             params: BoundsParams | None = None, **model: float) -> dict[str, Any]:
    """The pose-level table (see the module's docstring); ``start``: the ring set-down at the
    rover's start and the poses round it (0.5 m behind it to 1.6 m ahead, 1.2 m either side: the
    ground a rover leaving its start drives) instead of those 1.6-4.0 m ahead; ``models``: whole
    parameter sets, each judging the same map and poses (else one per epsilon); ``model``: further
    :class:`ChanceParams` for the chance check (e.g. ``prior_own=1.0``: a prior drawn cell by cell);
    ``params``: the bounds map's."""
    world, bounds, viewpoint = fused(scene, look, cell, world_seed, seed, params)
    said = set_down_at_start(world, bounds, body) if start else ""
    stats, g = whole(bounds)
    if made != "look":  # as the chooser makes it: no viewpoint
        viewpoint = None
        if made == "one":
            stats.pop("along_var")
    x0, y0, _ = world.rover_pose()
    truth = world.true_dem(0.01, (g.xmin, g.ymin, g.xmin + g.width * g.cell, g.ymax))
    tg = GridGeometry(0.01, g.xmin, g.ymax, truth.shape[1], truth.shape[0])
    ahead = np.arange(-0.5, 1.65, 0.1) if start else np.arange(1.6, 4.0, 0.1)
    px, py = np.meshgrid(x0 + ahead, y0 + np.arange(-1.2, 1.25, 0.1))
    poses = np.column_stack([np.repeat(px.ravel(), 4), np.repeat(py.ravel(), 4),
                             np.tile([0.0, 45.0, 90.0, 135.0], px.size)])
    on_truth = check_poses(truth, tg, poses, body)
    t0 = time.perf_counter()
    worst = check_poses((bounds.lower, bounds.upper), g, poses, body)
    t_worst = time.perf_counter() - t0
    rows = [{"check": f"worst case (k {bounds.params.k:g})", "safe": worst.safe, "unknown": worst.unknown,
             "ms": 1000 * t_worst}]
    for params in models or [ChanceParams(epsilon=eps, samples=samples, rock_sigma=rock_sigma, **model)
                             for eps in epsilons]:
        eps = params.epsilon
        t0 = time.perf_counter()
        post = posterior(stats, g, bounds.params.k, params, viewpoint)
        c = chance_check(post, g, poses, body, params)
        rows.append({"check": f"chance, epsilon {eps:g}", "safe": c.safe, "unknown": c.unknown,
                     "ms": 1000 * (time.perf_counter() - t0), "screened": int(c.screened.sum()),
                     "z": np.nan_to_num(c.z, nan=-np.inf).max(axis=1),
                     "misses": [_miss(poses[i], on_truth.excess[i], c.nominal.excess[i], float(c.p_any[i]))
                                for i in np.flatnonzero(c.safe & on_truth.unsafe)]})
    truly_safe = ~on_truth.unsafe
    for row in rows:
        judged = ~row["unknown"]
        row["judged"] = int(judged.sum())
        row["false_safe"] = int((row["safe"] & on_truth.unsafe).sum())
        row["kept"] = float(row["safe"][truly_safe & judged].mean())
        row["of"] = int((truly_safe & judged).sum())
        row["safe_n"] = int((row["safe"] & truly_safe).sum())
    return {"poses": len(poses), "rows": rows, "truly_unsafe": int(on_truth.unsafe.sum()), "set_down": said,
            "unsafe": on_truth.unsafe}


LAGS = (1, 2, 3, 4, 6, 8)  # cells: the lags the spatial correlation is measured at


def lag_correlation(e: np.ndarray, ok: np.ndarray, lag: int) -> float:
    """The correlation of ``e`` between cells ``lag`` apart along the rows and the columns (both
    ``ok``), averaged over the two directions."""
    out = []
    for axis in (0, 1):
        a, b = e, np.roll(e, -lag, axis=axis)
        m = ok & np.roll(ok, -lag, axis=axis)
        if axis == 0:
            m[-lag:, :] = False
        else:
            m[:, -lag:] = False
        x, y = a[m] - a[m].mean(), b[m] - b[m].mean()
        out.append(float((x * y).mean() / np.sqrt((x * x).mean() * (y * y).mean())))
    return float(np.mean(out))


def correlation(scene: str, look: str, cell: float, world_seed: int, seed: int) -> dict[str, Any]:
    """How the errors the chance check draws are correlated between neighbouring cells, on the
    truth: (a) the map's means against the true ground's mean over each cell (cells a frame bounded;
    all, off rock edges (J under 2 cm), near the look's mean sensor position and far from it), their spread
    against the map's own sigma and their correlation at :data:`LAGS`; (b) the true ground off the
    plane fitted to it over the blind disc round the rover's start (what the set-down's prior there
    is wrong by), its spread and correlation alike, on the map's cells."""
    world, bounds, viewpoint = fused(scene, look, cell, world_seed, seed)
    stats, g = whole(bounds)
    fine = world.true_dem(TRUE_CELL, (g.xmin, g.ymin, g.xmin + g.width * g.cell, g.ymax))
    truth = pooled(fine, g, np.mean)
    mean = np.asarray(stats["mean"], np.float64)
    seen = np.isfinite(mean)
    jump = headroom(stats, mean + stats["rise"])
    e = np.where(seen, truth - mean, 0.0)
    own = np.sqrt(np.asarray(stats["mean_var"], np.float64))
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    far = np.hypot(X - viewpoint[0], Y - viewpoint[1])
    rows = []
    for name, ok in (("map means, all", seen), ("map means, off rock edges", seen & (jump < FLAT)),
                     ("map means, under 2 m from the sensor", seen & (far < 2.0)),
                     ("map means, over 3 m from the sensor (grazing)", seen & (far > 3.0))):
        rows.append({"what": name, "cells": int(ok.sum()), "sd": float(e[ok].std()),
                     "own": float(np.median(own[ok])), "corr": [lag_correlation(e, ok, lag) for lag in LAGS]})
    x0, y0, _ = world.rover_pose()
    disc = np.hypot(X - x0, Y - y0) <= BLIND
    a = np.column_stack([np.ones(int(disc.sum())), X[disc] - x0, Y[disc] - y0])
    coef = np.linalg.lstsq(a, truth[disc], rcond=None)[0]
    off = np.zeros(g.shape)
    off[disc] = truth[disc] - a @ coef
    rows.append({"what": "true ground off its plane, blind disc", "cells": int(disc.sum()), "sd": float(off[disc].std()),
                 "own": float("nan"), "corr": [lag_correlation(off, disc, lag) for lag in LAGS]})
    return {"rows": rows}


def _miss(pose: np.ndarray, truth: np.ndarray, nominal: np.ndarray, p_any: float) -> dict[str, Any]:
    """A false safe traced: the limits the truth exceeds there and by how much, what the
    posterior's best estimate left, and the probability the check gave."""
    over = {name: round(float(truth[k]), 4) for k, name in enumerate(LIMITS) if truth[k] > 0}
    return {"pose": [round(float(v), 2) for v in pose], "truth_excess": over,
            "nominal_excess": {name: round(float(nominal[k]), 4) for k, name in enumerate(LIMITS) if name in over},
            "p_any": p_any}


def _risk_row(job: tuple[str, str, float, int, int, list[dict[str, float]], BoundsParams]) -> dict[str, Any]:
    """One look's counts with the declared parameters, and with them changed by each set of
    ``against`` (the ``against`` key, in order: the same map, poses and draws), in a pool's process."""
    scene, look, cell, world_seed, samples, against, params = job
    models = [ChanceParams(samples=samples)]
    models += [dataclasses.replace(models[0], **changed) for changed in against]
    out = evaluate(scene, look, cell, world_seed, world_seed, [], samples, RoverBody(), made="map", models=models,
                   params=params)
    rows = [{"judged": row["judged"], "false_safe": row["false_safe"], "kept": round(row["kept"], 4),
             "of": row["of"], "safe_n": row["safe_n"], "misses": row["misses"]} for row in out["rows"][1:]]
    head = {"scene": scene, "look": look, "world_seed": world_seed, "truly_unsafe": out["truly_unsafe"],
            "truly_safe": out["poses"] - out["truly_unsafe"]}
    return {**head, **rows[0], **({"against": rows[1:]} if against else {})}


def risk(scenes: list[str], looks: list[str], world_seeds: list[int], cell: float, samples: int,
         jobs: int, against: list[dict[str, float]] | None = None, params: BoundsParams | None = None
         ) -> list[dict[str, Any]]:
    """Per scene, the looks' counts summed: the false-safe rate per judged pose and its bound.
    Each look's row is printed as it comes, so a run cut short keeps what it measured."""
    todo = [(scene, look, cell, ws, samples, against or [], params or BoundsParams()) for ws in world_seeds for scene in scenes
            for look in looks]
    return streamed(_risk_row, todo, jobs)


def risk_table(rows: list[dict[str, Any]]) -> list[str]:
    lines = ["| scene | looks | judged poses | false safe | rate | 95 % upper bound | truly safe kept "
             "(of those judged) | truly safe kept (of all) |", "|---|---|---|---|---|---|---|---|"]
    for scene in dict.fromkeys(r["scene"] for r in rows):
        sel = [r for r in rows if r["scene"] == scene]
        n, k = sum(r["judged"] for r in sel), sum(r["false_safe"] for r in sel)
        kept = sum(r["kept"] * r["of"] for r in sel) / max(1, sum(r["of"] for r in sel))
        # of every truly safe pose, judged or not: a model that judges fewer poses keeps no more
        kept_all = sum(r.get("safe_n", 0) for r in sel) / max(1, sum(r.get("truly_safe", 0) for r in sel))
        lines.append(f"| {scene} | {len(sel)} | {n:,} | {k} | {k / max(n, 1):.1e} | "
                     f"{clopper_pearson_upper(k, n) if n else float('nan'):.1e} | {100 * kept:.1f} % | "
                     f"{100 * kept_all:.1f} % |")
    misses = [(r["scene"], m) for r in rows for m in r.get("misses", [])]
    for scene in dict.fromkeys(sc for sc, _ in misses):
        mine = [m for sc, m in misses if sc == scene]
        by = Counter(k for m in mine for k in m["truth_excess"])
        worst = max(v for m in mine for v in m["truth_excess"].values())
        lines.append(f"{scene}: false safes over {dict(by)} on the truth (worst excess {worst:g}), "
                     f"P(any) median {float(np.median([m['p_any'] for m in mine])):.1e}")
    return lines


SLACK_T = (3.43, 3.0, 2.5, 2.0, 1.5, 1.0, 0.5, 0.0)  # sigmas: 3.43 is the declared epsilon's normal tail


def slack_counts(unsafe: np.ndarray, safe: np.ndarray, unknown: np.ndarray, z: np.ndarray,
                 ts: tuple[float, ...] = SLACK_T) -> dict[str, Any]:
    """One look's counts for :func:`slack`: per verdict (the declared one, then a pose passed where
    the draws' mean excess lies ``t`` or more of their spread under every limit: the normal tail
    alone, without the share of draws over a limit) its false safes and truly safe kept."""
    judged = ~unknown
    verdicts = [("declared", safe)] + [(f"t {t:g}", judged & (z <= -t)) for t in ts]
    return {"judged": int(judged.sum()), "truly_safe": int((~unsafe).sum()),
            "verdicts": {name: [int((ok & unsafe).sum()), int((ok & ~unsafe).sum())] for name, ok in verdicts}}


def _slack_row(job: tuple[str, int, bool]) -> dict[str, Any]:
    """One look's :func:`slack_counts` (poses as ``--risk`` judges them; ``start``: round the
    start, set down on the ring)."""
    scene, world_seed, start = job
    out = evaluate(scene, "approach", BoundsParams().cell, world_seed, world_seed, [], ChanceParams().samples,
                   RoverBody(), made="map", start=start, models=[ChanceParams()])
    row = out["rows"][1]
    return {"scene": scene, "world_seed": world_seed,
            **slack_counts(out["unsafe"], row["safe"], row["unknown"], row["z"])}


def slack(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per scene and verdict, the looks' :func:`slack_counts` summed: false safes, their 95 % bound
    and the truly safe kept (of all). Whether the check's stated probability has slack at the
    pose level: if a lower ``t`` kept many more truly safe poses for few false safes, the model's
    spread would be too wide where it decides; if the false safes climb with the kept share, the
    spread is what the truth asks (3.43 is the declared epsilon's normal tail)."""
    out = []
    for scene in dict.fromkeys(r["scene"] for r in rows):
        sel = [r for r in rows if r["scene"] == scene]
        n, truly_safe = sum(r["judged"] for r in sel), max(1, sum(r["truly_safe"] for r in sel))
        for name in sel[0]["verdicts"]:
            fs, kept = (sum(r["verdicts"][name][i] for r in sel) for i in (0, 1))
            out.append({"scene": scene, "looks": len(sel), "verdict": name, "judged": n, "false_safe": fs,
                        "bound": clopper_pearson_upper(fs, n) if n else float("nan"), "kept": kept / truly_safe})
    return out


def timing(body: RoverBody, samples: int, poses: int = 1000) -> list[tuple[str, float]]:
    """Seconds per ``poses`` poses on a 4 x 4 m window of 5 cm cells: the worst-case check on bounds
    +-2.5 sigma, and the chance check where every pose is sampled (ground with 10 cm rocks, cells
    known to 1 cm) and where the screen clears every pose (flat ground known to 2 mm)."""
    g = GridGeometry.covering(-2.0, -2.0, 2.0, 2.0, 0.05)
    rng = np.random.default_rng(0)
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    rocky = np.zeros(g.shape)
    for x, y in rng.uniform(-1.8, 1.8, (40, 2)):
        rocky[np.hypot(X - x, Y - y) < 0.08] = 0.10
    at = np.column_stack([rng.uniform(-1.0, 1.0, poses), rng.uniform(-1.0, 1.0, poses), rng.uniform(-180, 180, poses)])
    out = []
    sd = 0.01
    t0 = time.perf_counter()
    check_poses(((rocky - 2.5 * sd).astype(np.float32), (rocky + 2.5 * sd).astype(np.float32)), g, at, body)
    out.append(("worst case on bounds", time.perf_counter() - t0))
    params = ChanceParams(samples=samples)
    for name, h, sigma in (("chance, every pose sampled", rocky, sd), ("chance, every pose screened", rocky * 0, 0.002)):
        post = Posterior(h, np.full(g.shape, sigma * sigma), np.full(g.shape, np.inf))
        t0 = time.perf_counter()
        c = chance_check(post, g, at, body, params)
        out.append((f"{name} ({int(c.screened.sum())} screened)", time.perf_counter() - t0))
    return out


def against_set(words: list[str]) -> dict[str, float]:
    """One ``--against`` set: NAME=VALUE words as ChanceParams changes, a clear error for a name
    the check does not declare."""
    known = {f.name for f in dataclasses.fields(ChanceParams)}
    declared = ChanceParams()
    out: dict[str, float] = {}
    for word in words:
        name, eq, value = word.partition("=")
        try:
            if not eq or name not in known:
                raise ValueError(name)
            out[name] = type(getattr(declared, name))(float(value))
        except ValueError:
            raise SystemExit(f"ERROR: --against takes NAME=VALUE, NAME one of {', '.join(sorted(known))} and "
                             f"VALUE a number; got {word!r}") from None
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="marsyard")
    ap.add_argument("--look", default="sweep", choices=LOOKS)
    ap.add_argument("--cell", type=float, default=BoundsParams().cell)
    ap.add_argument("--world-seed", type=int, default=1, help="the scene's rock draw (the bounds bench's: 1)")
    ap.add_argument("--seed", type=int, default=0, help="the ToF noise draw")
    ap.add_argument("--calibrate", action="store_true", help="fit the rock-edge error model instead")
    ap.add_argument("--rock-top", action="store_true",
                    help="with --scenes and --world-seeds: how far rock tops away from an edge are read low, per "
                         "band of the rock's height, against the rock top's declared common sigma")
    ap.add_argument("--epsilon", nargs="+", type=float, default=[1e-2, 1e-3, 1e-4])
    ap.add_argument("--samples", type=int, default=ChanceParams().samples)
    ap.add_argument("--rock-sigma", type=float, default=ChanceParams().rock_sigma,
                    help="ChanceParams.rock_sigma for the table (what the declared value is weighed against)")
    ap.add_argument("--posterior", choices=["look", "map", "one"], default="look",
                    help="seen from the look's sensor (look), as the chooser makes it (map), or that with one "
                         "return's horizontal error (one)")
    ap.add_argument("--risk", action="store_true",
                    help="the stated risk: the chance check at the declared epsilon over --world-seeds, per scene")
    ap.add_argument("--scenes", nargs="+", default=["marsyard", "hirise", "dense"], help="with --risk")
    ap.add_argument("--world-seeds", nargs="+", type=int, default=[20, 21, 22],
                    help="with --risk: rock draws no setting was tuned on")
    ap.add_argument("--jobs", type=int, default=1, help="with --risk: looks run in this many processes")
    ap.add_argument("--set-down", action="store_true",
                    help="the ring set-down at the rover's start and the poses round it (the blind disc's prior "
                         "judged) instead of the poses 1.6-4.0 m ahead")
    ap.add_argument("--prior-own", type=float, default=ChanceParams().prior_own,
                    help="ChanceParams.prior_own (1: a prior's error drawn cell by cell)")
    ap.add_argument("--shared-length", type=float, default=ChanceParams().shared_length,
                    help="ChanceParams.shared_length (m)")
    ap.add_argument("--correlation", action="store_true",
                    help="the spatial correlation of the map means' errors and of the blind disc's ground off its "
                         "plane, on the truth")
    ap.add_argument("--against", nargs="+", action="append", default=[], metavar="NAME=VALUE",
                    help="with --risk: also judge each look with these ChanceParams changed (e.g. a term "
                         "at 0: the model without it), on the same map and draws, and tabulate both; given "
                         "again, each set is judged and tabulated apart (e.g. --against epsilon=1e-4 "
                         "--against epsilon=3e-5: one fused map and one truth for every setting)")
    ap.add_argument("--bounds", nargs="+", default=[], metavar="KEY=VALUE",
                    help="with --risk: the bounds map's parameters (BoundsParams, e.g. stereo_first=false): a map "
                         "of its own, so a run of its own")
    ap.add_argument("--slack", action="store_true",
                    help="with --scenes and --world-seeds: the declared verdict against a threshold on the draws' "
                         "margin in sigmas, whether the stated probability has slack at the pose level (with "
                         "--set-down: round the start)")
    ap.add_argument("--time", action="store_true", help="time 1,000 poses on a synthetic 5 cm window instead")
    args = ap.parse_args(argv)
    if args.time:
        for name, seconds in timing(RoverBody(), args.samples):
            print(f"{name}: {seconds:.2f} s per 1,000 poses ({args.samples} samples)")
        return
    if args.slack:
        rows = streamed(_slack_row, [(sc, ws, args.set_down) for ws in args.world_seeds for sc in args.scenes],
                        args.jobs)
        print(f"the draws' margin against the truth, {'round the start' if args.set_down else '1.6-4.0 m ahead'}")
        print("| scene | looks | verdict | judged | false safe | 95 % bound | truly safe kept (of all) |")
        print("|---|---|---|---|---|---|---|")
        for r in slack(rows):
            print(f"| {r['scene']} | {r['looks']} | {r['verdict']} | {r['judged']:,} | {r['false_safe']} | "
                  f"{r['bound']:.1e} | {100 * r['kept']:.1f} % |")
        return
    if args.risk:
        against = [against_set(words) for words in args.against]
        try:
            params = BoundsParams(**BoundsParams.parse_assignments(args.bounds, flag="--bounds"))
        except SettingError as exc:
            raise SystemExit(f"ERROR: {exc}") from None
        rows = risk(args.scenes, [args.look], args.world_seeds, args.cell, args.samples, args.jobs, against, params)
        print(f"\nthe chance check at epsilon {ChanceParams().epsilon:g}, the chooser's posterior, {args.look} looks"
              + (f", the map's {' '.join(args.bounds)}" if args.bounds else ""))
        print("\n".join(risk_table(rows)))
        for i, words in enumerate(args.against):
            print(f"\nthe same with {' '.join(words)}")
            print("\n".join(risk_table([{**r, **r["against"][i]} for r in rows])))
        return
    head = f"{args.scene}, {args.look} ({args.posterior} posterior), cell {args.cell * 100:g} cm, rock draw {args.world_seed}, noise draw {args.seed}"
    if args.correlation:
        out = correlation(args.scene, args.look, args.cell, args.world_seed, args.seed)
        print(head)
        print("| error | cells | sd (cm) | own sd, median (cm) | correlation at " +
              ", ".join(f"{lag * args.cell * 100:g}" for lag in LAGS) + " cm |")
        print("|---|---|---|---|---|")
        for r in out["rows"]:
            print(f"| {r['what']} | {r['cells']} | {100 * r['sd']:.2f} | {100 * r['own']:.2f} | "
                  + " / ".join(f"{c:.2f}" for c in r["corr"]) + " |")
        return
    if args.rock_top:
        print(f"look {args.look}, cell {args.cell:g} m, world draws {' '.join(map(str, args.world_seeds))}, "
              "cells with J under 4 cm")
        sets = ["declared", *(" ".join(words) for words in args.against)]
        print("| setting | scene | rock height H (cm) | cells | true top - estimate: median / p99 / p99.9 / max (cm) "
              "| own sd (cm) | common sigma p99.9 needs (cm) | declared (cm) | worst 1 %: mean read low / relief missed "
              "(cm) |")
        print("|---|---|---|---|---|---|---|---|---|")
        for r in rock_top(args.scenes, args.look, args.cell, args.world_seeds, args.jobs,
                          [against_set(words) for words in args.against]):
            lo, hi = r["band"]
            print(f"| {sets[r['setting']]} | {r['scene']} | {lo * 100:g}-{hi * 100:g} | {r['cells']} | "
                  f"{100 * r['median']:.2f} / "
                  f"{100 * r['q99']:.2f} / {100 * r['q999']:.2f} / {100 * r['max']:.2f} | {100 * r['own_sd']:.2f} "
                  f"| {100 * r['needed']:.2f} | {100 * r['declared']:.2f} | {100 * r['worst_mean']:.2f} / "
                  f"{100 * r['worst_relief']:.2f} |")
        return
    if args.calibrate:
        out = calibrate(args.scene, args.look, args.cell, args.world_seed, args.seed, args.posterior)
        print(f"{head}: {out['cells']} cells with returns")
        print("| headroom J (cm) | cells | mean J (cm) | true top - estimate: median / p99.9 (cm) | posterior sd "
              "without edge terms (cm) | z p99.9 without / with the fit | share with z > 3.09 with the fit | "
              "z p99.9 / share over 3.09, declared model |")
        print("|---|---|---|---|---|---|---|---|")
        for r in out["rows"]:
            lo, hi = r["band"]
            print(f"| {lo * 100:g}-{hi * 100:g} | {r['cells']} | {100 * r['J']:.1f} | {100 * r['median']:.2f} / "
                  f"{100 * r['q999']:.2f} | {100 * r['model_sd']:.2f} | {r['z999']:.1f} / {r['z999_fit']:.2f} "
                  f"| {100 * r['over_fit']:.2f} % | {r['z999_declared']:.2f} / {100 * r['over_declared']:.2f} % |")
        print(f"edge_bias {out['edge_bias']:.3f}, edge_sigma {out['edge_sigma']:.3f}, top_sigma {out['top_sigma']:.4f} m")
        return
    body = RoverBody()
    out = evaluate(args.scene, args.look, args.cell, args.world_seed, args.seed, args.epsilon, args.samples,
                   dataclasses.replace(body), args.rock_sigma, args.posterior, args.set_down,
                   prior_own=args.prior_own, shared_length=args.shared_length)
    if args.set_down:
        head += f"; set down at the start: {out['set_down']}; prior_own {args.prior_own:g}, shared_length {args.shared_length:g} m"
    print(f"{head}: {out['poses']} poses, {out['truly_unsafe']} truly unsafe")
    print("| check | judged | false safe | truly safe kept (of) | poses screened | ms per 1,000 poses |")
    print("|---|---|---|---|---|---|")
    for r in out["rows"]:
        print(f"| {r['check']} | {r['judged']} | {r['false_safe']} | {100 * r['kept']:.1f} % ({r['of']}) "
              f"| {r.get('screened', '-')} | {1000 * r['ms'] / out['poses']:.0f} |")


if __name__ == "__main__":
    main()
