"""The server's state and the dispatcher: modes, pose, devices, the job slot, event fan-out.

Everything the server keeps between requests is a declared field of :class:`App`, so a reader
sees it in one place; command modules read and change it only through the fields' own methods
(each concern with its own lock), never by hanging new attributes on the app. Everything here
runs on the event loop except job handlers and monitors, which run in their own threads and
touch shared state only through the methods marked thread-safe.
"""

from __future__ import annotations

import asyncio
import difflib
import itertools
import threading
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any, Generic, TypeVar

import structlog

from drivers.base import DeviceError
from prox_workflows.products import finish_product_sets

from . import PROTOCOL_VERSION, __version__
from .auth_failures import AuthFailures
from .bus import Bus
from .config import ConfigStore, ServerConfig
from .devices import DeviceRegistry, stereo_points
from .jobs import Job, JobRunner, error_fields
from .maps import CurrentMaps, RecoverySets, ground_height
from .monitors import Monitors
from .protocol import ProtocolError, Reply, Request, TooLong, is_silent, parse_request, tag_of
from .table import ALWAYS, CONTROL, HARDWARE, Command, bind_options, check_positional, lookup
from .travel import Travel

if TYPE_CHECKING:
    from drivers.sim.world import World
    from prox_workflows.algorithms.odometry import DepthFrame
    from prox_workflows.algorithms.tracking import Detection

    from .server import Connection
    from .telemetry import Station
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
    request: Request
    command: Command
    # Run once the OK line is out: what must follow the reply rather than precede it (the JSON
    # greeting that format json sends).
    after_ok: list[Callable[[], None]] = field(default_factory=list)

    def log_context(self) -> dict[str, Any]:
        """What a thread this request starts (a monitor) binds to its log lines, as a job does."""
        return {"conn": self.conn.id, "peer": self.conn.peer, "command": self.command.name,
                "tag": self.request.tag}


@dataclass
class Pose:
    """The rover pose the server believes in (reported by the GNC with ``pose``, or set by
    orient, navigate and recover; ``source`` says which).

    Coerced to plain floats: a pose from the simulator or an estimator arrives as numpy scalars,
    and those must never reach a recovery manifest, a sidecar or a reply.
    """

    x: float = 0.0
    y: float = 0.0
    heading: float = 0.0
    time: float = field(default_factory=time.time)
    stopped: bool = False  # the GNC said the rover stands still here (it gave up on a leg)
    # Who said so: gnc (the pose command), orient (visual odometry), navigate (its -start),
    # odometry (the simulated rover's dead reckoning after an -auto leg: the truth differs from it
    # once sim slip is set), vo (navigate's registration of each leg's DEM on the previous one),
    # map (navigate's match of its DEM on the global DEM), recovery, or start (nobody yet).
    # On the wire as status's and navigate's pose_source.
    source: str = "start"
    # The estimate's 1-sigma: position along its worst direction (m) and heading (deg). 0 for a
    # pose given from outside (gnc, -start) that says nothing of its own accuracy; grows with
    # the distance driven on dead reckoning, shrinks with a VO or map fix (rvs_server.navigation.localiser).
    sigma: float = 0.0
    sigma_heading: float = 0.0
    # The body's roll (left side up) and pitch (nose up), deg, where the GNC reports them with its
    # pose (its IMU); None when it does not: the see loop then knows no more of the ground under
    # the wheels than the set-down assumes (drivers.rover attitude).
    roll: float | None = None
    pitch: float | None = None

    def __post_init__(self) -> None:
        self.x, self.y, self.heading = float(self.x), float(self.y), float(self.heading)
        self.sigma, self.sigma_heading = float(self.sigma), float(self.sigma_heading)


T = TypeVar("T")


class Shared(Generic[T]):
    """One value that job threads write and the event loop reads, behind its own lock."""

    def __init__(self, value: T) -> None:
        self._lock = threading.Lock()
        self._value = value

    def get(self) -> T:
        with self._lock:
            return self._value

    def set(self, value: T) -> None:
        with self._lock:
            self._value = value


@dataclass(frozen=True)
class OrientReference:
    """The last orient acquisition: what the next orient tracks against, and the pose it had."""

    sensor: str
    frame: DepthFrame
    pose: tuple[float, float, float]
    time: float


