"""Where the rover was set down: the plane of the ground round it, for the ground no sensor shows.

The mast's blind disc (about 0.7 m round its foot) is never seen, and the rover must drive out
of it. A prior there taken level meets sloped seen ground in a step at the disc's edge (12 cm on
a 10 deg slope), which the vehicle check refuses at every pose that straddles it; the plane the
wheels rest on (the IMU's) tips with a rock under one wheel. The ring of seen ground just
outside the disc says how the ground round the rover runs: :func:`ring_plane` fits it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["ring_plane", "MIN_CELLS"]

MIN_CELLS = 50  # seen cells in the ring below which the plane is not fitted (level instead)
OUTLIER = 0.02  # m: cells further than this (or twice the residuals' sd) from the first fit are rocks


def ring_plane(bounds: Any, centre: tuple[float, float], inner: float, outer: float, at: tuple[float, float]
               ) -> tuple[tuple[float, float, float], str]:
    """The plane z = z0 + gx (x - at_x) + gy (y - at_y) fitted to the frames' mean heights of the
    bounds map's cells between ``inner`` and ``outer`` metres from ``centre`` (cells a frame
    bounded; rocks dropped as outliers of a first fit), and a sentence saying what it took.
    With fewer than :data:`MIN_CELLS` such cells: level at 0 (the frames' datum, the rover's
    own ground)."""
    g = bounds.geometry
    c0 = max(0, int(math.floor((centre[0] - outer - g.xmin) / g.cell)))
    c1 = min(g.width, int(math.ceil((centre[0] + outer - g.xmin) / g.cell)))
    r0 = max(0, int(math.floor((g.ymax - centre[1] - outer) / g.cell)))
    r1 = min(g.height, int(math.ceil((g.ymax - centre[1] + outer) / g.cell)))
    if r1 <= r0 or c1 <= c0:
        return (0.0, 0.0, 0.0), "level ground (the map does not reach round the rover)"
    rows, cols = np.mgrid[r0:r1, c0:c1]
    xs = g.xmin + (cols + 0.5) * g.cell
    ys = g.ymax - (rows + 0.5) * g.cell
    dist = np.hypot(xs - centre[0], ys - centre[1])
    z = bounds.mean[r0:r1, c0:c1].astype(np.float64)
    use = (dist >= inner) & (dist <= outer) & np.isfinite(z) & (bounds.stamp[r0:r1, c0:c1] > 0)
    if use.sum() < MIN_CELLS:
        return (0.0, 0.0, 0.0), f"level ground (only {int(use.sum())} cells seen round the blind disc)"
    dx, dy, h = xs[use] - at[0], ys[use] - at[1], z[use]
    a = np.column_stack([np.ones(len(h)), dx, dy])
    coef = np.linalg.lstsq(a, h, rcond=None)[0]
    res = h - a @ coef
    keep = np.abs(res) <= max(OUTLIER, 2.0 * float(np.std(res)))
    if keep.sum() >= MIN_CELLS:
        coef = np.linalg.lstsq(a[keep], h[keep], rcond=None)[0]
    z0, gx, gy = (float(v) for v in coef)
    tilt = math.degrees(math.atan(math.hypot(gx, gy)))
    return (z0, gx, gy), f"the plane of {int(keep.sum())} seen cells round the blind disc ({tilt:.1f} deg)"
