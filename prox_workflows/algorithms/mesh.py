"""A textured mesh of a DEM for 3D viewing (PLY with per-vertex ortho colours; the thesis used
VRML). MeshLab, CloudCompare and Blender open it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..products import write_atomic


def dem_mesh(dem: np.ndarray, xs: np.ndarray, ys: np.ndarray, colours: np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertices N x 3 float32, faces M x 3 int32, colours N x 3 uint8): two triangles per 2 x 2
    block of defined cells; undefined cells leave holes rather than invented surface."""
    h, w = dem.shape
    defined = np.isfinite(dem)
    index = np.full((h, w), -1, np.int64)
    rows, cols = np.nonzero(defined)
    index[rows, cols] = np.arange(len(rows))
    vertices = np.stack([xs[cols], ys[rows], dem[rows, cols]], axis=1).astype(np.float32)
    a, b = index[:-1, :-1], index[:-1, 1:]
    c, d = index[1:, :-1], index[1:, 1:]
    quad = (a >= 0) & (b >= 0) & (c >= 0) & (d >= 0)
    a, b, c, d = a[quad], b[quad], c[quad], d[quad]
    # rows run south, so (a, c, b) is counter-clockwise seen from above: normals point up
    faces = np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)]).astype(np.int32)
    if colours is None:
        col = np.full((len(vertices), 3), 180, np.uint8)
    else:
        g = colours[rows, cols]
        col = np.repeat(g[:, None], 3, axis=1) if g.ndim == 1 else g[:, :3]
        col = col.astype(np.uint8)
    return vertices, faces, col


def write_mesh_ply(path: Path, vertices: np.ndarray, faces: np.ndarray, colours: np.ndarray) -> Path:
    """Binary little-endian PLY with coloured vertices and triangle faces."""
    vtype = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    vert = np.empty(len(vertices), vtype)
    vert["x"], vert["y"], vert["z"] = vertices[:, 0], vertices[:, 1], vertices[:, 2]
    vert["red"], vert["green"], vert["blue"] = colours[:, 0], colours[:, 1], colours[:, 2]
    ftype = np.dtype([("n", "u1"), ("v", "<i4", (3,))])
    face = np.empty(len(faces), ftype)
    face["n"] = 3
    face["v"] = faces
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment RVS DEM mesh, global frame (m), ortho colours\n"
        f"element vertex {len(vert)}\nproperty float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\n"
        f"element face {len(face)}\nproperty list uchar int vertex_indices\nend_header\n"
    )

    def write(p: Path) -> None:
        with open(p, "wb") as fh:
            fh.write(header.encode("ascii"))
            fh.write(vert.tobytes())
            fh.write(face.tobytes())

    return write_atomic(Path(path), write)
