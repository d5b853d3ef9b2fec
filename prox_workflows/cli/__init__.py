"""Command-line programs of the toolbox steps (rvs-dem-import, rvs-dem-mosaik, rvs-dem2hazard ...):
file I/O at the edges, the algorithms in prox_workflows.steps."""
