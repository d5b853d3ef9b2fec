"""Benchmark: one long see-loop mission (navigate -auto -loop see) in ``marsyard_long``, the Mars
yard's ground and rock cover on a 212 x 16 m strip, its missions 200 m apart
(:data:`rvs_truth.surface.SPAN`), reported per stretch of distance driven so that what grows with
distance shows (docs/NAVIGATE_BENCH.md, "A 200 m traverse").

Per stretch (``--stretch`` metres of true distance driven, 50 by default): the see cycles in it
and their p95 (wall and the process's CPU ms), the choices (the chooser's section choice: its
p95 wall and CPU), the process's memory (resident set, MB: most and last) and the size of the
loop's maps (the bounds map and the rolling map, MB), and the unsafe events of the stretch's
true track judged by the rover's own body on the true 1 cm surface, built in tiles along the
track (:func:`rvs_truth.surface.truth_checks`: the whole strip at 1 cm is several GB). The
server runs in this process (as navigate's bench runs it); a sampler thread reads the loop's
own timing lists (the running :class:`~rvs_server.navigation.see.SeeingDriver`'s
:class:`~rvs_server.navigation.loop_stats.LoopStats`; the mission is handed over on the server's bus as
it starts, its ``mission`` item) and the true track navigate records (a row every
5 cm or 5 deg) every ``--every`` wall seconds, so each cycle and choice is put at the distance
driven when it was read (within one poll, about 10-30 cm). Each stretch's row is printed (and appended to ``--out`` as a JSON line) once
the rover has driven past it, so a run cut short keeps the stretches it covered; the mission's
row and the table follow at its end.

A 200 m mission needs more than ``navigate.see_max_replans``'s 100 sections (at most 1 m each),
so the bench sets it to 2000 unless ``--set`` names it.

    nice -n 10 python -m tools.bench.scale --mission 0 --out /tmp/scale.jsonl
"""

from __future__ import annotations

import argparse
import json
import math
import os
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from prox_workflows.algorithms.vehicle import densify, unsafe_events
from rvs_truth.surface import missions, truth_checks
from rvs_truth.vehicle import TRACK_STEP, stop_reason, track_poses

SCENE = "marsyard_long"
STRETCH = 50.0  # m of true distance driven a row of the table covers
EVERY = 0.2  # s of wall time between two samples
SECTIONS = 2000  # navigate.see_max_replans for a 200 m mission (sections of at most 1 m, re-chosen)


def odometer(xy: np.ndarray) -> np.ndarray:
    """The distance driven (m) at each of the points ``xy`` ((N, 2), in the order driven)."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    if len(xy) < 2:
        return np.zeros(len(xy))
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])


def _p95(values: list[float]) -> float | None:
    return round(float(np.percentile(values, 95)), 1) if values else None


def stretch_row(k: int, every: float, timings: Sequence[tuple[float, str, float, float]],
                memory: Sequence[tuple[float, float, float]], events: Sequence[tuple[float, str]],
                end: float | None = None) -> dict[str, Any]:
    """Stretch ``k`` (from ``k * every`` to ``(k + 1) * every`` m driven, or to ``end``, the
    distance driven in all, in the last): its cycles and choices (``timings``: (at m, "cycle" or
    "choice", wall ms, CPU ms)), their count and p95, the memory samples in it (``memory``: (at m,
    resident MB, maps MB)): the most and the last, and its events (``events``: (at m, kind)). A
    value exactly on a boundary belongs to the stretch it starts."""
    lo = k * every
    hi = (k + 1) * every if end is None else end

    def inside(at: float) -> bool:
        return lo <= at < hi or (end is not None and at == end)

    cyc = [(w, c) for at, kind, w, c in timings if kind == "cycle" and inside(at)]
    cho = [(w, c) for at, kind, w, c in timings if kind == "choice" and inside(at)]
    mem = [(rss, maps) for at, rss, maps in memory if inside(at)]
    ev = [kind for at, kind in events if inside(at)]
    return {"stretch": k, "from_m": round(lo, 1), "to_m": round(hi, 1), "cycles": len(cyc),
            "cycle_ms_p95": _p95([w for w, _ in cyc]), "cycle_cpu_ms_p95": _p95([c for _, c in cyc]),
            "choices": len(cho), "choice_ms_p95": _p95([w for w, _ in cho]),
            "choice_cpu_ms_p95": _p95([c for _, c in cho]),
            "rss_mb_max": round(max(r for r, _ in mem), 1) if mem else None,
            "rss_mb_last": round(mem[-1][0], 1) if mem else None,
            "maps_mb_max": round(max(m for _, m in mem), 1) if mem else None,
            "events": len(ev), "event_kinds": sorted(set(ev))}


def stretch_table(timings: Sequence[tuple[float, str, float, float]], memory: Sequence[tuple[float, float, float]],
                  events: Sequence[tuple[float, str]], driven: float, every: float = STRETCH) -> list[dict[str, Any]]:
    """:func:`stretch_row` of every stretch of a mission that drove ``driven`` metres: the
    whole stretches, then the part one left at the end (if any)."""
    whole = int(driven // every)
    rows = [stretch_row(k, every, timings, memory, events) for k in range(whole)]
    if driven - whole * every > 1e-9 or not rows:
        rows.append(stretch_row(whole, every, timings, memory, events, end=driven))
    return rows


def judge(world: Any, scene: str, track: np.ndarray, body: Any, offset: float = 0.0) -> list[tuple[float, str]]:
    """The unsafe events of a true ``track`` ((N, 3): x, y, heading) densified to the truth
    check's step, each at the distance driven where it starts (``offset`` + along the track)."""
    if len(track) == 0:
        return []
    dense = densify(np.asarray(track, float), TRACK_STEP, body)
    at = offset + odometer(dense[:, :2])
    return [(round(float(at[e.first]), 2), e.kind.split()[0])
            for e in unsafe_events(truth_checks(world, scene, dense, body), dense, body)]


