"""DemImport: direct reconstruction of a DEM from a point cloud (seed 000 sect. 3.3.3, 5.2.2).

Each point goes to the cell that holds it (the nearest grid point, in the thesis's words) and the
cell keeps the greatest height: for a rover a rock's top matters more than the ground it hides,
and a wall seen edge-on should read as tall, not as its mean. Beside that DEM the cell's count,
mean, min and the spread (variance) of its heights are kept, so later steps can tell a flat cell
from one that straddles an edge; with per-point measurement variances (from the ToF noise model)
the cell also gets the fused measurement variance that DemMosaik's ``fuse`` rule weighs by.

Speed is the point of the implementation: a full 24-view scan is millions of points. There is no
per-point Python and no sort. Two implementations give the same layers (dem, min and count bit
for bit, the moments to rounding); ``IMPL`` picks one, tests run both.

**numba** (the default; a project dependency): one compiled pass over the points computes every
statistic, a block of 2048 points at a time. First the block's flat cell indices, in a loop the
compiler vectorises (the N x 3 / N x 4 rows read with a constant stride); then one scatter loop
that keeps the current cell's max, min, count and sums in registers while consecutive points fall
in the same cell (a ToF image's pixel order puts neighbours together) and adds them to the grid
when the cell changes; then a finishing pass per block of cells. Sums are float64 of
d = z - z0 (z0 the cloud's mid height, or that of a sample of it when the grid is given), so
E[d^2] - E[d]^2 keeps its precision for millimetre spreads on metre-scale terrain. With at
least 400 000 points, two a cell, and a core idle, two threads (the kernels release the GIL) each
read every point but scatter into their own half of the cells - no second set of sums to merge,
and the same result, bit for bit, as one thread. The kernels are compiled on first use and
cached by numba (``cache=True``: 2-6 s once per installation, then ~0.4 s per process with
numba's import); :func:`warm_up` does it ahead of time. See ``tools/bench/dem.py`` for the figures.

**numpy** (the fallback without numba, and for dtypes numba is not given): the points are
streamed in chunks small enough to stay in cache, and every statistic is one scatter of a chunk
into a grid-sized accumulator with numpy's ``ufunc.at`` (whose contiguous fast path runs at
bincount speed since numpy 1.25):

* max and min: ``np.maximum.at`` / ``np.minimum.at`` (exact, order-independent);
* count: ``np.add.at`` of ones;
* sum and sum of squares in one complex128 ``np.add.at`` (real = d, imaginary = d^2);
* with point variances, information 1/s^2 and information-weighted height in a second complex
  scatter.

In both, cell assignment is exactly :meth:`GridGeometry.cell_of`'s arithmetic (same expression,
same dtype), so points on a cell border land where ``cell_of`` says, whatever the input precision.
"""

from __future__ import annotations

import math
import os
import threading
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from rvs_params.jit import HAVE_NUMBA, jit

from ..grid import GridGeometry, Layers

CHUNK = 1 << 16  # points per chunk (numpy): index, heights and weights of one chunk stay in L2 cache

LAYERS = ("dem", "mean", "min", "count", "variance")  # by default; plus measurement_variance,
# wmean, intensity when point variances / a fourth column are given


def geometry_for(points: np.ndarray, cell: float, bounds: Sequence[float] | None = None) -> GridGeometry:
    """The grid of ``cell`` aligned to multiples of the cell size that holds every point (or
    ``bounds`` = (xmin, ymin, xmax, ymax)), including points exactly on its far edges."""
    if bounds is not None:
        xmin, ymin, xmax, ymax = (float(b) for b in bounds)
        if not (xmax > xmin and ymax > ymin):
            raise ValueError(f"bounds {bounds}: need xmin < xmax and ymin < ymax")
        return GridGeometry.covering(xmin, ymin, xmax, ymax, cell)
    lo, hi = _extremes(np.asarray(points))
    if not np.all(np.isfinite(lo[:2])) or not np.all(np.isfinite(hi[:2])):
        raise ValueError("points have no finite x, y")
    return _grid_holding(np.asarray(points).dtype, lo, hi, cell)


def _grid_holding(dtype: np.dtype, lo: np.ndarray, hi: np.ndarray, cell: float) -> GridGeometry:
    g = GridGeometry.covering(float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]), cell)
    # covering() is about bounds; points on the far edge (x == xmax, y == ymin) or a hair off a
    # rounded near edge would fall outside. Check the extremes with cell_of's own arithmetic.
    xs = np.array([lo[0], hi[0]], dtype=dtype)
    ys = np.array([hi[1], lo[1]], dtype=dtype)
    rows, cols = g.cell_of(xs, ys)
    xmin, ymax = g.xmin, g.ymax
    if cols[0] < 0:
        xmin -= cell * int(-cols[0])
    if rows[0] < 0:
        ymax += cell * int(-rows[0])
    g = GridGeometry(g.cell, xmin, ymax, g.width, g.height)
    rows, cols = g.cell_of(xs, ys)
    return GridGeometry(g.cell, xmin, ymax, max(g.width, int(cols[1]) + 1), max(g.height, int(rows[1]) + 1))


