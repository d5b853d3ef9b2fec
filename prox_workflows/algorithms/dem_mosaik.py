"""DemMosaik: merge DEMs of different extents and cell sizes into one grid (seed 000 sect. 3.1.4,
4.3.3), by one of three rules:

``max``
    the greatest height wherever any input is defined - direct reconstruction's own rule, so a
    mosaic of views equals the DEM of all their points together (for equal grids);
``newest``
    later inputs overwrite earlier ones where they are defined (a fresh scan replaces the map);
``fuse``
    a per-cell Kalman update (seed 003 eq. 6.1, after ETH elevation_mapping): the prior height h
    with variance s_h^2 and a new measurement p with s_p^2 give
    h+ = (s_p^2 h + s_h^2 p) / (s_h^2 + s_p^2) and s_h^2+ = s_h^2 s_p^2 / (s_h^2 + s_p^2).
    A Mahalanobis gate screens the measurement first: if |p - h| / sqrt(s_h^2 + s_p^2) exceeds
    ``gate``, the two disagree too much to average (a moved object, a wall edge, an outlier).
    With ``on_conflict="inflate"`` (different scans; elevation_mapping's rule between scans)
    the measurement is rejected and the prior's variance grows by ``inflation``, so that a
    change that persists over several scans is accepted once the prior has become uncertain
    enough; with ``on_conflict="higher"`` (views of one scan; elevation_mapping's rule inside
    one point cloud, and direct reconstruction's) the higher of the two wins outright; with
    ``on_conflict="precise"`` (two sensors' DEMs of one scan, each weighed by its own
    calibrated noise model) the one whose variance is smaller wins: the gate has found one of
    them an outlier, and the noise model says which is the likelier one.
    elevation_mapping measures the distance by the prior's variance alone; the innovation's
    variance used here is the textbook Mahalanobis distance and does not reject a noisy but
    consistent measurement just because the prior is already precise.

Inputs are resampled onto the output grid, which is the union of their extents at the finest
input cell size (or ``cell`` / ``geometry`` when given):

* a source cell smaller than the output cell (downsampling): the output cell takes the greatest
  height of the source cells whose centres fall in it (the DEM is a max-height map), with that
  cell's variance, and the sum of their counts;
* a source cell as large or larger (upsampling, or equal but shifted grids): the output cell
  takes the source cell under its centre (nearest neighbour; counts are not re-apportioned).

The variance of an input cell: its ``measurement_variance`` layer (DemImport with per-point noise)
or else ``sigma``^2, plus the spread of the cell's heights (its ``variance`` layer) because the
cell's height is the greatest of its points; a mosaic's own ``variance`` is already the variance
of its height estimate (``meta["variance"] == "estimate"``) and is used as it is.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from rvs_params import Settings, param

from ..grid import GridGeometry, Layers
from ..params import parameters

RULES = ("max", "newest", "fuse")
WINDOW = 5  # cells per side of the neighbourhood fuse_sensors reads (the median a conflict is settled by)
CONFLICTS = ("inflate", "higher", "precise")


@parameters("dem_mosaik")
@dataclass
class DemMosaikParams(Settings):
    """DemMosaik of DEM products into one (``rvs-dem-mosaik``)."""

    rule: str = param("max", "merge rule", choices=RULES)
    cell: float = param(0.0, "output cell size (0: the finest input's)", unit="m", min=0.0, max=100.0)
    sigma: float = param(0.01, "fuse: height sigma of inputs without a measurement variance layer", unit="m",
                         min=1e-6, max=10.0)
    gate: float = param(3.0, "fuse: Mahalanobis gate", min=0.0, max=1000.0)
    inflation: float = param(0.0025, "fuse: variance added to the prior when a measurement is rejected",
                             unit="m^2", min=0.0, max=100.0)
    on_conflict: str = param("inflate", "fuse: reject and inflate (separate scans) or let the higher win "
                             "(views of one scan)", choices=("inflate", "higher"))
    fill: float = param(0.0, "fill holes narrower than a disk of this radius", unit="m", min=0.0, max=100.0)


DEFAULTS = DemMosaikParams()  # what a caller that gives no value gets, here and in the step


def union_geometry(geometries: Sequence[GridGeometry], cell: float | None = None) -> GridGeometry:
    """The grid covering every input, aligned to multiples of ``cell`` (default: the finest)."""
    if not geometries:
        raise ValueError("no inputs")
    cell = min(g.cell for g in geometries) if cell is None else float(cell)
    xmin = min(g.xmin for g in geometries)
    ymin = min(g.ymin for g in geometries)
    xmax = max(g.xmax for g in geometries)
    ymax = max(g.ymax for g in geometries)
    return GridGeometry.covering(xmin, ymin, xmax, ymax, cell, common_crs(geometries))


def common_crs(geometries: Sequence[GridGeometry]) -> str | None:
    """The CRS the inputs share (None: the local frame); DEMs in different CRSs are refused,
    since merging them cell by cell would put one's eastings on the other's."""
    named = {g.crs for g in geometries if g.crs is not None}
    if len(named) > 1:
        raise ValueError(f"the DEMs are in different CRSs ({', '.join(sorted(named))}): reproject them first")
    return named.pop() if named else None


def input_variance(layers: Layers, sigma: float = DEFAULTS.sigma) -> np.ndarray:
    """Per-cell height variance of one input (see the module doc), float64, NaN where undefined."""
    if layers.meta.get("variance") == "estimate" and "variance" in layers:
        return np.asarray(layers["variance"], dtype=np.float64)
    if "measurement_variance" in layers:
        v = np.asarray(layers["measurement_variance"], dtype=np.float64).copy()
    else:
        v = np.full(layers.geometry.shape, float(sigma) ** 2)
    if "variance" in layers:
        spread = np.asarray(layers["variance"], dtype=np.float64)
        v += np.where(np.isfinite(spread), spread, 0.0)
    return v


def _aligned_offset(src: GridGeometry, dst: GridGeometry) -> tuple[int, int] | None:
    if not math.isclose(src.cell, dst.cell, rel_tol=1e-9):
        return None
    dc = (src.xmin - dst.xmin) / dst.cell
    dr = (dst.ymax - src.ymax) / dst.cell
    if abs(dc - round(dc)) > 1e-6 or abs(dr - round(dr)) > 1e-6:
        return None
    return int(round(dr)), int(round(dc))


def resample(height: np.ndarray, variance: np.ndarray, count: np.ndarray, src: GridGeometry,
             dst: GridGeometry) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One input's (height, variance, count) on the ``dst`` grid: NaN / 0 where it has nothing."""
    h_out = np.full(dst.shape, np.nan, np.float64)
    v_out = np.full(dst.shape, np.nan, np.float64)
    n_out = np.zeros(dst.shape, np.int64)
    off = _aligned_offset(src, dst)
    if off is not None:  # same cell size on the same lattice: a window copy
        r0, c0 = off
        rs0, cs0 = max(0, -r0), max(0, -c0)
        rd0, cd0 = max(0, r0), max(0, c0)
        nr = min(src.height - rs0, dst.height - rd0)
        nc = min(src.width - cs0, dst.width - cd0)
        if nr > 0 and nc > 0:
            sd = (slice(rd0, rd0 + nr), slice(cd0, cd0 + nc))
            ss = (slice(rs0, rs0 + nr), slice(cs0, cs0 + nc))
            h_out[sd] = height[ss]
            v_out[sd] = variance[ss]
            n_out[sd] = count[ss]
        return h_out, v_out, n_out
    if src.cell < dst.cell * (1 - 1e-9):  # downsampling: greatest height of the cells inside
        defined = np.isfinite(height)
        r, c = np.nonzero(defined)
        xs, ys = src.centers()
        tr, tc = dst.cell_of(xs[c], ys[r])
        inside = dst.inside(tr, tc)
        r, c, tr, tc = r[inside], c[inside], tr[inside], tc[inside]
        flat = tr * dst.width + tc
        h = height[r, c].astype(np.float64)
        hf = np.full(dst.height * dst.width, -np.inf)
        np.maximum.at(hf, flat, h)
        is_top = h == hf[flat]  # the source cells that hold the maximum give its variance
        vf = np.full(dst.height * dst.width, np.inf)
        np.minimum.at(vf, flat[is_top], variance[r[is_top], c[is_top]].astype(np.float64))
        nf = np.zeros(dst.height * dst.width, np.int64)
        np.add.at(nf, flat, count[r, c].astype(np.int64))
        got = np.isfinite(hf)
        h_out.reshape(-1)[got] = hf[got]
        v_out.reshape(-1)[got] = vf[got]
        n_out.reshape(-1)[:] = nf
        return h_out, v_out, n_out
    # upsampling or a shifted lattice: the source cell under each output cell's centre
    xs, ys = dst.centers()
    sr, _ = src.cell_of(np.zeros_like(ys), ys)
    _, sc = src.cell_of(xs, np.zeros_like(xs))
    rin = (sr >= 0) & (sr < src.height)
    cin = (sc >= 0) & (sc < src.width)
    if rin.any() and cin.any():
        block = np.ix_(np.flatnonzero(rin), np.flatnonzero(cin))
        sub = np.ix_(sr[rin], sc[cin])
        h_out[block] = height[sub]
        v_out[block] = variance[sub]
        n_out[block] = count[sub]
    return h_out, v_out, n_out


