"""The PROX-like workflow engine: validates a YAML script of registered steps whole, then runs it.

A script (``prox_workflows/scripts/*.yaml``) names steps and wires their inputs and outputs, so
a chain like read_views -> view_dem -> mosaic -> holes -> Dem2Hazard -> ortho -> write_products
is data a scientist can read and change, not code (as PROX scripts were in the thesis; as PDAL
pipelines are, readers and writers included):

    name: dem
    params: dem                           # the parameter class (prox_workflows.parameters)
    inputs: {base: Layers?}               # values the caller supplies, with their types
    outputs: [dem, files]                 # what the caller reads afterwards
    steps:
      - step: view_dem                    # a function registered with @step
        foreach: "@views"                 # optional: run once per item, outputs collected in a list
        in: {view: "@item", cell: "$cell"}
        out: view_dems
      - include: dem_chain                # the steps of another script, inlined here
      - step: write_products
        phase: write                      # progress is reported per phase
        when: "$mesh"                     # optional: skip the step when the value is false

Values: ``$name`` is a parameter (a field of the script's parameter class: declared once, with
its default, there and nowhere else), ``@name`` a workspace value (``@a.b`` an attribute or key
of it), anything else a literal. Each step declares its inputs and outputs with types
(``@step("dem_import", inputs=..., outputs=...)``); :func:`validate` checks the whole script
against those declarations before the first step runs (unknown step, unknown or missing input,
type mismatch, unused output, a ``$param`` nobody supplies, ...) and names the script line and
the fix of every mistake. Cancellation is checked before every step and every loop item;
progress is reported per phase; every step's time and outputs go to the run log.
"""

from __future__ import annotations

import argparse
import difflib
import importlib
import inspect
import sys
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from rvs_params import SettingError, Settings, assignments

from .params import PARAMETER_SETS, show_value

SCRIPTS_DIR = Path(__file__).resolve().parent / "scripts"

# Modules whose @step functions make up the registry, and those that declare script parameter
# classes beyond them; imported when the registry is first read, so that importing the engine
# stays cheap. (A step module registers the parameter classes it declares itself.)
STEP_MODULES: tuple[str, ...] = (
    "prox_workflows.steps.ptu_positions",
    "prox_workflows.steps.dem_import",
    "prox_workflows.steps.dem_chain",
    "prox_workflows.steps.spikes",
    "prox_workflows.steps.readers",
    "prox_workflows.steps.dem_products",
    "prox_workflows.steps.planner",
    "prox_workflows.steps.stereo_products",
    "prox_workflows.steps.stereo_odometry",
)
PARAMETER_MODULES: tuple[str, ...] = ("prox_workflows.parameters",)

# Keywords the engine passes itself to a step that accepts them; never wired by a script.
INJECTED = ("progress", "cancelled", "run_log")


class WorkflowError(Exception):
    """A script that cannot run: unknown step, missing value, bad wiring."""


class ScriptError(WorkflowError):
    """A script refused by validation; ``problems`` lists each mistake with its line and fix."""

    def __init__(self, script: str, problems: list[str]) -> None:
        self.script = script
        self.problems = problems
        super().__init__(f"{script}: {len(problems)} problem(s), nothing was run:\n  " + "\n  ".join(problems))


class Cancelled(Exception):
    """The caller asked the workflow to stop; raised at the next step or item boundary."""


# ------------------------------------------------------------------------------ types

# Types are short names: float, int, str, bool, floats (a list of numbers), dict, list, array,
# path, Layers, View, ... ; ``list[T]`` a list of T; a trailing ``?`` allows None; ``any`` anything.


def _base(t: str) -> tuple[str, bool]:
    return (t[:-1], True) if t.endswith("?") else (t, False)


def compatible(given: str, wanted: str) -> bool:
    """Can a value of type ``given`` go where ``wanted`` is declared?"""
    g, g_opt = _base(given)
    w, w_opt = _base(wanted)
    if g == "any" or w == "any":
        return True
    if g == "none":
        return w_opt
    if g_opt and not w_opt:
        return False
    if g == w:
        return True
    if (g, w) in (("int", "float"), ("floats", "list"), ("str", "path"), ("path", "str")):
        return True
    if g.startswith("list[") and w == "list":
        return True
    if g.startswith("list[") and w.startswith("list["):
        return compatible(g[5:-1], w[5:-1])
    if g == "floats" and w.startswith("list["):
        return compatible("float", w[5:-1])
    if g == "list" and w.startswith("list["):
        return True  # a literal list: its items are checked when the step runs
    return False


