"""Benchmark: a rock dropped in front of navigate -auto's see loop while it drives
(docs/NAVIGATE_BENCH.md, "A rock dropped ahead").

Each trial is one of the navigate benchmark's seeded missions (:func:`rvs_truth.surface.missions`)
driven by ``navigate -auto -loop see`` through a real server (simulated time). Once the rover has
driven ``--after`` metres (drawn per trial) and is rolling forward (judged at every step of the
simulated drive: :class:`_Dropper`), ``sim add-rock`` (a second
connection, as an operator would) puts a rock it can neither climb nor clear with its belly
(radius 0.15-0.25 m, height 0.15-0.30 m) on its way, 1-3 m ahead of its true pose along the
direction it is driving, the simulated clock held while the rock is made (:func:`clock_held`), so it
lands where it was meant. The trial ends when the rover has passed the rock (farther along than the
rock and clear of it), or has stopped short of it for ``--settle`` simulated seconds, or the job
ended; a running job is interrupted with ``break`` (the track so far is written).

Judged on the truth: the true track (``nav/<name>_track.csv``) from the pose the rover had at the
drop on (:func:`after_drop`), with the vehicle check of the
navigate benchmark (:func:`rvs_truth.vehicle.vehicle_check`) on the true 1 cm surface as it is
after the drop (the rock included), and the least clearance between the body's outline (box and
wheels) and the rock's base circle over that track. A trial **passes** when the clearance stayed
above 0 and the truth check finds no event. A trial whose ``sim add-rock`` is refused (the rock
would lie off the terrain) is not run: it is reported as "rock refused" and left out of the count,
as is one that ended before the drop. The reaction is the first of the loop's answers after
the drop: a stop (``EVENT kind=hazard level=stop``, the section's recheck refused a pose) or a new
section chosen.

    nice python -m tools.bench.rock_drop --trials 20 --scenes marsyard --jobs 2 --out rock.json
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import socket
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from prox_workflows.algorithms.vehicle import densify
from rvs_server.protocol import Reply, parse_reply
from rvs_truth.surface import missions, surface_over
from rvs_truth.vehicle import read_track, vehicle_check
from tools.bench.navigate import scene_server
from tools.bench.rows import streamed

RADIUS = (0.15, 0.25)  # m: the rock's base radius
HEIGHT = (0.15, 0.30)  # m: above both the climb (0.10) and the belly's clearance (0.08)
AHEAD = (1.0, 3.0)  # m from the rover's centre along its direction of travel
AFTER = (1.0, 3.0)  # m driven before the drop
POLL = 0.01  # s of wall time between two reads of the truth


class _Job:
    """The navigate job's own connection: every line, read in a thread, with the simulated time it came."""

    def __init__(self, port: int, line: str, world: Any) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=7200.0)
        self.file = self.sock.makefile("rb")
        self.file.readline()  # greeting
        self.world = world
        self.lines: list[tuple[float, Reply]] = []
        self.final: Reply | None = None
        self.sock.sendall(line.encode() + b"\n")
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self) -> None:
        job = None
        for raw in self.file:
            r = parse_reply(raw.decode().rstrip("\r\n"))
            self.lines.append((self.world.clock.now(), r))
            if r.status == "ACK":
                job = r.fields["job"]
            elif r.status in ("OK", "ERROR") and (job is None or r.fields.get("job") == job):
                self.final = r
                return

    def close(self) -> None:
        self.sock.close()


@contextlib.contextmanager
def clock_held(request: Callable[[str], Reply], world: Any, crawl: float = 0.001) -> Iterator[None]:
    """The simulated clock slowed to ``crawl`` while a rock is placed, and put back after.
    ``sim add-rock`` makes the new heightfield in 0.2-0.6 s of CPU, seconds on a loaded machine,
    while a rover on the instant clock drives on: a rock placed 1 m ahead of the pose read before
    lands half a metre nearer, in the mast's blind disc, which no loop can see into."""
    scale = world.clock.scale
    reply = request(f"config -module sim -set time_scale={crawl}")
    if reply.status != "OK":
        raise RuntimeError(f"the simulated clock could not be slowed: {reply.fields}")
    try:
        yield
    finally:
        request(f"config -module sim -set time_scale={scale}")


def _outline(body: Any) -> tuple[float, float]:
    """Half length and half width of the body's outline: the box or the wheels, whichever reach further."""
    hubs = np.abs(np.asarray(body.wheels, float))
    return (max(body.length / 2, float(hubs[:, 0].max()) + body.wheel_radius),
            max(body.width / 2, float(hubs[:, 1].max()) + body.wheel_width / 2))


