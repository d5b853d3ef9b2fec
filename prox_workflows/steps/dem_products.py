"""Writers: a DEM and its companion layers as products, the step that says where a script's
results go. One GeoTIFF per layer (GDAL and QGIS open them in place), a PNG preview with a
colour map and legend, a YAML sidecar each (all from the layer registry,
:mod:`prox_workflows.layers`), and a textured mesh for 3D viewing."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..engine import step
from ..grid import Layers
from ..layers import rover_meta, write_layers
from ..products import product_set
from .mesh import dem_mesh, write_mesh_ply

# what a DEM job publishes (the server's products); the other registered layers are a script's choice
DEM_PRODUCTS = ("dem", "variance", "count", "filled", "ortho", "slope", "step", "roughness", "hazard",
                "traversability")


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
    dem_file: str | None = None,
    rover_mask: Any = None,
) -> dict[str, Path]:
    """Write the selected layers (all registered ones present if ``select`` is None) as
    ``<out_dir>/<name>_<layer>.tif`` (the DEM as ``dem_file`` if given); returns layer name ->
    GeoTIFF path (and "mesh" -> PLY). ``rover_mask``, the footprint a scan masked out, is
    recorded in the DEM's meta as the rover, which the previews draw."""
    out_dir = Path(out_dir)
    g = layers.geometry
    dem_path = out_dir / (dem_file or f"{name}_dem.tif")
    rover = rover_meta(rover_mask)
    if rover is not None:
        layers = Layers(layers.geometry, dict(layers.layers), {**layers.meta, "rover": rover})
    with product_set(out_dir):  # all files or none: never a DEM whose layers come from two runs
        written: dict[str, Path] = write_layers(dem_path, layers, made_by=made_by, parameters=parameters,
                                                inputs=inputs, select=select, png=preview, run_log=run_log)
        if mesh and "dem" in layers:
            xs, ys = g.centers()
            colours = layers.layers.get("ortho")
            v, f, c = dem_mesh(layers["dem"], xs, ys, colours)
            written["mesh"] = write_mesh_ply(out_dir / f"{name}_mesh.ply", v, f, c)
    return written


@step("write_products", outputs={"files": "dict"})
def write_products(layers: Layers, out_dir: str | Path, name: str, made_by: str | None = None,
                   parameters: dict[str, Any] | None = None, inputs: list[str] | None = None,
                   mesh: bool = False, select: list[str] | None = None, preview: bool = True,
                   dem_file: str | None = None, rover_mask: Any = None, crs: str | None = None,
                   progress: Any = None, run_log: dict[str, Any] | None = None) -> dict[str, Path]:
    """The writer step: the layers as products under ``out_dir`` (see :func:`write_dem_products`).

    ``crs`` (``EPSG:<code>``) names the CRS of the layers' x and y when the inputs did not carry
    it (a point cloud, a GeoTIFF without GeoKeys): every GeoTIFF and sidecar then says it, so
    QGIS overlays the products on the source. None keeps the layers' own (the local frame)."""
    if crs is not None:
        layers = Layers(layers.geometry.with_crs(crs), layers.layers, layers.meta)
    if progress is not None:
        progress(0, 1, f"writing {name}")
    files = write_dem_products(layers, Path(out_dir), name, made_by=made_by or "rvs-prox", parameters=parameters, inputs=inputs,
                               run_log=run_log, mesh=mesh, select=select, preview=preview,
                               dem_file=dem_file, rover_mask=rover_mask)
    if progress is not None:
        progress(1, 1, f"wrote {len(files)} files")
    return files
