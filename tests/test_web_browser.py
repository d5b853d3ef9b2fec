"""The operator console in a real browser: Debian's chromium driven by Playwright.

What an operator does: open the page, run a DEM from its button and watch the progress bar and
the map, click a goal on the map and watch navigate drive the simulated rover there. Screenshots
go to ``test-artifacts/`` (or $RVS_ARTIFACTS) for a person to look at.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
from pathlib import Path
from typing import Any

import pytest
from conftest import long_only

CHROMIUM = "/usr/bin/chromium"
ARTIFACTS = Path(os.environ.get("RVS_ARTIFACTS", Path(__file__).resolve().parent.parent / "test-artifacts"))
# Chromium on a closed network: no background connections, no sandbox (CI runs as root)
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync"]

pytestmark = long_only()


def chromium_path() -> str:
    """Debian's chromium, installed with apt if missing; a skip says why only where neither works."""
    if Path(CHROMIUM).is_file():
        return CHROMIUM
    if shutil.which("apt-get") is None or os.geteuid() != 0:
        pytest.skip("no /usr/bin/chromium and no apt-get as root to install it (apt-get install chromium)")
    for cmd in (["apt-get", "install", "-y", "-q", "chromium"], ["apt-get", "update", "-q"],
                ["apt-get", "install", "-y", "-q", "chromium"]):
        subprocess.run(cmd, capture_output=True, timeout=900, env={**os.environ, "DEBIAN_FRONTEND": "noninteractive"})
        if Path(CHROMIUM).is_file():
            return CHROMIUM
    pytest.skip("apt-get could not install chromium (no package registry reachable?)")


@pytest.fixture
def browser() -> Any:
    playwright = pytest.importorskip("playwright.sync_api")
    path = chromium_path()
    with playwright.sync_playwright() as p:
        b = p.chromium.launch(executable_path=path, args=CHROMIUM_ARGS)
        yield b
        b.close()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_operator_runs_a_dem_and_navigates_from_the_page(server_factory: Any, browser: Any) -> None:
    port = free_port()
    srv = server_factory([f"server.web_port={port}", "server.scene=office", "dem_full_tof.range=-60,60,-50,-20",
                          "dem_full_tof.cell=0.04", "navigate.range=-110,30,-55,-20", "navigate.overlap=0.05",
                          "navigate.border=0.3"])
    ARTIFACTS.mkdir(exist_ok=True)
    page = browser.new_page(viewport={"width": 1400, "height": 850})
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.goto(f"http://127.0.0.1:{port}/")
    page.wait_for_selector("#link.up")
    assert page.text_content("#mode") == "ready"
    assert "no map yet" in page.text_content("#layers")

    # a DEM from the button: the bar moves, then the layers arrive and the map is drawn
    page.click("#btn-dem")
    page.wait_for_function("parseFloat(document.getElementById('bar-fill').style.width) > 5", timeout=120_000)
    assert page.text_content("#mode") == "busy"
    assert page.text_content("#job").startswith("dem-full-tof")
    page.wait_for_selector("#layers input[data-layer=dem]", timeout=300_000)
    page.wait_for_function("S.layers.dem && S.layers.dem.ready && S.layers.hazard && S.layers.hazard.ready")
    layers = page.eval_on_selector_all("#layers input", "els => els.map(e => [e.dataset.layer, e.checked])")
    assert {"dem", "hazard", "ortho", "traversability"} <= {name for name, _ in layers}
    assert dict(layers)["dem"] is True
    assert page.text_content("#legend").startswith("hazard")  # the legend of the top layer drawn
    page.screenshot(path=str(ARTIFACTS / "console_dem.png"))
    # the DEM is drawn where the map says: the pixel 1 m ahead of the rover is not background
    x, y = page.evaluate("toScreen(1.0, 0.0)")
    drawn = page.evaluate(f"""(() => {{ const d = ctx.getImageData({x} * devicePixelRatio, {y} * devicePixelRatio,
                                 1, 1).data; return [d[0], d[1], d[2], d[3]]; }})()""")
    assert drawn[3] > 0 and drawn[:3] != [255, 255, 255], drawn

    # click a goal, confirm, and watch the rover move on the map
    box = page.eval_on_selector("#map", "c => c.getBoundingClientRect().toJSON()")
    gx, gy = page.evaluate("toScreen(1.5, -1.2)")
    page.mouse.click(box["x"] + gx, box["y"] + gy)
    assert page.is_visible("#clickmenu")
    line = page.text_content("#clickmenu .cmdline")
    assert line.startswith("navigate -goal 1.50,-1.20") and line.endswith("-auto true")
    page.click("#go-nav")
    page.wait_for_function("S.state.job && S.state.job.command === 'navigate'", timeout=60_000)
    page.wait_for_function("S.plan.length >= 2", timeout=300_000)  # the leg's waypoints, drawn
    page.wait_for_function("Math.hypot(S.state.truth.x, S.state.truth.y) > 0.5", timeout=300_000)
    page.screenshot(path=str(ARTIFACTS / "console_navigate.png"))
    page.wait_for_function("S.state.job === null", timeout=600_000)
    result = page.text_content("#result")
    assert "EGP-RVS-NAVIGATE OK" in result and "reached=true" in result, result
    truth = page.evaluate("S.state.truth")
    assert abs(truth["x"] - 1.5) <= 0.3 + 0.05 and abs(truth["y"] + 1.2) <= 0.3 + 0.05
    assert page.evaluate("S.state.track.length") >= 2
    page.screenshot(path=str(ARTIFACTS / "console_arrived.png"))
    assert not errors, errors
    assert srv.app.jobs.current is None
