"""Point clouds on disk: PLY (what Open3D, CloudCompare and MeshLab read), ``.npy``, plain text,
and the 4-channel coordinate images AcquireTofCoordImages writes (x, y, z, intensity per pixel).

``read_points`` always returns N x 3 (x, y, z) or N x 4 (with intensity) rows of defined points,
so DemImport does not care where a cloud came from. The rows keep the precision of the file:
float32 for float32 sources (the cameras' coordinate images, float PLYs), float64 when the source
holds doubles (double PLY properties, float64 ``.npy``, text). Why: a georeferenced cloud has
eastings near 5e5 m and northings near 5e6 m, where float32 steps are 0.03-0.5 m, so narrowing it
would move points to the wrong cell before DemImport ever sees them. PLY is read in ascii and
binary_little/big_endian with any vertex properties (x, y, z required; intensity, scalar_intensity,
amplitude or a grey value taken as the fourth column) and any other elements skipped.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import tifffile

from .products import write_atomic

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_INTENSITY_NAMES = ("intensity", "scalar_intensity", "amplitude", "scalar_amplitude", "grey", "gray")


class PlyError(ValueError):
    """A file that is not a PLY this reader understands."""


def _parse_header(fh) -> tuple[str, list[dict]]:
    if fh.readline().strip() != b"ply":
        raise PlyError("not a PLY file (no 'ply' magic)")
    fmt = None
    elements: list[dict] = []
    while True:
        line = fh.readline()
        if not line:
            raise PlyError("PLY header has no end_header")
        words = line.decode("ascii", "replace").split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            fmt = words[1]
        elif words[0] == "element":
            elements.append({"name": words[1], "count": int(words[2]), "props": []})
        elif words[0] == "property":
            if not elements:
                raise PlyError("PLY property before any element")
            if words[1] == "list":
                elements[-1]["props"].append((words[4], "list", _PLY_TYPES[words[2]], _PLY_TYPES[words[3]]))
            else:
                if words[1] not in _PLY_TYPES:
                    raise PlyError(f"unknown PLY type {words[1]}")
                elements[-1]["props"].append((words[2], _PLY_TYPES[words[1]]))
        elif words[0] == "end_header":
            break
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise PlyError(f"unsupported PLY format {fmt}")
    return fmt, elements


def read_ply(path: Path) -> dict[str, np.ndarray]:
    """The vertex element of a PLY as {property name: array}."""
    with open(path, "rb") as fh:
        fmt, elements = _parse_header(fh)
        if fmt == "ascii":
            text = fh.read().decode("ascii").split("\n")
            pos = 0
            for el in elements:
                if any(p[1] == "list" for p in el["props"]):
                    if el["name"] == "vertex":
                        raise PlyError("list properties in the vertex element are not supported")
                    pos += el["count"]
                    continue
                if el["name"] == "vertex":
                    rows = [ln for ln in text[pos:pos + el["count"]]]
                    data = np.loadtxt(rows, dtype=np.float64, ndmin=2) if rows else np.zeros((0, len(el["props"])))
                    if data.shape[1] < len(el["props"]):
                        raise PlyError("PLY vertex rows have fewer values than properties")
                    # the declared types, as binary files give them (a float PLY stays float32)
                    return {name: data[:, i].astype(typ) for i, (name, typ) in enumerate(el["props"])}
                pos += el["count"]
            raise PlyError("PLY has no vertex element")
        endian = "<" if fmt == "binary_little_endian" else ">"
        for el in elements:
            if any(p[1] == "list" for p in el["props"]):
                if el["name"] == "vertex":
                    raise PlyError("list properties in the vertex element are not supported")
                # a list element (faces) before the vertices: walk it row by row
                for _ in range(el["count"]):
                    for p in el["props"]:
                        ct = np.dtype(endian + p[2])
                        (n,) = np.frombuffer(fh.read(ct.itemsize), ct)
                        fh.read(int(n) * np.dtype(p[3]).itemsize)
                continue
            dtype = np.dtype([(name, endian + t) for name, t in el["props"]])
            buf = fh.read(dtype.itemsize * el["count"])
            if len(buf) < dtype.itemsize * el["count"]:
                raise PlyError(f"PLY file is truncated in element {el['name']}")
            if el["name"] == "vertex":
                arr = np.frombuffer(buf, dtype)
                return {name: arr[name] for name in arr.dtype.names}
        raise PlyError("PLY has no vertex element")


def _from_columns(cols: dict[str, np.ndarray], source: str) -> np.ndarray:
    missing = [c for c in ("x", "y", "z") if c not in cols]
    if missing:
        raise PlyError(f"{source}: vertex has no {', '.join(missing)}")
    out = [cols["x"], cols["y"], cols["z"]]
    for name in _INTENSITY_NAMES:
        if name in cols:
            out.append(cols[name])
            break
    wide = any(np.asarray(c).dtype.itemsize > 4 or not np.issubdtype(np.asarray(c).dtype, np.floating)
               for c in out[:3])
    return np.column_stack(out).astype(np.float64 if wide else np.float32)


def read_points(path: Path | str) -> np.ndarray:
    """N x 3 or N x 4 points from PLY, .npy, a coordinate-image TIFF or x y z [i] text, in the
    source's precision (float64 for doubles and text, else float32: see the module docstring).

    Coordinate images (H x W x 3 or 4) keep only defined pixels: z finite, and not the -1
    marker the camera libraries use for 'no measurement' (all of x, y, z equal to -1)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".ply":
        return _from_columns(read_ply(path), str(path))
    if suffix == ".npy":
        arr = np.load(path, allow_pickle=False)
        if arr.ndim == 3:
            return _from_image(arr, str(path))
        if arr.ndim != 2 or arr.shape[1] not in (3, 4):
            raise ValueError(f"{path}: expected N x 3 or N x 4 points, got shape {arr.shape}")
        return np.asarray(arr, dtype=np.float64 if arr.dtype == np.float64 else np.float32)
    if suffix in (".tif", ".tiff"):
        return _from_image(tifffile.imread(path), str(path))
    if suffix in (".las", ".laz"):
        return read_las(path)[0]
    if suffix == ".pcd":
        return read_pcd(path)
    if suffix in (".txt", ".xyz", ".csv", ".asc", ".pts"):
        text = path.read_text().replace(",", " ")
        arr = np.loadtxt(text.splitlines(), dtype=np.float64, ndmin=2, comments="#")
        if arr.shape[1] < 3:
            raise ValueError(f"{path}: need at least x y z per line")
        return arr[:, :4].astype(np.float64)
    raise ValueError(f"{path}: unknown point cloud type (PLY, PCD, LAS/LAZ, .npy, coordinate TIFF or x y z text)")


