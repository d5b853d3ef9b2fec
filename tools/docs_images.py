"""Make the pictures in docs/img: every preview kind of a DEM and a navigation, and the web
console (after the DEM, its camera panel, and after a navigate on a laptop, a tablet and a phone:
1280 x 720, 768 x 1024, 390 x 844), from one simulated session (office scene). Look at them after running this.

    python -m tools.docs_images [--out docs/img] [--console-only]
"""

from __future__ import annotations

import argparse
import asyncio
import shutil
import tempfile
from pathlib import Path

from tools.bench.web import Server, free_port, tcp_request

SCREENS = ((1280, 720), (768, 1024), (390, 844))  # laptop, tablet, phone
PREVIEWS = ("dem", "ortho", "hazard", "traversability", "slope", "step", "roughness", "variance", "count",
            "filled")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/img")
    ap.add_argument("--console-only", action="store_true", help="only the console's screenshots")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        web_port = free_port()
        srv = Server(Path(tmp) / "data", web_port, 0.02, ["navigate.range=-110,30,-55,-20", "navigate.overlap=0.05",
                                                         "navigate.border=0.3"])
        try:
            from playwright.sync_api import sync_playwright

            asyncio.run(tcp_request(srv.port, "dem-full-tof -range -150,150,-50,-15 -name site"))
            asyncio.run(tcp_request(srv.port, "grab-stereo -resolution low -output docs"))  # for the camera panel
            for layer in () if args.console_only else PREVIEWS:
                shutil.copy(Path(tmp) / "data" / "dem" / f"site_{layer}.png", out / f"preview_{layer}.png")
            with sync_playwright() as p:
                browser = p.chromium.launch(executable_path="/usr/bin/chromium", args=[
                    "--no-sandbox", "--disable-gpu", "--disable-background-networking", "--no-first-run"])
                page = browser.new_page(viewport={"width": 1400, "height": 850})
                page.goto(f"http://127.0.0.1:{web_port}/")
                page.wait_for_function("S.layers.dem && S.layers.dem.ready && S.layers.hazard && S.layers.hazard.ready")
                page.screenshot(path=str(out / "console_dem.png"))
                # the camera panel: the scan's last ToF frames and the stereo pair's left image
                page.click("#tab-cameras")
                page.wait_for_function("['tof_amplitude', 'tof_depth', 'stereo_left'].every(n => "
                                       "document.querySelector(`figure[data-camera=${n}] img[data-v]`))")
                page.screenshot(path=str(out / "console_cameras.png"))
                page.click("#tab-layers")
                box = page.eval_on_selector("#map", "c => c.getBoundingClientRect().toJSON()")
                gx, gy = page.evaluate("toScreen(1.5, -1.2)")
                page.mouse.click(box["x"] + gx, box["y"] + gy)
                page.click("#go-nav")
                page.wait_for_function("S.plan.length >= 2", timeout=300_000)
                page.wait_for_function("S.state.job === null", timeout=600_000)
                page.wait_for_timeout(800)
                page.screenshot(path=str(out / "console_navigate.png"))
                for width, height in SCREENS:  # each a fresh page: its own layout and fit
                    small = browser.new_page(viewport={"width": width, "height": height}, has_touch=width < 900)
                    small.goto(f"http://127.0.0.1:{web_port}/")
                    small.wait_for_function("S.layers.dem && S.layers.dem.ready && S.layers.hazard && S.layers.hazard.ready")
                    small.wait_for_timeout(400)
                    small.screenshot(path=str(out / f"console_{width}x{height}.png"))
                browser.close()
            nav = Path(tmp) / "data" / "nav"
            for src, name in () if args.console_only else ((next(nav.glob("*_traverse.png")), "traverse.png"),
                              (next(nav.glob("*_leg1_plan_ortho.png")), "plan_ortho.png"),
                              (next(nav.glob("*_leg1_plan_map.png")), "plan_map.png")):
                shutil.copy(src, out / name)
        finally:
            srv.stop()
    print(f"wrote {len(list(out.glob('*.png')))} pictures to {out}")


if __name__ == "__main__":
    main()
