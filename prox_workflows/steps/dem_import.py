"""DemImport: direct reconstruction of a DEM from a point cloud (seed 000 sect. 3.3.3, 5.2.2).

Each point goes to the cell that holds it (the nearest grid point, in the thesis's words) and the
cell keeps the greatest height: for a rover a rock's top matters more than the ground it hides,
and a wall seen edge-on should read as tall, not as its mean. Beside that DEM the cell's count,
mean, min and the spread (variance) of its heights are kept, so later steps can tell a flat cell
from one that straddles an edge; with per-point measurement variances (from the ToF noise model)
the cell also gets the fused measurement variance that DemMosaik's ``fuse`` rule weighs by.

Speed is the point of the implementation: a full 24-view scan is millions of points. There is no
per-point Python and no sort; the points are streamed in chunks small enough to stay in cache,
and every statistic is one scatter of a chunk into a grid-sized accumulator with numpy's
``ufunc.at`` (whose contiguous fast path runs at bincount speed since numpy 1.25):

* max and min: ``np.maximum.at`` / ``np.minimum.at`` (exact, order-independent);
* count: ``np.add.at`` of ones;
* sum and sum of squares in one complex128 ``np.add.at`` (real = d, imaginary = d^2, with d the
  height relative to the cloud's mid height, in float64, so E[d^2] - E[d]^2 keeps its precision
  for millimetre spreads on metre-scale terrain);
* with point variances, information 1/s^2 and information-weighted height in a second complex
  scatter.

Cell assignment is exactly :meth:`GridGeometry.cell_of`'s arithmetic (same expression, same
dtype), so points on a cell border land where ``cell_of`` says, whatever the input precision.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..grid import GridGeometry, Layers

CHUNK = 1 << 16  # points per chunk: index, heights and weights of one chunk stay in L2 cache

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
    column ``intensity``, its mean. ``stats`` names the layers wanted of the first five (each
    costs a pass over the points; ``("dem",)`` is the bare direct reconstruction).
    """
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


def cells_from_bounds(bounds: str | Sequence[float]) -> tuple[float, float, float, float]:
    """Parse ``xmin,ymin,xmax,ymax`` (the CLI's --bounds)."""
    vals = [float(v) for v in bounds.split(",")] if isinstance(bounds, str) else [float(v) for v in bounds]
    if len(vals) != 4 or not all(math.isfinite(v) for v in vals):
        raise ValueError(f"bounds: need four numbers xmin,ymin,xmax,ymax, got {bounds!r}")
    return vals[0], vals[1], vals[2], vals[3]
