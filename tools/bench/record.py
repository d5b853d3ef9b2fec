"""Benchmark: what Foxglove publishing and MCAP recording cost the server, on and off side by
side in one run: the time of a heavy job (the README's 24-view ``dem-full-tof``) and the TCP
``status`` latency (p50, p99, max) from another connection while it runs.

Rows, each on a fresh data directory, interleaved and repeated (``--repeat``, the best kept):

- ``off``: no Foxglove server, no recording (the baseline);
- ``foxglove``: the Foxglove server with a client subscribed to every channel it advertises
  (without one nothing is encoded: the SDK tells the hub nobody listens);
- ``record``: ``record -start`` before the job, ``record -stop`` after (the stop's time, the
  summary written, is printed apart);
- ``both``: the two together.

The status poller and the Foxglove client run in processes of their own (tools.bench.server's
poller; ``--client`` here), so that only the server's own work decides the figures.

    python -m tools.bench.record [--repeat 2] [--job "dem-full-tof ..."] [--json out.jsonl]
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
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from tools.bench.server import ROOT, TARGET_MS, Control, load_average, polling, start_rvs, wait_warm_up

JOB = "dem-full-tof -range -180,180,-50,-10 -overlap 0.3 -name site1"
ROWS = ("off", "foxglove", "record", "both")


def client_main(argv: list[str]) -> None:
    """The Foxglove client's process: subscribe to every channel, count messages and bytes until
    a line arrives on stdin, print them as JSON."""
    import aiohttp

    port = int(argv[0])

    async def run() -> dict[str, int]:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        threading.Thread(target=lambda: (sys.stdin.readline(), loop.call_soon_threadsafe(stop.set)),
                         daemon=True).start()
        counts = {"messages": 0, "bytes": 0}
        async with aiohttp.ClientSession() as session, session.ws_connect(
                f"ws://127.0.0.1:{port}", protocols=["foxglove.sdk.v1"], max_msg_size=0) as ws:
            subscribed: set[int] = set()
            ready = False
            while not stop.is_set():
                try:
                    msg = await ws.receive(timeout=0.2)
                except TimeoutError:
                    continue
                if msg.type == aiohttp.WSMsgType.TEXT:
                    obj = json.loads(msg.data)
                    if obj["op"] == "advertise":
                        subs = [{"id": ch["id"], "channelId": ch["id"]} for ch in obj["channels"]
                                if ch["id"] not in subscribed]
                        subscribed.update(s["id"] for s in subs)
                        await ws.send_str(json.dumps({"op": "subscribe", "subscriptions": subs}))
                        if not ready:
                            ready = True
                            print("ready", flush=True)
                elif msg.type == aiohttp.WSMsgType.BINARY:
                    counts["messages"] += 1
                    counts["bytes"] += len(msg.data)
                else:
                    break
        return counts

    print(json.dumps(asyncio.run(run())), flush=True)


@contextmanager
def foxglove_client(port: int | None) -> Iterator[dict[str, int]]:
    out: dict[str, int] = {}
    if port is None:
        yield out
        return
    p = subprocess.Popen([sys.executable, "-m", "tools.bench.record", "--client", str(port)], cwd=ROOT,
                         stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert p.stdout is not None and p.stdin is not None
    if p.stdout.readline().strip() != "ready":
        raise RuntimeError("the Foxglove client did not start")
    time.sleep(0.5)  # its subscriptions reach the server
    try:
        yield out
    finally:
        p.stdin.write("\n")
        p.stdin.flush()
        out.update(json.loads(p.stdout.readline()))
        p.wait(10)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run_row(row: str, job: str, tmp: Path, n: int) -> dict[str, Any]:
    fox = free_port() if row in ("foxglove", "both") else 0
    port, app = start_rvs(tmp / f"{row}{n}", [f"server.foxglove_port={fox}", "server.web_port=0"])
    wait_warm_up()
    ctl = Control(port)
    try:
        if row in ("record", "both"):
            r = ctl.request(f"record -start -name {row}{n}")
            assert r.status == "OK", r
        with foxglove_client(fox or None) as seen, polling(port) as status:
            t0 = time.perf_counter()
            r = ctl.request(job)
            seconds = time.perf_counter() - t0
        assert r.status == "OK", r
        out: dict[str, Any] = {"row": row, "job_s": seconds, **{f"status_{k}": v for k, v in status.items()},
                               "client_messages": seen.get("messages", 0), "client_mb": seen.get("bytes", 0) / 1e6}
        if row in ("record", "both"):
            t0 = time.perf_counter()
            stop = ctl.request("record -stop")
            out.update(stop_s=time.perf_counter() - t0, file_mb=int(stop.fields["bytes"]) / 1e6,
                       messages=int(stop.fields["messages"]), dropped=int(stop.fields["dropped"]))
        return out
    finally:
        ctl.close()
        app.loop.call_soon_threadsafe(app.stopping.set)
        time.sleep(1.0)


def main() -> None:
    if sys.argv[1:2] == ["--client"]:
        client_main(sys.argv[2:])
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=2, help="runs of each row; the best is kept (default 2)")
    ap.add_argument("--job", default=JOB, help=f"the heavy job (default: {JOB})")
    ap.add_argument("--json", type=Path, help="append every run as a JSON line here")
    args = ap.parse_args()
    best: dict[str, dict[str, Any]] = {}
    with tempfile.TemporaryDirectory(prefix="rvs-bench-record-") as tmp:
        for n in range(args.repeat):
            for row in ROWS:
                res = run_row(row, args.job, Path(tmp), n)
                res["load"] = load_average()
                print(json.dumps({k: round(v, 3) if isinstance(v, float) else v for k, v in res.items()}), flush=True)
                if args.json:
                    with args.json.open("a") as f:
                        f.write(json.dumps(res) + "\n")
                if row not in best or res["job_s"] < best[row]["job_s"]:
                    best[row] = res
    base = best["off"]
    print(f"\njob: {args.job}   (best of {args.repeat}; status p99 target < {TARGET_MS:g} ms)")
    print(f"{'row':9} {'job s':>7} {'x off':>6} {'p50 ms':>7} {'p99 ms':>7} {'max ms':>7} {'p99 x off':>9}  extra")
    for row in ROWS:
        r = best[row]
        extra = ""
        if "file_mb" in r:
            extra += f"file {r['file_mb']:.1f} MB, {r['messages']} msgs, stop {r['stop_s']:.2f} s, dropped {r['dropped']}"
        if r["client_messages"]:
            extra += f"{'; ' if extra else ''}client got {r['client_messages']} msgs, {r['client_mb']:.1f} MB"
        print(f"{row:9} {r['job_s']:7.2f} {r['job_s'] / base['job_s']:6.3f} {r['status_p50']:7.2f} "
              f"{r['status_p99']:7.2f} {r['status_max']:7.2f} {r['status_p99'] / base['status_p99']:9.2f}  {extra}")


if __name__ == "__main__":
    main()