def literal_type(value: Any) -> str:
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "bool"
    if isinstance(value, int):
        return "int"
    if isinstance(value, float):
        return "float"
    if isinstance(value, str):
        return "str"
    if isinstance(value, list | tuple):
        if value and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value):
            return "floats"
        return "list"
    if isinstance(value, dict):
        return "dict"
    return "any"


_PARAM_KIND = {"float": "float", "int": "int", "str": "str", "bool": "bool", "floats": "floats", "dict": "dict"}


# ------------------------------------------------------------------------------ steps


@dataclass
class StepSpec:
    """A registered step: its function and the declared types of its inputs and outputs."""

    name: str
    fn: Callable[..., Any]
    inputs: dict[str, str]  # input -> type
    required: set[str]  # inputs without a default
    outputs: dict[str, str] | None  # output -> type, in the order a tuple result gives them; None: free
    accepts: set[str] = field(default_factory=set)  # injected keywords it takes (progress, ...)

    @classmethod
    def of(cls, name: str, fn: Callable[..., Any], inputs: dict[str, str] | None = None,
           outputs: dict[str, str] | str | None = None) -> StepSpec:
        sig = inspect.signature(fn)
        params = {n: p for n, p in sig.parameters.items() if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)}
        declared = dict(inputs or {})
        ins = {n: declared.get(n, "any") for n in params if n not in INJECTED}
        unknown = set(declared) - set(ins)
        if unknown:
            raise TypeError(f"step {name}: declares inputs {sorted(unknown)} its function does not take")
        required = {n for n in ins if params[n].default is inspect.Parameter.empty}
        outs = {name: outputs} if isinstance(outputs, str) else (dict(outputs) if outputs is not None else None)
        return cls(name, fn, ins, required, outs, {n for n in INJECTED if n in params})


_REGISTRY: dict[str, StepSpec] = {}
_loaded = [False]


def step(name: str, *, inputs: dict[str, str] | None = None,
         outputs: dict[str, str] | str | None = None) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Register a function as the workflow step ``name``.

    ``inputs`` gives the types of its keyword arguments (undeclared ones are ``any``; those
    without a default are required); ``outputs`` names what it returns: ``{"dem": "Layers"}``
    for one value, several names for a dict or tuple result. The declaration is what
    :func:`validate` checks a script against, so a miswired script fails before anything runs.
    """

    def register(fn: Callable[..., Any]) -> Callable[..., Any]:
        _REGISTRY[name] = StepSpec.of(name, fn, inputs, outputs)
        return fn

    return register


def registry() -> dict[str, StepSpec]:
    """Every registered step (importing the step modules the first time)."""
    if not _loaded[0]:
        for module in STEP_MODULES + PARAMETER_MODULES:
            importlib.import_module(module)
        _loaded[0] = True
    return _REGISTRY


def resolve_step(name: str, extra: dict[str, Callable[..., Any]] | None = None) -> Callable[..., Any]:
    if extra and name in extra:
        return extra[name]
    spec = registry().get(name)
    if spec is None:
        raise WorkflowError(f"unknown step '{name}'; known steps: {', '.join(sorted(registry()))}")
    return spec.fn


# ------------------------------------------------------------------------------ loading


class _LineLoader(yaml.SafeLoader):
    """Keeps the line of every mapping, so validation can say where a mistake is."""


def _construct_mapping(loader: _LineLoader, node: yaml.MappingNode) -> dict[str, Any]:
    mapping = _Lined(loader.construct_mapping(node, deep=True))
    mapping.line = node.start_mark.line + 1
    return mapping


class _Lined(dict):  # noqa: FURB189 - a dict that remembers its line
    line: int = 0
    source: str = ""


_LineLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def script_path(name_or_path: str | Path) -> Path:
    path = Path(name_or_path)
    if not path.suffix:
        path = SCRIPTS_DIR / f"{path.name}.yaml"
    return path


def load_script(name_or_path: str | Path) -> dict[str, Any]:
    """A script with its ``include:`` steps inlined; each step remembers its file and line."""
    return _load(script_path(name_or_path), [])


def _load(path: Path, stack: list[Path]) -> dict[str, Any]:
    if not path.is_file():
        raise WorkflowError(f"no workflow script {path.stem} (looked at {path})")
    try:
        script = yaml.load(path.read_text(), Loader=_LineLoader) or {}  # noqa: S506 - a SafeLoader
    except yaml.YAMLError as exc:
        raise ScriptError(path.name, [f"{path.name}: not YAML ({exc}); fix the syntax"]) from None
    if not isinstance(script, dict) or not isinstance(script.get("steps"), list):
        raise ScriptError(path.name, [f"{path.name}:1: a script needs 'steps:', a list of steps; add one"])
    script.setdefault("name", path.stem)
    steps: list[Any] = []
    for spec in script["steps"]:
        if isinstance(spec, _Lined):
            spec.source = path.name
        if isinstance(spec, dict) and "include" in spec:
            inner = script_path(spec["include"])
            if inner in stack or inner == path:
                raise ScriptError(path.name, [f"{path.name}:{getattr(spec, 'line', 0)}: include of "
                                              f"{inner.stem} loops back to itself; remove it"])
            included = _load(inner, [*stack, path])
            steps.extend(included["steps"])
            for key in ("inputs", "outputs"):
                if key in included and key not in script:
                    script[key] = included[key]
            continue
        steps.append(spec)
    script["steps"] = steps
    script["_file"] = path.name
    return script


# ------------------------------------------------------------------------------ validation


def _where(script: dict[str, Any], spec: Any, index: int) -> str:
    if isinstance(spec, _Lined) and spec.line:
        return f"{spec.source or script.get('_file', script.get('name', 'script'))}:{spec.line}"
    return f"{script.get('name', 'script')} step {index + 1}"


def _suggest(name: str, known: Iterable[str]) -> str:
    close = difflib.get_close_matches(name, list(known), n=1)
    return f"did you mean '{close[0]}'?" if close else ""


def param_class(script: dict[str, Any]) -> type[Settings] | None:
    name = script.get("params")
    if isinstance(name, str):
        registry()
        return PARAMETER_SETS.get(name)
    return None


def param_types(script: dict[str, Any], params: dict[str, Any] | None = None,
                param_cls: type[Settings] | None = None) -> dict[str, str]:
    """The parameters a script may read: its class's fields, then what the caller supplies."""
    cls = param_cls or param_class(script)
    out: dict[str, str] = {}
    if cls is not None:
        out.update({n: _PARAM_KIND.get(s.kind, "any") for n, s in cls.specs().items()})
    for name, value in (params or {}).items():
        out.setdefault(name, literal_type(value))
    return out


