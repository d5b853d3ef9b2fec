"""The terrain as a regular heightfield with bilinear patches, plus its max-height pyramid.

Heights sit on the nodes ``x = x0 + j*cell``, ``y = y0 + i*cell`` (row 0 = southmost, the
array's natural order; ``World.true_dem`` flips to north-up). Between nodes the surface is the
bilinear patch of the four corners, which is what both the renderer and ``sample`` use, so
rendered depth and ground truth describe one and the same surface.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np


@dataclass
class Heightfield:
    x0: float
    y0: float
    cell: float
    heights: np.ndarray  # (ny, nx) float32
    albedo: np.ndarray  # (ny, nx) float32, 0..1
    pyramid: list[np.ndarray] = field(default_factory=list, repr=False)
    rocks: list[dict[str, float]] = field(default_factory=list, repr=False)  # as placed, for ground truth
    # (ny, nx) float32 0..1, share of each node the sun reaches (cast shadows); None: all lit
    sunlit: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self.heights = np.ascontiguousarray(self.heights, np.float32)
        self._coef = None
        self.albedo = np.ascontiguousarray(self.albedo, np.float32)
        self.build_pyramid()

    @property
    def shape(self) -> tuple[int, int]:
        return self.heights.shape  # type: ignore[return-value]

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        ny, nx = self.shape
        return (self.x0, self.y0, self.x0 + (nx - 1) * self.cell, self.y0 + (ny - 1) * self.cell)

    def build_pyramid(self) -> None:
        """Max-height mipmap: level 0 holds each bilinear patch's highest corner.

        Levels are padded with -inf to even sizes so a ray over padding never stops there.
        Flattened into one array with per-level offsets so the renderer can look up cells of
        mixed levels in one fancy-indexing call.
        """
        h = self.heights
        m = np.maximum(np.maximum(h[:-1, :-1], h[1:, :-1]), np.maximum(h[:-1, 1:], h[1:, 1:]))
        # Pad level 0 to a multiple of 2^top so level L is exactly level 0 shifted by L bits
        # (the renderer computes coarse cell indices with shifts, not per-level tables).
        top = 0
        while max(m.shape) > 4 * (1 << top):
            top += 1
        mult = 1 << top
        py, px = (-m.shape[0]) % mult, (-m.shape[1]) % mult
        m = np.pad(m, ((0, py), (0, px)), constant_values=-np.inf)
        levels = [m]
        for _ in range(top):
            a = levels[-1]
            levels.append(a.reshape(a.shape[0] // 2, 2, a.shape[1] // 2, 2).max(axis=(1, 3)))
        self.pyramid = levels
        self.pyr_flat = np.concatenate([lv.ravel() for lv in levels]).astype(np.float32)
        sizes = [lv.size for lv in levels]
        self.pyr_offset = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
        self.pyr_width = np.array([lv.shape[1] for lv in levels], np.int64)
        self.pyr_height = np.array([lv.shape[0] for lv in levels], np.int64)
        self.pyr_cell = self.cell * (2.0 ** np.arange(len(levels)))
        finite = h[np.isfinite(h)]
        self.zmin = float(finite.min())
        self.zmax = float(finite.max())

    def patch_coefficients(self) -> np.ndarray:
        """Per cell (row-major over (ny-1) x (nx-1)): h00, h10-h00, h01-h00, h00-h10-h01+h11,
        so h(u, v) = h00 + b u + c v + e u v inside the cell; cached."""
        if getattr(self, "_coef", None) is None:
            h = self.heights
            h00, h10, h01, h11 = h[:-1, :-1], h[:-1, 1:], h[1:, :-1], h[1:, 1:]
            self._coef = np.stack([h00, h10 - h00, h01 - h00, h00 - h10 - h01 + h11], axis=-1).reshape(-1, 4)
        return self._coef

    def _frac(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return (np.asarray(x, np.float64) - self.x0) / self.cell, (np.asarray(y, np.float64) - self.y0) / self.cell

    def sample(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        """Bilinear height at world (x, y); NaN outside the grid."""
        return self._bilinear(self.heights, x, y)

    def _bilinear(self, grid: np.ndarray, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        fx, fy = self._frac(x, y)
        ny, nx = grid.shape
        inside = (fx >= 0) & (fx <= nx - 1) & (fy >= 0) & (fy <= ny - 1)
        ix = np.clip(np.floor(fx).astype(np.int64), 0, nx - 2)
        iy = np.clip(np.floor(fy).astype(np.int64), 0, ny - 2)
        u = fx - ix
        v = fy - iy
        g = grid
        out = (g[iy, ix] * (1 - u) * (1 - v) + g[iy, ix + 1] * u * (1 - v)
               + g[iy + 1, ix] * (1 - u) * v + g[iy + 1, ix + 1] * u * v)
        return np.where(inside, out, np.nan)

    def gradient(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """dz/dx, dz/dy of the bilinear patch containing (x, y)."""
        fx, fy = self._frac(x, y)
        ny, nx = self.shape
        ix = np.clip(np.floor(fx).astype(np.int64), 0, nx - 2)
        iy = np.clip(np.floor(fy).astype(np.int64), 0, ny - 2)
        u = np.clip(fx - ix, 0.0, 1.0)
        v = np.clip(fy - iy, 0.0, 1.0)
        g = self.heights
        h00, h10, h01, h11 = g[iy, ix], g[iy, ix + 1], g[iy + 1, ix], g[iy + 1, ix + 1]
        e = h00 - h10 - h01 + h11
        gx = ((h10 - h00) + e * v) / self.cell
        gy = ((h01 - h00) + e * u) / self.cell
        return gx, gy

    def shade(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """dz/dx, dz/dy and albedo at points on the surface (float32), sharing one lookup."""
        fx, fy = self._frac(x, y)
        ny, nx = self.shape
        ix = np.clip(fx.astype(np.int64), 0, nx - 2)
        iy = np.clip(fy.astype(np.int64), 0, ny - 2)
        u = np.clip(fx - ix, 0.0, 1.0).astype(np.float32)
        v = np.clip(fy - iy, 0.0, 1.0).astype(np.float32)
        k = iy * (nx - 1) + ix
        _, b, c, e = np.take(self.patch_coefficients(), k, axis=0).T
        inv = np.float32(1.0 / self.cell)
        gx = (b + e * v) * inv
        gy = (c + e * u) * inv
        # Albedo through cv2.remap (its 1/32-step weights are fine for reflectance, and it
        # is several times faster than four gathers on a large grid).
        m = fx.size
        rows = -(-m // 1024)
        mx = np.zeros(rows * 1024, np.float32)
        my = np.zeros(rows * 1024, np.float32)
        mx[:m] = fx
        my[:m] = fy
        alb = cv2.remap(self.albedo, mx.reshape(rows, 1024), my.reshape(rows, 1024), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE).ravel()[:m]
        return gx, gy, alb

    def sample_sunlit(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Share of sunlight reaching surface points (float32; 1 everywhere without a shadow map),
        through cv2.remap as the albedo: a shadow edge needs no more precision than a reflectance."""
        if self.sunlit is None:
            return np.ones(np.shape(x), np.float32)
        fx, fy = self._frac(x, y)
        m = fx.size
        rows = -(-m // 1024)
        mx = np.zeros(rows * 1024, np.float32)
        my = np.zeros(rows * 1024, np.float32)
        mx[:m] = fx
        my[:m] = fy
        return cv2.remap(self.sunlit, mx.reshape(rows, 1024), my.reshape(rows, 1024), cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE).ravel()[:m]

    def resample(self, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
        """Heights on the grid xs (columns) x ys (rows), exact bilinear, NaN outside; float32.

        (Not cv2.remap: its fixed-point weights would cost millimetres at steps.)
        """
        X, Y = np.meshgrid(np.asarray(xs, np.float64), np.asarray(ys, np.float64))
        return self.sample(X, Y).astype(np.float32)
