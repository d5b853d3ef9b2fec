"""The step registry: ``@step`` registers a function under the name scripts call it by, with the
types of its inputs and outputs."""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

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
    """A registered step: its function, the types of its inputs (from the function's annotations)
    and the declared names and types of its outputs."""

    name: str
    fn: Callable[..., Any]
    inputs: dict[str, str]  # input -> type
    required: set[str]  # inputs without a default
    outputs: dict[str, str] | None  # output -> type, in the order a tuple result gives them; None: free
    accepts: set[str] = field(default_factory=set)  # injected keywords it takes (progress, ...)

    @classmethod
    def of(cls, name: str, fn: Callable[..., Any], outputs: dict[str, str] | str | None = None) -> StepSpec:
        sig = inspect.signature(fn)
        params = {n: p for n, p in sig.parameters.items() if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)}
        ins = {n: _input_type(p.annotation) for n, p in params.items() if n not in INJECTED}
        required = {n for n in ins if params[n].default is inspect.Parameter.empty}
        outs = {name: outputs} if isinstance(outputs, str) else (dict(outputs) if outputs is not None else None)
        return cls(name, fn, ins, required, outs, {n for n in INJECTED if n in params})


_REGISTRY: dict[str, StepSpec] = {}
_loaded = [False]


def _input_type(annotation: Any) -> str:
    if annotation is inspect.Parameter.empty:
        return "any"
    return annotation_type(annotation if isinstance(annotation, str) else inspect.formatannotation(annotation))


def step(name: str, *, outputs: dict[str, str] | str | None = None
         ) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Register a function as the workflow step ``name``.

    The types of its keyword arguments are its annotations (:func:`.types.annotation_type`;
    those without a default are required); ``outputs`` names what it returns: ``{"dem":
    "Layers"}`` for one value, several names for a dict or tuple result. These are what
    :func:`validate` checks a script against, so a miswired script fails before anything runs.
    """

    def register(fn: Callable[..., Any]) -> Callable[..., Any]:
        _REGISTRY[name] = StepSpec.of(name, fn, outputs)
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
