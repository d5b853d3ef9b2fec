"""``rvs-dem-import INPUT... --cell M [--bounds xmin,ymin,xmax,ymax] -o DEM.tif``: DemImport (direct
reconstruction, the greatest height per cell) of point clouds into a GeoTIFF DEM.

Inputs: PLY (ascii or binary), ``.npy`` (N x 3 or N x 4), x y z [i] text, and the 4-channel
coordinate images AcquireTofCoordImages writes (x, y, z, intensity; NaN pixels undefined). All
inputs go into one DEM. With ``--noise tof`` every point gets a variance from the ToF noise model
(range from the sensor position - read from the image's ``.cal`` file beside it, or ``--sensor`` -
and the intensity as amplitude), which adds the ``measurement_variance`` and ``wmean`` layers
that ``rvs-dem-mosaik --rule fuse`` weighs by.

Files (the layer naming every DEM tool here shares): ``-o site_dem.tif`` writes ``site_dem.tif``
and its companions ``site_mean.tif``, ``site_min.tif``, ``site_count.tif``,
``site_variance.tif`` (spread of the heights in the cell), and when present
``site_measurement_variance.tif``, ``site_wmean.tif``, ``site_intensity.tif``; an output not
ending in ``_dem`` (``-o DEM.tif``) keeps its name and prefixes the companions with its stem
(``DEM_count.tif`` ...). Each GeoTIFF has a YAML sidecar (``site_dem.yaml`` lists every layer
file); ``--preview`` adds a PNG of the DEM.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from ..grid import GridGeometry, Layers, read_geotiff, write_geotiff
from ..pointcloud import read_points
from ..products import preview, write_png, write_sidecar
from ..steps.dem_import import cells_from_bounds, dem_import
from ..steps.noise import tof_sigma
from ..steps.transforms import read_cal
from .parser import ToolParser

MADE_BY = "rvs-dem-import (prox_workflows.steps.dem_import)"

MEANING = {
    "dem": "greatest height of the points in the cell (m, z up, global frame)",
    "mean": "mean height of the points in the cell (m)",
    "min": "least height of the points in the cell (m)",
    "count": "points in the cell",
    "variance": "variance of the heights in the cell (m^2, population)",
    "measurement_variance": "1 / sum(1 / point variance): variance of the information-weighted mean height (m^2)",
    "wmean": "information-weighted mean height (m)",
    "intensity": "mean intensity of the points in the cell",
    "source": "index of the input that last set the height (-1 none)",
    "filled": "1 where the height was interpolated from neighbours (hole filling)",
}


# ------------------------------------------------------------------------- layer files


def layer_prefix(dem_path: Path) -> Path:
    """``site_dem.tif`` -> ``site``; ``DEM.tif`` -> ``DEM`` (companions are ``<prefix>_<layer>.tif``)."""
    dem_path = Path(dem_path)
    stem = dem_path.stem
    if stem.endswith("_dem") and len(stem) > 4:
        stem = stem[:-4]
    return dem_path.with_name(stem)


def layer_path(dem_path: Path, layer: str) -> Path:
    if layer == "dem":
        return Path(dem_path)
    prefix = layer_prefix(dem_path)
    return prefix.with_name(f"{prefix.name}_{layer}.tif")


def write_layers(dem_path: Path, layers: Layers, made_by: str, parameters: dict[str, Any] | None = None,
                 inputs: list[str] | None = None, preview_png: bool = False,
                 meanings: dict[str, str] | None = None) -> dict[str, Path]:
    """Every layer as a GeoTIFF on the layers' grid, each with its sidecar; the DEM's sidecar
    lists the layer files and the metadata (``read_layers`` restores both)."""
    g = layers.geometry
    files: dict[str, Path] = {}
    for name, image in layers.layers.items():
        data = image.astype(np.float32) if image.dtype == np.float64 else image
        if data.dtype == np.bool_:
            data = data.astype(np.uint8)
        files[name] = write_geotiff(layer_path(dem_path, name), data, g)
    common = {"cell": g.cell, "bounds": list(g.bounds), "size": [g.width, g.height],
              "crs": "local: x forward at the start pose, y left, z up (m)"}
    for name, path in files.items():
        meaning = (meanings or {}).get(name) or MEANING.get(name, name)
        extra: dict[str, Any] = {"layer": name, "meaning": meaning, **common}
        if name == "dem":
            extra["layers"] = {k: p.name for k, p in files.items()}
            extra["meta"] = layers.meta
            extra["defined_cells"] = int(np.isfinite(layers["dem"]).sum())
        write_sidecar(path, made_by, parameters, inputs, **extra)
    if preview_png and "dem" in layers:
        write_png(Path(dem_path).with_suffix(".png"), preview(layers["dem"], cv2.COLORMAP_TURBO))
    return files


def read_layers(dem_path: Path) -> Layers:
    """A DEM GeoTIFF and whichever companion layers lie beside it (same grid), with the meta
    its sidecar recorded. A plain GeoTIFF DEM (from GDAL, say) reads as a lone ``dem`` layer."""
    dem_path = Path(dem_path)
    dem, g = read_geotiff(dem_path)
    if dem.ndim != 2:
        raise ValueError(f"{dem_path}: expected a single-band DEM, got shape {dem.shape}")
    layers = Layers(g)
    layers["dem"] = dem.astype(np.float32) if dem.dtype != np.float32 else dem
    names: list[str] = list(MEANING)
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
    for name in names:
        path = layer_path(dem_path, name)
        if name == "dem" or not path.is_file():
            continue
        image, gl = read_geotiff(path)
        if gl != g:
            raise ValueError(f"{path.name} is not on the grid of {dem_path.name}")
        layers[name] = image
    return layers


# ------------------------------------------------------------------------- inputs


def _parse_triplet(text: str, what: str) -> np.ndarray:
    vals = [float(v) for v in text.split(",")]
    if len(vals) != 3:
        raise ValueError(f"{what}: need x,y,z")
    return np.array(vals)


def _rover_mask(text: str | None) -> np.ndarray | None:
    """``xmin,ymin,xmax,ymax`` or ``x1,y1,x2,y2,x3,y3,...`` (a polygon) or a file of x y rows."""
    if text is None:
        return None
    if Path(text).is_file():
        return np.loadtxt(Path(text).read_text().replace(",", " ").splitlines(), ndmin=2)[:, :2]
    vals = [float(v) for v in text.split(",")]
    if len(vals) == 4:
        return np.array(vals)
    if len(vals) >= 6 and len(vals) % 2 == 0:
        return np.array(vals).reshape(-1, 2)
    raise ValueError("--rover-mask: xmin,ymin,xmax,ymax or x1,y1,x2,y2,x3,y3,... or a file")


def load_inputs(paths: list[Path], noise: str, sensor: np.ndarray | None,
                frequency_mhz: float = 30.0) -> tuple[np.ndarray, np.ndarray | None]:
    """All inputs' points stacked (N x 3, or N x 4 if every input has intensity) and, with the
    ToF noise model, each point's variance."""
    clouds, variances = [], []
    for path in paths:
        pts = read_points(path)
        clouds.append(pts)
        if noise == "tof":
            origin = sensor
            cal = path.with_suffix(".cal")
            if cal.is_file():
                origin = read_cal(cal)["T_global_camera"][:3, 3]
            if origin is None:
                raise ValueError(f"{path}: --noise tof needs the sensor position (a .cal file beside it or --sensor)")
            rng = np.linalg.norm(pts[:, :3].astype(np.float64) - origin[None, :], axis=1)
            amp = pts[:, 3] if pts.shape[1] == 4 else None
            variances.append(tof_sigma(rng, amp, frequency_mhz=frequency_mhz).astype(np.float64) ** 2)
    width = 4 if all(c.shape[1] == 4 for c in clouds) else 3
    points = np.concatenate([c[:, :width] for c in clouds]) if clouds else np.zeros((0, 3), np.float32)
    return points, (np.concatenate(variances) if variances else None)


