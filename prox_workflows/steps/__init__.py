"""The workflow steps: thin functions registered with :func:`prox_workflows.engine.step`, grouped
by role as PDAL groups its stages (readers.*, filters.*, writers.*).

A workflow script (``prox_workflows/scripts/*.yaml``) calls a step by its registered name,
wiring its keyword inputs from the workspace and the script's parameters, and the engine checks
that wiring against the step's input types (its annotations) and declared outputs before
anything runs. A step adapts one algorithm of :mod:`prox_workflows.algorithms` to the values
scripts pass; the work is the algorithm's. The roles, one module each (all listed in
:data:`prox_workflows.engine.STEP_MODULES`):

- :mod:`.read`: where a script's data comes from (recorded views, DEMs, point clouds, maps, a
  stereo pair);
- :mod:`.scan`: the PTU's pointings, the acquisition (supplied by the server) and what a scan's
  views say about themselves;
- :mod:`.dem`: DemImport, DemMosaik, spike removal, hole filling and the ortho-image on layers;
- :mod:`.hazard`: Dem2Hazard on layers;
- :mod:`.plan`: the path planner;
- :mod:`.stereo`: stereo matching and visual odometry;
- :mod:`.write`: where a script's results go (DEM, plan and stereo products with sidecars).
"""
