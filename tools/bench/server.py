"""Benchmark: request throughput and latency of the RVS server against a minimal asyncio
line-echo server (the ceiling of asyncio line handling on this machine), side by side in one run,
and the latency of ``status`` from another connection while each kind of heavy job runs.

Both servers run in this process (each on its own event loop thread); the load, the status
poller and the busy core are separate processes so that their own work does not compete for the
servers' GIL (a poller inside this process would be measuring its own waits for it too). The
job kinds, with the simulated devices at time_scale 0 so that they compute rather than wait:

- ``bench-burn`` (synthetic): a pure-Python loop that never waits, so the event loop gets the
  GIL only at the interpreter's switch interval; a worst case, not a job the server has.
- ``dem-full-tof``: the README's 24-view request in the office scene (renders, DemImport,
  mosaic, Dem2Hazard, products).
- ``dem-full``: a stereo DEM (pair renders, the matcher, triangulation).
- ``navigate``: ``navigate -auto -loop see`` over a 15-20 m marsyard mission (frames while
  rolling, D* Lite replans and repairs, the rolling map).
- ``check-move``: the help's extremes (``-dx 50 -dy 50`` ...) back to back on 1000 x 1000
  maps of 2 and 5 cm cells.
- ``sim-drive``: a 10 s ``sim drive`` in real time (sim.time_scale 1 for it): the rover a GNC
  polls status about, driving.
- ``grab-stereo``: three stereo pairs grabbed back to back (renders, trigger, TIFFs).

Each kind runs with the machine as it is (``quiet``: note the load average printed with each
run) and with a busy-loop process keeping one core busy (``busy``); ``--repeat`` runs every row
again and keeps the best. ``--holds MS`` adds a watch thread to the server's process that lists
where a thread held the GIL for MS or longer: where to look for a call that does not release it.

    python -m tools.bench.server [--clients 20] [--seconds 5] [--cpu both] [--repeat 3]
                                 [--kinds dem-full-tof,navigate] [--holds 15] [--json runs.jsonl]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import socket
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
TARGET_MS = 20.0

# ---------------------------------------------------------------------------- load generator


async def _load(port: int, clients: int, seconds: float, line: bytes, expect_prefix: bytes) -> dict:
    latencies: list[float] = []
    count = 0
    stop_at = time.perf_counter() + seconds

    async def one() -> None:
        nonlocal count
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        if expect_prefix != b"":
            await reader.readline()  # greeting
        while time.perf_counter() < stop_at:
            t0 = time.perf_counter()
            writer.write(line)
            while True:
                reply = await reader.readline()
                if not reply:
                    raise ConnectionError("server closed")
                if reply.startswith(expect_prefix):
                    break
            latencies.append(time.perf_counter() - t0)
            count += 1
        writer.close()

    t_start = time.perf_counter()
    await asyncio.gather(*(one() for _ in range(clients)))
    elapsed = time.perf_counter() - t_start
    lat = np.array(latencies) * 1000
    return {"count": count, "rate": count / elapsed, "p50": float(np.percentile(lat, 50)),
            "p99": float(np.percentile(lat, 99))}


def load_main(argv: list[str]) -> None:
    port, clients, seconds = int(argv[0]), int(argv[1]), float(argv[2])
    line, prefix = argv[3].encode() + b"\n", argv[4].encode()
    print(json.dumps(asyncio.run(_load(port, clients, seconds, line, prefix))))


def run_load(port: int, clients: int, seconds: float, line: str, prefix: str, procs: int = 1) -> dict:
    """Spread the clients over ``procs`` load processes and merge their figures."""
    per = max(1, clients // procs)
    ps = [subprocess.Popen([sys.executable, "-m", "tools.bench.server", "--load", str(port), str(per),
                            str(seconds), line, prefix], stdout=subprocess.PIPE, text=True,
                           cwd=ROOT) for _ in range(procs)]
    results = [json.loads(p.communicate()[0]) for p in ps]
    return {"count": sum(r["count"] for r in results), "rate": sum(r["rate"] for r in results),
            "p50": max(r["p50"] for r in results), "p99": max(r["p99"] for r in results)}


# ---------------------------------------------------------------------------- status poller


def poll_main(argv: list[str]) -> None:
    """The status poller's process: ``status`` as fast as it is answered, on its own connection,
    until a line arrives on stdin; then the latencies' summary as JSON on stdout. Blocking
    sockets in a process of its own, so that nothing but the server decides the figure."""
    port = int(argv[0])
    stop = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.readline(), stop.set()), daemon=True).start()
    sock = socket.create_connection(("127.0.0.1", port))
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    reader = sock.makefile("rb")
    reader.readline()  # greeting
    print("ready", flush=True)
    lat: list[float] = []
    while not stop.is_set():
        t0 = time.perf_counter()
        sock.sendall(b"status\n")
        while not (line := reader.readline()).startswith(b"EGP-RVS-STATUS"):  # events go to every connection
            if not line:
                raise ConnectionError("server closed")
        if not line.startswith(b"EGP-RVS-STATUS OK"):
            raise ConnectionError(f"status answered {line!r}")
        lat.append(time.perf_counter() - t0)
    sock.close()
    print(json.dumps(summary(np.array(lat) * 1000)))


def summary(lat_ms: np.ndarray) -> dict[str, float]:
    """The figures of a row, computed in the poller so that only they cross the pipe."""
    if len(lat_ms) == 0:
        return {"n": 0, "p50": float("nan"), "p99": float("nan"), "max": float("nan")}
    return {"n": int(len(lat_ms)), "p50": float(np.percentile(lat_ms, 50)),
            "p99": float(np.percentile(lat_ms, 99)), "max": float(lat_ms.max())}


@contextmanager
def polling(port: int) -> Iterator[dict[str, float]]:
    """Poll status for the duration of the block; the dict yielded is filled in at its end."""
    p = subprocess.Popen([sys.executable, "-m", "tools.bench.server", "--poll", str(port)], cwd=ROOT,
                         stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert p.stdout is not None and p.stdin is not None
    if p.stdout.readline().strip() != "ready":
        raise RuntimeError("the status poller did not start")
    out: dict[str, float] = {}
    try:
        yield out
    finally:
        try:
            p.stdin.write("\n")
            p.stdin.flush()
        except BrokenPipeError:  # it stopped on its own: its traceback is on stderr
            pass
        line = p.stdout.readline()
        if p.wait(10) != 0 or not line:
            raise RuntimeError("the status poller failed")
        out.update(json.loads(line))


@contextmanager
def busy_core(on: bool) -> Iterator[None]:
    """A process spinning in a loop: one of the machine's cores taken, as another program would."""
    if not on:
        yield
        return
    p = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        yield
    finally:
        p.kill()
        p.wait()


