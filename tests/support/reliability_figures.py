"""The reliability suites' measured figures: percentiles, and the file the results table of
docs/RELIABILITY.md is made from."""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Sequence
from typing import Any

from support.marks import LONG


def record(suite: str, **figures: Any) -> None:
    """Append measured figures to the JSON-lines file named by RVS_RESULTS (for the results table
    of docs/RELIABILITY.md); a no-op without it."""
    path = os.environ.get("RVS_RESULTS")
    if path:
        with open(path, "a", encoding="utf-8") as fh:
            fh.write(json.dumps({"suite": suite, "long": LONG, "time": time.time(), **figures}) + "\n")


def percentile(values: Sequence[float], q: float) -> float:
    if not values:
        return math.nan
    s = sorted(values)
    k = min(len(s) - 1, max(0, math.ceil(q / 100 * len(s)) - 1))
    return s[k]
