"""Soak test of an RVS server: many clients of mixed traffic for minutes, then a verdict.

Each client sends valid and invalid requests one after another (status, help, pose, config,
events and format switches, unknown commands, bad options, syntax errors, over-long and non-UTF-8
lines, blank and comment lines), starts short jobs (sleep, move-ptu, grab-tof) without waiting
for them, and now and then sends break or continue. Every request that is not blank or a comment
must get its final line. The server's resident memory is sampled from /proc: its growth is
measured from the end of a warm-up to the end of the run, and its file descriptors before the
clients connect and after they have gone.

    python -m tools.soak --seconds 600 --clients 20          # starts its own simulated server
    python -m tools.soak --port 7070 [--pid 1234] --seconds 60  # an already running one

Exit status 0 when every request was answered, nothing was E_INTERNAL or unparseable, memory grew
less than --max-growth and no file descriptor leaked; 1 otherwise; 2 on bad usage.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import random
import re
import statistics
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rvs_server.protocol import ProtocolError, parse_reply

FINAL = ("OK", "ERROR")
FAST = ["--set", "drivers.ptu.time_scale=0", "--set", "sim.time_scale=0", "--set", "server.web_port=0",
        "--set", "server.foxglove_port=0"]

# (weight, kind, line); {t} is the client's tag for the request, {a} {b} random numbers
MIX: list[tuple[float, str, str]] = [
    (12, "ok", "@{t} status"),
    (6, "ok", "@{t} version"),
    (4, "ok", "@{t} help"),
    (3, "ok", "@{t} help grab-tof"),
    (4, "ok", "@{t} pose -x {a} -y {b} -heading 10"),
    (3, "ok", "@{t} config -module sleep"),
    (2, "ok", "@{t} events off"),
    (2, "ok", "@{t} events on"),
    (2, "ok", "@{t} format json"),
    (2, "ok", "@{t} format text"),
    (4, "bad", "@{t} frobnicate -x 1"),
    (4, "bad", "@{t} sleep -seconds abc"),
    (3, "bad", '@{t} status -x "unterminated'),
    (3, "bad", "@{t} move-ptu -pan 1000"),
    (3, "bad", "@{t} grab-tof -output ../escape"),
    (2, "bad", "@{t} config -module server -set port=1"),
    (2, "bad", "@{t} help nosuch"),
    (2, "bad", "@{t}"),
    (2, "bad", "@{t} status \udcff\udcfb\x01-verbose"),  # telnet IAC WILL stripped; an unknown option
    (2, "untagged", "@bad/tag status"),
    (2, "untagged", "x" * 5000),
    (2, "bad", "@{t} status \udcc3("),  # not UTF-8 on the wire
    (2, "silent", ""),
    (2, "silent", "# a comment"),
    (5, "job", "@{t} sleep -seconds 0.{a3}"),
    (5, "job", "@{t} move-ptu -pan {a} -tilt -{a2}"),
    (4, "job", "@{t} grab-tof -output soak{a1} -integrate {a1}"),
    (0.7, "ok", "@{t} break"),
    (2, "job", "@{t} continue"),
]
WEIGHTS = [w for w, _, _ in MIX]


def facts(raw: bytes) -> tuple[str, str | None, str | None, str | None]:
    """(status, tag, job, code) of a text or JSON reply line; ValueError if it is neither."""
    text = raw.decode("utf-8", "replace").rstrip("\r\n")
    if text.startswith("{"):
        obj = json.loads(text)
        job = obj.get("job")
        return obj["status"], obj.get("tag"), None if job is None else str(job), obj.get("code")
    try:
        r = parse_reply(text)
    except ProtocolError as exc:
        raise ValueError(str(exc)) from None
    return r.status, r.tag, r.fields.get("job"), r.fields.get("code")


@dataclass
class Tally:
    requests: int = 0  # lines that must get a final line
    finals: int = 0  # final lines of requests that were not started as jobs
    silent: int = 0  # blank and comment lines (no reply)
    jobs_acked: int = 0
    job_finals: int = 0
    codes: dict[str, int] = field(default_factory=dict)
    internal: list[str] = field(default_factory=list)
    malformed: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    latencies: list[float] = field(default_factory=list)
    by_command: dict[str, list[float]] = field(default_factory=dict)
    unanswered: int = 0


async def client(i: int, host: str, port: int, stop_at: float, seed: int, tally: Tally) -> None:
    rng = random.Random(seed * 1000 + i)
    try:
        reader, writer = await asyncio.open_connection(host, port, limit=1 << 20)
    except OSError as exc:
        tally.errors.append(f"client {i}: {exc}")
        return
    open_jobs: dict[str, str] = {}  # job id -> tag
    n = 0

    async def line() -> tuple[str, str | None, str | None, str | None]:
        raw = await asyncio.wait_for(reader.readline(), 60)
        if not raw:
            raise ConnectionError("server closed the connection")
        try:
            status, tag, job, code = facts(raw)
        except (ValueError, KeyError) as exc:
            tally.malformed.append(f"{raw[:120]!r}: {exc}")
            return "?", None, None, None
        if code == "E_INTERNAL":
            tally.internal.append(raw[:200].decode("utf-8", "replace"))
        if status in FINAL:
            tally.codes[code or "OK"] = tally.codes.get(code or "OK", 0) + 1
            if job is not None and open_jobs.get(job) == tag and code != "E_BUSY":
                del open_jobs[job]
                tally.job_finals += 1
        return status, tag, job, code

    try:
        await asyncio.wait_for(reader.readline(), 30)  # hello
        while time.monotonic() < stop_at:
            n += 1
            tag = f"c{i}n{n}"
            _, kind, template = rng.choices(MIX, WEIGHTS)[0]
            text = template.format(t=tag, a=rng.randint(-150, 150), b=rng.randint(-40, 40), a1=rng.randint(1, 3),
                                   a2=rng.randint(1, 40), a3=rng.randint(0, 5))
            writer.write(text.encode("utf-8", "surrogateescape") + b"\n")
            if kind == "silent":
                tally.silent += 1
                continue
            tally.requests += 1
            want = None if kind == "untagged" else tag  # every job request is tagged
            t0 = time.perf_counter()
            while True:
                status, rtag, job, code = await line()
                if rtag != want:
                    continue  # events, progress and the final lines of earlier jobs
                if status == "ACK" and job is not None:
                    open_jobs[job] = rtag  # its final line is awaited while the client goes on
                    tally.jobs_acked += 1
                    break
                if status in FINAL:
                    tally.finals += 1
                    if kind != "job":
                        took = time.perf_counter() - t0
                        tally.latencies.append(took)
                        words = text.split()
                        name = words[1] if kind != "untagged" and len(words) > 1 else "(untagged)"
                        tally.by_command.setdefault(name, []).append(took)
                    break
            await asyncio.sleep(rng.random() * 0.01)
        # the jobs still running: their final lines are owed too
        deadline = time.monotonic() + 60
        while open_jobs and time.monotonic() < deadline:
            await line()
    except (TimeoutError, ConnectionError, OSError) as exc:
        tally.errors.append(f"client {i}: {type(exc).__name__}: {exc}")
    finally:
        tally.unanswered += len(open_jobs)
        writer.close()
        try:
            await writer.wait_closed()
        except (ConnectionError, OSError):
            pass


# ------------------------------------------------------------------------------------ /proc


def rss_kb(pid: int) -> int:
    for row in Path(f"/proc/{pid}/status").read_text().splitlines():
        if row.startswith("VmRSS:"):
            return int(row.split()[1])
    return 0


def fd_count(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/fd"))


def find_listener(port: int) -> int | None:
    """The pid that holds the listening TCP socket of ``port`` (readable /proc needed)."""
    inodes = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            rows = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for row in rows:
            cols = row.split()
            if cols[3] == "0A" and int(cols[1].split(":")[1], 16) == port:
                inodes.add(cols[9])
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            for fd in os.listdir(f"/proc/{pid}/fd"):
                m = re.fullmatch(r"socket:\[(\d+)\]", os.readlink(f"/proc/{pid}/fd/{fd}"))
                if m and m.group(1) in inodes:
                    return int(pid)
        except OSError:
            continue
    return None


def percentile(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    s = sorted(values)
    return s[min(len(s) - 1, max(0, int(round(q / 100 * len(s) + 0.5)) - 1))]


# ------------------------------------------------------------------------------------ run


async def soak(host: str, port: int, pid: int | None, seconds: float, warmup: float, clients: int,
               seed: int, progress: bool) -> dict[str, Any]:
    tally = Tally()
    fds_before = fd_count(pid) if pid else None
    samples: list[tuple[float, int]] = []
    t_start = time.monotonic()
    stop_at = t_start + warmup + seconds

    async def sample() -> None:
        while True:
            now = time.monotonic()
            if pid:
                samples.append((now - t_start, rss_kb(pid)))
            if progress:
                print(f"\r{now - t_start:6.0f} s  requests {tally.requests:8d}  answered {tally.finals:8d}"
                      + (f"  rss {samples[-1][1] / 1024:6.1f} MiB" if samples else ""), end="", file=sys.stderr)
            await asyncio.sleep(0.5)

    sampler = asyncio.ensure_future(sample())
    await asyncio.gather(*(client(i, host, port, stop_at, seed, tally) for i in range(clients)))
    sampler.cancel()
    if progress:
        print(file=sys.stderr)
    elapsed = time.monotonic() - t_start
    out: dict[str, Any] = {
        "seconds": round(elapsed, 1), "warmup": warmup, "clients": clients,
        "requests": tally.requests, "answered": tally.finals + tally.job_finals,
        "unanswered": tally.requests - tally.finals - tally.job_finals,
        "silent_lines": tally.silent, "jobs": tally.jobs_acked, "job_finals": tally.job_finals,
        "rate_per_s": round(tally.requests / max(elapsed, 1e-9), 1),
        "latency_p50_ms": round(percentile(tally.latencies, 50) * 1000, 2),
        "latency_p99_ms": round(percentile(tally.latencies, 99) * 1000, 2),
        "p99_ms_by_command": {k: round(percentile(v, 99) * 1000, 2) for k, v in sorted(tally.by_command.items())},
        "codes": dict(sorted(tally.codes.items())), "internal": tally.internal[:5], "malformed": tally.malformed[:5],
        "errors": tally.errors[:5],
    }
    if pid:
        await asyncio.sleep(0.5)
        deadline = time.monotonic() + 10
        while fd_count(pid) > (fds_before or 0) and time.monotonic() < deadline:
            await asyncio.sleep(0.1)
        # Memory as the median of the first and of the last quarter of the measured samples:
        # renders allocate and free tens of MiB, so single samples jitter by several per cent.
        after = [rss for t, rss in samples if t >= warmup] or [rss_kb(pid)]
        w = max(1, len(after) // 4)
        rss_base, end = statistics.median(after[:w]), statistics.median(after[-w:])
        step = max(1, len(samples) // 20)
        out["rss_timeline_mib"] = [(round(t), round(rss / 1024, 1)) for t, rss in samples[::step]]
        out.update(rss_base_kb=int(rss_base), rss_end_kb=int(end), rss_max_kb=max(after),
                   rss_growth=round((end - rss_base) / rss_base, 4),
                   fds_before=fds_before, fds_after=fd_count(pid))
    return out


def verdict(result: dict[str, Any], max_growth: float) -> list[str]:
    problems = []
    if result["unanswered"]:
        problems.append(f"{result['unanswered']} requests without a final line")
    for key in ("internal", "malformed", "errors"):
        if result[key]:
            problems.append(f"{key}: {result[key][:2]}")
    if result.get("rss_growth") is not None and result["rss_growth"] >= max_growth:
        problems.append(f"resident memory grew {result['rss_growth']:.1%} (limit {max_growth:.0%})")
    if result.get("fds_before") is not None and result["fds_after"] > result["fds_before"]:
        problems.append(f"file descriptors {result['fds_before']} -> {result['fds_after']}")
    if not result.get("alive", True):
        problems.append("the server died")
    if result.get("exit_status", 0) != 0:
        problems.append(f"the server exited with {result['exit_status']} on SIGTERM")
    return problems


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.soak", description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=600.0, help="measured duration after the warm-up (default 600)")
    p.add_argument("--warmup", type=float, default=60.0, help="traffic before the memory baseline (default 60)")
    p.add_argument("--clients", type=int, default=20, help="concurrent clients (default 20)")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, help="soak a running server on this port (default: start one)")
    p.add_argument("--pid", type=int, help="its process id, for memory and fds (default: found from the port)")
    p.add_argument("--server", action="store_true", help="start a simulated server in a child process (default "
                   "without --port)")
    p.add_argument("--data", help="data directory of the started server (default: a temporary one)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--max-growth", type=float, default=0.10, help="resident memory growth that fails (default 0.10)")
    p.add_argument("--json", help="also write the result to this file")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    args = p.parse_args(argv)
    if args.clients < 1 or args.seconds <= 0 or args.warmup < 0:
        p.error("--clients must be >= 1, --seconds > 0 and --warmup >= 0")
    server = None
    if args.port is None or args.server:
        from rvs_server.client.session import ServerProcess

        server = ServerProcess(args.data, extra_args=FAST)
        server.start()
        port, pid = server.port, server.proc.pid  # type: ignore[union-attr]
    else:
        port, pid = args.port, args.pid or find_listener(args.port)
    try:
        if server is not None:  # the port accepts before the devices are open: wait for them
            asyncio.run(_ready(args.host, port))
        result = asyncio.run(soak(args.host, port, pid, args.seconds, args.warmup, args.clients, args.seed,
                                  not args.quiet))
        result["alive"] = asyncio.run(_alive(args.host, port))
    finally:
        if server is not None:
            status = server.stop()
    if server is not None:
        result["exit_status"] = status  # SIGTERM: a clean shutdown is 0
    problems = verdict(result, args.max_growth)
    result["problems"] = problems
    text = json.dumps(result, indent=2)
    print(text)
    if args.json:
        Path(args.json).write_text(text + "\n")
    return 1 if problems else 0


async def _ready(host: str, port: int) -> None:
    reader, writer = await asyncio.open_connection(host, port)
    await asyncio.wait_for(reader.readline(), 60)
    writer.write(b"@ready version\n")
    await asyncio.wait_for(reader.readline(), 60)
    writer.close()
    await asyncio.sleep(0.2)


async def _alive(host: str, port: int) -> bool:
    try:
        reader, writer = await asyncio.open_connection(host, port)
        await asyncio.wait_for(reader.readline(), 10)
        writer.write(b"@alive status\n")
        ok = b"OK" in await asyncio.wait_for(reader.readline(), 10)
        writer.close()
        return ok
    except (OSError, TimeoutError):
        return False


if __name__ == "__main__":
    sys.exit(main())

