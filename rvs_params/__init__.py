"""Typed settings classes: one declaration gives the type, range, unit, help and default of a key.

The server's command options, the drivers' settings and the workflow scripts' parameters are
the same kind of thing (a value an operator types, that must be checked and explained), so they
share this one mechanism: the server's per-module config classes, every device backend's
settings class and every script's parameter class are dataclasses whose fields are declared
with :func:`param`. It is a package of its own because ``drivers`` and ``prox_workflows`` must
not import each other (nor the server), and both declare settings.

Errors are :class:`SettingError` (a ValueError): the server turns them into ``E_ARG`` replies
and fatal start-up messages, a console into a usage error.
"""

from __future__ import annotations

import copy
import dataclasses
import keyword
import math
import re
import types
import typing
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, fields
from typing import Any, TypeVar

from .numbers import (  # noqa: F401 - the wire's number rule, also for the server's own parsers
    INTEGER_FORM,
    NUMBER_FORM,
    is_number,
    load_wire_yaml,
    parse_integer,
    parse_number,
)

STEM_RE = re.compile(r"[A-Za-z0-9_\-][A-Za-z0-9_.\-]{0,63}")


def wire_key(name: str) -> str:
    """The name a field goes by on the wire, in YAML keys shown and in replies: a trailing
    underscore is Python's escape of a keyword (the field ``global_`` is the key ``global``, the
    option ``-global``), and reply keys are lower_snake_case without it."""
    bare = name[:-1]
    return bare if name.endswith("_") and keyword.iskeyword(bare) else name


def wire_flag(name: str) -> str:
    """The option a field is given by: ``-`` and its :func:`wire_key`, words joined by ``-``."""
    return "-" + wire_key(name).replace("_", "-")


# How a value says "not set" for a setting that can be unset (:attr:`ParamSpec.optional`): the
# word text replies show for it, and YAML's null spellings. Not an empty value: an empty output
# name is a mistake to refuse (tests/reliability/test_security.py), not a wish for the default.
NOT_SET = ("none", "null", "~")


def valid_stem(name: str) -> bool:
    """Output names are file stems confined to the data directory (PROTOCOL.md)."""
    return bool(STEM_RE.fullmatch(name)) and not name.startswith(".") and ".." not in name


