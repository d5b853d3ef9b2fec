"""The command table: every command declared as data next to its one handler function.

As in Redis's command table, the declaration (name, module id, job or immediate, mode rules,
config class) is what help, the E_ARG checks, the mode checks and the dispatcher read; handlers
never re-check their own arguments.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from .config import ModuleConfig, ParamSpec, SettingError
from .protocol import ProtocolError, Request

if TYPE_CHECKING:
    from .app import App

# What may run in which mode. "always": help, status and the like, answered even while a job
# runs; "control": the change-of-mode commands; "hardware": hardware and map commands, refused
# in standby, sleep, break and fault.
ALWAYS, CONTROL, HARDWARE, PLAIN = "always", "control", "hardware", "plain"


@dataclass(frozen=True)
class Command:
    name: str
    module: str
    handler: Callable[..., Any]
    config: type[ModuleConfig] | None
    job: bool
    klass: str
    help: str
    positional: tuple[str, ...] = ()  # accepted bare words, e.g. ("command",) for help
    open: bool = False  # answered before auth (help, version, auth)
    raw: bool = False  # the handler reads the Request itself (config, sim)
    sim_only: bool = False
    # check(app, cfg) runs on the event loop before a job's ACK: every refusal that needs no
    # hardware I/O (the PTU's limits read at open, a sim-only option) is an ERROR, never an ACK
    check: Callable[[App, Any], None] | None = None
    # ranges(app) -> {option: (min, max)}: ranges only the device knows (the PTU's limits, read
    # when it opens), which help shows instead of the declared ones; the check refuses beyond them
    ranges: Callable[[App], dict[str, tuple[float, float]]] | None = None

    def describe(self, spec: ParamSpec, app: App | None = None) -> str:
        """An option's phrase for help: as declared, but with the range the device reports where
        there is one, so help states the limits the E_ARG check applies, not a guess."""
        span = self.ranges(app).get(spec.name) if self.ranges is not None and app is not None else None
        if span is not None:
            spec = dataclasses.replace(spec, min=span[0], max=span[1])
        return spec.describe()

    def usage(self) -> str:
        parts = [self.name] + [f"[{p}]" for p in self.positional]
        if self.config is not None and not self.raw:
            for spec in self.config.keys().values():
                if spec.option:
                    item = f"{spec.flag} {spec.describe().split(' in [')[0]}"
                    parts.append(item if spec.required else f"[{item}]")
        return " ".join(parts)


COMMANDS: dict[str, Command] = {}
ALIASES: dict[str, str] = {}  # other names a command answers to (bye -> exit); help lists the command


def command(
    name: str,
    *,
    job: bool = False,
    klass: str = PLAIN,
    config: type[ModuleConfig] | None = None,
    help: str,
    positional: tuple[str, ...] = (),
    open: bool = False,
    raw: bool = False,
    sim_only: bool = False,
    module: str | None = None,
    check: Callable[[App, Any], None] | None = None,
    aliases: tuple[str, ...] = (),
    ranges: Callable[[App], dict[str, tuple[float, float]]] | None = None,
) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Register a handler; a job handler runs in a worker thread as ``handler(job, cfg)``."""

    def register(fn: Callable[..., Any]) -> Callable[..., Any]:
        mod = module or "EGP-RVS-" + name.upper()
        cmd = Command(name, mod, fn, config, job, klass, help, positional, open, raw, sim_only, check, ranges)
        COMMANDS[name] = cmd
        ALIASES.update(dict.fromkeys(aliases, name))
        return fn

    return register


def lookup(name: str) -> Command | None:
    """Command names and module ids are both accepted, case-insensitively."""
    name = name.lower()
    if name.startswith("egp-rvs-"):
        name = name[len("egp-rvs-") :]
    return COMMANDS.get(ALIASES.get(name, name))


def bind_options(cmd: Command, base: ModuleConfig | None, req: Request) -> ModuleConfig | None:
    """The request's options over a copy of the module's effective config, checked per option."""
    if cmd.raw:
        return copy.deepcopy(base) if base is not None else None
    if base is None:
        if req.options:
            name = req.options[0][0].replace("_", "-")
            raise ProtocolError("E_ARG", f"{cmd.name} takes no options (got -{name}); see help {cmd.name}")
        return None
    return apply_options(cmd.name, base, req.options)


def apply_options(name: str, base: ModuleConfig, options: list[tuple[str, str | bool]]) -> ModuleConfig:
    """Options over a copy of ``base``; unknown, repeated, mistyped and missing ones are E_ARG."""
    cfg = copy.deepcopy(base)
    specs = cfg.keys()
    seen: set[str] = set()
    for opt, raw in options:
        spec = specs.get(opt) or next((s for s in specs.values() if s.key == opt), None)  # -global: global_
        if spec is None or not spec.option:
            accepted = " ".join(s.flag for s in specs.values() if s.option) or "none"
            raise ProtocolError(
                "E_ARG", f"unknown option -{opt.replace('_', '-')} for {name}; options: {accepted}"
            )
        if spec.name in seen:
            raise ProtocolError("E_ARG", f"option {spec.flag} given twice")
        seen.add(spec.name)
        try:
            cfg.assign(spec, spec.parse(raw))
        except SettingError as exc:
            raise ProtocolError("E_ARG", exc.message) from None
    for spec in specs.values():
        if spec.required and spec.name not in seen:
            raise ProtocolError("E_ARG", f"{name} needs {spec.flag} ({spec.describe()})")
    try:
        cfg.check()
    except SettingError as exc:
        raise ProtocolError("E_ARG", exc.message) from None
    return cfg


def check_positional(cmd: Command, req: Request) -> None:
    if len(req.positional) > len(cmd.positional):
        extra = req.positional[len(cmd.positional)]
        if cmd.positional:
            raise ProtocolError("E_ARG", f"{cmd.name} takes {' '.join(cmd.positional)}, not '{extra[:40]}'")
        raise ProtocolError(
            "E_ARG", f"{cmd.name} takes options like -name value, not the bare word '{extra[:40]}'"
        )
