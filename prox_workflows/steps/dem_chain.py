"""The steps of the DEM workflow scripts on :class:`Layers`: each wraps one array algorithm
(DemImport, DemMosaik, hole filling, Dem2Hazard, ortho) so a script can chain them by name."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..engine import step
from ..grid import GridGeometry, Layers
from .acquire import View
from .dem2hazard import dem2hazard_layers
from .dem_import import dem_import
from .dem_mosaik import DEFAULTS as MOSAIK
from .dem_mosaik import dem_mosaik, fuse_sensors, union_geometry
from .holes import fill_layers
from .ortho import OrthoView, ortho_image


@step("acquire", outputs={"views": "list[View]"})
def acquire(positions: list[tuple[float, float]], progress: Any = None, cancelled: Any = None) -> list[View]:
    """The declaration of the acquisition step; its implementation is the caller's.

    The server supplies it (its PTU and sensors: ``run_workflow(..., steps={"acquire": fn})``),
    so this package never imports a driver; offline a script reads recorded views instead
    (``read_views``).
    """
    raise NotImplementedError("acquire is supplied by the server; offline, read recorded views with read_views")


@step("scan_rule", outputs={"within_scan": "str"})
def scan_rule(views: list[View]) -> str:
    """How views of one scan settle a conflict, from the sensors that took them: views of one
    sensor, the higher wins (a rock's top over its foot); ToF and stereo together, the gate
    rejects what the other sensor contradicts. Derived from the views, so the server and a
    reprocessing of its recorded views choose alike."""
    return "inflate" if len({v.sensor for v in views}) > 1 else "higher"


@step("join_views", outputs={"views": "list[View]"})
def join_views(earlier: list[View] | None, new: list[View]) -> list[View]:
    """Views a stopped acquisition left behind, then the new ones (newest last)."""
    return list(earlier or []) + list(new)


@step("view_dem", outputs={"dem": "Layers?"})
def view_dem(view: View, cell: float, rover_mask: np.ndarray | None = None, height: str = "mean",
             tof_correlation: float = 0.0, stereo_correlation: float = 0.0) -> Layers | None:
    """DemImport of one view's points, each with its noise-model variance.

    ``height`` is DemImport's rule for the ``dem`` layer (the mean for measured data, see
    :func:`dem_import`). With the mean, the cell's spread is in ``measurement_variance``, so
    ``variance`` is cleared for the fusion. The N points of a cell share part of their error
    (a stereo match is smoothed over its neighbours, a ToF pixel's multipath over a patch), so
    their mean is not N times better: with correlation rho its variance is the independent
    one times 1 + rho (N - 1), rho the sensor's (``tof_correlation`` / ``stereo_correlation``,
    calibrated with the noise models). A view that saw nothing (sky, all beyond range) gives None.
    """
    if len(view.points) == 0:
        return None
    layers = dem_import(view.points, cell=cell, point_variance=view.variance, rover_mask=rover_mask, height=height)
    rho = tof_correlation if view.sensor == "tof" else stereo_correlation
    if rho > 0 and "measurement_variance" in layers:
        n = np.maximum(np.asarray(layers["count"], np.float32), 1.0)
        layers["measurement_variance"] = (layers["measurement_variance"] * (1.0 + rho * (n - 1.0))).astype(np.float32)
    if height == "mean":
        layers.layers.pop("max", None)
        layers["variance"] = np.zeros_like(layers["variance"])  # the mean's spread is in measurement_variance
    layers.meta["view"] = view.index
    layers.meta["sensor"] = view.sensor
    return layers


@step("dem_mosaik", outputs={"mosaic": "Layers"})
def mosaik_layers(dems: list[Layers], rule: str = MOSAIK.rule, bounds: list[float] | None = None,
                  cell: float = MOSAIK.cell, sigma: float = MOSAIK.sigma, gate: float = MOSAIK.gate,
                  inflation: float = MOSAIK.inflation, on_conflict: str = MOSAIK.on_conflict) -> Layers:
    """DemMosaik of DEM products (``rvs-dem-mosaik``): on ``bounds`` if given, else the union of
    the inputs; ``cell`` 0 takes the finest input's."""
    geometry = None
    size = cell if cell > 0 else None
    if bounds is not None:
        geometry = GridGeometry.covering(*bounds, size or min(d.geometry.cell for d in dems))
    return dem_mosaik(dems, rule=rule, geometry=geometry, cell=size, sigma=sigma, gate=gate, inflation=inflation,
                      on_conflict=on_conflict)


