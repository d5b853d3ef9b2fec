"""Coordinate transforms of seed 000 sect. 3.3.2: camera -> PTU (mount calibration) -> pan and
tilt -> rover -> global (rover pose). 4x4 homogeneous matrices throughout.

Frames: camera optical (x right, y down, z forward); PTU, rover and global (x forward, y left,
z up). Pan is positive to the left (counter-clockwise seen from above), tilt negative looking
down, as the PTU-D46 counts them. The same chain is the simulator's truth; this module is the
server's *belief*, read from ``config/head.yaml``, which a calibration may correct.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rvs_params.frames import (  # noqa: F401 - the workflows and the server import them from here
    R_BODY_FROM_OPTICAL,
    invert,
    make_T,
    rot_x,
    rot_y,
    rot_z,
    rover_rotation,
    rpy,
)

from ..products import write_yaml_atomic


def apply(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Transform N x 3 (or H x W x 3) points; float32 in, float32 out in the rover's local frame.

    float64 out when the points are float64 or the transform moves them more than 10 km (a global
    frame in a projected CRS): float32 steps are 0.5 m at 5e6 m, coarser than any DEM cell."""
    pts = np.asarray(points)
    flat = pts.reshape(-1, 3).astype(np.float64)
    out = flat @ T[:3, :3].T + T[:3, 3]
    wide = pts.dtype == np.float64 or float(np.abs(T[:3, 3]).max()) > GEOREFERENCED_M
    return out.reshape(pts.shape).astype(np.float64 if wide else np.float32)


# Beyond this offset (m) a frame is taken as georeferenced and coordinates stay float64.
GEOREFERENCED_M = 1.0e4


@dataclass
class HeadCalibration:
    """PTU placement and sensor mounts (``config/head.yaml``), in metres and degrees.

    ``mounts[sensor]`` is ``{xyz: [x, y, z], rpy: [roll, pitch, yaw]}``: the optical centre in the
    tilt frame and a small correction of the nominal forward-looking orientation.
    """

    ptu_base: tuple[float, float, float] = (0.10, 0.0, 1.20)
    tilt_offset: float = 0.06
    mounts: dict[str, dict[str, list[float]]] = field(default_factory=lambda: {
        "tof": {"xyz": [0.06, 0.0, 0.0], "rpy": [0.0, 0.0, 0.0]},
        "left": {"xyz": [0.06, 0.10, 0.0], "rpy": [0.0, 0.0, 0.0]},
        "right": {"xyz": [0.06, -0.10, 0.0], "rpy": [0.0, 0.0, 0.0]},
    })

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> HeadCalibration:
        mounts = {k: {"xyz": list(v.get("xyz", [0, 0, 0])), "rpy": list(v.get("rpy", [0, 0, 0]))}
                  for k, v in (d.get("mounts") or {}).items()}
        out = cls(tuple(d.get("ptu_base", (0.10, 0.0, 1.20))), float(d.get("tilt_offset", 0.06)))
        out.mounts.update(mounts)
        return out

    def T_tilt_from_sensor(self, sensor: str) -> np.ndarray:
        if sensor not in self.mounts:
            raise KeyError(f"no mount calibration for sensor '{sensor}' (have {', '.join(self.mounts)})")
        m = self.mounts[sensor]
        return make_T(rpy(*m.get("rpy", (0, 0, 0))) @ R_BODY_FROM_OPTICAL, m["xyz"])

    def T_rover_from_sensor(self, sensor: str, pan: float, tilt: float) -> np.ndarray:
        T_pan = make_T(rot_z(pan), self.ptu_base)
        T_tilt = make_T(rot_y(-tilt), (0.0, 0.0, self.tilt_offset))
        return T_pan @ T_tilt @ self.T_tilt_from_sensor(sensor)

    def look_at(self, target_rover: np.ndarray) -> tuple[float, float]:
        """Pan and tilt that put a rover-frame point on the PTU's axis of view (sensor offsets are
        a few centimetres against metres of range, so the PTU's own axes stand in for the sensor)."""
        base = np.array(self.ptu_base, dtype=float) + np.array([0.0, 0.0, self.tilt_offset])
        d = np.asarray(target_rover, float) - base
        pan = math.degrees(math.atan2(d[1], d[0]))
        tilt = math.degrees(math.atan2(d[2], math.hypot(d[0], d[1])))
        return pan, tilt


def in_rover_frame(pose: tuple[float, float, float], x: float, y: float) -> tuple[float, float]:
    """Global (x, y) in the frame of the rover at ``pose`` (x, y, heading deg; x forward, y left)."""
    c, s = math.cos(math.radians(pose[2])), math.sin(math.radians(pose[2]))
    dx, dy = x - pose[0], y - pose[1]
    return dx * c + dy * s, -dx * s + dy * c


def T_global_from_rover(x: float, y: float, heading: float, z: float = 0.0, roll: float = 0.0,
                        pitch: float = 0.0) -> np.ndarray:
    """The rover pose in the global frame, its body tilted by the roll and pitch its IMU or the
    GNC gives (level without them): the sensors ride on the body, so a frame taken on a 10 deg
    slope and placed level puts ground 3 m out 0.5 m off."""
    return make_T(rover_rotation(heading, roll, pitch), (x, y, z))


def camera_matrix(K: np.ndarray, T_global_cam: np.ndarray) -> np.ndarray:
    """The 3 x 4 calibration matrix P = K [R | t] that maps global points to image pixels."""
    T_cam_global = invert(T_global_cam)
    return K @ T_cam_global[:3, :]


def project(P: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel u, v and depth of N x 3 global points through P (depth <= 0: behind the camera)."""
    hom = points @ P[:, :3].T + P[:, 3]
    depth = hom[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = hom[:, 0] / depth
        v = hom[:, 1] / depth
    return u, v, depth


def write_cal(path: Path, K: np.ndarray, T_global_cam: np.ndarray, size: tuple[int, int], **extra: Any) -> Path:
    """A view's ``.cal`` file: the camera calibration matrix (global -> image) and its parts."""
    P = camera_matrix(K, T_global_cam)
    data = {  # full precision: reprocessing the recorded views must give the same products
        "P": P.tolist(),
        "K": np.asarray(K, float).tolist(),
        "T_global_camera": np.asarray(T_global_cam, float).tolist(),
        "image_size": list(size),
        **extra,
    }
    return write_yaml_atomic(Path(path), data)


def read_cal(path: Path) -> dict[str, Any]:
    import yaml

    data = yaml.safe_load(Path(path).read_text())
    for key in ("P", "K", "T_global_camera"):
        data[key] = np.asarray(data[key], dtype=float)
    return data