STEP_KEYS = {"step", "in", "out", "foreach", "when", "phase"}
SCRIPT_KEYS = {"name", "params", "inputs", "outputs", "steps", "_file"}


def validate(
    script: dict[str, Any] | str | Path,
    params: dict[str, Any] | None = None,
    workspace: dict[str, Any] | Iterable[str] | None = None,
    *,
    steps: dict[str, Callable[..., Any]] | None = None,
    param_cls: type[Settings] | None = None,
) -> dict[str, Any]:
    """Check the whole script before anything runs; returns it loaded, or raises :class:`ScriptError`.

    ``params`` and ``workspace`` are what the caller will supply (values or just names);
    ``steps`` are the caller's own step functions (their signatures are their declarations).
    Every problem is reported at once, each with its line and what to do about it.
    """
    if not isinstance(script, dict):
        script = load_script(script)
    name = str(script.get("name", "script"))
    where0 = script.get("_file", name)
    problems: list[str] = []
    reg = dict(registry())
    for extra_name, fn in (steps or {}).items():
        if extra_name in reg:  # the caller supplies the implementation; the declaration stands
            continue
        reg[extra_name] = StepSpec.of(extra_name, fn)

    for key in script:
        if key not in SCRIPT_KEYS:
            problems.append(f"{where0}: unknown script key '{key}'; use one of {', '.join(sorted(SCRIPT_KEYS - {'_file'}))}")
    declared_params = script.get("params")
    if isinstance(declared_params, dict):
        problems.append(f"{where0}: 'params:' declares values ({', '.join(map(str, declared_params))}); a "
                        "parameter and its default are declared once, in its parameter class: write "
                        "'params: <class name>' and set values from the caller (--set)")
    elif isinstance(declared_params, str) and param_cls is None and param_class(script) is None:
        hint = _suggest(declared_params, PARAMETER_SETS)
        problems.append(f"{where0}: no parameter class '{declared_params}'; {hint + ' ' if hint else ''}known: "
                        f"{', '.join(sorted(PARAMETER_SETS))} (prox_workflows/parameters.py)")
    ptypes = param_types(script, params, param_cls)
    if isinstance(declared_params, dict):  # reported above; do not report each of its names again
        for k, v in declared_params.items():
            ptypes.setdefault(str(k), literal_type(v))

    # what the workspace holds before the first step: the declared inputs, then the caller's
    declared_inputs = script.get("inputs") or {}
    if not isinstance(declared_inputs, dict):
        problems.append(f"{where0}: 'inputs:' must map each input to its type (base: Layers?)")
        declared_inputs = {}
    avail: dict[str, str] = {k: str(v) for k, v in declared_inputs.items()}
    if workspace is not None:
        supplied = set(workspace)
        for k, t in avail.items():
            if k not in supplied and not str(t).endswith("?"):
                problems.append(f"{where0}: input '{k}' ({t}) is declared under inputs: but the caller does not "
                                f"supply it; pass it (rvs-prox --input {k}=...) or declare it optional ({t}?)")
    if isinstance(workspace, dict):
        for k, v in workspace.items():
            avail.setdefault(k, "any" if v is not None else "none")
    elif workspace is not None:
        for k in workspace:
            avail.setdefault(k, "any")
    produced_at: dict[str, str] = {}  # output -> where it was made
    read: set[str] = set()
    later_outputs = _all_outputs(script)

    def check_ref(expr: Any, want: str, where: str, what: str, item: str | None) -> None:
        if isinstance(expr, dict):
            for v in expr.values():
                check_ref(v, "any", where, what, item)
            return
        if isinstance(expr, list):
            for v in expr:
                check_ref(v, "any", where, what, item)
            return
        if isinstance(expr, str) and expr[:1] in "$@":
            if len(expr) < 2 or not expr[1:2].isidentifier():
                problems.append(f"{where}: {what} '{expr}' is not a reference; write $param or @value")
                return
            head, *rest = expr[1:].split(".")
            if expr[0] == "$":
                if head not in ptypes:
                    hint = _suggest(head, ptypes)
                    problems.append(f"{where}: {what} reads parameter ${head}, which no one supplies; "
                                    f"{hint + ' ' if hint else ''}declare it in the parameter class "
                                    f"or pass it (--set {head}=...)")
                    return
                got = ptypes[head] if not rest else "any"
            else:
                if head == "item":
                    if item is None:
                        problems.append(f"{where}: {what} reads @item outside a foreach; add foreach: or "
                                        "name a workspace value")
                        return
                    got = item if not rest else "any"
                elif head not in avail:
                    if head in later_outputs:
                        problems.append(f"{where}: {what} reads @{head} before a step makes it; move "
                                        f"this step after the one with out: {head}")
                    else:
                        hint = _suggest(head, list(avail))
                        problems.append(f"{where}: {what} reads @{head}, which no step makes and the caller "
                                        f"does not supply; {hint + ' ' if hint else ''}add it under inputs: "
                                        "or to a step's out:")
                    return
                else:
                    read.add(head)
                    got = avail[head] if not rest else "any"
            if not compatible(got, want):
                problems.append(f"{where}: {what} wants {want} but {expr} is {got}; wire a value of that type")
            return
        got = literal_type(expr)
        if not compatible(got, want):
            problems.append(f"{where}: {what} wants {want} but the literal {expr!r} is {got}; give a {want}")

    if not any(isinstance(s, dict) and s.get("step") for s in script.get("steps") or []):
        problems.append(f"{where0}: the script has no steps; add at least one '- step: NAME'")
    seen_phases: list[str] = []
    for index, spec in enumerate(script.get("steps") or []):
        phase = str(spec.get("phase", "process")) if isinstance(spec, dict) else "process"
        if seen_phases and seen_phases[-1] != phase and phase in seen_phases:
            problems.append(f"{_where(script, spec, index)}: phase '{phase}' is split: its steps must follow "
                            "one another; move this step next to the others of its phase")
        seen_phases.append(phase)

    for index, spec in enumerate(script.get("steps") or []):
        where = _where(script, spec, index)
        if not isinstance(spec, dict):
            problems.append(f"{where}: a step is a mapping (- step: NAME, in: ..., out: ...), not {spec!r}")
            continue
        for key in spec:
            if key not in STEP_KEYS:
                hint = _suggest(str(key), STEP_KEYS)
                problems.append(f"{where}: unknown key '{key}' in a step; {hint or 'use one of ' + ', '.join(sorted(STEP_KEYS))}")
        sname = spec.get("step")
        sspec = reg.get(sname) if sname else None
        if sspec is None:
            if not sname:
                problems.append(f"{where}: a step without a name; write '- step: NAME'")
            else:
                hint = _suggest(str(sname), reg)
                problems.append(f"{where}: unknown step '{sname}'; {hint or 'known steps: ' + ', '.join(sorted(reg))}")
            for n in _names(spec.get("out")):  # its outputs exist as far as the later steps care
                if isinstance(n, str):
                    avail[n] = "any"
                    produced_at[n] = where
                    read.add(n)
            continue
        item_type: str | None = None
        if "foreach" in spec:
            fe = spec["foreach"]
            if isinstance(fe, list):
                item_type = "any"
            elif isinstance(fe, str) and fe[:1] in "@$":
                check_ref(fe, "list", where, "foreach", None)
                head = fe[1:].split(".")[0]
                src = avail.get(head) if fe[0] == "@" else ptypes.get(head)
                src = _base(src)[0] if src else "any"
                item_type = src[5:-1] if src.startswith("list[") else ("float" if src == "floats" else "any")
            else:
                problems.append(f"{where}: foreach wants a list or @value, not {fe!r}")
                item_type = "any"
        if "when" in spec:
            check_ref(spec["when"], "any", where, "when", item_type)
        wiring = spec.get("in") or {}
        if not isinstance(wiring, dict):
            problems.append(f"{where}: in: maps the step's inputs to values ({{cell: $cell}}), not {wiring!r}")
            wiring = {}
        for key, expr in wiring.items():
            if key not in sspec.inputs:
                hint = _suggest(str(key), sspec.inputs)
                problems.append(f"{where}: step {sname} has no input '{key}'; "
                                f"{hint or 'its inputs: ' + ', '.join(sspec.inputs)}")
                continue
            check_ref(expr, sspec.inputs[key], where, f"input {key} of {sname}", item_type)
        missing = sorted(sspec.required - set(wiring))
        if missing:
            problems.append(f"{where}: step {sname} needs input(s) {', '.join(missing)}; add them under in: "
                            f"({', '.join(f'{m}: ...' for m in missing)})")
        out = spec.get("out")
        names = _names(out)
        if out is not None and not isinstance(out, str | list):
            problems.append(f"{where}: out: is a name or a list of names, not {out!r}")
            names = []
        types: list[str] = []
        if sspec.outputs is not None:
            declared = list(sspec.outputs.items())
            if len(names) > len(declared):
                problems.append(f"{where}: step {sname} makes {len(declared)} output(s) "
                                f"({', '.join(n for n, _ in declared)}) but out: names {len(names)}; "
                                "name at most that many")
                names = names[:len(declared)]
            elif len(names) > 1 and len(names) < len(declared):
                problems.append(f"{where}: out: of step {sname} names {len(names)} of its {len(declared)} "
                                f"outputs ({', '.join(n for n, _ in declared)}); name them all, in order")
            types = [t for _, t in declared[:len(names)]]
        else:
            types = ["any"] * len(names)
        for n, t in zip(names, types, strict=False):
            if not isinstance(n, str) or not n.isidentifier():
                problems.append(f"{where}: output name {n!r} must be a plain name")
                continue
            if n in produced_at and n not in read:
                problems.append(f"{where}: output '{n}' replaces the one made at {produced_at[n]} before "
                                "anything read it; rename one")
            avail[n] = f"list[{t}]" if "foreach" in spec else t
            produced_at[n] = where
            read.discard(n)

    wanted = script.get("outputs")
    if wanted is None:
        last = next((s for s in reversed(script.get("steps") or []) if isinstance(s, dict)), {})
        finals = set(_names(last.get("out")))
    else:
        finals = set(_names(wanted))
        for n in finals - set(avail):
            problems.append(f"{where0}: outputs: lists '{n}', which no step makes; drop it or make it")
    for n, where in produced_at.items():
        if n not in read and n not in finals:
            problems.append(f"{where}: output '{n}' is never used; read it in a later step, list it under "
                            "outputs:, or drop it from out:")
    if problems:
        raise ScriptError(name, problems)
    return script


