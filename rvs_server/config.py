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
import math
import typing
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, ClassVar

import yaml

from .protocol import ProtocolError, valid_stem

DEFAULT_CONFIG_DIR = Path(__file__).resolve().parent.parent / "config"


def param(
    default: Any,
    help: str,
    *,
    unit: str = "",
    min: float | None = None,
    max: float | None = None,
    choices: tuple[str, ...] = (),
    length: int | tuple[int, int] | None = None,
    stem: bool = False,
    option: bool = True,
    required: bool = False,
    protected: bool = False,
) -> Any:
    """Declare a config field with what the command table needs to check and explain it.

    ``option=False`` keeps a parameter out of the request line (set it with ``config -set``);
    ``protected`` refuses run-time changes (host, port, token); ``stem`` marks output names.
    """
    meta = {
        "help": help,
        "unit": unit,
        "min": min,
        "max": max,
        "choices": tuple(choices),
        "length": length,
        "stem": stem,
        "option": option,
        "required": required,
        "protected": protected,
    }
    if isinstance(default, list | dict):
        return field(default_factory=lambda d=default: copy.deepcopy(d), metadata=meta)
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class ParamSpec:
    """What one parameter accepts; built from a dataclass field."""

    name: str
    kind: str  # float, int, str, bool, floats, dict
    help: str
    unit: str
    min: float | None
    max: float | None
    choices: tuple[str, ...]
    length: tuple[int, int] | None
    stem: bool
    option: bool
    required: bool
    protected: bool
    default: Any

    @property
    def flag(self) -> str:
        return "-" + self.name.replace("_", "-")

    def describe(self) -> str:
        """One phrase for help and error messages: type, range, unit, default."""
        if self.choices:
            what = "|".join(self.choices)
        elif self.kind == "floats":
            lo, hi = self.length or (1, 99)
            what = f"{lo} numbers a,b,..." if lo == hi else f"{lo}-{hi} numbers a,b,..."
        elif self.stem:
            what = "file stem"
        else:
            what = {"float": "number", "int": "integer", "bool": "true|false", "str": "text"}.get(self.kind, self.kind)
        if self.min is not None or self.max is not None:
            what += f" in [{_num(self.min)}, {_num(self.max)}]"
        if self.unit:
            what += f" {self.unit}"
        return what

    def parse(self, raw: str | bool) -> Any:
        """Convert and validate one value from a request or a ``-set``; E_ARG names the option."""
        name = self.flag
        if self.kind == "bool":
            if isinstance(raw, bool):
                return raw
            low = raw.lower()
            if low in ("true", "1", "yes", "on"):
                return True
            if low in ("false", "0", "no", "off"):
                return False
            raise ProtocolError("E_ARG", f"{name} takes true or false, not '{raw}'")
        if raw is True:
            raise ProtocolError("E_ARG", f"{name} needs a value: {self.describe()}")
        assert isinstance(raw, str)
        if self.kind == "floats":
            parts = [p for p in raw.split(",")] if raw else []
            try:
                values = [float(p) for p in parts]
            except ValueError:
                raise ProtocolError("E_ARG", f"{name} takes {self.describe()}, not '{raw[:40]}'") from None
            lo, hi = self.length or (1, 99)
            if not lo <= len(values) <= hi or not all(math.isfinite(v) for v in values):
                raise ProtocolError("E_ARG", f"{name} takes {self.describe()}, not '{raw[:40]}'")
            for v in values:
                self._check_range(v)
            return values
        if self.kind == "float":
            try:
                value = float(raw)
            except ValueError:
                raise ProtocolError("E_ARG", f"{name} takes a {self.describe()}, not '{raw[:40]}'") from None
            if not math.isfinite(value):
                raise ProtocolError("E_ARG", f"{name} must be a finite {self.describe()}")
            self._check_range(value)
            return value
        if self.kind == "int":
            try:
                value = int(raw, 10)
            except ValueError:
                raise ProtocolError("E_ARG", f"{name} takes an {self.describe()}, not '{raw[:40]}'") from None
            self._check_range(value)
            return value
        if self.choices:
            low = raw.lower()
            if low not in self.choices:
                raise ProtocolError("E_ARG", f"{name} takes {'|'.join(self.choices)}, not '{raw[:40]}'")
            return low
        if self.stem and not valid_stem(raw):
            raise ProtocolError(
                "E_ARG",
                f"{name} must be a file stem of 1-64 letters, digits, '_', '.', '-' not starting with '.'",
            )
        return raw

    def _check_range(self, value: float) -> None:
        if (self.min is not None and value < self.min) or (self.max is not None and value > self.max):
            raise ProtocolError(
                "E_ARG", f"{self.flag} is {_num(value)}, out of range [{_num(self.min)}, {_num(self.max)}]"
                + (f" {self.unit}" if self.unit else "")
            )


