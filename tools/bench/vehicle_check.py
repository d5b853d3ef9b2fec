"""Benchmark: the vehicle check (:func:`prox_workflows.algorithms.vehicle.check_poses`, one
compiled pass per pose) against :func:`reference`, the same definitions as whole-batch numpy over
(poses, samples) arrays (the peer, and the tests' reference), on each scene's true
1 cm surface (256 and 4,096 poses) and on 5 cm bounds of it (256 poses).

Poses are seeded uniform draws over the scene's mission area (``rvs_truth.surface.AREA``, 1 m in
from its edge) at any heading: rocks, slopes, drops and open ground as the oracle's lattice and
the live check meet them. The bounds are each 5 cm cell's lowest and highest true height less and
plus 0.5 cm (the candidates bench's ``tight`` map). Before any time is shown the two are checked
to agree: margins within 1e-6 m and 1e-4 deg, the same safe and unknown flags and the same worst
limit per pose.

Timing: best of ``--rounds`` interleaved rounds (ours, then the peer; a busy moment on a shared
machine hits both alike), the median beside it, as wall time and as the process's CPU time
(steadier where other jobs share the cores), and the load average. The first call (compiling or
loading the kernel) is not timed.

    python -m tools.bench.vehicle_check [--scenes marsyard hirise dense] [--rounds 5]
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from drivers.sim.world import World
from prox_workflows.algorithms.vehicle import (
    _EDGE_SAMPLES,
    _GRADE_DIRECTIONS,
    _TRIPLETS,
    BOUNDS_STEP,
    PoseChecks,
    VehicleBody,
    _pattern,
    check_poses,
)
from prox_workflows.grid import GridGeometry
from rvs_truth.surface import AREA, area, truth_surface

SPREAD = 0.005  # m: the bounds' spread over each cell's true range
TOL_M, TOL_DEG = 1e-6, 1e-4


def _reference_sample(heights: np.ndarray, geom: GridGeometry, x: np.ndarray, y: np.ndarray, cellwise: bool
                      ) -> np.ndarray:
    if cellwise:
        c0 = np.floor((x - geom.xmin) / geom.cell).astype(np.int64)
        r0 = np.floor((geom.ymax - y) / geom.cell).astype(np.int64)
        inside = (r0 >= 0) & (r0 < geom.height) & (c0 >= 0) & (c0 < geom.width)
        out = heights[np.clip(r0, 0, geom.height - 1), np.clip(c0, 0, geom.width - 1)].astype(np.float64)
        return np.where(inside, out, np.nan)
    fc = (x - geom.xmin) / geom.cell - 0.5
    fr = (geom.ymax - y) / geom.cell - 0.5
    c0, r0 = np.floor(fc).astype(np.int64), np.floor(fr).astype(np.int64)
    tc, tr = fc - c0, fr - r0
    inside = (r0 >= 0) & (r0 < geom.height - 1) & (c0 >= 0) & (c0 < geom.width - 1)
    r0c, c0c = np.clip(r0, 0, geom.height - 2), np.clip(c0, 0, geom.width - 2)
    h = heights
    out = ((h[r0c, c0c] * (1 - tc) + h[r0c, c0c + 1] * tc) * (1 - tr)
           + (h[r0c + 1, c0c] * (1 - tc) + h[r0c + 1, c0c + 1] * tc) * tr)
    return np.where(inside, out, np.nan)


def _reference_tip(body: VehicleBody, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    hubs = np.abs(np.asarray(body.wheels, float))
    fore, side = float(hubs[:, 0].min()), float(hubs[:, 1].min())
    with np.errstate(divide="ignore", invalid="ignore"):
        reach = np.hypot(a, b) * np.minimum(fore / np.abs(a), side / np.abs(b))
    return np.degrees(np.arctan(np.nan_to_num(reach, nan=np.inf) / body.cog_height))


def _reference_edges(lo: np.ndarray, hi: np.ndarray, lanes: np.ndarray) -> np.ndarray:
    out = np.full(len(lo), -np.inf)
    with np.errstate(invalid="ignore"):
        for k in range(1, min(_EDGE_SAMPLES, lanes.shape[1] - 1) + 1):
            a, b = lanes[:, :-k], lanes[:, k:]
            if hi is lo:
                up = np.abs(lo[:, b] - lo[:, a])  # (m, W, L - k)
            else:
                up = np.fmax(hi[:, b] - lo[:, a], hi[:, a] - lo[:, b])
            out = np.fmax(out, np.fmax.reduce(up.reshape(len(lo), -1), axis=1))
    return np.where(np.isinf(out), np.nan, out)


def reference(heights: np.ndarray | tuple[np.ndarray, np.ndarray], geom: GridGeometry, poses: np.ndarray,
              body: VehicleBody, step: float | None = None, chunk: int = 256) -> PoseChecks:
    """:func:`check_poses`'s definitions as numpy over chunks of poses ((chunk, samples) arrays),
    each limit as a few whole-array expressions, reading a bounds pair by the cell that holds each
    sample and sampling it every ``BOUNDS_STEP`` cells as ``check_poses`` does."""
    lower, upper = heights if isinstance(heights, tuple) else (heights, heights)
    bounded = lower is not upper
    poses = np.atleast_2d(np.asarray(poses, float))
    pat = _pattern(body, step or (geom.cell * BOUNDS_STEP if bounded else geom.cell))
    pts, wheel_of, belly = pat.pts, pat.wheel_of, pat.belly
    hubs = np.asarray(body.wheels, float)
    r = body.wheel_radius
    design = np.column_stack([pts, np.ones(len(pts))])
    ground_pinv = np.linalg.pinv(design)  # (3, S)
    u = np.linspace(0.0, np.pi, _GRADE_DIRECTIONS, endpoint=False)
    signs = np.sign(np.cos(u)[:, None] * ground_pinv[0] + np.sin(u)[:, None] * ground_pinv[1])  # (D, S)
    d = _GRADE_DIRECTIONS
    slopes = np.zeros((2 * len(pts), 2 + 2 * d))
    slopes[:len(pts), :2] = ground_pinv[:2].T
    slopes[len(pts):, 2:2 + d] = (signs * ground_pinv[0]).T
    slopes[len(pts):, 2 + d:] = (signs * ground_pinv[1]).T
    sag = r - np.sqrt(np.maximum(r * r - pat.dx * pat.dx, 0.0))
    planes = [(t, np.linalg.inv(np.column_stack([hubs[list(t[:3])], np.ones(3)]))) for t in _TRIPLETS]
    corners = [(0, 0, 0)] if not bounded else [(a, b, c) for a in (0, 1) for b in (0, 1) for c in (0, 1)]
    n = len(poses)
    edge = np.zeros((n, 4))
    intrusion = np.zeros(n)
    tilt = np.zeros(n)
    tip = np.full(n, 90.0)
    grade = np.zeros(n)
    stability = np.zeros(n)
    unknown = np.zeros(n, bool)
    for s in range(0, n, chunk):
        p = poses[s:s + chunk]
        m = len(p)
        c, si = np.cos(np.radians(p[:, 2]))[:, None], np.sin(np.radians(p[:, 2]))[:, None]
        wx = p[:, 0:1] + c * pts[:, 0] - si * pts[:, 1]
        wy = p[:, 1:2] + si * pts[:, 0] + c * pts[:, 1]
        lo = _reference_sample(lower, geom, wx, wy, bounded)
        hi = _reference_sample(upper, geom, wx, wy, bounded) if bounded else lo
        if bounded:
            unseen = np.isnan(hi).any(axis=1)
            for w in range(4):
                unseen |= np.isnan(lo[:, wheel_of == w]).mean(axis=1) > 0.5
            unknown[s:s + m] = unseen
            hi = np.where(np.isnan(hi), np.nanmax(np.where(np.isnan(hi).all(axis=1, keepdims=True), 0.0, hi),
                                                  axis=1, keepdims=True), hi)
            mid = (np.where(np.isnan(lo), hi, lo) + hi) / 2
            half = np.where(np.isnan(lo), 0.0, (hi - lo) / 2)
        else:
            if np.isnan(lo).any():
                low = np.nanmin(np.where(np.isnan(lo).all(axis=1, keepdims=True), 0.0, lo), axis=1, keepdims=True)
                lo = hi = np.where(np.isnan(lo), low, lo)
            mid = lo
        if bounded:
            ab = np.concatenate([mid, half], axis=1) @ slopes  # (m, 2 + 2D)
            grade_t = np.maximum(np.hypot(ab[:, :1] + ab[:, 2:2 + d], ab[:, 1:2] + ab[:, 2 + d:]).max(axis=1),
                                 np.hypot(ab[:, :1] - ab[:, 2:2 + d], ab[:, 1:2] - ab[:, 2 + d:]).max(axis=1))
        else:
            ab = mid @ slopes[:len(pts), :2]  # (m, 2): the fitted plane's a, b
            grade_t = np.hypot(ab[:, 0], ab[:, 1])
        grade[s:s + m] = np.degrees(np.arctan(grade_t))
        contact = np.empty((2, m, 4))
        with np.errstate(invalid="ignore"):
            for w in range(4):
                on = wheel_of == w
                edge[s:s + m, w] = _reference_edges(lo, hi, pat.lanes[w])
                contact[0, :, w] = np.fmax.reduce(lo[:, on] - sag[on], axis=1)
                contact[1, :, w] = (hi[:, on] - sag[on]).max(axis=1) if bounded else contact[0, :, w]
        open_box = (contact[1] - contact[0] > 1e-12).any(axis=1)
        worst_in = np.full(m, -np.inf)
        worst_st = np.full(m, -np.inf)
        worst_tilt, worst_tip = np.zeros(m), np.full(m, 90.0)
        for t, inv in planes:
            fourth = hubs[t[3]]
            for corner in corners:
                z3 = np.column_stack([contact[k, :, wheel] for k, wheel in zip(corner, t[:3], strict=True)])
                abc = z3 @ inv.T  # (m, 3): z = a x + b y + c
                rests = contact[0, :, t[3]] <= abc[:, 0] * fourth[0] + abc[:, 1] * fourth[1] + abc[:, 2] + 1e-9
                under = (hi[:, belly] - (abc[:, :2] @ pts[belly].T + abc[:, 2:3])).max(axis=1)
                angle = np.degrees(np.arctan(np.hypot(abc[:, 0], abc[:, 1])))
                limit = _reference_tip(body, abc[:, 0], abc[:, 1])
                margin = angle - limit / body.safety
                worst_in = np.where(rests, np.maximum(worst_in, under), worst_in)
                counts = (rests | open_box) & (margin > worst_st)
                worst_st = np.where(counts, margin, worst_st)
                worst_tilt = np.where(counts, angle, worst_tilt)
                worst_tip = np.where(counts, limit, worst_tip)
        intrusion[s:s + m] = worst_in - body.clearance
        stability[s:s + m] = np.where(np.isneginf(worst_st), np.nan, worst_st)
        tilt[s:s + m], tip[s:s + m] = worst_tilt, worst_tip
    excess = np.column_stack([edge.max(axis=1) - body.climb, intrusion, stability, grade - body.grade])
    return PoseChecks(step=edge, intrusion=intrusion, tilt=tilt, tip=tip, grade=grade, excess=excess,
                      wheel=np.nan_to_num(edge, nan=-np.inf).argmax(axis=1), unknown=unknown)


def disagreement(ours: PoseChecks, peer: PoseChecks, body: VehicleBody) -> list[str]:
    """What differs between two checks of the same poses beyond the tolerances (empty: they agree).
    A resting plane level to within rounding (tilt under 1e-9 deg: ground a hole was filled with
    one height) leans in the direction of its rounding error, so its tip-over angle (and the
    stability margin from it, tens of degrees under the limit either way) is that direction's, and
    is compared only where the plane leans."""
    out = []
    leans = (ours.tilt > 1e-9) | (peer.tilt > 1e-9)
    for name, tol in (("step", TOL_M), ("intrusion", TOL_M), ("tilt", TOL_DEG), ("tip", TOL_DEG),
                      ("stability", TOL_DEG), ("grade", TOL_DEG)):
        if name == "stability":
            a, b = ours.excess[:, 2], peer.excess[:, 2]
        else:
            a, b = getattr(ours, name), getattr(peer, name)
        if name in ("tip", "stability"):
            a, b = a[leans], b[leans]
        with np.errstate(invalid="ignore"):
            apart = ~((a == b) | (np.isnan(a) & np.isnan(b)))  # equal infinities and NaNs agree
            diff = np.abs(a - b)[apart]
        if (~np.isfinite(diff)).any():
            out.append(f"{name}: NaN or infinite at different poses")
        elif diff.max(initial=0.0) > tol:
            out.append(f"{name}: off by {diff.max():.3g}")
    for name in ("safe", "unknown"):
        if (bad := int((getattr(ours, name) != getattr(peer, name)).sum())):
            out.append(f"{name}: {bad} poses differ")
    if (bad := int((ours.worst(body)[0] != peer.worst(body)[0]).sum())):
        out.append(f"worst limit: {bad} poses differ")
    return out


def scene_poses(scene: str, n: int, seed: int = 0) -> np.ndarray:
    """``n`` seeded poses over the scene's mission area, 1 m in from its edge, any heading."""
    a = area(scene)
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(a[0] + 1, a[2] - 1, n), rng.uniform(a[1] + 1, a[3] - 1, n),
                            rng.uniform(-180.0, 180.0, n)])


