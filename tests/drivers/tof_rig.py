"""A bench for ToF tests: an analytic world of planes with the drivers.sim World's interface.

Analytic geometry makes the expected range of every pixel exact, so the tests can hold the
simulator to its own noise model. Planes may be bounded (rectangles) to build walls, boxes
and far targets.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import numpy as np

import drivers.tof as tof
from drivers.sim.clock import SimClock
from drivers.tof.simulated import nominal_camera_matrix


@dataclass
class Plane:
    point: tuple[float, float, float]
    normal: tuple[float, float, float]
    albedo: float = 0.5
    # Optional rectangle: two in-plane axes with half sizes (None = infinite plane).
    u: tuple[float, float, float] | None = None
    v: tuple[float, float, float] | None = None
    half_u: float = math.inf
    half_v: float = math.inf


def look_at(eye: Any, target: Any, up: Any = (0.0, 0.0, 1.0)) -> np.ndarray:
    """T_world_cam for an OpenCV camera (x right, y down, z forward) at eye looking at target."""
    eye, target, up = (np.asarray(a, dtype=np.float64) for a in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:  # looking along up: pick any right vector
        x = np.cross(z, (1.0, 0.0, 0.0)) if abs(z[0]) < 0.9 else np.cross(z, (0.0, 1.0, 0.0))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, eye
    return T


class PlaneWorld:
    """Planes seen by a camera at a fixed pose (``sensor_pose`` ignores the sensor name)."""

    def __init__(self, planes: list[Plane], T_world_cam: np.ndarray) -> None:
        self.clock = SimClock(0.0)  # frames take no wall time here
        self.rolling = False  # the rover stands: each frame takes its time on the clock
        self.planes = planes
        self.T = np.asarray(T_world_cam, dtype=np.float64)
        self.renders = 0

    def sensor_pose(self, sensor: str) -> np.ndarray:
        return self.T.copy()

    def camera_intrinsics(self, sensor: str, width: int, height: int) -> np.ndarray:
        return nominal_camera_matrix(width, height)

    def render(self, K: np.ndarray, width: int, height: int, T_world_cam: np.ndarray) -> SimpleNamespace:
        self.renders += 1
        u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
        d_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)
        d_cam /= np.linalg.norm(d_cam, axis=-1, keepdims=True)
        R, o = T_world_cam[:3, :3], T_world_cam[:3, 3]
        d = d_cam @ R.T
        best = np.full(u.shape, np.inf)
        normal = np.full((*u.shape, 3), np.nan)
        albedo = np.full(u.shape, np.nan)
        oid = np.full(u.shape, -1, dtype=np.int16)
        for i, p in enumerate(self.planes):
            n = np.asarray(p.normal, dtype=np.float64)
            n = n / np.linalg.norm(n)
            p0 = np.asarray(p.point, dtype=np.float64)
            denom = d @ n
            with np.errstate(divide="ignore", invalid="ignore"):
                t = ((p0 - o) @ n) / denom
            hit = np.isfinite(t) & (t > 1e-6)
            if p.u is not None:
                q = o + t[..., None] * d - p0
                hit &= np.abs(q @ np.asarray(p.u)) <= p.half_u
                hit &= np.abs(q @ np.asarray(p.v)) <= p.half_v
            closer = hit & (t < best)
            best = np.where(closer, t, best)
            facing = np.where((denom < 0)[..., None], n, -n)
            normal = np.where(closer[..., None], facing, normal)
            albedo = np.where(closer, p.albedo, albedo)
            oid = np.where(closer, i, oid).astype(np.int16)
        hit = np.isfinite(best)
        rng = np.where(hit, best, np.nan)
        points = o + rng[..., None] * d
        cos_inc = np.where(hit, -np.einsum("hwk,hwk->hw", normal, d), np.nan)
        return SimpleNamespace(
            depth=(rng * d_cam[..., 2]).astype(np.float32),
            range=rng.astype(np.float32),
            albedo=albedo.astype(np.float32),
            normal=normal.astype(np.float32),
            points=points.astype(np.float32),
            cos_incidence=cos_inc.astype(np.float32),
            object_id=oid,
        )


def floor_world(height: float = 1.5, albedo: float = 0.5) -> PlaneWorld:
    """A camera ``height`` metres above an endless floor, looking straight down."""
    return PlaneWorld([Plane((0, 0, 0), (0, 0, 1), albedo)], look_at((0, 0, height), (0, 0, 0), up=(1, 0, 0)))


def wall_world(distance: float, albedo: float = 0.5) -> PlaneWorld:
    """A camera looking straight at an endless wall ``distance`` metres away."""
    return PlaneWorld([Plane((distance, 0, 0), (-1, 0, 0), albedo)], look_at((0, 0, 1), (distance, 0, 1)))


def config(**overrides: Any) -> dict[str, Any]:
    """A sim config close to config/drivers.yaml, with the filters that hide noise switched off."""
    cfg: dict[str, Any] = {
        "backend": "sim",
        "serial": 0,
        "seed": 1,
        "modulation_mhz": 30.0,
        "integration": 30,
        "amplitude_threshold": 0,
        "corrections": ["fix_pattern", "conf_map"],
        "sim_multipath_gain": 0.0,
    }
    cfg.update(overrides)
    return cfg


def open_camera(world: Any, **overrides: Any) -> tof.Tof:
    cam = tof.create(config(**overrides), world)
    cam.open()
    return cam
