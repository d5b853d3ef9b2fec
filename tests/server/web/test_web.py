"""The operator web console through real sockets: HTTP routes, the WebSocket's lines and state,
layer images, the token, hostile paths and a clean close at quit."""

from __future__ import annotations

import asyncio
import json
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import aiohttp
import cv2
import numpy as np
import pytest
import yaml

from prox_workflows.grid import read_geotiff
from rvs_server.web.address import console_host
from rvs_server.web.console import HISTORY

DEM = "dem-full-tof -range -20,20,-50,-35 -cell 0.05 -name web"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def web(server_factory: Any) -> Any:
    """A test server with its console on a free port; yields (server, base URL)."""

    def make(*overrides: str) -> tuple[Any, str]:
        port = free_port()
        srv = server_factory([f"server.web_port={port}", *overrides])
        return srv, f"http://127.0.0.1:{port}"

    return make


class Page:
    """What the console page does, in Python: one WebSocket, lines out, messages in."""

    def __init__(self, ws: aiohttp.ClientWebSocketResponse) -> None:
        self.ws = ws
        self.states: list[dict[str, Any]] = []
        self.replies: list[dict[str, Any]] = []
        self.history: list[dict[str, Any]] = []  # the lines the page was shown when it opened

    async def next(self, timeout: float = 60.0) -> dict[str, Any]:
        """The next state or reply (the history comes first, once: kept in ``history``)."""
        while True:
            msg = await asyncio.wait_for(self.ws.receive(), timeout)
            assert msg.type == aiohttp.WSMsgType.TEXT, msg
            data = json.loads(msg.data)
            if data["type"] == "history":
                self.history = data["lines"]
                continue
            (self.states if data["type"] == "state" else self.replies).append(data)
            return data

    async def send(self, line: str) -> None:
        await self.ws.send_str(json.dumps({"line": line}))

    async def until(self, pred: Any, timeout: float = 120.0) -> dict[str, Any]:
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout
        while True:
            msg = await self.next(max(0.1, end - loop.time()))
            if pred(msg):
                return msg

    async def final(self, tag: str, timeout: float = 120.0) -> dict[str, Any]:
        msg = await self.until(lambda m: m["type"] == "reply" and m["reply"].get("tag") == tag
                               and m["reply"]["status"] in ("OK", "ERROR"), timeout)
        return msg["reply"]


def run_page(base: str, body: Any, *, origin: str | None = None) -> Any:
    async def go() -> Any:
        async with aiohttp.ClientSession() as http:
            headers = {"Origin": origin} if origin else {}
            async with http.ws_connect(base.replace("http", "ws") + "/ws", headers=headers) as ws:
                return await body(Page(ws), http)

    return asyncio.run(go())


def test_page_gets_hello_and_state_then_runs_lines_through_the_dispatcher(web: Any) -> None:
    srv, base = web()

    async def body(page: Page, http: aiohttp.ClientSession) -> None:
        hello = await page.next()
        assert hello["reply"]["kind"] == "hello" and hello["text"].startswith("RVS EVENT kind=hello")
        state = await page.next()
        assert state["type"] == "state" and state["mode"] == "ready" and state["scene"] == "office"
        assert state["devices"] == {"ptu": "ok", "tof": "ok", "trigger": "ok", "stereo": "ok", "rover": "ok", "hazcam": "ok"}
        assert state["rover"] == {"length": 0.51, "width": 0.4} and state["maps"] == {}
        await page.send("@s1 status")
        ok = await page.final("s1")
        assert ok["status"] == "OK" and ok["mode"] == "ready" and ok["pose"] == [0.0, 0.0, 0.0]
        await page.send("@s2 navigte -goal 1,1")
        err = await page.final("s2")
        assert err["code"] == "E_UNKNOWN" and "did you mean navigate" in err["message"]
        await page.send("@s3 status " + "x" * 5000)
        err = await page.until(lambda m: m["type"] == "reply" and m["reply"]["status"] == "ERROR")
        assert err["reply"]["code"] == "E_TOOLONG"
        await page.ws.send_str("not json")
        err = await page.until(lambda m: m["type"] == "reply" and m["reply"]["status"] == "ERROR")
        assert err["reply"]["code"] == "E_SYNTAX" and '{"line"' in err["reply"]["message"]
        async with http.get(base + "/api/state") as resp:
            assert resp.status == 200 and (await resp.json())["mode"] == "ready"

    run_page(base, body)
    with srv.client() as c:  # the TCP side still serves, and counts no page left behind
        assert c.request("status").fields["clients"] == "1"


