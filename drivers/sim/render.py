"""Render a pinhole view of the world: depth, range, albedo, normals, points, object ids.

Rays of all pixels are cast at once: first against the analytic objects (each only over the
image rectangle its bounding box projects to), then against the terrain, which stops early
at the nearest object already hit. Large images are split into row bands cast in parallel
threads (numpy releases the GIL inside its array operations).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

from drivers.sim.heightfield import Heightfield
from drivers.sim.objects import SceneObject
from drivers.sim.raycast import cast_heightfield

_POOL: ThreadPoolExecutor | None = None
_THREADS = max(1, min(4, os.cpu_count() or 1))


def _pool() -> ThreadPoolExecutor:
    global _POOL
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=_THREADS, thread_name_prefix="sim-render")
    return _POOL


@dataclass
class Render:
    """One rendered view; H x W arrays, NaN depth/range/points where nothing was hit."""

    depth: np.ndarray  # float32, z along the optical axis
    range: np.ndarray  # float32, euclidean distance from the optical centre
    albedo: np.ndarray  # float32 0..1
    normal: np.ndarray  # H x W x 3 float32, world frame, facing the camera
    points: np.ndarray  # H x W x 3 float32, world frame
    cos_incidence: np.ndarray  # float32, cosine between the normal and the ray back to the camera
    object_id: np.ndarray  # int16, 0 terrain, -1 nothing, else SceneObject.oid


@dataclass
class Detail:
    """Fine albedo texture: a periodic tile sampled at two incommensurate world scales."""

    tile: np.ndarray
    texel: float = 0.002
    amp_fine: float = 0.35
    amp_mid: float = 0.25

    def modulate(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        n = self.tile.shape[0]
        a = self._sample(u / self.texel, v / self.texel, n)
        b = self._sample(v / (self.texel * 7.31) + 17.3, -u / (self.texel * 7.31) + 5.1, n)
        return (1.0 + self.amp_fine * (a - 0.5) * 2) * (1.0 + self.amp_mid * (b - 0.5) * 2)

    def _sample(self, fu: np.ndarray, fv: np.ndarray, n: int) -> np.ndarray:
        # cv2.remap wants 2-D maps under 32767 per side: fold the list into rows of 1024.
        m = fu.size
        rows = -(-m // 1024)
        mu = np.zeros(rows * 1024, np.float32)
        mv = np.zeros(rows * 1024, np.float32)
        mu[:m] = np.mod(fu, n)
        mv[:m] = np.mod(fv, n)
        out = cv2.remap(self.tile, mu.reshape(rows, 1024), mv.reshape(rows, 1024), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_WRAP)
        return out.ravel()[:m]


def camera_rays(K: np.ndarray, width: int, height: int, T_world_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ray origin (3,) and world directions (H*W, 3) scaled so that t equals depth."""
    Kinv = np.linalg.inv(K)
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    pix = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], axis=1)
    dc = pix @ Kinv.T
    dc /= dc[:, 2:3]
    d = dc @ T_world_cam[:3, :3].T
    return T_world_cam[:3, 3].copy(), d


def _screen_rect(obj: SceneObject, K: np.ndarray, T_world_cam: np.ndarray, width: int, height: int):
    """Pixel rows/cols the object's bounding box can cover, or None if it is out of view.

    The box is clipped at a near plane first, so an object around or behind the camera (the
    rover under its own mast) still gets a tight, conservative rectangle.
    """
    lo, hi = obj.local_bounds()
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    T = np.linalg.inv(T_world_cam) @ obj.pose
    pc = corners @ T[:3, :3].T + T[:3, 3]
    near = 1e-3
    pts = [pc[pc[:, 2] > near]]
    for i in range(8):
        for bit in (1, 2, 4):
            j = i | bit
            if j == i:
                continue
            zi, zj = pc[i, 2], pc[j, 2]
            if (zi - near) * (zj - near) < 0:
                f = (near - zi) / (zj - zi)
                pts.append((pc[i] + f * (pc[j] - pc[i]))[None, :])
    pts = np.concatenate(pts)
    if pts.shape[0] == 0:
        return None
    z = np.maximum(pts[:, 2:3], near)
    uv = pts[:, :2] / z @ K[:2, :2].T + K[:2, 2]
    c0 = max(int(np.floor(uv[:, 0].min())) - 1, 0)
    c1 = min(int(np.ceil(uv[:, 0].max())) + 2, width)
    r0 = max(int(np.floor(uv[:, 1].min())) - 1, 0)
    r1 = min(int(np.ceil(uv[:, 1].max())) + 2, height)
    if c0 >= c1 or r0 >= r1:
        return None
    return r0, r1, c0, c1


