"""Writing a DEM and its companion layers as products: one GeoTIFF per layer (GDAL and QGIS
open them in place), a PNG preview with a colour map and legend, a YAML sidecar each, and a
textured mesh for 3D viewing."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..grid import Layers, write_geotiff
from ..products import write_png, write_sidecar
from .colormaps import classes_preview, fit_size, with_legend
from .colormaps import layer_preview as colormaps_layer_preview
from .mesh import dem_mesh, write_mesh_ply

# layer -> (unit, colour map, what it is)
LAYERS: dict[str, tuple[str, int | None, str]] = {
    "dem": ("m", cv2.COLORMAP_TURBO, "elevation (z up, global frame)"),
    "variance": ("m^2", cv2.COLORMAP_VIRIDIS, "variance of the fused elevation"),
    "count": ("points", cv2.COLORMAP_VIRIDIS, "points that fell in the cell"),
    "filled": ("0/1", None, "1 where a hole was filled from neighbours"),
    "ortho": ("grey", None, "ortho-image: what the cell looks like from above, 0 = unseen"),
    "slope": ("deg", cv2.COLORMAP_INFERNO, "slope of the plane fitted over the window"),
    "step": ("m", cv2.COLORMAP_INFERNO, "greatest height above the window's minimum"),
    "roughness": ("m", cv2.COLORMAP_INFERNO, "spread about the fitted plane"),
    "hazard": ("class", None, "0 safe, 128 undefined, 255 hazardous"),
    "traversability": ("0..1", cv2.COLORMAP_RdYlGn if hasattr(cv2, "COLORMAP_RdYlGn") else cv2.COLORMAP_JET,
                       "1 easy, 0 impassable"),
}


def layer_preview(name: str, image: np.ndarray) -> np.ndarray:
    """An RGB preview with its colour bar or legend, naming the layer and its unit."""
    unit, cmap, _ = LAYERS.get(name, ("", cv2.COLORMAP_VIRIDIS, ""))
    data = np.asarray(image)
    if name == "hazard":
        total = max(data.size, 1)
        shares = {"safe": float((data == 0).sum()) / total, "hazardous": float((data == 255).sum()) / total,
                  "undefined": float((data == 128).sum()) / total}
        return classes_preview(data, title="hazard", shares=shares)
    if name == "ortho":
        grey = fit_size(cv2.cvtColor(data.astype(np.uint8), cv2.COLOR_GRAY2RGB))
        return with_legend(grey, [((0, 0, 0), "unseen")], "ortho-image")
    values = data.astype(np.float32)
    if name == "traversability":
        return colormaps_layer_preview(values, 0.0, 1.0, cmap if cmap is not None else cv2.COLORMAP_JET,
                                       title=name, units=unit)
    return colormaps_layer_preview(values, colormap=cmap if cmap is not None else cv2.COLORMAP_BONE,
                                   title=name, units=unit)


def write_dem_products(
    layers: Layers,
    out_dir: Path,
    name: str,
    *,
    made_by: str,
    parameters: dict[str, Any] | None = None,
    inputs: list[str] | None = None,
    run_log: dict[str, Any] | None = None,
    mesh: bool = True,
) -> dict[str, Path]:
    """Write every layer; returns layer name -> GeoTIFF path (and "mesh" -> PLY)."""
    out_dir = Path(out_dir)
    g = layers.geometry
    files: dict[str, Path] = {}
    for layer, image in layers.layers.items():
        if layer not in LAYERS:
            continue
        data = image
        if data.dtype == np.float64:
            data = data.astype(np.float32)
        if data.dtype == np.bool_:
            data = data.astype(np.uint8)
        path = write_geotiff(out_dir / f"{name}_{layer}.tif", data, g,
                             nodata=128.0 if layer == "hazard" else None)
        write_png(path.with_suffix(".png"), layer_preview(layer, data))
        unit, _, what = LAYERS[layer]
        write_sidecar(path, made_by, parameters, inputs, layer=layer, unit=unit, meaning=what,
                      cell=g.cell, bounds=list(g.bounds), size=[g.width, g.height],
                      crs="local: x forward at the start pose, y left, z up (m)",
                      **({"run_log": run_log} if run_log and layer == "dem" else {}))
        files[layer] = path
    if mesh and "dem" in layers:
        xs, ys = g.centers()
        colours = layers.layers.get("ortho")
        v, f, c = dem_mesh(layers["dem"], xs, ys, colours)
        files["mesh"] = write_mesh_ply(out_dir / f"{name}_mesh.ply", v, f, c)
    return files
