"""System commands of appendix C (quit, standby, break, continue, reset, reinit, sleep, logbook)
and the extensions (help, status, version, events, format, config, pose, auth)."""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import platform
import shutil
import time
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any, ClassVar

import structlog

from drivers.base import DeviceInterrupted
from drivers.registry import DEVICE_KINDS, registry
from rvs_params import assignment

from .. import PROTOCOL_VERSION, __version__
from ..app import Context
from ..config import ModuleConfig, ServerConfig, param
from ..jobs import HISTORY, Job
from ..protocol import Fixed, Group, ProtocolError, render_value
from ..table import ALWAYS, COMMANDS, CONTROL, command, lookup
from ..web.address import console_fields

if TYPE_CHECKING:
    from ..app import App

log = structlog.get_logger("rvs.system")

# ------------------------------------------------------------------ config classes


@dataclass
class SleepConfig(ModuleConfig):
    module: ClassVar[str] = "sleep"
    seconds: float = param(10.0, "how long to sleep", unit="s", min=0.0, max=86400.0)


@dataclass
class ReinitConfig(ModuleConfig):
    module: ClassVar[str] = "reinit"
    device: str = param("all", "device to re-initialise", choices=("all", *DEVICE_KINDS))


@dataclass
class LogbookConfig(ModuleConfig):
    module: ClassVar[str] = "logbook"
    name: str = param("", "stem of the copy (default rvs_<time>)", stem=True)


@dataclass
class PoseConfig(ModuleConfig):
    module: ClassVar[str] = "pose"
    x: float = param(float("nan"), "rover x in the global frame", unit="m", min=-1e6, max=1e6)
    y: float = param(float("nan"), "rover y in the global frame", unit="m", min=-1e6, max=1e6)
    heading: float = param(float("nan"), "rover heading, counter-clockwise from +x", unit="deg", min=-360.0, max=360.0)
    stopped: bool = param(False, "the rover stands still here: ends a navigate wait short of the leg's end")
    roll: float = param(float("nan"), "body roll from the rover's IMU, left side up (optional, with -pitch: the "
                                      "see loop sets the rover down on it at navigate's start, the ground under the "
                                      "wheels on the plane it gives; navigate.see_set_down attitude at every frame)",
                        unit="deg", min=-90.0, max=90.0)
    pitch: float = param(float("nan"), "body pitch from the rover's IMU, nose up (optional; with -roll)", unit="deg",
                         min=-90.0, max=90.0)


@dataclass
class StatusConfig(ModuleConfig):
    module: ClassVar[str] = "status"
    job: int | None = param(None, f"a job id: how it runs, or how it ended (its final line; the last {HISTORY} "
                            "jobs are kept)", min=1, max=2**31 - 1)


@dataclass
class AuthConfig(ModuleConfig):
    module: ClassVar[str] = "auth"
    token: str = param("", "the server's token", required=True)


# ------------------------------------------------------------------ helpers


def _devices(summary: dict[str, str]) -> list[str]:
    return [f"{name}:{state}" for name, state in summary.items()]


# ------------------------------------------------------------------ appendix C


@command("quit", klass=ALWAYS,
         help="stop the server: interrupt every job, close all connections and exit (exit or bye closes only "
              "this connection)")
def quit_(ctx: Context, cfg: None) -> dict[str, Any]:
    # Answered at once, before the job it stopped ends: the shutdown waits for that job, so its
    # ERROR follows this OK on its connection before the connections close.
    job = ctx.app.quit()
    return {"interrupted": job.id if job else None}


@command("standby", klass=ALWAYS, help="wait for a change-of-mode command (continue, reset, reinit)")
def standby(ctx: Context, cfg: None) -> dict[str, Any]:
    app = ctx.app
    if app.jobs.current is not None:
        raise ProtocolError("E_BUSY", f"job {app.jobs.current.id} is running; wait for it or send break")
    if app.base_mode == "fault" or not app.devices.healthy():
        raise ProtocolError("E_STATE", "not healthy (a device failed); send reset first")
    app.set_mode("standby")
    return {"mode": "standby"}


@command("break", klass=ALWAYS, help="interrupt all jobs and store a recovery data set")
def break_(ctx: Context, cfg: None) -> Any:
    # The job is told to stop here, synchronously, before anything else the event loop runs
    # (see App.begin_break); what the recovery set says is taken now, as the break found it.
    app = ctx.app
    job, stopped = app.begin_break()
    manifest = app.recovery_manifest(job)
    if job is not None:
        app.jobs.hold_final(job)  # its ERROR after this break's OK, however fast it stops
    return _finish_break(app, job, stopped, manifest)