def _num(v: float | None) -> str:
    if v is None:
        return "..."
    if isinstance(v, int):  # any size: "-integrate 999...9" must be E_ARG, not an OverflowError
        text = str(v)
        return text if len(text) <= 16 else f"{text[:4]}...({len(text)} digits)"
    return str(int(v)) if v.is_integer() and abs(v) < 1e15 else format(v, "g")


_KIND = {float: "float", int: "int", str: "str", bool: "bool"}


@dataclass
class ModuleConfig:
    """Base of every module's config class; ``module`` names its YAML file and ``config -module``."""

    module: ClassVar[str] = ""

    @classmethod
    def specs(cls) -> dict[str, ParamSpec]:
        cached = cls.__dict__.get("_specs")
        if cached is not None:
            return cached
        hints = typing.get_type_hints(cls)
        out: dict[str, ParamSpec] = {}
        for f in fields(cls):
            meta = f.metadata
            hint = hints[f.name]
            origin = typing.get_origin(hint)
            if origin is list:
                kind = "floats"
            elif origin is dict or hint is dict:
                kind = "dict"
            else:
                kind = _KIND.get(hint, "str")
            default = f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore[misc]
            length = meta.get("length")
            if isinstance(length, int):
                length = (length, length)
            out[f.name] = ParamSpec(
                name=f.name,
                kind=kind,
                help=meta.get("help", ""),
                unit=meta.get("unit", ""),
                min=meta.get("min"),
                max=meta.get("max"),
                choices=meta.get("choices", ()),
                length=length,
                stem=meta.get("stem", False),
                option=meta.get("option", True) and kind != "dict",
                required=meta.get("required", False),
                protected=meta.get("protected", False),
                default=default,
            )
        cls._specs = out  # type: ignore[attr-defined]
        return out

    def as_dict(self) -> dict[str, Any]:
        return {f.name: copy.deepcopy(getattr(self, f.name)) for f in fields(self)}


def _coerce_yaml(spec: ParamSpec, value: Any, where: str) -> Any:
    """YAML already gives typed values; check them with the same rules as the wire."""
    if spec.kind == "dict":
        if not isinstance(value, dict):
            raise ValueError(f"{where}: {spec.name} must be a mapping")
        return value
    if spec.kind == "floats" and isinstance(value, list):
        value = ",".join(str(v) for v in value)
    elif isinstance(value, bool) and spec.kind != "bool":
        raise ValueError(f"{where}: {spec.name} must be {spec.describe()}")
    elif not isinstance(value, str | bool):
        value = str(value)
    try:
        return spec.parse(value)
    except ProtocolError as exc:
        raise ValueError(f"{where}: {exc.message}") from None


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
            node[key] = int(raw)
        elif isinstance(old, float):
            node[key] = float(raw)
        elif isinstance(old, list):
            node[key] = yaml.safe_load(f"[{raw}]")
        elif old is None:
            node[key] = yaml.safe_load(raw)
        else:
            node[key] = raw
    except ValueError:
        raise ProtocolError("E_ARG", f"{where}: '{raw}' is not a {type(old).__name__}") from None