def clearance(poses: np.ndarray, rock: tuple[float, float, float], body: Any) -> float:
    """The least distance between the body's outline at ``poses`` (x, y, heading deg; densified
    to 2 cm) and the rock's base circle (x, y, radius); 0 or less: the body was over the rock."""
    dense = densify(poses, 0.02, body)
    hx, hy = _outline(body)
    h = np.radians(dense[:, 2])
    dx, dy = rock[0] - dense[:, 0], rock[1] - dense[:, 1]
    u, v = dx * np.cos(h) + dy * np.sin(h), -dx * np.sin(h) + dy * np.cos(h)
    gap = np.hypot(np.maximum(np.abs(u) - hx, 0.0), np.maximum(np.abs(v) - hy, 0.0))
    return float(gap.min() - rock[2])


def _blocks(at: tuple[float, float], goal: tuple[float, float], rock: tuple[float, float, float], body: Any) -> bool:
    """Whether the straight way from ``at`` to ``goal`` would put the body's half width on the rock."""
    a, b, p = np.asarray(at), np.asarray(goal), np.asarray(rock[:2])
    u = float(np.clip(np.dot(p - a, b - a) / max(float(np.dot(b - a, b - a)), 1e-9), 0.0, 1.0))
    return bool(np.hypot(*(p - (a + u * (b - a)))) < rock[2] + _outline(body)[1])


class _Dropper:
    """The drop, decided at every step of the simulated drive, in the drive's own thread: the
    rover stands while the rock is placed, so the drop's pose is the same run to run. Polled on
    the wall clock instead, a rover on the instant clock drove on between two reads by as much as
    the machine's load let it, and each run dropped the rock at another pose."""

    def __init__(self, srv: Any, world: Any, after: float, ahead: float, radius: float, height: float,
                 goal: tuple[float, float], out: dict[str, Any]) -> None:
        self.srv, self.world, self.out = srv, world, out
        self.after, self.ahead, self.radius, self.height, self.goal = after, ahead, radius, height, goal
        self.driven, self.last, self.recent = 0.0, None, []
        self.done = threading.Event()
        self.sim_time = 0.0
        drive = world.drive

        def stepping(v: float, w_deg: float, seconds: float, stop: Any = None, on_step: Any = None) -> Any:
            def step() -> None:
                if on_step is not None:
                    on_step()
                if not self.done.is_set():
                    self._step()
            return drive(v, w_deg, seconds, stop, on_step=step)

        world.drive = stepping

    def _step(self) -> None:
        t = self.world.truth()
        xy = (t["x"], t["y"])
        if self.last is not None:
            self.driven += math.hypot(xy[0] - self.last[0], xy[1] - self.last[1])
        self.last = xy
        self.recent = [*self.recent, xy][-40:]
        if self.driven < self.after:
            return
        # rolling forward: the last 15 cm of the track run along the heading
        back = next((p for p in reversed(self.recent) if math.hypot(xy[0] - p[0], xy[1] - p[1]) >= 0.15), None)
        if back is None:
            return
        d = math.atan2(xy[1] - back[1], xy[0] - back[0])
        if abs((math.degrees(d) - t["heading"] + 180.0) % 360.0 - 180.0) > 10.0:
            return
        at = (xy[0] + self.ahead * math.cos(d), xy[1] + self.ahead * math.sin(d), self.radius)
        with clock_held(self.srv.request, self.world):  # the ToF's frames wait too
            r = self.srv.request(f"sim add-rock -x {at[0]:.3f} -y {at[1]:.3f} -radius {self.radius:.3f} "
                                 f"-height {self.height:.3f}")
        out = self.out
        if r.status != "OK":
            # no rock lies on the ground: the track proves nothing about one
            out["refused"] = f"sim add-rock: {r.fields.get('message', r.fields)}"
            out["end"] = "rock refused"
        else:
            self.sim_time = t["sim_time"]
            out["drop_pose"] = (round(t["x"], 3), round(t["y"], 3), round(t["heading"], 1))
            out["ahead"] = round(math.hypot(at[0] - t["x"], at[1] - t["y"]), 2)
            out["dir"], out["rock"] = d, at
            out["blocks_goal"] = _blocks(xy, self.goal, at, self.world.body)
        self.done.set()


