"""The step registry: ``@step`` registers a function under the name scripts call it by, with the
types of its inputs and outputs."""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from rvs_params import Settings

from .errors import WorkflowError
from .types import annotation_type

# Modules whose @step functions make up the registry, and those that declare script parameter
# classes beyond them; imported when the registry is first read, so that importing the engine
# stays cheap. (A step module registers the parameter classes it declares itself.)
STEP_MODULES: tuple[str, ...] = tuple(f"prox_workflows.steps.{role}" for role in (
    "read", "scan", "dem", "hazard", "plan", "stereo", "write",
))
PARAMETER_MODULES: tuple[str, ...] = ("prox_workflows.parameters",)

# Keywords the engine passes itself to a step that accepts them; never wired by a script.
INJECTED = ("progress", "cancelled", "run_log")


@dataclass
class StepSpec:
    """A registered step: its function, the types of its inputs (from the function's annotations),
    the declared names and types of its outputs, and the class of its own settings."""

    name: str
    fn: Callable[..., Any]
    inputs: dict[str, str]  # input -> type
    required: set[str]  # inputs without a default
    outputs: dict[str, str] | None  # output -> type, in the order a tuple result gives them; None: free
    accepts: set[str] = field(default_factory=set)  # injected keywords it takes (progress, ...)
    settings: type[Settings] | None = None  # its own settings, the ``settings`` keyword

    @classmethod
    def of(cls, name: str, fn: Callable[..., Any], outputs: dict[str, str] | str | None = None,
           settings: type[Settings] | None = None) -> StepSpec:
        sig = inspect.signature(fn)
        params = {n: p for n, p in sig.parameters.items() if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)}
        ins = {n: _input_type(p.annotation) for n, p in params.items() if n not in INJECTED}
        if settings is not None:
            if "settings" not in params or params["settings"].default is inspect.Parameter.empty:
                raise TypeError(f"step {name}: a step with settings takes them as 'settings=None'")
            ins["settings"] = "dict?"  # wired only to hand the step other values than the script's
        required = {n for n in ins if params[n].default is inspect.Parameter.empty}
        outs = {name: outputs} if isinstance(outputs, str) else (dict(outputs) if outputs is not None else None)
        return cls(name, fn, ins, required, outs, {n for n in INJECTED if n in params}, settings)


_REGISTRY: dict[str, StepSpec] = {}
_loaded = [False]


def _input_type(annotation: Any) -> str:
    if annotation is inspect.Parameter.empty:
        return "any"
    return annotation_type(annotation if isinstance(annotation, str) else inspect.formatannotation(annotation))


def step(name: str, *, outputs: dict[str, str] | str | None = None, settings: type[Settings] | None = None
         ) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Register a function as the workflow step ``name``.

    The types of its keyword arguments are its annotations (:func:`.types.annotation_type`;
    those without a default are required); ``outputs`` names what it returns: ``{"dem":
    "Layers"}`` for one value, several names for a dict or tuple result. These are what
    :func:`validate` checks a script against, so a miswired script fails before anything runs.

    ``settings`` is the step's own settings class, declared beside it, as a PDAL stage declares
    its arguments: every script that calls the step has its fields as parameters
    (:func:`.settings.script_parameters`), and the engine hands the step an instance of it as
    ``settings`` (from the script's parameters, or from what ``in: {settings: ...}`` wires). A
    setting of the step is then one ``param()`` in that class; its default, range, help, ``--set``,
    ``config -set``, YAML and the server's command options all follow from it.
    """

    def register(fn: Callable[..., Any]) -> Callable[..., Any]:
        _REGISTRY[name] = StepSpec.of(name, fn, outputs, settings)
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