def _all_outputs(script: dict[str, Any]) -> set[str]:
    out: set[str] = set()
    for spec in script.get("steps") or []:
        if isinstance(spec, dict):
            out.update(n for n in _names(spec.get("out")) if isinstance(n, str))
    return out


# ------------------------------------------------------------------------------ running


@dataclass
class RunLog:
    """What ran, how long it took and what it produced (kept with the products)."""

    script: str
    entries: list[dict[str, Any]] = field(default_factory=list)

    def add(self, step: str, seconds: float, **info: Any) -> None:
        self.entries.append({"step": step, "seconds": round(seconds, 4), **info})

    def as_dict(self) -> dict[str, Any]:
        return {"script": self.script, "steps": self.entries}


def _lookup(ref: str, workspace: dict[str, Any], params: dict[str, Any]) -> Any:
    source = params if ref[0] == "$" else workspace
    head, *rest = ref[1:].split(".")
    if head not in source:
        kind = "parameter" if ref[0] == "$" else "workspace value"
        raise WorkflowError(f"no {kind} '{head}' (have: {', '.join(sorted(source)) or 'none'})")
    value = source[head]
    for part in rest:
        value = value[part] if isinstance(value, dict) else getattr(value, part)
    return value


def evaluate(expr: Any, workspace: dict[str, Any], params: dict[str, Any]) -> Any:
    if isinstance(expr, str) and len(expr) > 1 and expr[0] in "$@":
        return _lookup(expr, workspace, params)
    if isinstance(expr, list):
        return [evaluate(e, workspace, params) for e in expr]
    if isinstance(expr, dict):
        return {k: evaluate(v, workspace, params) for k, v in expr.items()}
    return expr