class ConfigStore:
    """The effective configuration of every registered module, shared by all connections.

    Loading order: the built-in ``config/`` folder, then an optional ``--config DIR`` overlay,
    then ``--set`` overrides. Run-time ``config -set`` goes through the same validation.
    """

    def __init__(self, classes: list[type[ModuleConfig]], config_dir: Path | None = None) -> None:
        self.classes = {c.module: c for c in classes}
        self.values: dict[str, ModuleConfig] = {}
        dirs = [DEFAULT_CONFIG_DIR] + ([Path(config_dir)] if config_dir else [])
        for name, cls in self.classes.items():
            data: dict[str, Any] = {}
            for d in dirs:
                path = d / f"{name}.yaml"
                if path.is_file():
                    loaded = yaml.safe_load(path.read_text()) or {}
                    if not isinstance(loaded, dict):
                        raise ValueError(f"{path}: expected a mapping of key: value")
                    _merge(data, loaded)
            self.values[name] = self._build(cls, data, f"config/{name}.yaml")

    @staticmethod
    def _build(cls: type[ModuleConfig], data: dict[str, Any], where: str) -> ModuleConfig:
        specs = cls.specs()
        kwargs: dict[str, Any] = {}
        for key, value in data.items():
            if key not in specs:
                raise ValueError(f"{where}: unknown key '{key}'; known: {', '.join(specs)}")
            if specs[key].kind == "dict":
                merged = copy.deepcopy(specs[key].default)
                _merge(merged, value)
                kwargs[key] = merged
            else:
                kwargs[key] = _coerce_yaml(specs[key], value, where)
        return cls(**kwargs)

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

    def set(self, module: str, key: str, raw: str, *, runtime: bool = True) -> None:
        """Change one value (``key`` may be dotted for nested sections) with the wire's validation."""
        name = self.resolve(module)
        cfg = self.values[name]
        specs = type(cfg).specs()
        path = key.replace("-", "_").split(".")
        spec = specs.get(path[0])
        if spec is None:
            raise ProtocolError("E_ARG", f"{name} has no key '{key}'; keys: {', '.join(specs)}")
        if runtime and spec.protected:
            raise ProtocolError("E_ARG", f"{name}.{spec.name} is protected; set it when starting the server")
        if spec.kind == "dict":
            if len(path) < 2:
                raise ProtocolError("E_ARG", f"{name}.{spec.name} is a section; set one of its keys ({name}.{spec.name}.KEY)")
            section = copy.deepcopy(getattr(cfg, spec.name))
            _set_nested(section, path[1:], raw, f"{name}.{key}")
            setattr(cfg, spec.name, section)
            return
        if len(path) > 1:
            raise ProtocolError("E_ARG", f"{name}.{spec.name} has no sub-keys")
        setattr(cfg, spec.name, spec.parse(raw))

    def apply_overrides(self, items: list[str]) -> None:
        """``--set module.key=value`` at server start; errors are fatal there, so raise ValueError."""
        for item in items:
            target, sep, raw = item.partition("=")
            module, dot, key = target.partition(".")
            if not sep or not dot or not key:
                raise ValueError(f"--set {item!r}: write module.key=value")
            try:
                self.set(module, key, raw, runtime=False)
            except ProtocolError as exc:
                raise ValueError(f"--set {item!r}: {exc.message}") from None


def _merge(base: dict[str, Any], over: dict[str, Any]) -> None:
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(base.get(key), dict):
            _merge(base[key], value)
        else:
            base[key] = copy.deepcopy(value)


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
    max_clients: int = param(32, "connections served at once", min=1, max=10000)
    max_line: int = param(4096, "longest request line", unit="bytes", min=64, max=1048576, protected=True)
    log_level: str = param("info", "console and file log level", choices=("debug", "info", "warning", "error"))
    log_file: str = param("rvs.log", "log file, relative to the data directory", protected=True)
    shared_dir: str = param("shared", "where logbook copies go, relative to the data directory", protected=True)
    warm_up: bool = param(True, "compile or load the numba kernels (DemImport, A*) in the background at start")
    web_port: int = param(7071, "operator web console port, on the same host (0: no console)", min=0, max=65535,
                          protected=True)
    web_public: bool = param(False, "serve the console on a non-loopback host even without a token (anyone who "
                             "reaches the port can drive the rover)", protected=True)


@standalone
@dataclass
class DriversConfig(ModuleConfig):
    """config/drivers.yaml: one section per device; ``backend`` picks sim or the real driver."""

    module: ClassVar[str] = "drivers"
    ptu: dict = param({}, "pan-tilt unit (PTU-D46 over RS232)")
    tof: dict = param({}, "SwissRanger SR4000 time-of-flight camera (USB)")
    stereo: dict = param({}, "PIKE F-210B stereo pair (FireWire)")
    trigger: dict = param({}, "LPT trigger box")


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