def _extremes(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Column minima and maxima (NaN if a column has a NaN) in two cheap passes.

    ``points.min(axis=0)`` on an N x 3 array reduces a narrow strided axis and is ~50x slower
    than this: fold the rows into wide contiguous blocks and reduce element-wise."""
    n, k = points.shape
    block = 1024
    whole = (n // block) * block
    lo = np.full(k, np.inf)
    hi = np.full(k, -np.inf)
    if whole:
        a = points[:whole].reshape(-1, k * block)
        lo = np.minimum(lo, a.min(axis=0).reshape(block, k).min(axis=0))
        hi = np.maximum(hi, a.max(axis=0).reshape(block, k).max(axis=0))
    if whole < n:
        lo = np.minimum(lo, points[whole:].min(axis=0))
        hi = np.maximum(hi, points[whole:].max(axis=0))
    return lo, hi


def _in_polygon(x: np.ndarray, y: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Even-odd rule point-in-polygon, vectorised over the points (one loop over the edges)."""
    inside = np.zeros(x.shape, dtype=bool)
    px, py = poly[:, 0], poly[:, 1]
    qx, qy = np.roll(px, 1), np.roll(py, 1)
    for x0, y0, x1, y1 in zip(px, py, qx, qy, strict=True):
        if y0 == y1:
            continue
        crosses = (y0 > y) != (y1 > y)
        xc = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
        inside ^= crosses & (x < xc)
    return inside


def _rover_polygon(rover_mask: np.ndarray | Sequence[float]) -> np.ndarray:
    poly = np.asarray(rover_mask, dtype=np.float64)
    if poly.ndim == 1 and poly.size == 4:
        x0, y0, x1, y1 = poly
        if not (x1 > x0 and y1 > y0):
            raise ValueError(f"rover_mask box {poly.tolist()}: need xmin < xmax and ymin < ymax")
        poly = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    if poly.ndim != 2 or poly.shape[1] != 2 or len(poly) < 3:
        raise ValueError("rover_mask: a polygon (M >= 3 x 2) or a box (xmin, ymin, xmax, ymax)")
    return poly


def dem_import(
    points: np.ndarray,
    geometry: GridGeometry | None = None,
    cell: float = 0.02,
    bounds: Sequence[float] | None = None,
    point_variance: np.ndarray | None = None,
    rover_mask: np.ndarray | Sequence[float] | None = None,
    rover_ground_z: float | None = None,
    stats: Sequence[str] = LAYERS,
    chunk: int = CHUNK,
    height: str = "max",
) -> Layers:
    """Direct reconstruction of ``points`` (N x 3 x, y, z or N x 4 with intensity, global frame).

    The grid is ``geometry`` if given, else the ``cell``-sized grid over ``bounds`` (points
    outside are dropped), else the grid that holds every point. ``rover_mask`` is the rover's
    footprint in the global frame (polygon M x 2 or box xmin, ymin, xmax, ymax): points inside it
    are the rover's own body and dropped - all of them, or with ``rover_ground_z`` only those
    above that height, so ground seen between the wheels stays. Points with a NaN coordinate are
    ignored.

    Layers (float32, NaN where no point fell; count int32, 0 there):
    ``dem`` the greatest height, ``mean``, ``min``, ``count``, ``variance`` the population
    variance of the cell's heights (0 for one point); with ``point_variance`` (N, m^2) also
    ``measurement_variance`` = 1 / sum(1 / s_i^2), the variance of the information-weighted mean
    height ``wmean``, which is what DemMosaik's ``fuse`` rule weighs the cell by; with a fourth
    column ``intensity``, its mean. ``stats`` names the layers wanted of the first five (fewer
    cost less; ``("dem",)`` is the bare direct reconstruction). ``chunk`` is the points per chunk
    of the numpy implementation (the compiled one takes blocks of at most 2048).

    ``height`` says what the ``dem`` layer is: ``"max"`` the greatest height (the thesis's
    direct rule), ``"mean"`` the information-weighted mean ``wmean`` (the plain ``mean`` without
    point variances) with the greatest height kept as ``max``. Every entry point (the server's
    per-view DEMs, ``rvs-dem-import``, scripts) picks the rule here, so "dem" means one thing
    for a given rule: the greatest of several noisy ToF heights sits about a sigma above the
    ground, a bias fusion cannot average away, hence the mean for measured data.
    """
    if height not in ("max", "mean"):
        raise ValueError(f"height must be max or mean, not {height!r}")
    layers = _dem_import(points, geometry, cell, bounds, point_variance, rover_mask, rover_ground_z, stats, chunk)
    if height == "mean":
        mean = layers.layers.get("wmean", layers.layers.get("mean"))
        if mean is None:
            raise ValueError("height='mean' needs the mean layer: include 'mean' in stats")
        layers["max"] = layers["dem"]
        layers["dem"] = mean
        layers.meta["method"] = "direct reconstruction (information-weighted mean height per cell)"
    return layers


def _dem_import(points: np.ndarray, geometry: GridGeometry | None, cell: float, bounds: Sequence[float] | None,
                point_variance: np.ndarray | None, rover_mask: np.ndarray | Sequence[float] | None,
                rover_ground_z: float | None, stats: Sequence[str], chunk: int) -> Layers:
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] not in (3, 4):
        raise ValueError(f"points must be N x 3 or N x 4, got shape {pts.shape}")
    if not np.issubdtype(pts.dtype, np.floating):
        pts = pts.astype(np.float64)
    var = None
    if point_variance is not None:
        var = np.asarray(point_variance, dtype=np.float64).reshape(-1)
        if len(var) != len(pts):
            raise ValueError(f"point_variance has {len(var)} values for {len(pts)} points")
        if len(var) and not np.all(var > 0):
            raise ValueError("point_variance must be positive (a measurement has some noise)")
    if cell <= 0:
        raise ValueError(f"cell must be positive, got {cell}")
    unknown = set(stats) - set(LAYERS)
    if unknown or "dem" not in stats:
        raise ValueError(f"stats must include 'dem' and be among {', '.join(LAYERS)}; got {list(stats)}")
    if _choose(pts) == "numba":
        return _import_numba(pts, var, geometry, cell, bounds, rover_mask, rover_ground_z, stats, chunk)
    return _import_numpy(pts, var, geometry, cell, bounds, rover_mask, rover_ground_z, stats, chunk)


