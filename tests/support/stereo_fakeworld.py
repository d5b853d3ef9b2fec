"""A small analytic world for the stereo tests: a textured wall in front of a two-camera head.

It fills the parts of the drivers.sim World contract the stereo and trigger drivers use
(trigger, sensor_pose, camera_intrinsics, render, move_rover), with a geometry whose true depth
and disparity are known in closed form. Load it with ``load_fakeworld()`` from the test files.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np

from drivers.sim.settings import OpticsSettings, SunSettings
from drivers.sim.trigger import TriggerBus

Bus = TriggerBus  # the real bus: the fake world only replaces the geometry


@dataclass
class Render:
    depth: np.ndarray
    range: np.ndarray
    albedo: np.ndarray
    normal: np.ndarray
    points: np.ndarray
    cos_incidence: np.ndarray
    object_id: np.ndarray
    sunlit: np.ndarray | None = None  # no cast shadows in the fake world


@dataclass
class Head:
    baseline: float = 0.2
    height: float = 1.0


class FakeWorld:
    """A vertical wall at global x = ``wall_x`` facing -x, textured with 1 cm value noise."""

    def __init__(self, wall_x: float = 3.0, baseline: float = 0.2, hfov_deg: float = 60.0, seed: int = 1) -> None:
        self.wall_x = wall_x
        self.head = Head(baseline=baseline)
        self.hfov_deg = hfov_deg
        self.trigger = Bus()
        self._lock = threading.Lock()
        self._pose = (0.0, 0.0, 0.0)
        rng = np.random.default_rng(seed)
        self._cell = 0.01
        self._tex = rng.uniform(0.15, 0.85, size=(600, 600)).astype(np.float32)  # 6 m x 6 m of wall
        self.renders = 0
        self.sun = SunSettings()  # the scene blocks a World carries: default sun, ideal optics
        self.optics = OpticsSettings()

    def rover_pose(self) -> tuple[float, float, float]:
        with self._lock:
            return self._pose

    def set_rover_pose(self, x: float, y: float, heading_deg: float) -> None:
        with self._lock:
            self._pose = (x, y, heading_deg)

    def move_rover(self, dx: float, dy: float, dyaw_deg: float) -> None:
        with self._lock:
            x, y, h = self._pose
            c, s = math.cos(math.radians(h)), math.sin(math.radians(h))
            self._pose = (x + c * dx - s * dy, y + s * dx + c * dy, h + dyaw_deg)

    def sensor_pose(self, sensor: str) -> np.ndarray:
        x, y, h = self.rover_pose()
        c, s = math.cos(math.radians(h)), math.sin(math.radians(h))
        forward, left = np.array([c, s, 0.0]), np.array([-s, c, 0.0])
        offset = {"left": 0.5, "right": -0.5, "tof": 0.0}[sensor] * self.head.baseline
        T = np.eye(4)
        T[:3, 0] = -left  # camera x: right
        T[:3, 1] = [0.0, 0.0, -1.0]  # camera y: down
        T[:3, 2] = forward  # camera z: forward
        T[:3, 3] = np.array([x, y, self.head.height]) + offset * left
        return T

    def camera_intrinsics(self, sensor: str, width: int, height: int) -> np.ndarray:
        f = (width / 2.0) / math.tan(math.radians(self.hfov_deg) / 2.0)
        return np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])

    def render(self, K: np.ndarray, width: int, height: int, T_world_cam: np.ndarray) -> Render:
        self.renders += 1
        u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
        rays_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)
        R, o = T_world_cam[:3, :3], T_world_cam[:3, 3]
        rays = rays_cam @ R.T  # world direction per pixel, z_cam component = 1
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (self.wall_x - o[0]) / rays[..., 0]  # t is the camera z (rays have z_cam = 1)
        pts = o + t[..., None] * rays
        gy = (pts[..., 1] + 3.0) / self._cell
        gz = pts[..., 2] / self._cell
        inside = (t > 0) & (gy >= 0) & (gy < self._tex.shape[1] - 1) & (gz >= 0) & (gz < self._tex.shape[0] - 1)
        depth = np.where(inside, t, np.nan).astype(np.float32)
        iy = np.clip(np.floor(gy), 0, self._tex.shape[1] - 2).astype(np.intp)
        iz = np.clip(np.floor(gz), 0, self._tex.shape[0] - 2).astype(np.intp)
        fy, fz = np.clip(gy - iy, 0, 1), np.clip(gz - iz, 0, 1)
        tex = self._tex
        albedo = (
            tex[iz, iy] * (1 - fy) * (1 - fz)
            + tex[iz, iy + 1] * fy * (1 - fz)
            + tex[iz + 1, iy] * (1 - fy) * fz
            + tex[iz + 1, iy + 1] * fy * fz
        )
        albedo = np.where(inside, albedo, np.nan).astype(np.float32)
        normal = np.zeros((height, width, 3), np.float32)
        normal[..., 0] = -1.0
        rng = np.linalg.norm(rays, axis=-1) * t
        return Render(
            depth=depth,
            range=np.where(inside, rng, np.nan).astype(np.float32),
            albedo=albedo,
            normal=normal,
            points=pts.astype(np.float32),
            cos_incidence=np.ones((height, width), np.float32),
            object_id=np.zeros((height, width), np.int16),
        )