Progress = Callable[..., None]  # progress(done, total, message, phase=name)


def phases_of(plan: list[dict[str, Any]]) -> list[tuple[str, list[int]]]:
    """The script's phases in order: runs of steps with the same ``phase`` (default process).

    A phase is what a progress bar shows; one that came back later in the script would make
    its count run twice, so a script must keep each phase's steps together.
    """
    out: list[tuple[str, list[int]]] = []
    for index, spec in enumerate(plan):
        name = str(spec.get("phase", "process"))
        if out and out[-1][0] == name:
            out[-1][1].append(index)
        elif any(p == name for p, _ in out):
            raise WorkflowError(f"phase '{name}' is split: its steps must follow one another")
        else:
            out.append((name, [index]))
    return out


def resolve_params(script: dict[str, Any], params: dict[str, Any] | None = None,
                   param_cls: type[Settings] | None = None) -> dict[str, Any]:
    """The parameter values a run sees: the class's defaults, then the caller's values (each
    checked with the class's own rules when it is a field)."""
    cls = param_cls or param_class(script)
    merged: dict[str, Any] = {}
    if cls is not None:
        merged.update({n: s.default for n, s in cls.specs().items()})
    merged.update(params or {})
    return merged


def run_workflow(
    script: dict[str, Any] | str | Path,
    params: dict[str, Any] | None = None,
    workspace: dict[str, Any] | None = None,
    *,
    steps: dict[str, Callable[..., Any]] | None = None,
    progress: Progress | None = None,
    cancelled: Callable[[], bool] | None = None,
    param_cls: type[Settings] | None = None,
) -> tuple[dict[str, Any], RunLog]:
    """Validate the whole script, then run it; returns the final workspace and the run log.

    ``steps`` adds or overrides step functions (the server passes its device-backed
    acquisition this way, so this package never imports the drivers). Progress is reported
    per phase (``phase:`` of the steps): a phase of several steps counts its steps; a phase of
    one step that accepts a ``progress`` keyword reports that step's own count (views).
    Within a phase ``total`` is fixed and ``done`` only grows.
    """
    if not isinstance(script, dict):
        script = load_script(script)
    validate(script, params, workspace or {}, steps=steps, param_cls=param_cls)
    merged = resolve_params(script, params, param_cls)
    ws: dict[str, Any] = dict(workspace or {})
    for key in script.get("inputs") or {}:
        ws.setdefault(key, None)  # an optional input the caller left out
    log = RunLog(str(script.get("name", "workflow")))
    plan = script["steps"]
    phase_of: dict[int, tuple[str, list[int]]] = {}
    for phase in phases_of(plan):
        for index in phase[1]:
            phase_of[index] = phase

    def check() -> None:
        if cancelled is not None and cancelled():
            raise Cancelled("workflow interrupted")

    for index, spec in enumerate(plan):
        check()
        name = spec["step"]
        phase, members = phase_of[index]
        own_count = len(members) == 1  # the step's own progress is the phase's

        def report(message: str, phase: str = phase, members: list[int] = members, index: int = index) -> None:
            if progress is not None:
                progress(members.index(index) + 1, len(members), message, phase=phase)

        if "when" in spec and not evaluate(spec["when"], ws, merged):
            log.add(name, 0.0, skipped=True)
            report(f"{name} skipped")
            continue
        fn = resolve_step(name, steps)
        accepts = inspect.signature(fn).parameters
        t0 = time.perf_counter()
        if "foreach" in spec:
            items = list(evaluate(spec["foreach"], ws, merged))
            results = []
            for item in items:
                check()
                ws["item"] = item
                results.append(fn(**evaluate(spec.get("in") or {}, ws, merged)))
            ws.pop("item", None)
            result: Any = results
        else:
            kwargs = evaluate(spec.get("in") or {}, ws, merged)
            if "progress" in accepts:
                if own_count and progress is not None:
                    kwargs["progress"] = lambda d, t, m, phase=phase: progress(d, t, m, phase=phase)
                else:
                    kwargs["progress"] = lambda d, t, m: None
            if "cancelled" in accepts:
                kwargs["cancelled"] = cancelled or (lambda: False)
            if "run_log" in accepts:
                kwargs["run_log"] = log.as_dict()
            result = fn(**kwargs)
        declared = registry().get(name)
        _store(spec, result, ws, name, list(declared.outputs) if declared and declared.outputs else None)
        log.add(name, time.perf_counter() - t0, outputs=_names(spec.get("out")))
        if not (own_count and "progress" in accepts):
            report(name if "foreach" not in spec else f"{name} x{len(result)}")
    return ws, log


