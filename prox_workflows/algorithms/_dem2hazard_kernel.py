"""Dem2Hazard's plane fit as one compiled pass over a block of rows, in the subset of Python numba
compiles. :mod:`.dem2hazard` owns the definitions and calls this; it lives in its own module so
that importing :mod:`.dem2hazard` does not import numba (~0.3 s) before the first DEM.

Why a kernel and not whole-array filters: the closed-form fit needs ten windowed sums and about
forty arithmetic operations per cell on them. As OpenCV box filters plus numpy expressions that is
some sixty passes over grid-sized float64 temporaries, and memory traffic, not arithmetic, is
what they cost. Here a row's sums live in a few small buffers that stay in cache:

- six column sums over the window's rows (mask, y, y^2, z, z y, z^2 of the defined cells), updated
  by adding the row entering the window and subtracting the one leaving it;
- ten prefix sums of those along the row (the x-weighted ones multiply by the column's x), so a
  window's sum is the difference of two entries, in a loop over the cells that vectorises.

The mask moments are sums of integers (x counts columns from the grid's middle one, y rows from
the block's middle row), so they, the counts and the determinant are exact in float64 and the
undefined-cell decision (too few cells, collinear cells) is the same as with any other exact
formulation. The z moments are float64 running sums, as OpenCV's box filter keeps them.
"""

from __future__ import annotations

import math

import numpy as np

from rvs_params.jit import jit

# error_model="numpy": IEEE division (an undetermined plane's det may be 0; its cell is
# overwritten with NaN), no zero checks in the loops, which would keep them from vectorising
_jit = jit(error_model="numpy")
_inline = jit(error_model="numpy", inline="always")


# Cephes' atan (S. Moshier, netlib cephes/atan.c): a rational approximation after reducing the
# argument to |x| <= 0.66, within an ulp of libm's. Written with selects so that the cell loop
# vectorises; libm's atan is a call per cell and took half of the kernel's time.
_P = (-8.750608600031904122785e-1, -1.615753718733365076637e1, -7.500855792314704667340e1,
      -1.228866684490136173410e2, -6.485021904942025371773e1)
_Q = (2.485846490142306297962e1, 1.650270098316988542046e2, 4.328810604912902668951e2,
      4.853903996359136964868e2, 1.945506571482613964425e2)
_MOREBITS = 6.123233995736765886130e-17  # pi/2 - float64(pi/2)
_T3P8 = 2.41421356237309504880  # tan(3 pi / 8)
_DEG = 180.0 / math.pi


@_inline
def _atan(x: float) -> float:
    """atan(x) for x >= 0 (inf gives pi/2, NaN stays NaN)."""
    big = x > _T3P8
    mid = x > 0.66
    xr = -1.0 / x if big else ((x - 1.0) / (x + 1.0) if mid else x)
    y = math.pi / 2 if big else (math.pi / 4 if mid else 0.0)
    extra = _MOREBITS if big else (0.5 * _MOREBITS if mid else 0.0)
    z = xr * xr
    p = (((_P[0] * z + _P[1]) * z + _P[2]) * z + _P[3]) * z + _P[4]
    q = ((((z + _Q[0]) * z + _Q[1]) * z + _Q[2]) * z + _Q[3]) * z + _Q[4]
    return y + (xr * (z * p / q) + xr + extra)


@_jit
def _add_row(z: np.ndarray, row: int, sign: float, y: float, zref: float, cm: np.ndarray, cmy: np.ndarray,
             cmyy: np.ndarray, cz: np.ndarray, czy: np.ndarray, czz: np.ndarray) -> None:
    """Add (sign +1) or remove (-1) one DEM row's defined cells from the column sums."""
    yy = y * y
    for j in range(z.shape[1]):
        v = z[row, j]
        if abs(v) < np.inf:  # defined: finite (NaN and +-inf are holes)
            d = np.float64(v) - zref
            cm[j] += sign
            cmy[j] += sign * y
            cmyy[j] += sign * yy
            cz[j] += sign * d
            czy[j] += sign * d * y
            czz[j] += sign * d * d


