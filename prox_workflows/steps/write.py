"""Writers: the steps that say where a script's results go (as PDAL's writers are stages).

A DEM and its companion layers as products: one GeoTIFF per layer (GDAL and QGIS open them in
place), a PNG preview with a colour map and legend, a YAML sidecar each (all from the layer
registry, :mod:`prox_workflows.layers`), and a textured mesh for 3D viewing. A plan's products:
its summary (the plan YAML), the path and waypoint tables and its drawings. A stereo pair's
disparity and point cloud. Every product has its sidecar.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..algorithms.mesh import dem_mesh, write_mesh_ply
from ..algorithms.plan_drawing import LEGEND, draw_plan, ortho_figure, plan_map_rgb
from ..algorithms.planner import PlanResult
from ..algorithms.stereo import Disparity, SgbmParams, cloud, sigma_d_for, to_gray8
from ..engine import step
from ..grid import GridGeometry, Layers
from ..layers import rover_meta, write_layers
from ..mapview import Marks
from ..pointcloud import write_ply
from ..products import (
    preview,
    product_set,
    write_atomic,
    write_png,
    write_sidecar,
    write_text_atomic,
    write_tiff,
    write_yaml_atomic,
)

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


def plan_summary(result: PlanResult) -> dict[str, Any]:
    """YAML-ready plan: parameters, path and waypoints."""
    wp = result.waypoints
    return {
        "start": list(result.start),
        "goal": list(result.goal),
        "cost": result.cost,
        "cost_driven": float(result.cost_so_far[result.cut - 1]),
        "reaches_goal": result.reaches_goal,
        "expanded_cells": result.expanded,
        "grid": {"cell": result.image.geometry.cell, "xmin": result.image.geometry.xmin,
                 "ymax": result.image.geometry.ymax, "width": result.image.geometry.width,
                 "height": result.image.geometry.height},
        "parameters": result.params.as_dict(),
        "warnings": list(result.warnings),
        "path": [[float(x), float(y), float(g), int(i < result.cut)]
                 for i, ((x, y), g) in enumerate(zip(result.path, result.cost_so_far, strict=True))],
        "path_columns": ["x", "y", "cost_so_far", "drive"],
        "waypoints": wp.rows(),
        "waypoint_columns": list(wp.COLUMNS),
    }


def write_plan(result: PlanResult, prefix: str, ortho: tuple[np.ndarray, GridGeometry] | None = None,
               made_by: str = "rvs-path-planner", inputs: Sequence[str] = ()) -> list[str]:
    """PREFIX_path.csv, PREFIX_waypoints.csv, PREFIX_plan.yaml, PREFIX_plan_map.png and, with an
    ortho-image, PREFIX_plan_ortho.png (each product with its YAML sidecar). Returns the paths."""
    base = Path(prefix)
    params = result.params.as_dict()
    written: list[str] = []
    drive = (np.arange(len(result.path)) < result.cut).astype(int)
    lines = ["x,y,cost_so_far,drive"] + [f"{x:.4f},{y:.4f},{g:.6f},{d}" for (x, y), g, d
                                          in zip(result.path, result.cost_so_far, drive, strict=True)]
    p = write_text_atomic(base.with_name(base.name + "_path.csv"), "\n".join(lines) + "\n")
    written.append(str(p))
    write_sidecar(p, made_by, params, list(inputs), columns={
        "x, y": "world coordinates of the planning cells' centres (exact start and goal at the ends), m",
        "cost_so_far": "A* G from the start (w * distance + (1 - w) * environmental cost), m",
        "drive": "1 for the part the rover drives (before the cut at the local map's border)"})
    wp = result.waypoints
    lines = [",".join(wp.COLUMNS)] + [",".join(f"{v:.4f}" if np.isfinite(v) else "nan" for v in row)
                                      for row in wp.table()]
    p = write_text_atomic(base.with_name(base.name + "_waypoints.csv"), "\n".join(lines) + "\n")
    written.append(str(p))
    write_sidecar(p, made_by, params, list(inputs), columns={
        "x, y": "waypoint, world coordinates, m",
        "heading_deg": "heading of the leg leaving the waypoint (the last: arrival heading), deg CCW from x",
        "turn_deg": "turn on the spot at the waypoint before its leg, deg, left positive (NaN: heading unknown)",
        "leg_length": "length of the leg leaving the waypoint, m"})
    p = write_yaml_atomic(base.with_name(base.name + "_plan.yaml"),
                          {"made_by": made_by, "inputs": list(inputs), **plan_summary(result)})
    written.append(str(p))
    img = result.image
    rgb = draw_plan(plan_map_rgb(img), img.geometry, result.path, wp.xy, result.cut, img.local)
    p = write_png(base.with_name(base.name + "_plan_map.png"), rgb)
    written.append(str(p))
    write_sidecar(p, made_by, params, list(inputs), legend=list(LEGEND))
    if ortho is not None:
        o_img, o_geom = ortho
        rgb = ortho_figure(o_img, o_geom, "plan over the ortho-image", Marks(
            path=result.path, driven=result.cut, waypoints=wp.xy, goal=(float(result.goal[0]), float(result.goal[1]))))
        p = write_png(base.with_name(base.name + "_plan_ortho.png"), rgb)
        written.append(str(p))
        write_sidecar(p, made_by, params, list(inputs))
    return written


@step("write_plan", outputs={"files": "list[str]"})
def write_plan_step(plan: PlanResult, prefix: str, ortho: tuple[np.ndarray, GridGeometry] | None = None,
                    made_by: str | None = None, inputs: Sequence[str] | None = None) -> list[str]:
    """The plan's products (:func:`write_plan`): path, waypoints, summary and drawings."""
    return write_plan(plan, str(prefix), ortho=ortho, made_by=made_by or "rvs-prox", inputs=inputs or ())


