"""Render a pinhole view of the world: depth, range, albedo, normals, points, object ids.

Rays of all pixels are cast at once: first against the analytic objects (each only over the
image rectangle its bounding box projects to), then against the terrain, which stops early
at the nearest object already hit. Large images are split into vertical strips rendered in
parallel threads (numpy releases the GIL inside its array operations). A render given a
``cancel`` check (a camera's grab that a break may stop) is cut into strips of about
:data:`CANCEL_STRIP_PIXELS` and looks at it before each: a render nobody waits for any more stops
within one strip's time instead of running to the end.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from drivers.sim.heightfield import Heightfield
from drivers.sim.objects import Rect, SceneObject
from drivers.sim.raycast import cast_heightfield
from drivers.sim.transforms import rotate

_POOL: ThreadPoolExecutor | None = None
# RVS_SIM_THREADS overrides the number of threads a large render is split across.
_THREADS = max(1, int(os.environ.get("RVS_SIM_THREADS", 0)) or min(4, os.cpu_count() or 1))
# Pixels per strip of a cancellable render: a strip takes tens of milliseconds, the most a
# cancelled render goes on for, at a few percent more work than the fewest strips.
CANCEL_STRIP_PIXELS = 120_000


class RenderCancelled(Exception):
    """A render stopped by its ``cancel`` check before it was done."""


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
    # float32 0..1, share of sunlight reaching the point (terrain cast shadows); None when the
    # scene casts none. Only passive cameras use it: the ToF lights the scene itself.
    sunlit: np.ndarray | None = None


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
    """Ray origin (3,) and world directions (H*W, 3, float64) scaled so that t equals depth."""
    Kinv = np.linalg.inv(K)
    M = T_world_cam[:3, :3] @ Kinv  # pixel (u, v, 1) -> world direction with camera z = 1
    u = np.arange(width, dtype=np.float64)
    v = np.arange(height, dtype=np.float64)
    d = np.empty((height, width, 3))
    for k in range(3):
        d[:, :, k] = M[k, 0] * u[None, :] + (M[k, 1] * v[:, None] + M[k, 2])
    return T_world_cam[:3, 3].copy(), d.reshape(-1, 3)


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


def _filtered_plane_albedo(obj: SceneObject, K: np.ndarray, T_world_cam: np.ndarray, o: np.ndarray,
                           rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Albedo of a flat object box-filtered over each pixel's footprint on it.

    The ray through (u, v) is M (u, v, 1), linear in u and v, so the footprint corners come
    from intersecting the plane with the rays half a pixel either way.
    """
    M = T_world_cam[:3, :3] @ np.linalg.inv(K)
    Ti = np.linalg.inv(obj.pose)
    Ml = Ti[:3, :3] @ M
    ol = Ti[:3, :3] @ o + Ti[:3, 3]
    pix = np.stack([cols.astype(np.float64), rows.astype(np.float64), np.ones(rows.size)])

    def hit(du: float, dv: float) -> np.ndarray:
        dl = rotate((pix + np.array([[du], [dv], [0.0]])).T, Ml).T
        t = -ol[2] / dl[2]
        return (ol[:, None] + t * dl)[:2]

    pu = hit(0.5, 0.0) - hit(-0.5, 0.0)
    pv = hit(0.0, 0.5) - hit(0.0, -0.5)
    centre = hit(0.0, 0.0)
    wx = np.abs(pu[0]) + np.abs(pv[0])
    wy = np.abs(pu[1]) + np.abs(pv[1])
    return obj.albedo.filtered(centre.T, wx, wy)