def resident_mb() -> float:
    """The process's resident set (MB)."""
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def arrays_mb(*objects: Any) -> float:
    """MB of the numpy arrays held as attributes of ``objects`` (and of their attributes' own)."""
    total = 0
    for o in objects:
        for v in vars(o).values() if o is not None and hasattr(o, "__dict__") else ():
            if isinstance(v, np.ndarray):
                total += v.nbytes
            elif hasattr(v, "__dict__") and not callable(v):
                total += sum(a.nbytes for a in vars(v).values() if isinstance(a, np.ndarray))
    return total / 2**20


class Sampler(threading.Thread):
    """Reads the running see loop every ``every`` wall seconds: its cycles and choices since the
    last read, the true distance driven, the memory; hands each stretch to ``done`` (its row)
    once the rover has driven past it, and a progress line every ``beat`` metres driven (or 10
    minutes of wall time): so a mission too slow to finish a stretch still shows where it got."""

    def __init__(self, world: Any, scene: str, stretch: float, every: float,
                 done: Callable[[dict[str, Any]], None], beat: float = 5.0) -> None:
        super().__init__(daemon=True, name="scale-sampler")
        self.world, self.scene, self.stretch, self.every, self.done = world, scene, stretch, every, done
        self.timings: list[tuple[float, str, float, float]] = []
        self.memory: list[tuple[float, float, float]] = []
        self.events: list[tuple[float, str]] = []
        self.driven = 0.0
        self.rows: list[dict[str, Any]] = []
        self.halt = threading.Event()
        self.driver: Any = None
        self.track: Any = None
        self.mission: Any = None  # the running Mission, as the bus handed it over (:meth:`on_bus`)
        self._seen = (0, 0)
        self._rows = 0  # track rows counted into ``driven``
        self._judged = 0  # track rows judged (the stretches reported)
        self.beat = beat
        self._mark, self._beat_at, self._t0 = 0.0, time.monotonic(), time.monotonic()

    def on_bus(self, item: Any) -> None:
        """The server bus's subscriber: keeps the mission its ``mission`` item hands over."""
        if item.kind == "mission":
            self.mission = item.data["mission"]

    def run(self) -> None:
        while not self.halt.wait(self.every):
            if self.driver is None or self.track is None:
                mission = self.mission
                if mission is not None:
                    self.driver, self.track = getattr(mission.strategy, "driver", None), mission.track
                continue
            self.sample()
            if int(self.driven // self.stretch) > len(self.rows):
                self._close(len(self.rows))
            if self.driven >= self._mark + self.beat or time.monotonic() >= self._beat_at + 600.0:
                self._heartbeat()

    def sample(self) -> None:
        """One read: the distance driven since the last (along the true track navigate records),
        the loop's new timings, the memory."""
        n = len(self.track.rows)
        if n > self._rows:
            xy = np.asarray(self.track.rows[max(self._rows - 1, 0):n], float)[:, :2]
            self.driven += float(odometer(xy)[-1])
            self._rows = n
        stats = self.driver.stats
        nc, nr = len(stats.cycle_ms), len(stats.replan_ms)
        c0, r0 = self._seen
        self.timings += [(self.driven, "cycle", w, c) for w, c in zip(stats.cycle_ms[c0:nc], stats.cycle_cpu_ms[c0:nc],
                                                                         strict=False)]
        self.timings += [(self.driven, "choice", w, c) for w, c in zip(stats.replan_ms[r0:nr],
                                                                          stats.replan_cpu_ms[r0:nr], strict=False)]
        self._seen = (nc, nr)
        self.memory.append((self.driven, resident_mb(), arrays_mb(self.driver.bounds, self.driver.map)))

    def _heartbeat(self) -> None:
        since = [(w, c) for at, kind, w, c in self.timings if kind == "choice" and at >= self._mark]
        self.done({"progress_m": round(self.driven, 2), "wall_s": round(time.monotonic() - self._t0, 1),
                   "sim_s": round(self.world.clock.now(), 1),
                   "cycles": sum(1 for t in self.timings if t[1] == "cycle"),
                   "choices": sum(1 for t in self.timings if t[1] == "choice"),
                   "choice_ms_p95_since": _p95([w for w, _ in since]),
                   "choice_cpu_ms_p95_since": _p95([c for _, c in since]),
                   "rss_mb": round(self.memory[-1][1], 1) if self.memory else None,
                   "maps_mb": round(self.memory[-1][2], 1) if self.memory else None})
        self._mark, self._beat_at = self.driven, time.monotonic()

    def _judge_to_here(self) -> None:
        """Judge the track rows recorded since the last stretch (from the last judged row on)."""
        rows = np.asarray(self.track.rows[: self._rows] if self.track is not None else [], float).reshape(-1, 3)
        first = max(self._judged - 1, 0)
        offset = float(odometer(rows[: first + 1, :2])[-1]) if len(rows) else 0.0
        self.events += judge(self.world, self.scene, track_poses(rows[first:, :2], rows[first:, 2]),
                             self.world.body, offset)
        self._judged = len(rows)

    def _close(self, k: int, end: float | None = None) -> None:
        self._judge_to_here()
        row = stretch_row(k, self.stretch, self.timings, self.memory, self.events, end)
        self.rows.append(row)
        self.done(row)

    def finish(self) -> list[dict[str, Any]]:
        """Stop sampling; the last read and the stretches not yet reported (the last one partial)."""
        self.halt.set()
        self.join()
        if self.driver is not None and self.track is not None:
            self.sample()
        while len(self.rows) < int(self.driven // self.stretch):
            self._close(len(self.rows))
        if self.driven - len(self.rows) * self.stretch > 1e-9 or not self.rows:
            self._close(len(self.rows), end=self.driven)
        return self.rows


def run(scene: str, mission: int, seed: int, sets: list[str], stretch: float, every: float,
        out: Path | None, beat: float = 5.0) -> dict[str, Any]:
    """The mission, its stretches reported as they are driven past, and its row."""
    from tools.bench.navigate import scene_server

    start, goal = missions(scene, mission + 1, seed)[mission]
    if not any(s.split("=", 1)[0] in ("navigate.see_max_replans", "navigate.see.max_replans") for s in sets):
        sets = [*sets, f"navigate.see_max_replans={SECTIONS}"]

    def emit(row: dict[str, Any]) -> None:
        print(json.dumps(row), flush=True)
        if out is not None:
            with open(out, "a") as fh:
                fh.write(json.dumps(row) + "\n")

    emit({"scene": scene, "mission": mission, "start": start, "goal": goal,
          "distance": round(math.hypot(goal[0] - start[0], goal[1] - start[1]), 2), "sets": sets,
          "rss_mb_before": round(resident_mb(), 1)})
    with tempfile.TemporaryDirectory() as tmp:
        srv = scene_server(Path(tmp), scene, sets)
        try:
            world = srv.app.world
            heading = math.degrees(math.atan2(goal[1] - start[1], goal[0] - start[0]))
            sampler = Sampler(world, scene, stretch, every, emit, beat)
            srv.app.bus.subscribe(sampler.on_bus)
            t_sim0, t_wall0 = world.clock.now(), time.monotonic()
            sampler.start()
            r = srv.request(f"navigate -start {start[0]},{start[1]},{heading:.1f} -goal {goal[0]},{goal[1]} "
                            "-auto -loop see -footprint circle -name bench -max-legs 30")
            rows = sampler.finish()
            truth, pose = world.truth(), srv.app.pose
            row: dict[str, Any] = {
                "scene": scene, "mission": mission, "status": r.status,
                "reached": r.status == "OK" and r.fields.get("reached") == "true",
                "driven_m": round(sampler.driven, 1), "sim_s": round(world.clock.now() - t_sim0, 1),
                "wall_s": round(time.monotonic() - t_wall0, 1),
                "true_miss": round(math.hypot(truth["x"] - goal[0], truth["y"] - goal[1]), 3),
                "believed_miss": round(math.hypot(pose.x - goal[0], pose.y - goal[1]), 3),
                "events": sum(s["events"] for s in rows), "stretches": rows}
            for key in ("cycles", "cycle_ms_p95", "cycle_cpu_ms_p95", "replans", "replan_ms_p95",
                        "replan_cpu_ms_p95"):
                if key in r.fields:
                    row[key] = float(r.fields[key])
            if r.status != "OK":
                row["message"] = r.fields.get("message", "")
                if not row["events"]:
                    row["safe_stop"] = stop_reason(row["message"])
            emit(row)
            return row
        finally:
            srv.stop()


def print_table(rows: list[dict[str, Any]]) -> None:
    print("\nstretch (m)    cycles  cycle p95 wall/CPU ms  choices  choice p95 wall/CPU ms  RSS MB max/last  maps MB  "
          "events")
    for s in rows:
        print(f"{s['from_m']:6.0f}-{s['to_m']:<6.0f} {s['cycles']:6}  {s['cycle_ms_p95']!s:>10}/{s['cycle_cpu_ms_p95']!s:<10} "
              f"{s['choices']:7}  {s['choice_ms_p95']!s:>10}/{s['choice_cpu_ms_p95']!s:<10}  "
              f"{s['rss_mb_max']!s:>7}/{s['rss_mb_last']!s:<7} {s['maps_mb_max']!s:>7}  {s['events']} "
              f"{' '.join(s['event_kinds'])}", flush=True)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default=SCENE, help="the scene (its missions as rvs_truth.surface draws them)")
    ap.add_argument("--mission", type=int, default=0, help="which mission of the seeded draw")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--stretch", type=float, default=STRETCH, help="metres driven a row covers (%(default)s)")
    ap.add_argument("--every", type=float, default=EVERY, help="wall seconds between two samples (%(default)s)")
    ap.add_argument("--beat", type=float, default=5.0,
                    help="a progress line every this many metres driven (and every 10 min of wall time)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a server setting for the mission (e.g. navigate.see_margin=0)")
    ap.add_argument("--out", default="", help="append each stretch's row and the mission's as JSON lines here")
    args = ap.parse_args(argv)
    if args.stretch <= 0 or args.every <= 0 or args.beat <= 0:
        ap.error("--stretch, --every and --beat must be > 0")
    row = run(args.scene, args.mission, args.seed, args.set, args.stretch, args.every,
              Path(args.out) if args.out else None, args.beat)
    print_table(row["stretches"])
    print(f"\n{args.scene} mission {args.mission}: {row['status']}, reached {row['reached']}, driven {row['driven_m']} m, "
          f"true miss {row['true_miss']} m, events {row['events']}, sim {row['sim_s']} s, wall {row['wall_s']} s"
          + (f", stopped: {row.get('safe_stop', row.get('message', ''))}" if row["status"] != "OK" else ""))


if __name__ == "__main__":
    main()
