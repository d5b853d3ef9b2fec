"""The server's state and the dispatcher: modes, pose, devices, the job slot, event fan-out.

Everything here runs on the event loop except job handlers, which run in the job thread and
touch shared state only through the methods marked thread-safe.
"""

from __future__ import annotations

import asyncio
import difflib
import shutil
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import structlog

from drivers.base import DeviceError
from prox_workflows.products import write_yaml_atomic

from . import __version__
from .config import ConfigStore
from .devices import DeviceRegistry
from .jobs import Job, JobRunner, error_fields
from .protocol import ProtocolError, Reply, parse_request, tag_of
from .table import ALWAYS, CONTROL, HARDWARE, Command, bind_options, check_positional, lookup

if TYPE_CHECKING:
    from .server import Connection
    from .web.console import WebConsole

log = structlog.get_logger("rvs")

BLOCKING_MODES = {
    "standby": "the server is in standby; send continue, reset or reinit first",
    "sleep": "the server is asleep; wait for sleep to end or send break",
    "break": "the server was interrupted by break; send continue (or reset) first",
    "fault": "a device failed; send reset to recover (status shows which device)",
}


@dataclass
class Context:
    """What an immediate handler gets besides its config."""

    app: App
    conn: Connection
    request: Any
    command: Command
    # Run once the OK line is out: what must follow the reply rather than precede it (the JSON
    # greeting that format json sends).
    after_ok: list[Callable[[], None]] = field(default_factory=list)


@dataclass
class Pose:
    """The rover pose the server believes in (reported by the GNC with ``pose``).

    Coerced to plain floats: a pose from the simulator or an estimator arrives as numpy scalars,
    and those must never reach a recovery manifest, a sidecar or a reply.
    """

    x: float = 0.0
    y: float = 0.0
    heading: float = 0.0
    time: float = field(default_factory=time.time)
    stopped: bool = False  # the GNC said the rover stands still here (it gave up on a leg)

    def __post_init__(self) -> None:
        self.x, self.y, self.heading = float(self.x), float(self.y), float(self.heading)


