"""Benchmark: request throughput and latency of the RVS server against a minimal asyncio
line-echo server (the ceiling of asyncio line handling on this machine), side by side in one run,
and the p99 latency of ``status`` while a CPU-heavy job runs.

Both servers run in this process (each on its own event loop thread); the load comes from
separate processes so that the client's work does not steal the servers' interpreter.

    python -m tools.bench.server [--clients 20] [--seconds 5]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

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
                           cwd=Path(__file__).resolve().parents[2]) for _ in range(procs)]
    results = [json.loads(p.communicate()[0]) for p in ps]
    return {"count": sum(r["count"] for r in results), "rate": sum(r["rate"] for r in results),
            "p50": max(r["p50"] for r in results), "p99": max(r["p99"] for r in results)}


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


def start_rvs(data: Path, overrides: list[str] | None = None) -> tuple[int, object]:
    from rvs_server.jobs import Job
    from rvs_server.logs import setup
    from rvs_server.main import build_config, run
    from rvs_server.table import command

    @command("bench-burn", job=True, help="benchmark only: pure-Python CPU load until break")
    def burn(job: Job, cfg: None) -> dict:
        n = 0
        while not job.cancelled:
            n += sum(i * i for i in range(20000))  # holds the GIL, the worst case for the loop
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


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--load":
        load_main(sys.argv[2:])
        return
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--clients", type=int, default=20)
    ap.add_argument("--seconds", type=float, default=5.0)
    args = ap.parse_args()

    echo_port = start_echo()
    with tempfile.TemporaryDirectory() as tmp:
        rvs_port, app = start_rvs(Path(tmp))
        echo = run_load(echo_port, args.clients, args.seconds, "version", "")
        rvs = run_load(rvs_port, args.clients, args.seconds, "version", "EGP-RVS-VERSION OK")
        print(f"{'server':<22}{'commands/s':>12}{'p50 ms':>9}{'p99 ms':>9}")
        print(f"{'asyncio line echo':<22}{echo['rate']:>12.0f}{echo['p50']:>9.2f}{echo['p99']:>9.2f}")
        print(f"{'rvs (version)':<22}{rvs['rate']:>12.0f}{rvs['p50']:>9.2f}{rvs['p99']:>9.2f}")
        print(f"throughput ratio rvs/echo: {rvs['rate'] / echo['rate']:.2f} (target >= 0.5)")

        # status latency while a CPU-heavy job runs
        async def during_job() -> dict:
            reader, writer = await asyncio.open_connection("127.0.0.1", rvs_port)
            await reader.readline()
            writer.write(b"bench-burn\n")
            assert b"ACK" in await reader.readline()
            await asyncio.sleep(0.3)
            res = await _load(rvs_port, 1, args.seconds, b"status\n", b"EGP-RVS-STATUS OK")
            writer.write(b"break\n")
            while not (await reader.readline()).startswith(b"EGP-RVS-BREAK"):
                pass
            writer.close()
            return res

        idle = run_load(rvs_port, 1, 2.0, "status", "EGP-RVS-STATUS OK")
        busy = asyncio.run(during_job())
        print(f"status p99 idle: {idle['p99']:.2f} ms; during a CPU-heavy job: {busy['p99']:.2f} ms "
              f"(p50 {busy['p50']:.2f} ms, {busy['count']} requests; target p99 < 20 ms)")


if __name__ == "__main__":
    main()
