"""The layer registry: every map layer's name, unit, data type, nodata value, meaning, colour map
and preview rule, declared once and used by every writer and reader.

One table, so that a layer looks the same and means the same whichever entry point wrote it (the
server's product writer, ``rvs-dem-import``, ``rvs-dem2hazard``): tables kept per writer drift
apart (one layer, two colour maps, two meanings). :func:`write_layer` writes the GeoTIFF with the registry's
dtype and nodata, its YAML sidecar with unit and meaning, and its PNG preview by the registry's
rule; :func:`read_layers` reads a product's layers back.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from rvs_params.hazard import CODES_TEXT, UNDEFINED

from . import colormaps
from .grid import GridGeometry, Layers, read_geotiff, write_geotiff
from .mapview import Marks, Style, figure, layer_rgba
from .products import write_png, write_sidecar

CRS = "local: x forward at the start pose, y left, z up (m)"


@dataclass(frozen=True)
class LayerSpec:
    """One layer: what it is, how it is stored and how its preview is drawn.

    ``preview``: ``continuous`` (colour map over ``lo``..``hi``, or the 1st..99th percentile
    when they are None; with ``threshold`` the range is 0..2x that Dem2Hazard threshold,
    marked), ``classes`` (the hazard legend), ``grey`` (the ortho-image) or ``none``.
    """

    name: str
    unit: str
    dtype: str
    nodata: float | None  # None: NaN for float layers, none for integer ones
    meaning: str
    colormap: int | np.ndarray | None = cv2.COLORMAP_VIRIDIS
    preview: str = "continuous"
    lo: float | None = None
    hi: float | None = None
    threshold: str | None = None
    clipped: bool = True


_L = LayerSpec
LAYERS: dict[str, LayerSpec] = {spec.name: spec for spec in (
    _L("dem", "m", "float32", None, "elevation (z up, global frame): the information-weighted mean height of the "
       "cell's points (the plain mean without point variances; the greatest with height max)", cv2.COLORMAP_TURBO),
    _L("max", "m", "float32", None, "greatest height of the points in the cell", cv2.COLORMAP_TURBO),
    _L("mean", "m", "float32", None, "mean height of the points in the cell", cv2.COLORMAP_TURBO),
    _L("min", "m", "float32", None, "least height of the points in the cell", cv2.COLORMAP_TURBO),
    _L("wmean", "m", "float32", None, "information-weighted mean height", cv2.COLORMAP_TURBO),
    _L("count", "points", "int32", None, "points that fell in the cell"),
    _L("variance", "m^2", "float32", None, "variance of the elevation (of the fused DEM; of the cell's heights "
       "for one import)"),
    _L("measurement_variance", "m^2", "float32", None,
       "1 / sum(1 / point variance): variance of the information-weighted mean height"),
    _L("intensity", "grey", "float32", None, "mean intensity of the points in the cell", cv2.COLORMAP_BONE),
    _L("source", "index", "int16", None, "index of the input that last set the height (-1 none)"),
    _L("filled", "0/1", "uint8", None, "1 where a hole was filled from neighbours", cv2.COLORMAP_BONE),
    _L("spikes", "0/1", "uint8", None, "1 where a spike was removed", cv2.COLORMAP_BONE),
    _L("ortho", "grey", "uint8", None, "ortho-image: what the cell looks like from above, 0 = unseen", None,
       preview="grey"),
    _L("slope", "deg", "float32", None, "angle of the least-squares plane fitted over the window",
       cv2.COLORMAP_INFERNO, threshold="slope_max"),
    _L("step", "m", "float32", None, "greatest height above the window's minimum (max - min over the window)",
       cv2.COLORMAP_INFERNO, threshold="step_max"),
    _L("roughness", "m", "float32", None, "standard deviation of the window's cells about the fitted plane",
       cv2.COLORMAP_INFERNO, threshold="roughness_max"),
    _L("hazard", "class", "uint8", float(UNDEFINED), f"{CODES_TEXT} (any criterion past its threshold)",
       None, preview="classes"),
    # green good, red bad
    _L("traversability", "0..1", "float32", None, "1 easy, 0 impassable: weighted sum of 1 - value/threshold per "
       "criterion; 0 past any threshold", colormaps.RED_YELLOW_GREEN, lo=0.0, hi=1.0, clipped=False),
)}


def spec_of(name: str) -> LayerSpec:
    """The registry entry of a layer; an unknown layer is an error, not a silent default."""
    try:
        return LAYERS[name]
    except KeyError:
        raise KeyError(f"no layer '{name}' in the layer registry (prox_workflows/layers.py); "
                       f"known: {', '.join(LAYERS)}") from None


def stored(name: str, image: np.ndarray) -> np.ndarray:
    """The layer in its registry dtype (a float64 or bool array from an algorithm, say)."""
    dtype = np.dtype(spec_of(name).dtype)
    data = np.asarray(image)
    return data if data.dtype == dtype else data.astype(dtype)


def style_of(name: str, meta: dict[str, Any] | None = None) -> Style:
    """How a layer is drawn for people (console and preview PNGs), from its registry entry: a
    layer with a Dem2Hazard threshold spans 0..2x the threshold with the threshold marked."""
    spec = spec_of(name)
    if spec.preview == "classes":
        return Style("classes")
    if spec.preview == "grey":
        return Style("grey", unit=spec.unit)
    lo, hi, marks = spec.lo, spec.hi, ()
    thresholds = (meta or {}).get("dem2hazard") or {}
    if spec.threshold and spec.threshold in thresholds:
        crit = float(thresholds[spec.threshold])
        lo, hi, marks = 0.0, 2 * crit, ((crit, "max"),)
    colormap = spec.colormap if spec.colormap is not None else cv2.COLORMAP_BONE
    return Style("shaded" if name == "dem" else "continuous", colormap, lo, hi, spec.unit, marks)


def rover_meta(mask: Any) -> dict[str, float] | None:
    """The rover as a DEM's meta records it, from the footprint polygon its scan masked out
    (front-left, rear-left, rear-right, front-right corners, as the server builds it): in the
    meta, every product made from the DEM later (rvs-dem2hazard, a reprocessing) draws it too."""
    if mask is None:
        return None
    poly = np.asarray(mask, dtype=np.float64)
    if poly.shape != (4, 2):
        return None
    centre = poly.mean(axis=0)
    front = (poly[0] + poly[3]) / 2
    return {"x": round(float(centre[0]), 4), "y": round(float(centre[1]), 4),
            "heading": round(float(np.degrees(np.arctan2(front[1] - centre[1], front[0] - centre[0]))), 3),
            "length": round(float(np.linalg.norm(poly[0] - poly[1])), 4),
            "width": round(float(np.linalg.norm(poly[0] - poly[3])), 4)}


def marks_of(meta: dict[str, Any] | None) -> Marks | None:
    """What a DEM's previews draw over the map, from its meta (the rover, if a scan recorded it)."""
    rover = (meta or {}).get("rover")
    if not isinstance(rover, dict):
        return None
    return Marks(rover=(rover["x"], rover["y"], rover["heading"]), rover_size=(rover["length"], rover["width"]))


