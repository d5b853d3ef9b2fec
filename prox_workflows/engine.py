"""The PROX-like workflow engine: runs a YAML script of steps over a workspace of named values.

A script (``prox_workflows/scripts/*.yaml``) names step functions and wires their inputs and
outputs, so the chain DemImport -> DemMosaik -> holes -> Dem2Hazard -> ortho is data a scientist
can read and change, not code (as PROX scripts were in the thesis):

    name: dem-tof
    params: {cell: 0.02}                  # defaults, overridden by the caller / --set
    steps:
      - step: dem_import                  # a function registered in STEPS (or given by the caller)
        foreach: "@views"                 # optional: run once per item, outputs collected in a list
        in: {points: "@item.points", cell: "$cell"}
        out: view_dems
      - step: dem_mosaik
        in: {dems: "@view_dems", rule: fuse}
        out: dem
        when: "$fuse"                     # optional: skip the step when the value is false

Values: ``$name`` is a parameter, ``@name`` a workspace value (``@a.b`` an attribute or key of
it), anything else is a literal. A step with several outputs returns a dict or tuple that ``out``
(a list) names. Cancellation is checked before every step and every loop item; progress is
reported per step and per item; every step's time and outputs go to the run log.
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

SCRIPTS_DIR = Path(__file__).resolve().parent / "scripts"

# Step name -> "module:function", imported on first use so that a script only pays for its steps.
STEPS: dict[str, str] = {
    "get_ptu_positions": "prox_workflows.steps.ptu_positions:get_ptu_positions",
    "join_views": "prox_workflows.steps.dem_chain:join_views",
    "view_dem": "prox_workflows.steps.dem_chain:view_dem",
    "mosaic": "prox_workflows.steps.dem_chain:mosaic",
    "remove_spikes_layers": "prox_workflows.steps.spikes:remove_spikes_layers",
    "fill_holes_layers": "prox_workflows.steps.dem_chain:fill_holes_layers",
    "hazard_layers": "prox_workflows.steps.dem_chain:hazard_layers",
    "ortho_layer": "prox_workflows.steps.dem_chain:ortho_layer",
}


class WorkflowError(Exception):
    """A script that cannot run: unknown step, missing value, bad wiring."""


class Cancelled(Exception):
    """The caller asked the workflow to stop; raised at the next step or item boundary."""


@dataclass
class RunLog:
    """What ran, how long it took and what it produced (kept with the products)."""

    script: str
    entries: list[dict[str, Any]] = field(default_factory=list)

    def add(self, step: str, seconds: float, **info: Any) -> None:
        self.entries.append({"step": step, "seconds": round(seconds, 4), **info})

    def as_dict(self) -> dict[str, Any]:
        return {"script": self.script, "steps": self.entries}


def load_script(name_or_path: str | Path) -> dict[str, Any]:
    path = Path(name_or_path)
    if not path.suffix:
        path = SCRIPTS_DIR / f"{path.name}.yaml"
    if not path.is_file():
        raise WorkflowError(f"no workflow script {name_or_path} (looked at {path})")
    script = yaml.safe_load(path.read_text()) or {}
    if not isinstance(script.get("steps"), list):
        raise WorkflowError(f"{path}: a script needs a list of steps")
    script.setdefault("name", path.stem)
    return script


def resolve_step(name: str, extra: dict[str, Callable[..., Any]] | None = None) -> Callable[..., Any]:
    if extra and name in extra:
        return extra[name]
    target = STEPS.get(name)
    if target is None:
        known = sorted(set(STEPS) | set(extra or {}))
        raise WorkflowError(f"unknown step '{name}'; known steps: {', '.join(known)}")
    module, _, func = target.partition(":")
    return getattr(importlib.import_module(module), func)


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


def run_workflow(
    script: dict[str, Any] | str | Path,
    params: dict[str, Any] | None = None,
    workspace: dict[str, Any] | None = None,
    *,
    steps: dict[str, Callable[..., Any]] | None = None,
    progress: Progress | None = None,
    cancelled: Callable[[], bool] | None = None,
) -> tuple[dict[str, Any], RunLog]:
    """Run a script; returns the final workspace and the run log.

    ``steps`` adds or overrides step functions (the server passes its device-backed
    acquisition this way, so this package never imports the drivers). Progress is reported
    per phase (``phase:`` of the steps): a phase of several steps counts its steps; a phase of
    one step that accepts a ``progress`` keyword reports that step's own count (views).
    Within a phase ``total`` is fixed and ``done`` only grows.
    """
    if not isinstance(script, dict):
        script = load_script(script)
    merged = {**(script.get("params") or {}), **(params or {})}
    ws: dict[str, Any] = dict(workspace or {})
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
        name = spec.get("step")
        if not name:
            raise WorkflowError(f"a step without a name in {log.script}: {spec}")
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
            result = fn(**kwargs)
        _store(spec, result, ws, name)
        log.add(name, time.perf_counter() - t0, outputs=_names(spec.get("out")))
        if not (own_count and "progress" in accepts):
            report(name if "foreach" not in spec else f"{name} x{len(result)}")
    return ws, log


def _names(out: Any) -> list[str]:
    if out is None:
        return []
    return [out] if isinstance(out, str) else list(out)


def _store(spec: dict[str, Any], result: Any, ws: dict[str, Any], name: str) -> None:
    names = _names(spec.get("out"))
    if not names:
        return
    if len(names) == 1:
        ws[names[0]] = result
        return
    if isinstance(result, dict):
        missing = [n for n in names if n not in result]
        if missing:
            raise WorkflowError(f"step {name} did not produce {', '.join(missing)}")
        for n in names:
            ws[n] = result[n]
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


def main(argv: list[str] | None = None) -> int:
    """``rvs-prox SCRIPT --set key=value``: run a workflow script outside the server."""
    ap = argparse.ArgumentParser(prog="rvs-prox", description="Run a PROX-like workflow script.")
    ap.add_argument("script", help="script name (in prox_workflows/scripts) or path")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="set a parameter")
    ap.add_argument("--log", help="write the run log (YAML) here")
    args = ap.parse_args(argv)
    params: dict[str, Any] = {}
    for item in args.set:
        key, sep, raw = item.partition("=")
        if not sep:
            ap.error(f"--set {item}: write key=value")
        params[key] = _parse_value(raw)

    def show(done: int, total: int, message: str, phase: str = "") -> None:
        width = 30
        filled = int(width * done / max(total, 1))
        sys.stderr.write(f"\r{phase[:10]:<10} [{'#' * filled}{'.' * (width - filled)}] {done}/{total} "
                         f"{message[:40]:<40}")
        sys.stderr.flush()

    try:
        ws, log = run_workflow(args.script, params, progress=show)
    except (WorkflowError, FileNotFoundError, ValueError) as exc:
        sys.stderr.write(f"\nrvs-prox: {exc}\n")
        return 1
    except KeyboardInterrupt:
        sys.stderr.write("\nrvs-prox: interrupted\n")
        return 130
    sys.stderr.write("\n")
    text = yaml.safe_dump(log.as_dict(), sort_keys=False)
    if args.log:
        Path(args.log).write_text(text)
    print(text, end="")
    for key, value in ws.items():
        if isinstance(value, str | int | float | Path):
            print(f"{key}: {value}")
    return 0