def trial(scene: str, i: int, seed: int, timeout: float, settle: float, sets: tuple[str, ...] = ()) -> dict[str, Any]:
    """One seeded trial (see the module's docstring)."""
    rng = np.random.default_rng([seed, i])
    start, goal = missions(scene, 30, seed)[i % 30]
    after, ahead = float(rng.uniform(*AFTER)), float(rng.uniform(*AHEAD))
    radius, height = float(rng.uniform(*RADIUS)), float(rng.uniform(*HEIGHT))
    heading = math.degrees(math.atan2(goal[1] - start[1], goal[0] - start[0]))
    out: dict[str, Any] = {"scene": scene, "trial": i, "start": start, "goal": goal, "after": round(after, 2),
                           "radius": round(radius, 3), "height": round(height, 3)}
    with tempfile.TemporaryDirectory() as tmp:
        # the simulated PTU answers over a pseudo-terminal: on a loaded machine its 2 s reply wait
        # can run out, which is the machine's, not the loop's
        srv = scene_server(Path(tmp), scene, ["drivers.ptu.timeout=30", *sets])
        try:
            world = srv.app.world
            job = _Job(srv.port, f"navigate -start {start[0]},{start[1]},{heading:.1f} -goal {goal[0]},{goal[1]} "
                                 "-auto -loop see -name drop -max-legs 200", world)
            t_wall = time.monotonic()
            dropper = _Dropper(srv, world, after, ahead, radius, height, goal, out)
            rock, drop_t, still = None, 0.0, None
            while job.final is None and time.monotonic() - t_wall < timeout:
                time.sleep(POLL)
                if rock is None:
                    if not dropper.done.is_set():
                        continue
                    if "refused" in out:
                        break
                    rock, drop_t = out["rock"], dropper.sim_time
                t = world.truth()
                xy = (t["x"], t["y"])
                along = (xy[0] - rock[0]) * math.cos(out["dir"]) + (xy[1] - rock[1]) * math.sin(out["dir"])
                if along > radius + 0.6 and math.hypot(xy[0] - rock[0], xy[1] - rock[1]) > radius + 0.6:
                    out["end"] = "passed"
                    break
                if still is None or math.hypot(xy[0] - still[0], xy[1] - still[1]) > 0.05:
                    still = (xy[0], xy[1], t["sim_time"])
                elif t["sim_time"] - still[2] > settle:
                    out["end"] = "stood"
                    break
            else:
                out["end"] = "job ended" if job.final is not None else "timeout"
            if job.final is None:
                srv.request("break")
                job.thread.join(120)
            out["wall_s"] = round(time.monotonic() - t_wall, 1)
            final = job.final
            out["status"] = final.status if final else "none"
            if final is not None and final.status == "ERROR" and final.fields.get("code") != "E_INTERRUPTED":
                out["message"] = final.fields.get("message", "")[:200]
            if final is not None and final.status == "OK":
                out["reached"] = final.fields.get("reached") == "true"
                for key in ("cycles", "cycle_ms_p95", "cycle_cpu_ms_p95", "replan_ms_p95", "replan_cpu_ms_p95"):
                    if key in final.fields:
                        out[key] = float(final.fields[key])
            job.close()
            if rock is None:
                out.setdefault("end", "no drop")
                return out
            later = [(ts, r) for ts, r in job.lines if ts >= drop_t]
            events = [(ts, r) for ts, r in later if r.status == "EVENT" and r.fields.get("kind") == "hazard"
                      and r.fields.get("level") == "stop"]
            stops = [ts for ts, _ in events]
            out["stop_reasons"] = sorted({r.fields.get("reason", "") for _, r in events})
            chosen = [ts for ts, r in later if r.status == "PROGRESS"
                      and r.fields.get("message", "").startswith("chose candidate")]
            first = min([*stops, *chosen], default=None)
            out["reaction"] = ("none" if first is None else "stop" if stops and min(stops) == first else "section")
            out["reaction_s"] = None if first is None else round(first - drop_t, 1)
            out["stops"], out["sections"] = len(stops), len(chosen)
            track_file = Path(tmp) / "nav" / "drop_track.csv"
            # the track from the drop on: what came before drove ground that held no rock then
            poses = after_drop(read_track(track_file), out["drop_pose"])
            out["clearance"] = round(clearance(poses, rock, world.body), 3)
            pad = 1.0
            box = (float(poses[:, 0].min()) - pad, float(poses[:, 1].min()) - pad,
                   float(poses[:, 0].max()) + pad, float(poses[:, 1].max()) + pad)
            unsafe, checked = vehicle_check(poses, surface_over(world, box), world.body)
            out["events"] = [{"kind": e.kind, "excess": round(e.excess, 3), "x": round(e.x, 2), "y": round(e.y, 2),
                              "at_rock": math.hypot(e.x - rock[0], e.y - rock[1]) < radius + 0.6} for e in unsafe]
            out["poses_checked"] = checked
            out["passed"] = out["clearance"] > 0.0 and not unsafe
            return out
        finally:
            srv.stop()


