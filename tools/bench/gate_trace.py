"""Trace the see loop's refusals against the truth: one ``navigate -auto -loop see`` mission of
:mod:`tools.bench.navigate`'s seeded draws, with every pose the vehicle check refused on the
bounds map (in a choice of the next section, or re-judging the section being driven) checked
again at that pose on the simulator's true 1 cm surface (:mod:`rvs_truth.vehicle`): was it truly
unsafe, and by which limit.

    python -m tools.bench.gate_trace --scene marsyard --mission 0 --out m0.json
    python -m tools.bench.gate_trace --mission 0 --set navigate.see_set_down=attitude [--hang 0]  # the IMU's
    python -m tools.bench.gate_trace --mission 0 --set navigate.see_vehicle=bounds      # the worst case
    python -m tools.bench.gate_trace --scene hirise --mission 1 --detail 12           # the stop, per limit

``--detail N``: the refusals of the mission's last N choices (where it stopped) judged again, per
limit: the posterior's best estimate, the drawn surfaces' excess (mean and the worst of the
draws), the chance check's probability, and the true surface's excess at the same pose. Which of
them is far from the truth says what refuses: a wide posterior (the draws), the best estimate
itself (a step in the map that is not on the ground), or ground under the body not seen. With it,
the turn on the spot from the last choice's pose (:func:`turn_trace`): how far each way the truth
allows it, how far the check passes it, and how far with each of the check's terms taken out in
turn, which names the term that holds the rover where it stands; and the way out along the
body's axis (:func:`axis_trace`): how far straight ahead and back the check and the truth pass,
and the turn on the spot judged 0.3-1.2 m along it.

``--readings DUMP`` (no mission run): the refused poses of a ``--dump`` judged again on the
map's surfaces read several ways (:func:`readings`): the best estimate as the bounds check reads
it (each sample the cell that holds it, 0.7 of a cell apart), as the chance check reads its draws
(bilinearly, a cell apart), and bilinearly at the truth's 1 cm; and the chance check itself with
its draws sampled finer (:func:`chance_spacings`). A step is a rise within two samples along a
wheel's lane, so the sample spacing sets the run over which a rise counts: 2 cm on the truth, 3.5
and 5 cm on a 2.5 cm map. Where a reading's excess is far from the truth's, the reading, not the
ground, refuses.

Each unsafe event on the true track is traced to the nearest pose of a section the chooser
passed (:func:`trace_events`) and, where the choice kept its map, judged at its true pose on that
map: a pass there is the check's false safe, a refusal the track's straying from what was judged.

Every pose the checks judged is judged again on the truth after the mission
(:mod:`tools.bench.live_risk`): the live check's false-safe rate per judged pose, choosing and
driving; with ``--detail``, the false safes of the last N choices traced as the refusals are.

It hooks the checks the chooser builds (:mod:`rvs_server.navigation.sections`), so it measures the
loop as it runs; docs/NAVIGATE_BENCH.md has what it showed. A refused pose of a choice is one
the chooser's check said no to, not necessarily one the rover would have driven: most candidates
are refused far from the rover's way.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from collections import Counter
from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np

import rvs_server.navigation.sections as sections
from drivers.sim.world import World
from prox_workflows.algorithms import bounds_map, chance, vehicle
from prox_workflows.algorithms.candidates import verdict_name
from prox_workflows.grid import GridGeometry
from rvs_truth.surface import missions, truth_checks
from tools.bench import navigate as bench
from tools.bench.live_risk import Recorder, Truth, lines, live_risk


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="marsyard")
    ap.add_argument("--mission", type=int, default=0, help="index in the bench's seeded draws (seed 0)")
    ap.add_argument("--out", default="", help="also write the mission's row and every refusal as JSON here")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a server setting")
    ap.add_argument("--dump", default="", help="with --detail: also save those choices' maps and poses here (.npz), "
                                               "to judge them again offline")
    ap.add_argument("--goal", default="", metavar="X,Y", help="the mission's start with this goal instead (the long "
                                                              "tests drive a mission's first metres)")
    ap.add_argument("--detail", type=int, default=0, help="judge the refusals of the last N choices per limit")
    ap.add_argument("--hang", type=float, default=None, help="bounds_map hang (m) instead of its default")
    ap.add_argument("--readings", default="", metavar="DUMP", help="no mission: the refused poses of a --dump (of "
                                                                   "--scene) on the map read several ways")
    args = ap.parse_args()
    if args.readings:
        show_readings(args.readings, args.scene)
        return
    if args.hang is not None:
        init = bounds_map.BoundsMap.__init__

        def with_hang(self: Any, geometry: Any, params: Any = None) -> None:
            init(self, geometry, params)
            self.params.hang = args.hang

        bounds_map.BoundsMap.__init__ = with_hang

    rec = Recorder()
    choices: list[dict[str, Any]] = []  # every choice: the pose, its answer; the last ``detail`` keep their map

    choose_from = sections.choose_from

    def choosing(bounds: Any, pose: Any, goal: Any, body: Any, how: str, params: Any, chance_params: Any,
                 guide: Any = None, **kw: Any) -> Any:
        rec.choice = len(choices)
        r = sections.judged_reach(params, body)
        stats, wg = bounds.statistics(pose[0] - r, pose[1] - r, pose[0] + r, pose[1] + r)
        entry: dict[str, Any] = {"pose": [round(float(v), 3) for v in pose], "map": (stats, wg, bounds.params.k),
                                 "chance": chance_params}
        choices.append(entry)
        if len(choices) > args.detail:
            choices[-args.detail - 1].pop("map", None)
        choice, togo = choose_from(bounds, pose, goal, body, how, params, chance_params, guide, **kw)
        entry.update(status=choice.status, turn=round(choice.turn, 1), length=round(choice.length, 3),
                     togo=round(togo, 3), checked=choice.checked, reasons=dict(choice.reasons),
                     section=np.round(choice.poses, 3).tolist())
        if choice.status == "drive":  # what the check said of the section it passed
            c = chance.chance_check(chance.posterior(stats, wg, bounds.params.k, chance_params), wg, choice.poses,
                                    body, chance_params) if how == "chance" else None
            entry["section_p_any"] = None if c is None else float(np.nanmax(c.p_any))
        return choice, togo

    sections.choose_from = choosing

    start, goal = missions(args.scene, args.mission + 1, 0)[args.mission]
    if args.goal:
        goal = tuple(float(v) for v in args.goal.split(","))
    t0 = time.monotonic()
    with rec.installed():
        row = bench.run_mission(args.scene, "see", start, goal, [], tuple(args.set))
    world = World.from_scene(args.scene)
    def truth(poses: np.ndarray) -> vehicle.PoseChecks:
        return truth_checks(world, args.scene, poses, world.body)

    refusals = [{"pose": [round(float(v), 3) for v in p], "verdict": verdict_name(code), "where": where,
                 "choice": choice} for p, code, where, choice in rec.refusals()]
    if refusals:
        c = truth(np.array([r["pose"] for r in refusals]))
        for i, r in enumerate(refusals):
            r["truth"] = {"unsafe": bool(c.unsafe[i]), "tilt": round(float(c.tilt[i]), 2),
                          "belly": round(float(c.intrusion[i]), 4)}
    detailed = detail(choices, refusals, truth, world.body) if args.detail else []
    live = live_risk(rec.judged, truth)
    missed = detail(choices, [{**m, "where": "choose"} for m in live.get("choose", {}).get("misses", [])], truth,
                    world.body) if args.detail else []
    row["events_traced"] = trace_events(row["events"], choices, truth, world.body)
    for e in row["events_traced"]:
        at = e.get("at_event")
        print(f"event {e['kind']} +{e['excess'] * (100 if e['kind'][:4] in ('step', 'bell') else 1):.2f} at "
              f"({e['x']}, {e['y']}, {e['heading']}): nearest chosen pose {e['nearest']} of choice {e['choice']} "
              f"({e['off_m']:.3f} m, {e['off_deg']:.1f} deg off), truly unsafe there: {e['planned_truly_unsafe']} "
              f"{e['planned_truth']}; the section's P(any) {e['section_p_any']}"
              + ("" if at is None else f"; at the event's pose the choice's check {'passes' if at['passed'] else 'refuses'} "
                                       f"(P(any) {at['p_any']:.2g}, best estimate's excess {at['best']})"))
    turn: dict[str, Any] = {}
    way_out: dict[str, Any] = {}
    if args.detail:
        last = next((c for c in reversed(choices) if "map" in c), None)
        if last is not None:
            stats, wg, k = last["map"]
            turn = turn_trace(stats, wg, k, last["pose"], truth, world.body, last["chance"])
            way_out = axis_trace(stats, wg, k, last["pose"], truth, world.body, last["chance"])
    if args.dump:
        dump(args.dump, choices, refusals, goal)
    row.update(stop_turn=turn, way_out=way_out, live_risk=live, refusals=refusals, trace_wall_s=round(time.monotonic() - t0, 1), detailed=detailed,
               missed=missed,
               choices=[{k: v for k, v in c.items() if k not in ("map", "chance")} for c in choices])
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
    print("\n".join(lines(live)))
    for way, t in turn.items():
        print(f"the turn on the spot {way} from the last choice's pose: truly safe {t['truth']} deg, the check "
              f"passes {t['check']} deg; with one term out: "
              + ", ".join(f"{name} {deg}" for name, deg in t["without"].items()))
    for way, a in way_out.items():
        first = a["first_refusal"]
        print(f"straight {way} from the last choice's pose: the check passes {a['passes']} m, the truth "
              f"{a['truth']} m" + ("" if first is None else
                                   f" (first refused at {first['at']} m on the {first['limit']}, P {first['p']:.2g}; "
                                   f"the truth's excess there {first['truth']})")
              + "; the turn on the spot " + ", ".join(
                  f"at {t['at']} m ({t['framed']:.0%} of its disc framed) passes {t['check']} of {t['headings']} "
                  f"headings, {t['truth']} truly safe" for t in a["turns"]))
    for d in missed:
        print(f"false safe at {d['pose']} ({d['from_rover']} m from the rover, choice {d['choice']}, "
              f"{d['framed']:.0%} of the ground under the body framed): P {max(d['prob']):.2g}; per limit best "
              f"{d['best']}, draws' worst {d['draw_max']}, truth {d['truth']}")
    if detailed:
        print(f"the last {args.detail} choices' {len(detailed)} refused poses, per limit: over on the best estimate "
              "/ over only in the draws / truly over; median excess best, draw mean, draw max, truth")
        for k, name in enumerate(vehicle.LIMITS):
            best = np.array([d["best"][k] for d in detailed])
            dmax = np.array([d["draw_max"][k] for d in detailed])
            dmean = np.array([d["draw_mean"][k] for d in detailed])
            true = np.array([d["truth"][k] for d in detailed])
            print(f"  {name}: {(best > 0).sum()} / {((best <= 0) & (dmax > 0)).sum()} / {(true > 0).sum()}; "
                  f"{np.median(best):+.4f} {np.median(dmean):+.4f} {np.median(dmax):+.4f} {np.median(true):+.4f}")


AXIS_STANDS = (0.3, 0.6, 0.9, 1.2)  # m along the body's axis where axis_trace judges the turn on the spot

# the check's terms, each taken out in turn (:func:`turn_trace`): a change of the map's statistics
# or of the check's parameters
TERMS: dict[str, Any] = {
    "relief pair": lambda st, p: (st, dataclasses.replace(p, within=0.0)),
    "rock edge": lambda st, p: (st, dataclasses.replace(p, edge_bias=0.0, edge_sigma=0.0)),
    "rock top": lambda st, p: (st, dataclasses.replace(p, rock_sigma=0.0)),
    "frames' spread": lambda st, p: ({**st, "rise": np.minimum(st["rise"], st["relief"])}, p),
    "prior": lambda st, p: ({**st, "framed": np.ones_like(st["framed"])}, p),
    "epsilon 1e-2": lambda st, p: (st, dataclasses.replace(p, epsilon=1e-2)),
}


def turn_trace(stats: dict[str, np.ndarray], g: Any, k: float, pose: Any, truth: Truth, body: Any,
               params: chance.ChanceParams, step: float = 2.0) -> dict[str, dict[str, Any]]:
    """The turn on the spot from ``pose`` each way (``left``: the heading rising), in ``step`` deg:
    how many degrees of it are truly safe on the true surface (``truth`` judges poses there), how many the
    chance check passes on the map's ``stats`` over ``g``, and how many it passes with each of
    :data:`TERMS` taken out (``without``). The turn's first pose is the pose itself: -``step``
    means the rover's own pose fails. A stop where the truth allows a turn the check refuses is
    held by the map, and the term whose removal passes the turn is the one that holds it (taking
    it out is a diagnosis, not a fix: it changes the stated risk)."""

    turned = np.arange(0.0, 360.0 + step / 2, step)

    def judged(poses: np.ndarray, st: dict[str, np.ndarray], p: chance.ChanceParams) -> float:
        return _passes_to(chance.chance_check(chance.posterior(st, g, k, p), g, poses, body, p).safe, turned)

    out = {}
    for way, sign in (("left", 1.0), ("right", -1.0)):
        heads = pose[2] + sign * turned
        poses = np.column_stack([np.full(len(heads), pose[0]), np.full(len(heads), pose[1]), heads])
        out[way] = {"truth": _passes_to(truth(poses).safe, turned),
                    "check": judged(poses, stats, params),
                    "without": {name: judged(poses, *term(stats, params)) for name, term in TERMS.items()}}
    return out


def axis_trace(stats: dict[str, np.ndarray], g: Any, k: float, pose: Any, truth: Truth, body: Any,
               params: chance.ChanceParams, step: float = 0.02, along: tuple[float, ...] = AXIS_STANDS,
               heading_step: float = 4.0) -> dict[str, Any]:
    """The way out along the body's own axis from ``pose``, on the map's ``stats`` over ``g``: how
    far straight ahead and straight back the chance check passes every pose, ``step`` apart
    (``passes``, m: up to ``along``'s farthest; -``step``: the pose itself fails), and how far the
    truth does; and at each of ``along`` (m, either way) the share of the turn's disc (the body's
    reach) a frame bounded, how many of a turn on the spot's headings (``heading_step`` apart) the check
    passes there and how many are truly safe. Where the rover was set down every turn sweeps
    ground no camera shows, and along its axis the body meets only the box it stood over and what
    the end pairs show: a place along it whose turn disc is framed and whose turn the check
    passes is a way out the straight's first refusal holds shut (the trace names that pose, its
    limit and probability, against the truth there)."""
    post = chance.posterior(stats, g, k, params)
    x, y, heading = (float(v) for v in pose)
    c, s = math.cos(math.radians(heading)), math.sin(math.radians(heading))
    framed = np.asarray(stats.get("framed", np.isfinite(stats["mean"])), bool)
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    r = vehicle.reach(body)
    out: dict[str, Any] = {}
    for way, sign in (("ahead", 1.0), ("back", -1.0)):
        d = sign * np.arange(0.0, max(along) + step / 2, step)
        poses = np.column_stack([x + d * c, y + d * s, np.full(len(d), heading)])
        checked = chance.chance_check(post, g, poses, body, params)
        true = truth(poses)
        bad = np.flatnonzero(~checked.safe)
        first = None if not len(bad) else {
            "at": round(float(abs(d[bad[0]])), 3),
            "limit": "unknown" if checked.unknown[bad[0]] else vehicle.LIMITS[int(checked.worst()[0][bad[0]])],
            "p": float(checked.p_any[bad[0]]), "truth": [round(float(v), 4) for v in true.excess[bad[0]]]}
        stands = []
        for a in along:
            px, py = x + sign * a * c, y + sign * a * s
            heads = heading + np.arange(0.0, 360.0, heading_step)
            turn = np.column_stack([np.full(len(heads), px), np.full(len(heads), py), heads])
            disc = np.hypot(X - px, Y - py) <= r
            stands.append({"at": a, "framed": round(float(framed[disc].mean()), 3) if disc.any() else 0.0,
                           "check": int(chance.chance_check(post, g, turn, body, params).safe.sum()),
                           "truth": int(truth(turn).safe.sum()), "headings": len(heads)})
        out[way] = {"passes": _passes_to(checked.safe, d), "truth": _passes_to(true.safe, d), "first_refusal": first,
                    "turns": stands}
    return out


def _passes_to(ok: np.ndarray, d: np.ndarray) -> float:
    """How far along ``d`` (from the pose, signed, evenly spaced: metres or degrees) every pose
    passes: the last before the first that fails (minus a spacing: the pose itself fails)."""
    bad = np.flatnonzero(~ok)
    return round(float(abs(d[-1]) if not len(bad) else abs(d[bad[0]]) - abs(d[1] - d[0])), 3)


def trace_events(events: list[dict[str, Any]], choices: list[dict[str, Any]], truth: Truth, body: Any
                 ) -> list[dict[str, Any]]:
    """Per unsafe event on the true track: the nearest pose of a section the chooser passed (how far
    off the true pose was, in metres and degrees), and the truth's verdict at that planned pose.
    Where that choice kept its map (``--detail``), the true pose itself is judged on it with the
    choice's chance check (``at_event``: P(any), and the best estimate's excess per limit): a pass
    there is the check's false safe, whatever the planned pose's truth (a planned pose truly safe
    by a millimetre does not make the event the track's); a refusal is the track's straying."""
    planned = [(ci, np.asarray(c["section"], float)) for ci, c in enumerate(choices) if c.get("section")]
    out = []
    for e in events:
        best = None
        for ci, sec in planned:
            dh = np.abs((sec[:, 2] - e["heading"] + 180.0) % 360.0 - 180.0)
            d = np.hypot(sec[:, 0] - e["x"], sec[:, 1] - e["y"]) + 0.005 * dh  # 1 cm per 2 deg
            i = int(np.argmin(d))
            if best is None or d[i] < best[0]:
                best = (float(d[i]), ci, sec[i], float(dh[i]))
        if best is None:
            continue
        _, ci, pose, dh = best
        t = truth(pose[None, :])
        row = {**e, "choice": ci, "nearest": [round(float(v), 3) for v in pose],
               "off_m": float(np.hypot(pose[0] - e["x"], pose[1] - e["y"])), "off_deg": dh,
               "planned_truly_unsafe": bool(t.unsafe[0]), "planned_truth": [round(float(v), 4) for v in t.excess[0]],
               "section_p_any": choices[ci].get("section_p_any")}
        if "map" in choices[ci]:
            stats, g, k = choices[ci]["map"]
            params = choices[ci]["chance"]
            post = chance.posterior(stats, g, k, params)
            at = np.array([[e["x"], e["y"], e["heading"]]], float)
            checked = chance.chance_check(post, g, at, body, params)
            row["at_event"] = {"p_any": float(checked.p_any[0]), "passed": bool(checked.safe[0]),
                               "best": [round(float(v), 4) for v in checked.nominal.excess[0]]}
        out.append(row)
    return out


def dump(path: str, choices: list[dict[str, Any]], refusals: list[dict[str, Any]], goal: Any) -> None:
    """The choices that kept their map, as arrays: ``c<i>_<stat>`` per statistic, ``c<i>_geom``
    (cell, xmin, ymax, width, height), ``c<i>_k``, ``c<i>_pose`` and ``c<i>_refused`` (poses)."""
    out: dict[str, np.ndarray] = {"goal": np.asarray(goal, float)}
    for ci, c in enumerate(choices):
        if "map" not in c:
            continue
        stats, wg, k = c["map"]
        for name, a in stats.items():
            out[f"c{ci}_{name}"] = np.asarray(a)
        out[f"c{ci}_geom"] = np.array([wg.cell, wg.xmin, wg.ymax, wg.width, wg.height], float)
        out[f"c{ci}_k"] = np.array(k, float)
        out[f"c{ci}_pose"] = np.asarray(c["pose"], float)
        out[f"c{ci}_refused"] = np.array([r["pose"] for r in refusals if r["choice"] == ci] or np.zeros((0, 3)))
    np.savez_compressed(path, **out)


def show_readings(path: str, scene: str) -> None:
    """``--readings``: :func:`readings` of a dump of ``scene``'s mission, printed."""
    world = World.from_scene(scene)
    def judge(poses: np.ndarray) -> vehicle.PoseChecks:
        return truth_checks(world, scene, poses, world.body)

    dumped = dict(np.load(path))
    table = readings(dumped, judge, world.body)
    print(f"{path}: refused poses judged again; per reading and limit: over / over where the truth is "
          "within / within where the truth is over; median excess less the truth's")
    for name, row in table.items():
        print(f"  {name:24s} " + "   ".join(
            f"{lim} {r['over']} / {r['false_over']} / {r['missed']}; {r['median_error']:+.4f}"
            for lim, r in row.items()))
    print("the chance check again, its draws sampled at: judged / passed / passed but truly unsafe / refused but "
          "truly safe")
    for name, r in chance_spacings(dumped, judge, world.body).items():
        print(f"  {name:24s} {r['judged']} / {r['passed']} / {r['false_safe']} / {r['false_refusal']}")


def _spacing(spacing: float, unit: str, g: GridGeometry) -> float:
    """A sample spacing given in cells of ``g`` ("cell") or in metres ("m"), in metres."""
    return spacing * (g.cell if unit == "cell" else 1.0)


READINGS: dict[str, tuple[str, bool, float, str]] = {
    # name: (surface, cellwise, sample spacing, in "cell"s or "m")
    "best estimate, the bounds check's": ("best", True, vehicle.BOUNDS_STEP, "cell"),
    "best estimate, the chance check's": ("best", False, 1.0, "cell"),
    "best estimate, the truth's 1 cm": ("best", False, 0.01, "m"),
    "cell means, the truth's 1 cm": ("mean", False, 0.01, "m"),
}


def readings(dumped: Mapping[str, np.ndarray], truth: Truth, body: Any,
             limits: tuple[str, ...] = ("step", "belly")) -> dict[str, dict[str, dict[str, float]]]:
    """The refused poses of a :func:`dump` judged on each of :data:`READINGS` of its choices' maps
    and on the truth: per reading and limit, how many poses are over the limit, over where the
    truth is within it, within where the truth is over, and the median of the excess less the
    truth's. The truth row is the reference (its errors are 0). The bounds check reads each sample
    from its cell, 0.7 of a cell apart (the look-ahead's check and the worst case); the chance
    check reads its drawn surfaces bilinearly, a cell apart (the section's)."""
    excess: dict[str, list[np.ndarray]] = {name: [] for name in ("truth", *READINGS)}
    for _, poses, g, stats, k in dumped_choices(dumped):
        post = chance.posterior(stats, g, k)
        surfaces = {"best": post.best().astype(np.float32), "mean": np.asarray(stats["mean"], np.float32)}
        excess["truth"].append(truth(poses).excess)
        for name, (which, cellwise, spacing, unit) in READINGS.items():
            surface = surfaces[which]
            excess[name].append(vehicle.check_poses((surface, surface.copy()), g, poses, body, cellwise=cellwise,
                                                    step=_spacing(spacing, unit, g)).excess)
    true = np.concatenate(excess["truth"]) if excess["truth"] else np.zeros((0, len(vehicle.LIMITS)))
    out: dict[str, dict[str, dict[str, float]]] = {}
    for name, parts in excess.items():
        got = np.concatenate(parts) if parts else np.zeros_like(true)
        out[name] = {}
        for lim in limits:
            k = vehicle.LIMITS.index(lim)
            over, truly = got[:, k] > 0, true[:, k] > 0
            err = got[:, k] - true[:, k]
            out[name][lim] = {"over": int(over.sum()), "false_over": int((over & ~truly).sum()),
                              "missed": int((~over & truly).sum()),
                              "median_error": float(np.nanmedian(err)) if len(err) else 0.0}
    return out


def dumped_choices(d: Mapping[str, np.ndarray]
                   ) -> Iterator[tuple[int, np.ndarray, GridGeometry, dict[str, np.ndarray], float]]:
    """What :func:`dump` saved, per choice with refused poses: its index, the refused poses, the
    map window's geometry, its statistics and its k."""
    ids = sorted({int(k[1:].split("_")[0]) for k in d.keys() if k.startswith("c") and k.endswith("_pose")})
    for ci in ids:
        refused = np.asarray(d[f"c{ci}_refused"], float)
        if not len(refused):
            continue
        cell, xmin, ymax, width, height = d[f"c{ci}_geom"]
        prefix = f"c{ci}_"
        stats = {k[len(prefix):]: d[k] for k in d.keys() if k.startswith(prefix)}
        yield ci, refused, GridGeometry(float(cell), float(xmin), float(ymax), int(width), int(height)), stats, \
            float(d[f"c{ci}_k"])


SPACINGS: dict[str, tuple[float, str]] = {"a cell (the check's)": (1.0, "cell"), "0.7 of a cell": (0.7, "cell"),
                                          "the truth's 1 cm": (0.01, "m")}


def chance_spacings(dumped: Mapping[str, np.ndarray], truth: Truth, body: Any, per_choice: int = 60
                    ) -> dict[str, dict[str, int]]:
    """The chance check of a :func:`dump`'s refused poses (every n-th, about ``per_choice`` a
    choice) again, its drawn surfaces sampled at each of :data:`SPACINGS`: how many it passes, how
    many of those are truly unsafe (false safes), and how many it refuses that are truly safe. A
    step's run is two samples, so a finer spacing measures the step the truth measures."""
    out = {name: {"judged": 0, "passed": 0, "false_safe": 0, "false_refusal": 0} for name in SPACINGS}
    for _, poses, g, stats, k in dumped_choices(dumped):
        poses = poses[:: max(1, len(poses) // per_choice)]
        post = chance.posterior(stats, g, k)
        unsafe = truth(poses).unsafe
        for name, (spacing, unit) in SPACINGS.items():
            safe = chance.chance_check(post, g, poses, body, step=_spacing(spacing, unit, g)).safe
            row = out[name]
            row["judged"] += len(poses)
            row["passed"] += int(safe.sum())
            row["false_safe"] += int((safe & unsafe).sum())
            row["false_refusal"] += int((~safe & ~unsafe).sum())
    return out


def detail(choices: list[dict[str, Any]], refusals: list[dict[str, Any]], truth: Truth, body: Any,
           draws: int = 64, per_choice: int = 400) -> list[dict[str, Any]]:
    """Per refused pose (or any other, by choice) of the choices that kept their map: the share
    of the ground under the body's middle a frame bounded; per limit (LIMITS order) the excess on
    the posterior's best estimate, the mean and the worst of ``draws`` drawn surfaces' excesses,
    the chance check's probability, and the true excess; and which wheel's step it was."""
    out = []
    for ci, c in enumerate(choices):
        if "map" not in c:
            continue
        stats, wg, k = c["map"]
        post = chance.posterior(stats, wg, k, c["chance"])
        poses = np.array([r["pose"] for r in refusals if r["choice"] == ci and r["where"] == "choose"])[:per_choice]
        if not len(poses):
            continue
        full = chance.chance_check(post, wg, poses, body, c["chance"])
        ex = [vehicle.check_poses(surface, wg, poses, body).excess
              for surface in chance.surfaces(post, wg, dataclasses.replace(c["chance"], samples=draws))]
        ex = np.nan_to_num(np.array(ex), nan=-np.inf)
        true = truth(poses)
        xs, ys = wg.centers()
        framed = stats.get("framed")
        for i, p in enumerate(poses):
            under = np.hypot(*np.meshgrid(xs - p[0], ys - p[1])) <= body.width / 2  # the cells under the body's middle
            out.append({"choice": ci, "pose": [round(float(v), 3) for v in p],
                        "from_rover": round(float(np.hypot(*(p[:2] - np.array(c["pose"][:2])))), 3),
                        "framed": float(np.mean(framed[under])) if framed is not None and under.any() else math.nan,
                        "prob": [round(float(v), 4) for v in full.prob[i]],
                        "best": [round(float(v), 4) for v in full.nominal.excess[i]],
                        "best_wheel": int(full.nominal.wheel[i]),
                        "draw_mean": [round(float(v), 4) for v in ex[:, i].mean(axis=0)],
                        "draw_max": [round(float(v), 4) for v in ex[:, i].max(axis=0)],
                        "truth": [round(float(v), 4) for v in true.excess[i]], "truth_wheel": int(true.wheel[i]),
                        "truth_unsafe": bool(true.unsafe[i])})
    return out


if __name__ == "__main__":
    main()