def _import_numpy(pts: np.ndarray, var: np.ndarray | None, geometry: GridGeometry | None, cell: float,
                  bounds: Sequence[float] | None, rover_mask: np.ndarray | Sequence[float] | None,
                  rover_ground_z: float | None, stats: Sequence[str], chunk: int) -> Layers:
    """The numpy implementation: one ``ufunc.at`` scatter per statistic and chunk."""
    want_min = "min" in stats
    want_moments = "mean" in stats or "variance" in stats
    want_count = "count" in stats or want_moments or var is not None or pts.shape[1] == 4

    lo, hi = _extremes(pts) if len(pts) else (np.full(pts.shape[1], np.nan), np.full(pts.shape[1], np.nan))
    finite = bool(np.all(np.isfinite(lo[:3])) and np.all(np.isfinite(hi[:3])))
    if not finite and len(pts):
        keep = np.all(np.isfinite(pts[:, :3]), axis=1)
        pts = pts[keep]
        var = var[keep] if var is not None else None
        lo, hi = _extremes(pts) if len(pts) else (lo, hi)

    if geometry is None:
        if bounds is None and not len(pts):
            raise ValueError("no points and no geometry or bounds to make an empty grid")
        geometry = geometry_for(pts, cell, bounds) if bounds is not None else _grid_holding(pts.dtype, lo, hi, cell)
    g = geometry
    h, w = g.shape
    ncell = h * w
    itype = np.int32 if ncell < 2**31 else np.int64

    # Skip the per-chunk bounds test when the extremes (hence every point) are inside the grid.
    if len(pts):
        rows, cols = g.cell_of(np.array([lo[0], hi[0]], pts.dtype), np.array([hi[1], lo[1]], pts.dtype))
        need_clip = not (cols[0] >= 0 and cols[1] < w and rows[0] >= 0 and rows[1] < h)
    else:
        need_clip = False
    poly = _rover_polygon(rover_mask) if rover_mask is not None else None
    if poly is not None:
        pminx, pminy = poly.min(axis=0)
        pmaxx, pmaxy = poly.max(axis=0)
        if len(pts) and (pmaxx < lo[0] or pminx > hi[0] or pmaxy < lo[1] or pminy > hi[1]):
            poly = None  # the rover is nowhere near these points

    z0 = float(0.5 * (lo[2] + hi[2])) if len(pts) else 0.0  # reference height for the sums
    with_intensity = pts.shape[1] == 4
    zmax = np.full(ncell, -np.inf, np.float32)
    zmin = np.full(ncell, np.inf, np.float32) if want_min else None
    count = np.zeros(ncell, np.int32) if want_count else None
    moments = np.zeros(ncell, np.complex128) if want_moments else None  # sum d + i sum d^2
    info = np.zeros(ncell, np.complex128) if var is not None else None  # sum 1/s^2 + i sum d/s^2
    isum = np.zeros(ncell, np.float64) if with_intensity else None
    ones = np.ones(min(chunk, max(len(pts), 1)), np.int32)

    for start in range(0, len(pts), chunk):
        q = pts[start:start + chunk]
        x, y = q[:, 0], q[:, 1]
        # exactly GridGeometry.cell_of's arithmetic (floor of the same expression)
        tc = x - g.xmin
        tc /= g.cell
        tr = g.ymax - y
        tr /= g.cell
        sel = None
        if need_clip:
            sel = (tc >= 0) & (tc < w) & (tr >= 0) & (tr < h)
        if poly is not None:
            near = (x >= pminx) & (x <= pmaxx) & (y >= pminy) & (y <= pmaxy)
            if near.any():
                which = np.flatnonzero(near)
                body = _in_polygon(x[which].astype(np.float64), y[which].astype(np.float64), poly)
                if rover_ground_z is not None:
                    body &= q[which, 2] > rover_ground_z
                if body.any():
                    drop = np.zeros(len(q), bool)
                    drop[which[body]] = True
                    sel = ~drop if sel is None else sel & ~drop
        # t >= 0 everywhere kept, so truncation is floor
        if sel is not None:
            tc, tr, q = tc[sel], tr[sel], q[sel]
        idx = tr.astype(itype)
        idx *= w
        idx += tc.astype(itype)
        zc = np.ascontiguousarray(q[:, 2], dtype=np.float32)
        np.maximum.at(zmax, idx, zc)
        if zmin is not None:
            np.minimum.at(zmin, idx, zc)
        if count is not None:
            np.add.at(count, idx, ones[:len(idx)])
        if moments is not None or info is not None:
            wgt = np.empty(len(idx), np.complex128)
            d = wgt.real
            np.subtract(zc, z0, out=d, dtype=np.float64)
        if moments is not None:
            np.multiply(d, d, out=wgt.imag)
            np.add.at(moments, idx, wgt)
        if info is not None:
            v = var[start:start + chunk]
            if sel is not None:
                v = v[sel]
            iw = np.empty(len(idx), np.complex128)
            np.divide(1.0, v, out=iw.real)
            np.multiply(iw.real, d, out=iw.imag)
            np.add.at(info, idx, iw)
        if isum is not None:
            np.add.at(isum, idx, q[:, 3].astype(np.float64))

    return _finish(g, stats, zmax, zmin, count, moments, info, isum, z0)


