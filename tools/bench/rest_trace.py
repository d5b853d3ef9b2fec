"""Benchmark: where the chooser's check stands each wheel, against the truth, at the poses it refused.

Reads a :mod:`tools.bench.gate_trace` dump (``--dump F.npz``: the last choices' maps and refused
poses) and judges every refused pose again on the posterior's best estimate as the check reads it
(``ChanceParams`` as given, ``--set within=1`` for the pair of tops and lows) and on the scene's
true 1 cm surface, standing the body as :func:`vehicle.check_poses` stands it: per wheel the
lowest and highest rest the map allows (the highest ground its circle touches, over the lows and
over the tops) and the true contact; the plane the worst belly figure is over; the belly's highest
ground over it, and the same at the truth. So a refused belly says which of them is off the
truth: the ground under the box read high (``belly_high``: the estimate's ground at its belly
point over the true ground's highest within that cell), or the resting plane read low
(``plane_low``: the truth's plane under the estimate's belly point over the estimate's).

    python -m tools.bench.rest_trace --scene marsyard --dump m0.npz --set within=1 --out rest_m0.json

``--cells``: instead, every cell a frame bounded in the dump's last choice's map against the
truth inside it, by the map's spread in the cell (rise + drop, what ``ChanceParams.within`` takes
for the cell's relief): the map's top over the true highest ground, its low (mean less drop) over
the true lowest, and the true relief (highest less lowest), medians and p10 / p90.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from typing import Any

import numpy as np

from drivers.sim.world import World
from prox_workflows.algorithms import chance
from prox_workflows.algorithms.vehicle import _TRIPLETS, _pattern, _sample, check_poses
from prox_workflows.grid import GridGeometry
from rvs_truth.surface import truth_surface
from tools.bench.chance_trace import stand
from tools.bench.gate_trace import dumped_choices


def stand_pair(low: np.ndarray, high: np.ndarray, geom: GridGeometry, pose: np.ndarray, body: Any, step: float,
               rest_low: bool = True) -> dict[str, Any]:
    """The body at ``pose`` on a pair of surfaces (``low`` NaN: no rest there) read bilinearly, as
    :func:`chance._judge` reads a drawn pair: per wheel its lowest and highest rest (and where
    each is), and the worst belly figure over the planes its contacts allow (``rest_low``: the wheels
    on their lows, as the check stands a drawn pair; else every corner of the box of contacts), whose
    fourth wheel is at or under the plane, with the plane, the corner and the belly point."""
    pat = _pattern(body, step)
    rad = np.radians(pose[2])
    c, s = np.cos(rad), np.sin(rad)
    wx = pose[0] + c * pat.pts[:, 0] - s * pat.pts[:, 1]
    wy = pose[1] + s * pat.pts[:, 0] + c * pat.pts[:, 1]
    lo, hi = _sample(low, geom, wx, wy), _sample(high, geom, wx, wy)
    r = body.wheel_radius
    sag = r - np.sqrt(np.maximum(r * r - pat.dx * pat.dx, 0.0))
    hubs = np.asarray(body.wheels, float)
    contact = np.full((2, 4), np.nan)
    where = [[None] * 4, [None] * 4]
    for w in range(4):
        on = np.flatnonzero(pat.wheel_of == w)
        for k, h in enumerate((lo, hi)):
            v = h[on] - sag[on]
            if np.isfinite(v).any():
                j = on[np.nanargmax(v)]
                contact[k, w] = float(h[j] - sag[j])
                where[k][w] = (round(float(wx[j]), 3), round(float(wy[j]), 3), round(float(pat.dx[j]), 3))
    belly = np.flatnonzero(pat.belly)
    hb = np.where(np.isfinite(hi[belly]), hi[belly], np.nanmax(hi))
    worst: tuple[float, Any, Any, Any] = (-np.inf, None, None, None)
    for t in _TRIPLETS:
        A = np.column_stack([hubs[list(t[:3])], np.ones(3)])
        for corner in [(0, 0, 0)] if rest_low else np.ndindex(2, 2, 2):
            z = np.array([contact[corner[i], t[i]] for i in range(3)])
            a, b, c0 = np.linalg.solve(A, z)
            fx, fy = hubs[t[3]]
            if not contact[0, t[3]] <= a * fx + b * fy + c0 + 1e-9:
                continue
            over = hb - (a * pat.pts[belly, 0] + b * pat.pts[belly, 1] + c0)
            i = int(np.nanargmax(over))
            if over[i] > worst[0]:
                worst = (float(over[i]), int(belly[i]), (float(a), float(b), float(c0)), (t, corner))
    intr, i, plane, which = worst
    return {"contact_low": contact[0].tolist(), "contact_high": contact[1].tolist(), "where_low": where[0],
            "where_high": where[1], "intrusion": intr - body.clearance,
            "belly_xy": (float(wx[i]), float(wy[i])) if i is not None else None,
            "belly_local": (float(pat.pts[i, 0]), float(pat.pts[i, 1])) if i is not None else None,
            "belly_h": float(hb[np.flatnonzero(belly == i)[0]]) if i is not None else None,
            "plane": plane, "triplet": None if which is None else [list(which[0]), list(which[1])]}


def _datum(stats: dict[str, np.ndarray], g: GridGeometry, fine: np.ndarray, tg: GridGeometry) -> float:
    """The map's heights over the truth's (the map's frame sets its datum at the rover's start): the
    median over the cells a frame bounded of their mean over the true surface there."""
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    ok = np.isfinite(stats["mean"]) & np.asarray(stats.get("framed", np.isfinite(stats["mean"])), bool)
    return float(np.nanmedian(stats["mean"][ok] - _sample(fine, tg, X[ok], Y[ok])))


def _cell_of(fine: np.ndarray, tg: GridGeometry, x0: float, y1: float, cell: float) -> np.ndarray:
    """The true samples whose 1 cm cells meet the map's cell with its top-left corner at (x0, y1)."""
    c0, c1 = int(np.floor((x0 - tg.xmin) / tg.cell)), int(np.ceil((x0 + cell - tg.xmin) / tg.cell))
    r0, r1 = int(np.floor((tg.ymax - y1) / tg.cell)), int(np.ceil((tg.ymax - y1 + cell) / tg.cell))
    return fine[max(r0, 0):r1, max(c0, 0):c1]