def render(hf: Heightfield, objects: list[SceneObject], detail: Detail, K: np.ndarray, width: int, height: int,
           T_world_cam: np.ndarray) -> Render:
    K = np.asarray(K, np.float64)
    T_world_cam = np.asarray(T_world_cam, np.float64)
    o, d = camera_rays(K, width, height, T_world_cam)
    n = d.shape[0]
    t_best = np.full(n, np.inf)
    oid = np.full(n, -1, np.int16)
    normal = np.zeros((n, 3))
    albedo = np.zeros(n, np.float32)
    tex_amp = np.zeros(n, np.float32)

    grid = np.arange(n).reshape(height, width)
    for obj in objects:
        if not obj.visible:
            continue
        rect = _screen_rect(obj, K, T_world_cam, width, height)
        if rect is None:
            continue
        r0, r1, c0, c1 = rect
        sel = grid[r0:r1, c0:c1].ravel()
        t, nw, alb = obj.intersect(o, d[sel])
        better = t < t_best[sel]
        s = sel[better]
        t_best[s] = t[better]
        normal[s] = nw[better]
        albedo[s] = alb[better]
        oid[s] = obj.oid
        tex_amp[s] = obj.texture

    # Terrain, in parallel row bands.
    ob = np.broadcast_to(o, (n, 3))
    bands = np.array_split(np.arange(n), _THREADS * 2 if n > 20000 else 1)
    futures = [_pool().submit(cast_heightfield, hf, ob[b], d[b], t_best[b]) for b in bands]
    t_ter = np.concatenate([f.result() for f in futures])
    ter = t_ter < t_best
    t_best[ter] = t_ter[ter]
    oid[ter] = 0

    hit = np.isfinite(t_best)
    pts = np.full((n, 3), np.nan)
    pts[hit] = o + t_best[hit, None] * d[hit]
    ti = np.nonzero(ter)[0]
    if ti.size:
        gx, gy = hf.gradient(pts[ti, 0], pts[ti, 1])
        normal[ti, 0], normal[ti, 1], normal[ti, 2] = -gx, -gy, 1.0
        albedo[ti] = hf.sample_albedo(pts[ti, 0], pts[ti, 1])
        tex_amp[ti] = 1.0
    nn = np.linalg.norm(normal, axis=1)
    normal[hit] /= nn[hit, None]
    dn = np.linalg.norm(d, axis=1)
    cosi = -(normal * d).sum(1) / dn
    flip = hit & (cosi < 0)
    normal[flip] *= -1
    cosi = np.abs(cosi)

    # Fine albedo detail, projected along the dominant normal axis (triplanar style) so walls
    # and rock flanks carry texture as well as the ground.
    hi = np.nonzero(hit & (tex_amp > 0))[0]
    if hi.size:
        p = pts[hi]
        ax = np.abs(normal[hi]).argmax(axis=1)
        u = np.where(ax == 0, p[:, 1], p[:, 0])
        v = np.where(ax == 2, p[:, 1], p[:, 2])
        mod = detail.modulate(u, v)
        albedo[hi] = albedo[hi] * (1.0 + tex_amp[hi] * (mod - 1.0))
    albedo = np.clip(albedo, 0.0, 1.0)

    depth = np.where(hit, t_best, np.nan)
    shape = (height, width)
    return Render(
        depth=depth.reshape(shape).astype(np.float32),
        range=(depth * dn).reshape(shape).astype(np.float32),
        albedo=np.where(hit, albedo, 0.0).reshape(shape).astype(np.float32),
        normal=normal.reshape(height, width, 3).astype(np.float32),
        points=pts.reshape(height, width, 3).astype(np.float32),
        cos_incidence=np.where(hit, cosi, 0.0).reshape(shape).astype(np.float32),
        object_id=oid.reshape(shape),
    )