def _finish(g: GridGeometry, stats: Sequence[str], zmax: np.ndarray, zmin: np.ndarray | None,
            count: np.ndarray | None, moments: np.ndarray | None, info: np.ndarray | None,
            isum: np.ndarray | None, z0: float) -> Layers:
    shape = g.shape
    empty = count == 0 if count is not None else np.isneginf(zmax)
    zmax[empty] = np.nan
    out = Layers(g, meta={"method": "direct reconstruction (max height per cell)"})
    out["dem"] = zmax.reshape(shape)
    if zmin is not None:
        zmin[empty] = np.nan
        out["min"] = zmin.reshape(shape)
    if count is None:
        return out
    if "count" in stats:
        out["count"] = count.reshape(shape)
    n = count.astype(np.float64)
    n[empty] = np.nan  # empty cells come out NaN from every division below
    if moments is not None:
        mean_d = moments.real / n
        variance = moments.imag / n
        variance -= mean_d * mean_d
        np.maximum(variance, 0.0, out=variance)  # rounding can leave -1e-20 for a flat cell
        mean_d += z0
        if "mean" in stats:
            out["mean"] = mean_d.astype(np.float32).reshape(shape)
        if "variance" in stats:
            out["variance"] = variance.astype(np.float32).reshape(shape)
    if info is not None:
        with np.errstate(divide="ignore", invalid="ignore"):
            mvar = 1.0 / info.real
            wmean = info.imag / info.real + z0
        mvar[empty] = np.nan
        wmean[empty] = np.nan
        out["measurement_variance"] = mvar.astype(np.float32).reshape(shape)
        out["wmean"] = wmean.astype(np.float32).reshape(shape)
    if isum is not None:
        out["intensity"] = (isum / n).astype(np.float32).reshape(shape)
    return out


# ---------------------------------------------------------------------------------------------
# The compiled implementation: one pass over the points (numba)
# ---------------------------------------------------------------------------------------------
NUMBA_BLOCK = 2048  # points per block: their cell indices and heights stay in L1 between the phases
FINISH_BLOCK = 1024  # cells per block of the finishing pass
IMPL = "numba"  # "numba" (when installed) or "numpy"; tests switch it to run both implementations
THREADS = min(2, os.cpu_count() or 1)  # threads the compiled pass splits the grid's cells over ...
THREAD_MIN_POINTS = 400_000  # ... when there are this many points, at least 2 a cell, and a free core


