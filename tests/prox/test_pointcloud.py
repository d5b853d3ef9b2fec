"""Point cloud files: PLY round trips (binary and ascii), other writers' PLYs, .npy, text and the
4-channel coordinate images."""

from __future__ import annotations

import numpy as np
import pytest

from prox_workflows.pointcloud import PlyError, read_ply, read_points, write_ply
from prox_workflows.products import write_tiff


def cloud(n: int = 500, k: int = 4) -> np.ndarray:
    rng = np.random.default_rng(0)
    return (rng.normal(0, 3, (n, k)) * [1, 1, 0.3, 1000][:k]).astype(np.float32)


@pytest.mark.parametrize("binary", [True, False])
@pytest.mark.parametrize("k", [3, 4])
def test_round_trip(tmp_path, binary, k) -> None:
    pts = cloud(k=k)
    colors = np.random.default_rng(1).integers(0, 256, (len(pts), 3)).astype(np.uint8)
    path = write_ply(tmp_path / "c.ply", pts, colors=colors, binary=binary)
    back = read_points(path)
    assert back.dtype == np.float32 and back.shape == pts.shape
    assert np.array_equal(back, pts)  # float32 survives ascii too (9 significant digits)
    cols = read_ply(path)
    assert np.array_equal(np.column_stack([cols["red"], cols["green"], cols["blue"]]), colors)
    head = path.read_bytes()[:200]
    assert (b"binary_little_endian" in head) == binary


def test_reads_other_writers_plys(tmp_path) -> None:
    # big-endian doubles, extra properties, a face element after the vertices, comments
    pts = np.array([[1.5, -2.0, 0.25, 7.0], [3.0, 4.0, -1.0, 9.0]])
    header = ("ply\nformat binary_big_endian 1.0\ncomment made elsewhere\nelement vertex 2\n"
              "property double x\nproperty double y\nproperty double z\nproperty float nx\n"
              "property ushort scalar_intensity\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n")
    rows = np.zeros(2, np.dtype([("x", ">f8"), ("y", ">f8"), ("z", ">f8"), ("nx", ">f4"), ("i", ">u2")]))
    rows["x"], rows["y"], rows["z"], rows["i"] = pts[:, 0], pts[:, 1], pts[:, 2], pts[:, 3]
    face = np.array([3], ">u1").tobytes() + np.array([0, 1, 0], ">i4").tobytes()
    (tmp_path / "be.ply").write_bytes(header.encode() + rows.tobytes() + face)
    assert np.array_equal(read_points(tmp_path / "be.ply"), pts.astype(np.float32))
    # ascii with a face element before the vertices
    text = ("ply\nformat ascii 1.0\nelement face 1\nproperty list uchar int vertex_indices\n"
            "element vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
            "3 0 1 0\n1 2 3\n4 5 6\n")
    (tmp_path / "a.ply").write_text(text)
    assert np.array_equal(read_points(tmp_path / "a.ply"), [[1, 2, 3], [4, 5, 6]])


def test_bad_plys(tmp_path) -> None:
    (tmp_path / "x.ply").write_bytes(b"not a ply\n")
    with pytest.raises(PlyError):
        read_points(tmp_path / "x.ply")
    (tmp_path / "t.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 10\n"
                                     b"property float x\nproperty float y\nproperty float z\nend_header\n" + b"\0" * 20)
    with pytest.raises(PlyError, match="truncated"):
        read_points(tmp_path / "t.ply")
    (tmp_path / "n.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n")
    with pytest.raises(PlyError, match="no y, z"):
        read_points(tmp_path / "n.ply")


def test_npy_text_and_coordinate_images(tmp_path) -> None:
    pts = cloud(k=3)
    np.save(tmp_path / "p.npy", pts.astype(np.float64))
    assert np.array_equal(read_points(tmp_path / "p.npy"), pts)
    np.savetxt(tmp_path / "p.xyz", pts[:5], fmt="%.9g")
    # text keeps float64 (an x y z export of a georeferenced scan needs it): equal to 9 digits
    assert np.array_equal(read_points(tmp_path / "p.xyz").astype(np.float32), pts[:5])
    img = np.full((6, 8, 4), np.nan, np.float32)
    img[1:3, 2:5, :3] = np.arange(18, dtype=np.float32).reshape(2, 3, 3)
    img[..., 3] = 100.0
    img[4, 4, :3] = -1.0  # the camera libraries' "no measurement"
    write_tiff(tmp_path / "v.tif", img)  # as AcquireTofCoordImages writes them
    got = read_points(tmp_path / "v.tif")
    assert got.shape == (6, 4)
    assert np.array_equal(got[:, :3], img[1:3, 2:5, :3].reshape(-1, 3))
    assert np.all(got[:, 3] == 100.0)
    with pytest.raises(ValueError):
        read_points(tmp_path / "p.e57")  # LAS/LAZ, PCD are read now; E57 is not