def test_a_pages_requests_and_replies_reach_the_bus_as_a_tcp_clients_do(web: Any) -> None:
    """Foxglove and recordings watch the bus: a page's lines must be there, once each, its job
    lines marked as such; a line of a job another client started is that client's, not the page's."""
    srv, base = web()
    items: list[Any] = []
    srv.app.bus.subscribe(items.append)

    async def body(page: Page, http: aiohttp.ClientSession) -> None:
        await page.next()
        await page.send("@v1 version")
        await page.final("v1")
        await page.send("@z1 sleep -seconds 0.05")
        await page.final("z1")

    run_page(base, body)
    with srv.client() as c:
        assert c.request("sleep -seconds 0.05").status == "OK"
    replies = [i for i in items if i.kind == "reply"]
    page = {i.data["conn"] for i in replies if i.data["reply"].module == "EGP-RVS-VERSION"}
    assert len(page) == 1
    mine = [(i.data["reply"].module, i.data["reply"].status, i.data["job"]) for i in replies if i.data["conn"] in page]
    assert mine == [("EGP-RVS-VERSION", "OK", False), ("EGP-RVS-SLEEP", "ACK", True),
                    ("EGP-RVS-SLEEP", "OK", True)], mine
    tcp = [(i.data["reply"].status, i.data["job"]) for i in replies if i.data["conn"] not in page]
    assert tcp == [("ACK", True), ("OK", True)], tcp
    requests = [i.data["line"] for i in items if i.kind == "request"]
    assert any(b"@v1 version" in line for line in requests), requests
    assert sum(1 for i in srv.app.console.history if '"EGP-RVS-SLEEP"' in i) == 4  # ACK, OK of both


def test_a_job_from_tcp_shows_on_the_page_with_progress_and_its_layers(web: Any, tmp_path: Path) -> None:
    srv, base = web()

    async def body(page: Page, http: aiohttp.ClientSession) -> None:
        await page.next()
        await page.next()

        def tcp_dem() -> Any:
            with srv.client() as c:
                return c.request(DEM, timeout=300)

        dem = asyncio.get_running_loop().run_in_executor(None, tcp_dem)
        ack = await page.until(lambda m: m["type"] == "reply" and m["reply"]["status"] == "ACK")
        assert ack["own"] is False and ack["reply"]["module"] == "EGP-RVS-DEM-FULL-TOF"
        busy = await page.until(lambda m: m["type"] == "state" and m["job"] is not None)
        assert busy["mode"] == "busy" and busy["job"]["command"] == "dem-full-tof"
        progress = await page.until(lambda m: m["type"] == "reply" and m["reply"]["status"] == "PROGRESS")
        # the wait for the busy state above skips what came before it: on a loaded machine
        # the DEM may be past its acquisition by then, so any of its phases
        assert progress["reply"]["phase"] in ("pointing", "acquire", "process", "write")
        ok = await page.until(lambda m: m["type"] == "reply" and m["reply"]["status"] in ("OK", "ERROR"), 300)
        assert ok["reply"]["status"] == "OK", ok["text"]
        assert (await dem).status == "OK"
        state = await page.until(lambda m: m["type"] == "state" and m["maps"])
        maps = state["maps"]
        assert {"dem", "ortho", "hazard", "traversability", "slope"} <= maps.keys()
        values, geometry = read_geotiff(srv.data / ok["reply"]["dem"])
        assert maps["dem"]["bounds"] == pytest.approx(list(geometry.bounds))
        async with http.get(base + maps["dem"]["url"]) as resp:
            assert resp.status == 200 and resp.content_type == "image/png"
            legend = json.loads(resp.headers["X-Legend"])
            png = await resp.read()
        rgba = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
        assert rgba.shape == (geometry.height, geometry.width, 4)
        undefined = ~np.isfinite(values)
        assert undefined.any() and (rgba[..., 3][undefined] == 0).all()  # unseen: transparent, not black
        assert (rgba[..., 3][~undefined] == 255).all()
        assert legend["kind"] == "ramp" and legend["lo"] < legend["hi"] and legend["unit"].startswith("m")
        async with http.get(base + maps["dem"]["url"]) as resp:
            assert await resp.read() == png
        assert srv.app.console.layers.renders["dem"] == 1  # rendered once: later loads are cache hits
        async with http.get(base + maps["traversability"]["url"]) as resp:
            trav = cv2.imdecode(np.frombuffer(await resp.read(), np.uint8), cv2.IMREAD_UNCHANGED)
        score, _ = read_geotiff(srv.data / ok["reply"]["traversability"])
        good, bad = np.isfinite(score) & (score > 0.9), np.isfinite(score) & (score < 0.1)
        assert good.any() and bad.any()
        # BGRA: good ground green (G > R), blocked ground red (R > G)
        assert (trav[..., 1][good] > trav[..., 2][good]).all() and (trav[..., 2][bad] > trav[..., 1][bad]).all()

    run_page(base, body)


