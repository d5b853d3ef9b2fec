"""The operator console in a real browser: Debian's chromium driven by Playwright.

What an operator does: open the page, run a DEM from its button and watch the progress bar and
the map, click a goal on the map and watch navigate drive the simulated rover there; and what the
page must get right on the way (its layout on a laptop, a tablet and a phone, the layers' order,
legends and thresholds, offline, two pages at once, the locked command line, confirmations).
Screenshots go to ``test-artifacts/`` (or $RVS_ARTIFACTS) for a person to look at.
"""

from __future__ import annotations

import base64
import calendar
import fcntl
import json
import math
import os
import shutil
import socket
import subprocess
import tempfile
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import tifffile
import yaml
from support.marks import long_test
from support.server import ServerThread

from prox_workflows.grid import GridGeometry, read_geotiff, write_geotiff
from rvs_params.hazard import HAZARDOUS
from rvs_server.bus import tapped_call

CHROMIUM = "/usr/bin/chromium"
ARTIFACTS = Path(os.environ.get("RVS_ARTIFACTS", Path(__file__).resolve().parents[3] / "test-artifacts"))
# Chromium on a closed network: no background connections, no sandbox (CI runs as root)
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync"]
DEM = "dem-full-tof -range -20,20,-50,-35 -cell 0.05 -name web"  # one view, a second's work


def chromium_path() -> str:
    """Debian's chromium, installed with apt if missing; a skip says why only where neither works."""
    if Path(CHROMIUM).is_file():
        return CHROMIUM
    if shutil.which("apt-get") is None or os.geteuid() != 0:
        pytest.skip("no /usr/bin/chromium and no apt-get as root to install it (apt-get install chromium)")
    # pytest's workers each reach this on a fresh machine: one installs while the others wait on
    # the lock, since apt-get refuses outright while another holds dpkg's lock
    with open(Path(tempfile.gettempdir()) / "rvs-chromium-install.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        for cmd in ([], ["apt-get", "install", "-y", "-q", "chromium"], ["apt-get", "update", "-q"],
                    ["apt-get", "install", "-y", "-q", "chromium"]):
            if cmd:
                subprocess.run(cmd, capture_output=True, timeout=900,
                               env={**os.environ, "DEBIAN_FRONTEND": "noninteractive"})
            if Path(CHROMIUM).is_file():
                return CHROMIUM
    pytest.skip("apt-get could not install chromium (no package registry reachable?)")


@pytest.fixture(scope="module")
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


OPEN: list[Any] = []  # the browser contexts a test opened, closed after it (each holds a WebSocket)


@pytest.fixture(autouse=True)
def close_pages() -> Iterator[None]:
    yield
    while OPEN:
        OPEN.pop().close()


class Console:
    """A test server with its console, and what the tests ask of it."""

    def __init__(self, data: Path, *overrides: str, web_port: int | None = None) -> None:
        self.web_port = web_port or free_port()
        self.srv = ServerThread(data, [f"server.web_port={self.web_port}", *overrides]).start()
        self.url = f"http://127.0.0.1:{self.web_port}/"
        self.data = data

    def request(self, line: str, timeout: float = 300) -> Any:
        with self.srv.client() as c:
            return c.request(line, timeout=timeout)

    def open(self, browser: Any, width: int = 1280, height: int = 720, *, wait: bool = True, **kw: Any) -> Any:
        """A page in a browser context of its own (its own storage, touch or not)."""
        context = browser.new_context(viewport={"width": width, "height": height}, **kw)
        OPEN.append(context)
        page = context.new_page()
        page.errors = []
        page.on("pageerror", lambda exc: page.errors.append(str(exc)))
        if wait:
            page.goto(self.url)
            page.wait_for_selector("#link.up")
            page.wait_for_function("S.state !== null")
        return page

    def stop(self) -> None:
        self.srv.stop()


@pytest.fixture
def console(tmp_path: Path) -> Iterator[Any]:
    """``console(*overrides)``: a fresh server (for tests that change its mode or stop it)."""
    made: list[Console] = []

    def make(*overrides: str, data: str = "data", web_port: int | None = None) -> Console:
        made.append(Console(tmp_path / data, *overrides, web_port=web_port))
        return made[-1]

    yield make
    for c in made:
        c.stop()


@pytest.fixture(scope="module")
def mapped(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Console]:
    """One server with a DEM, for the tests that only look (layers, legends, hover, downloads)."""
    c = Console(tmp_path_factory.mktemp("mapped") / "data")
    assert c.request(DEM).status == "OK"
    yield c
    c.stop()


def pixel(page: Any, x: float, y: float) -> list[int]:
    """The canvas's RGBA at map point (x, y)."""
    return page.evaluate(f"""(() => {{ const [px, py] = toScreen({x}, {y});
        const d = ctx.getImageData(px * devicePixelRatio, py * devicePixelRatio, 1, 1).data;
        return [d[0], d[1], d[2], d[3]]; }})()""")


def wait_ready(page: Any, *names: str) -> None:
    page.wait_for_function("names => names.every(n => S.layers[n] && S.layers[n].ready)", arg=list(names))