def bounds_of(fine: np.ndarray, g: GridGeometry, coarse: GridGeometry, spread: float = SPREAD
              ) -> tuple[np.ndarray, np.ndarray]:
    """Each coarse cell's lowest and highest height of the fine surface it covers, less and plus
    ``spread`` (the fine grid refines the coarse one by a whole factor)."""
    f = int(round(coarse.cell / g.cell))
    blocks = fine[:coarse.height * f, :coarse.width * f].reshape(coarse.height, f, coarse.width, f)
    return blocks.min(axis=(1, 3)) - spread, blocks.max(axis=(1, 3)) + spread


def race(contenders: dict[str, Callable[[], object]], rounds: int) -> dict[str, tuple[float, float]]:
    """Best and median ms of each contender over interleaved rounds: wall time and the process's
    CPU time (on a machine shared with other jobs the wall time counts their share too)."""
    times: dict[str, list[tuple[float, float]]] = {k: [] for k in contenders}
    for _ in range(rounds):
        for name, fn in contenders.items():
            t, c = time.perf_counter(), time.process_time()
            fn()
            times[name].append(((time.perf_counter() - t) * 1e3, (time.process_time() - c) * 1e3))
    out = {}
    for k, v in times.items():
        wall, cpu = np.array(v).T
        out[k], out[k + " cpu"] = (float(wall.min()), float(np.median(wall))), (float(cpu.min()), float(np.median(cpu)))
    return out