def test_the_token_makes_the_page_read_only_until_auth(web: Any) -> None:
    srv, base = web("server.token=s3cret")

    async def body(page: Page, http: aiohttp.ClientSession) -> None:
        await page.next()
        state = await page.next()
        assert state["token"] is True and state["mode"] == "ready"  # the page can watch
        await page.send("@n1 navigate -goal 1,0 -auto true")
        err = await page.final("n1")
        assert err["code"] == "E_AUTH"
        await page.send("@a1 auth -token wrong")
        assert (await page.final("a1"))["code"] == "E_AUTH"
        await page.send("@a2 auth -token s3cret")
        assert (await page.final("a2"))["status"] == "OK"
        await page.send("@p1 pose -x 0.5 -y 0 -heading 0")
        assert (await page.final("p1"))["status"] == "OK"

    run_page(base, body)
    assert srv.app.pose.x == 0.5


def test_no_request_reaches_outside_the_data_directory(web: Any, tmp_path: Path) -> None:
    srv, base = web()
    secret = srv.data.parent / "secret.tif"
    secret.write_bytes(b"not for you")

    async def probe() -> list[int]:
        codes = []
        async with aiohttp.ClientSession() as http:
            for path in ("/static/../../secret.tif", "/static/%2e%2e%2fsecret.tif", "/static/console.py",
                         "/layers/..%2F..%2Fsecret.png", "/layers/%2e%2e.png", "/layers/dem.png",
                         "/layers/../secret.tif", "/../secret.tif", "/static/", "/layers/.png",
                         "/cameras/..%2F..%2Fsecret.tif", "/cameras/tof_depth.png", "/cameras/"):
                async with http.get(base + path) as resp:
                    body = await resp.read()
                    assert b"not for you" not in body
                    codes.append(resp.status)
            async with http.get(base + "/static/console.js") as resp:
                assert resp.status == 200 and b"WebSocket" in await resp.read()
        return codes

    codes = asyncio.run(probe())
    assert all(code in (403, 404) for code in codes), codes


def test_a_page_from_another_site_cannot_open_the_websocket(web: Any) -> None:
    _, base = web()

    async def body(page: Page, http: aiohttp.ClientSession) -> None:
        raise AssertionError("connected")

    with pytest.raises(aiohttp.WSServerHandshakeError) as err:
        run_page(base, body, origin="http://evil.example")
    assert err.value.status == 403


