"""Simulated sensor head for the stereo and calibration tests: the shared World with the stereo
pair and the ToF camera on it, checkerboard poses in front of the cameras, and ground truth
(true disparity, true depth, true calibrations) to hold the steps to.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

import drivers.stereo as stereo_drv
import drivers.tof as tof_drv
from drivers.sim.transforms import make_T, rot_x, rot_y, rot_z
from drivers.sim.world import World

ROOT = Path(__file__).resolve().parents[2]


def driver_config(section: str, **extra: Any) -> dict[str, Any]:
    cfg = yaml.safe_load((ROOT / "config" / "drivers.yaml").read_text())[section]
    cfg.update(extra)
    return cfg


def make_world(scene: str = "office", pan: float = 0.0, tilt: float = 0.0, seed: int | None = None) -> World:
    world = World.from_scene(scene, seed=seed)
    world.set_ptu(pan, tilt)
    return world


def stereo_pair(world: World, resolution: str = "low", **extra: Any) -> Any:
    cam = stereo_drv.create(driver_config("stereo", resolution=resolution, seed=3, **extra), world, None)
    cam.open()
    return cam


def tof_camera(world: World, **extra: Any) -> Any:
    cam = tof_drv.create(driver_config("tof", seed=5, settings_file=None, **extra), world)
    cam.open()
    return cam


def true_stereo_calibration(cam: Any) -> dict[str, Any]:
    """What ``rvs-calib sim-truth`` writes: the pair's true K, D and mount geometry."""
    cal = cam.calibration()
    return {k: cal[k] for k in ("image_size", "K1", "D1", "K2", "D2", "R", "T")}


def T_left_tof(world: World) -> np.ndarray:
    """True ToF -> left camera transform (X_left = R X_tof + t)."""
    return np.linalg.inv(world.head.mounts["left"]) @ world.head.mounts["tof"]


def board_pose(world: World, centre_cam: tuple[float, float, float], rpy_deg: tuple[float, float, float],
               rows: int, cols: int, square: float, sensor: str = "left") -> np.ndarray:
    """T_world_board for a board whose centre sits at ``centre_cam`` in the sensor's optical frame,
    facing the camera, tilted by roll (about the view axis), pitch (about x) and yaw (about y)."""
    roll, pitch, yaw = rpy_deg
    R = rot_z(roll) @ rot_x(pitch) @ rot_y(yaw)
    centre_board = np.array([cols * square / 2.0, rows * square / 2.0, 0.0])
    t = np.asarray(centre_cam, float) - R @ centre_board
    return world.sensor_pose(sensor) @ make_T(R, t)


def place(world: World, centre_cam: tuple[float, float, float], rpy_deg: tuple[float, float, float],
          rows: int, cols: int, square: float, sensor: str = "left") -> None:
    world.place_checkerboard(board_pose(world, centre_cam, rpy_deg, rows, cols, square, sensor), rows, cols, square)


def rectified_truth(world: World, rect: Any) -> tuple[np.ndarray, np.ndarray, Any]:
    """(true disparity, true depth, render) in the rectified left geometry: the world rendered by
    the rectified left camera (K = P1, orientation R1 applied to the left camera)."""
    w, h = rect.size
    T = world.sensor_pose("left") @ make_T(np.asarray(rect.R1).T, None)
    r = world.render(np.asarray(rect.P1)[:, :3], w, h, T)
    with np.errstate(divide="ignore", invalid="ignore"):
        disp = (rect.focal * rect.baseline / r.depth).astype(np.float32)
    return disp, r.depth, r
