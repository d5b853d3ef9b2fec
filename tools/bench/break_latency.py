"""Benchmark: how fast ``break`` answers, and how fast the job it caught stops, per job kind.

For each job kind a job is started on one connection and ``break`` sent on another at a moment
spread over the job's run (the k-th of N trials breaks at (k + 0.5) / N of its unbroken run,
measured once first, 0.9 of it), so the break lands in every phase: a PTU move, a camera render,
a DEM's processing or its writes. The break goes on the job's own connection, whose lines the
server writes in the order it makes them, so "OK before ERROR" counts what the server did. Two
figures per trial, from the moment the break's line is written to the socket: (1) its ``OK``
line, (2) the caught job's ``ERROR`` line; a thread reads the socket and stamps each line as it
arrives. A trial whose job ended before the break reached it (``interrupted=none``) is counted
as missed, not timed. ``continue``, on a second connection, returns the server to ready between
trials.

The server is a real one (``python -m rvs_server`` in a child process by default, the same code
path as ``rvs-server``; ``--in-process`` runs it in a thread of this process), with simulated
devices at real speed: the PTU moves at its configured speed, frames take their exposure time.

    python -m tools.bench.break_latency [--trials 20] [--kinds sleep,move-ptu,...] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import queue
import socket
import statistics
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rvs_server.protocol import Reply, parse_reply

FINAL = ("OK", "ERROR")


@dataclass
class Kind:
    """One row of the table: how to start the job and where the break timer starts.

    ``starts`` are used in turn (a PTU move alternates its targets, so each trial moves).
    ``after``: the break's delay counts from the first PROGRESS line containing it ("" from the
    ACK). ``window``: the span the breaks are spread over; None measures the unbroken job.
    ``before``: sent before every run (put the rover back where navigate starts); ``at_mark``:
    sent when the timer starts (navigate scans at 20x simulated speed, then drives at 1x)."""

    name: str
    starts: list[str]
    setup: list[str] = field(default_factory=list)
    before: list[str] = field(default_factory=list)
    at_mark: list[str] = field(default_factory=list)
    after: str = ""
    window: float | None = None


KINDS: dict[str, Kind] = {k.name: k for k in [
    Kind("sleep", ["sleep -seconds 30"], window=1.0),
    Kind("move-ptu", ["move-ptu -pan 150 -tilt -30", "move-ptu -pan -150 -tilt 0"]),
    Kind("grab-tof", ["grab-tof -output brk -type distance -integrate 10"]),
    Kind("grab-stereo", ["grab-stereo -output brk"]),
    Kind("grab-stereo highest", ["grab-stereo -output brk -resolution highest"]),
    Kind("dem-full-tof", ["dem-full-tof -range -60,60,-50,-30 -name brk"]),
    Kind("dem-full", ["dem-full -range -60,60,-50,-30 -name brk"]),
    Kind("navigate -auto (drive)", ["navigate -goal 1.5,0 -auto true -loop scan -scan-plan circle -name brk"], after="phase=drive", window=3.0,
         before=["sim scene office", "pose -x 0 -y 0 -heading 0", "config -module sim -set time_scale=20"],
         at_mark=["config -module sim -set time_scale=1"]),
    Kind("reset", ["reset"]),
    Kind("orient", ["orient"]),
]}


class Conn:
    """A socket whose lines a thread reads and stamps with their arrival time."""

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port))
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.lines: queue.Queue[tuple[float, str] | None] = queue.Queue()
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()
        self.next(lambda r: True)  # greeting
        self.send("events off")
        self.next(lambda r: r.module == "EGP-RVS-EVENTS")

    def _read(self) -> None:
        buf = b""
        try:
            while chunk := self.sock.recv(65536):
                now = time.perf_counter()
                buf += chunk
                while b"\n" in buf:
                    raw, buf = buf.split(b"\n", 1)
                    self.lines.put((now, raw.decode("utf-8", "replace").rstrip("\r")))
        except OSError:
            pass
        self.lines.put(None)

    def send(self, text: str) -> float:
        """Write a line; returns the time just before it was written."""
        t = time.perf_counter()
        self.sock.sendall(text.encode() + b"\n")
        return t

    def next(self, match: Callable[[Reply], bool], timeout: float = 600.0) -> tuple[float, Reply]:
        """The first line that ``match``es (earlier ones are dropped), with its arrival time."""
        deadline = time.monotonic() + timeout
        while True:
            item = self.lines.get(timeout=max(0.0, deadline - time.monotonic()))
            if item is None:
                raise ConnectionError("the server closed the connection")
            t, text = item
            reply = parse_reply(text)
            if match(reply):
                return t, reply

    def request(self, text: str, tag: str, timeout: float = 600.0) -> Reply:
        self.send(f"@{tag} {text}")
        return self.next(lambda r: r.tag == tag and r.status in FINAL, timeout)[1]

    def close(self) -> None:
        self.sock.close()


def _final_of(tag: str) -> Callable[[Reply], bool]:
    return lambda r: r.tag == tag and r.status in FINAL


def start(job: Conn, ctl: Conn, kind: Kind, text: str) -> float:
    """Start a job; returns when its break timer starts (ACK or the ``after`` PROGRESS line)."""
    t = _started(job, text, kind.after)
    for i, line in enumerate(kind.at_mark):
        r = ctl.request(line, f"m{i}")
        if r.status != "OK":
            raise RuntimeError(f"{line}: {r}")
    return t


def _started(job: Conn, text: str, after: str) -> float:
    job.send(f"@j {text}")
    t, r = job.next(lambda r: r.tag == "j")
    if r.status != "ACK":
        raise RuntimeError(f"{text}: {r}")
    if not after:
        return t
    while True:
        t, r = job.next(lambda r: r.tag == "j")
        if r.status in FINAL:
            raise RuntimeError(f"{text} ended before '{after}': {r}")
        if r.status == "PROGRESS" and any(after == f"{k}={v}" or after in str(v) for k, v in r.fields.items()):
            return t


def prepare(ctl: Conn, kind: Kind) -> None:
    for i, line in enumerate(kind.before):
        r = ctl.request(line, f"p{i}")
        if r.status != "OK":
            raise RuntimeError(f"{line}: {r}")


def calibrate(job: Conn, ctl: Conn, kind: Kind) -> float:
    """How long the job runs, unbroken, from its break timer's start."""
    prepare(ctl, kind)
    t0 = start(job, ctl, kind, kind.starts[0])
    t, r = job.next(_final_of("j"))
    if r.status != "OK":
        raise RuntimeError(f"{kind.starts[0]}: {r}")
    return t - t0


