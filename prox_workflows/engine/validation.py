"""Validation of a whole script before anything runs: every mistake named with its script line
and the fix."""

from __future__ import annotations

import difflib
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from rvs_params import Settings

from ..params import PARAMETER_SETS
from .errors import ScriptError, WorkflowError
from .loader import Lined, load_script
from .registry import StepSpec, registry
from .settings import script_parameters
from .types import PARAM_KIND, base_type, compatible, literal_type


def _where(script: dict[str, Any], spec: Any, index: int) -> str:
    if isinstance(spec, Lined) and spec.line:
        return f"{spec.source or script.get('_file', script.get('name', 'script'))}:{spec.line}"
    return f"{script.get('name', 'script')} step {index + 1}"


def _suggest(name: str, known: Iterable[str]) -> str:
    close = difflib.get_close_matches(name, list(known), n=1)
    return f"did you mean '{close[0]}'?" if close else ""


def param_class(script: dict[str, Any]) -> type[Settings] | None:
    """The script's parameters: its own class composed with its steps' settings."""
    return script_parameters(script)


def param_types(script: dict[str, Any], params: dict[str, Any] | None = None,
                param_cls: type[Settings] | None = None) -> dict[str, str]:
    """The parameters a script may read: its class's fields, then what the caller supplies."""
    cls = param_cls or param_class(script)
    out: dict[str, str] = {}
    if cls is not None:
        out.update({n: PARAM_KIND.get(s.kind, "any") for n, s in cls.specs().items()})
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
    Every problem is reported at once, each with its line and what to do about it, in the
    order the script is written.
    """
    if not isinstance(script, dict):
        script = load_script(script)
    name = str(script.get("name", "script"))
    where0 = script.get("_file", name)
    problems = [f"{where0}: unknown script key '{key}'; use one of {', '.join(sorted(SCRIPT_KEYS - {'_file'}))}"
                for key in script if key not in SCRIPT_KEYS]
    problems += _param_class_problems(script, where0, param_cls)
    try:
        param_cls = param_cls or param_class(script)
    except WorkflowError as exc:  # two steps' settings claim one name
        problems.append(f"{where0}: {exc}")
    ptypes = param_types(script, params, param_cls)
    declared_params = script.get("params")
    if isinstance(declared_params, dict):  # reported above; do not report each of its names again
        for k, v in declared_params.items():
            ptypes.setdefault(str(k), literal_type(v))
    avail = _workspace_types(script, workspace, where0, problems)
    check = _Check(script, _with_callers_steps(steps), ptypes, avail, problems)
    check.phases(where0)
    for index, spec in enumerate(script.get("steps") or []):
        check.step(index, spec)
    check.finals(where0)
    if problems:
        raise ScriptError(name, problems)
    return script


def _with_callers_steps(steps: dict[str, Callable[..., Any]] | None) -> dict[str, StepSpec]:
    reg = dict(registry())
    for extra_name, fn in (steps or {}).items():
        if extra_name not in reg:  # else the caller supplies the implementation; the declaration stands
            reg[extra_name] = StepSpec.of(extra_name, fn)
    return reg


def _param_class_problems(script: dict[str, Any], where0: str, param_cls: type[Settings] | None) -> list[str]:
    declared = script.get("params")
    if isinstance(declared, dict):
        return [f"{where0}: 'params:' declares values ({', '.join(map(str, declared))}); a "
                "parameter and its default are declared once, in its parameter class: write "
                "'params: <class name>' and set values from the caller (--set)"]
    registry()  # the step modules register the parameter classes they declare
    if isinstance(declared, str) and param_cls is None and declared not in PARAMETER_SETS:
        hint = _suggest(declared, PARAMETER_SETS)
        return [f"{where0}: no parameter class '{declared}'; {hint + ' ' if hint else ''}known: "
                f"{', '.join(sorted(PARAMETER_SETS))} (prox_workflows/parameters.py), or leave "
                "'params:' out when the steps' own settings are all the script reads"]
    return []


def _workspace_types(script: dict[str, Any], workspace: dict[str, Any] | Iterable[str] | None, where0: str,
                     problems: list[str]) -> dict[str, str]:
    """What the workspace holds before the first step: the declared inputs, then the caller's."""
    declared_inputs = script.get("inputs") or {}
    if not isinstance(declared_inputs, dict):
        problems.append(f"{where0}: 'inputs:' must map each input to its type (base: Layers?)")
        declared_inputs = {}
    avail: dict[str, str] = {k: str(v) for k, v in declared_inputs.items()}
    if workspace is None:
        return avail
    supplied = set(workspace)
    for k, t in avail.items():
        if k not in supplied and not str(t).endswith("?"):
            problems.append(f"{where0}: input '{k}' ({t}) is declared under inputs: but the caller does not "
                            f"supply it; pass it (rvs-prox --input {k}=...) or declare it optional ({t}?)")
    if isinstance(workspace, dict):
        for k, v in workspace.items():
            avail.setdefault(k, "any" if v is not None else "none")
    else:
        for k in workspace:
            avail.setdefault(k, "any")
    return avail


