"""The sensor head on its PTU: where each camera sits, and each camera's true intrinsics.

The chain (seed 000 sect. 3.3.2, fig. 23) is rover -> PTU base (top of the mast) -> pan about
the base's z axis (positive = left, CCW seen from above) -> a lift to the tilt axis -> tilt
about the pan frame's y axis (negative = looking down, as the PTU-D46 counts) -> the sensor
mount. The ToF camera sits between the two stereo cameras, which are ``baseline`` apart.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from drivers.sim.transforms import R_BODY_FROM_OPTICAL, make_T, rot_y, rot_z
from drivers.tof import constants as tof_k

SENSORS = ("tof", "left", "right")

# the SR4000's image and field of view (seed 000 sect. 4.2), as its driver declares them
TOF_SIZE = (tof_k.WIDTH, tof_k.HEIGHT)
TOF_FOV_DEG = (tof_k.FOV_H_DEG, tof_k.FOV_V_DEG)
# PIKE F-210B (1920 x 1080 at most) with a lens that gives about 60 degrees horizontally.
STEREO_HFOV_DEG = 60.0


@dataclass
class HeadGeometry:
    """PTU placement and sensor mounts, in metres; frames x forward, y left, z up.

    ``ptu_base``: the pan axis foot in the rover frame (rover frame origin = ground under the
    rover centre). ``tilt_offset``: height of the tilt axis above the pan base. ``tof_offset``
    and ``stereo_offset``: optical centres in the tilt frame (the stereo pair at +-baseline/2
    in y around ``stereo_offset``).
    """

    ptu_base: tuple[float, float, float] = (0.10, 0.0, 1.20)
    tilt_offset: float = 0.06
    tof_offset: tuple[float, float, float] = (0.06, 0.0, 0.02)
    stereo_offset: tuple[float, float, float] = (0.06, 0.0, 0.02)
    baseline: float = 0.20
    stereo_hfov_deg: float = STEREO_HFOV_DEG
    tof_fov_deg: tuple[float, float] = TOF_FOV_DEG
    mounts: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        sx, sy, sz = self.stereo_offset
        centres = {
            "tof": self.tof_offset,
            "left": (sx, sy + self.baseline / 2.0, sz),
            "right": (sx, sy - self.baseline / 2.0, sz),
        }
        for name, c in centres.items():
            self.mounts.setdefault(name, make_T(R_BODY_FROM_OPTICAL, c))

    @classmethod
    def from_spec(cls, spec: dict | None) -> HeadGeometry:
        spec = dict(spec or {})
        for key in ("ptu_base", "tof_offset", "stereo_offset", "tof_fov_deg"):
            if key in spec:
                spec[key] = tuple(float(v) for v in spec[key])
        return cls(**spec)

    def T_rover_from_tilt(self, pan_deg: float, tilt_deg: float) -> np.ndarray:
        T_pan = make_T(rot_z(pan_deg), self.ptu_base)
        T_tilt = make_T(rot_y(-tilt_deg), (0.0, 0.0, self.tilt_offset))
        return T_pan @ T_tilt

    def T_rover_from_sensor(self, sensor: str, pan_deg: float, tilt_deg: float) -> np.ndarray:
        if sensor not in self.mounts:
            raise KeyError(f"unknown sensor {sensor!r}; expected one of {sorted(self.mounts)}")
        return self.T_rover_from_tilt(pan_deg, tilt_deg) @ self.mounts[sensor]

    def intrinsics(self, sensor: str, width: int, height: int) -> np.ndarray:
        """True pinhole K; the principal point is the image centre ((W-1)/2, (H-1)/2)."""
        if sensor == "tof":
            fx = (width / 2.0) / np.tan(np.radians(self.tof_fov_deg[0] / 2.0))
            fy = (height / 2.0) / np.tan(np.radians(self.tof_fov_deg[1] / 2.0))
        elif sensor in ("left", "right"):
            fx = fy = (width / 2.0) / np.tan(np.radians(self.stereo_hfov_deg / 2.0))
        else:
            raise KeyError(f"unknown sensor {sensor!r}; expected one of {sorted(self.mounts)}")
        return np.array([[fx, 0.0, (width - 1) / 2.0], [0.0, fy, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