def resample_nearest(image: np.ndarray, src: GridGeometry, dst: GridGeometry, fill: Any = np.nan) -> np.ndarray:
    """A layer of one grid on another, nearest cell (for layers that must not be blended)."""
    xs, ys = dst.centers()
    row, col = src.cell_of(np.broadcast_to(xs, dst.shape), np.broadcast_to(ys[:, None], dst.shape))
    inside = src.inside(row, col)
    out = np.full(dst.shape, fill, dtype=image.dtype)
    out[inside] = image[row[inside], col[inside]]
    return out



def dem_mosaik(
    dems: Sequence[Layers],
    rule: str = DEFAULTS.rule,
    geometry: GridGeometry | None = None,
    cell: float | None = None,
    sigma: float = DEFAULTS.sigma,
    gate: float = DEFAULTS.gate,
    inflation: float = DEFAULTS.inflation,
    on_conflict: str = DEFAULTS.on_conflict,
    height_layer: str = "dem",
) -> Layers:
    """Merge ``dems`` (in order: later = newer) into one Layers: ``dem`` (float32), ``variance``
    (float32, the variance of that height: the Kalman estimate for ``fuse``, the chosen input's
    for ``max`` / ``newest``), ``count`` (int32, points from every input) and ``source`` (int16,
    the index of the input that last set the height; -1 undefined)."""
    if rule not in RULES:
        raise ValueError(f"rule must be one of {', '.join(RULES)}, got {rule!r}")
    if on_conflict not in CONFLICTS:
        raise ValueError(f"on_conflict must be one of {', '.join(CONFLICTS)}, got {on_conflict!r}")
    if gate <= 0 or inflation < 0 or sigma <= 0:
        raise ValueError("gate and sigma must be positive, inflation not negative")
    dems = list(dems)
    if not dems:
        raise ValueError("dem_mosaik needs at least one DEM")
    g = geometry if geometry is not None else union_geometry([d.geometry for d in dems], cell)
    h = np.full(g.shape, np.nan)
    v = np.full(g.shape, np.nan)
    n = np.zeros(g.shape, np.int64)
    src = np.full(g.shape, -1, np.int16)
    rejected = np.zeros(g.shape, np.int32)
    for k, layers in enumerate(dems):
        if height_layer not in layers:
            raise ValueError(f"input {k} has no '{height_layer}' layer (has {', '.join(layers.layers)})")
        height = np.asarray(layers[height_layer])
        count = np.asarray(layers["count"]) if "count" in layers else np.isfinite(height).astype(np.int64)
        hp, vp, np_ = resample(height, input_variance(layers, sigma), count, layers.geometry, g)
        new = np.isfinite(hp)
        n += np_
        empty = new & ~np.isfinite(h)
        if rule == "newest":
            take = new
        elif rule == "max":
            take = empty | (new & (hp > h))
        else:
            take = empty
            both = new & ~empty
            md = np.abs(hp - h) / np.sqrt(v + vp)
            accept = both & (md <= gate)
            conflict = both & ~accept
            ha, va, hpa, vpa = h[accept], v[accept], hp[accept], vp[accept]
            h[accept] = (vpa * ha + va * hpa) / (va + vpa)
            v[accept] = va * vpa / (va + vpa)
            src[accept] = k
            if on_conflict == "inflate":
                v[conflict] += inflation
                rejected[conflict] += 1
            elif on_conflict == "precise":
                take = take | (conflict & (vp < v))
            else:
                take = take | (conflict & (hp > h))
        h[take] = hp[take]
        v[take] = vp[take]
        src[take] = k
    out = Layers(g.with_crs(common_crs([d.geometry for d in dems])),
                 meta={"rule": rule, "variance": "estimate", "inputs": len(dems)})
    out["dem"] = h.astype(np.float32)
    out["variance"] = v.astype(np.float32)
    out["count"] = np.minimum(n, np.iinfo(np.int32).max).astype(np.int32)
    out["source"] = src
    if rule == "fuse" and on_conflict == "inflate":
        out.meta["rejected_cells"] = int((rejected > 0).sum())
    return out


