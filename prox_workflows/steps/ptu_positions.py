"""GetPtuPositions: the pan/tilt pointings that cover a view range with a sensor's field of view.

The range is the angular extent to cover (its edges), so a view range as wide as the field of
view is one view. Neighbouring views overlap by at least ``overlap`` of the field of view, so
that DemMosaik has common cells to fuse and no gaps open between views. Pointings are clipped
to the PTU limits and ordered as a serpentine (boustrophedon) to keep PTU travel short.
"""

from __future__ import annotations

import math

import numpy as np

from ..engine import step


def _axis(lo: float, hi: float, fov: float, overlap: float) -> list[float]:
    span = hi - lo
    if span <= fov:
        return [(lo + hi) / 2.0]
    step = fov * (1.0 - overlap)
    n = math.ceil((span - fov) / step - 1e-9) + 1
    return list(np.linspace(lo + fov / 2.0, hi - fov / 2.0, n))


@step("get_ptu_positions", inputs={"view_range": "floats", "fov": "floats", "overlap": "float", "limits": "floats?"},
      outputs={"positions": "list"})
def get_ptu_positions(
    view_range: list[float] | tuple[float, float, float, float],
    fov: tuple[float, float],
    overlap: float = 0.2,
    limits: tuple[float, float, float, float] | None = None,
) -> list[tuple[float, float]]:
    """``view_range`` = (pan_min, pan_max, tilt_min, tilt_max) in degrees; ``fov`` = (h, v)."""
    pan_min, pan_max, tilt_min, tilt_max = (float(v) for v in view_range)
    if pan_max < pan_min or tilt_max < tilt_min:
        raise ValueError("the view range must be pan_min,pan_max,tilt_min,tilt_max with min <= max")
    if not 0.0 <= overlap < 1.0:
        raise ValueError("overlap must be in [0, 1)")
    pans = _axis(pan_min, pan_max, fov[0], overlap)
    tilts = _axis(tilt_min, tilt_max, fov[1], overlap)
    if limits is not None:
        pans = list(np.clip(pans, limits[0], limits[1]))
        tilts = list(np.clip(tilts, limits[2], limits[3]))
    out: list[tuple[float, float]] = []
    for i, tilt in enumerate(tilts):
        row = pans if i % 2 == 0 else pans[::-1]
        for pan in row:
            p = (round(float(pan), 4), round(float(tilt), 4))
            if not out or out[-1] != p:
                out.append(p)
    return list(dict.fromkeys(out))