def _names(out: Any) -> list[str]:
    if out is None:
        return []
    return [out] if isinstance(out, str) else list(out)


def _store(spec: dict[str, Any], result: Any, ws: dict[str, Any], name: str,
           declared: list[str] | None = None) -> None:
    names = _names(spec.get("out"))
    if not names:
        return
    if len(names) == 1 and (declared is None or len(declared) == 1):
        ws[names[0]] = result
        return
    if isinstance(result, dict):
        keys = declared[:len(names)] if declared else names
        missing = [k for k in keys if k not in result]
        if missing:
            raise WorkflowError(f"step {name} did not produce {', '.join(missing)}")
        for n, k in zip(names, keys, strict=True):
            ws[n] = result[k]
        return
    if isinstance(result, tuple | list) and len(result) == len(names):
        ws.update(zip(names, result, strict=True))
        return
    raise WorkflowError(f"step {name} returned one value but the script names {len(names)} outputs")


def _parse_value(raw: str) -> Any:
    try:
        return yaml.safe_load(raw)
    except yaml.YAMLError:
        return raw


# ------------------------------------------------------------------------------ rvs-prox


def params_help(cls: type[Settings] | None) -> str:
    """The parameters of a script as ``help <command>`` shows them: type, range, default, help."""
    if cls is None:
        return "parameters: none declared (the script names no parameter class)"
    lines = ["parameters (--set NAME=VALUE; the server's command options are the same):"]
    for spec in cls.specs().values():
        shown = show_value(spec.default)
        lines.append(f"  {spec.name}: {spec.describe()}{f'; default {shown}' if shown else ''}: {spec.help}"
                     + ("" if spec.option else " [setting, not a request option]"))
    return "\n".join(lines)