def cell_inside(data: Path, where: Any, reach: int = 1, first: bool = False) -> tuple[float, float]:
    """The centre of a cell of the DEM's grid where ``where(dem)`` holds for every cell
    within ``reach`` (a pixel there is the cell's, not an edge's): the middle one, or the first."""
    dem, g = read_geotiff(data / "dem" / "web_dem.tif")
    ok = where(dem)
    ok[[0, -1], :] = False
    ok[:, [0, -1]] = False
    inner = ok.copy()
    for dr in range(-reach, reach + 1):
        for dc in range(-reach, reach + 1):
            inner &= np.roll(np.roll(ok, dr, 0), dc, 1)
    cells = np.argwhere(inner)
    r, c = cells[0] if first else cells[len(cells) // 2]
    xs, ys = g.centers()
    return float(xs[c]), float(ys[r])


def defined_cell(data: Path) -> tuple[float, float]:
    """Deep inside the seen ground."""
    return cell_inside(data, np.isfinite, reach=2)


def cell_where(data: Path, layer: str, value: float) -> tuple[float, float]:
    """On seen ground where ``layer`` is ``value``."""
    values, _ = read_geotiff(data / "dem" / f"web_{layer}.tif")
    return cell_inside(data, lambda dem: np.isfinite(dem) & (values == value))


def unseen_cell(data: Path) -> tuple[float, float]:
    """Inside the DEM's bounds where it has no height."""
    return cell_inside(data, lambda dem: ~np.isfinite(dem), first=True)


def sent_lines(page: Any) -> list[str]:
    """Record the command lines the page sends from now on (its WebSocket frames)."""
    lines: list[str] = []
    page.on("websocket", lambda ws: ws.on("framesent", lambda payload: lines.append(json.loads(payload)["line"])))
    return lines


# ------------------------------------------------------------------------------ the whole flow


@long_test
def test_operator_runs_a_dem_and_navigates_from_the_page(console: Any, browser: Any) -> None:
    c = console("server.scene=office", "dem_full_tof.range=-60,60,-50,-20", "dem_full_tof.cell=0.04",
                "navigate.range=-110,30,-55,-20", "navigate.overlap=0.05", "navigate.border=0.3")
    ARTIFACTS.mkdir(exist_ok=True)
    page = c.open(browser, 1400, 850)
    assert page.text_content("#mode") == "ready"
    assert "no map yet" in page.text_content("#layers")

    # a DEM from the button: the bar moves, then the layers arrive and the map is drawn
    page.click("#btn-dem")
    page.wait_for_function("parseFloat(document.getElementById('bar-fill').style.width) > 5", timeout=120_000)
    assert page.text_content("#mode") == "busy"
    assert page.text_content("#job").startswith("dem-full-tof")
    page.wait_for_selector("#layers input[data-layer=dem]", timeout=300_000)
    wait_ready(page, "dem", "hazard")
    layers = page.eval_on_selector_all("#layers input[type=checkbox]", "els => els.map(e => [e.dataset.layer, e.checked])")
    assert {"dem", "hazard", "ortho", "traversability"} <= {name for name, _ in layers}
    assert dict(layers)["dem"] is True
    page.screenshot(path=str(ARTIFACTS / "console_dem.png"))
    drawn = pixel(page, 1.0, 0.0)  # the DEM is drawn where the map says: 1 m ahead of the rover
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
    assert not page.errors, page.errors
    assert c.srv.app.jobs.current is None


# ------------------------------------------------------------------------------ wrong answers


def test_two_pages_never_take_each_others_lines_for_their_own(console: Any, browser: Any) -> None:
    c = console()
    a, b = c.open(browser), c.open(browser)
    sent_a, sent_b = sent_lines(a), sent_lines(b)
    a.reload()
    b.reload()
    for page in (a, b):
        page.wait_for_selector("#link.up")
        page.wait_for_function("S.state !== null")
    b.fill("#cmd", "sleep -seconds 30")
    b.press("#cmd", "Enter")
    a.wait_for_function("S.state.job && S.state.job.command === 'sleep'")
    a.click("#btn-break")
    a.wait_for_function("document.getElementById('result').textContent.includes('EGP-RVS-BREAK')")
    b.wait_for_function("document.getElementById('result').textContent.includes('E_INTERRUPTED')")
    assert "E_INTERRUPTED" not in a.text_content("#result")
    tags_a = {line.split()[0] for line in sent_a}
    tags_b = {line.split()[0] for line in sent_b}
    assert tags_a and tags_b and not tags_a & tags_b, (sent_a, sent_b)


def rect(page: Any, selector: str) -> dict[str, float]:
    return page.eval_on_selector(selector, "e => e.getBoundingClientRect().toJSON()")


def overlap(a: dict[str, float], b: dict[str, float]) -> bool:
    return a["x"] < b["x"] + b["width"] and b["x"] < a["x"] + a["width"] and \
        a["y"] < b["y"] + b["height"] and b["y"] < a["y"] + a["height"]


def inside(a: dict[str, float], b: dict[str, float]) -> bool:
    return a["x"] >= b["x"] - 0.5 and a["y"] >= b["y"] - 0.5 and a["x"] + a["width"] <= b["x"] + b["width"] + 0.5 \
        and a["y"] + a["height"] <= b["y"] + b["height"] + 0.5


@pytest.mark.parametrize("width, height", [(1280, 720), (768, 1024), (390, 844)])
def test_the_layout_hides_nothing_on_a_laptop_a_tablet_and_a_phone(mapped: Console, browser: Any,
                                                                    width: int, height: int) -> None:
    page = mapped.open(browser, width, height, has_touch=width < 900, is_mobile=width < 900)
    wait_ready(page, "dem", "hazard")
    page.wait_for_selector("#legend:not([hidden])")
    canvas = rect(page, "#map")
    # the legend lies beside the map, not on its data or its axis labels (drawn inside the canvas)
    assert not overlap(rect(page, "#legend"), canvas), (rect(page, "#legend"), canvas)

    # a tap where the legend used to be (the map's bottom right) opens the click menu, and the
    # menu opened near any edge lies inside the map
    for fx, fy in ((0.97, 0.97), (0.5, 0.98), (0.3, 0.02), (0.97, 0.5)):
        page.mouse.click(canvas["x"] + fx * canvas["width"], canvas["y"] + fy * canvas["height"])
        assert page.is_visible("#clickmenu"), (fx, fy)
        assert inside(rect(page, "#clickmenu"), canvas), (fx, fy, rect(page, "#clickmenu"), canvas)
        page.click("#go-cancel")

    # the grid's axis labels: at least two an axis, inside the map, clear of its buttons, of its
    # scale bar and of one another (canvas pixels, as the page drew them)
    page.evaluate("draw()")
    ticks = [{"x": t["x"], "y": t["y"], "width": t["w"], "height": t["h"], "axis": t["axis"], "text": t["text"]}
             for t in page.evaluate("S.ticks")]
    scale = page.evaluate("scaleBox(size().h)")
    buttons = rect(page, "#mapctl")
    taken = [{"x": scale["x"], "y": scale["y"], "width": scale["w"], "height": scale["h"]},
             {**buttons, "x": buttons["x"] - canvas["x"], "y": buttons["y"] - canvas["y"]}]
    whole = {"x": 0, "y": 0, "width": canvas["width"], "height": canvas["height"]}
    for axis in ("x", "y"):
        assert len([t for t in ticks if t["axis"] == axis]) >= 2, (axis, ticks)
    for i, t in enumerate(ticks):
        assert inside(t, whole) and not any(overlap(t, b) for b in taken + ticks[:i]), (t, taken, ticks)

    # a disabled button is grey, the red break too (no job: it cannot be pressed)
    colours = page.evaluate("""['btn-break', 'btn-continue', 'btn-dem'].map(id => {
        const b = document.getElementById(id); return [b.disabled, getComputedStyle(b).color]; })""")
    (brk_off, brk), (cont_off, cont), (dem_off, dem) = colours
    assert brk_off and cont_off and not dem_off, colours
    rgb = [int(v) for v in brk[brk.index("(") + 1:brk.index(")")].split(",")[:3]]
    assert max(rgb) - min(rgb) < 30 and brk == cont and brk != dem, colours

    # the labels of the goal and of a check-move at the rover's place cover neither each other
    # nor the rover
    placed = page.evaluate("""(() => {
        S.state = {...S.state, pose: {x: 0.5, y: 0.2, heading: 30, stopped: true}, truth: undefined,
                   goal: {x: 0.55, y: 0.2, tolerance: 0.3}, check: {from: [0, 0], to: [0.5, 0.25], verdict: "ok"}};
        draw(); return {labels: S.labels, at: toScreen(0.5, 0.2), scale: S.view.scale, rover: S.state.rover}; })()""")
    labels = [{"x": b["x"], "y": b["y"], "width": b["w"], "height": b["h"], "text": b["text"]} for b in placed["labels"]]
    assert sorted(b["text"] for b in labels) == ["check: ok", "goal"], labels
    (px, py), k = placed["at"], placed["scale"]
    h, half_l, half_w = math.radians(30), placed["rover"]["length"] / 2 * k, placed["rover"]["width"] / 2 * k
    corners = [(px + u * math.cos(h) - v * math.sin(h), py - (u * math.sin(h) + v * math.cos(h)))
               for u in (-half_l, half_l) for v in (-half_w, half_w)]
    xs, ys = [c[0] for c in corners], [c[1] for c in corners]
    body = {"x": min(xs), "y": min(ys), "width": max(xs) - min(xs), "height": max(ys) - min(ys)}
    assert not overlap(labels[0], labels[1]), labels
    assert not any(overlap(b, body) for b in labels), (labels, body)

    if width >= 900:
        # every panel of the side column is in sight without scrolling the page or the column:
        # Job and Actions always, the others one tab (one click) away, each with room to read
        for tab in ("events", "rover", "cameras", "layers"):
            page.click(f"#tab-{tab}")
            pane = rect(page, f"#pane-{tab}")
            assert pane["y"] >= 0 and pane["y"] + pane["height"] <= height + 1 and pane["height"] >= 150, (tab, pane)
            for panel in ("#job", "#cmd", "#btn-break"):
                box = rect(page, panel)
                assert box["y"] >= 0 and box["y"] + box["height"] <= height, (tab, panel, box)
        assert page.evaluate("document.documentElement.scrollHeight") <= height
        aside = page.eval_on_selector("aside", "e => [e.scrollHeight, e.clientHeight]")
        assert aside[0] <= aside[1] + 1, aside
        # a long reply scrolls in its own box
        page.fill("#cmd", "status")
        page.press("#cmd", "Enter")
        page.wait_for_function("document.getElementById('result').textContent.includes('EGP-RVS-STATUS OK')")
        assert rect(page, "#result")["height"] < 140
        page.click("#tab-events")
        log = rect(page, "#log")
        assert log["y"] + log["height"] <= height + 1 and log["height"] >= 120, log
        page.click("#tab-layers")
    page.evaluate("draw()")
    page.screenshot(path=str(ARTIFACTS / f"console_layout_{width}x{height}.png"))
    assert not page.errors, page.errors


@pytest.mark.parametrize("width, height", [(768, 1024), (390, 844)])
def test_below_900_px_the_page_stacks_and_touch_pans_and_pinches_the_map(mapped: Console, browser: Any,
                                                                         width: int, height: int) -> None:
    page = mapped.open(browser, width, height, has_touch=True, is_mobile=True)
    wait_ready(page, "dem", "hazard")
    mapbox = page.eval_on_selector("#mapbox", "e => e.getBoundingClientRect().toJSON()")
    aside = page.eval_on_selector("aside", "e => e.getBoundingClientRect().toJSON()")
    assert mapbox["width"] >= width - 2 and mapbox["height"] >= 300, mapbox
    assert aside["top"] >= mapbox["bottom"] - 1 and aside["width"] >= width - 20, aside
    page.screenshot(path=str(ARTIFACTS / f"console_{width}x{height}.png"))

    cdp = page.context.new_cdp_session(page)
    cx, cy = mapbox["x"] + mapbox["width"] / 2, mapbox["y"] + mapbox["height"] / 2

    def touch(kind: str, *points: tuple[float, float]) -> None:
        cdp.send("Input.dispatchTouchEvent", {"type": kind, "touchPoints": [
            {"x": x, "y": y, "id": i} for i, (x, y) in enumerate(points)]})

    before = page.evaluate("({...S.view})")
    touch("touchStart", (cx, cy))
    for k in range(1, 6):
        touch("touchMove", (cx + 12 * k, cy + 8 * k))
    touch("touchEnd")
    after = page.evaluate("({...S.view})")
    # the point under the finger stays under it: the view's centre moved 60 px left and 40 px up
    assert after["cx"] == pytest.approx(before["cx"] - 60 / before["scale"], rel=1e-3, abs=1e-3)
    assert after["cy"] == pytest.approx(before["cy"] + 40 / before["scale"], rel=1e-3, abs=1e-3)
    touch("touchStart", (cx - 20, cy), (cx + 20, cy))
    for k in range(1, 6):
        touch("touchMove", (cx - 20 - 4 * k, cy), (cx + 20 + 4 * k, cy))
    touch("touchEnd")
    pinched = page.evaluate("({...S.view, page: visualViewport.scale, menu: !document.getElementById('clickmenu').hidden})")
    assert pinched["scale"] == pytest.approx(2 * after["scale"], rel=0.02)  # 40 px apart to 80 px
    assert pinched["page"] == 1 and not pinched["menu"]  # the map zoomed, not the page; no click
    assert not page.errors, page.errors


def test_the_global_map_lies_under_the_rovers_own_layers_and_each_layer_has_an_opacity(
        console: Any, browser: Any, tmp_path: Path) -> None:
    glob = tmp_path / "global"
    glob.mkdir()
    g = GridGeometry.covering(-10, -10, 10, 10, 0.2)
    write_geotiff(glob / "hazard.tif", np.full(g.shape, HAZARDOUS, np.uint8), g)
    c = console(f"navigate.global_maps={glob}")
    page = c.open(browser)
    # a fresh page with a global map alone shows it, fitted, not an empty grid round the rover
    wait_ready(page, "global_hazard")
    view = page.evaluate("S.view")
    assert view["scale"] == pytest.approx(0.92 * min(1280 - 360, 720 - 34) / 20, rel=0.1)
    assert pixel(page, 5.0, 5.0)[0] > 150  # hazardous red

    assert c.request(DEM).status == "OK"
    x, y = defined_cell(c.data)
    # the same stack on the page that met the global map first and on one opened after the DEM
    for reload in (False, True):
        if reload:
            page.reload()
            page.wait_for_selector("#link.up")
        page.wait_for_selector("#layers input[data-layer=dem]")
        page.check("#layers input[data-layer=global_hazard]")
        page.check("#layers input[data-layer=dem]")
        page.uncheck("#layers input[data-layer=hazard]")
        wait_ready(page, "dem", "global_hazard")
        page.evaluate("draw()")
        r, g_, b, _ = pixel(page, x, y)
        assert not (r > 150 and g_ < 80 and b < 80), (reload, r, g_, b)  # the DEM, not the orbital red
    page.eval_on_selector("#layers input[data-opacity=dem]",  # the DEM made transparent shows what is under it
                          "e => { e.value = '0'; e.dispatchEvent(new Event('input')); }")
    r, g_, b, _ = pixel(page, x, y)
    assert r > 150 and g_ < 80 and b < 80, (r, g_, b)
    assert not page.errors, page.errors


def test_an_offline_server_shows_offline_and_a_reconnect_brings_a_fresh_legend(console: Any, browser: Any) -> None:
    c = console()
    assert c.request(DEM).status == "OK"
    page = c.open(browser)
    wait_ready(page, "dem", "hazard")
    assert page.is_visible("#legend")
    c.stop()
    page.wait_for_selector("#link.down")
    assert page.text_content("#mode") == "offline"
    enabled = page.eval_on_selector_all("button.act, #cmd-go", "els => els.filter(e => !e.disabled).map(e => e.id)")
    assert enabled == []
    assert not page.is_visible("#legend")
    c2 = console(data="fresh", web_port=c.web_port)  # another server, no map yet
    page.wait_for_selector("#link.up", timeout=30_000)
    page.wait_for_function("S.state && S.state.mode === 'ready'")
    assert page.text_content("#mode") == "ready"
    assert not page.is_visible("#legend") and "no map yet" in page.text_content("#layers")
    assert not page.eval_on_selector("#btn-dem", "e => e.disabled")
    assert c2.srv.app.console is not None


def test_overlays_stack_track_over_plan_over_check_move_in_distinct_colours(mapped: Console, browser: Any) -> None:
    page = mapped.open(browser)
    wait_ready(page, "dem", "hazard")
    for name in ("dem", "hazard"):
        page.uncheck(f"#layers input[data-layer={name}]")
    page.uncheck("#show-fov")
    page.evaluate("S.view = {cx: 1, cy: 0, scale: 200}; draw()")
    box = page.eval_on_selector("#map", "c => c.getBoundingClientRect().toJSON()")
    gx, gy = page.evaluate("toScreen(1.6, 0)")
    page.mouse.click(box["x"] + gx, box["y"] + gy)
    page.click("#go-check")  # a real check-move along y = 0, from the rover to x = 1.6
    page.wait_for_function("S.state.check && Math.abs(S.state.check.to[0] - 1.6) < 0.02")
    # the plan and the track along the same line (the track as the state would bring it); at
    # each place the colour most of a 16 px stretch of the line shows (dashes leave gaps)
    shown = page.evaluate("""(() => { S.plan = [[0.2, 0, 0], [1.4, 0, 0]]; S.state.track = [[0.6, 0], [1.0, 0]];
        draw(); const at = (x) => { const [px, py] = toScreen(x, 0);
          const d = ctx.getImageData((px - 8) * devicePixelRatio, py * devicePixelRatio, 16 * devicePixelRatio, 1).data;
          const n = {}; for (let i = 0; i < d.length; i += 4) {
            const c = [d[i], d[i + 1], d[i + 2]]; if (Math.max(...c) - Math.min(...c) < 60) continue;
            n[c] = (n[c] || 0) + 1; }
          return Object.entries(n).sort((a, b) => b[1] - a[1])[0][0].split(",").map(Number); };
        return {track: at(0.8), plan: at(1.3), check: at(1.5)}; })()""")
    track, plan, check = (np.array(shown[k]) for k in ("track", "plan", "check"))
    assert np.abs(track - [0x1F, 0x6F, 0xEB]).max() < 20, shown  # the track on top where all three lie
    assert np.abs(plan - track).sum() > 150 and np.abs(check - plan).sum() > 150, shown
    assert np.abs(check - track).sum() > 150, shown
    assert not page.errors, page.errors


def test_unseen_cells_are_drawn_hatched_as_the_legend_shows(mapped: Console, browser: Any) -> None:
    page = mapped.open(browser)
    wait_ready(page, "dem", "hazard")
    x, y = unseen_cell(mapped.data)
    page.evaluate(f"S.view = {{cx: {x}, cy: {y}, scale: 600}}; draw()")  # one cell is 30 px
    colours = page.evaluate("""([x, y]) => { const [px, py] = toScreen(x, y);
        const d = ctx.getImageData((px - 10) * devicePixelRatio, (py - 10) * devicePixelRatio, 20, 20).data;
        const out = new Set();
        for (let i = 0; i < d.length; i += 4) out.add(d[i + 3] > 0 ? `${d[i]},${d[i + 1]},${d[i + 2]}` : "clear");
        return [...out]; }""", [x, y])
    assert len(colours) >= 2, colours  # lines and gaps, not one blank
    assert "swatch transparent" in page.inner_html("#legend")


def test_a_refused_navigate_keeps_the_plan_and_an_accepted_one_marks_the_goal(console: Any, browser: Any) -> None:
    c = console()
    assert c.request(DEM).status == "OK"
    page = c.open(browser)
    page.evaluate("S.plan = [[0, 0, 0], [1, -0.5, 0]]; draw()")
    box = page.eval_on_selector("#map", "c => c.getBoundingClientRect().toJSON()")
    gx, gy = page.evaluate("toScreen(1.5, -1.2)")
    page.mouse.click(box["x"] + gx, box["y"] + gy)
    page.fill("#nav-tol", "0.01")  # under navigate's least tolerance: refused before its ACK
    page.dispatch_event("#nav-tol", "change")
    page.click("#go-nav")
    page.wait_for_function("document.getElementById('result').textContent.includes('E_ARG')")
    assert page.evaluate("S.plan.length") == 2 and page.evaluate("S.state.goal") is None

    c.request("break")  # navigate is refused in break too; continue brings ready back
    assert c.request("continue").status == "OK"
    page.wait_for_function("S.state.mode === 'ready'")
    gx, gy = page.evaluate("toScreen(1.5, -1.2)")  # where the goal is now: the view may have moved since
    page.mouse.click(box["x"] + gx, box["y"] + gy)
    page.fill("#nav-tol", "0.3")
    page.uncheck("#nav-auto")  # the GNC drives: the page's goal stays while it waits for pose
    page.click("#go-nav")
    page.wait_for_function("S.state.goal !== null", timeout=60_000)
    goal = page.evaluate("S.state.goal")
    assert [goal["x"], goal["y"], goal["tolerance"]] == pytest.approx([1.5, -1.2, 0.3], abs=0.01)
    page.wait_for_function("S.plan.length === 0")  # the old plan went when the server took the goal
    page.evaluate("draw()")
    r, g, b, _ = pixel(page, 1.5, -1.2)
    assert max(r, g, b) < 60, (r, g, b)  # the goal's cross, drawn where it was clicked
    c.request("break")


def test_the_rover_icon_follows_the_pose_and_heading_the_gnc_sends(mapped: Console, browser: Any) -> None:
    page = mapped.open(browser)
    try:
        for x, y, heading in ((0.6, 0.3, 90.0), (1.2, -0.4, -45.0)):
            assert mapped.request(f"pose -x {x} -y {y} -heading {heading}").status == "OK"
            page.wait_for_function(f"Math.abs(S.state.pose.x - {x}) < 1e-6 && S.state.pose.heading === {heading}")
            page.evaluate("draw()")
            # the body is dark beside the forward arrow, the arrow yellow ahead along the heading
            h = math.radians(heading)
            body = pixel(page, x - 0.1 * math.sin(h), y + 0.1 * math.cos(h))
            ahead = page.evaluate(f"""(() => {{ const [px, py] = toScreen({x}, {y}); const L = S.state.rover.length * S.view.scale;
                const a = {heading} * Math.PI / 180, r = L / 2 + 10;
                const d = ctx.getImageData((px + r * Math.cos(a)) * devicePixelRatio, (py - r * Math.sin(a)) * devicePixelRatio, 1, 1).data;
                return [d[0], d[1], d[2]]; }})()""")
            assert max(body[:3]) < 90, body
            assert ahead[0] > 200 and ahead[1] > 150 and ahead[2] < 150, ahead
    finally:
        mapped.request("pose -x 0 -y 0 -heading 0")


def test_the_locked_page_names_what_the_server_answers_and_an_unlock_outlives_a_reload(
        console: Any, browser: Any) -> None:
    c = console("server.token=s3cret")
    page = c.open(browser)
    assert page.is_visible("#auth") and page.eval_on_selector("#btn-dem", "e => e.disabled")
    # the panel names the commands the server answers without the token, and they are those
    named = page.text_content("#open-commands").split(", ")
    assert sorted(named) == ["auth", "exit", "help", "version"], named
    assert "status" not in page.text_content("#auth")
    for line, expect in (("help", "EGP-RVS-HELP OK"), ("version", "EGP-RVS-VERSION OK"),
                         ("status", "E_AUTH"), ("dem-full-tof", "E_AUTH")):
        page.fill("#cmd", line)
        page.press("#cmd", "Enter")
        page.wait_for_function(f"document.getElementById('result').textContent.includes({json.dumps(expect)})")
    page.fill("#token", "s3cret")
    page.click("#auth-go")
    page.wait_for_function("!document.getElementById('btn-dem').disabled")

    # a reload (a new WebSocket, a new connection to the server) stays unlocked
    page.reload()
    page.wait_for_selector("#link.up")
    page.wait_for_function("S.authed && !document.getElementById('btn-dem').disabled")
    assert not page.is_visible("#auth")
    page.fill("#cmd", "status")
    page.press("#cmd", "Enter")
    page.wait_for_function("document.getElementById('result').textContent.includes('EGP-RVS-STATUS OK')")
    # another tab of the same browser is not: the token stays with the tab it was given to
    other = page.context.new_page()
    other.errors = []
    other.on("pageerror", lambda exc: other.errors.append(str(exc)))
    other.goto(c.url)
    other.wait_for_selector("#link.up")
    other.wait_for_function("S.state !== null")
    other.wait_for_timeout(300)
    assert other.is_visible("#auth") and other.eval_on_selector("#btn-dem", "e => e.disabled")
    assert not page.errors and not other.errors, (page.errors, other.errors)


def test_an_auth_typed_on_the_command_line_unlocks_the_page_as_the_panel_does(console: Any, browser: Any) -> None:
    token = 'two "words"'  # a space and quotes: the page must send it as one quoted value
    c = console(f"server.token={token}")
    page = c.open(browser)

    def typed(line: str, expect: str) -> str:
        page.fill("#cmd", line)
        page.press("#cmd", "Enter")
        page.wait_for_function(f"document.getElementById('result').textContent.includes({json.dumps(expect)})")
        return page.text_content("#result")

    def unlocked() -> bool:
        return not page.is_visible("#auth") and not page.eval_on_selector("#btn-dem", "e => e.disabled")

    assert "E_AUTH" in typed("auth -token wrong", "EGP-RVS-AUTH ERROR") and not unlocked()
    # the server unlocks the connection, and the page knows it: panel gone, buttons on
    assert "tag=mine-1" in typed('@mine-1 auth -token "two \\"words\\""', "EGP-RVS-AUTH OK")
    page.wait_for_function("S.authed && !document.getElementById('btn-dem').disabled")
    assert unlocked()
    # the token stays out of the command history, which is kept on the disk
    stored = page.evaluate("JSON.stringify(localStorage)")
    assert "words" not in stored and "auth" not in stored, stored
    page.reload()
    page.wait_for_selector("#link.up")
    page.wait_for_function("S.authed && !document.getElementById('btn-dem').disabled")
    assert "EGP-RVS-STATUS OK" in typed("status", "EGP-RVS-STATUS")
    # a wrong token on an unlocked connection leaves it unlocked (the server's rule), the page too
    assert "E_AUTH" in typed("auth -token wrong", "EGP-RVS-AUTH ERROR") and unlocked()
    assert "EGP-RVS-STATUS OK" in typed("status", "EGP-RVS-STATUS")

    # the panel sends the same token, spaces and quotes included, in a tab of its own
    other = c.open(browser)
    other.fill("#token", token)
    other.click("#auth-go")
    other.wait_for_function("S.authed && !document.getElementById('btn-dem').disabled")
    assert not page.errors and not other.errors, (page.errors, other.errors)


def test_a_line_with_its_own_tag_keeps_it_and_its_answer_comes_to_this_page(mapped: Console, browser: Any) -> None:
    page = mapped.open(browser)
    sent = sent_lines(page)
    page.reload()  # its WebSocket, recorded from the start
    page.wait_for_selector("#link.up")
    page.fill("#cmd", "@wxyz-1 status")
    page.press("#cmd", "Enter")
    page.wait_for_function("document.getElementById('result').textContent.includes('EGP-RVS-STATUS OK')")
    assert "tag=wxyz-1" in page.text_content("#result")
    assert sent == ["@wxyz-1 status"], sent
    page.fill("#cmd", "@bad! version")  # a tag the server cannot read: its error still shows
    page.press("#cmd", "Enter")
    page.wait_for_function("document.getElementById('result').textContent.includes('bad tag')")
    assert page.eval_on_selector("#result", "e => e.className") == "error"
    page.fill("#cmd", "version")  # an untagged line gets the page's own tag
    page.press("#cmd", "Enter")
    page.wait_for_function("document.getElementById('result').textContent.includes('EGP-RVS-VERSION OK')")
    assert sent[-1].startswith("@w") and sent[-1].endswith(" version"), sent


def test_events_are_no_pages_own_and_every_page_draws_every_check_move(mapped: Console, browser: Any) -> None:
    a, b = mapped.open(browser), mapped.open(browser)
    for page in (a, b):
        wait_ready(page, "dem", "hazard")
    a.fill("#cmd", "sleep -seconds 0.1")  # its mode EVENTs go to every page
    a.press("#cmd", "Enter")
    a.wait_for_function("document.getElementById('result').textContent.includes('EGP-RVS-SLEEP OK')")
    b.wait_for_function("[...document.querySelectorAll('#log li')].some(li => li.textContent.includes('slept='))")
    for page in (a, b):
        rows = page.eval_on_selector_all("#log li:not(.past)", "els => els.map(e => [e.className, e.textContent])")
        events = [cls for cls, text in rows if "EVENT" in cls and "kind=mode" in text]
        assert events and not any("mine" in cls for cls in events), rows
    mine = a.eval_on_selector_all("#log li.mine", "els => els.map(e => e.textContent)")
    assert any("EGP-RVS-SLEEP ACK" in t for t in mine) and any("EGP-RVS-SLEEP OK" in t for t in mine), mine
    assert not b.eval_on_selector_all("#log li.mine:not(.past)", "els => els.map(e => e.textContent)")

    # a check-move from page a is drawn on page b, and one from a GNC on both
    for page in (a, b):
        page.uncheck("#layers input[data-layer=dem]")
        page.uncheck("#layers input[data-layer=hazard]")
        page.uncheck("#show-fov")
    box = rect(a, "#map")
    gx, gy = a.evaluate("toScreen(1.2, -0.4)")
    a.mouse.click(box["x"] + gx, box["y"] + gy)
    a.click("#go-check")
    for x, y in ((1.2, -0.4), (0.8, 0.5)):
        if x == 0.8:
            assert mapped.request(f"check-move -to {x},{y}").status == "OK"
        for page in (a, b):
            page.wait_for_function(f"S.state.check && Math.abs(S.state.check.to[0] - {x}) < 0.02 "
                                   f"&& Math.abs(S.state.check.to[1] - {y}) < 0.02")
            check = page.evaluate("S.state.check")
            page.evaluate("draw()")
            r, g, bl, _ = pixel(page, x, y)  # the check's end, in its verdict's colour
            colour = {"ok": (0x15, 0x80, 0x3D), "not_traversable": (0xDC, 0x26, 0x26)}.get(check["verdict"],
                                                                                       (0xD9, 0x77, 0x06))
            assert abs(r - colour[0]) + abs(g - colour[1]) + abs(bl - colour[2]) < 60, (check, (r, g, bl))
            assert check["from"] == pytest.approx([0.0, 0.0], abs=0.01)
    assert not a.errors and not b.errors, (a.errors, b.errors)


def test_the_progress_bar_is_the_jobs_and_the_result_box_says_whose_result_it_shows(
        console: Any, browser: Any) -> None:
    c = console()
    page = c.open(browser)
    # the bar after each PROGRESS line, as the page drew it
    page.evaluate("""window.bars = []; const onReplyWas = onReply;
        onReply = (m, past) => { onReplyWas(m, past); if (m.reply.status === "PROGRESS") bars.push([m.reply.phase,
            m.reply.done, m.reply.total, parseFloat(document.getElementById('bar-fill').style.width)]); }; 0""")
    page.fill("#cmd", DEM)
    page.press("#cmd", "Enter")
    page.wait_for_function("document.getElementById('result').textContent.includes('EGP-RVS-DEM-FULL-TOF OK')",
                           timeout=300_000)
    bars = page.evaluate("bars")
    phases = list(dict.fromkeys(p for p, _, _, _ in bars))
    assert phases == ["pointing", "acquire", "process", "write"], bars
    widths = [w for _, _, _, w in bars]
    assert all(b >= a for a, b in zip(widths, widths[1:], strict=False)), bars  # it never goes back
    assert widths[-1] >= 99 and widths[0] < 5, bars
    # each phase fills its share: the acquisition ends near half way, the processing near the end
    acquired = max(w for p, _, _, w in bars if p == "acquire")
    processed = max(w for p, _, _, w in bars if p == "process")
    assert 35 < acquired < 60 and 85 < processed < 99, bars
    # the estimate is the job's: a quarter of the bar in 10 s leaves 30 s
    assert page.evaluate("jobTimes({started: Date.now() / 1000 + S.clock - 10}, 0.25)") == \
        "elapsed 10 s · about 30 s left"
    first = page.text_content("#result")
    job = int(first.split("job=")[1].split()[0])

    # a job another client starts: the result box marks the last result as the previous job's
    with c.srv.client() as gnc:
        gnc.start_job("sleep -seconds 30")
        page.wait_for_function("document.getElementById('result').classList.contains('previous')")
        shown = page.evaluate("""(() => { const e = document.getElementById('result');
            return [getComputedStyle(e, '::before').content, e.textContent]; })()""")
        assert shown == [f'"previous job {job}: "', first], shown
        page.wait_for_function("document.getElementById('times').textContent.includes('elapsed')")
        assert gnc.request("break").status == "OK"
        gnc.until_final(60)
    page.wait_for_function("S.state.mode === 'break' && !S.state.job")
    assert page.text_content("#result") == first and page.text_content("#job") == "none"
    # the page's own next job replaces the result with its ACK
    assert c.request("continue").status == "OK"
    page.wait_for_function("S.state.mode === 'ready'")
    page.fill("#cmd", "sleep -seconds 0.2")
    page.press("#cmd", "Enter")
    page.wait_for_function("document.getElementById('result').textContent.includes('EGP-RVS-SLEEP')")
    assert not page.eval_on_selector("#result", "e => e.classList.contains('previous')")
    assert not page.errors, page.errors


def test_a_page_opened_mid_job_draws_the_whole_jobs_bar_and_drops_the_job_at_its_final_line(
        console: Any, browser: Any) -> None:
    c = console("navigate.range=-20,20,-50,-35")
    watching = c.open(browser)
    watching.evaluate("""window.phases = []; const onReplyWas = onReply; onReply = (m, past) => { onReplyWas(m, past);
        if (m.reply.status === "PROGRESS") phases.push(`${m.reply.leg}/${m.reply.phase}`); }; 0""")
    with c.srv.client() as gnc:
        gnc.start_job("navigate -goal 1.0,0.2 -auto false -loop scan -scan-plan circle")  # leg 1 scans, plans, then waits for the GNC
        watching.wait_for_function("S.state.job && S.state.job.phase === 'drive' && S.bar && S.bar.key === '1/drive'",
                                   timeout=120_000)
        late = c.open(browser)  # opened (as reloaded) while the job waits in its first leg's drive
        late.wait_for_function("S.state.job && S.state.job.phase === 'drive' && S.bar")
        bars = [page.evaluate("[S.bar.fraction, document.getElementById('bar-fill').style.width]")
                for page in (watching, late)]
        # the bar where the page that watched the scan and the plan drew it, not the drive's own
        assert bars[0][0] > 0.3 and bars[1][0] == pytest.approx(bars[0][0], abs=1e-9), (bars, watching.evaluate("phases"))
        assert bars[1][1] == bars[0][1], bars
        late.evaluate("""window.after = []; const onReplyWas = onReply; onReply = (m, past) => { onReplyWas(m, past);
            if (m.reply.status === "ERROR" && m.reply.job !== undefined) after.push(["job", "bar-fill", "btn-break"].map(
                id => { const e = document.getElementById(id); return id === "job" ? e.textContent : id === "bar-fill"
                        ? e.style.width : e.disabled; })); }; 0""")
        assert gnc.request("break").status == "OK"
        assert gnc.until_final(60)[-1].fields["code"] == "E_INTERRUPTED"
    # the final line ends the job on the page at once: no bar begun again from the last state
    late.wait_for_function("after.length > 0")
    assert late.evaluate("after") == [["none", "0px", True]]
    assert not watching.errors and not late.errors, (watching.errors, late.errors)


# ------------------------------------------------------------------------------ what the map says


def test_thresholds_are_marked_on_slope_step_and_roughness(mapped: Console, browser: Any) -> None:
    page = mapped.open(browser)
    for name in ("slope", "step", "roughness"):
        page.check(f"#layers input[data-layer={name}]")
    wait_ready(page, "slope", "step", "roughness")
    meta = yaml.safe_load((mapped.data / "dem" / "web_dem.yaml").read_text())["meta"]["dem2hazard"]
    for name, key in (("slope", "slope_max"), ("step", "step_max"), ("roughness", "roughness_max")):
        marks = page.eval_on_selector_all(f"#legend .lg[data-layer={name}] .mark", "els => els.map(e => +e.dataset.value)")
        assert marks == [pytest.approx(meta[key])], (name, marks)
        assert "hazardous above" in page.text_content(f"#legend .lg[data-layer={name}]")


def test_one_legend_per_visible_layer_masks_as_masks_and_which_end_is_good(mapped: Console, browser: Any) -> None:
    page = mapped.open(browser)
    wait_ready(page, "dem", "hazard")
    assert page.eval_on_selector_all("#legend .lg", "els => els.map(e => e.dataset.layer)") == ["hazard", "dem"]
    page.check("#layers input[data-layer=traversability]")
    page.check("#layers input[data-layer=filled]")
    wait_ready(page, "traversability", "filled")
    assert page.eval_on_selector_all("#legend .lg", "els => els.map(e => e.dataset.layer)") == [
        "filled", "traversability", "hazard", "dem"]
    assert "1 easy, 0 impassable" in page.text_content("#legend .lg[data-layer=traversability]")
    filled = page.eval_on_selector("#legend .lg[data-layer=filled]", "e => [e.querySelectorAll('.swatch').length, !!e.querySelector('.ramp')]")
    assert filled == [2, False]  # 1 and 0 (clear), not a ramp
    # a 0 of the mask is clear: where nothing was filled the DEM under it shows unchanged
    x, y = cell_where(mapped.data, "filled", 0)
    page.evaluate("S.visible.traversability = false; S.visible.hazard = false; draw()")
    with_mask = pixel(page, x, y)
    page.evaluate("S.visible.filled = false; draw()")
    assert pixel(page, x, y) == with_mask


def test_layers_are_fetched_when_shown_not_all_at_load(mapped: Console, browser: Any) -> None:
    page = mapped.open(browser, wait=False)
    fetched: list[str] = []
    page.on("request", lambda req: fetched.append(req.url.split("/layers/")[1].split(".")[0])
            if "/layers/" in req.url else None)
    page.goto(mapped.url)
    wait_ready(page, "dem", "hazard")
    page.wait_for_timeout(300)
    assert sorted(fetched) == ["dem", "hazard"]
    page.check("#layers input[data-layer=slope]")
    wait_ready(page, "slope")
    assert sorted(fetched) == ["dem", "hazard", "slope"]


# ------------------------------------------------------------------------------ buttons


def test_the_buttons_follow_the_mode_and_reset_and_quit_ask_first(console: Any, browser: Any) -> None:
    c = console()
    page = c.open(browser)

    def enabled() -> dict[str, bool]:
        return page.evaluate("Object.fromEntries(['btn-dem', 'btn-break', 'btn-continue', 'btn-reset']"
                             ".map(id => [id, !document.getElementById(id).disabled]))")

    assert enabled() == {"btn-dem": True, "btn-break": False, "btn-continue": False, "btn-reset": True}
    with c.srv.client() as gnc:
        gnc.start_job("sleep -seconds 30")
        page.wait_for_function("S.state.mode === 'sleep'")
        assert enabled() == {"btn-dem": False, "btn-break": True, "btn-continue": False, "btn-reset": False}
        page.click("#btn-break")
        page.wait_for_function("S.state.mode === 'break' && !S.state.job")
    assert enabled() == {"btn-dem": False, "btn-break": False, "btn-continue": True, "btn-reset": True}

    sent = sent_lines(page)
    page.reload()
    page.wait_for_function("S.state && S.state.mode === 'break'")
    asked: list[str] = []

    def answer(dialog: Any, accept: bool) -> None:
        asked.append(dialog.message)
        dialog.accept() if accept else dialog.dismiss()

    page.once("dialog", lambda d: answer(d, False))
    page.click("#btn-reset")
    page.fill("#cmd", "quit")
    page.once("dialog", lambda d: answer(d, False))
    page.press("#cmd", "Enter")
    page.wait_for_timeout(300)
    assert len(asked) == 2 and "Reset" in asked[0] and "Quit" in asked[1]
    assert not any(line.split()[1] in ("reset", "quit") for line in sent), sent
    page.once("dialog", lambda d: answer(d, True))
    page.click("#btn-reset")
    page.wait_for_function("S.state.mode === 'ready'", timeout=60_000)
    assert any(line.split()[1] == "reset" for line in sent)


# ------------------------------------------------------------------------------ what operators expect


def test_events_carry_the_time_and_survive_a_reload(console: Any, browser: Any) -> None:
    c = console()
    page = c.open(browser)
    before = time.time()
    assert c.request("sleep -seconds 0.1").status == "OK"
    page.wait_for_function("[...document.querySelectorAll('#log li')].some(li => li.textContent.includes('slept='))")
    page.reload()
    page.wait_for_selector("#link.up")
    page.wait_for_function("[...document.querySelectorAll('#log li')].some(li => li.textContent.includes('slept='))")
    rows = page.eval_on_selector_all("#log li", "els => els.map(e => [e.querySelector('time').dateTime, e.textContent])")
    done = [(t, text) for t, text in rows if "slept=" in text]
    assert len(done) == 1  # once: the history, not the history and a second copy
    stamp = done[0][0]  # ISO, UTC
    assert abs(calendar.timegm(time.strptime(stamp[:19], "%Y-%m-%dT%H:%M:%S")) - before) < 30, stamp
    assert any("ACK" in text for _, text in rows)


def test_the_hover_readout_gives_every_visible_layer_with_its_unit(mapped: Console, browser: Any) -> None:
    page = mapped.open(browser)
    wait_ready(page, "dem", "hazard")
    page.check("#layers input[data-layer=slope]")
    x, y = defined_cell(mapped.data)
    box = page.eval_on_selector("#map", "c => c.getBoundingClientRect().toJSON()")
    px, py = page.evaluate(f"toScreen({x}, {y})")
    page.mouse.move(box["x"] + px, box["y"] + py)
    page.wait_for_function("document.getElementById('cursor').textContent.includes('dem ')")
    text = page.text_content("#cursor")
    # where the page asked: the browser reports the pointer in whole pixels, which near a cell's
    # edge can be the next cell from the fractional point the test aimed at
    x_at, y_at = page.evaluate("hoverAt")
    values, g = read_geotiff(mapped.data / "dem" / "web_dem.tif")
    row, col = g.cell_of(np.array([x_at]), np.array([y_at]))
    z = float(values[row[0], col[0]])
    assert f"dem {page.evaluate(f'fmt({z})')} m" in text, (text, z)
    assert " m" in text and "slope " in text and " deg" in text, text
    assert "hazard safe" in text or "hazard hazardous" in text, text


def test_the_command_line_keeps_a_history_on_up_and_down(console: Any, browser: Any) -> None:
    c = console()
    page = c.open(browser)
    for line in ("status", "version", "help status"):
        page.fill("#cmd", line)
        page.press("#cmd", "Enter")
    page.reload()  # the history is the browser's: it outlives the page
    page.wait_for_selector("#link.up")
    seen = []
    for key in ("ArrowUp", "ArrowUp", "ArrowUp", "ArrowUp", "ArrowDown", "ArrowDown", "ArrowDown"):
        page.press("#cmd", key)
        seen.append(page.input_value("#cmd"))
    assert seen == ["help status", "version", "status", "status", "version", "help status", ""]


@long_test  # a scan of several views, slowed so that a phase lasts: ~10 s
def test_a_job_shows_its_elapsed_and_remaining_time(console: Any, browser: Any) -> None:
    c = console("drivers.ptu.time_scale=0.5")  # a scan of several views that takes a few seconds
    page = c.open(browser)
    with c.srv.client() as gnc:
        gnc.start_job("dem-full-tof -range -90,90,-50,-35 -cell 0.1 -name slow")
        page.wait_for_function("document.getElementById('times').textContent.includes('left')", timeout=120_000)
        text = page.text_content("#times")
        assert text.startswith("elapsed ") and " s" in text, text
        gnc.until_final(300)


def test_the_current_maps_products_can_be_downloaded(mapped: Console, browser: Any) -> None:
    page = mapped.open(browser)
    page.wait_for_selector("#downloads:not([hidden])")
    names = page.eval_on_selector_all("#products a", "els => els.map(a => a.textContent)")
    assert {"web_dem.tif", "web_dem.png", "web_hazard.tif", "web_mesh.ply"} <= set(names), names
    with page.expect_download() as info:
        page.click("#products a:text-is('web_dem.tif')")
    path = info.value.path()
    assert Path(path).read_bytes() == (mapped.data / "dem" / "web_dem.tif").read_bytes()


def test_the_distance_and_bearing_tool(mapped: Console, browser: Any) -> None:
    page = mapped.open(browser)
    box = page.eval_on_selector("#map", "c => c.getBoundingClientRect().toJSON()")
    page.click("#measure")
    for x, y in ((0.0, 0.0), (-2.0, -3.0)):
        px, py = page.evaluate(f"toScreen({x}, {y})")
        page.mouse.click(box["x"] + px, box["y"] + py)
    text = page.text_content("#measure-out")
    bearing = math.degrees(math.atan2(-3, -2)) % 360
    assert f"distance {math.hypot(2, 3):.2f} m" in text and f"bearing {bearing:.1f}°" in text, text
    assert not page.is_visible("#clickmenu")  # measuring, not navigating
    page.keyboard.press("Escape")
    assert not page.is_visible("#measure-out")


@long_test  # the simulated rover drives on the wall clock: ~40 s
def test_the_rover_icon_moves_and_turns_live_during_a_drive_and_keeps_the_true_heading_after_a_break(
        console: Any, browser: Any) -> None:
    c = console("sim.time_scale=1", "dem_full_tof.range=-60,60,-50,-20", "dem_full_tof.cell=0.04",
                "navigate.range=-110,30,-55,-20", "navigate.overlap=0.05", "navigate.border=0.3")
    page = c.open(browser)
    page.evaluate("""window.seen = []; const onStateWas = onState;
        onState = (st) => { onStateWas(st); if (st.job && st.truth) seen.push([st.pose.x, st.pose.y, st.pose.heading,
            st.truth.heading]); }; 0""")  # (a function as the last value would be called)
    with c.srv.client() as gnc:
        gnc.start_job("navigate -goal 1.5,-1.2 -auto true -loop scan -scan-plan circle")
        page.wait_for_function("seen.length > 1 && Math.hypot(seen.at(-1)[0], seen.at(-1)[1]) > 0.4", timeout=300_000)
        with c.srv.client() as other:
            assert other.request("break").status == "OK"
        gnc.until_final(120)
    page.wait_for_function("S.state.mode === 'break' && !S.state.job")
    seen = page.evaluate("seen")
    positions = {(round(x, 2), round(y, 2)) for x, y, _, _ in seen}
    headings = {round(h) for _, _, h, _ in seen}
    assert len(positions) >= 5 and len(headings) >= 2, seen  # it moved and it turned, live
    st = page.evaluate("[S.state.pose.heading, S.state.truth.heading]")
    assert abs((st[0] - st[1] + 180) % 360 - 180) < 5, st  # the icon's heading is the rover's


def camera_pixels(page: Any, name: str) -> np.ndarray:
    """The RGBA pixels of the image the camera panel shows for ``name``, at its own size (drawn
    on a canvas and read back as a lossless PNG)."""
    url = page.evaluate("""(name) => { const img = document.querySelector(`figure[data-camera="${name}"] img`);
        const c = document.createElement("canvas"); c.width = img.naturalWidth; c.height = img.naturalHeight;
        c.getContext("2d").drawImage(img, 0, 0); return c.toDataURL("image/png"); }""", name)
    png = base64.b64decode(url.split(",", 1)[1])
    return cv2.cvtColor(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED), cv2.COLOR_BGRA2RGBA)