def test_the_websocket_closes_cleanly_when_the_server_quits(web: Any) -> None:
    srv, base = web()

    async def body(page: Page, http: aiohttp.ClientSession) -> Any:
        await page.next()
        await page.send("@q quit")
        while True:
            msg = await asyncio.wait_for(page.ws.receive(), 30)
            if msg.type == aiohttp.WSMsgType.CLOSE:
                return msg.data  # the code in the server's close frame
            assert msg.type == aiohttp.WSMsgType.TEXT, msg  # no close frame at all would be CLOSED/ERROR

    assert run_page(base, body) == 1001  # going away
    srv.thread.join(30)
    assert srv.exit_code == 0


def test_the_console_binds_to_loopback_without_a_token() -> None:
    assert console_host("0.0.0.0", "", False) == "127.0.0.1"
    assert console_host("0.0.0.0", "tok", False) == "0.0.0.0"
    assert console_host("0.0.0.0", "", True) == "0.0.0.0"
    assert console_host("127.0.0.1", "", False) == "127.0.0.1"
    assert console_host("::1", "", False) == "::1"


def test_a_page_opens_with_the_recent_events_and_job_lines_each_with_the_servers_time(web: Any) -> None:
    srv, base = web()
    before = time.time()
    with srv.client() as c:
        assert c.request("sleep -seconds 0.05").status == "OK"
        assert c.request("status").status == "OK"  # an immediate reply of another client: not shown

    async def body(page: Page, http: aiohttp.ClientSession) -> None:
        hello = await page.next()
        assert hello["reply"]["kind"] == "hello" and before <= hello["t"] <= time.time()
        lines = page.history
        assert [m["reply"]["status"] for m in lines if m["reply"]["module"] == "EGP-RVS-SLEEP"] == ["ACK", "OK"]
        assert not any(m["reply"]["module"] == "EGP-RVS-STATUS" for m in lines)
        assert all(before - 1 <= m["t"] <= time.time() and m["own"] is False for m in lines)

    run_page(base, body)
    assert len(srv.app.console.history) <= HISTORY