def preview(name: str, image: np.ndarray, geometry: GridGeometry, meta: dict[str, Any] | None = None,
            marks: Marks | None = None) -> np.ndarray | None:
    """The layer's operator-ready RGB picture (None: the registry says no preview): the same
    colours as the console, unseen cells hatched, axes in metres, scale bar, north arrow, the
    rover, and a legend that matches (:func:`prox_workflows.mapview.figure`)."""
    spec = spec_of(name)
    if spec.preview == "none":
        return None
    rgba, legend = layer_rgba(np.asarray(image), style_of(name, meta), geometry.cell)
    title = f"{name} ({spec.unit})" if spec.unit and spec.preview != "classes" else name
    return figure(rgba, geometry, legend, title, marks)


def write_layer(path: Path, name: str, image: np.ndarray, geometry: GridGeometry, *, made_by: str,
                parameters: dict[str, Any] | None = None, inputs: list[str] | None = None,
                context: dict[str, Any] | None = None, png: bool = True, marks: Marks | None = None,
                **extra: Any) -> Path:
    """One layer as a GeoTIFF (registry dtype and nodata), its sidecar and its PNG preview;
    ``context`` is the layers' meta (the Dem2Hazard thresholds a preview marks), ``marks`` what
    the preview draws over the map (the rover)."""
    spec = spec_of(name)
    data = stored(name, image)
    path = write_geotiff(Path(path), data, geometry, nodata=spec.nodata)
    if png:
        rgb = preview(name, data, geometry, context, marks)
        if rgb is not None:
            write_png(path.with_suffix(".png"), rgb)
    write_sidecar(path, made_by, parameters, inputs, layer=name, unit=spec.unit, meaning=spec.meaning,
                  cell=geometry.cell, bounds=list(geometry.bounds), size=[geometry.width, geometry.height],
                  crs=geometry.crs or CRS, **extra)
    return path


