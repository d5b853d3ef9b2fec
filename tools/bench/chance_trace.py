"""Benchmark: each false safe of the chance check traced against the truth, cell by cell.

For every pose the stated-risk run (``python -m tools.bench.chance --risk``) calls safe and the
true surface does not, the body is stood on the truth (1 cm) and on the posterior's best estimate
(the chooser's, no viewpoint) as :func:`vehicle.check_poses` stands it: each wheel's contact (the
highest ground its circle touches), the resting plane (three contacts, the fourth at or under it,
the worse of such planes for the belly) and the belly's highest ground over it. The truth's belly
point and contacts are then read in the map's cells: the true top pooled to the cell (highest),
the posterior's mean and its sigma (own and common), and so which error makes the miss:
the ground under the belly read low (``belly_low``: true minus estimate at the belly point), or the
resting plane read high under the belly point (``plane_high``: the estimate's plane over the
truth's there). The cell's view is given too: its returns' elevation from the look's sensor and
whether the sensor sees the cell's face toward it (the true top rising toward the sensor) or only
its back (the top falls away from the sensor: returns at a grazing angle from the front of a
rock, its back face unseen).

    python -m tools.bench.chance_trace --log /work/helpers/risk_main2.log --out trace.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from collections import Counter
from typing import Any

import numpy as np

from drivers.sim.rover import RoverBody
from prox_workflows.algorithms.chance import ChanceParams, _judge, chance_check, headroom, posterior
from prox_workflows.algorithms.vehicle import _TRIPLETS, LIMITS, _pattern, _sample, check_poses
from prox_workflows.grid import GridGeometry
from tools.bench.bounds import TRUE_CELL, pooled
from tools.bench.chance import fused, whole


def stand(heights: np.ndarray, geom: GridGeometry, pose: np.ndarray, body: RoverBody, step: float,
          low: np.ndarray | None = None) -> dict[str, Any]:
    """The body at ``pose`` on one height grid, as the vehicle check stands it: per wheel the
    contact (height and where), the resting planes, and the belly's highest ground over the worse
    plane (where, how high). ``low``: the pair the declared check judges (``ChanceParams.within``),
    each wheel resting on its highest low (NaN: only a ray bounds the ground there) and the belly
    over ``heights``, the tops."""
    pat = _pattern(body, step)
    rad = np.radians(pose[2])
    c, s = np.cos(rad), np.sin(rad)
    wx = pose[0] + c * pat.pts[:, 0] - s * pat.pts[:, 1]
    wy = pose[1] + s * pat.pts[:, 0] + c * pat.pts[:, 1]
    h = _sample(heights, geom, wx, wy)
    rest = h if low is None else _sample(low, geom, wx, wy)
    r = body.wheel_radius
    sag = r - np.sqrt(np.maximum(r * r - pat.dx * pat.dx, 0.0))
    hubs = np.asarray(body.wheels, float)
    contacts = []
    for w in range(4):
        on = np.flatnonzero(pat.wheel_of == w)
        j = on[np.nanargmax(rest[on] - sag[on])]
        contacts.append((float(rest[j] - sag[j]), float(wx[j]), float(wy[j])))
    z = np.array([cz for cz, _, _ in contacts])
    belly = np.flatnonzero(pat.belly)
    worst = (-np.inf, None, None)
    for t in _TRIPLETS:
        A = np.column_stack([hubs[list(t[:3])], np.ones(3)])
        a, b, c0 = np.linalg.solve(A, z[list(t[:3])])
        fx, fy = hubs[t[3]]
        if z[t[3]] > a * fx + b * fy + c0 + 1e-9:
            continue
        over = h[belly] - (a * pat.pts[belly, 0] + b * pat.pts[belly, 1] + c0)
        i = int(np.nanargmax(over))
        if over[i] > worst[0]:
            worst = (float(over[i]), belly[i], (float(a), float(b), float(c0)))
    intr, i, plane = worst
    return {"contacts": contacts, "intrusion": intr - body.clearance, "belly_xy": (float(wx[i]), float(wy[i])),
            "belly_local": (float(pat.pts[i, 0]), float(pat.pts[i, 1])), "belly_h": float(h[i]), "plane": plane}


def _plane_at(plane: tuple[float, float, float], local: tuple[float, float]) -> float:
    a, b, c = plane
    return a * local[0] + b * local[1] + c


def trace_look(scene: str, look: str, world_seed: int, poses: list[list[float]], cell: float = 0.025
               ) -> list[dict[str, Any]]:
    world, bounds, viewpoint = fused(scene, look, cell, world_seed, world_seed)
    stats, g = whole(bounds)
    params = ChanceParams()
    post = posterior(stats, g, bounds.params.k, params, None)
    box = (g.xmin, g.ymin, g.xmin + g.width * g.cell, g.ymax)
    truth = world.true_dem(0.01, box)
    tg = GridGeometry(0.01, g.xmin, g.ymax, truth.shape[1], truth.shape[0])
    fine = world.true_dem(TRUE_CELL, box)
    top, floor = pooled(fine, g, np.max), pooled(fine, g, np.min)
    seen = np.isfinite(post.mean)
    best = post.best()
    # the wheels' rests as the declared check reads them: the tops less the cell's relief, none
    # where only a ray bounds the ground (None: one surface, within 0)
    span = None if post.span is None else np.where(seen, post.span, 0.0)
    low = None if span is None else np.where(seen, best - span, np.nan).astype(np.float32)
    jump = headroom(stats, np.asarray(stats["mean"], np.float64) + np.asarray(stats["rise"], np.float64))
    common = np.broadcast_to(post.common, post.mean.shape)
    body = RoverBody()
    out = []

    def cell_at(x: float, y: float) -> dict[str, Any]:
        col, row = int((x - g.xmin) / g.cell), int((g.ymax - y) / g.cell)
        d = np.hypot(x - viewpoint[0], y - viewpoint[1])
        # the true top's slope along the ray (toward the sensor: + rises toward it, the face seen)
        ux, uy = (viewpoint[0] - x) / d, (viewpoint[1] - y) / d
        near = _sample(truth, tg, np.array([x + 0.02 * ux]), np.array([y + 0.02 * uy]))[0]
        far = _sample(truth, tg, np.array([x - 0.02 * ux]), np.array([y - 0.02 * uy]))[0]
        return {"true_top": round(float(top[row, col]), 4), "mean": round(float(post.mean[row, col]), 4),
                "sd_own": round(float(np.sqrt(post.var[row, col])), 4),
                "sd_common": round(float(common[row, col]), 4),
                "z": round(float((top[row, col] - post.mean[row, col])
                                 / np.sqrt(post.var[row, col] + common[row, col] ** 2)), 2),
                "true_floor": round(float(floor[row, col]), 4),
                "rise": round(float(stats["rise"][row, col]), 4), "drop": round(float(stats["drop"][row, col]), 4),
                # the frames' own relief in the cell (rise + drop over it: the frames' disagreement)
                "relief": round(float(stats["relief"][row, col]), 4) if "relief" in stats else None,
                "span": None if span is None else round(float(span[row, col]), 4),
                "headroom": round(float(jump[row, col]), 4), "ray_only": bool(not seen[row, col]),
                "framed": bool(stats["framed"][row, col]),
                "upper": round(float(stats["upper"][row, col]), 4),
                "elev_deg": round(float(np.degrees(np.arctan2(viewpoint[2] - top[row, col], d))), 1),
                "range": round(float(d), 2),
                "slope_toward_sensor": round(float((near - far) / 0.04), 2)}

    for pose in poses:
        p = np.asarray(pose, float)
        t = stand(truth, tg, p, body, 0.01)
        e = stand(best.astype(np.float32), g, p, body, g.cell, low)
        on_est = _judge(best, seen, span, g, p[None], body, None).excess[0]
        bl = t["belly_local"]
        est_h = float(_sample(best.astype(np.float32), g, np.array([t["belly_xy"][0]]),
                              np.array([t["belly_xy"][1]]))[0])
        est_plane = _plane_at(e["plane"], bl) if e["plane"] else float("nan")
        true_plane = _plane_at(t["plane"], bl)
        out.append({"scene": scene, "world_seed": world_seed, "pose": pose,
                    "truth_intrusion": round(t["intrusion"], 4), "estimate_intrusion": round(e["intrusion"], 4),
                    "estimate_excess": [round(float(v), 4) for v in on_est],
                    "belly_point_local": [round(v, 3) for v in bl],
                    "belly_low": round(t["belly_h"] - est_h, 4),
                    "plane_high": round(est_plane - true_plane, 4),
                    "belly_cell": cell_at(*t["belly_xy"]),
                    "wheels": [{"true": round(tc[0], 4), "estimate": round(ec[0], 4), "cell": cell_at(tc[1], tc[2]),
                                "estimate_cell": cell_at(ec[1], ec[2]),
                                "truth_at_estimate": round(float(_sample(truth, tg, np.array([ec[1]]),
                                                                         np.array([ec[2]]))[0]), 4)}
                               for tc, ec in zip(t["contacts"], e["contacts"], strict=True)]})
    return out


def by_term(truly_unsafe: np.ndarray, checks: dict[str, Any]) -> dict[str, Any]:
    """Per pose verdicts (``safe``, ``unknown``) of the one surface (``one``), the pair without
    relief (``rays``) and the declared pair (``pair``) against the truth: the truly safe poses and
    false safes each keeps, and per term (the rays: a wheel over ground only a ray bounds rests
    on nothing; the relief: the rests lowered) the truly safe poses the one surface keeps that it
    loses, and the false safes of the one surface that it catches (a pose is the rays' where the
    pair without relief already loses or catches it)."""
    ok, bad = ~truly_unsafe, truly_unsafe
    one, rays, pair = (checks[n] for n in ("one", "rays", "pair"))
    lost_rays = ok & one.safe & ~rays.safe
    return {"truly_safe": int(ok.sum()),
            "kept": {n: int((c.safe & ok).sum()) for n, c in checks.items()},
            "false_safe": {n: int((c.safe & bad).sum()) for n, c in checks.items()},
            "lost_to_rays": {"poses": int(lost_rays.sum()), "unknown": int((lost_rays & rays.unknown).sum())},
            "caught_by_rays": int((bad & one.safe & ~rays.safe).sum()),
            "lost_to_relief": int((ok & one.safe & rays.safe & ~pair.safe).sum()),
            "caught_by_relief": int((bad & one.safe & rays.safe & ~pair.safe).sum()),
            "gained_by_relief": int((ok & ~one.safe & rays.safe & pair.safe).sum())}


def kept_trace(scene: str, look: str, world_seed: int, cell: float = 0.025) -> dict[str, Any]:
    """Which term of the declared check refuses the truly safe poses one surface (``within`` 0)
    keeps, and what each term buys: the same look's map and poses judged three times, by one
    surface, by the pair with no relief (``within`` at a hair over 0: a wheel over ground only a
    ray bounds rests on nothing, nothing lowered) and by the declared pair. A pose the one surface
    keeps is lost to the rays where the pair without relief already leaves it, else to the relief;
    per term, how many truly safe poses it costs and how many false safes of the one surface it
    catches, and at the poses the relief refuses, the limit and how far the wheels' rests (the
    lows) lie under the true contacts."""
    world, bounds, _ = fused(scene, look, cell, world_seed, world_seed)
    stats, g = whole(bounds)
    x0, y0, _ = world.rover_pose()
    truth = world.true_dem(0.01, (g.xmin, g.ymin, g.xmin + g.width * g.cell, g.ymax))
    tg = GridGeometry(0.01, g.xmin, g.ymax, truth.shape[1], truth.shape[0])
    px, py = np.meshgrid(x0 + np.arange(1.6, 4.0, 0.1), y0 + np.arange(-1.2, 1.25, 0.1))
    poses = np.column_stack([np.repeat(px.ravel(), 4), np.repeat(py.ravel(), 4),
                             np.tile([0.0, 45.0, 90.0, 135.0], px.size)])
    body = RoverBody()
    on_truth = check_poses(truth, tg, poses, body)
    declared = ChanceParams()
    checks = {}
    for name, within in (("one", 0.0), ("rays", 1e-6), ("pair", declared.within)):
        params = dataclasses.replace(declared, within=within)
        checks[name] = chance_check(posterior(stats, g, bounds.params.k, params, None), g, poses, body, params)
    out: dict[str, Any] = {"scene": scene, "world_seed": world_seed, **by_term(on_truth.unsafe, checks)}
    one, rays, pair = (checks[n] for n in ("one", "rays", "pair"))
    # the relief's refusals: the limit most likely over, and how far the best estimate's rests
    # lie from the truth's contacts (a rest under the true contact leans the plane off the truth)
    idx = np.flatnonzero(~on_truth.unsafe & one.safe & rays.safe & ~pair.safe)
    k, _ = pair.worst()
    out["relief_refused_on"] = dict(Counter(LIMITS[int(k[i])] for i in idx))
    out["relief_refused_on_best_estimate"] = int(pair.nominal.unsafe[idx].sum())
    if len(idx):
        post = posterior(stats, g, bounds.params.k, declared, None)
        seen = np.isfinite(post.mean)
        best = post.best()
        low = np.where(seen, best - post.span, np.nan).astype(np.float32)
        rest_err, span_at, plane_low = [], [], []
        for i in idx[:: max(1, len(idx) // 60)]:
            t = stand(truth, tg, poses[i], body, 0.01)
            e = stand(best.astype(np.float32), g, poses[i], body, g.cell, low)
            bl = t["belly_local"]
            plane_low.append(_plane_at(t["plane"], bl) - _plane_at(e["plane"], bl) if e["plane"] else np.nan)
            for (tz, _, _), (ez, ex, ey) in zip(t["contacts"], e["contacts"], strict=True):
                rest_err.append(ez - tz)
                col, row = int((ex - g.xmin) / g.cell), int((g.ymax - ey) / g.cell)
                span_at.append(float(post.span[row, col]))
        q = (10, 50, 90)
        out["relief_rest_minus_true_contact_cm"] = [round(100 * float(v), 2) for v in np.nanpercentile(rest_err, q)]
        out["relief_span_at_rest_cm"] = [round(100 * float(v), 2) for v in np.nanpercentile(span_at, q)]
        out["relief_plane_low_at_belly_cm"] = [round(100 * float(v), 2) for v in np.nanpercentile(plane_low, q)]
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--log", help="the JSON rows of a --risk run")
    ap.add_argument("--look", default="approach")
    ap.add_argument("--out", required=True)
    ap.add_argument("--kept", nargs=2, metavar=("SCENE", "DRAW"), action="append", default=[],
                    help="instead: which term refuses the truly safe poses the one surface keeps, on this "
                         "scene's rock draw (repeatable)")
    args = ap.parse_args(argv)
    if args.kept:
        outs = []
        for scene, draw in args.kept:
            outs.append(kept_trace(scene, args.look, int(draw)))
            print(json.dumps(outs[-1]), flush=True)
        with open(args.out, "w") as f:
            json.dump(outs, f, indent=1)
        return
    if not args.log:
        ap.error("--log (or --kept) is required")
    rows = [json.loads(line) for line in open(args.log) if line.startswith("{")]
    traced = []
    for r in rows:
        if r["misses"]:
            traced += trace_look(r["scene"], r["look"], r["world_seed"], [m["pose"] for m in r["misses"]])
            print(json.dumps(traced[-len(r["misses"]):]), flush=True)
    with open(args.out, "w") as f:
        json.dump(traced, f, indent=1)


if __name__ == "__main__":
    main()