def run_kind(port: int, kind: Kind, trials: int) -> dict[str, Any]:
    job, ctl = Conn(port), Conn(port)
    try:
        for i, line in enumerate(kind.setup):
            r = job.request(line, f"s{i}")
            if r.status != "OK":
                raise RuntimeError(f"setup {line}: {r}")
        window = kind.window if kind.window is not None else calibrate(job, ctl, kind)
        ok_ms: list[float] = []
        err_ms: list[float] = []
        missed = 0
        order_ok = 0
        for i in range(trials):
            text = kind.starts[(i + 1) % len(kind.starts)]  # the calibration ran the first
            prepare(ctl, kind)
            t_start = start(job, ctl, kind, text)
            delay = window * 0.9 * (i + 0.5) / trials
            time.sleep(max(0.0, t_start + delay - time.perf_counter()))
            t0 = job.send("@b break")  # on the job's own connection: the lines' order is the server's
            got = [job.next(lambda r: r.tag in ("b", "j") and r.status in FINAL) for _ in range(2)]
            (t_ok, brk), (t_err, final) = sorted(got, key=lambda item: item[1].tag != "b")
            if brk.status != "OK":
                raise RuntimeError(f"break: {brk}")
            if final.status == "OK" or brk.fields.get("interrupted") == "none":
                missed += 1
            else:
                if final.fields.get("code") != "E_INTERRUPTED":
                    raise RuntimeError(f"{text}: {final}")
                ok_ms.append((t_ok - t0) * 1000)
                err_ms.append((t_err - t0) * 1000)
                order_ok += got[0][1].tag == "b"
            r = ctl.request("continue", "c")
            if r.status != "OK":
                raise RuntimeError(f"continue after break: {r}")
        return {"kind": kind.name, "trials": trials, "missed": missed, "window_s": round(window, 3),
                "ok_ms": ok_ms, "error_ms": err_ms, "ok_first": order_ok}
    finally:
        job.close()
        ctl.close()


def _pct(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    if len(values) == 1:
        return values[0]
    return statistics.quantiles(values, n=100, method="inclusive")[int(q) - 1] if q < 100 else max(values)


def table(rows: list[dict[str, Any]]) -> str:
    out = ["| job | trials (missed) | break OK p50 | break OK max | job ERROR p50 | job ERROR max | OK before ERROR |",
           "|---|---|---|---|---|---|---|"]
    for row in rows:
        ok, err = row["ok_ms"], row["error_ms"]
        out.append(f"| {row['kind']} | {row['trials']} ({row['missed']}) | {_pct(ok, 50):.1f} ms | {_pct(ok, 100):.1f} ms "
                   f"| {_pct(err, 50):.1f} ms | {_pct(err, 100):.1f} ms | {row['ok_first']}/{len(ok)} |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--trials", type=int, default=20)
    p.add_argument("--kinds", default=",".join(KINDS), help="comma-separated rows (default all): " + ", ".join(KINDS))
    p.add_argument("--set", action="append", default=[], metavar="MODULE.KEY=VALUE", help="server configuration override")
    p.add_argument("--in-process", action="store_true", help="run the server in a thread of this process")
    p.add_argument("--json", help="also write the raw figures here")
    args = p.parse_args(argv)
    kinds = [KINDS[name.strip()] for name in args.kinds.split(",") if name.strip()]
    sets = ["server.warm_up=false", *args.set]
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="rvs-break-") as tmp:
        stop: Callable[[], Any]
        if args.in_process:
            from rvs_server.client.session import ServerThread
            srv = ServerThread([f"server.data={tmp}", "server.port=0", "server.web_port=0", *sets]).start()
            port, stop = srv.port, srv.stop
        else:
            from rvs_server.client.session import ServerProcess
            proc = ServerProcess(Path(tmp), [a for s in sets for a in ("--set", s)])
            port, stop = proc.start(), proc.stop
        try:
            for kind in kinds:
                t = time.monotonic()
                rows.append(run_kind(port, kind, args.trials))
                print(f"{kind.name}: {time.monotonic() - t:.0f} s", file=sys.stderr, flush=True)
        finally:
            stop()
    print(table(rows))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
