"""Command line of ``rvs-server``: configuration, logging, the simulated world, the event loop."""

from __future__ import annotations

import argparse
import asyncio
import errno
import logging
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from drivers.sim.scene import SCENES_DIR, scene_path
from rvs_params.cli import ToolParser

from . import commands as _commands  # noqa: F401 - fills the command table
from .app import App
from .config import STANDALONE, ConfigStore, ModuleConfig
from .heap import bound_malloc_arenas
from .logs import setup as setup_logging
from .server import listen, serve
from .table import COMMANDS
from .web.address import console_host


def config_classes() -> list[type[ModuleConfig]]:
    classes: dict[str, type[ModuleConfig]] = dict(STANDALONE)
    for cmd in COMMANDS.values():
        if cmd.config is not None:
            classes.setdefault(cmd.config.module, cmd.config)
    return list(classes.values())


def build_config(config_dir: str | None = None, overrides: list[str] | None = None) -> ConfigStore:
    store = ConfigStore(config_classes(), Path(config_dir) if config_dir else None)
    store.apply_overrides(overrides or [])
    return store


def make_world(store: ConfigStore) -> Any:
    """The simulated world, when any device is simulated (sim commands exist only then)."""
    drivers = store.get("drivers")
    if not any(section.backend == "sim" for section in vars(drivers).values()):
        return None
    try:
        from drivers.sim.world import World
    except ImportError:
        return None
    # The clock reads sim.time_scale each time, so config -module sim -set time_scale=... applies live.
    return World.from_scene(store.get("server").scene, clock_scale=lambda: store.get("sim").time_scale)


def make_app(store: ConfigStore, loop: asyncio.AbstractEventLoop) -> App:
    server = store.get("server")
    return App(store, data_dir=Path(server.data), world=make_world(store), loop=loop)


class StartupError(Exception):
    """The server cannot start (port taken, unknown scene...): said once, exit status 1."""


def check_scripts() -> None:
    """Every command's workflow script is validated before the server serves: a misspelled step
    or input stops the start with the line and the fix, instead of an E_INTERNAL after a sweep."""
    from prox_workflows.engine import WorkflowError

    from .commands import dem, navigation

    try:
        dem.validate_scripts()
        navigation.validate_scripts()
    except WorkflowError as exc:
        raise StartupError(f"a command's workflow script is broken, not serving: {exc}") from exc


async def run(store: ConfigStore, *, ready: Callable[[int], None] | None = None, handle_signals: bool = True,
              on_app: Callable[[App], None] | None = None, recover: str | None = None) -> int:
    check_scripts()
    try:
        app = make_app(store, asyncio.get_running_loop())
    except (OSError, ValueError, KeyError) as exc:
        raise StartupError(f"cannot set up: {exc}") from exc
    if recover is not None:
        from .maps import load_recovery
        from .protocol import ProtocolError

        try:
            load_recovery(app, recover)
        except ProtocolError as exc:
            raise StartupError(f"--recover {recover}: {exc.message}") from exc
    if on_app is not None:
        on_app(app)
    server = store.get("server")
    try:
        sock = listen(server.host, server.port)
    except OSError as exc:
        raise StartupError(f"cannot listen on {server.host}:{server.port}: {exc}") from exc
    web_sock, console_off = None, "server.web_port is 0"
    if server.web_port:
        host = console_host(server.host, server.token, server.web_public)
        try:
            web_sock = listen(host, server.web_port)
            console_off = None
        except OSError as exc:
            # The console is the operator's window, the TCP port the GNC's: a console port taken
            # (by another server on this machine) costs the console, never the server.
            why = ("is in use (another server on this machine?)" if exc.errno == errno.EADDRINUSE
                   else f"cannot be bound ({exc.strerror or exc})")
            console_off = f"web console port {host}:{server.web_port} {why}; start with --web-port N for a console"
    return await serve(app, sock, ready=ready, handle_signals=handle_signals, web_sock=web_sock,
                       console_off=console_off)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = ToolParser(
        prog="rvs-server",
        description="Rover vision system server (simulated hardware unless config/drivers.yaml says otherwise): "
                    "the RVS protocol on a TCP port, and an operator web console (map, jobs, commands) at "
                    "http://HOST:7071/ (--web-port), and a Foxglove live view at ws://HOST:8765 (--foxglove-port). "
                    "A console or Foxglove port already taken (another server on this machine) only turns that "
                    "view off; the log and status say so.",
    )
    p.add_argument("--host", help="listen address (default 127.0.0.1)")
    p.add_argument("--port", type=int, help="listen port (default 7070; 0 picks a free one)")
    p.add_argument("--web-port", type=int, metavar="N",
                   help="operator web console port, on the same host (default 7071; 0: no console)")
    p.add_argument("--foxglove-port", type=int, metavar="N",
                   help="Foxglove WebSocket port for a read-only live view in Foxglove Studio, on the same host "
                        "(default 8765; 0: off)")
    p.add_argument("--data", help="data directory (default ./data)")
    p.add_argument("--scene", help=f"simulated scene: {', '.join(sorted(q.stem for q in SCENES_DIR.glob('*.yaml')))}, "
                                   "or a scene .yaml path (default office)")
    p.add_argument("--config", help="folder of YAML files overriding config/")
    p.add_argument("--set", action="append", default=[], metavar="MODULE.KEY=VALUE",
                   help="override one configuration value (repeatable)")
    p.add_argument("--recover", nargs="?", const="last", metavar="SET",
                   help="load a recovery set written by break (default: the last one) before serving")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    overrides = list(args.set)
    for key in ("host", "port", "data", "scene", "web_port", "foxglove_port"):
        value = getattr(args, key)
        if value is not None:
            overrides.append(f"server.{key}={value}")
    try:
        store = build_config(args.config, overrides)
        # a misspelt scene is a usage error like a bad --set: said before anything starts, exit 2
        scene_path(store.get("server").scene)
    except (ValueError, OSError) as exc:
        print(f"rvs-server: {exc}", file=sys.stderr)
        return 2
    server = store.get("server")
    data = Path(server.data)
    setup_logging(server.log_level, data / server.log_file)
    bound_malloc_arenas(server.malloc_arenas)
    try:
        status = asyncio.run(run(store, recover=args.recover))
    except StartupError as exc:
        print(f"rvs-server: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:  # Ctrl-C before the signal handlers are in place
        print("rvs-server: interrupted while starting", file=sys.stderr)
        return 130
    # The server has shut down cleanly (jobs ended, recording finished, devices closed, the log
    # flushed below): end the process without finalising the interpreter. That teardown frees the
    # whole heap object by object (the scene, the maps, the compiled kernels): 1-2 s after Ctrl-C
    # on a loaded machine, for nothing. And a compile cannot be stopped: finalising under a
    # warm-up thread inside LLVM may crash it.
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)