@_jit
def plane_rows(z: np.ndarray, zref: float, r0: int, r1: int, n: int, need: int, inv_cell: float,
               slope: np.ndarray, roughness: np.ndarray, valid: np.ndarray) -> None:
    """Slope (deg), roughness (m) and the valid mask of rows ``r0:r1`` of ``z``, written into
    those rows of the grid-sized outputs (NaN and False where undefined).

    ``z`` is the whole DEM (the window reaches ``n // 2`` rows beyond the block); cells beyond the
    grid count as undefined. The formulas are :func:`.dem2hazard._strip`'s: C_uv = N S_uv - S_u S_v,
    the plane's gradient from the 2 x 2 system, N * RSS = Czz - a Cxz - b Cyz.
    """
    h, w = z.shape
    r = n // 2
    yc = (r0 + r1) // 2  # integer centres: the mask moments stay exact
    xc = w // 2
    cm = np.zeros(w)
    cmy = np.zeros(w)
    cmyy = np.zeros(w)
    cz = np.zeros(w)
    czy = np.zeros(w)
    czz = np.zeros(w)
    # prefix sums along the row, padded so that the window of column j is q[j + n] - q[j]
    m = w + n
    q0 = np.zeros(m)  # N
    q1 = np.zeros(m)  # S_x
    q2 = np.zeros(m)  # S_xx
    q3 = np.zeros(m)  # S_y
    q4 = np.zeros(m)  # S_xy
    q5 = np.zeros(m)  # S_yy
    q6 = np.zeros(m)  # S_z
    q7 = np.zeros(m)  # S_xz
    q8 = np.zeros(m)  # S_yz
    q9 = np.zeros(m)  # S_zz
    for row in range(max(0, r0 - r), min(h, r0 + r)):  # the first window but its last row
        _add_row(z, row, 1.0, np.float64(yc - row), zref, cm, cmy, cmyy, cz, czy, czz)
    for i in range(r0, r1):
        if i + r < h:
            _add_row(z, i + r, 1.0, np.float64(yc - i - r), zref, cm, cmy, cmyy, cz, czy, czz)
        if i > r0 and i - r - 1 >= 0:
            _add_row(z, i - r - 1, -1.0, np.float64(yc - i + r + 1), zref, cm, cmy, cmyy, cz, czy, czz)
        s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = s8 = s9 = 0.0
        for j in range(w):
            x = np.float64(j - xc)
            a, b, c = cm[j], cmy[j], cz[j]
            s0 += a
            s1 += x * a
            s2 += x * x * a
            s3 += b
            s4 += x * b
            s5 += cmyy[j]
            s6 += c
            s7 += x * c
            s8 += czy[j]
            s9 += czz[j]
            t = j + r + 1
            q0[t] = s0
            q1[t] = s1
            q2[t] = s2
            q3[t] = s3
            q4[t] = s4
            q5[t] = s5
            q6[t] = s6
            q7[t] = s7
            q8[t] = s8
            q9[t] = s9
        for t in range(w + r + 1, m):
            q0[t] = s0
            q1[t] = s1
            q2[t] = s2
            q3[t] = s3
            q4[t] = s4
            q5[t] = s5
            q6[t] = s6
            q7[t] = s7
            q8[t] = s8
            q9[t] = s9
        for j in range(w):
            k = j + n
            cnt = q0[k] - q0[j]
            sx = q1[k] - q1[j]
            sy = q3[k] - q3[j]
            sz = q6[k] - q6[j]
            cxx = cnt * (q2[k] - q2[j]) - sx * sx
            cxy = cnt * (q4[k] - q4[j]) - sx * sy
            cyy = cnt * (q5[k] - q5[j]) - sy * sy
            cxz = cnt * (q7[k] - q7[j]) - sx * sz
            cyz = cnt * (q8[k] - q8[j]) - sy * sz
            czz_ = cnt * (q9[k] - q9[j]) - sz * sz
            det = cxx * cyy - cxy * cxy
            c2 = cnt * cnt
            ok = (abs(z[i, j]) < np.inf) & (cnt >= need) & (det > 1e-6 * (c2 * c2))
            inv = 1.0 / det  # divisions are what the vectorised loop waits for
            ga = (cyy * cxz - cxy * cyz) * inv  # dz per cell along x
            gb = (cxx * cyz - cxy * cxz) * inv  # dz per cell along y
            rss = max(czz_ - ga * cxz - gb * cyz, 0.0) / max(cnt * (cnt - 3.0), 1.0)
            # selects, not branches: the loop vectorises
            slope[i, j] = _DEG * _atan(math.sqrt(ga * ga + gb * gb) * inv_cell) if ok else np.nan
            roughness[i, j] = math.sqrt(rss) if ok else np.nan
            valid[i, j] = ok