class App:
    def __init__(
        self,
        config: ConfigStore,
        *,
        data_dir: Path,
        world: Any = None,
        loop: asyncio.AbstractEventLoop,
    ) -> None:
        self.config = config
        self.server_cfg = config.get("server")
        self.data_dir = Path(data_dir)
        self.data_dir.mkdir(parents=True, exist_ok=True)
        self.world = world
        self.loop = loop
        self.jobs = JobRunner(loop)
        self.devices = DeviceRegistry(config.get("drivers"), world)  # live: config -set reaches it
        self.connections: set[Connection] = set()
        self.base_mode = "ready"
        self._announced_mode = "ready"
        self.pose = Pose()
        self.pose_changed = threading.Condition()
        self.pose_version = 0
        self.last_used_hardware = False
        self.last_ptu: tuple[float, float] | None = None
        self.last_recovery: str | None = None
        self.maps: dict[str, str] = {}  # current map products: layer -> path under the data dir
        self.maps_lock = threading.RLock()
        # Background monitors (hazard-start, track3d-start) by name; each has status_fields() and
        # stop(). A job holds device_lock while it runs, a monitor for each of its cycles: so a
        # monitor yields the PTU and cameras to any job and resumes after it.
        self.monitors: dict[str, Any] = {}
        self.device_lock = threading.RLock()
        self.console: WebConsole | None = None  # the operator web console, when server.web_port is set
        self.started = time.monotonic()
        self.stopping = asyncio.Event()
        self.quitting = False
        self.name = f"{self.server_cfg.name}/{__version__}"
        self._find_last_recovery()

    # ---------------------------------------------------------------- modes and events

    @property
    def mode(self) -> str:
        job = self.jobs.current
        if job is not None:
            return "sleep" if job.command == "sleep" else "busy"
        return self.base_mode

    def set_mode(self, mode: str) -> None:
        self.base_mode = mode
        self.announce_mode()

    def announce_mode(self) -> None:
        mode = self.mode
        if mode != self._announced_mode:
            self._announced_mode = mode
            self.broadcast(Reply("RVS", "EVENT", {"kind": "mode", "mode": mode}))
            log.info("mode", mode=mode)

    def broadcast(self, reply: Reply) -> None:
        """Send an EVENT to every connection that has not said ``events off`` (loop only)."""
        for conn in list(self.connections):
            if conn.events:
                conn.send(reply)

    def job_reply(self, conn: Connection, reply: Reply) -> None:
        """A line of a job: to the connection that started it, and to every connection that
        watches all jobs (the web console's pages; loop only)."""
        conn.send(reply)
        for other in list(self.connections):
            if other.observes_jobs and other is not conn:
                other.observe(reply)

    async def start_console(self, sock: Any) -> None:
        """Serve the operator web console on ``sock`` (bound by the caller, as the TCP port is)."""
        from .web.console import WebConsole

        self.console = WebConsole(self)
        await self.console.start(sock)

    def current_maps(self) -> dict[str, str]:
        """The current map products (layer -> path relative to the data directory); thread-safe."""
        with self.maps_lock:
            return dict(self.maps)

    def broadcast_threadsafe(self, reply: Reply) -> None:
        self.loop.call_soon_threadsafe(self.broadcast, reply)

    # ---------------------------------------------------------------- pose

    def set_pose(self, x: float, y: float, heading: float, *, stopped: bool = False) -> None:
        """Thread-safe; wakes a navigation job waiting for the rover to move."""
        with self.pose_changed:
            self.pose = Pose(x, y, heading, stopped=stopped)
            self.pose_version += 1
            self.pose_changed.notify_all()

    def ptu_position(self) -> tuple[float, float] | None:
        """The PTU's last reported position, without touching the serial line."""
        dev = self.devices.devices.get("ptu")
        if dev is None:
            return None
        try:
            state = dev.status()
        except Exception:  # noqa: BLE001 - status never fails because a device does
            return None
        pan, tilt = state.get("pan_deg"), state.get("tilt_deg")
        if pan is None or tilt is None:
            return None
        self.last_ptu = (float(pan), float(tilt))
        return self.last_ptu

    # ---------------------------------------------------------------- files

    def data_path(self, *parts: str) -> Path:
        path = self.data_dir.joinpath(*parts)
        path.parent.mkdir(parents=True, exist_ok=True)
        return path

    def rel(self, path: Path) -> str:
        """Paths on the wire are relative to the data directory."""
        try:
            return Path(path).resolve().relative_to(self.data_dir.resolve()).as_posix()
        except ValueError:
            return str(path)

    def log_file(self) -> Path:
        return self.data_dir / self.server_cfg.log_file

    def _find_last_recovery(self) -> None:
        """The newest complete recovery set; temp folders of a set a crash cut short are removed."""
        root = self.data_dir / "recovery"
        if not root.is_dir():
            return
        for stray in root.glob(".*.tmp"):
            shutil.rmtree(stray, ignore_errors=True)
            log.warning("recovery_tmp_removed", folder=stray.name)
        sets = sorted(p for p in root.iterdir() if (p / "manifest.yaml").is_file())
        if sets:
            self.last_recovery = self.rel(sets[-1])

    def write_recovery(self, job: Job | None) -> str:
        """Store the recovery data set of a break: job, parameters, pose, PTU, current maps.

        Written into a temporary folder and renamed, so a set is either complete or absent;
        a failure removes the temporary folder before it is raised.
        """
        stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%S_%fZ")
        root = self.data_dir / "recovery"
        root.mkdir(parents=True, exist_ok=True)
        tmp = root / f".{stamp}.tmp"
        tmp.mkdir()
        try:
            ptu = self.ptu_position() or self.last_ptu  # mid-reinit the PTU may not answer: its last position
            copied: dict[str, str] = {}
            with self.maps_lock:
                maps = dict(self.maps)
            for layer, rel in maps.items():
                src = self.data_dir / rel
                if src.is_file():
                    (tmp / "maps").mkdir(exist_ok=True)
                    shutil.copy2(src, tmp / "maps" / src.name)
                    copied[layer] = f"maps/{src.name}"
            pose = self.pose
            manifest = {
                "time": datetime.now(UTC).isoformat(),
                "server": self.name,
                "job": None if job is None else {
                    "id": job.id, "command": job.command, "parameters": job.params,
                    "progress": {"phase": job.phase, "done": job.done, "total": job.total},
                },
                "pose": {"x": pose.x, "y": pose.y, "heading": pose.heading},
                "ptu": None if ptu is None else {"pan": ptu[0], "tilt": ptu[1]},
                "maps": copied,
            }
            write_yaml_atomic(tmp / "manifest.yaml", manifest)
            final = root / stamp
            tmp.rename(final)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        self.last_recovery = self.rel(final)
        return self.last_recovery

    # ---------------------------------------------------------------- dispatch

    def dispatch(self, conn: Connection, raw: bytes | None) -> Any:
        """Handle one request line; returns an awaitable when the handler is asynchronous."""
        if self.quitting:
            return None  # quit was answered; every connection is about to close
        if raw is None:
            conn.send(Reply("RVS", "ERROR", {
                "code": "E_TOOLONG",
                "message": f"request line over {self.server_cfg.max_line} bytes was discarded; send shorter lines",
            }))
            return None
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            conn.send(Reply("RVS", "ERROR", {
                "code": "E_SYNTAX", "message": f"request is not UTF-8 (byte {exc.start}); send UTF-8 text",
            }, tag_of(raw.decode("utf-8", "replace"))))
            return None
        try:
            req = parse_request(text)
        except ProtocolError as exc:
            conn.send(Reply("RVS", "ERROR", {"code": exc.code, "message": exc.message},
                            getattr(exc, "tag", None) or tag_of(text)))
            return None
        if req is None:
            return None
        cmd = lookup(req.command)
        if cmd is None or (cmd.sim_only and self.world is None):
            conn.send(Reply("RVS", "ERROR", {"code": "E_UNKNOWN", "message": self._unknown(req.command)}, req.tag))
            return None
        try:
            if self.server_cfg.token and not conn.authenticated and not cmd.open:
                raise ProtocolError("E_AUTH", "not authenticated; send auth -token <token> first")
            check_positional(cmd, req)
            base = self.config.values.get(cmd.config.module) if cmd.config is not None else None
            cfg = bind_options(cmd, base, req)
            mode = self.mode
            if mode in BLOCKING_MODES and (
                cmd.klass == HARDWARE or (mode in ("standby", "break", "fault") and cmd.job and cmd.klass != CONTROL)
            ):
                raise ProtocolError("E_STATE", BLOCKING_MODES[mode])
            if cmd.job:
                return self._start_job(conn, cmd, req, cfg)
            ctx = Context(self, conn, req, cmd)
            result = cmd.handler(ctx, cfg)
            if asyncio.iscoroutine(result):
                return self._finish_async(ctx, result)
            self._reply_ok(ctx, result)
        except ProtocolError as exc:
            fields = {"code": exc.code}
            if exc.code == "E_BUSY" and self.jobs.current is not None:
                fields["job"] = self.jobs.current.id
            fields["message"] = exc.message
            conn.send(Reply(cmd.module, "ERROR", fields, req.tag))
        except Exception as exc:  # noqa: BLE001 - a handler bug costs only its request
            fields, _ = error_fields(exc)
            if fields["code"] == "E_INTERNAL":
                log.exception("handler_failed", command=cmd.name)
            conn.send(Reply(cmd.module, "ERROR", fields, req.tag))
        return None

    def _unknown(self, name: str) -> str:
        from .table import COMMANDS

        names = [n for n, c in COMMANDS.items() if not (c.sim_only and self.world is None)]
        close = difflib.get_close_matches(name.lower(), names, n=1)
        hint = f"; did you mean {close[0]}?" if close else "; try help"
        return f"unknown command '{name[:40]}'{hint}"

    def _reply_ok(self, ctx: Context, result: dict[str, Any] | None) -> None:
        ctx.conn.send(Reply(ctx.command.module, "OK", dict(result or {}), ctx.request.tag))
        for then in ctx.after_ok:
            then()

    async def _finish_async(self, ctx: Context, coro: Any) -> None:
        conn, cmd, req = ctx.conn, ctx.command, ctx.request
        try:
            result = await coro
            self._reply_ok(ctx, result)
        except ProtocolError as exc:
            conn.send(Reply(cmd.module, "ERROR", {"code": exc.code, "message": exc.message}, req.tag))
        except Exception as exc:  # noqa: BLE001
            log.exception("handler_failed", command=cmd.name)
            conn.send(Reply(cmd.module, "ERROR", error_fields(exc)[0], req.tag))

    def _start_job(self, conn: Connection, cmd: Command, req: Any, cfg: Any) -> None:
        running = self.jobs.current
        if running is not None:
            raise ProtocolError(
                "E_BUSY", f"job {running.id} ({running.command}) is running; wait for it or send break"
            )
        if cmd.check is not None:
            cmd.check(self, cfg)
        job_id = self.jobs.new_id()
        module, tag = cmd.module, req.tag
        self.ptu_position()  # remember where the PTU is, for a recovery set written mid-job

        def emit(status: str, fields: dict[str, Any]) -> None:
            reply = Reply(module, status, {"job": job_id, **fields}, tag)
            self.loop.call_soon_threadsafe(self.job_reply, conn, reply)

        params = cfg.as_dict() if cfg is not None else {}
        job = Job(job_id, cmd.name, module, params, tag, emit, uses_hardware=cmd.klass in (HARDWARE, CONTROL),
                  connection=conn.id)
        job.app = self  # type: ignore[attr-defined]
        self.job_reply(conn, Reply(module, "ACK", {"job": job_id}, tag))
        conn.jobs_running += 1
        conn.jobs_started += 1
        jlog = conn.log.bind(command=cmd.name, job=job_id, tag=tag)
        jlog.info("job_start", params=params)

        def work(j: Job) -> dict[str, Any]:
            with self.device_lock:
                return cmd.handler(j, cfg) or {}

        def done(j: Job, result: dict[str, Any] | None, error: BaseException | None) -> None:
            if cmd.klass != ALWAYS:
                self.last_used_hardware = j.uses_hardware
            if error is None:
                self.job_reply(conn, Reply(module, "OK", {"job": j.id, **(result or {})}, tag))
                jlog.info("job_ok", seconds=round(time.monotonic() - j.started, 3))
            else:
                fields, device_failed = error_fields(error)
                if device_failed:
                    self.base_mode = "fault"
                    if isinstance(error, DeviceError):
                        self.devices.errors[error.device] = error.message
                self.job_reply(conn, Reply(module, "ERROR", {"job": j.id, **fields}, tag))
                jlog.warning("job_error", code=fields["code"], error=fields["message"])
            self.announce_mode()
            conn.jobs_running -= 1
            conn.close_if_done()

        self.jobs.start(job, work, done)
        self.announce_mode()

    async def interrupt(self) -> Job | None:
        """Stop the running job (break and quit)."""
        return await self.jobs.interrupt()

    def stop_monitors(self) -> None:
        """Stop every background monitor and wait for its thread (server shutdown; blocking)."""
        for monitor in list(self.monitors.values()):
            monitor.stop()
        self.monitors.clear()

