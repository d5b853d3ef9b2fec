"""Things in the world that are not terrain: walls, the target, the checkerboard, the rover.

Each object is a few analytic shapes (box, vertical cylinder, sphere, flat rectangle) posed in
the object's frame, itself posed in the world, so a moving object only changes one 4x4. Ray
tests are closed-form and vectorised; albedo is a function of the hit point in the object's
frame (markers and checkerboard squares live there).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from drivers.sim.transforms import invert, rotate, transform

AlbedoFn = Callable[[np.ndarray, np.ndarray], np.ndarray]  # (points_obj N x 3, normals_obj N x 3) -> N


def _safe_inv(d: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return np.where(np.abs(d) > 1e-15, 1.0 / np.where(d == 0, 1.0, d), 1e30)


def slab(o: np.ndarray, inv: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ray/axis-aligned-box slabs, one axis at a time (cheaper than N x 3 temporaries).

    ``o`` is (3,) or (N, 3); returns t_near, t_far and the axis that set t_near.
    """
    tn = None
    for k in range(3):
        a = (lo[k] - o[..., k]) * inv[:, k]
        b = (hi[k] - o[..., k]) * inv[:, k]
        near = np.minimum(a, b)
        far = np.maximum(a, b)
        if tn is None:
            tn, tf, axis = near, far, np.zeros(near.shape, np.int8)
        else:
            upd = near > tn
            tn = np.where(upd, near, tn)
            axis = np.where(upd, np.int8(k), axis)
            tf = np.minimum(tf, far)
    return tn, tf, axis


