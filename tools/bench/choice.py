"""Benchmark: the see loop's choice (:func:`rvs_server.navigation.sections.choose_from`: the
whole map's bounds, the coarse cost to go, the candidates ranked and checked) and the map work of
its cycle (one frame fused into the bounds map, :meth:`BoundsMap.fuse`, and the recheck of the
section ahead, :func:`sections.map_check`), timed on bounds maps dumped from a real mission, with
the reference path and the fast one side by side in one process.

``capture`` drives one mission of :mod:`tools.bench.navigate`'s seeded draws through a real
server (``navigate -auto -loop see``) and saves the bounds map as it stood at every ``--every``-th
choice (``--max`` of them), with the pose, the goal, the section chosen and the first frame fused
after it (the frame's returns, their sigmas and the sensor's position), one pickle per choice:

    python -m tools.bench.choice capture --scene marsyard --mission 0 --out /tmp/choices/marsyard0

``time`` (the default) loads them and, per dumped choice, runs the choice and the cycle with the
reference path (:func:`reference_spread`: the bounds' spread over the map as one OpenCV dilation
and erosion of the whole window per shape of spread) and with the path the server runs (the
compiled spread, :func:`prox_workflows.algorithms._bounds_kernels.spread_extremes`), checks that
both give the same answer (the window's bounds bit for bit, the choice's status, candidate, rank,
candidates and poses checked, the recheck's verdicts), and prints the wall and CPU milliseconds of
each at p50 and p95 over the dumped choices (best of ``--rounds`` interleaved rounds per choice)
and their ratio:

    python -m tools.bench.choice --maps /tmp/choices/marsyard0 /tmp/choices/dense0 [--rounds 3]

The cycle here is the map's share of a see-loop cycle (the frame's fusion into the bounds map
and the recheck); the server's cycle also fuses the frame into the rolling map and publishes it.
"""

from __future__ import annotations

import argparse
import copy
import os
import pickle
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import cv2
import numpy as np

import rvs_server.navigation.sections as sections
from prox_workflows.algorithms import bounds_map
from prox_workflows.grid import GridGeometry


