"""4x4 homogeneous transforms between the frames of seed 000 sect. 3.3.2 (camera -> PTU -> rover
-> global), for every package: the simulator builds its truth with them, the workflows and the
server their belief, so the two are one arithmetic and differ only where a calibration does.

Frames: camera optical (x right, y down, z forward); body frames (PTU, rover, global: x forward,
y left, z up). Angles in degrees, lengths in metres.
"""

from __future__ import annotations

from typing import Any

import numpy as np

# Camera optical frame (x right, y down, z forward) expressed in a body frame (x forward, y left, z up).
R_BODY_FROM_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


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


def rover_rotation(heading: float, roll: float = 0.0, pitch: float = 0.0) -> np.ndarray:
    """The rover body's orientation in the global frame from its heading and the roll (left side
    up) and pitch (nose up) an IMU gives: yaw, then pitch, then roll. Along the body's x the
    ground it stands on rises tan(pitch) per metre, along its y tan(roll) / cos(pitch)."""
    return rot_z(heading) @ rot_y(-pitch) @ rot_x(roll)


def make_T(R: np.ndarray | None = None, t: Any = None) -> np.ndarray:
    """The 4x4 transform of rotation ``R`` (identity if None) then translation ``t`` (zero if None)."""
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    if t is not None:
        T[:3, 3] = np.asarray(t, dtype=float)
    return T


def invert(T: np.ndarray) -> np.ndarray:
    """The inverse of a rigid 4x4 transform (rotation transposed, no general matrix inverse)."""
    R = T[:3, :3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ T[:3, 3]
    return out


def pose_from_spec(spec: dict | None) -> np.ndarray:
    """A pose written in a scene or head file: ``{xyz: [x, y, z], rpy: [roll, pitch, yaw]}``."""
    spec = spec or {}
    return make_T(rpy(*spec.get("rpy", (0.0, 0.0, 0.0))), spec.get("xyz", (0.0, 0.0, 0.0)))
