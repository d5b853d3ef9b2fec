"""Per-module configuration classes (one per command module, as in the thesis).

A config class is a dataclass whose fields are the module's parameters. Fields declared with
:func:`param` carry their unit, range and help, so that the command's options, its help text
and every E_ARG check come from this one declaration (Redis-style command table as data).
Defaults come from ``config/<module>.yaml``, then ``rvs-server --set module.key=value``, then
``config -module X -set key=value`` at run time, then the request's own options.
"""

from __future__ import annotations

import copy
import dataclasses
import importlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import yaml

from drivers.registry import DEVICE_KINDS, registry
from rvs_params import (
    INTEGER_FORM,
    NUMBER_FORM,
    ParamSpec,
    SettingError,
    Settings,
    assignment,
    load_wire_yaml,
    merge,
    param,
    parse_integer,
    parse_number,
    wire_key,
)

from .protocol import ProtocolError

__all__ = ["ConfigStore", "ModuleConfig", "ParamSpec", "SettingError", "merge", "param", "standalone"]

DEFAULT_CONFIG_DIR = Path(__file__).resolve().parent.parent / "config"


@dataclass
class ModuleConfig(Settings):
    """Base of every module's config class; ``module`` names its YAML file and ``config -module``.

    A command whose parameters a workflow script also receives derives from the script's
    parameter class (``prox_workflows.parameters``) and this, so they are declared once.
    """

    module: ClassVar[str] = ""


def _set_in(cfg: Settings, path: list[str], raw: str, where: str, *, runtime: bool,
            named: str | None = None) -> None:
    """Set ``path`` (``key`` or ``section.key``) in ``cfg`` with the wire's validation; a bad value's
    error calls it ``named`` (the server's ``--set navigate.tolerance``), by default its option.

    A nested settings section is replaced by a changed copy, never edited in place, so whoever
    holds the old object (a device built from it) keeps what it was built with.
    """
    specs = type(cfg).specs()
    spec = specs.get(path[0])
    lent = type(cfg).keys().get(path[0]) if spec is None else None
    if lent is not None:  # a key a flat section lends: set it in the section
        _set_in(cfg, [*lent.path, *path[1:]], raw, where, runtime=runtime, named=named)
        return
    if spec is None:  # a key as the wire names it (global for the field global_)
        spec = next((s for s in specs.values() if s.key == path[0]), None)
    if spec is None:
        raise ProtocolError("E_ARG", f"{where} has no key '{path[0]}'; keys: {', '.join(type(cfg).keys())}")
    if spec.required:
        raise ProtocolError("E_ARG", f"{where}.{spec.key} is given with each request ({spec.flag}); "
                                     "it has no default to set")
    if runtime and spec.protected:
        raise ProtocolError("E_ARG", f"{where}.{spec.name} is protected; set it when starting the server")
    if spec.kind == "section":
        if len(path) < 2:
            raise ProtocolError("E_ARG", f"{where}.{spec.name} is a section; set one of its keys "
                                         f"({where}.{spec.name}.KEY for KEY in {', '.join(spec.section.specs())})")
        section = copy.deepcopy(vars(cfg)[spec.name])
        _set_in(section, path[1:], raw, f"{where}.{spec.name}", runtime=runtime, named=named)
        setattr(cfg, spec.name, section)
        return
    if spec.kind == "dict":
        if len(path) < 2:
            raise ProtocolError("E_ARG", f"{where}.{spec.name} is a section; set one of its keys ({where}.{spec.name}.KEY)")
        nested = copy.deepcopy(vars(cfg)[spec.name])
        _set_nested(nested, path[1:], raw, f"{where}.{'.'.join(path)}")
        setattr(cfg, spec.name, nested)
        return
    if len(path) > 1:
        raise ProtocolError("E_ARG", f"{where}.{spec.name} has no sub-keys")
    try:
        setattr(cfg, spec.name, spec.parse(raw, named))
    except SettingError as exc:
        raise ProtocolError("E_ARG", exc.message) from None


def _set_nested(target: dict[str, Any], path: list[str], raw: str, where: str) -> None:
    """Set a nested key (drivers.ptu.backend) keeping the existing value's type."""
    node = target
    for key in path[:-1]:
        if not isinstance(node.get(key), dict):
            raise ProtocolError("E_ARG", f"{where}: no section '{key}'")
        node = node[key]
    key = path[-1]
    if key not in node:
        raise ProtocolError("E_ARG", f"{where}: unknown key '{key}'; known: {', '.join(sorted(node))}")
    old = node[key]
    try:
        if isinstance(old, bool):
            low = raw.lower()
            if low not in ("true", "false", "1", "0", "yes", "no", "on", "off"):
                raise ValueError
            node[key] = low in ("true", "1", "yes", "on")
        elif isinstance(old, int):
            node[key] = parse_integer(raw)
        elif isinstance(old, float):
            node[key] = parse_number(raw, NUMBER_FORM)
        elif isinstance(old, list):
            node[key] = load_wire_yaml(f"[{raw}]")
        elif old is None:
            node[key] = load_wire_yaml(raw)
        else:
            node[key] = raw
    except ValueError as exc:
        if "is not a number" in str(exc):
            raise ProtocolError("E_ARG", f"{where}: {exc}") from None
        form = f" (write it in {INTEGER_FORM if type(old) is int else NUMBER_FORM})" if type(old) in (int, float) else ""
        raise ProtocolError("E_ARG", f"{where}: '{raw}' is not a {type(old).__name__}{form}") from None


