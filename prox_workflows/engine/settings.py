"""A script's parameters, composed from what declares them: the script's own class (``params:``,
for the settings no single step owns, such as the cell size every step of a DEM shares) and the
settings class of every step it calls, the way a device's settings are composed from its front
end's and its backends' (``drivers.registry``). A step's setting is so declared once, beside the
step, and every script that runs the step, the server's command that runs the script, ``--set``,
``config -set``, YAML and help read that one declaration.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import Any

from rvs_params import Settings

from ..params import PARAMETER_SETS
from .errors import WorkflowError
from .loader import load_script
from .registry import registry


def step_settings(script: dict[str, Any]) -> tuple[type[Settings], ...]:
    """The settings classes of the steps the script calls, in script order, each once; a step the
    script hands its settings (``in: {settings: ...}``) reads no parameter of it."""
    reg = registry()
    found: dict[type[Settings], None] = {}
    for spec in script.get("steps") or []:
        if not isinstance(spec, dict):
            continue
        declared = reg.get(spec.get("step"))  # type: ignore[arg-type]
        wiring = spec.get("in")
        if declared is None or declared.settings is None or (isinstance(wiring, dict) and "settings" in wiring):
            continue
        found[declared.settings] = None
    return tuple(found)


def script_parameters(script: dict[str, Any] | str | Path, own: type[Settings] | None = None
                      ) -> type[Settings] | None:
    """The parameter class of a script: ``own`` (default: the class its ``params:`` names)
    composed with its steps' settings; None for a script that reads no parameter."""
    if not isinstance(script, dict):
        script = load_script(script)
    if own is None and isinstance(script.get("params"), str):
        registry()  # the step modules register the parameter classes they declare
        own = PARAMETER_SETS.get(script["params"])
    return compose(own, step_settings(script))


def parameters_of(script: dict[str, Any] | str | Path, own: type[Settings] | None = None) -> type[Settings]:
    """:func:`script_parameters` for a caller that runs the script with its parameters (a command's
    config derives from it, a CLI lists it): a script that reads none is a mistake there."""
    cls = script_parameters(script, own)
    if cls is None:
        name = script.get("name", "script") if isinstance(script, dict) else str(script)
        raise WorkflowError(f"workflow {name} reads no parameter: there is no parameter class to derive from")
    return cls


@functools.cache
def compose(own: type[Settings] | None, steps: tuple[type[Settings], ...]) -> type[Settings] | None:
    """One class with the fields of ``own`` (first) and of each step's settings, refusing a name
    two of them declare: a parameter has one declaration, so two steps' settings must not both
    claim one (share a settings class, or rename one)."""
    classes = ([own] if own is not None else []) + [c for c in steps if own is None or not issubclass(own, c)]
    if len(classes) <= 1:
        return classes[0] if classes else None
    owner: dict[str, type[Settings]] = {}
    for cls in classes:
        for f in dataclasses.fields(cls):
            first = owner.setdefault(f.name, cls)
            if first is not cls and not issubclass(first, cls):
                raise WorkflowError(f"parameter '{f.name}' is declared by both {first.__name__} and "
                                    f"{cls.__name__}; a parameter has one declaration: let one settings "
                                    "class hold it, or rename one")
    composed = dataclasses.make_dataclass(classes[0].__name__, [], bases=tuple(reversed(classes)))
    composed.__doc__ = classes[0].__doc__
    composed.__module__ = __name__
    return composed