def main(argv: list[str] | None = None) -> int:
    ap = ToolParser(prog="rvs-dem-import", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("inputs", nargs="+", type=Path, help="PLY, .npy, x y z text or 4-channel coordinate TIFF")
    ap.add_argument("--cell", type=float, required=True, help="cell size (m)")
    ap.add_argument("--bounds", help="xmin,ymin,xmax,ymax (m); default: the extent of the points")
    ap.add_argument("-o", "--output", type=Path, required=True, help="the DEM GeoTIFF (e.g. site_dem.tif)")
    ap.add_argument("--noise", choices=["none", "tof"], default="none",
                    help="per-point variances from the ToF noise model (default none)")
    ap.add_argument("--sensor", help="x,y,z of the sensor for --noise tof when no .cal file is beside an input")
    ap.add_argument("--frequency", type=float, default=30.0, help="ToF modulation frequency (MHz) for --noise tof")
    ap.add_argument("--rover-mask", help="the rover's footprint: xmin,ymin,xmax,ymax or a polygon x1,y1,x2,y2,...")
    ap.add_argument("--rover-ground-z", type=float, help="keep points in the footprint below this height")
    ap.add_argument("--preview", action="store_true", help="also write a PNG preview of the DEM")
    args = ap.parse_args(argv)
    try:
        if args.cell <= 0:
            raise ValueError("--cell must be positive")
        bounds = cells_from_bounds(args.bounds) if args.bounds else None
        sensor = _parse_triplet(args.sensor, "--sensor") if args.sensor else None
        mask = _rover_mask(args.rover_mask)
        t0 = time.perf_counter()
        points, variance = load_inputs(args.inputs, args.noise, sensor, args.frequency)
        t1 = time.perf_counter()
        geometry = GridGeometry.covering(*bounds, args.cell) if bounds else None
        if geometry is None and not len(points):
            raise ValueError("the inputs hold no defined points (and no --bounds to make an empty grid)")
        layers = dem_import(points, geometry=geometry, cell=args.cell, point_variance=variance,
                            rover_mask=mask, rover_ground_z=args.rover_ground_z)
        t2 = time.perf_counter()
        params = {"cell": args.cell, "bounds": list(bounds) if bounds else None, "noise": args.noise,
                  "rover_mask": mask, "rover_ground_z": args.rover_ground_z}
        files = write_layers(args.output, layers, MADE_BY, params, [str(p) for p in args.inputs], args.preview)
    except (OSError, ValueError) as exc:
        sys.stderr.write(f"rvs-dem-import: {exc}\n")
        return 1
    g = layers.geometry
    defined = int(np.isfinite(layers["dem"]).sum())
    print(f"{len(points)} points -> {g.width} x {g.height} cells of {g.cell} m, {defined} defined "
          f"({100.0 * defined / max(g.width * g.height, 1):.1f} %); read {t1 - t0:.2f} s, DemImport {t2 - t1:.3f} s")
    for name, path in files.items():
        print(f"  {name}: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