def local_scatter(height: np.ndarray, window: int = WINDOW) -> np.ndarray:
    """The squared deviation (m^2) of each cell's height from the median of the defined heights in
    the ``window`` x ``window`` cells around it (itself included); 0 where it or all of them are
    undefined. Ground is continuous, so a cell far from its neighbours' median is either on an
    edge the cell's sampling cannot place, or wrong."""
    h = np.asarray(height, np.float64)
    r = window // 2
    pad = np.pad(h, r, constant_values=np.nan)
    win = np.lib.stride_tricks.sliding_window_view(pad, (window, window)).reshape(h.shape + (-1,))
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        dev = h - np.nanmedian(win, axis=-1)
    return np.where(np.isfinite(dev), dev * dev, 0.0)


def fuse_sensors(dems: Sequence[Layers], geometry: GridGeometry | None = None, gate: float = DEFAULTS.gate,
                 window: int = WINDOW, sigma: float = DEFAULTS.sigma, scatter: Sequence[float] = (0.0, 0.0)) -> Layers:
    """Fuse the DEMs of two sensors of one scan (a ToF DEM and a stereo DEM) cell by cell.

    Where both see a cell and agree - the Mahalanobis distance |h1 - h2| / sqrt(s1^2 + s2^2)
    within ``gate`` - the height is their information-weighted mean, with the smaller variance
    s1^2 s2^2 / (s1^2 + s2^2): each sensor weighed by its own calibrated noise model, so the
    mean is better than either. Where they disagree one of them is an outlier (a ToF mixed
    pixel or multipath return, a stereo mismatch), and averaging would spread its error over
    both; the one kept is the one the neighbourhood supports: the smaller deviation, in its own
    standard deviations, from the median of the agreed heights in the ``window`` x ``window``
    cells around (errors of one sensor are isolated; the ground is continuous). With no agreed
    neighbour the smaller variance wins. Order-free: swapping the inputs gives the same DEM.
    A cell one sensor alone sees keeps that sensor's height and variance. Layers as
    :func:`dem_mosaik`, with ``meta["conflicts"]`` the number of cells the gate settled.

    ``scatter`` (one coefficient per input) adds each input's own evidence against a cell to
    the variance its noise model gives it before the two are weighed: the coefficient times the
    squared deviation of the cell from the median of that input's cells in the ``window``
    around (:func:`local_scatter`). The per-point models see a point's image, not the cells the
    sensor made of it and its neighbours; a sensor's errors are heavy-tailed (a ToF cell on a
    step the coarse far pixels straddle, a stereo mismatch), and its own map shows them as cells
    off their neighbours, where the model, fitted to the inliers, would still trust them. The
    coefficients are fitted with the models (tools/bench/fusion.py --calibrate)."""
    if len(dems) != 2:
        raise ValueError(f"fuse_sensors takes two DEMs (one per sensor), got {len(dems)}")
    if gate <= 0 or window < 1:
        raise ValueError("gate must be positive and window at least 1")
    if len(scatter) != 2 or min(scatter) < 0:
        raise ValueError(f"scatter takes one coefficient (not negative) per DEM, got {list(scatter)}")
    g = geometry if geometry is not None else union_geometry([d.geometry for d in dems])
    hs, vs, ns = [], [], []
    for layers in dems:
        height = np.asarray(layers["dem"])
        count = np.asarray(layers["count"]) if "count" in layers else np.isfinite(height).astype(np.int64)
        h, v, n = resample(height, input_variance(layers, sigma), count, layers.geometry, g)
        if scatter[len(hs)] > 0:
            v = v + float(scatter[len(hs)]) * local_scatter(h, window)
        hs.append(h)
        vs.append(v)
        ns.append(n)
    (h0, h1), (v0, v1) = hs, vs
    d0, d1 = np.isfinite(h0), np.isfinite(h1)
    both = d0 & d1
    with np.errstate(invalid="ignore", divide="ignore"):
        md = np.abs(h0 - h1) / np.sqrt(v0 + v1)
        mean = (v1 * h0 + v0 * h1) / (v0 + v1)
        vmean = v0 * v1 / (v0 + v1)
    agree = both & (md <= gate)
    conflict = both & ~agree
    h = np.where(agree, mean, np.where(d0 & ~d1, h0, np.where(d1 & ~d0, h1, np.nan)))
    v = np.where(agree, vmean, np.where(d0 & ~d1, v0, np.where(d1 & ~d0, v1, np.nan)))
    src = np.where(agree, 1, np.where(d0 & ~d1, 0, np.where(d1 & ~d0, 1, -1))).astype(np.int16)
    rows, cols = np.nonzero(conflict)
    if rows.size:
        r = window // 2
        pad = np.pad(h, r, constant_values=np.nan)
        win = np.lib.stride_tricks.sliding_window_view(pad, (window, window))[rows, cols].reshape(rows.size, -1)
        with np.errstate(all="ignore"):
            import warnings

            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                ref = np.nanmedian(win, axis=1)
        c0 = np.abs(h0[rows, cols] - ref) / np.sqrt(v0[rows, cols])
        c1 = np.abs(h1[rows, cols] - ref) / np.sqrt(v1[rows, cols])
        first = np.where(np.isfinite(ref), c0 <= c1, v0[rows, cols] <= v1[rows, cols])
        h[rows, cols] = np.where(first, h0[rows, cols], h1[rows, cols])
        v[rows, cols] = np.where(first, v0[rows, cols], v1[rows, cols])
        src[rows, cols] = np.where(first, 0, 1)
    out = Layers(g.with_crs(common_crs([d.geometry for d in dems])),
                 meta={"rule": "fuse_sensors", "variance": "estimate", "inputs": 2, "conflicts": int(rows.size)})
    out["dem"] = h.astype(np.float32)
    out["variance"] = v.astype(np.float32)
    out["count"] = np.minimum(ns[0] + ns[1], np.iinfo(np.int32).max).astype(np.int32)
    out["source"] = src
    return out
