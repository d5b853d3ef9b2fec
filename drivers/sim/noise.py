"""Seeded procedural noise: smooth fractal fields for relief and albedo, periodic detail tiles.

Everything is drawn from a ``numpy.random.Generator`` the scene seeds, so one seed always
gives the same world.
"""

from __future__ import annotations

import cv2
import numpy as np


def smooth_field(shape: tuple[int, int], cell: float, scale: float, rng: np.random.Generator) -> np.ndarray:
    """Zero-mean, unit-std random field with features about ``scale`` metres wide.

    Drawn on a coarse lattice of spacing ``scale`` and upsampled bicubically, which is cheap
    for large grids and smooth across cells.
    """
    ny, nx = shape
    step = max(scale / cell, 1.0)
    cy = int(np.ceil(ny / step)) + 4
    cx = int(np.ceil(nx / step)) + 4
    coarse = rng.standard_normal((cy, cx)).astype(np.float32)
    if step <= 1.0:
        out = coarse[:ny, :nx]
    else:
        # Sample the coarse lattice at fine positions (offset 1.5 lattice units keeps the
        # bicubic kernel inside the drawn area).
        xs = (np.arange(nx, dtype=np.float32) / step + 1.5)[None, :].repeat(ny, 0)
        ys = (np.arange(ny, dtype=np.float32) / step + 1.5)[:, None].repeat(nx, 1)
        out = cv2.remap(coarse, xs, ys, interpolation=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    out = out - out.mean()
    std = float(out.std())
    return out / std if std > 0 else out


def fractal(shape: tuple[int, int], cell: float, scales: list[float], rng: np.random.Generator,
            falloff: float = 0.6) -> np.ndarray:
    """Sum of smooth fields from the largest scale down, each octave ``falloff`` times weaker."""
    out = np.zeros(shape, np.float32)
    amp = 1.0
    for s in sorted(scales, reverse=True):
        out += amp * smooth_field(shape, cell, s, rng)
        amp *= falloff
    std = float(out.std())
    return out / std if std > 0 else out


def periodic_tile(size: int, rng: np.random.Generator, beta: float = 1.2, min_period: float = 2.0) -> np.ndarray:
    """A seamless ``size`` x ``size`` tile of 1/f^beta noise in 0..1, for fine albedo detail.

    Periodic by construction (shaped in Fourier space), so it can be sampled with wrap-around
    at any world position without seams; frequencies above 1/min_period texels are cut so
    bilinear sampling does not alias.
    """
    white = rng.standard_normal((size, size))
    f = np.fft.fftfreq(size)
    fr = np.sqrt(f[:, None] ** 2 + f[None, :] ** 2)
    filt = np.zeros_like(fr)
    ok = (fr > 0) & (fr <= 1.0 / min_period)
    filt[ok] = fr[ok] ** (-beta / 1.0)
    tile = np.real(np.fft.ifft2(np.fft.fft2(white) * filt))
    tile = (tile - tile.mean()) / tile.std()
    # Map to 0..1 through a soft clip so the albedo range is used without hard saturation.
    return (0.5 + 0.5 * np.tanh(tile / 1.5)).astype(np.float32)
