"""The operator web console: an HTTP page and a WebSocket on the server's own event loop.

Seed 000 sect. 4.4.4 asks for "a simple GUI, showing the global map and allowing the user to
click the destination point". The page is a client like telnet: every button and click becomes
a command line that goes through the same dispatcher (so the same checks, modes, token and
errors apply), and it sees the same EVENT lines, plus the lines of every job (so an operator
watches a job the GNC started). What a map view needs beyond the lines (pose, PTU, layers and
their versions) comes as a state snapshot, computed once per tick for all pages and sent only
when it changed. Every line carries the server's time; the events and job lines of the last
minutes are kept in a bounded ring that a page gets when it opens, so a reload keeps its history.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import socket
import time
from collections import deque
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import structlog
from aiohttp import WSMsgType, web

from drivers.tof.constants import FOV_H_DEG as TOF_HFOV_DEG
from prox_workflows.grid import read_geotiff_geometry

from ..protocol import Reply, TooLong, format_reply, format_reply_json
from ..table import COMMANDS
from .cameras import CameraFrames
from .tiles import LayerCache, ValueCache, unit_of, version_of

if TYPE_CHECKING:
    from ..app import App
    from ..bus import Item

log = structlog.get_logger("rvs.web")

TICK = 0.2  # seconds between state snapshots (pose, PTU, progress): 5 Hz is smooth enough to watch
MAX_QUEUED = 2000  # messages a page may lag behind before it is dropped (it reloads and catches up)
SNAPSHOT_TRACK = 1000  # of which each state snapshot carries the newest (5 per second to every page)
HISTORY = 500  # event and job lines a page is shown when it opens (a reload keeps its history)
PRODUCTS_EVERY = 2.0  # seconds between two listings of the current map's products
DOWNLOADS = (".tif", ".png", ".ply", ".csv", ".yaml")  # what a page may download of the current map
STATIC = {"index.html": "text/html", "console.js": "text/javascript", "console.css": "text/css"}
SHOWN_FIRST = ("dem", "hazard")  # the layers a new page shows (console.js S.visible)
# bottom to top: the orbital map under the rover's own (where the rover has seen, it knows better)
LAYER_ORDER = ("global_hazard", "ortho", "dem", "hazard", "traversability", "slope", "step", "roughness",
               "variance", "count", "filled")


_last: list[tuple[Reply, bool, str]] = []  # the last reply encoded: a mirrored job line goes to every page


def _encode(reply: Reply, own: bool) -> str:
    """The page's message for a reply line, encoded once however many pages get it."""
    if _last and _last[0][0] is reply and _last[0][1] == own:
        return _last[0][2]
    obj = json.loads(format_reply_json(reply))
    message = json.dumps({"type": "reply", "own": own, "t": round(time.time(), 3), "reply": obj,
                          "text": format_reply(reply)}, separators=(",", ":"))
    _last[:] = [(reply, own, message)]
    return message


