"""The hazard map's class codes, as every map file, the planner, the console and a GNC read them.

In the bottom layer because the map writers and viewers (``prox_workflows.layers``,
``mapview``) and the algorithms that make and read hazard maps (Dem2Hazard, the planner) all
need them, and the writers may not depend on the algorithms.
"""

from __future__ import annotations

SAFE = 0
UNDEFINED = 128
HAZARDOUS = 255
CODES = (SAFE, UNDEFINED, HAZARDOUS)
CODES_TEXT = f"{SAFE} safe, {UNDEFINED} undefined, {HAZARDOUS} hazardous"