class App:
    """Everything the server keeps, as declared fields; see the module docstring for the rules.

    Fields a thread other than the event loop may touch say how (their lock, or thread-safe
    methods); the rest belong to the event loop.
    """

    # -- configuration and surroundings (set once)
    config: ConfigStore  # every module's effective configuration; config -set changes it in place
    server_cfg: ServerConfig  # the live "server" module of ``config``
    data_dir: Path  # every file the server writes lands under it
    world: World | None  # the simulated world when any device is simulated, else None
    loop: asyncio.AbstractEventLoop
    name: str  # server/version, as the hello line and recovery sets say
    started: float  # monotonic time of start (status: uptime)
    # -- jobs, devices, connections (event loop, except where said)
    jobs: JobRunner  # the single job slot
    devices: DeviceRegistry  # open devices and their errors; its own lock
    # Held by a job for its whole run and by a monitor for each of its cycles: so a monitor
    # yields the PTU and cameras to any job and resumes after it.
    device_lock: threading.RLock
    connections: set[Connection]
    last_used_hardware: bool  # whether the last job used hardware (continue checks, or re-inits)
    last_ptu: tuple[float, float] | None  # the PTU's last known pan/tilt, for a recovery set
    stopping: asyncio.Event  # set when the server is to shut down
    # -- what the server knows of the rover and its surroundings (thread-safe, one lock each)
    pose_changed: threading.Condition  # guards the pose; notified on every change
    maps: CurrentMaps  # the current DEM's layers, their files and views kept for an update
    odometry: Shared[OrientReference | None]  # orient's reference acquisition
    track_target: Shared[Detection | None]  # what track3d-detect found, where track3d-start begins
    travel: Travel  # the driven track (fed by every pose change) and the last navigate's goal
    monitors: Monitors  # hazard monitor, target tracker (event loop only)
    recovery: RecoverySets  # break's recovery sets and the newest of them
    console: WebConsole | None  # the operator web console, when server.web_port is set (event loop)
    console_off: str | None  # why there is no console (web_port 0, its port taken): status says it
    auth_failures: AuthFailures  # wrong tokens by client address (event loop only)
    bus: Bus  # what happens in the server, for Foxglove and recordings (thread-safe)
    telemetry: Station | None  # the Foxglove server and the MCAP recording, once serve started them

    def __init__(
        self,
        config: ConfigStore,
        *,
        data_dir: Path,
        world: World | None = None,
        loop: asyncio.AbstractEventLoop,
    ) -> None:
        self.config = config
        self.server_cfg = config.get("server")
        self.data_dir = Path(data_dir)
        self.data_dir.mkdir(parents=True, exist_ok=True)
        finished = finish_product_sets(self.data_dir)  # a crash mid-write: whole sets only
        if any(finished.values()):
            log.warning("product_sets_finished", **finished)
        self.world = world
        self.loop = loop
        self.name = f"{self.server_cfg.name}/{__version__}"
        self.started = time.monotonic()
        self.jobs = JobRunner(loop)
        # live: config -set reaches it; the rover reports into (and its GNC is heard through) the pose
        self.devices = DeviceRegistry(config.get("drivers"), world, poses=self, matcher=stereo_points)
        self.device_lock = threading.RLock()
        self.connections = set()
        self.last_used_hardware = False
        self.last_ptu = None
        self.console = None
        self.console_off = None
        self.auth_failures = AuthFailures()
        self._connection_ids = itertools.count(1)
        self.bus = Bus()
        self.telemetry = None
        self.stopping = asyncio.Event()
        self._quitting = False
        self._base_mode = "ready"
        self._announced_mode = "ready"
        self.pose_changed = threading.Condition()
        self._pose = Pose()
        self._pose_version = 0
        self.maps = CurrentMaps(self.bus)
        self.odometry = Shared(None)
        self.track_target = Shared(None)
        self.travel = Travel()
        self._travelled(self._pose.x, self._pose.y)  # the track starts where the rover stands
        self.monitors = Monitors(loop)
        self.recovery = RecoverySets(self.data_dir, self.rel)

    # ---------------------------------------------------------------- modes and events

    @property
    def mode(self) -> str:
        job = self.jobs.current
        if job is not None:
            return "sleep" if job.command == "sleep" else "busy"
        return self._base_mode

    @property
    def base_mode(self) -> str:
        """The mode when no job runs: ready, standby, break or fault."""
        return self._base_mode

    @property
    def quitting(self) -> bool:
        """quit was answered: requests still arriving are ignored."""
        return self._quitting

    def mode_blocks_devices(self) -> bool:
        """Whether the mode keeps hardware untouched (a monitor pauses in it)."""
        return self._base_mode in BLOCKING_MODES

    def set_mode(self, mode: str) -> None:
        self._base_mode = mode
        self.announce_mode()

    def device_failed(self, device: str, message: str) -> None:
        """A device failed in a job or a monitor: fault mode, and status names it (loop only)."""
        self._base_mode = "fault"
        self.devices.errors[device] = message

    def begin_break(self) -> tuple[Job | None, bool]:
        """Tell the running job to stop, synchronously, and be in break mode from here on.

        Called before anything else the event loop runs: a job started by the same batch of
        lines is caught however short it is, and its end announces break, never a passing ready.
        Returns the job and whether it ends interrupted (False: its outcome was settled before the
        break came), known at once, so that break answers without waiting for the job to stop."""
        job = self.jobs.current
        stopped = job.stop() if job is not None else False
        self._base_mode = "break"
        return job, stopped

    def quit(self) -> Job | None:
        """Stop taking requests, tell the job to stop and have the server shut down; the job it
        stopped (None if none, or one whose outcome was settled). Never waits: the shutdown
        waits for the job, so its ERROR still goes out after quit's OK, before the connections
        close."""
        self._quitting = True
        job = self.jobs.current
        stopped = job.stop() if job is not None else False
        self.loop.call_soon(self.stopping.set)
        return job if stopped else None

    def announce_mode(self) -> None:
        mode = self.mode
        if mode != self._announced_mode:
            self._announced_mode = mode
            self.broadcast(Reply("RVS", "EVENT", {"kind": "mode", "mode": mode}))
            log.info("mode", mode=mode)

    def broadcast(self, reply: Reply) -> None:
        """Send an EVENT to every connection that has not said ``events off`` (loop only)."""
        self.bus.publish("event", reply=reply)
        for conn in list(self.connections):
            if conn.events:
                conn.send(reply)

    def sent(self, conn: Connection, reply: Reply, *, job: bool = False) -> None:
        """Publish a line sent to ``conn`` (its ``send`` calls this first, whether or not it is
        still open: a job's final line is part of the record when its client left before it);
        an EVENT is published once, by :meth:`broadcast`. ``job``: a line of a job (its ACK,
        PROGRESS, OK or ERROR), not an immediate reply."""
        if reply.status != "EVENT":
            self.bus.publish("reply", conn=conn.id, reply=reply, job=job)

    def job_reply(self, conn: Connection, reply: Reply) -> None:
        """A line of a job: to the connection that started it, and to every connection that
        watches all jobs (the web console's pages; loop only)."""
        conn.send(reply, job=True)
        for other in list(self.connections):
            if other.observes_jobs and other is not conn:
                other.observe(reply)

    def hello(self) -> Reply:
        """The greeting: the contract's keys first, then ``console`` (on/off), so an operator whose
        server started without its console (its port taken) learns it at connect."""
        return Reply("RVS", "EVENT", {"kind": "hello", "protocol": PROTOCOL_VERSION, "server": self.name,
                                      "mode": self.mode, "console": "off" if self.console is None else "on"})

    def new_connection_id(self) -> int:
        """Connection numbers are shared by TCP clients and web pages: logs name each one once."""
        return next(self._connection_ids)

    def broadcast_threadsafe(self, reply: Reply) -> None:
        self.loop.call_soon_threadsafe(self.broadcast, reply)

    # ---------------------------------------------------------------- pose

    @property
    def pose(self) -> Pose:
        """The rover pose the server believes in (replaced whole, never changed in place)."""
        return self._pose

    @property
    def pose_version(self) -> int:
        """Counts pose changes: a waiter compares it to tell a new report from the one it saw."""
        return self._pose_version

    def set_pose(self, x: float, y: float, heading: float, *, stopped: bool = False, source: str = "gnc",
                 sigma: float = 0.0, sigma_heading: float = 0.0, roll: float | None = None,
                 pitch: float | None = None) -> None:
        """Thread-safe; wakes a navigation job waiting for the rover to move."""
        with self.pose_changed:
            self._pose = Pose(x, y, heading, stopped=stopped, source=source, sigma=sigma,
                              sigma_heading=sigma_heading, roll=roll, pitch=pitch)
            self._pose_version += 1
            self.pose_changed.notify_all()
        self._travelled(x, y)

    def _travelled(self, x: float, y: float) -> None:
        """The track follows the simulated rover where there is one (it shows where the rover
        really went, slip and all), else the pose the GNC reports."""
        if self.world is not None:
            x, y, _ = self.world.rover_pose()
        self.travel.moved(x, y, lambda x, y: ground_height(self.maps.layers, x, y))

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

    @property
    def last_recovery(self) -> str | None:
        """The newest complete recovery set (relative to the data directory), if any."""
        return self.recovery.last

    def recovery_manifest(self, job: Job | None) -> dict[str, Any]:
        """What a break's recovery set says, as known at the break: the job's parameters and
        progress, the pose, and the PTU where it last reported (never asked: it may be moving)."""
        ptu = self.ptu_position() or self.last_ptu  # mid-reinit the PTU may not answer: its last position
        pose = self.pose
        return {
            "time": datetime.now(UTC).isoformat(),
            "server": self.name,
            "job": None if job is None else {
                "id": job.id, "command": job.command, "parameters": job.params,
                "progress": {"phase": job.phase, "done": job.done, "total": job.total},
            },
            "pose": {"x": pose.x, "y": pose.y, "heading": pose.heading},
            "ptu": None if ptu is None else {"pan": ptu[0], "tilt": ptu[1]},
        }

    def write_recovery(self, job: Job | None, manifest: dict[str, Any] | None = None) -> str:
        """Store the recovery data set of a break (``manifest``, default: as of now) with copies
        of the current maps; blocking file I/O, run off the event loop."""
        return self.recovery.write(manifest or self.recovery_manifest(job), self.maps.files())

    # ---------------------------------------------------------------- dispatch

    def dispatch(self, conn: Connection, raw: bytes | TooLong) -> Any:
        """Handle one request line; returns an awaitable when the handler is asynchronous."""
        if self.quitting:
            return None  # quit was answered; every connection is about to close
        self.bus.publish("request", conn=conn.id, line=b"(line too long)" if isinstance(raw, TooLong) else raw)
        if isinstance(raw, TooLong):
            conn.send(Reply("RVS", "ERROR", {
                "code": "E_TOOLONG",
                "message": f"request line over {self.server_cfg.max_line} bytes was discarded; send shorter lines",
            }, raw.tag))
            return None
        if is_silent(raw):
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
            conn.send(Reply("RVS", "ERROR", {"code": "E_UNKNOWN", "message": self._unknown(req.sent)}, req.tag))
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

    async def _finish_async(self, ctx: Context, coro: Awaitable[dict[str, Any] | None]) -> None:
        conn, cmd, req = ctx.conn, ctx.command, ctx.request
        try:
            result = await coro
            self._reply_ok(ctx, result)
        except ProtocolError as exc:
            conn.send(Reply(cmd.module, "ERROR", {"code": exc.code, "message": exc.message}, req.tag))
        except Exception as exc:  # noqa: BLE001
            log.exception("handler_failed", command=cmd.name)
            conn.send(Reply(cmd.module, "ERROR", error_fields(exc)[0], req.tag))

    def _start_job(self, conn: Connection, cmd: Command, req: Request, cfg: Any) -> None:
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
        context = {"conn": conn.id, "peer": conn.peer, "command": cmd.name, "job": job_id, "tag": tag}
        job = Job(job_id, cmd.name, module, params, tag, emit, uses_hardware=cmd.klass in (HARDWARE, CONTROL),
                  connection=conn.id, app=self, log_context=context)
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
                    if isinstance(error, DeviceError):
                        self.device_failed(error.device, error.message)
                    else:
                        self._base_mode = "fault"
                self.job_reply(conn, Reply(module, "ERROR", {"job": j.id, **fields}, tag))
                jlog.warning("job_error", code=fields["code"], error=fields["message"])
            self.announce_mode()
            conn.jobs_running -= 1
            conn.close_if_done()

        self.jobs.start(job, work, done)
        self.announce_mode()

    async def interrupt(self) -> Job | None:
        """Stop the running job and wait until it has (shutdown: its ERROR goes out before the
        connections close)."""
        return await self.jobs.interrupt()

    def stop_monitors(self) -> None:
        """Stop every background monitor and wait for its thread (server shutdown; blocking)."""
        self.monitors.stop_all()