async def _finish_break(app: App, job: Job | None, stopped: bool, manifest: dict[str, Any]) -> dict[str, Any]:
    # The reply waits for the recovery set, not for the job: the set is written off the loop
    # (the maps are copied; docs/PROTOCOL.md says why before the OK) while the job winds down.
    try:
        try:
            recovery = await app.loop.run_in_executor(None, app.write_recovery, job, manifest)
            failure = None
        except Exception as exc:  # noqa: BLE001 - the break itself must still happen
            recovery, failure = None, exc
            log.exception("recovery_failed")
    finally:
        if job is not None:  # call_soon: after this reply is written, also when it is an ERROR
            app.loop.call_soon(app.jobs.release_final, job)
    app.announce_mode()  # break since begin_break, unless a continue came meanwhile
    # A job whose last step was done when the break came ends OK: then nothing was interrupted.
    interrupted = job.id if job is not None and stopped else None
    if failure is not None:
        raise ProtocolError("E_IO", f"job {interrupted or 'none'} was interrupted and the server is in break mode, "
                                    f"but no recovery set was written ({type(failure).__name__}: {failure}); check "
                                    "the data directory, then send continue")
    return {"interrupted": interrupted, "recovery": recovery}


@command("exit", klass=ALWAYS, open=True, aliases=("bye",),
         help="close this connection (alias bye); jobs it started run on; quit stops the whole server")
def exit_(ctx: Context, cfg: None) -> dict[str, Any]:
    ctx.conn.exiting = True
    return {"closing": True}


def _control_done(job: Job, summary: dict[str, str]) -> dict[str, Any]:
    app = job.app

    def ready() -> None:  # on the loop, so a break either came before (and stays) or comes after
        if not job.cancelled:
            app.set_mode("ready")

    app.loop.call_soon_threadsafe(ready)
    return {"mode": "ready", "devices": _devices(summary)}


@command("continue", job=True, klass=CONTROL, help="check (or re-initialise) the hardware and return to ready")
def continue_(job: Job, cfg: None) -> dict[str, Any]:
    app = job.app
    job.progress(0, 1, "checking hardware" if app.last_used_hardware else "re-initialising hardware")
    summary = app.devices.check() if app.last_used_hardware else app.devices.reinit()
    job.progress(1, 1, "hardware ready")
    return _control_done(job, summary)


@command("reset", job=True, klass=CONTROL, help="check the hardware status, then re-initialise all hardware")
def reset(job: Job, cfg: None) -> dict[str, Any]:
    app = job.app
    names = app.devices.names
    checked: dict[str, str] = {}
    for i, name in enumerate(names):
        job.check()
        job.progress(i, 2 * len(names), f"checking {name}")
        try:
            app.devices.check([name])
            checked[name] = "ok"
        except Exception as exc:  # noqa: BLE001 - reset goes on to re-initialise what failed
            checked[name] = f"failed: {exc}"
    for i, name in enumerate(names):
        job.check()
        job.progress(len(names) + i, 2 * len(names), f"re-initialising {name}")
        try:
            app.devices.reset(name, job.cancel)
        except DeviceInterrupted:
            job.check()  # the break that stopped the wait ends the job as interrupted
            raise
    out = _control_done(job, app.devices.summary())
    out["checked"] = [f"{n}:{'ok' if s == 'ok' else 'failed'}" for n, s in checked.items()]
    return out


def _check_reinit(app: App, cfg: ReinitConfig) -> None:
    if cfg.device != "all" and cfg.device not in app.devices.names:
        raise ProtocolError("E_ARG", f"-device {cfg.device} is not configured in this build")


@command("reinit", job=True, klass=CONTROL, config=ReinitConfig, check=_check_reinit, help="re-initialise the hardware (-device for one)")
def reinit(job: Job, cfg: ReinitConfig) -> dict[str, Any]:
    app = job.app
    names = None if cfg.device == "all" else [cfg.device]
    job.progress(0, 1, f"re-initialising {cfg.device}")
    summary = app.devices.reinit(names)
    return _control_done(job, summary)


@command("sleep", job=True, config=SleepConfig, help="no operations for -seconds (break ends it early)")
def sleep(job: Job, cfg: SleepConfig) -> dict[str, Any]:
    start = time.monotonic()
    job.sleep(cfg.seconds)
    return {"slept": Fixed(time.monotonic() - start, 3)}