# ---------------------------------------------------------------------------- servers


class EchoProtocol(asyncio.Protocol):
    """The minimal line echo server: split lines, write each back."""

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]
        self.buf = b""

    def data_received(self, data: bytes) -> None:
        self.buf += data
        *lines, self.buf = self.buf.split(b"\n")
        for line in lines:
            self.transport.write(line + b"\n")  # type: ignore[attr-defined]


def start_echo() -> int:
    ready = threading.Event()
    port = [0]

    async def main() -> None:
        server = await asyncio.get_running_loop().create_server(EchoProtocol, "127.0.0.1", 0)
        port[0] = server.sockets[0].getsockname()[1]
        ready.set()
        await asyncio.Event().wait()

    threading.Thread(target=lambda: asyncio.run(main()), daemon=True).start()
    ready.wait()
    return port[0]


def start_rvs(data: Path, overrides: list[str] | None = None) -> tuple[int, Any]:
    from rvs_server.jobs import Job
    from rvs_server.logs import setup
    from rvs_server.main import build_config, run
    from rvs_server.table import command

    @command("bench-burn", job=True, help="benchmark only: pure-Python CPU load until break")
    def burn(job: Job, cfg: None) -> dict:
        n = 0
        while not job.cancelled:
            n += sum(i * i for i in range(20000))  # pure Python: the GIL changes hands only at the switch interval
            job.check()
        return {"n": n}

    setup("warning", None, console=False)
    store = build_config(None, [f"server.data={data}", "server.port=0", "server.max_clients=256",
                                "drivers.ptu.time_scale=0", "sim.time_scale=0", *(overrides or [])])
    ready = threading.Event()
    box: dict = {}

    def ready_cb(port: int) -> None:
        box["port"] = port
        ready.set()

    threading.Thread(target=lambda: asyncio.run(run(store, ready=ready_cb, handle_signals=False,
                                                    on_app=lambda a: box.setdefault("app", a))),
                     daemon=True).start()
    ready.wait(60)
    return box["port"], box["app"]