def true_cells(fine: np.ndarray, tg: GridGeometry, g: GridGeometry, datum: float) -> tuple[np.ndarray, ...]:
    """Per cell of ``g``: the truth's highest, lowest (its 1 cm samples meeting the cell) and their
    mean, in the map's datum (NaN off the truth)."""
    out = [np.full(g.shape, np.nan) for _ in range(3)]
    for r in range(g.height):
        for c in range(g.width):
            cell = _cell_of(fine, tg, g.xmin + c * g.cell, g.ymax - r * g.cell, g.cell)
            if cell.size:
                out[0][r, c], out[1][r, c], out[2][r, c] = cell.max(), cell.min(), cell.mean()
    return tuple(a + datum for a in out)


BANDS = (0.0, 0.01, 0.03, 0.06, np.inf)  # m: the map's spread in a cell


def cells(scene: str, dump: str) -> list[dict[str, Any]]:
    """The last choice's map of the dump, cell by cell against the truth, per band of spread."""
    d = np.load(dump)
    ci = max(int(k[1:].split("_")[0]) for k in d.files if k.startswith("c") and k.endswith("_geom"))
    cell, xmin, ymax, width, height = d[f"c{ci}_geom"]
    g = GridGeometry(float(cell), float(xmin), float(ymax), int(width), int(height))
    st = {n: d[f"c{ci}_{n}"] for n in ("mean", "rise", "drop", "framed")}
    world = World.from_scene(scene)
    fine, tg, _ = truth_surface(world, scene)
    high, low, _mean = true_cells(fine, tg, g, _datum(st, g, fine, tg))
    top, floor, spread = st["mean"] + st["rise"], st["mean"] - st["drop"], st["rise"] + st["drop"]
    ok = np.isfinite(top) & st["framed"].astype(bool) & np.isfinite(high)
    rows = []
    for lo, hi in zip(BANDS[:-1], BANDS[1:], strict=True):
        m = ok & (spread >= lo) & (spread < hi)
        if m.sum() < 20:
            continue

        def q(a: np.ndarray, m: np.ndarray = m) -> list[float]:
            return [round(float(v) * 100, 2) for v in np.percentile(a[m], [10, 50, 90])]

        rows.append({"spread_cm": [lo * 100, hi * 100], "cells": int(m.sum()), "top_over_true_highest_cm": q(top - high),
                     "low_over_true_lowest_cm": q(floor - low), "true_relief_cm": q(high - low)})
    return rows