def show_progress(done: int, total: int, message: str, phase: str = "") -> None:
    """The console tools' progress bar on stderr: phase, bar, count, message, one line redrawn."""
    width = 30
    filled = int(width * done / max(total, 1))
    sys.stderr.write(f"\r{phase[:10]:<10} [{'#' * filled}{'.' * (width - filled)}] {done}/{total} "
                     f"{message[:40]:<40}")
    sys.stderr.flush()


def _main_from(script: str, source: str, sets: list[str], out: str | None) -> int:
    """``rvs-prox dem --from JOB``: a recorded DEM job run again (prox_workflows.reprocess)."""
    from .reprocess import ReprocessError, parse_overrides, reprocess

    try:
        result = reprocess(source, parse_overrides(sets), out, script=script, progress=show_progress)
    except ReprocessError as exc:  # the command line's fault: no such job, a parameter it refuses
        sys.stderr.write(f"\nrvs-prox: {exc}\n")
        return 2
    except (WorkflowError, FileNotFoundError) as exc:
        sys.stderr.write(f"\nrvs-prox: {exc}\n")
        return 1
    except KeyboardInterrupt:
        sys.stderr.write("\nrvs-prox: interrupted\n")
        return 130
    sys.stderr.write("\n")
    print(f"views: {result['views']}")
    for layer, path in result["files"].items():
        print(f"{layer}: {path}")
    return 0


# The campaign tools are dispatched before the script parser sees argv, so argparse would never
# mention them: the help names them here.
CAMPAIGN_HELP = """\
campaign commands (each has its own --help):
  rvs-prox batch SCRIPT --inputs GLOB [--scheduler tcp://HOST:PORT] [--workers N] [-o DIR]
                        re-run every recorded DEM job the GLOB finds on Dask (a LocalCluster
                        here by default), one task per job; up-to-date jobs are skipped
  rvs-prox mosaic-campaign --inputs GLOB -o DIR [--name NAME] [--cell M] [--tile N]
                        fuse site DEMs (*_dem.tif) into one mosaic written tile by tile:
                        DIR/NAME_dem.tif, NAME_variance.tif, NAME_count.tif (NAME: mosaic)
"""