def wait_warm_up(timeout: float = 120.0) -> None:
    """The kernels' warm-up thread compiles or loads in the background at start: wait it out,
    or the first job kind would measure it."""
    from rvs_server.server import WARM_UP_THREAD

    for t in threading.enumerate():
        if t.name == WARM_UP_THREAD:
            t.join(timeout)


# ---------------------------------------------------------------------------- the control connection


class Control:
    """A blocking connection that sends a request and returns its final reply (the job's OK or
    ERROR when it is a job)."""

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port))
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.reader = self.sock.makefile("rb")
        self.reader.readline()  # greeting

    def request(self, line: str) -> Any:
        from rvs_server.protocol import parse_reply

        self.sock.sendall(line.encode() + b"\n")
        job = None
        while True:
            text = self.reader.readline().decode()
            if not text:
                raise ConnectionError("server closed")
            r = parse_reply(text.rstrip("\r\n"))
            if r.status == "ACK":
                job = r.fields.get("job")
            elif r.status in ("OK", "ERROR") and (job is None or r.fields.get("job") == job):
                return r

    def close(self) -> None:
        self.sock.close()


# ---------------------------------------------------------------------------- job kinds


@dataclass
class Kind:
    """One row: ``setup`` lines are sent untimed, then ``run`` does the job on the control
    connection while status is polled from another, and returns what to print after the row."""

    name: str
    run: Callable[[Control, Any], str]
    setup: list[str] = field(default_factory=list)
    synthetic: bool = False


def _burn(ctl: Control, app: Any, seconds: float) -> str:
    """The burn runs until break: a second connection breaks it after ``seconds``."""
    ctl.sock.sendall(b"bench-burn\n")
    time.sleep(seconds)
    other = Control(ctl.sock.getpeername()[1])
    other.request("break")
    other.close()
    while not ctl.reader.readline().startswith(b"EGP-RVS-BENCH-BURN ERROR"):
        pass
    ctl.request("continue")
    return f"{seconds:g} s, then break"


def _job(line: str) -> Callable[[Control, Any], str]:
    def run(ctl: Control, app: Any) -> str:
        t0 = time.perf_counter()
        r = ctl.request(line)
        wall = time.perf_counter() - t0
        extra = "".join(f" {k}={r.fields[k]}" for k in ("views", "legs", "replans", "searches", "repairs", "reached",
                                                          "cycles", "cycle_ms_p95", "cycle_cpu_ms_p95", "cycle_ms_max",
                                                          "replan_ms_p95", "replan_cpu_ms_p95")
                        if k in r.fields)
        return f"{r.status} in {wall:.1f} s{extra}" + ("" if r.status == "OK" else f" {r.fields}")
    return run


def _jobs(line: str, times: int) -> Callable[[Control, Any], str]:
    """``line`` ``times`` times back to back (a job too short to poll through alone)."""
    def run(ctl: Control, app: Any) -> str:
        t0, statuses = time.perf_counter(), []
        for i in range(times):
            statuses.append(ctl.request(line.format(i=i)).status)
        return f"{times} x {' '.join(sorted(set(statuses)))} in {time.perf_counter() - t0:.1f} s"
    return run


