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
import json
from typing import Any

import numpy as np

from drivers.sim.rover import RoverBody
from prox_workflows.algorithms.chance import ChanceParams, posterior
from prox_workflows.algorithms.vehicle import _TRIPLETS, _pattern, _sample, check_poses
from prox_workflows.grid import GridGeometry
from tools.bench.bounds import TRUE_CELL, pooled
from tools.bench.chance import fused, whole


def stand(heights: np.ndarray, geom: GridGeometry, pose: np.ndarray, body: RoverBody, step: float
          ) -> dict[str, Any]:
    """The body at ``pose`` on one height grid, as the vehicle check stands it: per wheel the
    contact (height and where), the resting planes, and the belly's highest ground over the worse
    plane (where, how high)."""
    pat = _pattern(body, step)
    rad = np.radians(pose[2])
    c, s = np.cos(rad), np.sin(rad)
    wx = pose[0] + c * pat.pts[:, 0] - s * pat.pts[:, 1]
    wy = pose[1] + s * pat.pts[:, 0] + c * pat.pts[:, 1]
    h = _sample(heights, geom, wx, wy)
    r = body.wheel_radius
    sag = r - np.sqrt(np.maximum(r * r - pat.dx * pat.dx, 0.0))
    hubs = np.asarray(body.wheels, float)
    contacts = []
    for w in range(4):
        on = np.flatnonzero(pat.wheel_of == w)
        j = on[np.nanargmax(h[on] - sag[on])]
        contacts.append((float(h[j] - sag[j]), float(wx[j]), float(wy[j])))
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
    best = np.where(np.isfinite(post.mean), post.mean, np.where(np.isfinite(post.ceiling), post.ceiling, np.nan))
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
                "upper": round(float(stats["upper"][row, col]), 4),
                "elev_deg": round(float(np.degrees(np.arctan2(viewpoint[2] - top[row, col], d))), 1),
                "range": round(float(d), 2),
                "slope_toward_sensor": round(float((near - far) / 0.04), 2)}

    for pose in poses:
        p = np.asarray(pose, float)
        t = stand(truth, tg, p, body, 0.01)
        e = stand(best.astype(np.float32), g, p, body, g.cell)
        on_est = check_poses(best.astype(np.float32), g, p[None], body).excess[0]
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


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--log", required=True, help="the JSON rows of a --risk run")
    ap.add_argument("--look", default="approach")
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)
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
