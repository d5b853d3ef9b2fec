"""The bounds map's ray kernel, compiled on first use (see rvs_params.jit)."""

from __future__ import annotations

import math

import numpy as np

from rvs_params.jit import jit


@jit
def lower_ceiling(ox: float, oy: float, oz: float, px: np.ndarray, py: np.ndarray, pz: np.ndarray,
                  xmin: float, ymax: float, cell: float, near: float, reach: float, ceiling: np.ndarray) -> None:
    """Lower ``ceiling`` (rows north-first) to the height of each ray from the sensor at
    (ox, oy, oz) to a return (px, py, pz) over the cells it crosses, up to ``near`` metres
    (horizontally) short of the return. Sampled once a cell: a ray crossing a cell's corner
    may skip it, which only leaves that cell's bound where it was. Only the stretch where the ray
    is at most ``reach`` above its return is walked: higher up it bounds nothing a rover meets."""
    h, w = ceiling.shape
    step = cell
    for i in range(px.shape[0]):
        dx = px[i] - ox
        dy = py[i] - oy
        dz = pz[i] - oz
        length = math.sqrt(dx * dx + dy * dy)
        if length <= near:
            continue
        n = int((length - near) / step)
        j0 = 1
        if oz - pz[i] > reach:  # the ray comes down to ``reach`` over its return only at t_reach
            j0 = max(1, int((1.0 - reach / (oz - pz[i])) * length / step))
        for j in range(j0, n + 1):
            t = j * step / length
            c = int(math.floor((ox + t * dx - xmin) / cell))
            r = int(math.floor((ymax - (oy + t * dy)) / cell))
            if 0 <= r < h and 0 <= c < w:
                z = oz + t * dz
                if z < ceiling[r, c]:
                    ceiling[r, c] = z


@jit
def spread_extremes(top: np.ndarray, bottom: np.ndarray, index: np.ndarray, start: np.ndarray, dr: np.ndarray,
                    dc: np.ndarray, up: np.ndarray, lo: np.ndarray) -> None:
    """Raise ``up`` to each cell's ``top`` and lower ``lo`` to its ``bottom`` over the cells its
    spread reaches: cell (r, c) of shape ``index[r, c]`` (-1: none) reaches (r + dr[j], c + dc[j])
    for j in ``start[index]:start[index + 1]``. The scatter form of a dilation of the tops and an
    erosion of the bottoms by each shape's structuring element: the cost is the cells spread times
    their shapes' sizes, where the image form passes over the whole grid once per shape."""
    h, w = top.shape
    for r in range(h):
        for c in range(w):
            k = index[r, c]
            if k < 0:
                continue
            t = top[r, c]
            b = bottom[r, c]
            for j in range(start[k], start[k + 1]):
                rr = r + dr[j]
                cc = c + dc[j]
                if rr < 0 or rr >= h or cc < 0 or cc >= w:
                    continue
                if t > up[rr, cc]:
                    up[rr, cc] = t
                if b < lo[rr, cc]:
                    lo[rr, cc] = b
