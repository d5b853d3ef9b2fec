"""Hole filling: undefined DEM cells between defined ones, up to a maximum gap size, filled from
their neighbours in float32 - so sub-millimetre relief survives (grid_map's OpenCV inpainting
quantises to 8 bits first; cv2.inpaint accepts float32 too, but Telea's fast marching is not
exact even on a plane).

Which cells: the gaps that a disk of radius ``max_radius`` cannot fit into - the morphological
closing of the defined cells by that disk, minus the defined cells, computed exactly with two
Euclidean distance transforms. This fills the sparse far-range pattern of direct
reconstruction (seed 000 sect. 3.3.3: "grid points will still be undefined ... may be
approximated by interpolating with the surrounding defined grid points") and narrow notches,
and leaves larger gaps (occlusion shadows, unseen ground) undefined rather than inventing
terrain there; it never grows the map outward.

How: first-order normalised convolution (Knutsson & Westin): a plane z = a + b dx + c dy fitted
by weighted least squares to the defined cells within ``max_radius`` + 2 cells, weights 1/d^3.
The nine weighted moments are correlations of the grid with fixed kernels (OpenCV filter2D in
float64), so the whole fill is a handful of vectorised passes; a plane is reproduced exactly
and a smooth surface to second order. Where the neighbours are collinear the fit falls back to
their weighted mean.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from rvs_params.deferred import deferred

from ..grid import Layers

ndimage = deferred("scipy.ndimage")


def fillable(defined: np.ndarray, radius_cells: float) -> np.ndarray:
    """Undefined cells inside the closing of ``defined`` by a disk of ``radius_cells``."""
    if radius_cells <= 0 or defined.all() or not defined.any():
        return np.zeros(defined.shape, bool)
    near = ndimage.distance_transform_edt(~defined) <= radius_cells  # dilation
    if near.all():  # (edt of an array without zeros measures to a phantom corner)
        return ~defined
    closed = ndimage.distance_transform_edt(near) > radius_cells  # erosion of the dilation
    # edt measures to the nearest zero inside the array: the grid border does not erode, so
    # gaps open to the border are judged by their width alone
    return closed & ~defined


def _kernels(support: int) -> dict[str, np.ndarray]:
    k = np.arange(-support, support + 1, dtype=np.float64)
    dx, dy = np.meshgrid(k, k)  # dx along columns (x), dy along rows (south)
    d2 = dx * dx + dy * dy
    w = np.where((d2 > 0) & (d2 <= support * support + 1e-9), np.maximum(d2, 1.0) ** -1.5, 0.0)
    return {"1": w, "x": w * dx, "y": w * dy, "xx": w * dx * dx, "xy": w * dx * dy, "yy": w * dy * dy}


def fill_holes_array(dem: np.ndarray, radius_cells: float) -> tuple[np.ndarray, np.ndarray]:
    """Fill ``dem`` (NaN undefined); returns (filled float32 copy, mask of the cells filled)."""
    z = np.asarray(dem)
    defined = np.isfinite(z)
    todo = fillable(defined, radius_cells)
    out = z.astype(np.float32, copy=True)
    if not todo.any():
        return out, todo
    support = int(math.ceil(radius_cells)) + 2
    # work on the bounding box of what is to fill, plus the support
    rows, cols = np.nonzero(todo)
    r0, r1 = max(rows.min() - support, 0), min(rows.max() + support + 1, z.shape[0])
    c0, c1 = max(cols.min() - support, 0), min(cols.max() + support + 1, z.shape[1])
    zd = z[r0:r1, c0:c1].astype(np.float64)
    m = defined[r0:r1, c0:c1].astype(np.float64)
    ref = float(np.nanmedian(zd[m > 0]))  # heights relative to a local level keep precision
    f = np.where(m > 0, zd - ref, 0.0)
    ker = _kernels(support)

    def corr(img: np.ndarray, k: np.ndarray) -> np.ndarray:
        return cv2.filter2D(img, cv2.CV_64F, k, borderType=cv2.BORDER_CONSTANT)

    s = {name: corr(m, k) for name, k in ker.items()}
    t1, tx, ty = corr(f, ker["1"]), corr(f, ker["x"]), corr(f, ker["y"])
    sel = todo[r0:r1, c0:c1]
    s1, sx, sy = s["1"][sel], s["x"][sel], s["y"][sel]
    sxx, sxy, syy = s["xx"][sel], s["xy"][sel], s["yy"][sel]
    b1, bx, by = t1[sel], tx[sel], ty[sel]
    # Cramer's rule on the 3 x 3 normal equations, all cells at once; the plane's offset is
    # the value at the cell. Neighbours on a line give a (near) singular system: weighted mean.
    c11 = sxx * syy - sxy * sxy
    det = s1 * c11 - sx * (sx * syy - sxy * sy) + sy * (sx * sxy - sxx * sy)
    num = b1 * c11 - sx * (bx * syy - sxy * by) + sy * (bx * sxy - sxx * by)
    good = (s1 > 0) & (det > 1e-6 * s1 * np.maximum(sxx * syy, 1e-300))
    with np.errstate(divide="ignore", invalid="ignore"):
        value = np.where(good, num / np.where(good, det, 1.0), b1 / np.where(s1 > 0, s1, 1.0))
    valid = s1 > 0
    block = out[r0:r1, c0:c1]
    fill_vals = np.where(valid, value + ref, np.nan).astype(np.float32)
    block[sel] = fill_vals
    filled = np.zeros_like(todo)
    filled[r0:r1, c0:c1][sel] = valid
    return out, filled


def fill_holes(dem: np.ndarray, cell: float, max_radius: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Fill the gaps of ``dem`` (NaN undefined, cells of ``cell`` m) that a disk of ``max_radius``
    metres does not fit into; returns (filled float32 copy, bool mask of the cells filled)."""
    if cell <= 0 or max_radius < 0:
        raise ValueError(f"cell must be positive and max_radius not negative, got {cell}, {max_radius}")
    return fill_holes_array(dem, max_radius / cell)


def fill_layers(layers: Layers, max_radius: float = 0.1, layer: str = "dem") -> Layers:
    """A copy of ``layers`` with ``layer`` hole-filled and a ``filled`` layer (uint8, 1 where a
    value was interpolated); the other layers are passed on unchanged."""
    filled, mask = fill_holes(layers[layer], layers.geometry.cell, max_radius)
    out = Layers(layers.geometry, dict(layers.layers), dict(layers.meta))
    out[layer] = filled
    out["filled"] = mask.astype(np.uint8)
    out.meta["hole_fill_radius_m"] = float(max_radius)
    return out