def _accumulate_kernel(pts, var, clo, chi, block, xmin, ymax, cell, fw, fh, w, z0,  # noqa: C901 - one pass
                       want_min, want_count, want_moments, poly, pbox, use_ground, ground32, ground,
                       zmax, zmin, count, s1, s2, i1, i2, isum, idx, zb, ib):
    """Every statistic of the points that fall in cells ``clo <= c < chi``, in one pass over the
    points, a block at a time: first the block's flat cell indices (-1 for a point outside the
    grid, with a non-finite coordinate, or on the rover's body) in a loop the compiler
    vectorises, then one scatter loop, which sums runs of consecutive points in the same cell
    (pixel order puts neighbours together) in registers before touching the grid.
    Written in the subset of Python numba compiles; the arrays of statistics not wanted are
    empty. ``d`` is the height relative to ``z0`` in float64, as in the numpy implementation."""
    n = pts.shape[0]
    ncol = pts.shape[1]
    use_var = var.shape[0] > 0
    with_int = isum.shape[0] > 0
    npoly = poly.shape[0]
    for s in range(0, n, block):
        m = min(n - s, block)
        flat = pts[s:s + m].reshape(-1)  # a constant stride below: the loads vectorise
        if ncol == 3:
            for j in range(m):
                x = flat[3 * j]
                y = flat[3 * j + 1]
                z = flat[3 * j + 2]
                tc = (x - xmin) / cell  # GridGeometry.cell_of's expression, in the points' dtype
                tr = (ymax - y) / cell
                ok = (tc >= 0) & (tc < fw) & (tr >= 0) & (tr < fh) & (z - z == 0)
                c = np.int32(tr) * np.int32(w) + np.int32(tc)  # t >= 0 where kept: truncation is floor
                idx[j] = c if ok else np.int32(-1)
                zb[j] = np.float32(z)
        else:
            for j in range(m):
                x = flat[4 * j]
                y = flat[4 * j + 1]
                z = flat[4 * j + 2]
                v = flat[4 * j + 3]  # loading all four keeps the stride-4 loads vectorised
                tc = (x - xmin) / cell
                tr = (ymax - y) / cell
                ok = (tc >= 0) & (tc < fw) & (tr >= 0) & (tr < fh) & (z - z == 0)
                c = np.int32(tr) * np.int32(w) + np.int32(tc)
                idx[j] = c if ok else np.int32(-1)
                zb[j] = np.float32(z)
                ib[j] = v
        if npoly:  # the rover's body: _in_polygon's even-odd rule, in float64
            for j in range(m):
                if idx[j] < 0:
                    continue
                x = np.float64(flat[ncol * j])
                y = np.float64(flat[ncol * j + 1])
                if not (x >= pbox[0] and x <= pbox[2] and y >= pbox[1] and y <= pbox[3]):
                    continue
                inside = False
                for e in range(npoly):
                    x0 = poly[e, 0]
                    y0 = poly[e, 1]
                    x1 = poly[e - 1 if e > 0 else npoly - 1, 0]
                    y1 = poly[e - 1 if e > 0 else npoly - 1, 1]
                    if y0 == y1:
                        continue
                    if (y0 > y) != (y1 > y):
                        xc = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
                        if x < xc:
                            inside = not inside
                if inside and use_ground:
                    zz = flat[ncol * j + 2]
                    inside = (np.float32(zz) > np.float32(ground)) if ground32 else (np.float64(zz) > ground)
                if inside:
                    idx[j] = -1
        if want_min and want_count and want_moments and not use_var and not with_int:  # the usual case
            cur = -1
            mx = np.float32(0.0)
            mn = np.float32(0.0)
            k = 0
            a1 = 0.0
            a2 = 0.0
            for j in range(m):
                c = idx[j]
                if c < clo or c >= chi:  # -1 included: clo >= 0
                    continue
                zf = zb[j]
                d = np.float64(zf) - z0
                if c == cur:  # the same cell as the point before: sum in registers
                    mx = max(mx, zf)
                    mn = min(mn, zf)
                    k += 1
                    a1 += d
                    a2 += d * d
                    continue
                if cur >= 0:
                    zmax[cur] = max(zmax[cur], mx)
                    zmin[cur] = min(zmin[cur], mn)
                    count[cur] += k
                    s1[cur] += a1
                    s2[cur] += a2
                cur = c
                mx = zf
                mn = zf
                k = 1
                a1 = d
                a2 = d * d
            if cur >= 0:
                zmax[cur] = max(zmax[cur], mx)
                zmin[cur] = min(zmin[cur], mn)
                count[cur] += k
                s1[cur] += a1
                s2[cur] += a2
        elif want_min and want_count and want_moments:  # and point variances or intensity
            cur = -1
            mx = np.float32(0.0)
            mn = np.float32(0.0)
            k = 0
            a1 = 0.0
            a2 = 0.0
            b1 = 0.0
            b2 = 0.0
            bi = 0.0
            for j in range(m):
                c = idx[j]
                if c < clo or c >= chi:
                    continue
                zf = zb[j]
                d = np.float64(zf) - z0
                iv = 1.0 / var[s + j] if use_var else 0.0
                it = np.float64(ib[j]) if with_int else 0.0
                if c == cur:
                    mx = max(mx, zf)
                    mn = min(mn, zf)
                    k += 1
                    a1 += d
                    a2 += d * d
                    b1 += iv
                    b2 += iv * d
                    bi += it
                    continue
                if cur >= 0:
                    zmax[cur] = max(zmax[cur], mx)
                    zmin[cur] = min(zmin[cur], mn)
                    count[cur] += k
                    s1[cur] += a1
                    s2[cur] += a2
                    if use_var:
                        i1[cur] += b1
                        i2[cur] += b2
                    if with_int:
                        isum[cur] += bi
                cur = c
                mx = zf
                mn = zf
                k = 1
                a1 = d
                a2 = d * d
                b1 = iv
                b2 = iv * d
                bi = it
            if cur >= 0:
                zmax[cur] = max(zmax[cur], mx)
                zmin[cur] = min(zmin[cur], mn)
                count[cur] += k
                s1[cur] += a1
                s2[cur] += a2
                if use_var:
                    i1[cur] += b1
                    i2[cur] += b2
                if with_int:
                    isum[cur] += bi
        else:  # a subset of the statistics: point by point
            for j in range(m):
                c = idx[j]
                if c < clo or c >= chi:
                    continue
                zf = zb[j]
                zmax[c] = max(zmax[c], zf)
                if want_min:
                    zmin[c] = min(zmin[c], zf)
                if want_count:
                    count[c] += 1
                d = np.float64(zf) - z0
                if want_moments:
                    s1[c] += d
                    s2[c] += d * d
                if use_var:
                    iv = 1.0 / var[s + j]
                    i1[c] += iv
                    i2[c] += iv * d
                if with_int:
                    isum[c] += np.float64(ib[j])