def served(url: str) -> np.ndarray:
    """An image the console serves, as RGBA (or grey) pixels."""
    with urllib.request.urlopen(url, timeout=30) as resp:
        image = cv2.imdecode(np.frombuffer(resp.read(), np.uint8), cv2.IMREAD_UNCHANGED)
    return cv2.cvtColor(image, cv2.COLOR_BGRA2RGBA) if image.ndim == 3 else image


def open_cameras(c: Console, browser: Any) -> tuple[Any, list[str]]:
    """A page and the camera images it fetches from now on."""
    page = c.open(browser)
    asked: list[str] = []
    page.on("request", lambda r: asked.append(r.url) if "/cameras/" in r.url else None)
    return page, asked


def test_the_camera_panel_shows_the_tof_frames_the_server_grabbed_once_opened(console: Any, browser: Any) -> None:
    c = console()
    page, asked = open_cameras(c, browser)
    assert c.request("grab-tof -type amplitude -output amp").status == "OK"
    assert c.request("grab-tof -type z -output depth").status == "OK"
    page.wait_for_function("S.state.cameras.filter(c => c.url).length === 2")
    page.wait_for_timeout(1200)  # a tick of the panel's clock: closed, it fetches nothing
    assert not page.is_visible("#camera-list") and asked == []
    # the simulated rover carries both hazcam pairs (config/drivers.yaml): listed, not yet grabbed
    assert page.evaluate("S.state.cameras.map(c => c.name)") == ["tof_amplitude", "tof_depth", "stereo_left",
                                                                 "hazcam_front_left", "hazcam_rear_left"]
    page.click("#tab-cameras")
    for name in ("tof_amplitude", "tof_depth"):
        page.wait_for_selector(f"figure[data-camera={name}] img[data-v]")
    assert "no frame yet: grab-stereo" in page.text_content("figure[data-camera=stereo_left] figcaption")
    assert "no frame yet" in page.text_content("figure[data-camera=hazcam_front_left] figcaption")

    # the depth image on the page is the one served, and it is the grabbed frame: its pixels
    # without a measurement are the transparent ones, the rest a ramp of the depth
    depth = camera_pixels(page, "tof_depth")
    v = page.get_attribute("figure[data-camera=tof_depth] img", "data-v")
    np.testing.assert_array_equal(depth, served(f"{c.url}cameras/tof_depth.png?v={v}"))
    z = tifffile.imread(c.data / "tof" / "depth_z.tif")
    measured = np.isfinite(z) & (z > 0)
    assert depth.shape[:2] == z.shape and measured.mean() > 0.5
    np.testing.assert_array_equal(depth[..., 3] == 255, measured)
    assert depth[measured][:, :3].std(axis=0).max() > 20  # not blank: a ramp of many colours
    # nearer is bluer, farther redder (turbo): the nearest tenth against the farthest tenth
    near, far = z[measured] < np.percentile(z[measured], 10), z[measured] > np.percentile(z[measured], 90)
    rgb = depth[measured][:, :3].astype(float)
    assert rgb[near, 2].mean() > rgb[near, 0].mean() and rgb[far, 0].mean() > rgb[far, 2].mean()
    caption = page.text_content("figure[data-camera=tof_depth] figcaption")
    assert caption.startswith("ToF depth ") and f" m (z), {z.shape[1]}x{z.shape[0]}, " in caption, caption
    amplitude = camera_pixels(page, "tof_amplitude")
    assert amplitude[..., :3].std() > 10, amplitude[..., :3].std()
    assert len(asked) == 2, asked
    assert not page.errors, page.errors


