"""Values as YAML's safe dumper takes them, for every file and console listing the project writes.

numpy scalars and arrays, paths and tuples come out of the algorithms and devices; ``safe_dump``
refuses the first three, and a numpy scalar that reached a manifest mid-break once lost the
recovery set. NaN becomes null, which every YAML reader takes as "not defined".
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


def plain(value: Any, *, decimals: int | None = None) -> Any:
    """``value`` with its containers, numpy values and paths made plain Python; arrays rounded to
    ``decimals`` when given (a console listing a calibration matrix)."""
    if isinstance(value, dict):
        return {str(k): plain(v, decimals=decimals) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [plain(v, decimals=decimals) for v in value]
    if isinstance(value, np.ndarray):
        return (value if decimals is None else np.round(value, decimals)).tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, float) and value != value:
        return None
    return value
