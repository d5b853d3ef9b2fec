"""Running a validated script: phases, progress, cancellation, the run log."""

from __future__ import annotations

import inspect
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rvs_params import Settings

from .errors import Cancelled, WorkflowError
from .loader import load_script
from .registry import registry, resolve_step
from .validation import output_names, param_class, validate


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
        declared = registry().get(name)
        settings = declared.settings if declared is not None else None
        t0 = time.perf_counter()
        if "foreach" in spec:
            result: Any = _call_each(fn, spec, ws, merged, check, settings)
        else:
            own = progress if own_count else None
            kwargs = _kwargs(spec, ws, merged, accepts, _phase_progress(own, phase), cancelled, log)
            result = fn(**_with_settings(kwargs, settings, merged))
        _store(spec, result, ws, name, list(declared.outputs) if declared and declared.outputs else None)
        log.add(name, time.perf_counter() - t0, outputs=output_names(spec.get("out")))
        if not (own_count and "progress" in accepts):
            report(name if "foreach" not in spec else f"{name} x{len(result)}")
    return ws, log


def _call_each(fn: Callable[..., Any], spec: dict[str, Any], ws: dict[str, Any], merged: dict[str, Any],
               check: Callable[[], None], settings: type[Settings] | None) -> list[Any]:
    """A foreach step: once per item (``@item``), the results in a list."""
    items = list(evaluate(spec["foreach"], ws, merged))
    results = []
    for item in items:
        check()
        ws["item"] = item
        results.append(fn(**_with_settings(evaluate(spec.get("in") or {}, ws, merged), settings, merged)))
    ws.pop("item", None)
    return results


def _with_settings(kwargs: dict[str, Any], settings: type[Settings] | None, merged: dict[str, Any]
                   ) -> dict[str, Any]:
    """A step's own settings: from the script's parameters, or what ``in: {settings: ...}``
    wires (None: the declared defaults), checked by the class either way."""
    if settings is not None:
        if "settings" in kwargs:
            kwargs["settings"] = settings.from_mapping(kwargs["settings"], where=f"{settings.__name__} (in: settings)")
        else:
            kwargs["settings"] = settings.picked_from(merged)
    return kwargs


def _phase_progress(progress: Progress | None, phase: str) -> Callable[[int, int, str], None]:
    """A step's own progress as its phase's (a no-op when the phase counts its steps instead)."""
    if progress is None:
        return lambda d, t, m: None
    return lambda d, t, m: progress(d, t, m, phase=phase)


def _kwargs(spec: dict[str, Any], ws: dict[str, Any], merged: dict[str, Any], accepts: Any,
            step_progress: Callable[[int, int, str], None], cancelled: Callable[[], bool] | None,
            log: RunLog) -> dict[str, Any]:
    """The step's wired inputs and the keywords the engine passes itself to a step that takes them."""
    kwargs = evaluate(spec.get("in") or {}, ws, merged)
    if "progress" in accepts:
        kwargs["progress"] = step_progress
    if "cancelled" in accepts:
        kwargs["cancelled"] = cancelled or (lambda: False)
    if "run_log" in accepts:
        kwargs["run_log"] = log.as_dict()
    return kwargs


def _store(spec: dict[str, Any], result: Any, ws: dict[str, Any], name: str,
           declared: list[str] | None = None) -> None:
    names = output_names(spec.get("out"))
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
