"""Vectorised ray casting against the heightfield's bilinear patches.

Max-mipmap traversal (as in GPU relief mapping): every ray walks the max-height pyramid,
climbing a level after each free cell and descending when it may touch a cell's content, so
it crosses open space in a few coarse steps and only visits fine cells near the surface. At
level 0 the hit is the exact root of the ray against the cell's bilinear patch (a quadratic
along the ray), so depth is exact to floating point, not to a marching step. All rays advance
together as numpy arrays; finished rays are dropped from the working set as they stop.

The walk itself is a compiled kernel (:func:`_walk_kernel`, numba, ``nogil``) doing per ray
exactly the float32/float64 arithmetic of the numpy walk (:func:`_walk_numpy`, kept as the path
without numba and as the kernel's reference), with the same working set and compaction, so the
two give the same bits. The numpy walk makes some 70 calls per step, hundreds of steps a strip,
and holds the GIL between them, so a render thread the OS preempts there holds the server's
event loop up until it runs again; the kernel holds the GIL for none of the walk (and is
1.0-3.2x faster on one thread).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from drivers.sim.heightfield import Heightfield
from rvs_params.jit import HAVE_NUMBA, jit

# Rows of the packed float32 working state (one column per ray).
_OX, _OY, _OZ, _DX, _DY, _DZ, _IX, _IY, _T, _TEND, _LEV, _IDX = range(12)


def cast_heightfield(hf: Heightfield, o: np.ndarray, d: np.ndarray, t_limit: np.ndarray,
                     t_min: float = 1e-6, max_iter: int = 100000, start_level: int = 3,
                     batch: int = 65536) -> np.ndarray:
    """Ray parameter of the first terrain hit for rays ``o + t d``, inf for none.

    ``o`` is one origin (3,) or one per ray (N, 3); ``d`` is (N, 3) and need not be unit
    length (t is in units of ``d``). Only hits with ``t_min <= t < t_limit`` count
    (``t_limit`` lets the caller stop a ray at an object already hit).

    The walk runs in float32 on a working set of about ``batch`` rays (small enough to stay
    in cache, large enough to amortise numpy's per-call cost) packed in one array, compacted
    with one ``np.take`` and refilled from the queue as rays finish.
    """
    n = d.shape[0]
    if n >= 1 << 24:
        raise ValueError("at most 16M rays per call (ray ids are carried in float32)")
    f32 = np.float32
    t_hit = np.full(n, np.inf)
    xmin, ymin, xmax, ymax = hf.bounds
    o = np.asarray(o, np.float64)
    dT = np.ascontiguousarray(np.asarray(d).T, dtype=f32)
    oT = np.asarray(o.reshape(-1, 3).T, np.float64)  # (3, 1) shared origin or (3, N)
    # Entry and exit of the terrain's bounding box (float32 slabs, one axis at a time).
    lo = (xmin, ymin, hf.zmin - 1e-4)
    hi = (xmax, ymax, hf.zmax + 1e-4)
    t0 = np.full(n, np.float32(t_min), f32)
    t1 = np.minimum(np.asarray(t_limit, f32), f32(1e30))
    inv = np.empty((3, n), f32)
    for k in range(3):
        dk = dT[k]
        safe = np.where(np.abs(dk) < 1e-12, f32(1e-12), dk)
        np.divide(f32(1.0), safe, out=inv[k])
        ta = (lo[k] - oT[k]).astype(f32) * inv[k]
        tb = (hi[k] - oT[k]).astype(f32) * inv[k]
        np.maximum(t0, np.minimum(ta, tb), out=t0)
        np.minimum(t1, np.maximum(ta, tb), out=t1)
    queue = np.nonzero(t0 < t1)[0]
    if queue.size == 0:
        return t_hit

    top = len(hf.pyramid) - 1
    nq = queue.size
    # Every queued ray's packed state, built once; the working set is refilled by slicing.
    ALL = np.empty((12, nq), f32)
    for row, k, base in ((_OX, 0, xmin), (_OY, 1, ymin), (_OZ, 2, 0.0)):
        ok = oT[k] - base
        ALL[row] = ok[0] if ok.size == 1 else ok[queue]
    ALL[_DX:_DZ + 1] = np.take(dT, queue, axis=1)
    ALL[_IX:_IY + 1] = np.take(inv[:2], queue, axis=1)
    ALL[_T] = t0[queue]
    ALL[_TEND] = t1[queue]
    ALL[_LEV] = min(start_level, top)
    ALL[_IDX] = queue

    w0 = int(hf.pyr_width[0])  # level-0 width, padded so every level halves it exactly
    ny0, nx0 = (int(v) for v in hf.pyramid[0].shape)
    nyc, nxc = hf.heights.shape[0] - 1, hf.heights.shape[1] - 1
    walk = _walker() if IMPL == "numba" else _walk_numpy
    walk(ALL, t_hit, hf.pyr_flat, hf.pyr_offset, hf.patch_coefficients(), w0, ny0, nx0, nyc, nxc, f32(hf.cell),
         f32(1.0 / hf.cell), f32(2e-5), top, batch, max_iter)
    return t_hit


IMPL = "numba" if HAVE_NUMBA else "numpy"  # tests switch it to compare the two walks
_compiled: list[Any] = []  # the compiled kernel, made on first use (importing numba takes ~0.3 s)


def _walker() -> Any:
    if not _compiled:
        _compiled.append(jit(_walk_kernel, error_model="numpy"))
    return _compiled[0]


def warm_up() -> None:
    """Compile (or load from numba's cache) the walk now rather than in the first render: a
    compile holds the GIL for seconds."""
    hf = Heightfield(0.0, 0.0, 1.0, np.zeros((4, 4), np.float32), np.zeros((4, 4), np.float32))
    cast_heightfield(hf, np.array([1.5, 1.5, 1.0]), np.array([[0.0, 0.0, -1.0]]), np.array([np.inf]))


def _walk_numpy(ALL: np.ndarray, t_hit: np.ndarray, flat: np.ndarray, off: np.ndarray, coef: np.ndarray,
                w0: int, ny0: int, nx0: int, nyc: int, nxc: int, c0: np.float32, ic0: np.float32,
                nudge: np.float32, top: int, batch: int, max_iter: int) -> None:
    """The walk over all queued rays' packed state ``ALL``, writing hits into ``t_hit``."""
    f32 = np.float32
    nq = ALL.shape[1]
    S = ALL[:, :batch].copy()
    qpos = min(batch, nq)
    for _ in range(max_iter):
        m = S.shape[1]
        if m == 0:
            break
        ox, oy, oz, dx, dy, dz = S[_OX], S[_OY], S[_OZ], S[_DX], S[_DY], S[_DZ]
        t = S[_T]
        lev = S[_LEV].astype(np.int64)
        fx = (ox + t * dx) * ic0
        fy = (oy + t * dy) * ic0
        # Rays are inside the box, so fx, fy >= -epsilon (truncation gives 0); only the top
        # edge needs a clamp. (np.minimum, not np.clip: clip's wrapper costs more than the work.)
        ix0 = fx.astype(np.int64)
        np.minimum(ix0, nx0 - 1, out=ix0)
        iy0 = fy.astype(np.int64)
        np.minimum(iy0, ny0 - 1, out=iy0)
        ixl = ix0 >> lev
        iyl = iy0 >> lev
        hmax = flat[off[lev] + iyl * (w0 >> lev) + ixl]
        tx = (((ixl + (dx > 0)) << lev).astype(f32) * c0 - ox) * S[_IX]
        ty = (((iyl + (dy > 0)) << lev).astype(f32) * c0 - oy) * S[_IY]
        t_exit = np.minimum(tx, ty)
        np.maximum(t_exit, t, out=t_exit)
        zt = oz + t * dz
        zlow = np.minimum(zt, oz + t_exit * dz)
        touch = zlow <= hmax
        at0 = lev == 0
        fine = touch & at0
        hit = np.zeros(m, bool)
        f = np.nonzero(fine)[0]
        if f.size:
            # Exact hit with the bilinear patch: along the ray the patch height is quadratic
            # in s = t - t_cell, so z(s) - h(s) = A s^2 + B s + C.
            ix = np.minimum(ix0[f], nxc - 1)
            iy = np.minimum(iy0[f], nyc - 1)
            h00, b, c, e = np.take(coef, iy * nxc + ix, axis=0).T
            u0 = fx[f] - ix
            v0 = fy[f] - iy
            du = dx[f] * ic0
            dv = dy[f] * ic0
            A = -e * du * dv
            B = dz[f] - b * du - c * dv - e * (u0 * dv + v0 * du)
            C = zt[f] - (h00 + b * u0 + c * v0 + e * u0 * v0)
            tf_ = t[f]
            s_len = t_exit[f] - tf_
            # A ray found already under the patch crossed it within the nudge that carried
            # it over the cell edge: step back along the surface's local slope (f is close
            # to linear over such a sliver), so steep faces are hit where they stand.
            back = nudge * (1 + tf_)
            s_hit = _first_root(A, B, C, s_len, back)
            ok = s_hit <= s_len
            fo = f[ok]
            hit[fo] = True
            t[fo] += s_hit[ok]
        # Descending: drop to a finer level, skipping straight to where the ray comes down
        # to the cell's top (it cannot touch anything above it).
        dsc = touch & ~at0
        jump = dsc & (dz < 0) & (zt > hmax)
        g = np.nonzero(jump)[0]
        if g.size:
            t[g] = (hmax[g] - oz[g]) / dz[g]
        # Free cells (and fine cells crossed without a hit): go past the exit, climb a level.
        adv = ~touch | (fine & ~hit)
        a = np.nonzero(adv)[0]
        ta = t_exit[a]
        t[a] = ta + nudge * (1 + ta)
        # (Descending two levels at a time and climbing one was the fastest mix measured.)
        S[_LEV] = np.minimum(np.maximum(lev - 2 * dsc, 0) + adv, top)

        tend = S[_TEND]
        hh = np.nonzero(hit & (t < tend))[0]
        if hh.size:
            t_hit[S[_IDX, hh].astype(np.int64)] = t[hh]
        done = hit | (t >= tend)
        # Compact lazily and top up from the queue: a finished ray left in the set is
        # harmless (a hit ray re-hits at the same t, a missed ray's later "hits" lie beyond
        # its t_end and are ignored).
        nd = int(np.count_nonzero(done))
        if nd > m // 4 or nd == m:
            S = np.take(S, np.nonzero(~done)[0], axis=1)
            room = batch - S.shape[1]
            if room > batch // 4 and qpos < nq:
                S = np.concatenate([S, ALL[:, qpos:qpos + room]], axis=1)
                qpos += room


def _walk_kernel(ALL: np.ndarray, t_hit: np.ndarray, flat: np.ndarray, off: np.ndarray, coef: np.ndarray,
                 w0: int, ny0: int, nx0: int, nyc: int, nxc: int, c0: np.float32, ic0: np.float32,
                 nudge: np.float32, top: int, batch: int, max_iter: int) -> None:  # pragma: no cover - compiled
    """:func:`_walk_numpy` one ray at a time (compiled by numba; see the module's docstring).

    Every step does each ray's arithmetic in the types numpy gives it there (float32 state, the
    patch root in float64 where the numpy walk promotes), constants as float32 where numpy
    takes a Python scalar as float32, and the same compaction of the working set, so a ray
    takes the same steps and ends on the same bits."""
    def _nmin(a: Any, b: Any) -> Any:  # np.minimum of two scalars: a NaN wins
        return a if (a < b or a != a) else b

    def _nmax(a: Any, b: Any) -> Any:  # np.maximum
        return a if (a > b or a != a) else b

    one = np.float32(1.0)
    four = np.float32(4.0)
    tiny = np.float32(1e-20)
    eps = np.float32(1e-6)
    inf = np.inf
    nq = ALL.shape[1]
    S = np.empty((12, batch), np.float32)
    m = min(batch, nq)
    S[:, :m] = ALL[:, :m]
    qpos = m
    done = np.zeros(batch, np.bool_)
    for _ in range(max_iter):
        if m == 0:
            break
        nd = 0
        for j in range(m):
            ox, oy, oz = S[0, j], S[1, j], S[2, j]
            dx, dy, dz = S[3, j], S[4, j], S[5, j]
            t = S[8, j]
            lev = np.int64(S[10, j])
            fx = (ox + t * dx) * ic0
            fy = (oy + t * dy) * ic0
            ix0 = min(np.int64(fx), nx0 - 1)
            iy0 = min(np.int64(fy), ny0 - 1)
            ixl = ix0 >> lev
            iyl = iy0 >> lev
            hmax = flat[off[lev] + iyl * (w0 >> lev) + ixl]
            tx = (np.float32((ixl + (1 if dx > 0 else 0)) << lev) * c0 - ox) * S[6, j]
            ty = (np.float32((iyl + (1 if dy > 0 else 0)) << lev) * c0 - oy) * S[7, j]
            t_exit = _nmax(_nmin(tx, ty), t)
            zt = oz + t * dz
            zlow = _nmin(zt, oz + t_exit * dz)
            touch = zlow <= hmax
            at0 = lev == 0
            fine = touch and at0
            hit = False
            t_new = t
            if fine:
                ix = min(ix0, nxc - 1)
                iy = min(iy0, nyc - 1)
                k = iy * nxc + ix
                h00, b, c, e = coef[k, 0], coef[k, 1], coef[k, 2], coef[k, 3]
                u0 = np.float64(fx) - np.float64(ix)
                v0 = np.float64(fy) - np.float64(iy)
                du = dx * ic0
                dv = dy * ic0
                A = -e * du * dv
                B = dz - b * du - c * dv - e * (u0 * dv + v0 * du)
                C = zt - (h00 + b * u0 + c * v0 + e * u0 * v0)
                s_len = t_exit - t
                back = nudge * (one + t)
                # _first_root, one ray
                disc = B * B - four * A * C
                sq = np.sqrt(_nmax(disc, 0.0))
                q = -0.5 * (B + (sq if B >= 0 else -sq))
                r1 = q / A if abs(A) > tiny else inf
                r2 = C / q
                r1 = r1 if r1 >= 0 else inf
                r2 = r2 if r2 >= 0 else inf
                s = _nmin(r1, r2) if disc >= 0 else inf
                s_back = _nmin(_nmax(-C / B, -back), 0.0) if B < 0 else 0.0
                if C <= 0:
                    s = s_back
                tol = eps * (one + s_len)
                if s > s_len and s <= s_len + tol:
                    s = s_len
                s_hit = np.float32(s)
                if s_hit <= s_len:
                    hit = True
                    t_new = t + s_hit
            dsc = touch and not at0
            if dsc and dz < 0 and zt > hmax:
                t_new = (hmax - oz) / dz
            adv = (not touch) or (fine and not hit)
            if adv:
                t_new = t_exit + nudge * (one + t_exit)
            S[10, j] = np.float32(min(max(lev - (2 if dsc else 0), 0) + (1 if adv else 0), top))
            S[8, j] = t_new
            tend = S[9, j]
            if hit and t_new < tend:
                t_hit[np.int64(S[11, j])] = t_new
            dj = hit or t_new >= tend
            done[j] = dj
            nd += dj
        if nd > m // 4 or nd == m:
            kept = 0
            for j in range(m):
                if not done[j]:
                    if kept != j:
                        S[:, kept] = S[:, j]
                    kept += 1
            m = kept
            room = batch - m
            if room > batch // 4 and qpos < nq:
                take = min(room, nq - qpos)
                S[:, m:m + take] = ALL[:, qpos:qpos + take]
                m += take
                qpos += room


def _first_root(A: np.ndarray, B: np.ndarray, C: np.ndarray, s_len: np.ndarray, back: np.ndarray) -> np.ndarray:
    """Smallest s >= 0 with A s^2 + B s + C = 0 when C = f(0) > 0; inf if none (callers
    compare with the segment length). When C <= 0 (already under the patch), the linear
    root in [-back, 0]."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        disc = B * B - 4.0 * A * C
        sq = np.sqrt(np.maximum(disc, 0.0))
        q = -0.5 * (B + np.where(B >= 0, sq, -sq))
        r1 = np.where(np.abs(A) > 1e-20, q / A, np.inf)
        r2 = C / q
        r1 = np.where(r1 >= 0, r1, np.inf)
        r2 = np.where(r2 >= 0, r2, np.inf)
        s = np.where(disc >= 0, np.minimum(r1, r2), np.inf)
        s_back = np.where(B < 0, np.minimum(np.maximum(-C / B, -back), 0.0), 0.0)
    s = np.where(C <= 0, s_back, s)
    # A root a hair past the end (rounding) still belongs to this patch.
    tol = 1e-6 * (1 + s_len)
    return np.where((s > s_len) & (s <= s_len + tol), s_len, s).astype(s_len.dtype)