class ConfigStore:
    """The effective configuration of every registered module, shared by all connections.

    Loading order: the built-in ``config/`` folder, then an optional ``--config DIR`` overlay,
    then ``--set`` overrides. Run-time ``config -set`` goes through the same validation.
    """

    def __init__(self, classes: list[type[ModuleConfig]], config_dir: Path | None = None) -> None:
        self.classes = {c.module: c for c in classes}
        self.values: dict[str, ModuleConfig] = {}
        if config_dir is not None and not Path(config_dir).is_dir():
            # a mistyped folder would otherwise start the server on the built-in defaults, silently
            raise ValueError(f"--config {config_dir}: no such folder (want a folder of <module>.yaml files "
                             "overriding config/)")
        dirs = [DEFAULT_CONFIG_DIR] + ([Path(config_dir)] if config_dir else [])
        for name, cls in self.classes.items():
            data: dict[str, Any] = {}
            sources = []
            for d in dirs:
                path = d / f"{name}.yaml"
                if path.is_file():
                    try:
                        loaded = yaml.safe_load(path.read_text()) or {}
                    except yaml.YAMLError as exc:
                        mark = getattr(exc, "problem_mark", None)
                        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
                        raise ValueError(f"{path}: not valid YAML: {getattr(exc, 'problem', None) or exc}"
                                         f"{where}") from None
                    except OSError as exc:
                        raise ValueError(f"{path}: cannot read it: {exc.strerror or exc}") from None
                    if not isinstance(loaded, dict):
                        raise ValueError(f"{path}: expected a mapping of key: value")
                    merge(data, loaded)
                    sources.append(f"config/{name}.yaml" if d == DEFAULT_CONFIG_DIR else str(path))
            self.values[name] = self._build(cls, data, " over ".join(reversed(sources)) or f"config/{name}.yaml")

    @staticmethod
    def _build(cls: type[ModuleConfig], data: dict[str, Any], where: str) -> ModuleConfig:
        return cls.from_mapping(data, where=where)

    def module_names(self) -> list[str]:
        return sorted(self.classes)

    def resolve(self, module: str) -> str:
        """Accept ``grab-tof``, ``grab_tof`` or ``EGP-RVS-GRAB-TOF``."""
        name = module.lower()
        if name.startswith("egp-rvs-"):
            name = name[len("egp-rvs-") :]
        name = name.replace("-", "_")
        if name not in self.classes:
            raise ProtocolError(
                "E_ARG", f"-module '{module}' has no configuration; modules: {', '.join(self.module_names())}"
            )
        return name

    def get(self, module: str) -> Any:
        return self.values[self.resolve(module)]

    def set(self, module: str, key: str, raw: str, *, runtime: bool = True, named: str | None = None) -> None:
        """Change one value (``key`` may be dotted for nested sections) with the wire's validation;
        ``named``: what a bad value's error calls it (default: its option, as on the wire)."""
        name = self.resolve(module)
        _set_in(self.values[name], key.replace("-", "_").split("."), raw, name, runtime=runtime, named=named)

    def apply_overrides(self, items: list[str]) -> None:
        """``--set module.key=value`` at server start; errors are fatal there, so raise ValueError."""
        for item in items:
            module, dot, rest = item.partition(".")
            if not dot or "=" in module:
                raise ValueError(f"--set '{item[:40]}': write module.key=value")
            key, raw = assignment(rest, form="module.key=value")
            if module.lower().replace("-", "_") not in self.classes:
                raise ValueError(f"--set {item!r}: no module '{module}'; modules: {', '.join(self.module_names())}")
            # a bad value is named as this command line types it, not as the wire's option
            named = f"--set {module}.{rest.partition('=')[0].strip()}"
            try:
                self.set(module, key, raw, runtime=False, named=named)
            except ProtocolError as exc:
                raise ValueError(exc.message if exc.message.startswith(named) else f"--set {item!r}: {exc.message}") from None
        for name, values in self.values.items():
            try:
                values.check(wire_key)
            except SettingError as exc:
                raise ValueError(f"--set {name}: {exc.message}") from None


# ------------------------------------------------------------------------------------------
# the server's own modules (not commands)

