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

Values: ``$name`` is a parameter, ``@name`` a workspace value (``@a.b`` an attribute or key of
it), anything else a literal. A script's parameters are its own class's fields (``params:``, the
settings no single step owns) and those of its steps' own settings classes
(``@step(..., settings=SpikeRemoval)``), composed by :func:`.settings.script_parameters`: a step
reads its settings with no wiring, and each is declared once, with its default, beside the step.
Each step's input types are its function's annotations, and it declares its outputs with types
(``@step("dem_import", outputs={"layers": "Layers"})``); :func:`validate` checks the whole script
against those declarations before the first step runs (unknown step, unknown or missing input,
type mismatch, unused output, a ``$param`` nobody supplies, a step setting its caller's class
lacks, ...) and names the script line and the fix of every mistake. Cancellation is checked
before every step and every loop item; progress is reported per phase; every step's time and
outputs go to the run log.

The engine is this package: :mod:`.types` (the value types and which fits where), :mod:`.registry`
(``@step`` and the step modules), :mod:`.settings` (a script's parameters composed from its steps'
settings), :mod:`.loader` (scripts from YAML, lines kept), :mod:`.validation`
(the whole script checked first) and :mod:`.run` (phases, progress, cancellation, the run log).
The ``rvs-prox`` program is :mod:`prox_workflows.cli.prox`.
"""

from __future__ import annotations

from .errors import Cancelled, ScriptError, WorkflowError
from .loader import SCRIPTS_DIR, load_script, script_path
from .registry import INJECTED, PARAMETER_MODULES, STEP_MODULES, StepSpec, registry, resolve_step, step
from .run import Progress, RunLog, evaluate, phases_of, resolve_params, run_workflow
from .settings import compose, parameters_of, script_parameters, step_settings
from .types import compatible, literal_type
from .validation import output_names, param_class, param_types, validate

__all__ = [
    "INJECTED", "PARAMETER_MODULES", "SCRIPTS_DIR", "STEP_MODULES", "Cancelled", "Progress", "RunLog",
    "ScriptError", "StepSpec", "WorkflowError", "compatible", "compose", "evaluate", "literal_type", "load_script",
    "output_names", "param_class", "parameters_of", "param_types", "phases_of", "registry", "resolve_params", "resolve_step",
    "run_workflow", "script_parameters", "script_path", "step", "step_settings", "validate",
]
