"""Vectorised ray casting against the heightfield's bilinear patches.

Max-mipmap traversal (as in GPU relief mapping): every ray walks the max-height pyramid,
climbing a level after each free cell and descending when it may touch a cell's content, so
it crosses open space in a few coarse steps and only visits fine cells near the surface. At
level 0 the hit is the exact root of the ray against the cell's bilinear patch (a quadratic
along the ray), so depth is exact to floating point, not to a marching step. All rays advance
together as numpy arrays; finished rays are dropped from the working set as they stop.
"""

from __future__ import annotations

import numpy as np

from drivers.sim.heightfield import Heightfield

_BIG = 1e30


def _slab(o: np.ndarray, inv: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t1 = (lo[None, :] - o) * inv
    t2 = (hi[None, :] - o) * inv
    return np.minimum(t1, t2).max(axis=1), np.maximum(t1, t2).min(axis=1)


def cast_heightfield(hf: Heightfield, o: np.ndarray, d: np.ndarray, t_limit: np.ndarray,
                     t_min: float = 1e-6, max_iter: int = 4000) -> np.ndarray:
    """Ray parameter of the first terrain hit for rays ``o + t d`` (N x 3), inf for none.

    Only hits with ``t_min <= t < t_limit`` count (``t_limit`` lets the caller stop a ray at
    an object already hit). ``d`` need not be unit length; t is in units of ``d``.
    """
    n = o.shape[0]
    t_hit = np.full(n, np.inf)
    xmin, ymin, xmax, ymax = hf.bounds
    with np.errstate(divide="ignore"):
        inv = np.where(np.abs(d) > 1e-15, 1.0 / np.where(d == 0, 1.0, d), _BIG)
    lo = np.array([xmin, ymin, hf.zmin - 1e-4])
    hi = np.array([xmax, ymax, hf.zmax + 1e-4])
    t0, t1 = _slab(o, inv, lo, hi)
    t0 = np.maximum(t0, t_min)
    t1 = np.minimum(t1, t_limit)
    idx = np.nonzero(t0 < t1)[0]
    if idx.size == 0:
        return t_hit

    ox, oy, oz = (o[idx, k].copy() for k in range(3))
    dx, dy, dz = (d[idx, k].copy() for k in range(3))
    ix_inv, iy_inv = inv[idx, 0].copy(), inv[idx, 1].copy()
    t = t0[idx]
    t_end = t1[idx]
    top = len(hf.pyramid) - 1
    lev = np.full(idx.size, top, np.int64)

    flat, off, wid = hf.pyr_flat, hf.pyr_offset, hf.pyr_width
    hgt = hf.pyr_height
    csize = hf.pyr_cell
    c0 = hf.cell
    heights = hf.heights.ravel()
    nxh = hf.heights.shape[1]
    stepx = (dx > 0).astype(np.float64)
    stepy = (dy > 0).astype(np.float64)

    for _ in range(max_iter):
        if idx.size == 0:
            break
        cs = csize[lev]
        x = ox + t * dx
        y = oy + t * dy
        fx = (x - xmin) / cs
        fy = (y - ymin) / cs
        ixc = np.clip(np.floor(fx).astype(np.int64), 0, wid[lev] - 1)
        iyc = np.clip(np.floor(fy).astype(np.int64), 0, hgt[lev] - 1)
        hmax = flat[off[lev] + iyc * wid[lev] + ixc]
        tx = (xmin + (ixc + stepx) * cs - ox) * ix_inv
        ty = (ymin + (iyc + stepy) * cs - oy) * iy_inv
        t_exit = np.maximum(np.minimum(tx, ty), t)
        z0 = oz + t * dz
        z1 = oz + t_exit * dz
        touch = np.minimum(z0, z1) <= hmax
        fine = touch & (lev == 0)
        descend = touch & (lev > 0)

        hit = np.zeros(idx.size, bool)
        if fine.any():
            f = np.nonzero(fine)[0]
            s_hit = _patch_root(heights, nxh, c0, xmin, ymin, x[f], y[f], z0[f], dx[f], dy[f], dz[f],
                                t_exit[f] - t[f])
            ok = np.isfinite(s_hit)
            hit[f[ok]] = True
            t[f[ok]] = t[f[ok]] + s_hit[ok]

        # Descending: drop to the child level and skip straight to where the ray reaches the
        # cell's top (it cannot touch anything above it).
        if descend.any():
            dsc = np.nonzero(descend)[0]
            lev[dsc] -= 1
            going_down = (dz[dsc] < 0) & (z0[dsc] > hmax[dsc])
            g = dsc[going_down]
            t[g] = np.maximum(t[g], (hmax[g] - oz[g]) / dz[g])

        # Free cells (and fine cells crossed without a hit): go to the exit, climb a level.
        adv = ~touch | (fine & ~hit)
        a = np.nonzero(adv)[0]
        t[a] = t_exit[a] * (1.0 + 1e-12) + 1e-9
        lev[a] = np.minimum(lev[a] + 1, top)

        done = hit | (t >= t_end)
        if done.any():
            dn = np.nonzero(done)[0]
            h = dn[hit[dn] & (t[dn] < t_end[dn])]
            t_hit[idx[h]] = t[h]
            keep = ~done
            idx = idx[keep]
            ox, oy, oz, dx, dy, dz = ox[keep], oy[keep], oz[keep], dx[keep], dy[keep], dz[keep]
            ix_inv, iy_inv, t, t_end, lev = ix_inv[keep], iy_inv[keep], t[keep], t_end[keep], lev[keep]
            stepx, stepy = stepx[keep], stepy[keep]
    return t_hit


def _patch_root(heights: np.ndarray, nx: int, cell: float, xmin: float, ymin: float,
                x: np.ndarray, y: np.ndarray, z: np.ndarray, dx: np.ndarray, dy: np.ndarray, dz: np.ndarray,
                s_len: np.ndarray) -> np.ndarray:
    """First s in [0, s_len] where the ray meets the bilinear patch under (x, y); inf if none.

    Along the ray the patch height is quadratic in s, so f(s) = z(s) - h(s) = A s^2 + B s + C.
    """
    fx = (x - xmin) / cell
    fy = (y - ymin) / cell
    ny = heights.size // nx
    ix = np.clip(np.floor(fx).astype(np.int64), 0, nx - 2)
    iy = np.clip(np.floor(fy).astype(np.int64), 0, ny - 2)
    u0 = fx - ix
    v0 = fy - iy
    k = iy * nx + ix
    h00 = heights[k].astype(np.float64)
    h10 = heights[k + 1]
    h01 = heights[k + nx]
    h11 = heights[k + nx + 1]
    b = h10 - h00
    c = h01 - h00
    e = h00 - h10 - h01 + h11
    du = dx / cell
    dv = dy / cell
    A = -e * du * dv
    B = dz - b * du - c * dv - e * (u0 * dv + v0 * du)
    C = z - (h00 + b * u0 + c * v0 + e * u0 * v0)
    tol = 1e-9 * (1.0 + s_len)
    out = np.full(x.shape, np.inf)
    below = C <= 0.0
    out[below] = 0.0
    lin = ~below & (np.abs(A) * s_len * s_len <= 1e-12 * (np.abs(B) * s_len + np.abs(C) + 1e-12))
    with np.errstate(divide="ignore", invalid="ignore"):
        s_lin = -C / B
        disc = B * B - 4.0 * A * C
        sq = np.sqrt(np.maximum(disc, 0.0))
        q = -0.5 * (B + np.where(B >= 0, sq, -sq))
        r1 = q / A
        r2 = C / q
    r1 = np.where(r1 >= 0, r1, np.inf)
    r2 = np.where(r2 >= 0, r2, np.inf)
    s_quad = np.where(disc >= 0, np.minimum(r1, r2), np.inf)
    s = np.where(lin, np.where(s_lin >= 0, s_lin, np.inf), s_quad)
    ok = ~below & (s <= s_len + tol)
    out[ok] = np.minimum(s[ok], s_len[ok])
    return out
