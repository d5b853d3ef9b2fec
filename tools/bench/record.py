"""Benchmark: what Foxglove publishing and MCAP recording cost the server, on and off side by
side in one run, for this tree and (``--peer``) another checkout of the server (the revision
before the telemetry process, in a ``git worktree``): the time of a heavy job (the README's
24-view ``dem-full-tof``) and the TCP ``status`` latency (p50, p99, max) from another connection
while it runs.

Rows, each on a fresh data directory and a fresh server process (run from the tree measured),
interleaved and repeated (``--repeat``, the best kept):

- ``off``: no Foxglove server, no recording (the baseline);
- ``foxglove``: the Foxglove server with a client subscribed to every channel it advertises
  (without one nothing is encoded: the SDK tells the hub nobody listens);
- ``record``: ``record -start`` before the job, ``record -stop`` after (the stop's time, the
  summary written, is printed apart);
- ``ros2``: as ``record``, in the ``ros2`` profile (``record -start -profile ros2``: the same
  messages as ROS 2 messages, CDR), printed beside ``record`` with the ratio of the two;
- ``both``: Foxglove and a recording together.

The status poller and the Foxglove client run in processes of their own (tools.bench.server's
poller; ``--client`` here), so that only the server's own work decides the figures.

``--stall`` measures instead how long the server's event loop is held up while a map of 10
layers of 1717 x 1695 float32 cells (11.6 MB each, the size of the quarry's) is published to a
subscribed client and to a recording: a coroutine on the server's loop sleeps 1 ms over and over
and notes how late it wakes, for 6 s before the map (the baseline: what the machine's load
alone costs) and 6 s from its publication.

    python -m tools.bench.record [--repeat 2] [--rows off,record,ros2] [--job "dem-full-tof ..."] [--peer ../old]
                                 [--json out.jsonl]
    python -m tools.bench.record --stall [--repeat 3] [--rows record,ros2] [--peer ../old]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
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
ROWS = ("off", "foxglove", "record", "ros2", "both")
STALL_ROWS = ("foxglove", "record", "ros2", "both")
# the rows that record, and the request that starts their recording (a peer without profiles takes the first)
RECORDING = {"record": "record -start -name {}", "ros2": "record -start -name {} -profile ros2",
             "both": "record -start -name {}"}
WINDOW_S = 6.0  # --stall: the loop is watched this long before the map and as long from its publication


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


def stall_row(row: str, tmp: Path, n: int) -> dict[str, Any]:
    """The event loop's lateness (ms) before and after a 10-layer map is published."""
    import numpy as np

    from prox_workflows.grid import GridGeometry, Layers
    from prox_workflows.layers import LAYERS

    fox = free_port() if row in ("foxglove", "both") else 0
    port, app = start_rvs(tmp / f"stall-{row}{n}", [f"server.foxglove_port={fox}", "server.web_port=0"])
    rng = np.random.default_rng(n)
    layers = Layers(GridGeometry(0.02, 0.0, 33.9, 1717, 1695),
                    {name: rng.random((1695, 1717), np.float32) for name in list(LAYERS)[:10]})
    ctl = Control(port)

    async def lateness(seconds: float) -> list[float]:
        late: list[float] = []
        end = time.perf_counter() + seconds
        while time.perf_counter() < end:
            t0 = time.perf_counter()
            await asyncio.sleep(0.001)
            late.append((time.perf_counter() - t0 - 0.001) * 1000)
        return late

    try:
        if row in RECORDING:
            assert ctl.request(RECORDING[row].format(f"stall{n}")).status == "OK"
        with foxglove_client(fox or None) as seen:
            base = asyncio.run_coroutine_threadsafe(lateness(WINDOW_S), app.loop).result()
            during = asyncio.run_coroutine_threadsafe(lateness(WINDOW_S), app.loop)
            time.sleep(0.05)
            app.bus.publish("maps", layers=layers, name="stall")
            late = during.result()
        out: dict[str, Any] = {"row": row, "base_max_ms": max(base), "base_over_20ms": sum(x > TARGET_MS for x in base),
                               "max_ms": max(late), "p99_ms": float(np.percentile(late, 99)),
                               "over_20ms": sum(x > TARGET_MS for x in late),
                               "client_mb": seen.get("bytes", 0) / 1e6}
        if row in RECORDING:
            t0 = time.perf_counter()
            stop = ctl.request("record -stop")
            out.update(file_mb=int(stop.fields["bytes"]) / 1e6, stop_s=time.perf_counter() - t0)
        return out
    finally:
        ctl.close()
        app.loop.call_soon_threadsafe(app.stopping.set)
        time.sleep(1.0)


