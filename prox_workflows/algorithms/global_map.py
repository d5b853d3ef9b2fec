"""Global maps from orbit (seed 000 sect. 4.4.4): a GeoTIFF DEM or hazard map, moved into the
rover's frame and turned into what the planner and the map matcher take.

An orbital DTM comes in a map projection (UTM, a Mars equirectangular or polar stereographic
CRS: any whose units are metres); the rover's frame has its origin on the ground under the
rover's start. A configured origin (the start's easting and northing in the file's CRS) moves
one onto the other by a translation, the map's axes staying east and north (a rover whose start
heading is not east says so in its start pose, as it does for every other map). Heights keep
their datum: the matcher and the planner only use height differences.

A DEM becomes hazard and slope through Dem2Hazard, the code path of the rover's own maps, with
its step and roughness criteria out of reach: at a metre per cell an orbiter cannot see steps
or rocks the rover cares about, so only the slope judges; the rover's scans judge the rest. A
file that is already a hazard map (uint8 0 / 128 / 255) is taken as it is, with no slope and no
DEM to match against.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from rvs_params.hazard import CODES

from ..grid import GridGeometry, _is_geographic, epsg_code, read_geotiff
from .dem2hazard import dem2hazard, load_params


@dataclass
class GlobalMap:
    """A global map in the rover frame: hazard (0/128/255) and slope (deg, NaN unknown) for the
    planner, and the DEM (m, NaN unknown) when the source was one, for map matching."""

    hazard: np.ndarray
    slope: np.ndarray
    geometry: GridGeometry
    dem: np.ndarray | None = None
    source: str = ""


def orbital_hazard(dem: np.ndarray, cell: float, slope_max: float | None = None) -> dict[str, np.ndarray]:
    """Slope and hazard of an orbital DEM through Dem2Hazard, judged by slope alone (the window
    three cells wide; steps and roughness out of reach: an orbiter cannot see them)."""
    params = load_params(window=3 * cell, step_max=1e6, roughness_max=1e6,
                         **({"slope_max": slope_max} if slope_max is not None else {}))
    layers = dem2hazard(np.asarray(dem, dtype=np.float32), cell, params)
    return {"slope": layers["slope"].astype(np.float32), "hazard": layers["hazard"].astype(np.uint8)}


def is_hazard_map(values: np.ndarray) -> bool:
    """A uint8 raster holding only the hazard codes is a hazard map, not heights."""
    return values.dtype == np.uint8 and set(np.unique(values).tolist()) <= set(CODES)


def load_global(path: str | Path, origin: tuple[float, float] = (0.0, 0.0),
                slope_max: float | None = None) -> GlobalMap:
    """Read a global DEM or hazard map GeoTIFF and move it to the rover frame: the file's
    (easting, northing) = ``origin`` becomes (0, 0). Raises ValueError for a CRS in degrees
    (a geographic CRS cannot be offset by metres) or a raster that is neither heights nor a
    hazard map."""
    values, geom = read_geotiff(Path(path))
    code = epsg_code(geom.crs)
    if code is not None and _is_geographic(code):
        raise ValueError(f"{path} is in a geographic CRS (EPSG:{code}, degrees); reproject it to one in metres")
    if values.ndim != 2:
        raise ValueError(f"{path}: expected one band, found shape {values.shape}")
    if not (math.isfinite(origin[0]) and math.isfinite(origin[1])):
        raise ValueError("the global map's origin must be finite")
    local = replace(geom, xmin=geom.xmin - origin[0], ymax=geom.ymax - origin[1], crs=None)
    if is_hazard_map(values):
        slope = np.where(values == 0, 0.0, np.nan).astype(np.float32)
        return GlobalMap(values.astype(np.uint8), slope, local, None, str(path))
    if not np.issubdtype(values.dtype, np.number):
        raise ValueError(f"{path}: neither heights nor a 0/128/255 hazard map ({values.dtype})")
    dem = values.astype(np.float32)
    from ..grid import gdal_nodata

    nodata = gdal_nodata(Path(path))
    if nodata is not None:
        dem[dem == nodata] = np.nan
    layers = orbital_hazard(dem, geom.cell, slope_max)
    return GlobalMap(layers["hazard"], layers["slope"], local, dem, str(path))