def _finish_kernel(acc, clo, chi, block, z0, want_min, want_count, want_moments, rezero,
                   mean, variance, mvar, wmean, inten):
    """The layers of cells ``clo <= c < chi`` from their sums, as :func:`_finish` does (NaN where
    no point fell), a block of cells at a time in loops the compiler vectorises. ``acc`` =
    (zmax, zmin, count, s1, s2, i1, i2, isum); dem, min and count are finished in place, and
    with ``rezero`` the float64 sums are zeroed again for the next call (while in cache)."""
    zmax, zmin, count, s1, s2, i1, i2, isum = acc
    nan = np.float32(np.nan)
    use_var = i1.shape[0] > 0
    with_int = isum.shape[0] > 0
    for b0 in range(clo, chi, block):
        b1 = min(chi, b0 + block)
        m = b1 - b0
        zm = zmax[b0:b1]
        if not want_count:  # dem (and min) only: a cell is empty while its max is -inf
            for j in range(m):
                zm[j] = nan if zm[j] == -np.inf else zm[j]
            if want_min:
                zn = zmin[b0:b1]
                for j in range(m):
                    zn[j] = nan if zn[j] == np.inf else zn[j]
            continue
        ct = count[b0:b1]
        for j in range(m):
            zm[j] = nan if ct[j] == 0 else zm[j]
        if want_min:
            zn = zmin[b0:b1]
            for j in range(m):
                zn[j] = nan if ct[j] == 0 else zn[j]
        if want_moments:
            t1 = s1[b0:b1]
            t2 = s2[b0:b1]
            me = mean[b0:b1]
            va = variance[b0:b1]
            for j in range(m):
                nk = np.float64(ct[j])
                md = t1[j] / nk
                v = t2[j] / nk - md * md
                me[j] = nan if ct[j] == 0 else np.float32(md + z0)
                va[j] = nan if ct[j] == 0 else np.float32(max(v, 0.0))  # rounding can leave -1e-20
        if use_var:
            u1 = i1[b0:b1]
            u2 = i2[b0:b1]
            mv = mvar[b0:b1]
            wm = wmean[b0:b1]
            for j in range(m):
                mv[j] = nan if ct[j] == 0 else np.float32(1.0 / u1[j])
                wm[j] = nan if ct[j] == 0 else np.float32(u2[j] / u1[j] + z0)
        if with_int:
            u = isum[b0:b1]
            it = inten[b0:b1]
            for j in range(m):
                it[j] = nan if ct[j] == 0 else np.float32(u[j] / np.float64(ct[j]))
        if rezero:
            for q in (s1, s2, i1, i2, isum):  # the same type: a homogeneous tuple
                if q.shape[0] > 0:
                    u = q[b0:b1]
                    for j in range(m):
                        u[j] = 0.0


_compiled: dict[str, Any] = {}  # the compiled kernels, made on first use (importing numba takes ~0.3 s)
_compile_lock = threading.Lock()
_pool_made: list[ThreadPoolExecutor] = []  # the worker that takes the second part of the grid


def _pool() -> ThreadPoolExecutor:
    with _compile_lock:
        if not _pool_made:
            _pool_made.append(ThreadPoolExecutor(max_workers=1, thread_name_prefix="dem_import"))
    return _pool_made[0]