def _from_image(img: np.ndarray, source: str) -> np.ndarray:
    if img.ndim != 3 or img.shape[2] not in (3, 4):
        # tifffile may return channels first for planar files
        if img.ndim == 3 and img.shape[0] in (3, 4):
            img = np.moveaxis(img, 0, -1)
        else:
            raise ValueError(f"{source}: expected an H x W x 3|4 coordinate image, got {img.shape}")
    pix = img.reshape(-1, img.shape[2]).astype(np.float32)
    xyz = pix[:, :3]
    defined = np.isfinite(xyz).all(axis=1) & ~np.all(xyz == -1.0, axis=1)
    return pix[defined]


def write_ply(path: Path | str, points: np.ndarray, colors: np.ndarray | None = None,
              binary: bool = True, comment: str = "RVS point cloud, global frame (m)") -> Path:
    """Points (N x 3, or N x 4 with intensity) and optional N x 3 uint8 colours as a PLY
    (binary little-endian by default, ascii on request), written atomically."""
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] not in (3, 4):
        raise ValueError(f"points must be N x 3 or N x 4, got {pts.shape}")
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if pts.shape[1] == 4:
        fields.append(("intensity", "<f4"))
    if colors is not None:
        colors = np.asarray(colors)
        if colors.shape != (len(pts), 3):
            raise ValueError(f"colors must be N x 3, got {colors.shape}")
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    vert = np.empty(len(pts), np.dtype(fields))
    for i, (name, _) in enumerate(fields[: pts.shape[1]]):
        vert[name] = pts[:, i]
    if colors is not None:
        vert["red"], vert["green"], vert["blue"] = colors[:, 0], colors[:, 1], colors[:, 2]
    ply_type = {"<f4": "float", "u1": "uchar"}
    header = "ply\nformat {} 1.0\ncomment {}\nelement vertex {}\n{}end_header\n".format(
        "binary_little_endian" if binary else "ascii", comment, len(vert),
        "".join(f"property {ply_type[t]} {n}\n" for n, t in fields))

    def write(p: Path) -> None:
        with open(p, "wb") as fh:
            fh.write(header.encode("ascii"))
            if binary:
                fh.write(vert.tobytes())
            else:
                cols = [vert[n] for n, _ in fields]
                fmts = ["%.9g" if t == "<f4" else "%d" for _, t in fields]
                np.savetxt(fh, np.column_stack([c.astype(np.float64) for c in cols]), fmt=fmts)

    return write_atomic(Path(path), write)