def after_drop(poses: np.ndarray, drop_pose: tuple[float, float, float], tol: float = 0.02,
               tol_deg: float = 2.0) -> np.ndarray:
    """The true track (N x 3) from the pose the rover had when the rock was dropped: the first
    pose within ``tol`` and ``tol_deg`` of it (the track keeps no time; a rover that passed the
    same pose earlier is judged from there, more than it need be, never less). The whole track
    where none matches. Judged whole on the surface after the drop, a turn at the start over
    ground the rock later covered counted as contact with a rock not yet there."""
    d = np.hypot(poses[:, 0] - drop_pose[0], poses[:, 1] - drop_pose[1])
    turn = np.abs((poses[:, 2] - drop_pose[2] + 180.0) % 360.0 - 180.0)
    match = np.flatnonzero((d <= tol) & (turn <= tol_deg))
    return poses[int(match[0]):] if len(match) else poses


def _trial(job: tuple[str, int, int, float, float, tuple[str, ...]]) -> dict[str, Any]:
    return trial(*job)


def dropped(row: dict[str, Any]) -> bool:
    """Whether a rock lay on the ground in this trial, so that its verdict counts: a trial whose
    ``sim add-rock`` was refused, or that ended before the drop, has nothing to be judged on."""
    return "rock" in row and "refused" not in row and "passed" in row


def table(rows: list[dict[str, Any]]) -> None:
    """One line per trial, then the ratio of passes per scene over the trials where a rock was
    dropped (one refused by ``sim add-rock`` or never dropped is no evidence either way)."""
    print("\nscene     trial after ahead radius height blocks end        reaction (s)       stops sections clearance events  "
          "pass")
    for r in rows:
        if "refused" in r:
            print(f"{r['scene']:9} {r['trial']:5} {r['after']:5.2f}     -  rock refused: {r['refused']}")
            continue
        if "rock" not in r:
            print(f"{r['scene']:9} {r['trial']:5} {r['after']:5.2f}     -  no drop: {r.get('end')} {r.get('message', '')}")
            continue
        ev = ", ".join(f"{e['kind']} +{e['excess']:.3f}{' at rock' if e['at_rock'] else ''}" for e in r["events"]) or "-"
        react = f"{r['reaction']} ({r['reaction_s']})"
        print(f"{r['scene']:9} {r['trial']:5} {r['after']:5.2f} {r['ahead']:5.2f} {r['radius']:6.3f} {r['height']:6.3f} "
              f"{'yes' if r['blocks_goal'] else 'no':6} {r['end']:10} {react:18} {r['stops']:5} {r['sections']:8} {r['clearance']:9.3f} {ev:7} "
              f"{'pass' if r['passed'] else 'FAIL'}", flush=True)
    for scene in dict.fromkeys(r["scene"] for r in rows):
        sel = [r for r in rows if r["scene"] == scene and dropped(r)]
        refused = sum(1 for r in rows if r["scene"] == scene and "refused" in r)
        print(f"{scene}: {sum(r['passed'] for r in sel)}/{len(sel)} trials passed (no contact, no event); "
              f"{sum(r['passed'] for r in sel if r['blocks_goal'])}/{sum(r['blocks_goal'] for r in sel)} of those with "
              "the rock on the straight way to the goal; "
              f"{sum(1 for r in rows if r['scene'] == scene and not dropped(r)) - refused} ended before the drop; "
              f"{refused} rock refused (not run)", flush=True)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials", type=int, default=20, help="trials per scene")
    ap.add_argument("--first", type=int, default=0, help="the first trial's number (a run split in parts)")
    ap.add_argument("--scenes", nargs="+", default=["marsyard"])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=1, choices=[1, 2], help="trials run in this many processes")
    ap.add_argument("--timeout", type=float, default=1800.0, help="wall seconds a trial may take")
    ap.add_argument("--settle", type=float, default=120.0,
                    help="simulated seconds the rover may stand within 5 cm after the drop before the trial ends")
    ap.add_argument("--out", default="", help="also write the rows as JSON here")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a server setting for every trial (the peer a change is measured against)")
    args = ap.parse_args(argv)
    todo = [(scene, i, args.seed, args.timeout, args.settle, tuple(args.set)) for i in range(args.first, args.first + args.trials)
            for scene in args.scenes]
    rows = streamed(_trial, todo, args.jobs)
    table(rows)
    if args.out:
        Path(args.out).write_text(json.dumps({"rows": rows}, indent=1))


if __name__ == "__main__":
    main()