def _kernels() -> dict[str, Any] | None:
    """numba's compiled kernels (compiled once per installation, then loaded from numba's cache),
    or None when numba is missing. Division follows IEEE (``error_model="numpy"``): no check for
    zero in the loops, which would keep them from vectorising; no divisor can be zero here
    (cell > 0, point variances > 0, and empty cells are overwritten with NaN)."""
    if not HAVE_NUMBA:
        return None
    with _compile_lock:
        if not _compiled:
            for name, fn in (("accumulate", _accumulate_kernel), ("finish", _finish_kernel)):
                _compiled[name] = jit(fn, error_model="numpy")
    return _compiled


def warm_up() -> None:
    """Compile (or load from numba's cache) the kernels now rather than in the first import:
    float32 and float64 points (N x 3 and N x 4 share a kernel), with every option."""
    if _kernels() is None:
        return
    for dtype in (np.float32, np.float64):
        pts = np.zeros((4, 4), dtype)
        pts[:, :2] = [[0.01, 0.01], [0.03, 0.01], [0.5, 0.5], [0.01, 0.03]]
        _import_numba(pts, np.ones(4), None, 0.02, None, (0.4, 0.4, 0.6, 0.6), 0.1, LAYERS, CHUNK)


def _choose(pts: np.ndarray) -> str:
    if IMPL == "numba" and pts.dtype in (np.float32, np.float64) and _kernels() is not None:
        return "numba"
    return "numpy"