def run_row(row: str, job: str, tmp: Path, n: int) -> dict[str, Any]:
    fox = free_port() if row in ("foxglove", "both") else 0
    port, app = start_rvs(tmp / f"{row}{n}", [f"server.foxglove_port={fox}", "server.web_port=0"])
    wait_warm_up()
    ctl = Control(port)
    try:
        if row in RECORDING:
            r = ctl.request(RECORDING[row].format(f"{row}{n}"))
            assert r.status == "OK", r
        with foxglove_client(fox or None) as seen, polling(port) as status:
            t0 = time.perf_counter()
            r = ctl.request(job)
            seconds = time.perf_counter() - t0
        assert r.status == "OK", r
        out: dict[str, Any] = {"row": row, "job_s": seconds, **{f"status_{k}": v for k, v in status.items()},
                               "client_messages": seen.get("messages", 0), "client_mb": seen.get("bytes", 0) / 1e6}
        if row in RECORDING:
            t0 = time.perf_counter()
            stop = ctl.request("record -stop")
            out.update(stop_s=time.perf_counter() - t0, file_mb=int(stop.fields["bytes"]) / 1e6,
                       messages=int(stop.fields["messages"]), dropped=int(stop.fields["dropped"]))
        return out
    finally:
        ctl.close()
        app.loop.call_soon_threadsafe(app.stopping.set)
        time.sleep(1.0)