def _drive(ctl: Control, app: Any) -> str:
    """``sim drive`` in real time (time_scale 1: the drive model stepping and the pose published
    as a rover's drive takes, not computed at once as at time_scale 0), then time_scale 0 again."""
    ctl.request("config -module sim -set time_scale=1")
    try:
        return _job("sim drive -v 0.2 -w 3 -seconds 10")(ctl, app)
    finally:
        ctl.request("config -module sim -set time_scale=0")


CHECK_MOVE_EXTREMES = ("-dx 50 -dy 50", "-dx -50 -dy 50 -dyaw 360", "-dyaw 360", "-to 150,150")


def _check_move(ctl: Control, app: Any, seconds: float) -> str:
    """The extremes back to back on a 2 cm and a 5 cm 1000 x 1000 map (the sweep's box bound is
    in cells, so both reach it), half of the time each."""
    from prox_workflows.grid import GridGeometry, Layers

    n, slowest = 0, 0.0
    for cell in (0.02, 0.05):
        g = GridGeometry(cell, -500 * cell, 500 * cell, 1000, 1000)
        t = np.full(g.shape, 0.8, np.float32)
        app.maps.replace(Layers(g, {"dem": np.zeros(g.shape, np.float32), "traversability": t}), "bench", {})
        stop_at = time.perf_counter() + seconds / 2
        while time.perf_counter() < stop_at:
            for args in CHECK_MOVE_EXTREMES:
                t0 = time.perf_counter()
                ctl.request(f"check-move {args}")
                slowest = max(slowest, time.perf_counter() - t0)
                n += 1
    return f"{n} checks, slowest reply {slowest * 1000:.0f} ms"


NAV_START, NAV_GOAL = (11.68, 6.88), (1.12, -6.18)  # tools.bench.navigate's first marsyard mission


def kinds(seconds: float) -> dict[str, Kind]:
    heading = float(np.degrees(np.arctan2(NAV_GOAL[1] - NAV_START[1], NAV_GOAL[0] - NAV_START[0])))
    office = ["sim scene office", "pose -x 0 -y 0 -heading 0"]
    return {k.name: k for k in [
        Kind("bench-burn", lambda c, a: _burn(c, a, seconds), synthetic=True),
        Kind("dem-full-tof", _job("dem-full-tof -range -180,180,-50,-10 -overlap 0.3 -name bench"), setup=office),
        Kind("dem-full", _job("dem-full -range -60,60,-50,-30 -name bench_stereo"), setup=office),
        Kind("navigate", _job(f"navigate -start {NAV_START[0]},{NAV_START[1]},{heading:.1f} "
                              f"-goal {NAV_GOAL[0]},{NAV_GOAL[1]} -auto -loop see -name bench_nav -max-legs 30"),
             setup=["sim scene marsyard"]),
        Kind("check-move", lambda c, a: _check_move(c, a, seconds)),
        # what a GNC polls status through: its rover driving (the simulated drive model, in real
        # time) and the mast's stereo pair grabbed (two 1920 x 1080 renders, the trigger, the TIFFs)
        Kind("sim-drive", _drive, setup=office),
        Kind("grab-stereo", _jobs("grab-stereo -output bench_pair_{i}", 3), setup=office),
    ]}


# ---------------------------------------------------------------------------- GIL holds