STANDALONE: dict[str, type[ModuleConfig]] = {}


def standalone(cls: type[ModuleConfig]) -> type[ModuleConfig]:
    """Register a config module that belongs to no single command (server, drivers, head...)."""
    STANDALONE[cls.module] = cls
    return cls


@standalone
@dataclass
class ServerConfig(ModuleConfig):
    """config/server.yaml: where the server listens and keeps its data."""

    module: ClassVar[str] = "server"
    host: str = param("127.0.0.1", "listen address (loopback by default)", protected=True)
    port: int = param(7070, "listen port, 0 picks a free one", min=0, max=65535, protected=True)
    name: str = param("rvs", "server name in the hello line")
    data: str = param("data", "data directory", protected=True)
    scene: str = param("office", "simulated world scene (config/scenes/<scene>.yaml)")
    token: str = param("", "if set, clients must send auth -token first", protected=True)
    auth_delay: float = param(0.5, "after a wrong token, the next auth from that client address is answered this "
                              "late, doubling with each further wrong token", unit="s", min=0.0, max=60.0, protected=True)
    auth_delay_max: float = param(8.0, "longest wait before an auth answer to an address with wrong tokens",
                                  unit="s", min=0.0, max=600.0, protected=True)
    auth_forget: float = param(900.0, "an address's wrong tokens are forgotten after this long without another",
                               unit="s", min=0.1, max=86400.0, protected=True)
    auth_addresses: int = param(1024, "client addresses whose wrong tokens are remembered (the one quiet longest "
                                "is forgotten first)", min=1, max=1000000, protected=True)
    max_clients: int = param(32, "connections served at once", min=1, max=10000)
    max_line: int = param(4096, "longest request line", unit="bytes", min=64, max=1048576, protected=True)
    log_level: str = param("info", "console and file log level", choices=("debug", "info", "warning", "error"))
    log_file: str = param("rvs.log", "log file, relative to the data directory", protected=True)
    shared_dir: str = param("shared", "where logbook copies go, relative to the data directory", protected=True)
    warm_up: bool = param(True, "compile or load the numba kernels (DemImport, A*) in the background at start")
    malloc_arenas: int = param(2, "glibc malloc arenas the rvs-server process's threads share (0: glibc's default, 8 a core); each "
                               "arena keeps what its threads freed, so with one a thread the resident size climbs "
                               "in steps as job threads take turns at the renders", min=0, max=1024, protected=True)
    web_port: int = param(7071, "operator web console port, on the same host (0: no console)", min=0, max=65535,
                          protected=True)
    web_public: bool = param(False, "serve the console on a non-loopback host even without a token (anyone who "
                             "reaches the port can drive the rover)", protected=True)
    foxglove_port: int = param(8765, "Foxglove WebSocket port (read-only live view), on the console's host (0: off)",
                               min=0, max=65535, protected=True)
    record: bool = param(False, "record the whole run from start to recordings/rvs_<UTC time>.mcap under the data "
                         "directory (record -start/-stop for one part of it)", protected=True)


def _drivers_config() -> type[ModuleConfig]:
    """config/drivers.yaml: one section per device kind (drivers.registry.DEVICE_KINDS), each typed
    by the settings its front end and its registered backends declare; ``backend`` picks one."""
    sections = []
    for kind in DEVICE_KINDS:
        reg = registry(kind)
        title = (importlib.import_module(f"drivers.{kind}").__doc__ or kind).strip().splitlines()[0]
        sections.append((kind, reg.settings_class(), dataclasses.field(
            default_factory=reg.settings_class(), metadata={"help": title})))
    cls = dataclasses.make_dataclass("DriversConfig", sections, bases=(ModuleConfig,), namespace={"module": "drivers"})
    cls.__doc__ = _drivers_config.__doc__
    cls.__module__ = __name__
    return cls


DriversConfig = standalone(_drivers_config())


@standalone
@dataclass
class HeadConfig(ModuleConfig):
    """config/head.yaml: the sensor head's mount calibration and the rover body, as the server
    believes them (the simulator has its own truth; calibration corrects this file)."""

    module: ClassVar[str] = "head"
    ptu_base: list[float] = param([0.10, 0.0, 1.20], "pan axis foot in the rover frame", unit="m", length=3)
    tilt_offset: float = param(0.06, "tilt axis above the pan base", unit="m", min=0.0, max=2.0)
    mounts: dict = param({}, "per sensor: xyz (optical centre in the tilt frame, m) and rpy (deg)")
    rover_length: float = param(0.51, "rover body length (masked out of its own scans)", unit="m", min=0.0, max=10.0)
    rover_width: float = param(0.40, "rover body width", unit="m", min=0.0, max=10.0)
    rover_margin: float = param(0.10, "extra margin around the body when masking", unit="m", min=0.0, max=2.0)
