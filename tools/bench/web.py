"""Benchmark: the operator web console.

1. Layer render time of a ~2000 x 2000 layer (cold: read, colour, encode; warm: the cache), on the
   simulated quarry's terrain and on real terrain (the HiRISE Mars DTM crop and the Kootenai lidar
   DEM of ../shared/realdata, resampled to the same size).
2. Time to first map: a page's requests (page, script, style, WebSocket state, the DEM layer) on a
   server whose current DEM is ~1800 x 1800 cells, cold and warm.
3. Event latency with 5 pages open while a DEM job runs: each PROGRESS line's arrival at a page
   minus its arrival at the TCP client that started the job (the page path's extra delay).
4. TCP ``status`` p50/p99 while a DEM job runs, without and with 5 pages open (ratio).

The server runs in this process on its own loop thread, as rvs-server runs it.

    python -m tools.bench.web [--cell 0.005]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import socket
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from prox_workflows.grid import GridGeometry, write_geotiff
from rvs_server.main import build_config, run
from rvs_server.web.tiles import LayerCache

REALDATA = Path(__file__).resolve().parents[2].parent / "shared" / "realdata"
SIDE = 2000


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def terrains() -> list[tuple[str, np.ndarray, float]]:
    """(name, heights, cell) at ~SIDE cells on the longer side."""
    from drivers.sim.world import World

    out = []
    quarry = World.from_scene("quarry").terrain
    out.append(("sim quarry (2 cm heightfield)", quarry.heights, quarry.cell))
    mars = REALDATA / "dem" / "mars_dtm.npy"
    if mars.is_file():
        out.append(("real Mars HiRISE DTM (1 m, resampled)", np.load(mars).astype(np.float32), 1.01))
    lidar = REALDATA / "dem" / "DEM-kootenai_37x50_1x1.asc"
    if lidar.is_file():
        lines = lidar.read_text().splitlines()
        header = {ln.split()[0].lower(): float(ln.split()[1]) for ln in lines[:6] if ln.split()[0][0].isalpha()}
        grid = np.loadtxt(lines[len(header):], dtype=np.float32)
        grid[grid == header.get("nodata_value", -9999)] = np.nan
        out.append(("real Kootenai lidar DEM (1 m, UTM, resampled)", grid, header["cellsize"]))
    return terrains_at(out)


def terrains_at(items: list[tuple[str, np.ndarray, float]]) -> list[tuple[str, np.ndarray, float]]:
    out = []
    for name, z, cell in items:
        f = SIDE / max(z.shape)
        size = (round(z.shape[1] * f), round(z.shape[0] * f))
        out.append((name, cv2.resize(z, size, interpolation=cv2.INTER_CUBIC), cell / f))
    return out


def bench_render(tmp: Path) -> None:
    print("## layer render (PNG for the page), ~2000 x 2000")
    print(f"{'terrain':48s} {'cells':>11s} {'cold ms':>8s} {'warm ms':>8s} {'PNG MB':>7s}")
    for i, (name, z, cell) in enumerate(terrains()):
        path = tmp / f"t{i}" / "dem.tif"
        path.parent.mkdir()
        # UTM-sized origins for the real rows: the renderer must not care where the map lies
        write_geotiff(path, z, GridGeometry(cell, 556440.0 if "real" in name else -4.0,
                                            5394932.0 if "real" in name else 8.0, z.shape[1], z.shape[0]))
        cache = LayerCache()
        t0 = time.perf_counter()
        image = cache.get("dem", path)
        cold = time.perf_counter() - t0
        t0 = time.perf_counter()
        cache.get("dem", path)
        warm = time.perf_counter() - t0
        print(f"{name:48s} {z.shape[1]:>5d}x{z.shape[0]:<5d} {cold * 1000:8.0f} {warm * 1000:8.2f} "
              f"{len(image.png) / 1e6:7.2f}")


class Server:
    """rvs-server on its own loop thread, with its console on ``web_port``."""

    def __init__(self, data: Path, web_port: int, cell: float, sets: list[str] | None = None) -> None:
        self.store = build_config(None, [f"server.data={data}", "server.port=0", f"server.web_port={web_port}",
                                         "server.warm_up=false", "drivers.ptu.time_scale=0", "server.scene=office",
                                         f"dem_full_tof.cell={cell}", *(sets or [])])
        self.port = 0
        self.app: Any = None
        self.ready = threading.Event()
        self.thread = threading.Thread(target=lambda: asyncio.run(run(
            self.store, ready=self._ready, handle_signals=False, on_app=self._app)), daemon=True)
        self.thread.start()
        self.ready.wait(60)

    def _ready(self, port: int) -> None:
        self.port = port
        self.ready.set()

    def _app(self, app: Any) -> None:
        self.app = app

    def stop(self) -> None:
        self.app.loop.call_soon_threadsafe(self.app.stopping.set)
        self.thread.join(30)


async def tcp_request(port: int, line: str, on_line: Any = None) -> tuple[str, float]:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    await reader.readline()
    writer.write(line.encode() + b"\n")
    await writer.drain()
    while True:
        raw = (await reader.readline()).decode().rstrip("\r\n")
        now = time.perf_counter()
        if on_line is not None:
            on_line(raw, now)
        parts = raw.split(" ")
        if len(parts) > 1 and parts[1] in ("OK", "ERROR"):
            writer.close()
            return raw, now


async def status_loop(port: int, stop: asyncio.Event) -> list[float]:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    await reader.readline()
    out = []
    while not stop.is_set():
        t0 = time.perf_counter()
        writer.write(b"status\n")
        await writer.drain()
        while True:
            line = await reader.readline()
            if b" OK " in line or b" ERROR " in line:
                break
        out.append((time.perf_counter() - t0) * 1000)
        await asyncio.sleep(0.01)
    writer.close()
    return out


async def page(base: str, received: dict[str, float], stop: asyncio.Event, opened: asyncio.Event) -> None:
    import aiohttp

    async with aiohttp.ClientSession() as http, http.ws_connect(base.replace("http", "ws") + "/ws") as ws:
        opened.set()
        while not stop.is_set():
            try:
                msg = await asyncio.wait_for(ws.receive(), 0.5)
            except TimeoutError:
                continue
            if msg.type != aiohttp.WSMsgType.TEXT:
                break
            now = time.perf_counter()
            data = json.loads(msg.data)
            if data["type"] == "reply" and data["reply"]["status"] == "PROGRESS":
                received.setdefault(data["text"], now)


async def first_map(base: str) -> float:
    import aiohttp

    t0 = time.perf_counter()
    async with aiohttp.ClientSession() as http:
        for path in ("/", "/static/console.js", "/static/console.css"):
            async with http.get(base + path) as resp:
                await resp.read()
        async with http.ws_connect(base.replace("http", "ws") + "/ws") as ws:
            while True:
                data = json.loads((await ws.receive()).data)
                if data["type"] == "state":
                    break
        async with http.get(base + data["maps"]["dem"]["url"]) as resp:
            await resp.read()
    return time.perf_counter() - t0


async def dem_with_pages(srv: Server, base: str, pages: int) -> tuple[list[float], list[float]]:
    """Status latencies (ms) during a DEM job, and the page-minus-TCP PROGRESS delays (ms)."""
    stop = asyncio.Event()
    tcp: dict[str, float] = {}
    seen: list[dict[str, float]] = [{} for _ in range(pages)]
    opened = [asyncio.Event() for _ in range(pages)]
    tasks = [asyncio.create_task(page(base, seen[i], stop, opened[i])) for i in range(pages)]
    for ev in opened:
        await ev.wait()
    status = asyncio.create_task(status_loop(srv.port, stop))

    def on_line(raw: str, now: float) -> None:
        if " PROGRESS " in raw:
            tcp.setdefault(raw, now)

    await tcp_request(srv.port, "dem-full-tof -range -120,120,-50,-20 -cell 0.02", on_line)
    await asyncio.sleep(0.5)
    stop.set()
    latencies = await status
    await asyncio.gather(*tasks)
    delays = [(got[text] - t) * 1000 for got in seen for text, t in tcp.items() if text in got]
    return latencies, delays


async def bench_server(cell: float) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        web_port = free_port()
        srv = Server(Path(tmp) / "data", web_port, cell)
        base = f"http://127.0.0.1:{web_port}"
        try:
            t0 = time.perf_counter()
            raw, _ = await tcp_request(srv.port, "dem-full-tof -name big")
            made = time.perf_counter() - t0
            shape = srv.app.console.layer_paths()["dem"]
            from prox_workflows.grid import read_geotiff_geometry

            g = read_geotiff_geometry(shape)
            print(f"\n## time to first map (DEM {g.width} x {g.height} cells at {cell} m, made in {made:.0f} s)")
            cold = await first_map(base)
            warm = await first_map(base)
            print(f"cold (renders the layer): {cold * 1000:.0f} ms; warm (cached): {warm * 1000:.0f} ms")
            print("\n## during a DEM job: TCP status latency, and PROGRESS delay to the pages vs the TCP client")
            base_lat, _ = await dem_with_pages(srv, base, 0)
            lat, delays = await dem_with_pages(srv, base, 5)
            p = np.percentile
            print(f"status without pages: p50 {p(base_lat, 50):.2f} ms  p99 {p(base_lat, 99):.2f} ms "
                  f"({len(base_lat)} requests)")
            print(f"status with 5 pages:  p50 {p(lat, 50):.2f} ms  p99 {p(lat, 99):.2f} ms ({len(lat)} requests)")
            print(f"ratio p99 with/without pages: {p(lat, 99) / p(base_lat, 99):.2f}")
            print(f"PROGRESS delay page - TCP client: p50 {p(delays, 50):.2f} ms  p99 {p(delays, 99):.2f} ms "
                  f"({len(delays)} lines over 5 pages)")
        finally:
            srv.stop()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cell", type=float, default=0.005, help="cell of the big DEM (0.005 m: ~1800^2 cells)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        bench_render(Path(tmp))
    asyncio.run(bench_server(args.cell))


if __name__ == "__main__":
    main()