def in_tree(tree: Path, args: list[str]) -> dict[str, Any]:
    """One row in a fresh process running ``tree``'s server (its rvs_server first on the path)."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    out = subprocess.run([sys.executable, str(Path(__file__).resolve()), *args], cwd=tree, env=env,
                         stdout=subprocess.PIPE, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    if sys.argv[1:2] == ["--client"]:
        client_main(sys.argv[2:])
        return
    if sys.argv[1:2] in (["--row"], ["--stall-row"]):
        row, n, tmp, job = sys.argv[2], int(sys.argv[3]), Path(sys.argv[4]), sys.argv[5]
        res = stall_row(row, tmp, n) if sys.argv[1] == "--stall-row" else run_row(row, job, tmp, n)
        print(json.dumps(res), flush=True)
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=2, help="runs of each row; the best is kept (default 2)")
    ap.add_argument("--job", default=JOB, help=f"the heavy job (default: {JOB})")
    ap.add_argument("--peer", type=Path, help="another checkout of the server, measured side by side")
    ap.add_argument("--stall", action="store_true", help="the event loop's lateness while a large map is published")
    ap.add_argument("--rows", help=f"comma-separated rows to run (default all: {','.join(ROWS)}; --stall: "
                                   f"{','.join(STALL_ROWS)}); off is the job's baseline and always runs")
    ap.add_argument("--json", type=Path, help="append every run as a JSON line here")
    args = ap.parse_args()
    trees = {"this": ROOT, **({"peer": args.peer.resolve()} if args.peer else {})}
    rows = STALL_ROWS if args.stall else ROWS
    if args.rows:
        asked = args.rows.split(",")
        unknown = set(asked) - set(rows)
        if unknown:
            ap.error(f"unknown rows {', '.join(sorted(unknown))}; rows: {', '.join(rows)}")
        rows = tuple(r for r in rows if r in asked or (r == "off" and not args.stall))
    key = "max_ms" if args.stall else "job_s"
    best: dict[tuple[str, str], dict[str, Any]] = {}
    with tempfile.TemporaryDirectory(prefix="rvs-bench-record-") as tmp:
        for n in range(args.repeat):
            for row in rows:
                for name, tree in trees.items():
                    if row == "ros2" and name != "this":  # a peer may predate the profiles
                        continue
                    res = in_tree(tree, ["--stall-row" if args.stall else "--row", row, str(n), str(Path(tmp) / name),
                                         args.job])
                    res.update(tree=name, load=load_average())
                    print(json.dumps({k: round(v, 3) if isinstance(v, float) else v for k, v in res.items()}),
                          flush=True)
                    if args.json:
                        with args.json.open("a") as f:
                            f.write(json.dumps(res) + "\n")
                    if (row, name) not in best or res[key] < best[row, name][key]:
                        best[row, name] = res
    if args.stall:
        print(f"\nevent loop lateness, ms (best of {args.repeat} by max; target < {TARGET_MS:g} ms)")
        print(f"{'row':9} {'tree':5} {'base max':>8} {'base >20':>8} {'max':>7} {'p99':>7} {'>20 ms':>7} "
              f"{'max x this':>10}  extra")
        for row in rows:
            for name in trees:
                if (row, name) not in best:
                    continue
                r = best[row, name]
                extra = f"file {r['file_mb']:.1f} MB, stop {r['stop_s']:.2f} s" if "file_mb" in r else ""
                print(f"{row:9} {name:5} {r['base_max_ms']:8.1f} {r['base_over_20ms']:8d} {r['max_ms']:7.1f} "
                      f"{r['p99_ms']:7.1f} {r['over_20ms']:7d} {r['max_ms'] / best[row, 'this']['max_ms']:10.2f}  {extra}")
        _profiles(best, ("max_ms", "stop_s", "file_mb"))
        return
    print(f"\njob: {args.job}   (best of {args.repeat}; status p99 target < {TARGET_MS:g} ms)")
    print(f"{'row':9} {'tree':5} {'job s':>7} {'x off':>6} {'p50 ms':>7} {'p99 ms':>7} {'max ms':>7} {'p99 x off':>9}"
          "  extra")
    for row in rows:
        for name in trees:
            if (row, name) not in best:
                continue
            r, base = best[row, name], best["off", name]
            extra = ""
            if "file_mb" in r:
                extra += (f"file {r['file_mb']:.1f} MB, {r['messages']} msgs, stop {r['stop_s']:.2f} s, "
                          f"dropped {r['dropped']}")
            if r["client_messages"]:
                extra += f"{'; ' if extra else ''}client got {r['client_messages']} msgs, {r['client_mb']:.1f} MB"
            print(f"{row:9} {name:5} {r['job_s']:7.2f} {r['job_s'] / base['job_s']:6.3f} {r['status_p50']:7.2f} "
                  f"{r['status_p99']:7.2f} {r['status_max']:7.2f} {r['status_p99'] / base['status_p99']:9.2f}  {extra}")
    _profiles(best, ("job_s", "status_p99", "stop_s", "file_mb"))


def _profiles(best: dict[tuple[str, str], dict[str, Any]], keys: tuple[str, ...]) -> None:
    """The ros2 row against the record row of this tree, figure by figure."""
    ros2, fox = best.get(("ros2", "this")), best.get(("record", "this"))
    if ros2 is None or fox is None:
        return
    print("\nros2 profile / foxglove profile (this tree): " + ", ".join(
        f"{key} {ros2[key]:.2f} / {fox[key]:.2f} = x{ros2[key] / fox[key]:.2f}" for key in keys))


if __name__ == "__main__":
    main()
