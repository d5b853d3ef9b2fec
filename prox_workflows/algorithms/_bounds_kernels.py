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


@jit(inline="always")
def _box(px: np.ndarray, py: np.ndarray, xmin: float, ymax: float, cell: float, h: int, w: int
         ) -> tuple[int, int, int, int]:
    """The rows and columns (first, past the last) of the grid's cells that hold any of the
    points: what a frame's sums need to index, not the whole map (a mission's map is millions of
    cells, a frame's a few thousand)."""
    r0, r1, c0, c1 = h, 0, w, 0
    for i in range(px.shape[0]):
        fc = (px[i] - xmin) / cell
        fr = (ymax - py[i]) / cell
        if fc >= 0.0 and fr >= 0.0 and fc < w and fr < h:
            r, c = int(fr), int(fc)
            r0, r1, c0, c1 = min(r0, r), max(r1, r + 1), min(c0, c), max(c1, c + 1)
    return r0, max(r1, r0), c0, max(c1, c0)


@jit
def cell_moments(px: np.ndarray, py: np.ndarray, pz: np.ndarray, sig: np.ndarray, sig_xy: np.ndarray,
                 across: np.ndarray, ox: float, oy: float, oz: float, max_range: float, along_rays: bool,
                 xmin: float, ymax: float, cell: float, h: int, w: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One frame's returns summed per cell of the grid, in one pass: the cells (flat indices,
    ascending), their counts, and per cell the sums of the heights, the height variances, the
    horizontal variances along the rays and along the larger axis, and the horizontal covariance
    (xx, xy, yy), then the highest and lowest height (columns of the (cells, 9) array, in that
    order). Each return's horizontal error is ``sig_xy`` along its ray's bearing from (ox, oy)
    and ``across`` at right angles (``along_rays``), else ``sig_xy`` both ways. A cell's sums run
    over its returns in their order."""
    r0, r1, c0, c1 = _box(px, py, xmin, ymax, cell, h, w)
    slot = np.full((r1 - r0, c1 - c0), -1, np.int64)
    most = min(px.shape[0], slot.size)
    cells = np.empty(most, np.int64)
    acc = np.zeros((most, 9))
    count = np.zeros(most, np.int64)
    m = 0
    for i in range(px.shape[0]):
        c = math.floor((px[i] - xmin) / cell)
        r = math.floor((ymax - py[i]) / cell)
        if r < 0 or r >= h or c < 0 or c >= w:
            continue
        # a cell the range cut crosses takes none of the frame's returns: its far corner from the
        # sensor, at the return's height, lies beyond the cut
        far = math.hypot(abs(px[i] - ox) + cell, abs(py[i] - oy) + cell)
        if not math.hypot(far, pz[i] - oz) <= max_range:
            continue
        f = r * w + c
        k = slot[r - r0, c - c0]
        if k < 0:
            k = m
            slot[r - r0, c - c0] = k
            cells[k] = f
            acc[k, 7] = pz[i]
            acc[k, 8] = pz[i]
            m += 1
        if along_rays:
            dx, dy = px[i] - ox, py[i] - oy
            norm = max(math.hypot(dx, dy), 1e-9)
            ux, uy = dx / norm, dy / norm
        else:
            ux, uy = 1.0, 0.0
        a2 = sig_xy[i] ** 2
        b2 = across[i] ** 2
        xx = a2 * ux * ux + b2 * uy * uy
        xy = (a2 - b2) * ux * uy
        yy = a2 * uy * uy + b2 * ux * ux
        count[k] += 1
        acc[k, 0] += pz[i]
        acc[k, 1] += sig[i] ** 2
        acc[k, 2] += a2
        acc[k, 3] += xx + yy - min(a2, b2)  # the larger axis
        acc[k, 4] += xx
        acc[k, 5] += xy
        acc[k, 6] += yy
        if pz[i] > acc[k, 7]:
            acc[k, 7] = pz[i]
        if pz[i] < acc[k, 8]:
            acc[k, 8] = pz[i]
    order = np.argsort(cells[:m])
    return cells[:m][order], count[:m][order], acc[:m][order]


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