@step("write_stereo", outputs={"files": "dict"})
def write_stereo(disparity: Disparity, left: np.ndarray, params: dict[str, Any] | None = None,
                 disparity_path: str | Path | None = None, rectified_path: str | Path | None = None,
                 cloud_path: str | Path | None = None, sigma_d: float | None = None, max_depth: float | None = None,
                 made_by: str | None = None, inputs: list[str] | None = None) -> dict[str, Any]:
    """The disparity (left and/or rectified geometry) and the point cloud in the left camera
    frame, each with its sidecar; returns what was written and the figures it printed."""
    disp = disparity
    p = SgbmParams.from_dict(params or {})
    made_by = made_by or "rvs-prox"
    inputs = list(inputs or [])
    valid = np.isfinite(disp.left)
    files: dict[str, Any] = {"lines": []}
    lines: list[str] = files["lines"]
    named = [Path(q) for q in (disparity_path, rectified_path, cloud_path) if q is not None]
    with product_set(named[0].parent if named else Path(".")):  # the disparity, cloud and sidecars land together
        if disparity_path is not None:
            path = Path(disparity_path)
            write_tiff(path, disp.left.astype(np.float32))
            write_png(path.with_suffix(".png"), preview(disp.left, cv2.COLORMAP_JET))
            write_sidecar(path, made_by, p.to_dict(), inputs, units="px", nan="invalid",
                          geometry="left original image", focal_px=disp.rect.focal, baseline_m=disp.rect.baseline,
                          valid_share=float(valid.mean()))
            files["disparity"] = path
            lines.append(f"disparity -> {path}")
        if rectified_path is not None:
            path = Path(rectified_path)
            write_tiff(path, disp.rectified.astype(np.float32))
            write_sidecar(path, made_by, p.to_dict(), inputs, units="px", nan="invalid",
                          geometry="rectified left image (cv2.stereoRectify, alpha 0)", P1=np.asarray(disp.rect.P1),
                          R1=np.asarray(disp.rect.R1), Q=np.asarray(disp.rect.Q))
            files["rectified"] = path
            lines.append(f"rectified disparity -> {path}")
        if cloud_path is not None:
            path = Path(cloud_path)
            sd = sigma_d_for(p.scale) if sigma_d is None else sigma_d
            pts, sig, pix = cloud(disp, sd)
            if max_depth is not None:
                keep = pts[:, 2] <= max_depth
                pts, sig, pix = pts[keep], sig[keep], pix[keep]
            if path.suffix.lower() == ".npy":
                write_atomic(path, lambda t: _save_npy(t, pts))
            else:
                grey = to_gray8(left)[pix[:, 0], pix[:, 1]]
                write_ply(path, np.column_stack([pts, grey.astype(np.float32)]),
                          np.repeat(grey[:, None], 3, axis=1), comment="rvs-stereo cloud, left camera frame (m)")
            write_sidecar(path, made_by, p.to_dict(), inputs, frame="left camera (x right, y down, "
                          "z forward)", units="m", points=len(pts), intensity="left image grey value",
                          noise_model="sigma_z = z^2 * sigma_d / (b * f)", sigma_d_px=sd,
                          baseline_m=disp.rect.baseline, focal_px=disp.rect.focal,
                          sigma_z_m={"median": float(np.median(sig)) if len(sig) else None,
                                     "max": float(np.max(sig)) if len(sig) else None})
            files["cloud"] = path
            lines.append(f"{len(pts)} points -> {path}")
    return files


def _save_npy(path: Path, pts: np.ndarray) -> None:
    with open(path, "wb") as fh:
        np.save(fh, pts.astype(np.float32), allow_pickle=False)