def _at(plane: tuple[float, float, float], local: tuple[float, float]) -> float:
    return plane[0] * local[0] + plane[1] * local[1] + plane[2]


def trace(scene: str, dump: str, params: chance.ChanceParams, limit: int = 0, box: bool = False
          ) -> list[dict[str, Any]]:
    """Every refused pose of the dump's choices, stood on the best estimate and on the truth
    (``box``: each wheel anywhere between its low and its top, the worst corner judged)."""
    d = np.load(dump)
    world = World.from_scene(scene)
    fine, tg, _ = truth_surface(world, scene)
    body = world.body
    out = []
    for ci, refused, g, stats, k in dumped_choices(d):
        post = chance.posterior(stats, g, k, params)
        seen = np.isfinite(post.mean)
        best = post.best()
        span = np.zeros(best.shape) if post.span is None else np.where(seen, post.span, 0.0)
        low = np.where(seen, best - span, np.nan).astype(np.float32)
        high = best.astype(np.float32)
        top = stats["mean"] + stats["rise"]
        poses = np.asarray(refused, float)[: limit or None]
        nominal = chance.chance_check(post, g, poses, body, params)
        truth = check_poses(fine, tg, poses, body)
        rover = d[f"c{ci}_pose"]
        datum = _datum(stats, g, fine, tg)
        for n, p in enumerate(poses):
            e = stand_pair(low, high, g, p, body, g.cell, rest_low=not box)
            t = stand(fine, tg, p, body, 0.01)
            row: dict[str, Any] = {"choice": ci, "pose": [round(float(v), 3) for v in p],
                                   "from_rover": round(float(np.hypot(*(p[:2] - rover[:2]))), 3),
                                   "p_any": float(nominal.p_any[n]),
                                   "best": [round(float(v), 4) for v in nominal.nominal.excess[n]],
                                   "truth": [round(float(v), 4) for v in truth.excess[n]],
                                   "est_intrusion": round(e["intrusion"], 4), "true_intrusion": round(t["intrusion"], 4),
                                   "datum": round(datum, 4)}
            if e["belly_xy"] is not None:
                bx, by = e["belly_xy"]
                col, r_ = int((bx - g.xmin) / g.cell), int((g.ymax - by) / g.cell)
                # the truth's highest ground within the estimate's belly cell, and its plane there
                x0, y1 = g.xmin + col * g.cell, g.ymax - r_ * g.cell
                true_cell = _cell_of(fine, tg, x0, y1, g.cell) + datum
                tpl = _at(t["plane"], e["belly_local"]) + datum
                epl = _at(e["plane"], e["belly_local"])
                row.update(belly_point=[round(bx, 3), round(by, 3)], belly_local=[round(v, 3) for v in e["belly_local"]],
                           est_belly_ground=round(e["belly_h"], 4),
                           true_cell_top=round(float(true_cell.max()), 4) if true_cell.size else None,
                           true_at_point=round(float(_sample(fine, tg, np.array([bx]), np.array([by]))[0]) + datum, 4),
                           belly_high=round(e["belly_h"] - float(true_cell.max()), 4) if true_cell.size else None,
                           est_plane=round(epl, 4), true_plane=round(tpl, 4), plane_low=round(tpl - epl, 4),
                           belly_cell={"seen": bool(seen[r_, col]), "top": round(float(top[r_, col]), 4),
                                       "span": round(float(span[r_, col]), 4),
                                       "sd": round(float(np.sqrt(np.nan_to_num(post.var[r_, col]))), 4)},
                           triplet=e["triplet"])
            wheels = []
            for w in range(4):
                item = {"true": round(t["contacts"][w][0] + datum, 4),
                        "low": round(e["contact_low"][w], 4), "high": round(e["contact_high"][w], 4),
                        "where_low": e["where_low"][w]}
                wl = e["where_low"][w]
                if wl is not None:
                    col, r_ = int((wl[0] - g.xmin) / g.cell), int((g.ymax - wl[1]) / g.cell)
                    item["low_cell"] = {"top": round(float(top[r_, col]), 4), "span": round(float(span[r_, col]), 4),
                                        "rise": round(float(stats["rise"][r_, col]), 4),
                                        "drop": round(float(stats["drop"][r_, col]), 4),
                                        "framed": bool(stats["framed"][r_, col]) if "framed" in stats else None}
                # how many of the wheel's cells have no return (a ray's height only)
                wheels.append(item)
            row["wheels"] = wheels
            out.append(row)
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="marsyard")
    ap.add_argument("--dump", required=True, help="a gate_trace --dump file")
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE", help="a ChanceParams field")
    ap.add_argument("--limit", type=int, default=0, help="at most this many refused poses a choice (0: all)")
    ap.add_argument("--box", action="store_true", help="stand each wheel anywhere between its low and its top "
                                                       "(the worst corner), not on its low")
    ap.add_argument("--cells", action="store_true", help="the last choice's cells against the truth, by the map's "
                                                         "spread in the cell")
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)
    if args.cells:
        rows = cells(args.scene, args.dump)
        with open(args.out, "w") as f:
            json.dump(rows, f, indent=1)
        for r in rows:
            print(json.dumps(r))
        return
    params = chance.ChanceParams()
    for kv in args.set:
        key, value = kv.split("=", 1)
        params = dataclasses.replace(params, **{key: type(getattr(params, key))(value)})
    rows = trace(args.scene, args.dump, params, args.limit, args.box)
    with open(args.out, "w") as f:
        json.dump(rows, f, indent=1, default=float)
    belly = [r for r in rows if r["est_intrusion"] > 0]
    print(f"{len(rows)} refused poses, {len(belly)} over the belly on the best estimate stood so, "
          f"{sum(r['truth'][1] > 0 for r in belly)} of them truly")
    if belly:
        mixed = [r for r in belly if r.get("triplet") and any(r["triplet"][1])]
        print(f"  worst plane with a wheel at its top: {len(mixed)} of {len(belly)}")
        lo = np.array([[w["low"] - w["true"] for w in r["wheels"]] for r in belly], float)
        hi = np.array([[w["high"] - w["true"] for w in r["wheels"]] for r in belly], float)
        print(f"  a wheel's low over its true contact: median {np.nanmedian(lo) * 100:+.2f} cm, under it by more than "
              f"2 mm {np.mean(lo < -0.002) * 100:.0f} %, over it {np.mean(lo > 0.002) * 100:.0f} %; its top over it: median {np.nanmedian(hi) * 100:+.2f} cm")
        for name in ("est_intrusion", "true_intrusion", "belly_high", "plane_low"):
            v = np.array([r[name] for r in belly if r.get(name) is not None], float)
            print(f"  {name}: median {np.median(v) * 100:+.2f} cm (p10 {np.percentile(v, 10) * 100:+.2f}, "
                  f"p90 {np.percentile(v, 90) * 100:+.2f})")


if __name__ == "__main__":
    main()
