"""Ortho-image (seed 000 sect. 3.3.4): each DEM cell projected into the views' intensity images
through each view's calibration matrix, taking the view that sees it best.

"Best" is the nearest view that sees the cell unoccluded: the cell's depth in the view must
agree with the view's own depth image at that pixel, so a rock's far side is not painted with
the rock's front. Cells seen by no view are black (0), as in the thesis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class OrthoView:
    """One view for the ortho-image: its calibration matrix, intensity and depth images."""

    P: np.ndarray  # 3 x 4, global -> pixel
    intensity: np.ndarray  # H x W, any scale (normalised across views by ``ortho``)
    depth: np.ndarray | None = None  # H x W camera z in metres, NaN/<=0 where unknown


def ortho_image(
    dem: np.ndarray,
    xs: np.ndarray,
    ys: np.ndarray,
    views: list[OrthoView],
    occlusion_tol: float = 0.05,
    occlusion_rel: float = 0.02,
) -> tuple[np.ndarray, np.ndarray]:
    """(ortho uint8 H x W with 0 = unseen, view index int16 with -1 = unseen).

    ``xs``/``ys`` are the column and row centre coordinates of the DEM grid.
    """
    h, w = dem.shape
    defined = np.isfinite(dem)
    rows, cols = np.nonzero(defined)
    px, py, pz = xs[cols].astype(np.float64), ys[rows].astype(np.float64), dem[rows, cols].astype(np.float64)
    best_depth = np.full(len(px), np.inf)
    best_value = np.zeros(len(px), np.float32)
    best_view = np.full(len(px), -1, np.int16)
    lo, hi = _intensity_range(views)
    for index, view in enumerate(views):
        P = view.P  # element-wise rather than a (N x 3) @ (3 x 3) product: no BLAS thread start-up
        z = P[2, 0] * px + P[2, 1] * py + P[2, 2] * pz + P[2, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = (P[0, 0] * px + P[0, 1] * py + P[0, 2] * pz + P[0, 3]) / z
            v = (P[1, 0] * px + P[1, 1] * py + P[1, 2] * pz + P[1, 3]) / z
        ih, iw = view.intensity.shape[:2]
        ok = (z > 0) & (u > -0.5) & (u < iw - 0.5) & (v > -0.5) & (v < ih - 0.5)
        idx = np.nonzero(ok)[0]
        ui = np.rint(u[idx]).astype(np.int64)
        vi = np.rint(v[idx]).astype(np.int64)
        if view.depth is not None and len(idx):
            seen = view.depth[vi, ui]
            tol = occlusion_tol + occlusion_rel * z[idx]
            visible = np.isfinite(seen) & (seen > 0) & (np.abs(seen - z[idx]) <= tol)
            idx, ui, vi = idx[visible], ui[visible], vi[visible]
        value = view.intensity[vi, ui].astype(np.float32)
        finite = np.isfinite(value)
        idx, value = idx[finite], value[finite]
        better = z[idx] < best_depth[idx]
        sel = idx[better]
        best_depth[sel] = z[sel]
        best_value[sel] = value[better]
        best_view[sel] = index
    scaled = np.clip((best_value - lo) / max(hi - lo, 1e-12), 0, 1) * 254 + 1  # 1..255: 0 means unseen
    ortho = np.zeros((h, w), np.uint8)
    which = np.full((h, w), -1, np.int16)
    seen = best_view >= 0
    ortho[rows[seen], cols[seen]] = scaled[seen].astype(np.uint8)
    which[rows[seen], cols[seen]] = best_view[seen]
    return ortho, which


def _intensity_range(views: list[OrthoView]) -> tuple[float, float]:
    """A robust common scale, so neighbouring views do not show as a patchwork."""
    samples = [v.intensity[np.isfinite(v.intensity)].ravel()[::7] for v in views]
    data = np.concatenate(samples) if samples else np.zeros(0)
    if data.size == 0:
        return 0.0, 1.0
    if views and views[0].intensity.dtype == np.uint8:
        return 0.0, 255.0
    return float(np.percentile(data, 1)), float(np.percentile(data, 99))