class WebPeer:
    """One open page, as the dispatcher sees a connection: it sends lines and receives replies.

    Replies are queued and written by one task, in order; a page that stops reading is dropped
    rather than letting its queue grow, as a TCP client that reads nothing is.
    """

    observes_jobs = True  # also gets the lines of jobs other connections started

    def __init__(self, app: App, ws: web.WebSocketResponse, peer: str, conn_id: int) -> None:
        self.app = app
        self.ws = ws
        self.id = conn_id
        self.peer = peer
        self.address = peer  # wrong tokens are counted by it, as a TCP client's
        self.log = log.bind(conn=conn_id, peer=peer, web=True)
        self.events = True
        self.json = True
        self.authenticated = False
        self.jobs_running = 0
        self.jobs_started = 0
        self.exiting = False
        self.closed = False
        self.close_code = 1000
        self.queue: asyncio.Queue[str | None] = asyncio.Queue()
        self.writing: asyncio.Task[None] | None = None  # the task that writes the queue out

    def send(self, reply: Reply, *, own: bool = True, job: bool = False) -> None:
        """Queue a reply line for the page (event loop only); ``own``: an answer to this page's
        request, ``job``: a line of a job (see Connection.send)."""
        if own:  # also once the page is gone (another line's: its own connection publishes it)
            self.app.sent(self, reply, job=job)
        if self.closed:
            return
        if self.queue.qsize() > MAX_QUEUED:
            self.log.warning("client_dropped", reason="page not reading its messages")
            self.close()
            return
        if reply.status == "EVENT":  # every page's (App.broadcast publishes it): no page's answer
            own = False
        self.queue.put_nowait(_encode(reply, own))

    def observe(self, reply: Reply) -> None:
        """A line of a job another connection started."""
        self.send(reply, own=False)

    def send_raw(self, message: str) -> None:
        if not self.closed:
            self.queue.put_nowait(message)

    def greet(self) -> None:
        self.send(self.app.hello())

    def close_if_done(self) -> None:
        """A page closes when its socket does; nothing waits for its jobs' final lines."""

    def close(self, code: int = 1000) -> None:
        """Close the page's socket after what is queued for it (its writer sends the close
        frame: 1001 'going away' when the server stops)."""
        if not self.closed:
            self.closed = True
            self.close_code = code
            self.queue.put_nowait(None)
        self.app.connections.discard(self)  # type: ignore[arg-type]

    async def writer(self) -> None:
        while True:
            message = await self.queue.get()
            if message is None or self.ws.closed:
                break
            try:
                await self.ws.send_str(message)
            except (ConnectionError, RuntimeError):
                break
        self.closed = True
        with contextlib.suppress(ConnectionError, RuntimeError):
            await self.ws.close(code=self.close_code, message=b"server stopping" if self.close_code == 1001 else b"")