class SettingError(ValueError):
    """A value or key a settings class refuses; ``message`` names the key and what it accepts."""

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
    live: bool = False,
    ordered: bool = False,
    flat: str | None = None,
    at_most: str | None = None,
) -> Any:
    """Declare a settings field with what a checker and a help text need to know about it.

    ``option=False`` keeps a parameter out of the request line (set it with ``config -set``);
    ``protected`` refuses run-time changes (host, port, token); ``stem`` marks output names;
    ``live`` marks a driver setting an open device takes at once (others wait for its reinit);
    ``ordered`` marks a list of min,max pairs (a view range), refused when a pair is inverted.
    A nested settings section (``default`` a :class:`Settings`) declared ``flat`` (a prefix, ""
    for none) also lends its keys to this class under that prefix: the request's options, ``-set``
    and YAML take them by those names as well as by ``section.key`` (:meth:`Settings.keys`).
    ``at_most`` names another key of the class this value must not exceed (a stop distance within
    the warning distance): both keys' help states it, and :meth:`Settings.check` refuses a pair
    that breaks it, whichever of the two was given.
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
        "live": live,
        "ordered": ordered,
        "flat": flat,
        "at_most": at_most,
    }
    if isinstance(default, list | dict | Settings):
        return field(default_factory=lambda d=default: copy.deepcopy(d), metadata=meta)
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class ParamSpec:
    """What one parameter accepts; built from a dataclass field."""

    name: str
    kind: str  # float, int, str, bool, floats, dict, any, section
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
    optional: bool = False  # can be put back to "not set" (NOT_SET words): its value is then ``unset``
    live: bool = False
    section: type[Settings] | None = None  # kind "section": the nested settings class
    ordered: bool = False  # floats: min,max pairs, each min <= max
    flat: str | None = None  # section: the prefix its keys take among this class's keys (None: not lent)
    path: tuple[str, ...] = ()  # a section's key lent to this class (Settings.keys): the fields to its value
    unset: Any = None  # an optional setting's "not set" value: None, or the declared default NaN / ""
    at_most: str | None = None  # another key of the class this value must not exceed
    at_least: str | None = None  # the key that declared at_most this one (the same rule, seen from here)

    @property
    def key(self) -> str:
        """The name on the wire and in replies (:func:`wire_key`)."""
        return wire_key(self.name)

    @property
    def flag(self) -> str:
        return wire_flag(self.name)

    def describe(self) -> str:
        """One phrase for help and error messages: type, range, unit, default."""
        if self.choices:
            what = "|".join(self.choices)
        elif self.kind in ("floats", "ints"):
            lo, hi = self.length or (1, 99)
            what = f"{lo} numbers a,b,..." if lo == hi else f"{lo}-{hi} numbers a,b,..."
        elif self.stem:
            what = "file stem"
        else:
            what = {"float": "number", "int": "integer", "bool": "true|false", "str": "text",
                    "any": "YAML value"}.get(self.kind, self.kind)
        if self.min is not None or self.max is not None:
            what += f" in [{_num(self.min)}, {_num(self.max)}]"
        if self.unit:
            what += f" {self.unit}"
        if self.at_most:
            what += f", at most {wire_flag(self.at_most)}"
        if self.at_least:
            what += f", at least {wire_flag(self.at_least)}"
        if self.optional:
            what += " or none"
        return what

    @property
    def cli_flag(self) -> str:
        """The option as a program's command line spells it (``--cell``; the wire's is ``-cell``)."""
        return "-" + self.flag

    def parse(self, raw: str | bool, flag: str | None = None) -> Any:  # noqa: C901 - one branch per kind, in order
        """Convert and validate one value from a request or a ``-set``; every error names the value
        as ``flag`` (default: the wire's spelling; a program's command line passes ``cli_flag``
        or ``--set key``, a YAML file the key)."""
        name = flag or self.flag
        if self.optional and isinstance(raw, str) and raw.strip().lower() in NOT_SET:
            return copy.copy(self.unset)
        if self.kind == "any":
            if raw is True:
                raise SettingError(f"{name} needs a value: {self.describe()}")
            import yaml  # only for the few free-form keys (a camera matrix, a mapping)

            text = str(raw)
            if isinstance(self.default, list) and not text.lstrip().startswith("["):
                text = f"[{text}]"  # a list typed as on the wire: a,b,c
            try:
                return load_wire_yaml(text)
            except yaml.YAMLError:
                raise SettingError(f"{name} takes {self.describe()}, not '{str(raw)[:40]}'") from None
            except ValueError as exc:
                raise SettingError(f"{name}: {exc}") from None
        if self.kind == "bool":
            if isinstance(raw, bool):
                return raw
            low = raw.lower()
            if low in ("true", "1", "yes", "on"):
                return True
            if low in ("false", "0", "no", "off"):
                return False
            raise SettingError(f"{name} takes true or false, not '{raw}'")
        if raw is True:
            raise SettingError(f"{name} needs a value: {self.describe()}")
        assert isinstance(raw, str)
        if self.kind in ("floats", "ints"):
            parts = [p for p in raw.split(",")] if raw else []
            try:
                values = [parse_number(p, NUMBER_FORM) for p in parts]
            except ValueError:
                raise SettingError(f"{name} takes {self.describe()}, not '{raw[:40]}' "
                                   f"(write each in {NUMBER_FORM})") from None
            lo, hi = self.length or (1, 99)
            if not lo <= len(values) <= hi:
                raise SettingError(f"{name} takes {self.describe()}, not '{raw[:40]}'")
            if not all(math.isfinite(v) for v in values):
                raise SettingError(f"{name} takes {self.describe()}, each finite, not '{raw[:40]}'")
            for v in values:
                self._check_range(v, name)
            for i in range(0, len(values) - 1, 2) if self.ordered else ():
                if values[i] > values[i + 1]:
                    raise SettingError(f"{name} takes min,max pairs, and {_num(values[i])},{_num(values[i + 1])} "
                                       f"is inverted: give {_num(values[i + 1])},{_num(values[i])}")
            if self.kind == "ints":
                if not all(v.is_integer() for v in values):
                    raise SettingError(f"{name} takes {self.describe()}, not '{raw[:40]}'")
                return [int(v) for v in values]
            return values
        if self.kind == "float":
            try:
                value = parse_number(raw, NUMBER_FORM)
            except ValueError:
                raise SettingError(f"{name} takes a {self.describe()}, not '{raw[:40]}' "
                                   f"(write it in {NUMBER_FORM})") from None
            if not math.isfinite(value):
                raise SettingError(f"{name} must be a finite {self.describe()}")
            self._check_range(value, name)
            return value
        if self.kind == "int":
            try:
                value = parse_integer(raw)
            except ValueError:
                raise SettingError(f"{name} takes an {self.describe()}, not '{raw[:40]}' "
                                   f"(write it in {INTEGER_FORM})") from None
            self._check_range(value, name)
            return value
        if self.choices:
            low = raw.lower()
            if low not in self.choices:
                raise SettingError(f"{name} takes {'|'.join(self.choices)}, not '{raw[:40]}'")
            return low
        if self.stem and not valid_stem(raw):
            raise SettingError(
                f"{name} must be a file stem of 1-64 letters, digits, '_', '.', '-' not starting with '.'"
                + ("; none for the default" if self.optional else "")
            )
        return raw

    def coerce(self, value: Any, where: str) -> Any:
        """A value that is already typed (YAML, a Python caller): checked with the wire's rules,
        an error named ``where`` and the key as a file writes it (``drivers.ptu: baudrate ...``)."""
        if value is None and self.optional:
            return copy.copy(self.unset)
        if self.kind == "any":
            return copy.deepcopy(value)
        if self.kind == "section":
            assert self.section is not None
            return self.section.from_mapping(value, where=f"{where}, section {self.name}")
        if self.kind == "dict":
            if not isinstance(value, dict):
                raise SettingError(f"{where}: {self.name} must be a mapping")
            return value
        if self.kind in ("floats", "ints") and isinstance(value, list | tuple):
            value = ",".join(str(v) for v in value)
        elif isinstance(value, bool) and self.kind != "bool":
            raise SettingError(f"{where}: {self.name} must be {self.describe()}")
        elif self.kind == "float" and isinstance(value, int | float):
            value = repr(float(value))
        elif not isinstance(value, str | bool):
            value = str(value)
        try:
            return self.parse(value, self.key)
        except SettingError as exc:
            raise SettingError(f"{where}: {exc.message}") from None

    def _check_range(self, value: float, name: str) -> None:
        if (self.min is not None and value < self.min) or (self.max is not None and value > self.max):
            raise SettingError(
                f"{name} is {_num(value)}, out of range [{_num(self.min)}, {_num(self.max)}]"
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


def _unset_default(kind: str, default: Any, meta: Mapping[str, Any]) -> Any:
    """The "not set" value a declaration gives by its default, for a type without None: a number
    declared NaN (a PTU axis that keeps its position), a free text or file stem declared ""
    (an output named by the time) or a list declared empty (navigate's goal not given). None when the default is a value like any other (a required
    option has none: it is always given)."""
    if kind == "float" and isinstance(default, float) and math.isnan(default):
        return default
    if kind == "str" and default == "" and not meta.get("choices") and not meta.get("required"):
        return default
    if kind in ("floats", "ints") and default == [] and not meta.get("required"):
        return default
    return None

S = TypeVar("S", bound="Settings")


def _kind_of(hint: Any) -> tuple[str, bool, type[Settings] | None]:
    """The parser kind of a type hint, whether None is allowed, and a nested settings class."""
    optional = False
    args = typing.get_args(hint)
    if typing.get_origin(hint) in (typing.Union, types.UnionType) and type(None) in args:
        optional = True
        rest = [a for a in args if a is not type(None)]
        hint = rest[0] if len(rest) == 1 else Any
    origin = typing.get_origin(hint)
    if isinstance(hint, type) and issubclass(hint, Settings):
        return "section", optional, hint
    if origin is list:
        inner = typing.get_args(hint)
        if inner and inner[0] is int:
            return "ints", optional, None
        return ("floats" if inner and inner[0] is float else "any"), optional, None
    if origin is dict or hint is dict:
        return "dict", optional, None
    if hint is Any or hint is list:
        return "any", optional, None
    return _KIND.get(hint, "str"), optional, None


@dataclass
class Settings:
    """Base of every typed settings class (a command module's config, a device backend's settings)."""

    @classmethod
    def specs(cls) -> dict[str, ParamSpec]:
        cached = cls.__dict__.get("_specs")
        if cached is not None:
            return cached
        hints = typing.get_type_hints(cls)
        out: dict[str, ParamSpec] = {}
        for f in fields(cls):
            meta = f.metadata
            kind, optional, section = _kind_of(hints[f.name])
            default = f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore[misc]
            length = meta.get("length")
            if isinstance(length, int):
                length = (length, length)
            unset = None if optional else _unset_default(kind, default, meta)
            if unset is not None:
                optional = True
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
                option=meta.get("option", True) and kind not in ("dict", "section", "any"),
                required=meta.get("required", False),
                protected=meta.get("protected", False),
                default=default,
                optional=optional,
                live=meta.get("live", False),
                section=section,
                ordered=meta.get("ordered", False),
                flat=meta.get("flat"),
                unset=unset,
                at_most=meta.get("at_most"),
            )
        for spec in list(out.values()):
            if spec.at_most is not None:
                if spec.at_most not in out:
                    raise TypeError(f"{cls.__name__}.{spec.name}: at_most names no field {spec.at_most!r}")
                out[spec.at_most] = dataclasses.replace(out[spec.at_most], at_least=spec.name)
        cls._specs = out  # type: ignore[attr-defined]
        return out

    @classmethod
    def keys(cls) -> dict[str, ParamSpec]:
        """Every key by the name the request's options, ``-set`` and YAML know it by: this class's
        own and those its flat sections lend it (each with the ``path`` of fields to its value)."""
        cached = cls.__dict__.get("_keys")
        if cached is not None:
            return cached
        own = cls.specs()
        out = dict(own)
        for name, spec in own.items():
            if spec.kind != "section" or spec.flat is None:
                continue
            assert spec.section is not None
            for sub, lent in spec.section.keys().items():
                key = spec.flat + sub
                if key in out:
                    raise TypeError(f"{cls.__name__}: key {key!r} is declared twice (section {name})")
                out[key] = dataclasses.replace(lent, name=key, path=(name, *(lent.path or (sub,))))
        cls._keys = out  # type: ignore[attr-defined]
        return out

    def value_of(self, spec: ParamSpec) -> Any:
        """The value of one of :meth:`keys` (a lent key's from its section)."""
        node: Any = self
        for name in spec.path or (spec.name,):
            node = getattr(node, name)
        return node

    def assign(self, spec: ParamSpec, value: Any) -> None:
        """Set one of :meth:`keys` to a checked value (a lent key's in its section)."""
        *sections, name = spec.path or (spec.name,)
        node: Any = self
        for section in sections:
            node = getattr(node, section)
        setattr(node, name, value)

    @classmethod
    def from_mapping(cls: type[S], data: Mapping[str, Any] | Settings | None = None, *, where: str = "") -> S:
        """An instance from a mapping (YAML, a test's dict), refusing unknown keys with the known ones."""
        if isinstance(data, cls):
            return copy.deepcopy(data)
        if isinstance(data, Settings):
            data = data.as_dict()
        if data is not None and not isinstance(data, Mapping):
            raise SettingError(f"{where or cls.__name__}: expected a mapping of key: value, got {data!r}")
        specs = cls.specs()
        where = where or cls.__name__
        data = _nest_lent(cls.keys(), data or {})
        kwargs: dict[str, Any] = {}
        for key, value in data.items():
            spec = specs.get(str(key))
            if spec is None:
                raise SettingError(f"{where}: unknown key '{key}'; known: {', '.join(specs)}")
            if spec.kind == "dict":
                merged = copy.deepcopy(spec.default)
                merge(merged, value if isinstance(value, dict) else spec.coerce(value, where))
                kwargs[spec.name] = merged
            else:
                kwargs[spec.name] = spec.coerce(value, where)
        made = cls(**kwargs)
        try:
            made.check(wire_key)
        except SettingError as exc:
            raise SettingError(f"{where}: {exc.message}") from None
        return made

    @classmethod
    def picked_from(cls: type[S], source: Mapping[str, Any] | Settings) -> S:
        """This class's own keys out of a wider set of values (a script's parameters, a command's
        config that composes this class with others), each checked by its declaration."""
        values = source.as_dict() if isinstance(source, Settings) else source
        return cls.from_mapping({k: values[k] for k in cls.specs() if k in values})

    @classmethod
    def parse_assignments(cls, items: Iterable[str] | str | None, *, flag: str = "--set") -> dict[str, Any]:
        """``key=value`` words (:func:`assignments`) typed and checked by each key's ParamSpec, as
        the wire checks an option, an error naming it as typed (``--set window``); an unknown key
        is refused with the known ones."""
        specs = cls.specs()
        out: dict[str, Any] = {}
        for key, raw in assignments(items, flag=flag).items():
            spec = specs.get(key)
            if spec is None:
                raise SettingError(f"{flag} {key}: unknown key; known: {', '.join(specs)}")
            out[key] = spec.parse(raw, f"{flag} {key}")
        return out

    def check(self, spell: Callable[[str], str] = wire_flag) -> None:
        """The rules between keys (``at_most``), in this class and its sections: SettingError
        naming both keys and what to give when a pair breaks one, each key as ``spell`` writes a
        field's name (the wire's option by default; a file or ``--set`` passes :func:`wire_key`)."""
        for spec in self.specs().values():
            value = getattr(self, spec.name)
            if isinstance(value, Settings):
                value.check(spell)
            if spec.at_most is None:
                continue
            limit = getattr(self, spec.at_most)
            if value is not None and limit is not None and value > limit:
                lo, hi = spell(spec.name), spell(spec.at_most)
                raise SettingError(f"{lo} {_num(value)} must not exceed {hi} {_num(limit)}: give {hi} "
                                   f"at least {_num(value)} or {lo} at most {_num(limit)}")

    def wire_dict(self) -> dict[str, Any]:
        """:meth:`as_dict` with every key as the wire names it (:func:`wire_key`), for replies,
        without the options a request must give (they have no setting). A setting that can be
        unset and is shows as None (``none`` on a text line, null in JSON), the word ``-set`` takes
        back: its stored form ("" or NaN) is refused as a value."""
        out: dict[str, Any] = {}
        specs = self.specs()
        for name, value in vars(self).items():
            if name not in specs:
                continue
            spec = specs[name]
            if spec.required:  # given with each request: there is no setting to show
                continue
            if isinstance(value, Settings):
                value = value.wire_dict()
            elif spec.optional and _is_unset(value, spec.unset):
                value = None
            else:
                value = _wire_keys(value) if isinstance(value, dict) else copy.deepcopy(value)
            out[wire_key(name)] = value
        return out

    def as_dict(self) -> dict[str, Any]:
        """Plain values (nested settings as mappings), for replies, sidecars and YAML."""
        out: dict[str, Any] = {}
        for f in fields(self):
            value = vars(self)[f.name]
            out[f.name] = value.as_dict() if isinstance(value, Settings) else copy.deepcopy(value)
        return out

    def changed(self, other: Settings | None) -> list[str]:
        """Keys whose value differs from ``other`` (all of them when there is none)."""
        mine = self.as_dict()
        theirs = other.as_dict() if other is not None else {}
        return [k for k in mine if k not in theirs or mine[k] != theirs[k]]


def assignment(item: str, *, flag: str = "--set", form: str = "key=value") -> tuple[str, str]:
    """One ``key=value`` word split at its first '=': the key stripped and spelled as a field name
    ('-' written '_', as an option's flag is), the value as typed. ``flag`` and ``form`` name the
    option and the shape in the error, so it says what to write."""
    key, sep, raw = item.partition("=")
    key = key.strip()
    if not sep or not key:
        raise SettingError(f"{flag} '{item[:40]}': write {form}")
    return key.replace("-", "_"), raw


def assignments(items: Iterable[str] | str | None, *, flag: str = "--set",
                form: str = "key=value") -> dict[str, str]:
    """``["cell=0.05", ...]`` or ``"cell=0.05 fill_radius=0.1"`` -> ``{"cell": "0.05", ...}``,
    each word split by :func:`assignment`; a later key wins."""
    if items is None:
        return {}
    words = items.split() if isinstance(items, str) else items
    return dict(assignment(word, flag=flag, form=form) for word in words)


def _nest_lent(keys: dict[str, ParamSpec], data: Mapping[str, Any]) -> dict[str, Any]:
    """``data`` with the keys a flat section lends (see :meth:`Settings.keys`) moved into it."""
    out = dict(data)
    for key in [k for k in out if keys.get(str(k)) is not None and keys[str(k)].path]:
        *sections, name = keys[str(key)].path
        node = out
        for section in sections:
            inner = node.get(section)
            node[section] = inner.as_dict() if isinstance(inner, Settings) else dict(inner or {})
            node = node[section]
        node[name] = out.pop(key)
    return out


def _is_unset(value: Any, unset: Any) -> bool:
    if isinstance(value, float) and isinstance(unset, float) and math.isnan(unset):
        return math.isnan(value)
    return value is None or (type(value) is type(unset) and value == unset)


def _wire_keys(values: dict[str, Any]) -> dict[str, Any]:
    return {wire_key(k): _wire_keys(v) if isinstance(v, dict) else copy.deepcopy(v) for k, v in values.items()}


def merge(base: dict[str, Any], over: Mapping[str, Any]) -> None:
    """Deep-merge ``over`` into ``base`` (YAML overlays, dict-valued settings)."""
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(base.get(key), dict):
            merge(base[key], value)
        else:
            base[key] = copy.deepcopy(value)
