"""Benchmark: the console page's load in a real browser, the page of a baseline revision against
today's, side by side on the same server and the same big DEM.

For each page, fresh browser contexts (no HTTP cache) open the console, alternating old and new,
and measure the time from navigation to the first map drawn (the DEM and hazard layers loaded),
how many layer images the page fetched in its first seconds and how many bytes they were. The
server renders every layer ahead (its pre-render), so both pages meet warm layers after a
warm-up load.

    python -m tools.bench.web_page [--cell 0.005] [--baseline REV] [--repeat 5]
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

from tools.bench.web import Server, free_port, tcp_request

ROOT = Path(__file__).resolve().parents[2]
STATIC = ("index.html", "console.js", "console.css")
SETTLE_MS = 1500  # what a page fetches in this long after its first map counts as its load


def static_of(rev: str) -> dict[str, bytes]:
    return {name: subprocess.run(["git", "show", f"{rev}:rvs_server/web/static/{name}"], cwd=ROOT, check=True,
                                 capture_output=True).stdout for name in STATIC}


def load(browser: Any, url: str) -> tuple[float, int, int]:
    """(seconds to the first map, layer images fetched, their bytes) of one fresh page."""
    context = browser.new_context(viewport={"width": 1280, "height": 720})
    page = context.new_page()
    t0 = time.perf_counter()
    page.goto(url)
    page.wait_for_function("S.layers.dem && S.layers.dem.ready && S.layers.hazard && S.layers.hazard.ready",
                           timeout=300_000)
    first = time.perf_counter() - t0
    page.wait_for_timeout(SETTLE_MS)
    sizes = page.evaluate("""performance.getEntriesByType("resource").filter(e => e.name.includes("/layers/"))
                             .map(e => e.encodedBodySize)""")
    context.close()
    return first, len(sizes), sum(sizes)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cell", type=float, default=0.005, help="cell of the big DEM (0.005 m: ~1800^2 cells)")
    ap.add_argument("--baseline", default="3ee13bf^", help="revision whose page is compared with today's")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    from playwright.sync_api import sync_playwright

    pages = {"baseline": static_of(args.baseline), "today": {}}
    with tempfile.TemporaryDirectory() as tmp:
        web_port = free_port()
        srv = Server(Path(tmp) / "data", web_port, args.cell)
        try:
            asyncio.run(tcp_request(srv.port, "dem-full-tof -name big"))
            pages["today"] = dict(srv.app.console._static)
            from prox_workflows.grid import read_geotiff_geometry

            g = read_geotiff_geometry(srv.app.console.layer_paths()["dem"])
            layers = len(srv.app.console.layer_paths())
            print(f"## page load to first map: DEM {g.width} x {g.height} cells at {args.cell} m, {layers} layers, "
                  f"median of alternating fresh pages ({args.repeat} each)")
            results: dict[str, list[tuple[float, int, int]]] = {name: [] for name in pages}
            with sync_playwright() as p:
                browser = p.chromium.launch(executable_path="/usr/bin/chromium", args=[
                    "--no-sandbox", "--disable-gpu", "--disable-background-networking", "--no-first-run"])
                url = f"http://127.0.0.1:{web_port}/"
                load(browser, url)  # warm-up: every layer rendered and cached by the server
                for _ in range(args.repeat):
                    for name, files in pages.items():
                        srv.app.console._static.update(files)
                        results[name].append(load(browser, url))
                browser.close()
            print(f"{'page':10s} {'first map ms (median)':>22s} {'layer images':>13s} {'layer MB':>9s}")
            for name, rows in results.items():
                first = statistics.median(r[0] for r in rows) * 1000
                print(f"{name:10s} {first:22.0f} {rows[0][1]:13d} {rows[0][2] / 1e6:9.2f}")
            base, now = (statistics.median(r[0] for r in results[k]) for k in ("baseline", "today"))
            print(f"ratio today/baseline: first map {now / base:.2f}, bytes "
                  f"{results['today'][0][2] / max(1, results['baseline'][0][2]):.2f}")
        finally:
            srv.stop()


if __name__ == "__main__":
    main()
