"""Points moved by 4x4 transforms in the renderer's hot loops; the transforms themselves are
:mod:`rvs_params.frames`' (imported here for the world, the head chain and the renderer)."""

from __future__ import annotations

import numpy as np

from rvs_params.frames import (  # noqa: F401 - the simulator's modules import them from here
    R_BODY_FROM_OPTICAL,
    invert,
    make_T,
    pose_from_spec,
    rot_x,
    rot_y,
    rot_z,
    rover_rotation,
    rpy,
)


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
