"""The steps of the DEM workflow scripts on :class:`Layers`: each wraps one array algorithm
(DemImport, DemMosaik, hole filling, Dem2Hazard, ortho) so a script can chain them by name."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..grid import GridGeometry, Layers
from .acquire import View
from .dem2hazard import dem2hazard_layers
from .dem_import import dem_import
from .dem_mosaik import dem_mosaik
from .holes import fill_holes
from .ortho import OrthoView, ortho_image


def join_views(earlier: list[View] | None, new: list[View]) -> list[View]:
    """Views a stopped acquisition left behind, then the new ones (newest last)."""
    return list(earlier or []) + list(new)


def view_dem(view: View, cell: float, rover_mask: np.ndarray | None = None, height: str = "mean") -> Layers | None:
    """DemImport of one view's points, each with its noise-model variance.

    ``height="mean"`` makes the view's height the information-weighted mean of its cell's
    points: the greatest of several noisy ToF heights sits about a sigma above the ground, which
    is a bias the fusion cannot average away; ``"max"`` keeps the thesis's direct rule.
    A view that saw nothing (sky, all beyond range) gives None.
    """
    if len(view.points) == 0:
        return None
    layers = dem_import(view.points, cell=cell, point_variance=view.variance, rover_mask=rover_mask)
    if height == "mean" and "wmean" in layers:
        layers["dem"] = layers["wmean"]
        layers["variance"] = np.zeros_like(layers["variance"])  # the mean's spread is in measurement_variance
    layers.meta["view"] = view.index
    return layers


def mosaic(dems: list[Layers | None], base: Layers | None, rule: str, cell: float,
           within_scan: str = "higher") -> Layers:
    """DemMosaik of the views, then onto the current DEM (if any), on the union of extents.

    Views of one sensor in one scan disagree mostly where one sees a rock's top and another its
    foot, so there the higher wins (``within_scan="higher"``); between scans, and between two
    sensors (``"inflate"``), a disagreement is a change or an outlier (multipath, a stereo
    mismatch), so the gate rejects it and inflates the prior's variance (elevation_mapping's
    two rules).
    """
    views = [d for d in dems if d is not None and np.isfinite(d["dem"]).any()]
    if not views and base is None:
        raise ValueError("no view produced any point: nothing to map (check the view range and the sensor)")
    if rule != "fuse":
        return dem_mosaik(([base] if base is not None else []) + views, rule=rule, cell=cell)
    scan = dem_mosaik(views, rule="fuse", cell=cell, on_conflict=within_scan) if views else None
    if base is None:
        assert scan is not None
        return scan
    if scan is None:
        return base
    return dem_mosaik([base, scan], rule="fuse", cell=cell, on_conflict="inflate")


def fill_holes_layers(layers: Layers, radius: float) -> Layers:
    filled, mask = fill_holes(layers["dem"], layers.geometry.cell, radius)
    out = Layers(layers.geometry, dict(layers.layers), dict(layers.meta))
    out["dem"] = filled
    out["filled"] = mask.astype(np.uint8)
    return out


def hazard_layers(layers: Layers, params: dict[str, Any] | None = None) -> Layers:
    return dem2hazard_layers(layers, params)


def ortho_layer(layers: Layers, views: list[View], base: Layers | None = None) -> Layers:
    """The ortho-image from the views; where none sees a cell, the current DEM's ortho is kept."""
    g: GridGeometry = layers.geometry
    xs, ys = g.centers()
    ortho, _ = ortho_image(layers["dem"], xs, ys, [OrthoView(v.P, v.intensity, v.depth) for v in views])
    if base is not None and "ortho" in base:
        old = resample_nearest(base["ortho"], base.geometry, g, fill=0)
        ortho = np.where(ortho == 0, old, ortho).astype(np.uint8)
    layers["ortho"] = ortho
    return layers


def resample_nearest(image: np.ndarray, src: GridGeometry, dst: GridGeometry, fill: Any = np.nan) -> np.ndarray:
    """A layer of one grid on another, nearest cell (for layers that must not be blended)."""
    xs, ys = dst.centers()
    row, col = src.cell_of(np.broadcast_to(xs, dst.shape), np.broadcast_to(ys[:, None], dst.shape))
    inside = src.inside(row, col)
    out = np.full(dst.shape, fill, dtype=image.dtype)
    out[inside] = image[row[inside], col[inside]]
    return out
