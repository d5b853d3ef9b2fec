"""Writers: a DEM and its companion layers as products, the step that says where a script's
results go. One GeoTIFF per layer (GDAL and QGIS open them in place), a PNG preview with a
colour map and legend, a YAML sidecar each (all from the layer registry,
:mod:`prox_workflows.layers`), and a textured mesh for 3D viewing."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..engine import step
from ..grid import Layers
from ..layers import LAYERS, layer_path, write_layer
from ..layers import preview as _preview
from .mesh import dem_mesh, write_mesh_ply

# what a DEM job publishes (the server's products); the other registered layers are a script's choice
DEM_PRODUCTS = ("dem", "variance", "count", "filled", "ortho", "slope", "step", "roughness", "hazard",
                "traversability")


def layer_preview(name: str, image: np.ndarray, meta: dict[str, Any] | None = None) -> np.ndarray | None:
    """An RGB preview with its colour bar or legend, naming the layer and its unit."""
    return _preview(name, image, meta)


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
    select: list[str] | tuple[str, ...] | None = DEM_PRODUCTS,
    preview: bool = True,
) -> dict[str, Path]:
    """Write the selected layers (all registered ones present if ``select`` is None) as
    ``<out_dir>/<name>_<layer>.tif``; returns layer name -> GeoTIFF path (and "mesh" -> PLY).
    The DEM's sidecar lists the layer files and the layers' meta, so :func:`read_layers`
    restores both."""
    out_dir = Path(out_dir)
    g = layers.geometry
    wanted = [n for n in (select if select is not None else LAYERS) if n in layers.layers and n in LAYERS]
    files = {n: layer_path(out_dir / name, n) for n in wanted}
    written: dict[str, Path] = {}
    for layer in wanted:
        extra: dict[str, Any] = {}
        if layer == "dem":
            extra = {"layers": {k: p.name for k, p in files.items()}, "meta": layers.meta,
                     "defined_cells": int(np.isfinite(layers["dem"]).sum())}
            if run_log:
                extra["run_log"] = run_log
        written[layer] = write_layer(files[layer], layer, layers[layer], g, made_by=made_by, parameters=parameters,
                                     inputs=inputs, context=layers.meta, png=preview, **extra)
    if mesh and "dem" in layers:
        xs, ys = g.centers()
        colours = layers.layers.get("ortho")
        v, f, c = dem_mesh(layers["dem"], xs, ys, colours)
        written["mesh"] = write_mesh_ply(out_dir / f"{name}_mesh.ply", v, f, c)
    return written


@step("write_products", inputs={"layers": "Layers", "out_dir": "path", "name": "str", "made_by": "str?",
                                "parameters": "dict?", "inputs": "list?", "mesh": "bool", "select": "list?",
                                "preview": "bool"},
      outputs={"files": "dict"})
def write_products(layers: Layers, out_dir: str | Path, name: str, made_by: str | None = None,
                   parameters: dict[str, Any] | None = None, inputs: list[str] | None = None,
                   mesh: bool = False, select: list[str] | None = None, preview: bool = True,
                   progress: Any = None, run_log: dict[str, Any] | None = None) -> dict[str, Path]:
    """The writer step: the layers as products under ``out_dir`` (see :func:`write_dem_products`)."""
    if progress is not None:
        progress(0, 1, f"writing {name}")
    files = write_dem_products(layers, Path(out_dir), name, made_by=made_by or "rvs-prox", parameters=parameters, inputs=inputs,
                               run_log=run_log, mesh=mesh, select=select, preview=preview)
    if progress is not None:
        progress(1, 1, f"wrote {len(files)} files")
    return files