def _import_numba(pts: np.ndarray, var: np.ndarray | None, geometry: GridGeometry | None, cell: float,
                  bounds: Sequence[float] | None, rover_mask: np.ndarray | Sequence[float] | None,
                  rover_ground_z: float | None, stats: Sequence[str], chunk: int) -> Layers:
    """The compiled implementation: the layers of :func:`_import_numpy` in one pass."""
    kern = _kernels()
    assert kern is not None
    z0 = None
    if geometry is None and bounds is None:
        if not len(pts):
            raise ValueError("no points and no geometry or bounds to make an empty grid")
        lo, hi = _extremes(pts)
        if not (np.all(np.isfinite(lo[:3])) and np.all(np.isfinite(hi[:3]))):
            finite = pts[np.all(np.isfinite(pts[:, :3]), axis=1)]
            if not len(finite):
                raise ValueError("no points and no geometry or bounds to make an empty grid")
            lo, hi = _extremes(finite)
        geometry = _grid_holding(pts.dtype, lo, hi, cell)
        z0 = float(0.5 * (lo[2] + hi[2]))  # as the numpy implementation
    elif geometry is None:
        geometry = geometry_for(pts, cell, bounds)
    g = geometry
    h, w = g.shape
    ncell = h * w
    # cell_of computes in the dtype numpy gives (x - xmin) / cell: the points' own for Python
    # floats, float64 for float32 points and numpy float64 numbers in the geometry; so does the kernel
    adt = np.result_type((pts[:0, 0] - g.xmin) / g.cell, (g.ymax - pts[:0, 1]) / g.cell)
    if ncell >= 2**31 or adt not in (np.float32, np.float64):  # int32 cell indices only
        return _import_numpy(pts, var, g, cell, bounds, rover_mask, rover_ground_z, stats, chunk)
    kp = np.ascontiguousarray(pts, dtype=adt)
    # rover_ground_z compares as numpy compares it with the points' heights (a Python float: in
    # the points' dtype)
    ground32 = bool(rover_ground_z is not None and np.result_type(pts.dtype, rover_ground_z) == np.float32)
    if z0 is None:  # a reference height amid the data, for the precision of the sums of squares
        zs = kp[:: max(1, len(kp) // 4096), 2].astype(np.float64)
        zs = zs[np.isfinite(zs)]
        z0 = float(0.5 * (zs.min() + zs.max())) if len(zs) else 0.0

    want_min = "min" in stats
    want_moments = "mean" in stats or "variance" in stats
    want_count = "count" in stats or want_moments or var is not None or pts.shape[1] == 4
    with_intensity = pts.shape[1] == 4
    f32 = np.float32
    none32, none64 = np.empty(0, f32), np.empty(0)
    # zmax, zmin, count, s1, s2 (sum d, sum d^2), i1, i2 (sum 1/s^2, sum d/s^2), isum; those not
    # wanted are empty (the kernels' types stay the same)
    kept, sums = _sums(2 * want_moments + 2 * (var is not None) + with_intensity, ncell)
    rows = iter(sums)
    acc = (np.full(ncell, -np.inf, f32), np.full(ncell, np.inf, f32) if want_min else none32,
           np.zeros(ncell if want_count else 0, np.int32),
           next(rows) if want_moments else none64, next(rows) if want_moments else none64,
           next(rows) if var is not None else none64, next(rows) if var is not None else none64,
           next(rows) if with_intensity else none64)
    mean = np.empty(ncell, f32) if want_moments else none32
    variance = np.empty(ncell, f32) if want_moments else none32
    mvar = np.empty(ncell, f32) if var is not None else none32
    wmean = np.empty(ncell, f32) if var is not None else none32
    inten = np.empty(ncell, f32) if with_intensity else none32
    if rover_mask is not None:
        poly = np.ascontiguousarray(_rover_polygon(rover_mask))
        pbox = np.concatenate([poly.min(axis=0), poly.max(axis=0)])
    else:
        poly, pbox = np.empty((0, 2)), np.empty(4)
    block = max(1, min(int(chunk), NUMBA_BLOCK))
    t = kp.dtype.type
    fixed = (block, t(g.xmin), t(g.ymax), t(g.cell), t(w), t(h), w, z0, want_min, want_count, want_moments,
             poly, pbox, rover_ground_z is not None, ground32, float(rover_ground_z or 0.0))
    vv = var if var is not None else none64

    def run(clo: int, chi: int) -> None:
        """Accumulate and finish the cells clo <= c < chi (the threads' parts share no cell)."""
        kern["accumulate"](kp, vv, clo, chi, *fixed, *acc, np.empty(block, np.int32), np.empty(block, f32),
                           np.empty(block if with_intensity else 0, kp.dtype))
        kern["finish"](acc, clo, chi, FINISH_BLOCK, z0, want_min, want_count, want_moments, kept,
                       mean, variance, mvar, wmean, inten)

    n = len(kp)
    split = _split_cell(kp, g) if THREADS > 1 and n >= THREAD_MIN_POINTS and n >= 2 * ncell and _core_free() else 0
    if 0 < split < ncell:
        # two threads, each over all the points but scattering only into its own cells (about
        # half the points each, by a sample): no second set of sums, nothing to merge. If the
        # worker has not started by the time this thread is done, this thread does its part too.
        job = _pool().submit(run, split, ncell)
        run(0, split)
        if job.cancel():
            run(split, ncell)
        else:
            job.result()
    else:
        run(0, ncell)
    if kept:
        _scratch.dirty = False  # zeroed again by the finishing pass

    shape = g.shape
    out = Layers(g, meta={"method": "direct reconstruction (max height per cell)"})
    out["dem"] = acc[0].reshape(shape)
    if want_min:
        out["min"] = acc[1].reshape(shape)
    if not want_count:
        return out
    if "count" in stats:
        out["count"] = acc[2].reshape(shape)
    if "mean" in stats:
        out["mean"] = mean.reshape(shape)
    if "variance" in stats:
        out["variance"] = variance.reshape(shape)
    if var is not None:
        out["measurement_variance"] = mvar.reshape(shape)
        out["wmean"] = wmean.reshape(shape)
    if with_intensity:
        out["intensity"] = inten.reshape(shape)
    return out


_scratch = threading.local()  # per thread: the float64 sums, kept zeroed between calls
SCRATCH_MAX_BYTES = 64 << 20  # ... up to this size (a 500 x 500 grid with all sums: 10 MB)


def _sums(k: int, ncell: int) -> tuple[bool, np.ndarray]:
    """``k`` zeroed float64 rows of ``ncell`` for the sums, and whether they are this thread's
    kept buffer (which the finishing pass zeroes again). Reusing it spares the page faults of
    fresh memory on every call, which cost more than the pass itself on a 100 000-point view."""
    need = k * ncell
    if need * 8 > SCRATCH_MAX_BYTES:
        return False, np.zeros((k, ncell))
    buf = getattr(_scratch, "buf", None)
    if buf is None or len(buf) < need or getattr(_scratch, "dirty", False):
        buf = _scratch.buf = np.zeros(max(need, len(buf) if buf is not None else 0))
    _scratch.dirty = True  # until the finishing pass has zeroed it again
    return True, buf[:need].reshape(k, ncell)


def _core_free() -> bool:
    """Whether another core looks idle (the 1-minute load average, which counts this thread, is
    below the number of cores less a half). On a shared machine a second thread only pays when
    it gets a core to itself: time-sliced with another process it makes the call slower."""
    try:
        return os.getloadavg()[0] < (os.cpu_count() or 1) - 0.5
    except (AttributeError, OSError):  # no load average (Windows): assume a free core
        return True


def _split_cell(pts: np.ndarray, g: GridGeometry) -> int:
    """The flat cell index that splits a sample of the points into halves (0: no split)."""
    sample = pts[:: max(1, len(pts) // 8192)]
    with np.errstate(invalid="ignore"):
        rows, cols = g.cell_of(sample[:, 0], sample[:, 1])
    inside = g.inside(rows, cols)
    if inside.sum() < 2:
        return 0
    flat = rows[inside] * g.width + cols[inside]
    return int(np.median(flat))


def cells_from_bounds(bounds: str | Sequence[float]) -> tuple[float, float, float, float]:
    """Parse ``xmin,ymin,xmax,ymax`` (the CLI's --bounds)."""
    vals = [float(v) for v in bounds.split(",")] if isinstance(bounds, str) else [float(v) for v in bounds]
    if len(vals) != 4 or not all(math.isfinite(v) for v in vals):
        raise ValueError(f"bounds: need four numbers xmin,ymin,xmax,ymax, got {bounds!r}")
    return vals[0], vals[1], vals[2], vals[3]