def test_the_hover_values_and_the_downloads_of_the_current_map(web: Any) -> None:
    srv, base = web()
    with srv.client() as c:
        ok = c.request(DEM, timeout=300)
    assert ok.status == "OK"
    dem, g = read_geotiff(srv.data / ok.fields["dem"])
    hazard, _ = read_geotiff(srv.data / ok.fields["hazard"])
    rows, cols = np.nonzero(np.isfinite(dem))
    r, col = int(rows[len(rows) // 2]), int(cols[len(cols) // 2])
    xs, ys = g.centers()

    async def probe() -> None:
        async with aiohttp.ClientSession() as http:
            url = f"{base}/api/at?x={xs[col]}&y={ys[r]}&layers=dem,hazard,slope,nosuch"
            async with http.get(url) as resp:
                values = (await resp.json())["values"]
            assert values["dem"] == {"value": pytest.approx(float(dem[r, col]), abs=1e-6), "unit": "m"}
            assert values["slope"]["unit"] == "deg" and "nosuch" not in values
            assert values["hazard"]["class"] == {0: "safe", 255: "hazardous"}[int(hazard[r, col])]
            async with http.get(f"{base}/api/at?x={g.xmax + 5}&y=0&layers=dem") as resp:
                assert (await resp.json())["values"]["dem"]["value"] is None  # off the map
            async with http.get(f"{base}/api/at?x=one&y=0") as resp:
                assert resp.status == 400 and "x and y" in await resp.text()
            async with http.get(base + "/api/state") as resp:
                state = await resp.json()
            names = [p["name"] for p in state["products"]]
            assert {"web_dem.tif", "web_dem.png", "web_dem.yaml", "web_mesh.ply", "web_hazard.tif"} <= set(names)
            assert state["maps"]["slope"]["unit"] == "deg"
            async with http.get(base + "/products/web_mesh.ply") as resp:
                assert resp.status == 200 and await resp.read() == (srv.data / "dem" / "web_mesh.ply").read_bytes()
                assert "attachment" in resp.headers["Content-Disposition"]
            for bad in ("rvs.log", "..%2Frvs.log", "..%2F..%2Fsecret.tif", "web_dem"):
                async with http.get(base + "/products/" + bad) as resp:
                    assert resp.status == 404, bad

    asyncio.run(probe())


def test_layer_images_mark_thresholds_and_draw_masks_and_counts_with_nothing_clear(web: Any) -> None:
    srv, base = web()
    with srv.client() as c:
        ok = c.request(DEM, timeout=300)
    meta = yaml.safe_load((srv.data / ok.fields["dem"]).with_suffix(".yaml").read_text())["meta"]["dem2hazard"]

    async def get(http: aiohttp.ClientSession, name: str) -> tuple[np.ndarray, dict[str, Any]]:
        async with http.get(f"{base}/layers/{name}.png") as resp:
            legend = json.loads(resp.headers["X-Legend"])
            return cv2.imdecode(np.frombuffer(await resp.read(), np.uint8), cv2.IMREAD_UNCHANGED), legend

    async def probe() -> None:
        async with aiohttp.ClientSession() as http:
            for name, key in (("slope", "slope_max"), ("step", "step_max"), ("roughness", "roughness_max")):
                _, legend = await get(http, name)
                assert legend["marks"] == [[pytest.approx(meta[key]), "max"]], name
                assert legend["hi"] == pytest.approx(2 * meta[key])
            for name in ("filled", "count"):
                rgba, legend = await get(http, name)
                values, _ = read_geotiff(srv.data / "dem" / f"web_{name}.tif")
                assert (rgba[..., 3][values == 0] == 0).all() and (rgba[..., 3][values > 0] > 0).all(), name
            _, legend = await get(http, "filled")
            assert legend["kind"] == "classes" and [label for _, label in legend["entries"]] == ["1", "0"]
            _, legend = await get(http, "traversability")
            assert legend["meaning"].startswith("1 easy, 0 impassable")

    asyncio.run(probe())


def test_rvs_server_help_names_the_console_and_its_port() -> None:
    out = subprocess.run([sys.executable, "-m", "rvs_server", "--help"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0
    assert "--web-port N" in out.stdout and "console" in out.stdout and "7071" in out.stdout


def test_the_state_names_the_open_commands_and_keeps_any_clients_check_move_and_no_event_is_a_pages_own(
        web: Any) -> None:
    srv, base = web("server.token=s3cret")
    with srv.client() as gnc:  # no page open: the console keeps the check-move all the same
        assert gnc.request("status").fields["code"] == "E_AUTH"
        assert gnc.request("auth -token s3cret").status == "OK"
        assert gnc.request(DEM).status == "OK"
        assert gnc.request("pose -x 0.2 -y 0.1 -heading 0").status == "OK"
        check = gnc.request("@c1 check-move -to 0.9,-0.3")
        assert check.status == "OK"

    async def body(page: Page, http: aiohttp.ClientSession) -> None:
        async with http.get(base + "/api/state") as resp:
            state = await resp.json()
        assert sorted(state["open_commands"]) == ["auth", "exit", "help", "version"]
        assert state["check"]["from"] == [0.2, 0.1] and state["check"]["to"] == [0.9, -0.3]
        assert state["check"]["verdict"] == check.fields["verdict"]
        await page.next()  # the greeting
        await page.send("@h1 help")
        assert (await page.final("h1"))["status"] == "OK"
        assert [m["own"] for m in page.replies if m["reply"].get("tag") == "h1"] == [True]
        with srv.client() as gnc:  # a mode EVENT is every page's, none's answer
            gnc.request("auth -token s3cret")
            gnc.start_job("sleep -seconds 0.1")
            event = await page.until(lambda m: m["type"] == "reply" and m["reply"]["status"] == "EVENT"
                                     and m["reply"].get("kind") == "mode")
            gnc.until_final(60)
        assert event["own"] is False
        assert all(not m["own"] for m in page.replies if m["reply"]["status"] == "EVENT")

    run_page(base, body)
