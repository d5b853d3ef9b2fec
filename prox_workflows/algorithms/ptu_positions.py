"""GetPtuPositions: the pan/tilt pointings that cover a view range with a sensor's field of view,
in the order the PTU reaches them soonest, and what the hardware allows for such a scan.

The range is the angular extent to cover (its edges), so a view range as wide as the field of
view is one view. Neighbouring views overlap by at least ``overlap`` of the field of view, so
that DemMosaik has common cells to fuse and no gaps open between views; per axis that is the
fewest views that do it. Pointings are clipped to the PTU limits.

Order: a serpentine (boustrophedon), by rows (pan sweeps, the tilt changing at the row ends) or
by columns (tilt sweeps, the pan stepping at the column ends), from whichever corner; given the
PTU's motion (its speed, acceleration and base speed per axis) and where it stands, the one it
travels soonest. The D46 runs both axes at once, so a move lasts as long as its slower axis:
with a scan's few tilt rows close together, the columns are usually the shorter path (each
column's tilt step is short, the pan crosses the range once). Without the motion, the rows from
the lowest pan and tilt (the order a PTU needs no model for).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from rvs_params.motion import trapezoid_time

# per axis ("pan", "tilt"): {"speed": deg/s, "acceleration": deg/s^2, "base": deg/s}
Motion = Mapping[str, Mapping[str, float]]
ORDERS = ("fastest", "rows")


def _axis(lo: float, hi: float, fov: float, overlap: float) -> list[float]:
    span = hi - lo
    if span <= fov:
        return [(lo + hi) / 2.0]
    step = fov * (1.0 - overlap)
    n = math.ceil((span - fov) / step - 1e-9) + 1
    return list(np.linspace(lo + fov / 2.0, hi - fov / 2.0, n))


def grid(view_range: Sequence[float], fov: Sequence[float], overlap: float,
         limits: Sequence[float] | None = None) -> tuple[list[float], list[float]]:
    """The fewest pans and tilts (each ascending) that cover ``view_range`` at ``overlap``."""
    pan_min, pan_max, tilt_min, tilt_max = (float(v) for v in view_range)
    if pan_max < pan_min or tilt_max < tilt_min:
        raise ValueError("the view range must be pan_min,pan_max,tilt_min,tilt_max with min <= max")
    if not 0.0 <= overlap < 1.0:
        raise ValueError("overlap must be in [0, 1)")
    pans = _axis(pan_min, pan_max, float(fov[0]), overlap)
    tilts = _axis(tilt_min, tilt_max, float(fov[1]), overlap)
    if limits is not None:
        pans = list(np.clip(pans, limits[0], limits[1]))
        tilts = list(np.clip(tilts, limits[2], limits[3]))
    return [round(float(p), 4) for p in pans], [round(float(t), 4) for t in tilts]


def serpentines(pans: list[float], tilts: list[float]) -> list[list[tuple[float, float]]]:
    """Every boustrophedon over the grid: by rows or by columns, from each of its four corners
    (the first is by rows from the lowest pan and tilt)."""
    out: list[list[tuple[float, float]]] = []
    for by_rows in (True, False):
        for outer_rev in (False, True):
            for inner_rev in (False, True):
                outer = tilts if by_rows else pans
                inner = pans if by_rows else tilts
                seq: list[tuple[float, float]] = []
                for i, o in enumerate(outer[::-1] if outer_rev else outer):
                    row = inner[::-1] if (i % 2 == 1) != inner_rev else inner
                    seq += [(p, o) if by_rows else (o, p) for p in row]
                out.append(list(dict.fromkeys(seq)))  # a clipped grid repeats pointings
    return out


def move_time(a: tuple[float, float], b: tuple[float, float], motion: Motion) -> float:
    """Seconds the PTU takes from pointing ``a`` to rest at ``b``: both axes move at once, each
    on its trapezoid (speed, acceleration, base speed), the move ends with the slower."""
    return max(trapezoid_time(b[k] - a[k], m["speed"], m["acceleration"], m.get("base", 0.0))
               for k, m in enumerate((motion["pan"], motion["tilt"])))


def path_time(positions: Sequence[tuple[float, float]], motion: Motion,
              start: tuple[float, float] | None = None) -> float:
    """The PTU's travel through ``positions`` in order (from ``start`` if given), at rest at each."""
    seq = ([tuple(start)] if start is not None else []) + [tuple(p) for p in positions]
    return sum(move_time(a, b, motion) for a, b in zip(seq, seq[1:], strict=False))


def plan(view_range: Sequence[float], fov: Sequence[float], overlap: float = 0.2,
         limits: Sequence[float] | None = None, motion: Motion | None = None,
         start: tuple[float, float] | None = None, order: str = "fastest") -> list[tuple[float, float]]:
    """The pointings in the order the scan takes them (see the module docstring)."""
    if order not in ORDERS:
        raise ValueError(f"order must be one of {', '.join(ORDERS)}")
    candidates = serpentines(*grid(view_range, fov, overlap, limits))
    if order == "rows" or motion is None:
        return candidates[0]
    return min(candidates, key=lambda seq: path_time(seq, motion, start))


def scan_limit(view_range: Sequence[float], fov: Sequence[float], overlap: float, limits: Sequence[float] | None,
               motion: Motion, start: tuple[float, float] | None, view_seconds: float) -> dict[str, Any]:
    """What the hardware allows for this scan: the fewest views, the PTU's travel along the
    shortest serpentine through them from ``start``, and ``view_seconds`` of exposure at each
    (the ToF's frames at rest). Processing, rendering and the serial line are not in it."""
    positions = plan(view_range, fov, overlap, limits, motion, start)
    travel = path_time(positions, motion, start)
    exposure = len(positions) * view_seconds
    return {"views": len(positions), "travel": travel, "exposure": exposure, "total": travel + exposure}
