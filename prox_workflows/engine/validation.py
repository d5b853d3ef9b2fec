"""Validation of a whole script before anything runs: every mistake named with its script line
and the fix."""

from __future__ import annotations

import difflib
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from rvs_params import Settings

from ..params import PARAMETER_SETS
from .errors import ScriptError
from .loader import Lined, load_script
from .registry import StepSpec, registry
from .types import PARAM_KIND, base_type, compatible, literal_type


def _where(script: dict[str, Any], spec: Any, index: int) -> str:
    if isinstance(spec, Lined) and spec.line:
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
        out.update({n: PARAM_KIND.get(s.kind, "any") for n, s in cls.specs().items()})
    for name, value in (params or {}).items():
        out.setdefault(name, literal_type(value))
    return out


STEP_KEYS = {"step", "in", "out", "foreach", "when", "phase"}
SCRIPT_KEYS = {"name", "params", "inputs", "outputs", "steps", "_file"}


def validate(  # noqa: C901 - one pass over the script, so the mistakes come back in the order written
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
            for n in output_names(spec.get("out")):  # its outputs exist as far as the later steps care
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
                src = base_type(src)[0] if src else "any"
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
        names = output_names(out)
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
        finals = set(output_names(last.get("out")))
    else:
        finals = set(output_names(wanted))
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
            out.update(n for n in output_names(spec.get("out")) if isinstance(n, str))
    return out


def output_names(out: Any) -> list[str]:
    if out is None:
        return []
    return [out] if isinstance(out, str) else list(out)
