"""Parameters declared once: the ``param()`` fields of a parameter class, with unit, range and help.

A parameter class (a dataclass of :func:`param` fields) is the one declaration of a workflow's
parameters and their defaults: a script names its class (``params: dem``) and receives the
values as ``$cell`` etc.; ``rvs-prox SCRIPT --help`` lists the class; the server's per-command
config classes (``rvs_server/commands/*.py``) derive from it, so ``help dem-full-tof`` lists the
same parameters with the same defaults, and its E_ARG checks are the same ``ParamSpec.parse``.

It lives here, not in ``rvs_server``, because imports go one way: the server uses
``prox_workflows``, never the reverse, and ``rvs-prox`` needs the declarations without a server.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import re
import typing
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar

STEM_RE = re.compile(r"[A-Za-z0-9_\-][A-Za-z0-9_.\-]{0,63}")


def valid_stem(name: str) -> bool:
    """Output names are file stems confined to the data directory (PROTOCOL.md)."""
    return bool(STEM_RE.fullmatch(name)) and not name.startswith(".") and ".." not in name


class ParamError(ValueError):
    """A parameter value of the wrong type or out of range; the message names the option."""

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message


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
    error: Callable[[str], Exception] = field(default=ParamError, compare=False, repr=False)

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
            raise self.error(f"{name} takes true or false, not '{raw}'")
        if raw is True:
            raise self.error(f"{name} needs a value: {self.describe()}")
        assert isinstance(raw, str)
        if self.kind == "floats":
            parts = [p for p in raw.split(",")] if raw else []
            try:
                values = [float(p) for p in parts]
            except ValueError:
                raise self.error(f"{name} takes {self.describe()}, not '{raw[:40]}'") from None
            lo, hi = self.length or (1, 99)
            if not lo <= len(values) <= hi or not all(math.isfinite(v) for v in values):
                raise self.error(f"{name} takes {self.describe()}, not '{raw[:40]}'")
            for v in values:
                self._check_range(v)
            return values
        if self.kind == "float":
            try:
                value = float(raw)
            except ValueError:
                raise self.error(f"{name} takes a {self.describe()}, not '{raw[:40]}'") from None
            if not math.isfinite(value):
                raise self.error(f"{name} must be a finite {self.describe()}")
            self._check_range(value)
            return value
        if self.kind == "int":
            try:
                value = int(raw, 10)
            except ValueError:
                raise self.error(f"{name} takes an {self.describe()}, not '{raw[:40]}'") from None
            self._check_range(value)
            return value
        if self.choices:
            low = raw.lower()
            if low not in self.choices:
                raise self.error(f"{name} takes {'|'.join(self.choices)}, not '{raw[:40]}'")
            return low
        if self.stem and not valid_stem(raw):
            raise self.error(
                f"{name} must be a file stem of 1-64 letters, digits, '_', '.', '-' not starting with '.'",
            )
        return raw

    def _check_range(self, value: float) -> None:
        if (self.min is not None and value < self.min) or (self.max is not None and value > self.max):
            raise self.error( f"{self.flag} is {_num(value)}, out of range [{_num(self.min)}, {_num(self.max)}]"
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
class ParamSet:
    """Base of every parameter class: a dataclass of :func:`param` fields.

    ``error`` makes the exception a bad value raises (the server's config classes make it an
    E_ARG ProtocolError; here it is a :class:`ParamError`, a ValueError).
    """

    error: ClassVar[Callable[[str], Exception]] = ParamError

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
                error=cls.error,
            )
        cls._specs = out  # type: ignore[attr-defined]
        return out

    def as_dict(self) -> dict[str, Any]:
        return {f.name: copy.deepcopy(getattr(self, f.name)) for f in fields(self)}


def show_value(value: Any) -> str:
    """A default as it is typed on the wire (true, 0.3, -150,150,-50,-15); "" for none, whose
    meaning the option's help gives (default tof_<UTC time>, keep the axis)."""
    if isinstance(value, float) and value != value:
        return ""
    if isinstance(value, list | tuple):
        return ",".join(show_value(v) for v in value)
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return format(value, "g")
    return str(value) if value != "" else ""


def reuse(cls: type[ParamSet], name: str) -> Any:
    """A field declared as ``cls.<name>`` is, for a class that cannot derive from ``cls`` (its
    own fields come first, and their order is its help's): the same default and metadata, so
    the declaration still lives in one place."""
    f = next(f for f in fields(cls) if f.name == name)
    if f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
        return field(default_factory=f.default_factory, metadata=f.metadata)  # type: ignore[misc]
    return field(default=f.default, metadata=f.metadata)


# Parameter classes of the workflow scripts, by the name a script's ``params:`` gives.
PARAMETER_SETS: dict[str, type[ParamSet]] = {}


def parameters(name: str) -> Callable[[type[ParamSet]], type[ParamSet]]:
    """Register a parameter class under the name scripts use (``params: dem``)."""

    def register(cls: type[ParamSet]) -> type[ParamSet]:
        PARAMETER_SETS[name] = cls
        return cls

    return register