def load_average() -> float:
    return os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")


def run(scene: str, rounds: int) -> list[dict[str, Any]]:
    world = World.from_scene(scene)
    body = world.body
    fine, g, coarse = truth_surface(world, scene)
    bounds = bounds_of(fine, g, coarse)
    rows = []
    for label, heights, geom, n in (("truth 1 cm", fine, g, 256), ("truth 1 cm", fine, g, 4096),
                                    ("bounds 5 cm", bounds, coarse, 256)):
        poses = scene_poses(scene, n)
        ours, peer = check_poses(heights, geom, poses, body), reference(heights, geom, poses, body)
        if (bad := disagreement(ours, peer, body)):
            raise SystemExit(f"{scene} {label} {n}: the check and its reference disagree: {'; '.join(bad)}")
        t = race({"ours": lambda h=heights, gg=geom, p=poses: check_poses(h, gg, p, body),
                  "peer": lambda h=heights, gg=geom, p=poses: reference(h, gg, p, body)}, rounds)
        rows.append({"scene": scene, "map": label, "poses": n, "safe": float(ours.safe.mean()), **t})
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", nargs="+", default=["marsyard", "hirise", "dense"], choices=sorted(AREA))
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args(argv)
    print(f"vehicle check (compiled) vs the numpy reference; load average {load_average():.2f}")
    print("  ms per call: best of the interleaved rounds (median), wall and the process's CPU; ratio: reference / "
          "ours, best against best")
    print(f"  {'scene':<9} {'map':<12} {'poses':>6} {'safe':>5} {'ours wall':>16} {'reference wall':>18} "
          f"{'ratio':>5} {'ours cpu':>16} {'reference cpu':>18} {'ratio':>5}")
    for scene in args.scenes:
        for row in run(scene, args.rounds):
            cols = []
            for kind in ("", " cpu"):
                o, p = row["ours" + kind], row["peer" + kind]
                cols.append(f"{o[0]:>7.1f} ({o[1]:>6.1f}) {p[0]:>9.1f} ({p[1]:>6.1f}) {p[0] / o[0]:>5.1f}")
            print(f"  {row['scene']:<9} {row['map']:<12} {row['poses']:>6} {row['safe']:>5.2f} {cols[0]} {cols[1]}")
    print(f"  agreement: margins within {TOL_M:g} m / {TOL_DEG:g} deg, same safe / unknown flags and worst "
          f"limits at every pose; load average after {load_average():.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
