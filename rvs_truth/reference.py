"""Independent implementations that the fast kernels are held to, by the tests (equal outputs)
and by the benchmarks (the peer a kernel's time is compared with)."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from prox_workflows.algorithms import dem2hazard as d2h


def dem2hazard_vectorised(dem: np.ndarray, cell: float, params: d2h.HazardParams | dict[str, Any] | None = None
               ) -> dict[str, np.ndarray]:
    """Dem2Hazard's five layers from whole-array OpenCV filters and numpy expressions.

    The plane z = a x + b y + c over each window's defined cells needs the sums of 1, x, y, z,
    xx, xy, yy, xz, yz, zz over those cells: box filters of the mask m and of m x, m y, z0, ...
    (z0 the heights with undefined cells 0, relative to their mean so z^2 keeps its precision).
    With C_uv = N S_uv - S_u S_v the plane's gradient solves a 2 x 2 system and the residual sum
    of squares is (Czz - a Cxz - b Cyz) / N. Undefined: the centre, fewer than ``min_cells``
    defined, or a determinant too small for a plane, the same rule as ours.
    """
    p = d2h.load_params(**params) if isinstance(params, dict) else (params or d2h.load_params())
    n, need = p.window_cells(cell), p.min_cells(cell)
    z = np.asarray(dem)
    if not np.issubdtype(z.dtype, np.floating):
        z = z.astype(np.float64)
    h, w = z.shape
    defined = np.isfinite(z)
    zref = float(z[defined].mean()) if defined.any() else 0.0
    m = defined.astype(np.float64)
    z0 = np.where(defined, z.astype(np.float64) - zref, 0.0)
    x = (np.arange(w, dtype=np.float64) - (w - 1) / 2)[None, :]
    y = ((h - 1) / 2 - np.arange(h, dtype=np.float64))[:, None]  # y grows up the raster (north)

    def box(a: np.ndarray) -> np.ndarray:
        return cv2.boxFilter(a, cv2.CV_64F, (n, n), normalize=False, borderType=cv2.BORDER_CONSTANT)

    mx, my = m * x, m * y
    count, sx, sy, sz = box(m), box(mx), box(my), box(z0)
    cxx = count * box(mx * x) - sx * sx
    cxy = count * box(mx * y) - sx * sy
    cyy = count * box(my * y) - sy * sy
    cxz = count * box(z0 * x) - sx * sz
    cyz = count * box(z0 * y) - sy * sz
    czz = count * box(z0 * z0) - sz * sz
    det = cxx * cyy - cxy * cxy
    valid = defined & (count >= need) & (det > 1e-6 * count**4)
    with np.errstate(divide="ignore", invalid="ignore"):
        a = (cyy * cxz - cxy * cyz) / det
        b = (cxx * cyz - cxy * cxz) / det
        rss = np.maximum(czz - a * cxz - b * cyz, 0.0) / np.maximum(count * (count - 3.0), 1.0)
    slope = np.degrees(np.arctan(np.hypot(a, b) / cell))
    roughness = np.sqrt(rss)
    kernel = np.ones((n, n), np.uint8)
    zs = z if z.dtype in (np.float32, np.float64) else z.astype(np.float64)
    zmax = cv2.dilate(np.where(defined, zs, -np.inf), kernel)
    zmin = cv2.erode(np.where(defined, zs, np.inf), kernel)
    with np.errstate(over="ignore", invalid="ignore"):
        step = zmax.astype(np.float64) - zmin
    layers = [np.where(valid, v, np.nan).astype(np.float32) for v in (slope, roughness, step)]
    return d2h.classify(*layers, valid, p)