class _Check:
    """One pass over a script's steps: the type of every value the workspace holds so far, where
    each output was made and whether anything read it, and the problems found (appended in the
    order the script is written)."""

    def __init__(self, script: dict[str, Any], reg: dict[str, StepSpec], ptypes: dict[str, str],
                 avail: dict[str, str], problems: list[str]) -> None:
        self.script = script
        self.reg = reg
        self.ptypes = ptypes
        self.avail = avail
        self.problems = problems
        self.produced_at: dict[str, str] = {}  # output -> where it was made
        self.read: set[str] = set()
        self.later_outputs = _all_outputs(script)

    def ref(self, expr: Any, want: str, where: str, what: str, item: str | None) -> None:
        """A wired value: a reference must name something there by then, of a type that fits."""
        if isinstance(expr, dict | list):
            for v in expr.values() if isinstance(expr, dict) else expr:
                self.ref(v, "any", where, what, item)
            return
        if not (isinstance(expr, str) and expr[:1] in "$@"):
            got = literal_type(expr)
            if not compatible(got, want):
                self.problems.append(f"{where}: {what} wants {want} but the literal {expr!r} is {got}; give a {want}")
            return
        if len(expr) < 2 or not expr[1:2].isidentifier():
            self.problems.append(f"{where}: {what} '{expr}' is not a reference; write $param or @value")
            return
        got = self._param_ref(expr, where, what) if expr[0] == "$" else self._value_ref(expr, where, what, item)
        if got is not None and not compatible(got, want):
            self.problems.append(f"{where}: {what} wants {want} but {expr} is {got}; wire a value of that type")

    def _param_ref(self, expr: str, where: str, what: str) -> str | None:
        head, *rest = expr[1:].split(".")
        if head not in self.ptypes:
            hint = _suggest(head, self.ptypes)
            self.problems.append(f"{where}: {what} reads parameter ${head}, which no one supplies; "
                                 f"{hint + ' ' if hint else ''}declare it in the parameter class "
                                 f"or pass it (--set {head}=...)")
            return None
        return self.ptypes[head] if not rest else "any"

    def _value_ref(self, expr: str, where: str, what: str, item: str | None) -> str | None:
        head, *rest = expr[1:].split(".")
        if head == "item":
            if item is None:
                self.problems.append(f"{where}: {what} reads @item outside a foreach; add foreach: or "
                                     "name a workspace value")
                return None
            return item if not rest else "any"
        if head not in self.avail:
            if head in self.later_outputs:
                self.problems.append(f"{where}: {what} reads @{head} before a step makes it; move "
                                     f"this step after the one with out: {head}")
            else:
                hint = _suggest(head, list(self.avail))
                self.problems.append(f"{where}: {what} reads @{head}, which no step makes and the caller "
                                     f"does not supply; {hint + ' ' if hint else ''}add it under inputs: "
                                     "or to a step's out:")
            return None
        self.read.add(head)
        return self.avail[head] if not rest else "any"

    def phases(self, where0: str) -> None:
        """At least one step, and each phase's steps together (progress counts a phase once)."""
        specs = self.script.get("steps") or []
        if not any(isinstance(s, dict) and s.get("step") for s in specs):
            self.problems.append(f"{where0}: the script has no steps; add at least one '- step: NAME'")
        seen_phases: list[str] = []
        for index, spec in enumerate(specs):
            phase = str(spec.get("phase", "process")) if isinstance(spec, dict) else "process"
            if seen_phases and seen_phases[-1] != phase and phase in seen_phases:
                self.problems.append(f"{_where(self.script, spec, index)}: phase '{phase}' is split: its steps "
                                     "must follow one another; move this step next to the others of its phase")
            seen_phases.append(phase)

    def step(self, index: int, spec: Any) -> None:
        where = _where(self.script, spec, index)
        if not isinstance(spec, dict):
            self.problems.append(f"{where}: a step is a mapping (- step: NAME, in: ..., out: ...), not {spec!r}")
            return
        for key in spec:
            if key not in STEP_KEYS:
                hint = _suggest(str(key), STEP_KEYS)
                self.problems.append(f"{where}: unknown key '{key}' in a step; "
                                     f"{hint or 'use one of ' + ', '.join(sorted(STEP_KEYS))}")
        sname = spec.get("step")
        sspec = self.reg.get(sname) if sname else None
        if sspec is None:
            self._unknown_step(spec, sname, where)
            return
        item_type = self._foreach(spec, where)
        if "when" in spec:
            self.ref(spec["when"], "any", where, "when", item_type)
        self._inputs(spec, sspec, where, item_type)
        self._outputs(spec, sspec, where)

    def _unknown_step(self, spec: dict[str, Any], sname: Any, where: str) -> None:
        if not sname:
            self.problems.append(f"{where}: a step without a name; write '- step: NAME'")
        else:
            hint = _suggest(str(sname), self.reg)
            self.problems.append(f"{where}: unknown step '{sname}'; "
                                 f"{hint or 'known steps: ' + ', '.join(sorted(self.reg))}")
        for n in output_names(spec.get("out")):  # its outputs exist as far as the later steps care
            if isinstance(n, str):
                self.avail[n] = "any"
                self.produced_at[n] = where
                self.read.add(n)

    def _foreach(self, spec: dict[str, Any], where: str) -> str | None:
        """The type of ``@item`` in the step (None without foreach)."""
        if "foreach" not in spec:
            return None
        fe = spec["foreach"]
        if isinstance(fe, list):
            return "any"
        if isinstance(fe, str) and fe[:1] in "@$":
            self.ref(fe, "list", where, "foreach", None)
            head = fe[1:].split(".")[0]
            src = self.avail.get(head) if fe[0] == "@" else self.ptypes.get(head)
            src = base_type(src)[0] if src else "any"
            return src[5:-1] if src.startswith("list[") else ("float" if src == "floats" else "any")
        self.problems.append(f"{where}: foreach wants a list or @value, not {fe!r}")
        return "any"

    def _inputs(self, spec: dict[str, Any], sspec: StepSpec, where: str, item_type: str | None) -> None:
        sname = sspec.name
        wiring = spec.get("in") or {}
        if not isinstance(wiring, dict):
            self.problems.append(f"{where}: in: maps the step's inputs to values ({{cell: $cell}}), not {wiring!r}")
            wiring = {}
        for key, expr in wiring.items():
            if key not in sspec.inputs:
                hint = _suggest(str(key), sspec.inputs)
                self.problems.append(f"{where}: step {sname} has no input '{key}'; "
                                     f"{hint or 'its inputs: ' + ', '.join(sspec.inputs)}")
                continue
            self.ref(expr, sspec.inputs[key], where, f"input {key} of {sname}", item_type)
        missing = sorted(sspec.required - set(wiring))
        if missing:
            self.problems.append(f"{where}: step {sname} needs input(s) {', '.join(missing)}; add them under in: "
                                 f"({', '.join(f'{m}: ...' for m in missing)})")
        if sspec.settings is not None and "settings" not in wiring:
            unread = [n for n in sspec.settings.specs() if n not in self.ptypes]
            if unread:
                self.problems.append(f"{where}: step {sname} reads its settings ({', '.join(unread)}) from the "
                                     f"parameters, and the caller's class lacks them; derive it from "
                                     f"script_parameters('{self.script.get('name', 'script')}') or wire "
                                     "in: {settings: ...}")

    def _outputs(self, spec: dict[str, Any], sspec: StepSpec, where: str) -> None:
        out = spec.get("out")
        names = output_names(out)
        if out is not None and not isinstance(out, str | list):
            self.problems.append(f"{where}: out: is a name or a list of names, not {out!r}")
            names = []
        names, types = self._output_types(names, sspec, where)
        for n, t in zip(names, types, strict=False):
            if not isinstance(n, str) or not n.isidentifier():
                self.problems.append(f"{where}: output name {n!r} must be a plain name")
                continue
            if n in self.produced_at and n not in self.read:
                self.problems.append(f"{where}: output '{n}' replaces the one made at {self.produced_at[n]} before "
                                     "anything read it; rename one")
            self.avail[n] = f"list[{t}]" if "foreach" in spec else t
            self.produced_at[n] = where
            self.read.discard(n)

    def _output_types(self, names: list[Any], sspec: StepSpec, where: str) -> tuple[list[Any], list[str]]:
        """The names out: gives (at most as many as the step makes) and the types they get."""
        if sspec.outputs is None:
            return names, ["any"] * len(names)
        sname = sspec.name
        declared = list(sspec.outputs.items())
        if len(names) > len(declared):
            self.problems.append(f"{where}: step {sname} makes {len(declared)} output(s) "
                                 f"({', '.join(n for n, _ in declared)}) but out: names {len(names)}; "
                                 "name at most that many")
            names = names[:len(declared)]
        elif len(names) > 1 and len(names) < len(declared):
            self.problems.append(f"{where}: out: of step {sname} names {len(names)} of its {len(declared)} "
                                 f"outputs ({', '.join(n for n, _ in declared)}); name them all, in order")
        return names, [t for _, t in declared[:len(names)]]

    def finals(self, where0: str) -> None:
        """What the caller reads afterwards is made, and every other output is read by a later step."""
        wanted = self.script.get("outputs")
        if wanted is None:
            last = next((s for s in reversed(self.script.get("steps") or []) if isinstance(s, dict)), {})
            finals = set(output_names(last.get("out")))
        else:
            finals = set(output_names(wanted))
            for n in finals - set(self.avail):
                self.problems.append(f"{where0}: outputs: lists '{n}', which no step makes; drop it or make it")
        for n, where in self.produced_at.items():
            if n not in self.read and n not in finals:
                self.problems.append(f"{where}: output '{n}' is never used; read it in a later step, list it "
                                     "under outputs:, or drop it from out:")


def _all_outputs(script: dict[str, Any]) -> set[str]:
    out: set[str] = set()
    for spec in script.get("steps") or []:
        if isinstance(spec, dict):
            out.update(n for n in output_names(spec.get("out")) if isinstance(n, str))
    return out


def output_names(out: Any) -> list[str]:
    if out is None:
        return []
    return [out] if isinstance(out, str) else list(out)
