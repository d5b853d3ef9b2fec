"""Isolated spikes and pits in a DEM: single cells that every neighbour contradicts.

A ToF pixel that straddles a silhouette (a mixed or "flying" pixel) or catches a multipath
return lands on the ray between the surfaces it mixes: one or two points, centimetres to
decimetres off the ground, alone in their cell. DemImport keeps them (the noise model gives one
point a centimetre's variance, not the decimetre it is off), and Dem2Hazard's step, the window's
max - min, turns one such cell 9 cm up and another 5 cm down into a 0.15 m step hazard on open
ground (on the marsyard a clear goal was judged "0.45 m from a hazardous cell" that way).

A cell is a spike (a pit) when it stands higher (lower) than *every* defined one of its eight
neighbours by more than ``max(min_jump, k * sigma)``, sigma its height's standard deviation, and
no more than ``max_points`` points back it. Those cells are made undefined, and hole filling
then gives them their neighbours' surface. What a real obstacle leaves is never a lone cell
with few points: a rock the rover must avoid (taller than the 0.15 m step) is more than 0.27 m
wide in every scene (Golombek & Rapp height ratios) so its cells have neighbours at its own
height, and a thin object seen from close by puts many points in its cell.
"""

from __future__ import annotations

import numpy as np


def find_spikes(dem: np.ndarray, variance: np.ndarray | None = None, count: np.ndarray | None = None,
                min_jump: float = 0.05, k: float = 4.0, max_points: int = 3, min_neighbours: int = 3) -> np.ndarray:
    """Mask of the isolated spikes and pits of ``dem`` (NaN undefined); see the module doc.

    ``variance`` (m^2) and ``count`` (points per cell) may be None: then the jump is
    ``min_jump`` alone and any number of points qualifies. Cells with fewer than
    ``min_neighbours`` defined neighbours are not judged (too little to contradict them)."""
    z = np.asarray(dem, dtype=np.float64)
    if z.ndim != 2:
        raise ValueError(f"find_spikes: the DEM must be 2-D, not {z.shape}")
    if min_jump < 0 or k < 0:
        raise ValueError("find_spikes: min_jump and k must not be negative")
    h, w = z.shape
    pad = np.pad(z, 1, constant_values=np.nan)
    hi = np.full((h, w), -np.inf)
    lo = np.full((h, w), np.inf)
    n = np.zeros((h, w), np.int32)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr == 0 and dc == 0:
                continue
            nb = pad[1 + dr:1 + dr + h, 1 + dc:1 + dc + w]
            ok = np.isfinite(nb)
            np.fmax(hi, np.where(ok, nb, -np.inf), out=hi)
            np.fmin(lo, np.where(ok, nb, np.inf), out=lo)
            n += ok
    jump = np.full((h, w), float(min_jump))
    if variance is not None:
        v = np.asarray(variance, dtype=np.float64)
        np.fmax(jump, k * np.sqrt(np.where(np.isfinite(v) & (v > 0), v, 0.0)), out=jump)
    with np.errstate(invalid="ignore"):
        lone = np.isfinite(z) & (n >= min_neighbours) & ((z - hi > jump) | (lo - z > jump))
    if count is not None:
        lone &= np.asarray(count) <= max_points
    return lone
