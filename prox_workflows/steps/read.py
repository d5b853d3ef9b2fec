"""Readers: the steps that say where a script's data comes from (as PDAL's readers are stages).

``read_views`` turns a recorded views folder (what a DEM job's acquisition wrote: coordinate
images, their companions, ``.cal`` files, the image list and the scan's pose) back into the
views the server processed live, value for value; ``read_layers`` reads a DEM product and its
companion layers; ``read_points`` stacks point clouds for DemImport; ``read_stereo_pair`` a
stereo pair as taken and its calibration.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import numpy as np
import tifffile
import yaml

from rvs_params.hazard import CODES, UNDEFINED

from ..algorithms.acquire import AUX_SUFFIX, View, view_from_images
from ..algorithms.noise import tof_sigma
from ..algorithms.stereo import load_calibration
from ..algorithms.stereo import read_image as read_image_file
from ..algorithms.transforms import read_cal
from ..engine import step
from ..grid import Layers, gdal_nodata, parse_crs, read_geotiff
from ..layers import read_layers as _read_layers
from ..pointcloud import read_las
from ..pointcloud import read_points as _read_points


@step("read_views", outputs={"views": "list[View]", "rover_mask": "array?"})
def read_views(folder: str | Path) -> dict[str, Any]:
    """The views of a recorded folder in the order they were taken, and the rover mask the
    scan used (from ``*_scan.yaml``)."""
    folder = Path(folder)
    lists = sorted(folder.glob("*_images.csv"))
    if not lists:
        raise FileNotFoundError(f"{folder}: no *_images.csv (is this a DEM job's views folder?)")
    views: list[View] = []
    for listing in lists:
        with open(listing, newline="") as fh:
            for row in csv.DictReader(fh):
                image = folder / row["file"]
                coords = tifffile.imread(image)
                aux_path = image.with_name(image.stem + AUX_SUFFIX)
                if not aux_path.is_file():
                    raise FileNotFoundError(f"{aux_path}: the view's companion image is missing")
                view = view_from_images(len(views), coords, tifffile.imread(aux_path), read_cal(folder / row["cal"]))
                view.files = {"image": row["file"], "cal": row["cal"]}
                views.append(view)
    mask = None
    scans = sorted(folder.glob("*_scan.yaml"))
    if scans:
        info = yaml.safe_load(scans[0].read_text()) or {}
        if info.get("rover_mask") is not None:
            mask = np.asarray(info["rover_mask"], dtype=float)
    return {"views": views, "rover_mask": mask}


@step("read_layers", outputs={"layers": "Layers"})
def read_layers(path: str | Path) -> Layers:
    """A DEM GeoTIFF and its companion layers (the layer registry's names beside it)."""
    return _read_layers(Path(path))


@step("read_dem", outputs={"layers": "Layers"})
def read_dem(path: str | Path, nodata: float | None = None) -> Layers:
    """A single-band DEM GeoTIFF (ours or GDAL's) as a lone ``dem`` layer, float32 with NaN
    where undefined (the file's GDAL nodata value, or ``nodata``). The rover one of our DEMs
    recorded comes along in the meta, so products made from it draw the rover as the DEM's do."""
    image, geometry = read_geotiff(Path(path))
    if image.ndim != 2:
        raise ValueError(f"{path}: expected a single-band DEM, got shape {image.shape}")
    if nodata is None:
        nodata = gdal_nodata(path)
    dem = image.astype(np.float32)
    if nodata is not None and not math.isnan(nodata):
        dem[image == nodata] = np.nan
    meta: dict[str, Any] = {}
    sidecar = Path(path).with_suffix(".yaml")
    if sidecar.is_file():
        try:
            rover = ((yaml.safe_load(sidecar.read_text()) or {}).get("meta") or {}).get("rover")
        except (yaml.YAMLError, AttributeError):
            rover = None
        if isinstance(rover, dict):
            meta["rover"] = rover
    return Layers(geometry, {"dem": dem}, meta)


@step("read_points", outputs={"points": "array", "variance": "array?", "points_crs": "str?"})
def read_points(paths: list[str | Path], noise: str = "recorded", sensor: list[float] | None = None,
                frequency: float = 30.0, classes: list[int] | None = None, range: list[float] | None = None,
                min_reflectivity: float | None = None, crs: str | None = None) -> dict[str, Any]:
    """All inputs' points stacked (N x 3, or N x 4 if every input has intensity) and each
    point's height variance: ``recorded`` takes the variances a DEM job recorded beside its
    views (the server's own noise model; none if absent), ``tof`` computes them with the ToF
    noise model (sensor position from the ``.cal`` beside an input, or ``sensor``), ``none``
    gives no variances.

    Real scans need two filters the camera's views do not: ``classes`` keeps the LAS/LAZ points
    of those ASPRS classes (2 = ground: a DEM of the terrain, not of its trees and roofs), and
    ``range`` = (min, max) keeps the points whose distance from the sensor (``sensor`` or the
    ``.cal`` beside an input) lies within it. ``min_reflectivity`` > 0 is the server's
    phase-wrap filter on a raw cloud with intensity (amplitude x range^2 below that share of the
    input's median, after the range filter, as ``view_from_frame`` does). ``points_crs`` is ``crs`` if given, else the EPSG
    code a LAS/LAZ header names (when its unit is the metre: see CloudInfo), else None (local)."""
    if noise not in ("recorded", "tof", "none"):
        raise ValueError(f"noise must be recorded, tof or none, not {noise!r}")
    min_reflectivity = min_reflectivity or 0.0
    if range is not None and (len(range) != 2 or not 0 <= range[0] < range[1]):
        raise ValueError(f"range {range}: need min,max with 0 <= min < max (m from the sensor)")
    clouds: list[np.ndarray] = []
    variances: list[np.ndarray] = []
    file_crs: set[str] = set()
    for raw in paths:
        path = Path(raw)
        aux = path.with_name(path.stem + AUX_SUFFIX)
        if path.suffix.lower() in (".las", ".laz"):
            pts, info = read_las(path, [int(c) for c in classes] if classes else None)
            if info.crs:
                file_crs.add(info.crs)
        elif classes:
            raise ValueError(f"{path}: classes filter only LAS/LAZ points ({path.suffix} has no classification)")
        elif path.suffix in (".tif", ".tiff") and aux.is_file() and noise == "recorded":
            coords = tifffile.imread(path).reshape(-1, 4)
            keep = np.isfinite(coords[:, 2])
            pts = np.ascontiguousarray(coords[keep])
            variances.append(tifffile.imread(aux).reshape(-1, 4)[keep, 0].astype(np.float64))
        else:
            pts = _read_points(path)
        if noise == "tof" or range is not None or min_reflectivity > 0:
            cal = path.with_suffix(".cal")
            origin = read_cal(cal)["T_global_camera"][:3, 3] if cal.is_file() else (
                np.asarray(sensor, float) if sensor is not None else None)
            if origin is None:
                raise ValueError(f"{path}: --noise tof and the range and reflectivity filters need the sensor position "
                                 "(a .cal file beside it or --sensor)")
            rng = np.linalg.norm(pts[:, :3].astype(np.float64) - origin[None, :], axis=1)
            if range is not None:
                keep = (rng >= range[0]) & (rng <= range[1])
                pts, rng = pts[keep], rng[keep]
                if len(variances) == len(clouds) + 1:
                    variances[-1] = variances[-1][keep]
            if min_reflectivity > 0 and pts.shape[1] == 4 and len(pts):
                refl = pts[:, 3].astype(np.float64) * rng.astype(np.float32).astype(np.float64) ** 2
                keep = refl >= min_reflectivity * float(np.median(refl))
                pts, rng = pts[keep], rng[keep]
                if len(variances) == len(clouds) + 1:
                    variances[-1] = variances[-1][keep]
            if noise == "tof":
                amp = pts[:, 3] if pts.shape[1] == 4 else None
                variances.append(tof_sigma(rng, amp, frequency_mhz=frequency).astype(np.float64) ** 2)
        clouds.append(pts)
    width = 4 if clouds and all(c.shape[1] == 4 for c in clouds) else 3
    points = np.concatenate([c[:, :width] for c in clouds]) if clouds else np.zeros((0, 3), np.float32)
    variance = np.concatenate(variances) if variances and len(variances) == len(clouds) else None
    if len(file_crs) > 1:
        raise ValueError(f"the inputs are in different CRSs ({', '.join(sorted(file_crs))})")
    return {"points": points, "variance": variance, "points_crs": parse_crs(crs) or (file_crs.pop() if file_crs else None)}


def _read_map_layer(path: Path) -> tuple[np.ndarray, Any]:
    """A single-band GeoTIFF; float layers get NaN where the file's GDAL nodata value is."""
    image, geometry = read_geotiff(path)
    if image.ndim != 2:
        raise ValueError(f"{path}: expected a single-band map, got shape {image.shape}")
    if np.issubdtype(image.dtype, np.floating):
        nodata = gdal_nodata(path)
        if nodata is not None and not math.isnan(nodata):
            image = np.where(image == nodata, np.nan, image)
        image = image.astype(np.float32)
    return image, geometry


@step("read_global_maps", outputs={"maps": "NavMaps?"})
def read_global_maps(hazard: str | Path | None, slope: str | Path | None) -> Any:
    """Global maps (as :func:`read_nav_maps`) if given; None means blank ones."""
    if hazard is None and slope is None:
        return None
    if hazard is None or slope is None:
        raise ValueError("a hazard map and its slope map go together")
    return read_nav_maps(hazard, slope)


@step("read_nav_maps", outputs={"maps": "NavMaps"})
def read_nav_maps(hazard: str | Path, slope: str | Path) -> Any:
    """A hazard map (dem2hazard's CODES) and its slope map (degrees) on the same grid, as the planner
    takes them."""
    from ..algorithms.plan_maps import NavMaps

    hz, hgeom = _read_map_layer(Path(hazard))
    sl, sgeom = _read_map_layer(Path(slope))
    if hgeom != sgeom:
        raise ValueError(f"{hazard} and {slope} are on different grids ({hgeom} vs {sgeom})")
    if np.issubdtype(hz.dtype, np.floating):
        hz = np.where(np.isnan(hz), UNDEFINED, hz)
    values = set(np.unique(hz).tolist())
    if not values <= set(CODES):
        raise ValueError(f"{hazard}: a hazard map holds {', '.join(map(str, CODES))} only, found {sorted(values)[:8]}")
    return NavMaps(hz.astype(np.uint8), sl.astype(np.float32), hgeom)


@step("read_image", outputs={"image": "any"})
def read_image(path: str | Path | None) -> Any:
    """A GeoTIFF image and its grid (an ortho-image to draw on), or None without a path."""
    return None if path is None else read_geotiff(Path(path))


@step("read_stereo_pair", outputs={"left": "array", "right": "array", "calib": "any"})
def read_stereo_pair(left: str | Path, right: str | Path, calib: str | Path) -> dict[str, Any]:
    """A pair as taken and its calibration (image_size, K1 D1 K2 D2 R T)."""
    return {"calib": load_calibration(calib), "left": read_image_file(left), "right": read_image_file(right)}