@dataclass
class Box:
    """Axis-aligned box ``lo..hi`` in its own frame."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]

    def intersect(self, o: np.ndarray, d: np.ndarray, inv: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        inv = _safe_inv(d) if inv is None else inv
        t_near, t_far, axis = slab(o, inv, self.lo, self.hi)
        ok = (t_near <= t_far) & (t_near > 0)
        t = np.where(ok, t_near, np.inf)
        n = np.zeros(d.shape)
        for k in range(3):
            n[:, k] = np.where(axis == k, -np.sign(d[:, k]), 0.0)
        return t, n

    def corners(self) -> np.ndarray:
        lo, hi = self.lo, self.hi
        return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


@dataclass
class Cylinder:
    """Cylinder about its frame's z axis, radius r, from z0 to z1, with flat caps."""

    r: float
    z0: float
    z1: float

    def intersect(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        a = d[:, 0] ** 2 + d[:, 1] ** 2
        b = 2 * (o[..., 0] * d[:, 0] + o[..., 1] * d[:, 1])
        c = o[..., 0] ** 2 + o[..., 1] ** 2 - self.r**2
        disc = b * b - 4 * a * c
        with np.errstate(divide="ignore", invalid="ignore"):
            ts = (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a)
        zs = o[..., 2] + ts * d[:, 2]
        side = (disc >= 0) & (a > 1e-18) & (ts > 0) & (zs >= self.z0) & (zs <= self.z1)
        t_side = np.where(side, ts, np.inf)
        with np.errstate(divide="ignore", invalid="ignore"):
            tc0 = (self.z0 - o[..., 2]) / d[:, 2]
            tc1 = (self.z1 - o[..., 2]) / d[:, 2]
        best = t_side
        n = np.zeros(d.shape)
        p = o + ts[:, None] * d
        n[:, 0], n[:, 1] = p[:, 0] / self.r, p[:, 1] / self.r
        for tc, nz in ((tc0, -1.0), (tc1, 1.0)):
            pc = o + np.nan_to_num(tc, nan=0.0, posinf=0.0, neginf=0.0)[:, None] * d
            okc = np.isfinite(tc) & (tc > 0) & (pc[:, 0] ** 2 + pc[:, 1] ** 2 <= self.r**2) & (tc < best)
            best = np.where(okc, tc, best)
            n[okc] = (0.0, 0.0, nz)
        return best, n

    def corners(self) -> np.ndarray:
        r = self.r
        return np.array([[x, y, z] for x in (-r, r) for y in (-r, r) for z in (self.z0, self.z1)])


@dataclass
class Sphere:
    centre: tuple[float, float, float]
    r: float

    def intersect(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        oc = o - np.asarray(self.centre)
        a = (d * d).sum(1)
        b = 2 * (oc * d).sum(-1)
        c = (oc * oc).sum(-1) - self.r**2
        disc = b * b - 4 * a * c
        t = (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a)
        ok = (disc >= 0) & (t > 0)
        t = np.where(ok, t, np.inf)
        p = oc + np.where(ok, t, 0)[:, None] * d
        return t, p / self.r

    def corners(self) -> np.ndarray:
        c, r = np.asarray(self.centre), self.r
        return np.array([c + [x, y, z] for x in (-r, r) for y in (-r, r) for z in (-r, r)])


@dataclass
class Rect:
    """Flat two-sided rectangle in its frame's z = 0 plane, x in x0..x1, y in y0..y1."""

    x0: float
    x1: float
    y0: float
    y1: float

    def intersect(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -o[..., 2] / d[:, 2]
        tt = np.nan_to_num(t, nan=0.0, posinf=0.0, neginf=0.0)
        px = o[..., 0] + tt * d[:, 0]
        py = o[..., 1] + tt * d[:, 1]
        ok = np.isfinite(t) & (t > 0) & (px >= self.x0) & (px <= self.x1) & (py >= self.y0) & (py <= self.y1)
        n = np.zeros(d.shape)
        n[:, 2] = 1.0
        return np.where(ok, t, np.inf), n

    def corners(self) -> np.ndarray:
        return np.array([[x, y, 0.0] for x in (self.x0, self.x1) for y in (self.y0, self.y1)])


def constant_albedo(value: float) -> AlbedoFn:
    def fn(p: np.ndarray, n: np.ndarray) -> np.ndarray:
        return np.full(p.shape[0], value, np.float32)

    return fn


@dataclass
class SceneObject:
    """One named thing with an id (0 is terrain; the rover is 1), shapes and a world pose.

    ``in_dem``: whether it stands on the ground and belongs in the true DEM (walls, boxes) or
    not (rover, moving target, a checkerboard held in the air).
    """

    name: str
    oid: int
    shapes: list[Shape]
    albedo: AlbedoFn
    pose: np.ndarray = field(default_factory=lambda: np.eye(4))
    in_dem: bool = True
    texture: float = 0.15  # amplitude of the fine procedural albedo detail added on render
    visible: bool = True

    def intersect(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Nearest t over shapes, world normal, and albedo at the hit (inf / 0 where none).

        ``o`` is one origin (3,) shared by all rays, or one per ray (N, 3). Rays are first
        tested against the object's bounding box; only those that hit it see the shapes.
        """
        Ti = invert(self.pose)
        R, tr = Ti[:3, :3], Ti[:3, 3]
        ol = rotate(o, R) + tr
        dl = rotate(d, R)
        m = d.shape[0]
        best = np.full(m, np.inf)
        nw = np.zeros((m, 3))
        alb = np.zeros(m, np.float32)
        inv = _safe_inv(dl)
        if len(self.shapes) == 1 and isinstance(self.shapes[0], Box):
            # A lone box is its own bounding box: one slab test does it all.
            best, nl = self.shapes[0].intersect(ol, dl, inv)
            hit = np.nonzero(np.isfinite(best))[0]
            if hit.size:
                oh = ol if ol.ndim == 1 else ol[hit]
                alb[hit] = self.albedo(oh + best[hit, None] * dl[hit], nl[hit])
                nw[hit] = rotate(nl[hit], self.pose[:3, :3])
            return best, nw, alb
        lo, hi = self.local_bounds()
        tn, tf, _ = slab(ol, inv, lo, hi)
        cand = np.nonzero((tn <= tf) & (tf > 0))[0]
        if cand.size == 0:
            return best, nw, alb
        oc = ol if ol.ndim == 1 else ol[cand]
        dc = dl[cand]
        bc = np.full(cand.size, np.inf)
        nl = np.zeros((cand.size, 3))
        for s in self.shapes:
            t, n = s.intersect(oc, dc)
            better = t < bc
            bc = np.where(better, t, bc)
            nl[better] = n[better]
        hit = np.isfinite(bc)
        if hit.any():
            oh = oc if oc.ndim == 1 else oc[hit]
            pl = oh + bc[hit, None] * dc[hit]
            alb[cand[hit]] = self.albedo(pl, nl[hit])
        best[cand] = bc
        nw[cand] = rotate(nl, self.pose[:3, :3])
        return best, nw, alb

    def local_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        pts = np.concatenate([s.corners() for s in self.shapes])
        pad = 1e-6
        return pts.min(axis=0) - pad, pts.max(axis=0) + pad

    def world_corners(self) -> np.ndarray:
        pts = np.concatenate([s.corners() for s in self.shapes])
        return transform(pts, self.pose)


def _odd_integral(x: np.ndarray) -> np.ndarray:
    """Integral from 0 to x of the indicator "floor(x) is odd" (a unit square wave)."""
    h = np.floor(x / 2.0)
    return h + np.maximum(x - 2.0 * h - 1.0, 0.0)


class CheckerAlbedo:
    """Board frame as OpenCV's object points: origin at the outer corner of the square grid,
    x along columns, y along rows, z into the board. The top-left square is dark.

    ``filtered`` box-filters the pattern over each pixel's footprint on the board (in
    metres), so edges are anti-aliased the way a real pixel integrates light and corner
    detection reaches sub-pixel accuracy without supersampling.
    """

    def __init__(self, rows: int, cols: int, square: float, dark: float = 0.06, light: float = 0.9) -> None:
        self.rows, self.cols, self.square = rows, cols, square
        self.dark, self.light = dark, light

    def __call__(self, p: np.ndarray, n: np.ndarray) -> np.ndarray:
        i = np.floor(p[:, 1] / self.square).astype(np.int64)
        j = np.floor(p[:, 0] / self.square).astype(np.int64)
        inside = (i >= 0) & (i < self.rows) & (j >= 0) & (j < self.cols)
        val = np.where((i + j) % 2 == 0, self.dark, self.light)
        return np.where(inside, val, self.light).astype(np.float32)

    def filtered(self, p: np.ndarray, wx: np.ndarray, wy: np.ndarray) -> np.ndarray:
        sq = self.square
        x, y = p[:, 0] / sq, p[:, 1] / sq
        wx = np.maximum(wx / sq, 1e-6)
        wy = np.maximum(wy / sq, 1e-6)
        fx = (_odd_integral(x + wx / 2) - _odd_integral(x - wx / 2)) / wx  # share of odd columns
        fy = (_odd_integral(y + wy / 2) - _odd_integral(y - wy / 2)) / wy
        p_dark = fx * fy + (1 - fx) * (1 - fy)
        ix = np.clip((np.minimum(x + wx / 2, self.cols) - np.maximum(x - wx / 2, 0)) / wx, 0, 1)
        iy = np.clip((np.minimum(y + wy / 2, self.rows) - np.maximum(y - wy / 2, 0)) / wy, 0, 1)
        return (self.light + (self.dark - self.light) * p_dark * ix * iy).astype(np.float32)


def checker_albedo(rows: int, cols: int, square: float, margin: float = 0.0,
                   dark: float = 0.06, light: float = 0.9) -> CheckerAlbedo:
    return CheckerAlbedo(rows, cols, square, dark, light)


def marker_bits(marker_id: int, size: int = 6) -> np.ndarray:
    """The ArUco 6x6 marker's cells with its black border ((size+2)^2, 1 = white).

    Uses OpenCV's ArUco dictionary when the build has it, so cv2.aruco can detect the target;
    otherwise a seeded random pattern of the same layout.
    """
    try:
        import cv2

        dic = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250)
        img = cv2.aruco.generateImageMarker(dic, int(marker_id), size + 2)
        return (img > 127).astype(np.float32)
    except Exception:  # noqa: BLE001 - no aruco module: fall back to a deterministic pattern
        rng = np.random.default_rng(marker_id)
        bits = np.zeros((size + 2, size + 2), np.float32)
        bits[1:-1, 1:-1] = rng.integers(0, 2, (size, size))
        return bits


def marker_box_albedo(half: float, marker_id: int, body: float = 0.8) -> AlbedoFn:
    """A cube of half-size ``half`` with the marker on its four vertical faces (with a white
    quiet zone of one cell), body colour on top and bottom."""
    bits = marker_bits(marker_id)
    m = bits.shape[0]
    cells = m + 2  # one quiet-zone cell either side

    def fn(p: np.ndarray, n: np.ndarray) -> np.ndarray:
        ax = np.abs(n).argmax(axis=1)
        # Face coordinates: horizontal along the face (seen from outside, left to right), vertical up.
        s = np.where(ax == 0, np.where(n[:, 0] > 0, p[:, 1], -p[:, 1]),
                     np.where(n[:, 1] > 0, -p[:, 0], p[:, 0]))
        u = (s + half) / (2 * half) * cells - 1
        v = (half - p[:, 2]) / (2 * half) * cells - 1
        iu = np.floor(u).astype(np.int64)
        iv = np.floor(v).astype(np.int64)
        inside = (ax != 2) & (iu >= 0) & (iu < m) & (iv >= 0) & (iv < m)
        val = np.full(p.shape[0], body, np.float32)
        val[inside] = np.where(bits[iv[inside], iu[inside]] > 0, 0.9, 0.05)
        return val

    return fn


@dataclass
class Posed:
    """A shape placed inside its object by its own transform (wheels, a head on a body)."""

    shape: Shape
    T: np.ndarray

    def intersect(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        Ti = invert(self.T)
        t, n = self.shape.intersect(transform(o, Ti), rotate(d, Ti[:3, :3]))
        return t, rotate(n, self.T[:3, :3])

    def corners(self) -> np.ndarray:
        return transform(self.shape.corners(), self.T)


Shape = Box | Cylinder | Sphere | Rect | Posed