@command("logbook", klass=ALWAYS, config=LogbookConfig, help="copy the current log file to the shared directory")
def logbook(ctx: Context, cfg: LogbookConfig) -> dict[str, Any]:
    app = ctx.app
    src = app.log_file()
    if not src.is_file():
        raise ProtocolError("E_IO", f"no log file at {src}; is logging to a file enabled?")
    stem = cfg.name or "rvs_" + datetime.now(UTC).strftime("%Y%m%dT%H%M%S")
    dest = app.data_path(app.server_cfg.shared_dir, stem + ".log")
    shutil.copyfile(src, dest)
    return {"file": app.rel(dest)}


# ------------------------------------------------------------------ extensions


@command("help", klass=ALWAYS, positional=("command",), open=True, help="list commands, or explain one")
def help_(ctx: Context, cfg: None) -> dict[str, Any]:
    req = ctx.request
    world = ctx.app.world is not None
    if not req.positional:
        names = [n for n, c in COMMANDS.items() if world or not c.sim_only]
        return {"commands": " ".join(names), "text": "help <command> shows its options; requests are: [@tag] command -option value ..."}
    cmd = lookup(req.positional[0])
    if cmd is None or (cmd.sim_only and not world):
        raise ProtocolError("E_ARG", f"no command '{req.positional[0][:40]}'; help lists them")
    out: dict[str, Any] = {
        "command": cmd.name,
        "module_id": cmd.module,
        "kind": "job" if cmd.job else "immediate",
        "usage": cmd.usage(),
        "text": cmd.help,
    }
    if cmd.config is not None and not cmd.raw:
        current = ctx.app.config.values.get(cmd.config.module)
        for spec in cmd.config.keys().values():
            if spec.option:
                default = current.value_of(spec) if current is not None else spec.default
                shown = _show(default)
                out["opt_" + spec.flag[1:].replace("-", "_")] = f"{cmd.describe(spec, ctx.app)}{f'; default {shown}' if shown else ''}: {spec.help}"
    return out


def _show(value: Any) -> str:
    """A default as it is typed on the wire (true, 0.3, -150,150,-50,-15); "" for none, whose
    meaning the option's help gives (default tof_<UTC time>, keep the axis)."""
    if isinstance(value, float) and value != value:
        return ""
    if isinstance(value, list):
        return ",".join(_show(v) for v in value)
    if isinstance(value, float):
        return format(value, "g")
    return render_value(value) if value != "" else ""


@command("status", klass=ALWAYS, config=StatusConfig,
         help="mode, running job, pose, devices and connections; -job N: how job N runs or how it ended")
def status(ctx: Context, cfg: StatusConfig) -> dict[str, Any]:
    app = ctx.app
    if cfg.job is not None:
        return _job_status(app, cfg.job)
    job = app.jobs.current
    out: dict[str, Any] = {"mode": app.mode, "job": job.id if job else None}
    if job is not None:
        out["job_command"] = job.command
        if job.phase:
            out["phase"] = job.phase
        out["progress"] = f"{job.done}/{job.total}"
    pose = app.pose
    out["pose"] = [Fixed(pose.x, 3), Fixed(pose.y, 3), Fixed(pose.heading, 2)]
    out["pose_source"] = pose.source
    out["pose_sigma"] = Fixed(pose.sigma, 3)
    out["pose_sigma_heading"] = Fixed(pose.sigma_heading, 2)
    ptu = app.ptu_position()
    if ptu is not None:
        out["ptu"] = [Fixed(ptu[0], 3), Fixed(ptu[1], 3)]
    out["devices"] = _devices(app.devices.summary())
    for name, err in app.devices.errors.items():
        out[f"error_{name}"] = err
    out["clients"] = len(app.connections)
    out["uptime"] = Fixed(time.monotonic() - app.started, 1)
    out["recovery"] = app.last_recovery
    # How the last job ended: a client that lost its connection meanwhile learns it here
    # (status -job N for the whole final line).
    last = next(reversed(app.jobs.history.values()), None)
    out["last_job"] = last.id if last else None
    if last is not None:
        out["last_job_command"] = last.command
        out["last_job_outcome"] = "OK" if last.status == "OK" else last.fields.get("code", "ERROR")
    out.update(console_fields(app))  # console=on console_url, or off console_reason
    if app.telemetry is not None:  # foxglove=on foxglove_url, or off foxglove_reason; recording
        out.update(app.telemetry.fields())
    if app.world is not None:
        out["scene"] = app.world.scene_name
        # Beside the believed pose: the simulated rover's true one (they part with sim slip).
        t = app.world.truth()
        out["truth"] = [Fixed(t["x"], 3), Fixed(t["y"], 3), Fixed(t["heading"], 2)]
        out["sim_time"] = Fixed(t["sim_time"], 3)
    out.update(app.monitors.status_fields())
    return out