@long_test  # a stereo grab, a hazcam pair matched and the panel's clock watched: ~8 s
def test_the_camera_panel_shows_stereo_and_hazcam_frames_and_fetches_only_new_ones_while_open(
        console: Any, browser: Any) -> None:
    c = console("drivers.hazcam.cameras=front")
    page, asked = open_cameras(c, browser)
    assert page.evaluate("S.state.cameras.map(c => c.name)") == ["tof_amplitude", "tof_depth", "stereo_left",
                                                                 "hazcam_front_left"]
    page.click("#tab-cameras")
    assert "no frame yet" in page.text_content("figure[data-camera=hazcam_front_left] figcaption")
    assert c.request("grab-stereo -resolution low -output pair").status == "OK"
    page.wait_for_selector("figure[data-camera=stereo_left] img[data-v]")
    left = camera_pixels(page, "stereo_left")
    assert left.shape[:2] == (480, 640) and left[..., :3].std() > 10
    hazcam = c.srv.app.devices.get("hazcam")
    frame = tapped_call(c.srv.app.bus, hazcam.grab, "front")
    page.wait_for_selector("figure[data-camera=hazcam_front_left] img[data-v]")
    shown = camera_pixels(page, "hazcam_front_left")[..., 0].astype(float)
    assert shown.shape == frame.left.shape and np.abs(shown - frame.left).mean() < 3.0  # the JPEG of that frame
    assert len(asked) == 2, asked
    page.wait_for_timeout(1500)  # no new frame, no new fetch
    assert len(asked) == 2, asked
    # a new frame replaces the shown one
    assert c.request("grab-tof -type amplitude").status == "OK"
    page.wait_for_selector("figure[data-camera=tof_amplitude] img[data-v]")
    assert len(asked) == 3, asked
    # closed again: new frames are not fetched
    page.click("#tab-layers")
    assert c.request("grab-tof -type z").status == "OK"
    page.wait_for_timeout(1500)
    assert len(asked) == 3, asked
    assert not page.errors, page.errors
