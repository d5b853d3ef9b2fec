"""Stereo odometry's truth: two simulated stereo pairs with a known rover motion between them, and
the error of an estimated motion against it."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import yaml

import drivers.stereo as stereo_drv
from drivers.sim.world import World
from rvs_server.config import DEFAULT_CONFIG_DIR

CONFIG = DEFAULT_CONFIG_DIR / "drivers.yaml"


def sim_sequence(scene: str = "quarry", move: tuple[float, float, float] = (0.3, 0.0, 2.0),
                 tilt: float = -20.0, resolution: str = "low", seed: int = 3) -> dict[str, Any]:
    """Two simulated stereo pairs with the rover moved by ``move`` (dx forward, dy left m,
    dyaw deg) in between; the true pose of camera B in camera A, and the calibration."""
    world = World.from_scene(scene)
    world.set_target_visible(False)
    world.set_rover_pose(0.0, 0.0, 0.0)
    world.set_ptu(0.0, tilt)
    cfg = yaml.safe_load(CONFIG.read_text())["stereo"]
    cam = stereo_drv.create({**cfg, "resolution": resolution, "seed": seed}, world, None)
    cam.open()
    try:
        cal = cam.calibration()
        calib = {k: cal[k] for k in ("image_size", "K1", "D1", "K2", "D2", "R", "T")}
        T_wa = world.sensor_pose("left")
        la, ra = cam.grab_stereo_direct()
        world.move_rover(*move)
        T_wb = world.sensor_pose("left")
        lb, rb = cam.grab_stereo_direct()
    finally:
        cam.close()
    return {"left_a": la, "right_a": ra, "left_b": lb, "right_b": rb, "calib": calib,
            "truth": np.linalg.inv(T_wa) @ T_wb}


def motion_error(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """(translation error m, rotation error deg) between two poses."""
    D = np.linalg.inv(T_true) @ T_est
    ang = math.degrees(math.acos(float(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1.0, 1.0))))
    return float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3])), ang