def render(hf: Heightfield, objects: list[SceneObject], detail: Detail, K: np.ndarray, width: int, height: int,
           T_world_cam: np.ndarray, cancel: Callable[[], bool] | None = None) -> Render:
    """Render a view; large images are cut into vertical strips rendered in parallel threads
    (strips, not row bands, so each holds a share of the costly rays near the horizon).

    With ``cancel``, strips are smaller and each starts only if ``cancel()`` is false; the call
    raises :class:`RenderCancelled` as soon as it turns true (strips already running end on
    their own, their result unused)."""
    K = np.asarray(K, np.float64)
    T_world_cam = np.asarray(T_world_cam, np.float64)
    parts = _THREADS if width * height > 300_000 else 1
    if cancel is not None:
        parts = min(width, max(parts, -(-width * height // CANCEL_STRIP_PIXELS)))
        if cancel():
            raise RenderCancelled("render cancelled")
    if parts == 1:
        return _render(hf, objects, detail, K, width, height, T_world_cam)
    cuts = np.linspace(0, width, parts + 1).astype(int)

    def strip(Kp: np.ndarray, w: int) -> Render | None:
        if cancel is not None and cancel():
            return None
        return _render(hf, objects, detail, Kp, w, height, T_world_cam)

    futures = []
    for c0, c1 in zip(cuts[:-1], cuts[1:], strict=True):
        Kp = K.copy()
        Kp[0, 2] -= c0  # the strip's own principal point: same rays as in the full image
        futures.append(_pool().submit(strip, Kp, int(c1 - c0)))
    strips = [_wait(f, futures, cancel) for f in futures]
    out: dict[str, Any] = {}
    for name in Render.__dataclass_fields__:
        # joining a 2-megapixel view's ~100 MB of layers takes a good share of a second on a busy
        # machine: a cancel is looked at between layers, as between strips
        if cancel is not None and cancel():
            raise RenderCancelled("render cancelled")
        out[name] = (None if getattr(strips[0], name) is None
                     else np.concatenate([getattr(r, name) for r in strips], axis=1))
    return Render(**out)


def _wait(future: Future[Render | None], futures: list[Future[Render | None]],
          cancel: Callable[[], bool] | None) -> Render:
    """A strip's result; with ``cancel``, looked at every 20 ms while waiting, and once true the
    strips not started are dropped and RenderCancelled raised."""
    while True:
        try:
            result = future.result(timeout=None if cancel is None else 0.02)
        except FutureTimeout:
            if cancel is None or not cancel():
                continue
            result = None
        if result is not None:
            return result
        for f in futures:  # cancelled: while waiting, or the strip saw it and was skipped
            f.cancel()
        raise RenderCancelled("render cancelled")


def _render(hf: Heightfield, objects: list[SceneObject], detail: Detail, K: np.ndarray, width: int, height: int,
            T_world_cam: np.ndarray) -> Render:
    K = np.asarray(K, np.float64)
    T_world_cam = np.asarray(T_world_cam, np.float64)
    H, W = height, width
    o, d = camera_rays(K, W, H, T_world_cam)
    n = d.shape[0]
    t_best = np.full(n, np.inf)
    oid = np.full(n, -1, np.int16)
    tb2, oid2, d3 = t_best.reshape(H, W), oid.reshape(H, W), d.reshape(H, W, 3)
    obj_normal: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, float]] = {}

    # Objects first, each over the image rectangle its bounding box covers.
    for obj in objects:
        if not obj.visible:
            continue
        rect = _screen_rect(obj, K, T_world_cam, W, H)
        if rect is None:
            continue
        r0, r1, c0, c1 = rect
        t, nw, alb = obj.intersect(o, d3[r0:r1, c0:c1].reshape(-1, 3))
        t = t.reshape(r1 - r0, c1 - c0)
        better = t < tb2[r0:r1, c0:c1]
        if not better.any():
            continue
        tb2[r0:r1, c0:c1][better] = t[better]
        oid2[r0:r1, c0:c1][better] = obj.oid
        rows, cols = np.nonzero(better)
        flat_idx = (rows + r0) * W + cols + c0
        alb = alb[better.ravel()]
        if hasattr(obj.albedo, "filtered") and len(obj.shapes) == 1 and isinstance(obj.shapes[0], Rect):
            alb = _filtered_plane_albedo(obj, K, T_world_cam, o, rows + r0, cols + c0)
        obj_normal[obj.oid] = (flat_idx, nw[better.ravel()], alb, obj.texture)

    # Terrain, stopped at the nearest object already hit.
    t_ter = cast_heightfield(hf, o, d, t_best)
    ter = t_ter < t_best
    t_best[ter] = t_ter[ter]
    oid[ter] = 0

    # Shading, on hit pixels only, one array per component (no N x 3 temporaries).
    hi = np.flatnonzero(np.isfinite(t_best))
    th = t_best[hi]
    M = T_world_cam[:3, :3] @ np.linalg.inv(K)
    uu = (hi % W).astype(np.float64)
    vv = (hi // W).astype(np.float64)
    dx, dy, dz = (M[k, 0] * uu + M[k, 1] * vv + M[k, 2] for k in range(3))
    px, py, pz = o[0] + th * dx, o[1] + th * dy, o[2] + th * dz
    m = hi.size
    nx = np.zeros(m, np.float32)
    ny = np.zeros(m, np.float32)
    nz = np.zeros(m, np.float32)
    albedo = np.zeros(m, np.float32)
    tex = np.zeros(m, np.float32)
    pos = np.full(n, -1, np.int64)
    pos[hi] = np.arange(m)
    for obj_id, (flat_idx, nw, alb, amp) in obj_normal.items():
        # Keep only the pixels this object still owns (terrain or a later object may be nearer).
        own = oid[flat_idx] == obj_id
        k = pos[flat_idx[own]]
        nwo = nw[own]
        nx[k], ny[k], nz[k] = nwo[:, 0], nwo[:, 1], nwo[:, 2]
        albedo[k] = alb[own]
        tex[k] = amp
    ti = np.flatnonzero(oid[hi] == 0)
    sunlit = None if hf.sunlit is None else np.ones(m, np.float32)
    if ti.size:
        gx, gy, alb = hf.shade(px[ti], py[ti])
        nx[ti], ny[ti], nz[ti] = -gx, -gy, 1.0
        albedo[ti] = alb
        tex[ti] = 1.0
        if sunlit is not None:
            sunlit[ti] = hf.sample_sunlit(px[ti], py[ti])
    inv_len = 1.0 / np.sqrt(nx * nx + ny * ny + nz * nz)
    dn = np.sqrt(dx * dx + dy * dy + dz * dz)
    cosi = (-(nx * dx + ny * dy + nz * dz) / dn).astype(np.float32) * inv_len
    # Normals face the camera (walls and boards are seen from both sides).
    sgn = np.where(cosi < 0, -inv_len, inv_len)
    nx *= sgn
    ny *= sgn
    nz *= sgn
    np.abs(cosi, out=cosi)

    # Fine albedo detail, projected along the dominant normal axis (triplanar style) so walls
    # and rock flanks carry texture as well as the ground.
    tx = np.flatnonzero(tex > 0)
    if tx.size:
        ax, ay, az = np.abs(nx[tx]), np.abs(ny[tx]), np.abs(nz[tx])
        xdom = (ax >= ay) & (ax >= az)
        zdom = ~xdom & (az >= ay)
        u = np.where(xdom, py[tx], px[tx])
        v = np.where(zdom, py[tx], pz[tx])
        albedo[tx] *= 1.0 + tex[tx] * (detail.modulate(u, v) - 1.0)
    np.clip(albedo, 0.0, 1.0, out=albedo)

    def img(vals: np.ndarray, fill: float) -> np.ndarray:
        out = np.full(n, fill, np.float32)
        out[hi] = vals
        return out.reshape(H, W)

    def img3(a: np.ndarray, b: np.ndarray, c: np.ndarray, fill: float) -> np.ndarray:
        out = np.full((n, 3), fill, np.float32)
        for k, vals in enumerate((a, b, c)):
            out[hi, k] = vals
        return out.reshape(H, W, 3)

    return Render(
        depth=img(th, np.nan),
        range=img(th * dn, np.nan),
        albedo=img(albedo, 0.0),
        normal=img3(nx, ny, nz, 0.0),
        points=img3(px, py, pz, np.nan),
        cos_incidence=img(cosi, 0.0),
        object_id=oid.reshape(H, W),
        sunlit=None if sunlit is None else img(sunlit, 1.0),
    )
