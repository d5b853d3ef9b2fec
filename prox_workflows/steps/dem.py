"""The DEM steps on :class:`Layers`: each wraps one array algorithm (DemImport, DemMosaik, spike
removal, hole filling, ortho) so a script can chain them by name."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rvs_params import Settings, param

from ..algorithms.acquire import View
from ..algorithms.dem_import import dem_import
from ..algorithms.dem_mosaik import DEFAULTS as MOSAIK
from ..algorithms.dem_mosaik import dem_mosaik, fuse_sensors, resample_nearest, union_geometry
from ..algorithms.holes import fill_layers
from ..algorithms.ortho import OrthoView, ortho_image
from ..algorithms.spikes import find_spikes
from ..engine import step
from ..grid import GridGeometry, Layers

step("dem_import", outputs={"dem": "Layers"})(dem_import)


@dataclass
class PointCorrelation(Settings):
    """How much of their error the points of one cell share, per sensor (calibrated with the
    noise models by ``python -m tools.bench.fusion --calibrate``)."""

    tof_cell_correlation: float = param(0.7, "correlation of the ToF points' errors within a cell (the cell's "
                                        "variance is the points' / N x (1 + rho (N - 1)))", min=0.0, max=1.0,
                                        option=False)
    stereo_cell_correlation: float = param(1.0, "correlation of the stereo points' errors within a cell (see "
                                           "tof_cell_correlation)", min=0.0, max=1.0, option=False)


@step("view_dem", outputs={"dem": "Layers?"}, settings=PointCorrelation)
def view_dem(view: View, cell: float, rover_mask: np.ndarray | None = None, height: str = "mean",
             settings: PointCorrelation | None = None) -> Layers | None:
    """DemImport of one view's points, each with its noise-model variance.

    ``height`` is DemImport's rule for the ``dem`` layer (the mean for measured data, see
    :func:`dem_import`). With the mean, the cell's spread is in ``measurement_variance``, so
    ``variance`` is cleared for the fusion. The N points of a cell share part of their error
    (a stereo match is smoothed over its neighbours, a ToF pixel's multipath over a patch), so
    their mean is not N times better: with correlation rho its variance is the independent
    one times 1 + rho (N - 1), rho the sensor's (:class:`PointCorrelation`). A view that saw
    nothing (sky, all beyond range) gives None.
    """
    if len(view.points) == 0:
        return None
    s = settings or PointCorrelation()
    layers = dem_import(view.points, cell=cell, point_variance=view.variance, rover_mask=rover_mask, height=height)
    rho = s.tof_cell_correlation if view.sensor == "tof" else s.stereo_cell_correlation
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


@dataclass
class SensorFusion(Settings):
    """How a ToF DEM and a stereo DEM of one scan fuse (:func:`fuse_sensors`), chosen by the same
    calibration as the noise models."""

    tof_fuse_scatter: float = param(1.23, "ToF-stereo fusion: share of the squared deviation of a ToF cell from "
                                    "the median of its neighbours added to its variance (the ToF map's own "
                                    "evidence against the cell)", min=0.0, max=100.0, option=False)
    stereo_fuse_scatter: float = param(1.66, "ToF-stereo fusion: the same for a stereo cell", min=0.0, max=100.0,
                                       option=False)
    fuse_gate: float = param(1.5, "ToF-stereo fusion: Mahalanobis gate between the two sensors' cell heights; "
                             "past it the one the neighbouring cells support wins (the one of 1.5 and 2 "
                             "with no 1 m band fused worse than either sensor on the office, quarry and "
                             "marsyard scans from the tilted rover, and the lower RMSE on each)",
                             min=0.0, max=1000.0, option=False)


@step("mosaic", outputs={"mosaic": "Layers"}, settings=SensorFusion)
def mosaic(dems: list[Layers | None], base: Layers | None, rule: str, cell: float,
           within_scan: str = "higher", settings: SensorFusion | None = None) -> Layers:
    """DemMosaik of the views, then onto the current DEM (if any), on the union of extents.

    Views of one sensor in one scan disagree mostly where one sees a rock's top and another its
    foot, so there the higher wins (``within_scan="higher"``). Two sensors (``"inflate"``, from
    :func:`scan_rule`) are mosaicked each on its own first, as each alone would be, and the two
    DEMs are then fused cell by cell (:func:`fuse_sensors`): the information-weighted mean where
    they agree within ``gate`` standard deviations of their difference, else the one the
    neighbourhood supports - order-free, where fusing the views in acquisition order let
    whichever sensor came first keep a cell it had wrong; each sensor's cells count as less
    certain the farther they stand from their neighbours (:class:`SensorFusion`). Between scans
    a disagreement is a change or an outlier, so the gate rejects it and inflates the prior's
    variance (elevation_mapping's rule).
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
            f = settings or SensorFusion()
            scan = fuse_sensors(each, geometry=g, gate=f.fuse_gate,
                                scatter=[f.tof_fuse_scatter if s == "tof" else f.stereo_fuse_scatter for s in sensors])
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


@dataclass
class SpikeRemoval(Settings):
    """What makes a lone cell a spike (:func:`find_spikes`): flying pixels and multipath that
    every neighbour contradicts."""

    spike_jump: float = param(0.05, "a cell above (below) all its neighbours by more than this ...", unit="m",
                              min=0.0, max=2.0, option=False)
    spike_sigma: float = param(4.0, "... and by more than this many of its height's standard deviations ...",
                               min=0.0, max=100.0, option=False)
    spike_points: int = param(3, "... with at most this many points is a spike: made undefined, then filled",
                              min=0, max=1000, option=False)


@step("remove_spikes_layers", outputs={"layers": "Layers"}, settings=SpikeRemoval)
def remove_spikes_layers(layers: Layers, settings: SpikeRemoval | None = None) -> Layers:
    """A copy of ``layers`` with the spikes of its ``dem`` undefined (and their variance and
    count cleared), and a ``spikes`` layer (uint8, 1 where one was)."""
    s = settings or SpikeRemoval()
    dem = layers["dem"]
    mask = find_spikes(dem, layers["variance"] if "variance" in layers else None,
                       layers["count"] if "count" in layers else None, s.spike_jump, s.spike_sigma, s.spike_points)
    out = Layers(layers.geometry, dict(layers.layers), dict(layers.meta))
    out["dem"] = np.where(mask, np.nan, dem).astype(dem.dtype)
    if "variance" in layers:
        out["variance"] = np.where(mask, np.nan, layers["variance"]).astype(layers["variance"].dtype)
    if "count" in layers:
        out["count"] = np.where(mask, 0, layers["count"]).astype(layers["count"].dtype)
    out["spikes"] = mask.astype(np.uint8)
    out.meta["spikes_removed"] = int(mask.sum())
    return out


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