class HoldWatch:
    """A thread that sleeps 1 ms at a time. When it wakes ``threshold`` late, a thread that ran
    for most of that time on the CPU meanwhile held the GIL in a call that did not release it (a
    Python loop gives it up within the switch interval, 5 ms); its stack, taken as soon as the
    watch has the GIL back, points at the line just after that call, and the figure is its CPU
    time over the wait. A late wake with no such thread was the machine's other processes
    taking the core, and is counted apart. (A thread inside a call that released the GIL runs
    too: its line names that call, a numba kernel say, and it is not the holder.)"""

    def __init__(self, threshold_ms: float) -> None:
        self.threshold = threshold_ms / 1000
        self.holds: Counter[str] = Counter()
        self.worst: dict[str, float] = {}
        self.starved = 0
        self.stopped = threading.Event()
        self.thread = threading.Thread(target=self._run, name="bench-hold-watch", daemon=True)
        self.thread.start()

    @staticmethod
    def _cpu() -> dict[int, tuple[str, float]]:
        out = {}
        for t in threading.enumerate():
            try:
                out[t.ident or 0] = (t.name, time.clock_gettime(time.pthread_getcpuclockid(t.ident or 0)))
            except (OSError, OverflowError):  # the thread ended meanwhile
                pass
        return out

    def _run(self) -> None:
        me = threading.get_ident()
        while not self.stopped.is_set():
            before = self._cpu()
            t0 = time.perf_counter()
            time.sleep(0.001)
            late = time.perf_counter() - t0
            if late < self.threshold:
                continue
            frames = sys._current_frames()
            after = self._cpu()
            found = False
            for ident, (name, cpu) in after.items():
                ran = cpu - before[ident][1] if ident in before else 0.0
                if ident == me or ran < self.threshold * 0.75:
                    continue
                frame = frames.get(ident)
                stack = traceback.extract_stack(frame) if frame is not None else []
                where = " < ".join(f"{Path(f.filename).name}:{f.lineno} {f.name}" for f in reversed(stack[-4:]))
                key = f"[{name}] {where}"
                self.holds[key] += 1
                self.worst[key] = max(self.worst.get(key, 0.0), ran)
                found = True
            self.starved += not found

    def report(self) -> str:
        self.stopped.set()
        self.thread.join()
        lines = [f"    {n:>3}x {self.worst[k] * 1000:5.0f} ms  {k}" for k, n in self.holds.most_common(12)]
        lines.append(f"    {self.starved} late wakes with no thread of this process running (other processes)")
        return "\n".join(lines)


# ---------------------------------------------------------------------------- main


def measure(port: int, app: Any, kind: Kind, busy: bool, holds_ms: float | None) -> tuple[dict[str, float], str, str]:
    ctl = Control(port)
    try:
        for line in kind.setup:
            r = ctl.request(line)
            if r.status != "OK":
                raise RuntimeError(f"{line}: {r.fields}")
        with busy_core(busy):
            time.sleep(0.2)
            watch = HoldWatch(holds_ms) if holds_ms else None
            with polling(port) as lat:
                note = kind.run(ctl, app)
            holds = watch.report() if watch else ""
    finally:
        ctl.close()
    return lat, note, holds