def layer_path(prefix: Path, name: str) -> Path:
    """``<prefix>_<layer>.tif``: the one naming every writer here uses."""
    prefix = Path(prefix)
    return prefix.with_name(f"{prefix.name}_{name}.tif")


def prefix_of(dem_path: Path) -> Path:
    """``site_dem.tif`` -> ``site``; ``DEM.tif`` -> ``DEM`` (companions are ``<prefix>_<layer>.tif``)."""
    dem_path = Path(dem_path)
    stem = dem_path.stem
    if stem.endswith("_dem") and len(stem) > 4:
        stem = stem[:-4]
    return dem_path.with_name(stem)


def write_layers(dem_path: Path, layers: Layers, made_by: str, parameters: dict[str, Any] | None = None,
                 inputs: list[str] | None = None, *, select: list[str] | tuple[str, ...] | None = None,
                 png: bool = True, run_log: dict[str, Any] | None = None) -> dict[str, Path]:
    """The selected layers (every registered one present if ``select`` is None): the DEM at
    ``dem_path``, each companion at ``<prefix>_<layer>.tif``; the DEM's sidecar lists the layer
    files and the layers' meta, so :func:`read_layers` restores both. The one writer of every
    entry point (server, toolbox CLIs, scripts)."""
    dem_path = Path(dem_path)
    wanted = [n for n in (select if select is not None else LAYERS) if n in layers.layers]
    for n in wanted:
        spec_of(n)
    prefix = prefix_of(dem_path)
    files = {n: dem_path if n == "dem" else layer_path(prefix, n) for n in wanted}
    g = layers.geometry
    summary = (layers.meta.get("dem2hazard") or {}).get("summary")
    for name in wanted:
        extra: dict[str, Any] = {}
        if name == "dem":
            extra = {"layers": {k: p.name for k, p in files.items()}, "meta": layers.meta,
                     "defined_cells": int(np.isfinite(layers["dem"]).sum())}
            if run_log:
                extra["run_log"] = run_log
        if name == "hazard" and summary:
            extra["shares"] = {k: round(float(v), 6) for k, v in summary.items()}
        write_layer(files[name], name, layers[name], g, made_by=made_by, parameters=parameters, inputs=inputs,
                    context=layers.meta, png=png, marks=marks_of(layers.meta), **extra)
    return files


def read_layers(dem_path: Path) -> Layers:
    """A DEM GeoTIFF and whichever registered companion layers lie beside it (same grid), with
    the meta its sidecar recorded. A plain GeoTIFF DEM (from GDAL, say) reads as a lone ``dem``."""
    dem_path = Path(dem_path)
    dem, g = read_geotiff(dem_path)
    if dem.ndim != 2:
        raise ValueError(f"{dem_path}: expected a single-band DEM, got shape {dem.shape}")
    layers = Layers(g)
    layers["dem"] = stored("dem", dem)
    names: list[str] = list(LAYERS)
    files: dict[str, str] = {}
    sidecar = dem_path.with_suffix(".yaml")
    if sidecar.is_file():
        try:
            info = yaml.safe_load(sidecar.read_text()) or {}
        except yaml.YAMLError:
            info = {}
        files = info.get("layers") or {}
        names = [n for n in files if n != "dem"] or names
        if isinstance(info.get("meta"), dict):
            layers.meta.update(info["meta"])
    prefix = prefix_of(dem_path)
    for name in names:
        path = dem_path.with_name(files[name]) if name in files else layer_path(prefix, name)
        if name == "dem" or not path.is_file() or path.suffix != ".tif":
            continue
        image, gl = read_geotiff(path)
        if gl != g:
            raise ValueError(f"{path.name} is not on the grid of {dem_path.name}")
        layers[name] = image
    return layers
