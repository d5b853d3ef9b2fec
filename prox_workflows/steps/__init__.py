"""The workflow steps and the algorithms behind them.

A step is one function registered with :func:`prox_workflows.engine.step`: a workflow script
(``prox_workflows/scripts/*.yaml``) calls it by its registered name, wiring its keyword inputs
from the workspace and the script's parameters, and the engine checks that wiring against the
step's declared input and output types before anything runs. Steps take and return arrays,
:class:`~prox_workflows.grid.Layers`, views and paths, never devices, so the same step serves a
server job, a command-line tool and a test.

The modules that register steps are listed in :data:`prox_workflows.engine.STEP_MODULES`; the
others here hold the algorithms the steps call (and the server calls directly). A step's own
settings (its thresholds, windows, rules) are one :class:`rvs_params.Settings` class declared
beside it and registered with :func:`prox_workflows.params.parameters` under the name scripts
give in ``params:`` (Dem2Hazard's ``hazard``, DemMosaik's ``dem_mosaik``).
"""