def reference_spread(top: np.ndarray, bottom: np.ndarray, seen: np.ndarray, shape: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """The bounds' spread as whole-window image morphology: per shape code of the seen cells, the
    tops dilated and the bottoms eroded by that code's structuring element (code 0: the cell's own
    only), the highest and lowest kept. The straightforward formulation of
    :func:`prox_workflows.algorithms._bounds_kernels.spread_extremes`, which must give its bits."""
    up = np.full(top.shape, -np.inf, np.float32)
    lo = np.full(top.shape, np.inf, np.float32)
    for code in np.unique(shape[seen]):
        at = seen & (shape == code)
        if code == 0:
            up, lo = np.where(at, np.maximum(up, top), up), np.where(at, np.minimum(lo, bottom), lo)
            continue
        kernel = bounds_map._kernel(int(code))
        up = np.maximum(up, cv2.dilate(np.where(at, top, -np.inf).astype(np.float32), kernel))
        lo = np.minimum(lo, cv2.erode(np.where(at, bottom, np.inf).astype(np.float32), kernel))
    return up, lo


def reference_whole(self: bounds_map.BoundsMap) -> tuple[np.ndarray, np.ndarray]:
    """The whole map's bounds computed whole, every call (:meth:`BoundsMap.whole`'s reference)."""
    g = self.geometry
    return self.bounds((slice(0, g.height), slice(0, g.width)))


def reference_moments(pts: np.ndarray, sig: np.ndarray, sig_xy: np.ndarray, across: np.ndarray,
                      origin: np.ndarray | None, max_range: float | None, across_rays: bool, g: GridGeometry
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A frame's returns summed per cell as a sort and segment sums: the straightforward
    formulation of :func:`prox_workflows.algorithms.bounds_map._cell_moments`, which must give its
    cells and counts, and its sums to within rounding."""
    if origin is not None and max_range is not None:
        far = np.hypot(np.abs(pts[:, 0] - origin[0]) + g.cell, np.abs(pts[:, 1] - origin[1]) + g.cell)
        whole = np.hypot(far, pts[:, 2] - origin[2]) <= max_range
        pts, sig, sig_xy, across = pts[whole], sig[whole], sig_xy[whole], across[whole]
    if across_rays and origin is not None:
        dx, dy = pts[:, 0] - origin[0], pts[:, 1] - origin[1]
        norm = np.maximum(np.hypot(dx, dy), 1e-9)
        ux, uy = dx / norm, dy / norm
    else:
        ux, uy = np.ones(len(pts)), np.zeros(len(pts))
    a2, b2 = sig_xy**2, across**2
    xx, xy, yy = a2 * ux * ux + b2 * uy * uy, (a2 - b2) * ux * uy, a2 * uy * uy + b2 * ux * ux
    r, c = g.cell_of(pts[:, 0], pts[:, 1])
    inside = g.inside(r, c)
    flat = (r * g.width + c)[inside]
    order = np.argsort(flat, kind="stable")
    flat = flat[order]
    starts = np.flatnonzero(np.r_[True, flat[1:] != flat[:-1]]) if len(flat) else np.zeros(0, np.int64)
    columns = [v[inside][order] for v in (pts[:, 2], sig**2, a2, xx + yy - np.minimum(a2, b2), xx, xy, yy)]
    z = columns[0]
    acc = np.column_stack([np.add.reduceat(v, starts) for v in columns]
                          + [np.maximum.reduceat(z, starts), np.minimum.reduceat(z, starts)]) \
        if len(flat) else np.zeros((0, 9))
    return flat[starts], np.diff(np.r_[starts, len(flat)]), acc


@contextmanager
def reference() -> Iterator[None]:
    """Within the block, the bounds map's spread computed by :func:`reference_spread`, its whole
    bounds by :func:`reference_whole` and a frame's sums per cell by :func:`reference_moments`: the
    straightforward path."""
    names = ("_spread", "_cell_moments")
    fast = [getattr(bounds_map, n) for n in names], bounds_map.BoundsMap.whole
    for n, f in zip(names, (reference_spread, reference_moments), strict=True):
        setattr(bounds_map, n, f)
    bounds_map.BoundsMap.whole = reference_whole
    try:
        yield
    finally:
        for n, f in zip(names, fast[0], strict=True):
            setattr(bounds_map, n, f)
        bounds_map.BoundsMap.whole = fast[1]


def capture(scene: str, mission: int, every: int, most: int, out: Path) -> int:
    """Run one mission, saving every ``every``-th choice's map (at most ``most``) under ``out``."""
    from rvs_truth.surface import missions
    from tools.bench import navigate as bench

    out.mkdir(parents=True, exist_ok=True)
    state: dict[str, Any] = {"n": 0, "pending": None, "saved": 0}
    choose_from = sections.choose_from

    def choosing(bounds: Any, pose: Any, goal: Any, body: Any, how: str, params: Any, chance: Any,
                 guide: Any = None, **kw: Any) -> Any:
        keep = state["n"] % every == 0 and state["saved"] < most
        snapshot = copy.deepcopy((bounds, guide)) if keep else None
        choice, togo = choose_from(bounds, pose, goal, body, how, params, chance, guide, **kw)
        if keep:
            assert snapshot is not None
            state["pending"] = {"bounds": snapshot[0], "guide": snapshot[1], "pose": tuple(map(float, pose)),
                                "goal": tuple(map(float, goal)),
                                "body": body, "how": how, "params": params, "chance": chance, "kw": kw,
                                "section": np.asarray(choice.poses), "status": choice.status, "scene": scene,
                                "mission": mission, "choice": state["n"]}
        state["n"] += 1
        return choice, togo

    fuse = bounds_map.BoundsMap.fuse

    def fusing(self: Any, points: Any, sigma: Any, origin: Any = None, *a: Any, **k: Any) -> int:
        entry = state["pending"]
        if entry is not None and origin is not None:
            entry["frame"] = {"points": np.array(points), "sigma": np.array(sigma), "origin": np.array(origin),
                              "args": a, "kwargs": {key: np.array(v) if isinstance(v, np.ndarray) else v
                                                    for key, v in k.items()}}
            with open(out / f"choice{entry['choice']:03d}.pkl", "wb") as fh:
                pickle.dump(entry, fh, protocol=pickle.HIGHEST_PROTOCOL)
            state["pending"] = None
            state["saved"] += 1
        return fuse(self, points, sigma, origin, *a, **k)

    sections.choose_from = choosing
    bounds_map.BoundsMap.fuse = fusing
    try:
        start, goal = missions(scene, mission + 1, 0)[mission]
        row = bench.run_mission(scene, "see", start, goal, [])
    finally:
        sections.choose_from = choose_from
        bounds_map.BoundsMap.fuse = fuse
    print(f"{scene} mission {mission}: {row['status']} reached={row['reached']} after {state['n']} choices; "
          f"saved {state['saved']} under {out}")
    return state["saved"]


def load(dirs: list[str]) -> list[dict[str, Any]]:
    out = []
    for d in dirs:
        for f in sorted(Path(d).glob("choice*.pkl")):
            with open(f, "rb") as fh:
                out.append(pickle.load(fh))
    return out


def _timed(fn: Callable[[], Any]) -> tuple[Any, float, float]:
    w0, c0 = time.perf_counter(), time.thread_time()
    r = fn()
    return r, (time.perf_counter() - w0) * 1000, (time.thread_time() - c0) * 1000


def _choice(e: dict[str, Any]) -> Any:
    """The dumped choice made again, with the coarse guidance as it stood (a copy: a choice
    writes into it)."""
    guide = copy.deepcopy(e.get("guide"))
    return sections.choose_from(e["bounds"], e["pose"], e["goal"], e["body"], e["how"], e["params"], e["chance"],
                                guide, **e.get("kw", {}))


def _cycle(e: dict[str, Any]) -> Any:
    """One frame fused into a copy of the dumped map, then the recheck of the chosen section."""
    bounds = copy.deepcopy(e["bounds"])
    f = e["frame"]
    t0 = (time.perf_counter(), time.thread_time())
    bounds.fuse(f["points"], f["sigma"], f["origin"], *f["args"], **f["kwargs"])
    section = e["section"]
    if not len(section):
        return None, (time.perf_counter() - t0[0]) * 1000, (time.thread_time() - t0[1]) * 1000
    body = e["body"]
    pad = sections.reach(body) + 0.05
    box = (section[:, 0].min() - pad, section[:, 1].min() - pad, section[:, 0].max() + pad, section[:, 1].max() + pad)
    codes = np.asarray(sections.map_check(bounds, box, body, e["how"], e["chance"])(section[1:]))
    return codes, (time.perf_counter() - t0[0]) * 1000, (time.thread_time() - t0[1]) * 1000


def _digest(choice: Any) -> tuple:
    return (choice.status, choice.candidate, choice.rank, choice.checked, choice.poses_checked, choice.look_at,
            tuple(sorted(choice.reasons.items())))


def time_maps(entries: list[dict[str, Any]], rounds: int) -> dict[str, dict[str, list[float]]]:
    """Per path (``reference``, ``fast``) and product (``choice``, ``cycle``, ``window``): the best
    wall and CPU ms per dumped choice; raises if the two paths disagree anywhere."""
    times: dict[str, dict[str, list[float]]] = {f"{p} {w}": {"wall": [], "cpu": []}
                                                for p in ("reference", "fast") for w in ("window", "choice", "cycle")}
    for e in entries:
        _choice(dict(e, bounds=copy.deepcopy(e["bounds"])))  # compile and warm the caches outside the timing
        best: dict[str, list[float]] = {k: [np.inf, np.inf] for k in times}
        answers: dict[str, Any] = {}
        for _ in range(rounds):
            for path in ("reference", "fast"):
                with reference() if path == "reference" else _nothing():
                    # each on the map as dumped: with the whole bounds the previous choice left
                    # (the frames since then changed the map where they fell)
                    b = copy.deepcopy(e["bounds"])
                    w, wall, cpu = _timed(lambda b=b: b.whole())
                    b = copy.deepcopy(e["bounds"])
                    c, cwall, ccpu = _timed(lambda e=e, b=b: _choice(dict(e, bounds=b)))
                    codes, ywall, ycpu = _cycle(e)
                for name, (wv, cv) in (("window", (wall, cpu)), ("choice", (cwall, ccpu)), ("cycle", (ywall, ycpu))):
                    k = f"{path} {name}"
                    best[k] = [min(best[k][0], wv), min(best[k][1], cv)]
                answers[path] = (w, _digest(c[0]), round(c[1], 9), None if codes is None else codes.tolist())
        ref, fast = answers["reference"], answers["fast"]
        same_window = all(np.array_equal(x, y, equal_nan=True) for x, y in zip(ref[0], fast[0], strict=True))
        if not same_window or ref[1:] != fast[1:]:
            raise SystemExit(f"the paths disagree on {e['scene']} choice {e['choice']}: "
                             f"window equal {same_window}, reference {ref[1:3]}, fast {fast[1:3]}")
        for k, (wv, cv) in best.items():
            times[k]["wall"].append(wv)
            times[k]["cpu"].append(cv)
    return times


@contextmanager
def _nothing() -> Iterator[None]:
    yield


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="command")
    cap = sub.add_parser("capture", help="run a mission and save its choices' maps")
    cap.add_argument("--scene", default="marsyard")
    cap.add_argument("--mission", type=int, default=0)
    cap.add_argument("--every", type=int, default=4, help="save every N-th choice")
    cap.add_argument("--max", type=int, default=8, help="save at most this many")
    cap.add_argument("--out", required=True)
    tm = sub.add_parser("time", help="time the dumped choices, reference and fast (the default)")
    for p in (ap, tm):
        p.add_argument("--maps", nargs="+", default=[], help="directories written by capture")
        p.add_argument("--rounds", type=int, default=3, help="interleaved rounds per choice (best kept)")
    args = ap.parse_args(argv)
    if args.command == "capture":
        capture(args.scene, args.mission, args.every, args.max, Path(args.out))
        return
    if not args.maps:
        ap.error("--maps: name the directories capture wrote (python -m tools.bench.choice capture --out DIR)")
    for d in args.maps:
        entries = load([d])
        if not entries:
            ap.error(f"--maps: no choice*.pkl under {d}")
        times = time_maps(entries, args.rounds)
        g = entries[0]["bounds"].geometry
        print(f"{d}: {len(entries)} choices, map {g.width} x {g.height} cells of {g.cell * 100:g} cm, "
              f"load average {os.getloadavg()[0]:.1f}; verdicts identical on both paths")
        print(f"{'':8s} {'reference p50/p95 wall ms':>27s} {'fast p50/p95 wall ms':>22s} {'ratio p95':>9s} "
              f"{'reference p95 CPU':>17s} {'fast p95 CPU':>12s} {'ratio':>6s}")
        for name in ("window", "choice", "cycle"):
            r, f = times[f"reference {name}"], times[f"fast {name}"]
            rp = [float(np.percentile(r["wall"], q)) for q in (50, 95)]
            fp = [float(np.percentile(f["wall"], q)) for q in (50, 95)]
            rc, fc = float(np.percentile(r["cpu"], 95)), float(np.percentile(f["cpu"], 95))
            print(f"{name:8s} {rp[0]:12.1f} / {rp[1]:8.1f} {fp[0]:11.1f} / {fp[1]:6.1f} {fp[1] / rp[1]:9.2f} "
                  f"{rc:17.1f} {fc:12.1f} {fc / rc:6.2f}")


if __name__ == "__main__":
    main()