class WebConsole:
    """The console's HTTP routes, its open pages and what they are shown."""

    def __init__(self, app: App) -> None:
        self.app = app
        self.pages: set[WebPeer] = set()
        self.layers = LayerCache()
        self.values = ValueCache()
        self.cameras = CameraFrames()
        self.history: deque[str] = deque(maxlen=HISTORY)
        self._products: tuple[float, dict[str, Path]] = (0.0, {})
        self.snapshot = ""  # the last state message sent to the pages
        self.bounds: dict[tuple[str, str], list[float]] = {}  # (path, version) -> layer bounds
        self.runner: web.AppRunner | None = None
        self.port = 0
        self.url = ""  # where the page is, once started (status shows it)
        self._ticker: asyncio.Task[None] | None = None
        self._to_render: list[tuple[str, Path]] = []  # new layer versions, rendered before a page asks
        self._renderer: asyncio.Task[None] | None = None
        self._static = {name: resources.files(__package__).joinpath("static", name).read_bytes() for name in STATIC}
        self.web = web.Application()
        self.web.add_routes([
            web.get("/", self.index),
            web.get("/static/{name}", self.static),
            web.get("/layers/{name}.png", self.layer),
            web.get("/api/state", self.state_json),
            web.get("/api/at", self.values_at),
            web.get("/products/{name}", self.product),
            web.get("/cameras/{file}", self.camera),
            web.get("/ws", self.websocket),
            web.get("/favicon.ico", self.favicon),
        ])

    # ------------------------------------------------------------ lifecycle

    async def start(self, sock: socket.socket) -> None:
        self.runner = web.AppRunner(self.web, access_log=None, handle_signals=False)
        await self.runner.setup()
        site = web.SockSite(self.runner, sock)
        await site.start()
        host, self.port = sock.getsockname()[:2]
        self.url = f"http://{f'[{host}]' if ':' in host else host}:{self.port}/"
        self._ticker = asyncio.create_task(self._tick())
        self.app.bus.subscribe(self.remember)
        self.app.bus.subscribe(self.cameras.accept)
        log.info("web_console", url=self.url)

    async def close(self) -> None:
        """Close every page's WebSocket with 'going away' (1001), then the HTTP server."""
        self.app.bus.unsubscribe(self.remember)
        self.app.bus.unsubscribe(self.cameras.accept)
        for task in (self._ticker, self._renderer):
            if task is not None:
                task.cancel()
        writers = []
        for page in list(self.pages):
            page.close(1001)
            if page.writing is not None:
                writers.append(page.writing)
        if writers:
            await asyncio.wait(writers, timeout=5.0)
        if self.runner is not None:
            await self.runner.cleanup()

    # ------------------------------------------------------------ state

    def remember(self, item: Item) -> None:
        """Keep each event and job line the server sends (the bus, on the event loop) for the
        pages that open later; PROGRESS is left out, the state carries the running job's progress."""
        reply = item.data.get("reply")
        if reply is None or reply.status == "PROGRESS":
            return
        if item.kind == "event" or item.data.get("job"):
            self.history.append(_encode(reply, False))

    def history_message(self) -> str:
        return '{"type":"history","lines":[' + ",".join(self.history) + "]}"

    def dem_path(self) -> Path | None:
        rel = self.app.maps.files().get("dem")
        return None if rel is None else (self.app.data_dir / rel)

    def products(self) -> dict[str, Path]:
        """The current map's files by name (GeoTIFFs, their PNGs and sidecars, the mesh, CSV
        tables): what is beside the DEM under its prefix. Listed at most every PRODUCTS_EVERY
        seconds; only these names can be downloaded, so no request names a file."""
        at, listed = self._products
        if time.monotonic() - at < PRODUCTS_EVERY:
            return listed
        out: dict[str, Path] = {}
        dem = self.dem_path()
        if dem is not None and dem.is_file():
            prefix = dem.name[: -len("_dem.tif")] if dem.name.endswith("_dem.tif") else dem.stem
            for path in sorted(dem.parent.iterdir()):
                if path.name.startswith(prefix + "_") or path.stem == prefix:
                    if path.suffix in DOWNLOADS and path.is_file():
                        out[path.name] = path
        self._products = (time.monotonic(), out)
        return out

    def layer_paths(self) -> dict[str, Path]:
        """The current map products by layer: only names the server itself recorded, so no
        request can name a file (no path from a request reaches the file system)."""
        out: dict[str, Path] = {}
        root = self.app.data_dir.resolve()
        for name, rel in self.app.maps.files().items():
            path = (root / rel).resolve()
            if path.suffix == ".tif" and path.is_relative_to(root) and path.is_file():
                out[name] = path
        glob_dir = self.app.config.get("navigate").global_maps
        if glob_dir and (Path(glob_dir) / "hazard.tif").is_file():
            out["global_hazard"] = Path(glob_dir) / "hazard.tif"
        return out

    def state(self) -> dict[str, Any]:
        app = self.app
        job = app.jobs.current
        pose = app.pose
        out: dict[str, Any] = {
            "type": "state",
            "server": app.name,
            "mode": app.mode,
            # the phase as its PROGRESS lines name it (a navigate's with its leg): a page that
            # opens mid-job draws the bar of the whole job from it
            "job": None if job is None else {"id": job.id, "command": job.command, "phase": job.phase, **job.context,
                                             "done": job.done, "total": job.total, "tag": job.tag,
                                             # on the server's clock (the page corrects for its own)
                                             "started": round(time.time() - (time.monotonic() - job.started), 1)},
            "pose": {"x": pose.x, "y": pose.y, "heading": pose.heading, "stopped": pose.stopped},
            "ptu": app.ptu_position(),
            "devices": app.devices.summary(),
            "token": bool(app.server_cfg.token),
            # what a page without the token may send: the command table's answer, not the page's
            "open_commands": [name for name, cmd in COMMANDS.items() if cmd.open],
        }
        if app.world is not None:
            t = app.world.truth()
            out["truth"] = {"x": float(t["x"]), "y": float(t["y"]), "heading": float(t["heading"])}
            out["ptu"] = out["ptu"] or (float(t["pan"]), float(t["tilt"]))
            out["scene"] = app.world.scene_name
        head = app.config.get("head")
        out["rover"] = {"length": head.rover_length, "width": head.rover_width}
        goal = app.travel.goal
        out["goal"] = None if goal is None else {"x": goal.x, "y": goal.y, "tolerance": goal.tolerance, "job": goal.job}
        out["tof_hfov"] = TOF_HFOV_DEG  # drawn as the ToF's wedge
        maps: dict[str, Any] = {}
        for name, path in self.layer_paths().items():
            try:
                version = version_of(path)
            except OSError:
                continue
            key = (str(path), version)
            if key not in self.bounds:
                self.bounds[key] = list(read_geotiff_geometry(path).bounds)
                self._to_render.append((name, path))  # the page asks for it in a moment
            maps[name] = {"url": f"/layers/{name}.png?v={version}", "bounds": self.bounds[key], "version": version,
                          "unit": unit_of(name)}
        out["maps"] = {k: maps[k] for k in sorted(maps, key=lambda n: (LAYER_ORDER + (n,)).index(n))}
        out["products"] = [{"name": n, "url": f"/products/{n}"} for n in self.products()]
        hazcam = app.devices.devices.get("hazcam")
        out["cameras"] = self.cameras.listing(hazcam.cameras() if hazcam is not None else [])
        check = app.travel.check
        out["check"] = None if check is None else {
            "from": [round(check.start[0], 3), round(check.start[1], 3)], "to": list(check.to),
            "verdict": str(check.fields["verdict"])}
        monitors = json.loads(format_reply_json(Reply("RVS", "OK", app.monitors.status_fields())))
        out["monitors"] = {k: v for k, v in monitors.items() if k not in ("module", "status")}
        out["track"] = [(round(x, 3), round(y, 3)) for x, y, _ in app.travel.track()[-SNAPSHOT_TRACK:]]
        return out

    async def _prerender(self) -> None:
        """Render new layer versions one at a time, those a page shows at first first: in
        parallel they would compete with each other, the running job and the page's request."""
        loop = asyncio.get_running_loop()
        while self._to_render:
            self._to_render.sort(key=lambda item: item[0] not in SHOWN_FIRST)
            name, path = self._to_render.pop(0)
            try:
                await loop.run_in_executor(None, self.layers.get, name, path, self.dem_path())
            except (OSError, ValueError) as exc:
                log.warning("layer_render_failed", layer=name, error=str(exc))

    async def _tick(self) -> None:
        while True:
            try:
                if self.pages:
                    message = json.dumps(self.state(), separators=(",", ":"))
                    if self._to_render and (self._renderer is None or self._renderer.done()):
                        self._renderer = asyncio.create_task(self._prerender())
                    if message != self.snapshot:
                        self.snapshot = message
                        for page in list(self.pages):
                            page.send_raw(message)
            except Exception:  # noqa: BLE001 - a snapshot bug must not stop the console
                log.exception("web_state_failed")
            await asyncio.sleep(TICK)

    # ------------------------------------------------------------ routes

    async def index(self, request: web.Request) -> web.Response:
        return web.Response(body=self._static["index.html"], content_type="text/html",
                            headers={"Cache-Control": "no-cache"})

    async def favicon(self, request: web.Request) -> web.Response:
        return web.Response(status=204)

    async def static(self, request: web.Request) -> web.Response:
        name = request.match_info["name"]
        if name not in STATIC:
            raise web.HTTPNotFound(text=f"no such file: {name[:40]}")
        return web.Response(body=self._static[name], content_type=STATIC[name], headers={"Cache-Control": "no-cache"})

    async def layer(self, request: web.Request) -> web.Response:
        name = request.match_info["name"]
        path = self.layer_paths().get(name)
        if path is None:
            raise web.HTTPNotFound(text=f"no current layer '{name[:40]}'; run dem-full-tof (or dem-full) first")
        loop = asyncio.get_running_loop()
        try:
            image = await loop.run_in_executor(None, self.layers.get, name, path, self.dem_path())
        except (OSError, ValueError) as exc:
            raise web.HTTPNotFound(text=f"layer '{name}' unreadable: {exc}") from None
        return web.Response(body=image.png, content_type="image/png", headers={
            "Cache-Control": "max-age=3600" if request.query.get("v") == image.version else "no-cache",
            "X-Bounds": ",".join(f"{b:.6f}" for b in image.bounds),
            "X-Legend": json.dumps(image.legend, ensure_ascii=True),
        })

    async def state_json(self, request: web.Request) -> web.Response:
        return web.json_response(self.state())

    async def values_at(self, request: web.Request) -> web.Response:
        """The hover readout: each asked layer's value at x, y with its unit."""
        try:
            x, y = float(request.query["x"]), float(request.query["y"])
        except (KeyError, ValueError):
            raise web.HTTPBadRequest(text="give x and y in metres: /api/at?x=1.5&y=-0.2&layers=dem,slope") from None
        paths = self.layer_paths()
        names = [n for n in request.query.get("layers", "").split(",") if n in paths]
        loop = asyncio.get_running_loop()

        def read() -> dict[str, Any]:
            out = {}
            for name in names:
                with contextlib.suppress(OSError, ValueError):
                    out[name] = self.values.at(name, paths[name], x, y)
            return out

        return web.json_response({"x": x, "y": y, "values": await loop.run_in_executor(None, read)})

    async def product(self, request: web.Request) -> web.StreamResponse:
        name = request.match_info["name"]
        self._products = (0.0, {})  # list again: a product may have been written since
        path = self.products().get(name)
        if path is None:
            raise web.HTTPNotFound(text=f"'{name[:60]}' is not a product of the current map")
        return web.FileResponse(path, headers={"Content-Disposition": f'attachment; filename="{name}"'})

    async def camera(self, request: web.Request) -> web.Response:
        """A camera's newest frame (the state's ``cameras`` lists them with their versions)."""
        file = request.match_info["file"]
        name = self.cameras.name_of(file)
        if name is None:
            raise web.HTTPNotFound(text=f"no frame of '{file[:40]}' yet; grab one (grab-tof, grab-stereo) or run a DEM")
        loop = asyncio.get_running_loop()
        try:
            image = await loop.run_in_executor(None, self.cameras.encoded, name)
        except (KeyError, ValueError) as exc:
            raise web.HTTPNotFound(text=f"camera '{name}' has no image: {exc}") from None
        return web.Response(body=image.body, content_type=image.content_type, headers={
            "Cache-Control": "max-age=3600" if request.query.get("v") == str(image.seq) else "no-cache",
            "X-Version": str(image.seq),
            "X-Caption": image.caption,
        })

    async def websocket(self, request: web.Request) -> web.StreamResponse:
        origin = request.headers.get("Origin")
        if origin is not None and origin.split("://", 1)[-1] != request.host:
            # another site's page in the operator's browser must not drive the rover
            raise web.HTTPForbidden(text="cross-origin WebSocket refused; open the console from this server")
        app = self.app
        if len(app.connections) >= app.server_cfg.max_clients:
            raise web.HTTPServiceUnavailable(text=f"too many clients ({app.server_cfg.max_clients}); try again later")
        # room for a line well over the limit, so that it gets E_TOOLONG as on TCP instead of
        # closing the page's socket (aiohttp closes with 1009 past max_msg_size)
        ws = web.WebSocketResponse(heartbeat=20.0, max_msg_size=4 * app.server_cfg.max_line + 1024)
        await ws.prepare(request)
        page = WebPeer(app, ws, request.remote or "?", app.new_connection_id())
        app.connections.add(page)  # type: ignore[arg-type]
        self.pages.add(page)
        page.writing = asyncio.create_task(page.writer())
        page.log.info("client_connected", clients=len(app.connections))
        page.send_raw(self.history_message())
        page.greet()
        page.send_raw(json.dumps(self.state(), separators=(",", ":")))
        try:
            async for msg in ws:
                if msg.type != WSMsgType.TEXT:
                    break
                try:
                    line = str(json.loads(msg.data)["line"])
                except (ValueError, KeyError, TypeError):
                    page.send(Reply("RVS", "ERROR", {"code": "E_SYNTAX",
                                                     "message": 'send {"line": "<command line>"}'}))
                    continue
                raw = line.encode("utf-8")
                result = app.dispatch(page, raw if len(raw) <= app.server_cfg.max_line else TooLong.of(raw))
                if result is not None:
                    await result
        finally:
            page.close()
            self.pages.discard(page)
            await page.writing
            page.log.info("client_disconnected", clients=len(app.connections))
        return ws