def _job_status(app: App, job_id: int) -> dict[str, Any]:
    """One job: its progress while it runs; once ended, its final line's status and fields
    under ``final`` (text: ``final_status=ERROR final_code=E_INTERRUPTED ...``)."""
    job = app.jobs.current
    if job is not None and job.id == job_id:
        out: dict[str, Any] = {"job": job.id, "job_command": job.command, "job_tag": job.tag, "job_state": "running"}
        if job.phase:
            out["phase"] = job.phase
        out["progress"] = f"{job.done}/{job.total}"
        out["job_seconds"] = Fixed(time.monotonic() - job.started, 1)
        return out
    rec = app.jobs.record(job_id)
    if rec is None:
        newest = app.jobs.issued
        if job_id > newest:
            raise ProtocolError("E_DATA", f"there is no job {job_id}: the newest is {newest or 'none'}")
        raise ProtocolError("E_DATA", f"job {job_id} ended before the last {HISTORY} jobs the server keeps; "
                                      "its products, if any, are on disk and in the log")
    return {"job": rec.id, "job_command": rec.command, "job_tag": rec.tag, "job_state": rec.status.lower(),
            "job_seconds": Fixed(rec.seconds, 1), "final": {"status": rec.status, **rec.fields}}


@command("version", klass=ALWAYS, open=True, help="server, protocol and Python versions")
def version(ctx: Context, cfg: None) -> dict[str, Any]:
    return {
        "server": ctx.app.name,
        "version": __version__,
        "protocol": PROTOCOL_VERSION,
        "python": platform.python_version(),
    }


@command("events", klass=ALWAYS, positional=("on|off",), help="switch EVENT lines on or off for this connection")
def events(ctx: Context, cfg: None) -> dict[str, Any]:
    if ctx.request.positional:
        word = ctx.request.positional[0].lower()
        if word not in ("on", "off"):
            raise ProtocolError("E_ARG", f"events takes on or off, not '{word[:20]}'")
        ctx.conn.events = word == "on"
    return {"events": "on" if ctx.conn.events else "off"}


@command("format", klass=ALWAYS, positional=("text|json",), help="reply as text lines or JSON objects")
def format_(ctx: Context, cfg: None) -> dict[str, Any]:
    if ctx.request.positional:
        word = ctx.request.positional[0].lower()
        if word not in ("text", "json"):
            raise ProtocolError("E_ARG", f"format takes text or json, not '{word[:20]}'")
        ctx.conn.json = word == "json"
        if ctx.conn.json and not ctx.conn.jobs_started:
            ctx.after_ok.append(ctx.conn.greet)
    return {"format": "json" if ctx.conn.json else "text"}


def _drivers_help() -> str:
    """The drivers keys as their settings classes declare them: which apply at once, which wait."""
    parts = []
    for kind in DEVICE_KINDS:
        specs = registry(kind).settings_class().specs()
        live = [n for n, s in specs.items() if s.live]
        waits = [n for n, s in specs.items() if not s.live]
        text = f"{kind}.KEY for KEY in {'|'.join(waits)}"
        if live:
            text += f"; at once: {kind}.KEY for KEY in {'|'.join(live)}"
        parts.append(text)
    return "; ".join(parts)


CONFIG_HELP = (
    "config -module X [-set key=value ...]: show or change a module's configuration. "
    "drivers (refused while a job runs): keys marked 'at once' go to the open device at once (the ToF's "
    "camera settings; with tof.settings_file set they are refused); any other drivers key takes effect when "
    "its device is next re-initialised (reinit, reset, or a continue that re-initialises), and the reply's "
    f"pending= lists those keys until then. Keys: {_drivers_help()}"
)


