"""4x4 homogeneous transforms shared by the world, the head chain and the renderer."""

from __future__ import annotations

import numpy as np


def rot_x(deg: float) -> np.ndarray:
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(deg: float) -> np.ndarray:
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(deg: float) -> np.ndarray:
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Rotation from roll/pitch/yaw in degrees (applied x, then y, then z: R = Rz Ry Rx)."""
    return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)


def make_T(R: np.ndarray | None = None, t: np.ndarray | list[float] | tuple[float, ...] | None = None) -> np.ndarray:
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    if t is not None:
        T[:3, 3] = np.asarray(t, dtype=float)
    return T


def invert(T: np.ndarray) -> np.ndarray:
    R = T[:3, :3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ T[:3, 3]
    return out


def pose_from_spec(spec: dict | None) -> np.ndarray:
    """A pose written in a scene file: ``{xyz: [x, y, z], rpy: [roll, pitch, yaw]}`` (metres, degrees)."""
    spec = spec or {}
    return make_T(rpy(*spec.get("rpy", (0.0, 0.0, 0.0))), spec.get("xyz", (0.0, 0.0, 0.0)))


# Camera optical frame (x right, y down, z forward) expressed in a body frame (x forward, y left, z up).
R_BODY_FROM_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def rotate(x: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Rows of x (N x 3, or one 3-vector) rotated by R, i.e. ``x @ R.T``.

    Written out per component rather than as a matmul: BLAS on N x 3 by 3 x 3 is erratic
    (its threads spin against the renderer's own on a busy 2-core machine: 100x slower).
    """
    x = np.asarray(x)
    if x.ndim == 1:
        return R @ x
    out = np.empty(x.shape, np.result_type(x.dtype, np.float32))
    x0, x1, x2 = x[:, 0], x[:, 1], x[:, 2]
    for k in range(3):
        out[:, k] = x0 * R[k, 0] + x1 * R[k, 1] + x2 * R[k, 2]
    return out


def transform(x: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Points x (N x 3 or 3) mapped by the 4x4 T."""
    return rotate(x, T[:3, :3]) + T[:3, 3]
