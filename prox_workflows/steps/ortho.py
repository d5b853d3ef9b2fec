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
    pts = np.stack([xs[cols], ys[rows], dem[rows, cols]], axis=1).astype(np.float64)
    best_depth = np.full(len(pts), np.inf)
    best_value = np.zeros(len(pts), np.float32)
    best_view = np.full(len(pts), -1, np.int16)
    lo, hi = _intensity_range(views)
    for index, view in enumerate(views):
        hom = pts @ view.P[:, :3].T + view.P[:, 3]
        z = hom[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = hom[:, 0] / z
            v = hom[:, 1] / z
        ih, iw = view.intensity.shape[:2]
        ui = np.round(u).astype(np.int64, copy=False) if len(u) else u.astype(np.int64)
        vi = np.round(v).astype(np.int64, copy=False) if len(v) else v.astype(np.int64)
        ok = (z > 0) & (ui >= 0) & (ui < iw) & (vi >= 0) & (vi < ih) & np.isfinite(u) & np.isfinite(v)
        idx = np.nonzero(ok)[0]
        if view.depth is not None and len(idx):
            seen = view.depth[vi[idx], ui[idx]]
            tol = occlusion_tol + occlusion_rel * z[idx]
            visible = np.isfinite(seen) & (seen > 0) & (np.abs(seen - z[idx]) <= tol)
            idx = idx[visible]
        value = view.intensity[vi[idx], ui[idx]].astype(np.float32)
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
