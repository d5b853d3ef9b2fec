"""One hazard camera pair as geometry: its lens model and where its two cameras sit on the body.

Built from the drivers.hazcam settings alone, so the simulator renders exactly the pair that the
front end turns into points, and a bench that models the same sensor asks for it here instead
of declaring its own.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.base import DeviceError
from drivers.stereo.calibration import load_calibration
from rvs_params.frames import R_BODY_FROM_OPTICAL, make_T, rot_y, rot_z

from .backend import CAMERAS, NAME


@dataclass(frozen=True)
class PairRig:
    """``T_rover_left`` / ``T_rover_right``: each camera's OpenCV optical frame (x right, y down,
    z ahead) in the rover frame. ``calibration``: OpenCV stereoCalibrate's K1 D1 K2 D2 R T
    image_size (x_right = R x_left + T), what the stereo matcher rectifies with."""

    camera: str
    size: tuple[int, int]  # (width, height) px
    K: np.ndarray
    baseline: float
    T_rover_left: np.ndarray
    T_rover_right: np.ndarray
    calibration: dict[str, Any]

    @property
    def focal(self) -> float:
        return float(self.K[0, 0])

    @property
    def origin(self) -> np.ndarray:
        """The left camera's centre in the rover frame."""
        return self.T_rover_left[:3, 3].copy()


def pinhole(hfov_deg: float, size: tuple[int, int]) -> np.ndarray:
    """The intrinsics of an ideal pinhole of ``hfov_deg`` across ``size`` (principal point at the
    image centre, pixel centres at integers: the renderer's convention)."""
    w, h = size
    f = (w / 2.0) / np.tan(np.radians(hfov_deg) / 2.0)
    return np.array([[f, 0.0, (w - 1) / 2.0], [0.0, f, (h - 1) / 2.0], [0.0, 0.0, 1.0]])


def pair_rig(config: Any, camera: str) -> PairRig:
    """The pair ``camera`` ("front" or "rear") of the typed drivers.hazcam settings; with a
    calibration file configured for it, that file's lens model and baseline on the declared mount."""
    if camera not in CAMERAS:
        raise ValueError(f"no hazcam {camera!r}; the body's pairs are {', '.join(CAMERAS)}")
    size = (int(config.size[0]), int(config.size[1]))
    path = getattr(config, f"{camera}_calibration")
    if path:
        try:
            cal = load_calibration(path, size)
        except DeviceError as exc:  # the stereo pair's file format, read for this pair's key
            raise DeviceError(NAME, f"drivers.hazcam.{camera}_calibration: {exc.message}") from None
        if tuple(cal["image_size"]) != size:
            raise DeviceError(NAME, f"{camera} calibration {path} is for {cal['image_size'][0]}x"
                                    f"{cal['image_size'][1]}, drivers.hazcam.size is {size[0]}x{size[1]}")
        K = np.asarray(cal["K1"], np.float64)
        baseline = float(np.linalg.norm(cal["T"]))
        calibration = {k: cal[k] for k in ("K1", "D1", "K2", "D2", "R", "T", "image_size")}
    else:
        K = pinhole(float(config.hfov_deg), size)
        baseline = float(config.baseline)
        calibration = {"K1": K, "D1": np.zeros(5), "K2": K.copy(), "D2": np.zeros(5), "R": np.eye(3),
                       "T": np.array([-baseline, 0.0, 0.0]), "image_size": list(size)}
    look = rot_z(float(getattr(config, f"{camera}_yaw_deg"))) @ rot_y(float(getattr(config, f"{camera}_pitch_deg")))
    T_mount = make_T(look @ R_BODY_FROM_OPTICAL, getattr(config, f"{camera}_xyz"))
    left = T_mount @ make_T(None, (-baseline / 2.0, 0.0, 0.0))
    right = T_mount @ make_T(None, (baseline / 2.0, 0.0, 0.0))
    return PairRig(camera, size, K, baseline, left, right, calibration)
