"""Parameters declared once: a workflow script's own parameter class, registered by name.

A parameter class (a :class:`rvs_params.Settings` dataclass of :func:`rvs_params.param`
fields) declares the parameters no single step owns: a script names its class (``params: dem``)
and receives the values as ``$cell`` etc. Its steps' own settings classes join it
(:func:`prox_workflows.engine.script_parameters`); ``rvs-prox SCRIPT --help`` lists the result,
and the server's per-command config classes (``rvs_server/commands/*.py``) derive from it, so
``help dem-full-tof`` lists the same parameters with the same defaults, and its E_ARG checks are
the same ``ParamSpec.parse``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rvs_params import Settings


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


# Parameter classes of the workflow scripts, by the name a script's ``params:`` gives.
PARAMETER_SETS: dict[str, type[Settings]] = {}


def parameters(name: str) -> Callable[[type[Settings]], type[Settings]]:
    """Register a parameter class under the name scripts use (``params: dem``)."""

    def register(cls: type[Settings]) -> type[Settings]:
        PARAMETER_SETS[name] = cls
        return cls

    return register