def load_average() -> float:
    with open("/proc/loadavg") as fh:
        return float(fh.read().split()[0])


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--load":
        load_main(sys.argv[2:])
        return
    if len(sys.argv) > 1 and sys.argv[1] == "--poll":
        poll_main(sys.argv[2:])
        return
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--clients", type=int, default=20)
    ap.add_argument("--seconds", type=float, default=5.0, help="throughput run, bench-burn and check-move")
    ap.add_argument("--cpu", choices=("quiet", "busy", "both"), default="both",
                    help="busy: a busy-loop process keeps one core busy meanwhile")
    ap.add_argument("--kinds", default="", help="comma-separated job kinds (default all): " + ", ".join(kinds(0)))
    ap.add_argument("--repeat", type=int, default=1,
                    help="runs of every row; the table shows the run with the lowest p99 and the p99 range")
    ap.add_argument("--no-throughput", action="store_true", help="only the job kinds")
    ap.add_argument("--holds", type=float, default=None, metavar="MS",
                    help="list where the GIL was held for MS or longer during each job kind (the watch "
                         "thread takes the GIL every millisecond: use it to find holds, not for the figures)")
    ap.add_argument("--json", type=Path, default=None, help="append every run as a JSON line")
    args = ap.parse_args()
    table = kinds(args.seconds)
    chosen = [table[k.strip()] for k in args.kinds.split(",") if k.strip()] if args.kinds else list(table.values())
    cpus = {"quiet": [False], "busy": [True], "both": [False, True]}[args.cpu]

    with tempfile.TemporaryDirectory() as tmp:
        rvs_port, app = start_rvs(Path(tmp))
        wait_warm_up()
        if not args.no_throughput:
            echo_port = start_echo()
            echo = run_load(echo_port, args.clients, args.seconds, "version", "")
            rvs = run_load(rvs_port, args.clients, args.seconds, "version", "EGP-RVS-VERSION OK")
            print(f"{'server':<22}{'commands/s':>12}{'p50 ms':>9}{'p99 ms':>9}")
            print(f"{'asyncio line echo':<22}{echo['rate']:>12.0f}{echo['p50']:>9.2f}{echo['p99']:>9.2f}")
            print(f"{'rvs (version)':<22}{rvs['rate']:>12.0f}{rvs['p50']:>9.2f}{rvs['p99']:>9.2f}")
            print(f"throughput ratio rvs/echo: {rvs['rate'] / echo['rate']:.2f} (target >= 0.5)\n")
        idle = run_load(rvs_port, 1, 2.0, "status", "EGP-RVS-STATUS OK")
        print(f"status idle: p50 {idle['p50']:.2f} ms, p99 {idle['p99']:.2f} ms")
        print("\nstatus from another connection during each job kind, every run (load: 1-minute load average)")
        head = f"{'job kind':<24}{'cpu':<7}{'n':>7}{'p50 ms':>8}{'p99 ms':>8}{'max ms':>8}"
        print(f"{head}  job")
        runs: dict[tuple[str, str], list[dict[str, Any]]] = {}
        for _ in range(args.repeat):
            for kind in chosen:
                for busy in cpus:
                    load = load_average()
                    lat, note, holds = measure(rvs_port, app, kind, busy, args.holds)
                    cpu = "busy" if busy else "quiet"
                    row = {"kind": kind.name, "cpu": cpu, "load": load, **lat, "job": note}
                    runs.setdefault((kind.name, cpu), []).append(row)
                    label = kind.name + (" (synthetic)" if kind.synthetic else "")
                    print(f"{label:<24}{cpu:<7}{lat['n']:>7}{lat['p50']:>8.2f}{lat['p99']:>8.2f}{lat['max']:>8.1f}"
                          f"  {note}; load {load:.1f}", flush=True)
                    if args.holds:
                        print(f"  GIL held >= {args.holds:g} ms (count, holder's CPU time, thread, where after the "
                              f"hold):\n{holds}", flush=True)
                    if args.json:
                        with open(args.json, "a") as fh:
                            fh.write(json.dumps(row) + "\n")
        print(f"\nbest of {args.repeat} (the run with the lowest p99; target p99 < {TARGET_MS:g} ms for the job "
              "kinds the server has)")
        print(f"{head}{'p99 range':>14}{'load':>11}")
        for kind in chosen:
            for busy in cpus:
                rows = runs[(kind.name, "busy" if busy else "quiet")]
                best = min(rows, key=lambda r: r["p99"])
                p99s, loads = [r["p99"] for r in rows], [r["load"] for r in rows]
                label = kind.name + (" (synthetic)" if kind.synthetic else "")
                over = "" if kind.synthetic or best["p99"] < TARGET_MS else "  OVER"
                print(f"{label:<24}{best['cpu']:<7}{best['n']:>7}{best['p50']:>8.2f}{best['p99']:>8.2f}"
                      f"{best['max']:>8.1f}{min(p99s):>7.1f}-{max(p99s):<6.1f}{min(loads):>5.1f}-{max(loads):<5.1f}{over}")


if __name__ == "__main__":
    main()