# ------------------------------------------------------------------ LAS/LAZ and PCD

# metres per unit of the GeoTIFF/EPSG linear unit codes a LAS header names (ProjLinearUnitsGeoKey)
_UNIT_M = {9001: 1.0, 9002: 0.3048, 9003: 1200.0 / 3937.0, 9030: 1852.0, 9036: 1000.0}
_WKT_UNIT = re.compile(r'UNIT\["[^"]*",\s*([0-9.eE+-]+)(?:,\s*AUTHORITY\["EPSG",\s*"\d+"\])?\]\]\s*$')


@dataclass
class CloudInfo:
    """What a georeferenced file says about its coordinates.

    Points are always returned in metres (the toolbox's cells, thresholds and slopes are metric):
    a file in feet is scaled by ``unit_m``. ``crs`` is the EPSG code the returned x, y are in,
    which is the file's own only when its unit is the metre; a file in feet keeps its CRS in
    ``source_crs`` (for the sidecar) and gets ``crs`` None, since metre coordinates written
    with a feet CRS would put QGIS's overlay 3.3 times too far out."""

    crs: str | None = None
    source_crs: str | None = None
    unit_m: float = 1.0
    classes: dict[int, int] = field(default_factory=dict)  # class -> points in the file


def _las_geokeys(header: Any) -> tuple[dict[int, int], str | None]:
    keys: dict[int, int] = {}
    wkt = None
    for vlr in header.vlrs:
        kind = type(vlr).__name__
        if kind == "GeoKeyDirectoryVlr":
            keys = {int(k.id): int(k.value_offset) for k in vlr.geo_keys if int(k.tiff_tag_location) == 0}
        elif kind == "WktCoordinateSystemVlr":
            wkt = str(vlr.string).strip("\x00 ")
    return keys, wkt