@command("config", klass=ALWAYS, raw=True, help=CONFIG_HELP)
def config(ctx: Context, cfg: None) -> dict[str, Any]:
    store = ctx.app.config
    module: str | None = None
    sets: list[str] = []
    for name, value in ctx.request.options:
        if name == "module" and isinstance(value, str):
            module = value
        elif name == "set" and isinstance(value, str):
            sets.append(value)
        else:
            raise ProtocolError("E_ARG", f"config takes -module NAME and -set key=value, not -{name.replace('_', '-')}")
    if module is None:
        if sets:
            raise ProtocolError("E_ARG", "config -set needs -module NAME")
        return {"modules": " ".join(store.module_names())}
    name = store.resolve(module)
    if sets:
        if ctx.app.jobs.current is not None and name == "drivers":
            raise ProtocolError("E_BUSY", "drivers cannot change while a job runs")
        current = store.values[name]
        before = dict(vars(current))  # set replaces values (sections too), never edits them in place
        try:
            for item in sets:
                store.set(name, *assignment(item, flag="-set"))
            current.check()  # the rules between keys, on the values all the -set gave together
            if name == "drivers":
                ctx.app.devices.reconfigure()
        except (ProtocolError, ValueError) as exc:
            vars(current).update(before)  # all or nothing: an E_ARG request changes nothing
            if isinstance(exc, ValueError):
                raise ProtocolError("E_ARG", f"{exc}; nothing was changed") from None
            raise
    settings = store.values[name].wire_dict()
    if settings.get("token"):
        settings["token"] = "***"
    # module_name, not name: a module's settings may have a name of their own (dem_full's -name)
    out: dict[str, Any] = {"module_name": name}
    if name == "drivers":
        out["pending"] = ctx.app.devices.pending() or None
    out["settings"] = Group(settings)
    return out


@command("pose", klass=ALWAYS, config=PoseConfig, help="the GNC reports where the rover is (-x -y -heading)")
def pose(ctx: Context, cfg: PoseConfig) -> dict[str, Any]:
    app = ctx.app
    given = {k for k, _ in ctx.request.options}
    if given:
        cur = app.pose
        x = cfg.x if "x" in given else cur.x
        y = cfg.y if "y" in given else cur.y
        heading = cfg.heading if "heading" in given else cur.heading
        heading = (heading + 180.0) % 360.0 - 180.0
        if ("roll" in given) != ("pitch" in given):
            raise ProtocolError("E_ARG", "pose: give -roll and -pitch together (the IMU's attitude), or neither")
        attitude = (cfg.roll, cfg.pitch) if "roll" in given else (None, None)
        app.set_pose(x, y, heading, stopped=cfg.stopped, roll=attitude[0], pitch=attitude[1])
    p = app.pose
    out = {"x": Fixed(p.x, 3), "y": Fixed(p.y, 3), "heading": Fixed(p.heading, 2), "stopped": p.stopped}
    if p.roll is not None and p.pitch is not None:
        out.update(roll=Fixed(p.roll, 2), pitch=Fixed(p.pitch, 2))
    return out


def _auth_wait(server: ServerConfig, failures: int) -> float:
    """Seconds before an auth is answered from an address that sent ``failures`` wrong tokens:
    guessing the token gets slower the longer it goes on, however often the guesser reconnects."""
    if failures == 0:
        return 0.0
    return min(server.auth_delay * 2.0 ** (failures - 1), server.auth_delay_max)


@command("auth", klass=ALWAYS, config=AuthConfig, open=True, help="authenticate this connection with the server's token")
async def auth(ctx: Context, cfg: AuthConfig) -> dict[str, Any]:
    app, conn = ctx.app, ctx.conn
    server = app.server_cfg
    if not server.token:
        conn.authenticated = True
        return {"authenticated": True, "required": False}
    table, address = app.auth_failures, conn.address
    known = table.of(address, server.auth_forget)
    # an address with wrong tokens is answered one auth at a time: parallel connections from it
    # guess no faster than one; only this connection's lines wait, others are served at once
    async with known.turn if known is not None else contextlib.nullcontext():
        known = table.of(address, server.auth_forget)  # what the auths before this one left
        failures = known.failures if known is not None else 0
        wait = _auth_wait(server, failures)
        if wait > 0:
            conn.log.info("auth_delayed", seconds=wait, failures=failures, address=address)
            await asyncio.sleep(wait)
        if not hmac.compare_digest(cfg.token.encode(), server.token.encode()):
            failures = table.failed(address, server.auth_addresses)
            wait = _auth_wait(server, failures)
            conn.log.warning("auth_failed", failures=failures, next_wait=wait, address=address)
            raise ProtocolError("E_AUTH", f"wrong token; check server.token in the server's configuration; the next "
                                f"auth from {address} is answered after {wait:g} s")
        table.clear(address)
    conn.authenticated = True
    return {"authenticated": True}
