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


def view_dem(view: View, cell: float, rover_mask: np.ndarray | None = None) -> Layers:
    """DemImport of one view's points, each with its noise-model variance."""
    layers = dem_import(view.points, cell=cell, point_variance=view.variance, rover_mask=rover_mask)
    layers.meta["view"] = view.index
    return layers


def mosaic(dems: list[Layers], base: Layers | None, rule: str, cell: float) -> Layers:
    """DemMosaik of the views onto the current DEM (if any), on the union of their extents."""
    inputs = ([base] if base is not None else []) + [d for d in dems if np.isfinite(d["dem"]).any()]
    if not inputs:
        raise ValueError("no view produced any point: nothing to map (check the view range and the sensor)")
    return dem_mosaik(inputs, rule=rule, cell=cell)


def fill_holes_layers(layers: Layers, radius: float) -> Layers:
    filled, mask = fill_holes(layers["dem"], layers.geometry.cell, radius)
    layers["dem"] = filled
    layers["filled"] = mask.astype(np.uint8)
    return layers


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