def read_las(path: Path | str, classes: list[int] | None = None) -> tuple[np.ndarray, CloudInfo]:
    """N x 4 float64 (x, y, z in metres, intensity) of a LAS or LAZ file (laspy; LAZ through
    lazrs), optionally only the points of ``classes`` (ASPRS: 2 ground), and what its header
    says of its CRS and unit (GeoKeys first, else the WKT record)."""
    try:
        import laspy
    except ImportError as exc:  # a dependency; a broken install should say which
        raise ValueError(f"{path}: reading LAS/LAZ needs laspy (pip install 'laspy[lazrs]')") from exc
    try:
        las = laspy.read(str(path))
    except laspy.errors.LaspyException as exc:
        raise ValueError(f"{path}: {exc}") from exc
    cls = np.asarray(las.classification, np.int64)
    found = dict(zip(*(v.tolist() for v in np.unique(cls, return_counts=True)), strict=True))
    keep = np.isin(cls, classes) if classes else np.ones(len(cls), bool)
    pts = np.column_stack([np.asarray(las.x, np.float64)[keep], np.asarray(las.y, np.float64)[keep],
                           np.asarray(las.z, np.float64)[keep], np.asarray(las.intensity, np.float64)[keep]])
    keys, wkt = _las_geokeys(las.header)
    code = keys.get(3072) if keys.get(1024) == 1 else keys.get(2048) if keys.get(1024) == 2 else None
    code = code if code and 0 < code < 32767 else None
    unit = _UNIT_M.get(keys.get(3076, 9001), 1.0)
    if 3076 not in keys and wkt and (m := _WKT_UNIT.search(wkt)):
        unit = float(m.group(1))
    vunit = _UNIT_M.get(keys[4099], unit) if 4099 in keys else unit
    source = f"EPSG:{code}" if code else wkt
    if unit != 1.0 or vunit != 1.0:
        pts[:, 0:2] *= unit
        pts[:, 2] *= vunit
    return pts, CloudInfo(f"EPSG:{code}" if code and unit == 1.0 else None, source, unit, found)


_PCD_TYPES = {("F", 4): "f4", ("F", 8): "f8", ("I", 1): "i1", ("I", 2): "i2", ("I", 4): "i4", ("I", 8): "i8",
              ("U", 1): "u1", ("U", 2): "u2", ("U", 4): "u4", ("U", 8): "u8"}


def read_pcd(path: Path | str) -> np.ndarray:
    """The x, y, z (and intensity) of a PCD file (PCL's format, ascii or binary; not
    binary_compressed), in the file's precision, NaN points dropped."""
    head: dict[str, list[str]] = {}
    with open(path, "rb") as fh:
        while True:
            line = fh.readline()
            if not line:
                raise ValueError(f"{path}: PCD header has no DATA line")
            words = line.decode("ascii", "replace").split()
            if not words or words[0].startswith("#"):
                continue
            head[words[0].upper()] = words[1:]
            if words[0].upper() == "DATA":
                break
        body = fh.read()
    names, sizes, types = head.get("FIELDS", []), head.get("SIZE", []), head.get("TYPE", [])
    counts = [int(c) for c in head.get("COUNT", ["1"] * len(names))]
    n = int(head.get("POINTS", ["0"])[0])
    if not {"x", "y", "z"} <= set(names):
        raise ValueError(f"{path}: PCD fields {names} have no x, y, z")
    dtype = np.dtype([(nm, _PCD_TYPES[(t.upper(), int(s))], (c,)) if c > 1 else (nm, _PCD_TYPES[(t.upper(), int(s))])
                      for nm, s, t, c in zip(names, sizes, types, counts, strict=True)])
    mode = head["DATA"][0].lower()
    if mode == "ascii":
        flat = np.loadtxt(body.decode("ascii").splitlines(), dtype=np.float64, ndmin=2)
        cols: dict[str, np.ndarray] = {}
        pos = 0
        for nm, c in zip(names, counts, strict=True):
            cols[nm] = flat[:, pos].astype(dtype[nm].base if dtype[nm].shape == () else np.float64)
            pos += c
    elif mode == "binary":
        rec = np.frombuffer(body, dtype=dtype, count=n)
        cols = {nm: rec[nm] for nm in names}
    else:
        raise ValueError(f"{path}: PCD DATA {mode} is not supported (save it as ascii or binary)")
    pts = _from_columns(cols, str(path))
    return pts[np.isfinite(pts[:, :3]).all(axis=1)]