@step("mosaic", outputs={"mosaic": "Layers"})
def mosaic(dems: list[Layers | None], base: Layers | None, rule: str, cell: float,
           within_scan: str = "higher", gate: float = MOSAIK.gate, tof_scatter: float = 0.0,
           stereo_scatter: float = 0.0) -> Layers:
    """DemMosaik of the views, then onto the current DEM (if any), on the union of extents.

    Views of one sensor in one scan disagree mostly where one sees a rock's top and another its
    foot, so there the higher wins (``within_scan="higher"``). Two sensors (``"inflate"``, from
    :func:`scan_rule`) are mosaicked each on its own first, as each alone would be, and the two
    DEMs are then fused cell by cell (:func:`fuse_sensors`): the information-weighted mean where
    they agree within ``gate`` standard deviations of their difference, else the one the
    neighbourhood supports - order-free, where fusing the views in acquisition order let
    whichever sensor came first keep a cell it had wrong; each sensor's cells count as less
    certain the farther they stand from their neighbours (``tof_scatter`` / ``stereo_scatter``,
    fuse_sensors's ``scatter``). Between scans a disagreement is a
    change or an outlier, so the gate rejects it and inflates the prior's variance
    (elevation_mapping's rule).
    """
    views = [d for d in dems if d is not None and np.isfinite(d["dem"]).any()]
    if not views and base is None:
        raise ValueError("no view produced any point: nothing to map (check the view range and the sensor)")
    if rule != "fuse":
        return dem_mosaik(([base] if base is not None else []) + views, rule=rule, cell=cell)
    scan = None
    if views:
        sensors = list(dict.fromkeys(str(v.meta.get("sensor", "")) for v in views))
        if within_scan == "higher" or len(sensors) < 2:
            scan = dem_mosaik(views, rule="fuse", cell=cell, on_conflict=within_scan)
        else:
            g = union_geometry([v.geometry for v in views], cell)
            each = [dem_mosaik([v for v in views if v.meta.get("sensor", "") == s], rule="fuse", geometry=g,
                               on_conflict="higher") for s in sensors]
            scan = fuse_sensors(each, geometry=g, gate=gate,
                                scatter=[tof_scatter if s == "tof" else stereo_scatter for s in sensors])
    if base is None:
        assert scan is not None
        return scan
    if scan is None:
        return base
    return dem_mosaik([base, scan], rule="fuse", cell=cell, on_conflict="inflate")


@step("fill_holes_layers", outputs={"layers": "Layers"})
def fill_holes_layers(layers: Layers, radius: float) -> Layers:
    """Holes up to ``radius`` filled from their neighbours; a ``filled`` layer marks them."""
    return fill_layers(layers, radius)


@step("hazard_layers", outputs={"layers": "Layers"})
def hazard_layers(layers: Layers, params: dict[str, Any] | None = None) -> Layers:
    """Dem2Hazard on the ``dem`` layer: slope, step, roughness, hazard, traversability."""
    return dem2hazard_layers(layers, params)


@step("ortho_layer", outputs={"layers": "Layers"})
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


@step("view_files", outputs={"inputs": "list[str]"})
def view_files(views: list[View], folder: str | None = None) -> list[str]:
    """The recorded images the views came from, as the products' sidecars cite them."""
    prefix = f"{folder}/" if folder else ""
    return [f"{prefix}{v.files['image']}" for v in views if v.files]
