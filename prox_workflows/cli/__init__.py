"""Command-line programs of the toolbox steps (rvs-dem-import, rvs-dem-mosaik, rvs-dem2hazard ...):
file I/O at the edges, the algorithms in prox_workflows.algorithms. Each parses its command line with
:class:`prox_workflows.cli.parser.ToolParser`, so coordinates and bounds may be negative lists."""