def main(argv: list[str] | None = None) -> int:
    """``rvs-prox SCRIPT [--validate] [--set key=value] [--help]``: validate or run a script;
    ``rvs-prox batch|mosaic-campaign ...``: the campaign tools (prox_workflows.batch)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in ("batch", "mosaic-campaign"):  # the campaign tools (prox_workflows.batch)
        from . import batch

        return batch.main(argv)
    ap = argparse.ArgumentParser(prog="rvs-prox", description="Validate or run a PROX-like workflow script.",
                                 formatter_class=argparse.RawDescriptionHelpFormatter, add_help=False,
                                 epilog=CAMPAIGN_HELP)
    ap.add_argument("script", nargs="?", help="script name (in prox_workflows/scripts) or path; or one of the "
                                              "campaign commands below")
    ap.add_argument("-h", "--help", action="store_true", help="show this help (and the script's parameters)")
    ap.add_argument("--validate", action="store_true", help="check the script and stop; nothing runs")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="set a parameter")
    ap.add_argument("--input", action="append", default=[], metavar="NAME=VALUE",
                    help="supply one of the script's inputs (a folder, a file: --input views=data/dem/site_views)")
    ap.add_argument("--log", help="write the run log (YAML) here")
    ap.add_argument("--from", dest="from_", metavar="JOB",
                    help="re-run a recorded DEM job (data/dem/site, or its site_views folder) with the "
                         "parameters it recorded, --set overriding them")
    ap.add_argument("-o", "--out", metavar="DIR",
                    help="with --from: the folder the products go in (default <job dir>/reprocessed)")
    args = ap.parse_args(argv)
    if not args.help and not args.script:
        ap.error("name a script to run (or batch, mosaic-campaign); --help lists the options")
    if args.log and not Path(args.log).absolute().parent.is_dir():  # found out before the run, not after it
        ap.error(f"--log {args.log}: no folder {Path(args.log).absolute().parent}")
    if args.help:
        text = ap.format_help()
        if args.script:
            try:
                script = load_script(args.script)
                text += f"\nscript {script['name']} ({script_path(args.script)}):\n"
                text += params_help(param_class(script)) + "\n"
                if script.get("inputs"):
                    text += "inputs (--input NAME=VALUE):\n" + "".join(
                        f"  {k}: {v}\n" for k, v in script["inputs"].items())
            except WorkflowError as exc:
                text += f"\n{exc}\n"
        print(text, end="")
        return 0
    if args.from_:
        return _main_from(args.script, args.from_, args.set, args.out)
    try:
        params = assignments(args.set)
        inputs = {k: _parse_value(v) for k, v in assignments(args.input, flag="--input", form="name=value").items()}
    except SettingError as exc:
        ap.error(exc.message)
    try:
        script = load_script(args.script)
        cls = param_class(script)
        typed: dict[str, Any] = {}
        for key, raw in params.items():
            spec = cls.specs().get(key) if cls is not None else None
            typed[key] = spec.parse(str(raw)) if spec is not None else _parse_value(raw)
        if args.validate:
            validate(script, typed, list(inputs) + list(script.get("inputs") or {}))
            print(f"{script['name']}: valid ({len(script['steps'])} steps)")
            return 0
    except ScriptError as exc:  # the script's own mistakes, each with its line: the validator's verdict
        sys.stderr.write(f"rvs-prox: {exc}\n")
        return 1
    except (WorkflowError, SettingError) as exc:  # no such script, a --set value its parameter refuses
        sys.stderr.write(f"rvs-prox: {exc}\n")
        return 2

    try:
        ws, log = run_workflow(script, typed, inputs, progress=show_progress)
    except (WorkflowError, FileNotFoundError, ValueError) as exc:
        sys.stderr.write(f"\nrvs-prox: {exc}\n")
        return 1
    except KeyboardInterrupt:
        sys.stderr.write("\nrvs-prox: interrupted\n")
        return 130
    sys.stderr.write("\n")
    text = yaml.safe_dump(log.as_dict(), sort_keys=False)
    if args.log:
        try:
            Path(args.log).write_text(text)
        except OSError as exc:
            sys.stderr.write(f"rvs-prox: cannot write the log {args.log}: {exc.strerror or exc}\n")
            return 2
    print(text, end="")
    for key, value in ws.items():
        if isinstance(value, str | int | float | Path):
            print(f"{key}: {value}")
        elif isinstance(value, dict) and all(isinstance(v, str | Path) for v in value.values()):
            for k, v in value.items():
                print(f"{key}.{k}: {v}")
    return 0
