"""Map geometry and layers (grid_map's idea: named layers on one geometry), and GeoTIFF I/O.

Every DEM product (elevation, variance, count, ortho, slope, step, roughness, hazard,
traversability) is a layer on one :class:`GridGeometry`. Rasters are north-up as GeoTIFF wants
them: row 0 is the northern edge (largest y), column 0 the western edge (smallest x); cell
(row, col) covers x in [xmin + col*cell, xmin + (col+1)*cell) and y in (ymax - (row+1)*cell,
ymax - row*cell]. The global frame is local (x forward at the start pose, y left, z up, metres),
so GeoTIFFs carry a local engineering CRS by default: GDAL, QGIS and rasterio open them in place
with the right cell size and origin. A grid whose ``crs`` is an EPSG code (``--crs EPSG:32611`` on
the CLIs, or the CRS of a georeferenced input) writes it into the GeoKeyDirectory
(ProjectedCSTypeGeoKey, or GeographicTypeGeoKey for a geographic code), so QGIS overlays the
products on the source data; reading such a GeoTIFF gives the code back.

Coordinates stay float64 everywhere here (the GeoTIFF tie point and scale are doubles): at
eastings ~5e5 m and northings ~5e6 m float32 steps are 0.03-0.5 m, coarser than a DEM cell.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import tifffile

from .products import write_atomic

# GeoTIFF tags (GeoTIFF 1.1 spec) and GDAL's nodata tag
MODEL_PIXEL_SCALE = 33550
MODEL_TIEPOINT = 33922
GEO_KEY_DIRECTORY = 34735
GEO_ASCII_PARAMS = 34737
GDAL_NODATA = 42113
GDAL_METADATA = 42112


# GeoKeys (GeoTIFF 1.1): model type, raster type, citation, geographic and projected CRS codes
GT_MODEL_TYPE, GT_RASTER_TYPE, GT_CITATION = 1024, 1025, 1026
GEOGRAPHIC_TYPE, PROJECTED_CS_TYPE, PROJ_LINEAR_UNITS = 2048, 3072, 3076
USER_DEFINED = 32767
_EPSG = re.compile(r"^\s*(?:epsg\s*:\s*)?(\d{4,6})\s*$", re.IGNORECASE)


def parse_crs(text: str | int | None) -> str | None:
    """``EPSG:32611``, ``epsg:32611`` or ``32611`` -> ``"EPSG:32611"``; None or ``local`` -> None
    (the rover's local frame). Only EPSG codes: they are what a GeoTIFF's GeoKeys can name
    without a WKT, and what QGIS and GDAL resolve on their own."""
    if text is None:
        return None
    if isinstance(text, int):
        return f"EPSG:{text}"
    if text.strip().lower() in ("", "local", "none"):
        return None
    m = _EPSG.match(text)
    if not m:
        raise ValueError(f"crs {text!r}: give an EPSG code, e.g. EPSG:32611 (UTM 11N), or 'local'")
    return f"EPSG:{int(m.group(1))}"


def epsg_code(crs: str | None) -> int | None:
    """The integer EPSG code of a CRS string made by :func:`parse_crs` (None for the local frame)."""
    return None if crs is None else int(crs.split(":")[1])


def _is_geographic(code: int) -> bool:
    # EPSG's 2-D geographic CRSs are numbered 4001-4999 (WGS 84 = 4326, NAD83 = 4269, ETRS89 =
    # 4258); 4978 and its neighbours there are geocentric, which a raster never uses. Everything
    # else a DEM would be in (UTM 326xx/327xx, state planes, national grids) is projected.
    return 4000 < code < 5000


@dataclass(frozen=True)
class GridGeometry:
    """A north-up grid: cell size in metres, the north-west corner, and the size in cells.

    ``crs`` is the coordinate reference system of x and y: None for the rover's local frame,
    else ``"EPSG:<code>"``. It is not part of equality (the same cells are the same grid), but it
    travels with the geometry into every product written on it."""

    cell: float
    xmin: float
    ymax: float
    width: int
    height: int
    crs: str | None = field(default=None, compare=False)

    @classmethod
    def covering(cls, xmin: float, ymin: float, xmax: float, ymax: float, cell: float,
                 crs: str | None = None) -> GridGeometry:
        """The grid aligned to multiples of ``cell`` that covers the bounds."""
        x0 = math.floor(xmin / cell + 1e-9) * cell
        y1 = math.ceil(ymax / cell - 1e-9) * cell
        width = max(1, math.ceil((xmax - x0) / cell - 1e-9))
        height = max(1, math.ceil((y1 - ymin) / cell - 1e-9))
        return cls(cell, x0, y1, width, height, crs)

    def with_crs(self, crs: str | None) -> GridGeometry:
        """The same grid in ``crs`` (parsed with :func:`parse_crs`)."""
        return replace(self, crs=parse_crs(crs))

    @property
    def shape(self) -> tuple[int, int]:
        return (self.height, self.width)

    @property
    def xmax(self) -> float:
        return self.xmin + self.width * self.cell

    @property
    def ymin(self) -> float:
        return self.ymax - self.height * self.cell

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        return (self.xmin, self.ymin, self.xmax, self.ymax)

    def transform(self) -> tuple[float, float, float, float, float, float]:
        """GDAL geotransform: x = c0 + col*c1 + row*c2, y = c3 + col*c4 + row*c5 (cell corners)."""
        return (self.xmin, self.cell, 0.0, self.ymax, 0.0, -self.cell)

    def cell_of(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Row and column of the cell holding each point (may be outside the grid)."""
        col = np.floor((np.asarray(x) - self.xmin) / self.cell).astype(np.int64)
        row = np.floor((self.ymax - np.asarray(y)) / self.cell).astype(np.int64)
        return row, col

    def centers(self) -> tuple[np.ndarray, np.ndarray]:
        """x of each column's centre and y of each row's centre."""
        xs = self.xmin + (np.arange(self.width) + 0.5) * self.cell
        ys = self.ymax - (np.arange(self.height) + 0.5) * self.cell
        return xs, ys

    def inside(self, row: np.ndarray, col: np.ndarray) -> np.ndarray:
        return (row >= 0) & (row < self.height) & (col >= 0) & (col < self.width)


@dataclass
class Layers:
    """Named float32 (or uint8) layers on one geometry, with free-form metadata."""

    geometry: GridGeometry
    layers: dict[str, np.ndarray] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.layers[name]

    def __setitem__(self, name: str, value: np.ndarray) -> None:
        if value.shape[:2] != self.geometry.shape:
            raise ValueError(f"layer {name} has shape {value.shape[:2]}, grid is {self.geometry.shape}")
        self.layers[name] = value

    def __contains__(self, name: str) -> bool:
        return name in self.layers


# ------------------------------------------------------------------------------ GeoTIFF


def median_near(values: np.ndarray, geometry: GridGeometry, x: float, y: float, radius: float = 0.5,
                min_cells: int = 1) -> float | None:
    """The median of ``values`` (a layer on ``geometry``) over the square of half side
    ``radius`` round (x, y); None when fewer than ``min_cells`` of it are defined. The ground
    under the rover, which a frame's or a scan's points are placed on."""
    r, c = geometry.cell_of(np.array([x]), np.array([y]))
    k = max(1, int(round(radius / geometry.cell)))
    r0, c0 = int(r[0]), int(c[0])
    window = values[max(r0 - k, 0): max(r0 + k + 1, 0), max(c0 - k, 0): max(c0 + k + 1, 0)]
    known = window[np.isfinite(window)]
    return float(np.median(known)) if known.size >= max(min_cells, 1) else None


def geo_tags(geometry: GridGeometry, nodata: float | None) -> list[tuple[int, str, int, Any, bool]]:
    # GeoKeyDirectory: version 1.1.0, then (key, location, count, value) entries, sorted by key.
    #   GTModelTypeGeoKey (1024) = 32767 user-defined (the rover's local engineering frame),
    #     1 projected (ProjectedCSTypeGeoKey 3072 = the EPSG code) or 2 geographic (2048)
    #   GTRasterTypeGeoKey (1025) = 1 RasterPixelIsArea
    #   GTCitationGeoKey (1026) -> ASCII params
    #   ProjLinearUnitsGeoKey (3076) = 9001 metre (local frame only: an EPSG code brings its unit)
    code = epsg_code(geometry.crs)
    if code is None:
        citation = "RVS local frame: x forward at the start pose, y left, z up (m)|"
        keys = [1, 1, 0, 4,
                GT_MODEL_TYPE, 0, 1, USER_DEFINED,
                GT_RASTER_TYPE, 0, 1, 1,
                GT_CITATION, GEO_ASCII_PARAMS, len(citation), 0,
                PROJ_LINEAR_UNITS, 0, 1, 9001]
    else:
        citation = f"RVS product, EPSG:{code}|"
        crs_key = GEOGRAPHIC_TYPE if _is_geographic(code) else PROJECTED_CS_TYPE
        keys = [1, 1, 0, 4,
                GT_MODEL_TYPE, 0, 1, 2 if crs_key == GEOGRAPHIC_TYPE else 1,
                GT_RASTER_TYPE, 0, 1, 1,
                GT_CITATION, GEO_ASCII_PARAMS, len(citation), 0,
                crs_key, 0, 1, code]
    tags: list[tuple[int, str, int, Any, bool]] = [
        (MODEL_PIXEL_SCALE, "d", 3, (geometry.cell, geometry.cell, 0.0), False),
        (MODEL_TIEPOINT, "d", 6, (0.0, 0.0, 0.0, geometry.xmin, geometry.ymax, 0.0), False),
        (GEO_KEY_DIRECTORY, "H", len(keys), tuple(keys), False),
        (GEO_ASCII_PARAMS, "s", 0, citation, False),
    ]
    if nodata is not None:
        text = "nan" if math.isnan(nodata) else str(int(nodata)) if float(nodata).is_integer() else repr(nodata)
        tags.append((GDAL_NODATA, "s", 0, text, False))
    return tags


def write_geotiff(path: Path, image: np.ndarray, geometry: GridGeometry, nodata: float | None = None) -> Path:
    """One layer as a GeoTIFF (atomically). Float layers default to NaN as nodata."""
    if image.shape[:2] != geometry.shape:
        raise ValueError(f"image shape {image.shape[:2]} does not match the grid {geometry.shape}")
    if nodata is None and np.issubdtype(image.dtype, np.floating):
        nodata = float("nan")
    rgb = image.ndim == 3 and image.shape[2] in (3, 4) and image.dtype == np.uint8
    tags = geo_tags(geometry, nodata)

    def write(p: Path) -> None:
        tifffile.imwrite(p, image, photometric="rgb" if rgb else "minisblack", extratags=tags,
                         compression="zlib" if image.size > 65536 else None)

    return write_atomic(Path(path), write)


def _geometry_of(page: Any, path: Path) -> GridGeometry:
    scale = page.tags.get(MODEL_PIXEL_SCALE)
    tie = page.tags.get(MODEL_TIEPOINT)
    if scale is None or tie is None:
        raise ValueError(f"{path} has no GeoTIFF georeferencing (ModelPixelScale/ModelTiepoint)")
    sx, sy = scale.value[0], scale.value[1]
    i, j, _, x, y, _ = tie.value[:6]
    if not math.isclose(sx, sy, rel_tol=1e-9):
        raise ValueError(f"{path}: non-square cells ({sx} x {sy}) are not supported")
    return GridGeometry(float(sx), float(x - i * sx), float(y + j * sy), int(page.shape[1]), int(page.shape[0]),
                        _crs_of(page))


def _crs_of(page: Any) -> str | None:
    """``EPSG:<code>`` from the GeoKeyDirectory (projected or geographic), None for a local or
    user-defined frame or a file without GeoKeys."""
    tag = page.tags.get(GEO_KEY_DIRECTORY)
    if tag is None:
        return None
    keys = [int(v) for v in tag.value]
    entries = {keys[k]: (keys[k + 1], keys[k + 3]) for k in range(4, 4 + 4 * keys[3], 4) if k + 3 < len(keys)}
    for key in (PROJECTED_CS_TYPE, GEOGRAPHIC_TYPE):
        loc, value = entries.get(key, (1, 0))
        if loc == 0 and 0 < value < USER_DEFINED:
            return f"EPSG:{value}"
    return None


def read_geotiff(path: Path) -> tuple[np.ndarray, GridGeometry]:
    """Read a GeoTIFF written here or by GDAL (north-up, no rotation)."""
    with tifffile.TiffFile(path) as tif:
        page = tif.pages[0]
        geometry = _geometry_of(page, path)
        return page.asarray(), geometry


def read_geotiff_geometry(path: Path) -> GridGeometry:
    """The grid of a GeoTIFF from its header alone (a map view places a layer without its data)."""
    with tifffile.TiffFile(path) as tif:
        return _geometry_of(tif.pages[0], path)


def gdal_nodata(path: str | Path) -> float | None:
    """The GDAL nodata value a GeoTIFF declares (None: none, or one that is not a number)."""
    with tifffile.TiffFile(path) as tif:
        tag = tif.pages[0].tags.get(GDAL_NODATA)
    if tag is None:
        return None
    try:
        return float(str(tag.value).strip("\x00 "))
    except ValueError:
        return None
