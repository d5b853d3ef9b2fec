"""The algorithms of the toolbox: plain functions on arrays, with their file I/O at the edges.

DemImport, DemMosaik, Dem2Hazard, hole filling, the noise models, stereo matching, odometry,
the planners, the bounds map, the vehicle gate...: each takes and returns numpy arrays,
:class:`~prox_workflows.grid.Layers`, views and paths, never devices, so the same function
serves a server job, a command-line tool, a benchmark and a test. An algorithm's own settings
(its thresholds, windows, rules) are one :class:`rvs_params.Settings` class declared beside it;
those a script takes are registered with :func:`prox_workflows.params.parameters` under the
name scripts give in ``params:`` (Dem2Hazard's ``hazard``, DemMosaik's ``dem_mosaik``).

Nothing here is registered with the workflow engine and nothing here imports it: the thin
registered steps that scripts call by name are in :mod:`prox_workflows.steps`. Modules whose
name starts with ``_`` hold compiled kernels, imported by their module on first use.
"""
