"""Map matching: where a local DEM lies on a reference DEM (seed 000 fig. 24: the rover's DEM
matched to the global map to find the rover on it).

Dead reckoning drifts (wheel slip, heading drift) without bound; a DEM the rover has just made
around itself, placed with the drifted pose, is the same terrain the orbiter mapped, shifted
and turned by exactly that drift. Matching the two heights bounds the drift by the match's
accuracy, whatever distance was driven. The same function registers two of the rover's own DEMs
(a scan against the previous leg's), which is surface-based visual odometry: relative, so it
drifts, but far more slowly than the wheels.

Method: height-map correlation over (x, y, yaw), then least squares. The local DEM is reduced
to block means on a sampling grid (a coarse reference cannot show finer detail, and fewer
points make the search cheap); each candidate rigid motion about the rover's believed position
samples the reference bilinearly under the moved points; the unknown height offset (the DEM's
z is relative to the rover's own ground) and a small tilt are removed by fitting them to the
residuals. The tilt is there because a rover's DEM is placed with its IMU's attitude, whose
error at rest is a bias of a tenth of a degree or so shared by the frames of one stand: on a
slope a tilt mimics a shift, 23 cm of it on the simulated Mars yard from a 0.1 deg bias. The
tilt is held to that bias by a prior (``tilt_sigma``), so a yaw error on a slope, which turns
the slope's own gradient, is not absorbed as tilt. The best candidate of the grid search
seeds a robust Gauss-Newton refinement (residuals beyond 3 MADs, rocks the orbiter cannot see,
are dropped), whose covariance, inflated for residuals that are correlated over a reference
cell, is the estimate's sigma.

Pure functions on arrays; the server (``rvs_server.navigation.localiser``) decides when to call them and
what to do with the answer.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from rvs_params.deferred import deferred
from rvs_params.hazard import UNDEFINED

from ..grid import GridGeometry, Layers

ndimage = deferred("scipy.ndimage")

# The prior on the tilt between a rover's DEM and the reference (rise per metre, 0.3 deg): an
# IMU's bias at rest is a tenth of a degree or two, and a wider prior lets a yaw error on a slope
# (which turns the slope's gradient) pass as tilt.
TILT_SIGMA = math.tan(math.radians(0.3))


@dataclass(frozen=True)
class MatchResult:
    """The rigid motion that puts the local DEM onto the reference: a point p of the local DEM
    lies at ``R(dyaw) (p - pivot) + pivot + (dx, dy)`` on the reference, and ``dz`` above it.

    For a local DEM placed with the believed pose (x, y, heading) and ``pivot`` = (x, y), the
    corrected pose is (x + dx, y + dy, heading + dyaw)."""

    dx: float
    dy: float
    dyaw: float  # deg, counter-clockwise
    dz: float
    rms: float  # residual height rms at the match (m), over the points kept
    rms_before: float  # the same at zero motion: how much the match explains
    sigma_xy: float  # 1-sigma of the position along its worst direction (m)
    sigma_yaw: float  # deg
    points: int  # sample points used
    ok: bool  # refined inside the search window with a usable sigma
    reason: str = ""
    seconds: float = 0.0
    # the local DEM's rise over the reference per metre along x and y (from the pivot): the
    # attitude error its frames were placed with
    tilt_x: float = 0.0
    tilt_y: float = 0.0


def sample_points(dem: np.ndarray, geom: GridGeometry, pivot: tuple[float, float], radius: float,
                  step: float, min_share: float = 0.3) -> np.ndarray:
    """Block means of ``dem`` on cells of ``step`` metres within ``radius`` of ``pivot``: an
    (N, 3) array of x, y, z. A block needs ``min_share`` of its cells defined (a block mean over
    a few cells at the edge of the seen ground is noise)."""
    k = max(1, int(round(step / geom.cell)))
    h, w = dem.shape
    H, W = h // k, w // k
    if H == 0 or W == 0:
        return np.zeros((0, 3))
    block = dem[: H * k, : W * k].reshape(H, k, W, k)
    valid = np.isfinite(block)
    count = valid.sum(axis=(1, 3))
    total = np.where(valid, block, 0.0).sum(axis=(1, 3), dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        z = total / count
    keep = count >= max(1, min_share * k * k)
    xs = geom.xmin + (np.arange(W) + 0.5) * k * geom.cell
    ys = geom.ymax - (np.arange(H) + 0.5) * k * geom.cell
    X, Y = np.meshgrid(xs, ys)
    keep &= np.hypot(X - pivot[0], Y - pivot[1]) <= radius
    return np.column_stack([X[keep], Y[keep], z[keep]])


class _Reference:
    """Bilinear heights of the reference DEM at any x, y (NaN outside or next to its holes)."""

    def __init__(self, dem: np.ndarray, geom: GridGeometry, fill: float = 0.1) -> None:
        self.geom = geom
        d = np.array(dem, dtype=np.float64)
        # A rover's DEM has cell-sized holes wherever its points thin out; bilinear heights need
        # four defined neighbours, so each hole would cost the cells around it too. Holes within
        # ``fill`` metres of a height take the nearest one.
        inv = ~np.isfinite(d)
        if inv.any() and not inv.all():
            dist, (ri, ci) = ndimage.distance_transform_edt(inv, return_indices=True)
            near = inv & (dist <= max(1.0, fill / geom.cell))
            d[near] = d[ri[near], ci[near]]
        self.valid = np.isfinite(d).astype(np.float64)
        self.filled = np.where(np.isfinite(d), d, np.nanmean(d) if self.valid.any() else 0.0)

    def __call__(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        g = self.geom
        col = (x - g.xmin) / g.cell - 0.5
        row = (g.ymax - y) / g.cell - 0.5
        coords = np.stack([row.ravel(), col.ravel()])
        z = ndimage.map_coordinates(self.filled, coords, order=1, mode="nearest")
        ok = ndimage.map_coordinates(self.valid, coords, order=1, mode="constant", cval=0.0) > 0.999
        inside = (row.ravel() >= -0.5) & (row.ravel() <= g.height - 0.5) & (col.ravel() >= -0.5) & \
                 (col.ravel() <= g.width - 0.5)
        z[~(ok & inside)] = np.nan
        return z.reshape(np.shape(x))


def _moved(pts: np.ndarray, pivot: tuple[float, float], dx: float, dy: float, dyaw: float) -> tuple[np.ndarray, np.ndarray]:
    c, s = math.cos(math.radians(dyaw)), math.sin(math.radians(dyaw))
    px, py = pts[:, 0] - pivot[0], pts[:, 1] - pivot[1]
    return c * px - s * py + pivot[0] + dx, s * px + c * py + pivot[1] + dy


def _cost(pts: np.ndarray, ref: _Reference, pivot: tuple[float, float], dx: float, dy: float, dyaw: float,
          min_valid: float, tilt_sigma: float) -> float:
    x, y = _moved(pts, pivot, dx, dy, dyaw)
    r = pts[:, 2] - ref(x, y)
    good = np.isfinite(r)
    if good.sum() < max(8, min_valid * len(pts)):
        return math.inf
    return float(_plane_variance(np.where(good, r, 0.0)[None, :], good[None, :], pts, pivot, tilt_sigma)[0])


def _plane_variance(R: np.ndarray, good: np.ndarray, pts: np.ndarray, pivot: tuple[float, float],
                    tilt_sigma: float) -> np.ndarray:
    """Per candidate (rows of ``R``, the residuals, 0 where not ``good``), the residuals'
    variance about the offset and tilt that fit them best, the tilt weighed by its prior: with
    the residuals' own variance s2 about their mean, the MAP estimate of the tilt under a prior of
    ``tilt_sigma`` (rise per metre) is a ridge regression of weight s2 / tilt_sigma^2. The cost
    adds that prior's term, so a candidate that needs a steep tilt pays for it. 0: the mean
    alone, no tilt."""
    g = good.astype(np.float64)
    cnt = g.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = R.sum(axis=1) / cnt
        s2 = (R * R).sum(axis=1) / cnt - mean * mean
    if tilt_sigma <= 0:
        return s2
    u, v = pts[:, 0] - pivot[0], pts[:, 1] - pivot[1]
    su, sv, suu, suv, svv = g @ u, g @ v, g @ (u * u), g @ (u * v), g @ (v * v)
    lam = np.where(np.isfinite(s2), s2, 0.0) / tilt_sigma ** 2
    N = np.stack([np.stack([cnt, su, sv], -1), np.stack([su, suu + lam, suv], -1),
                  np.stack([sv, suv, svv + lam], -1)], -2)
    b = np.stack([R.sum(axis=1), R @ u, R @ v], -1)
    N[cnt < 3] = np.eye(3)  # no fit: its variance is set apart by the caller's count anyway
    beta = np.linalg.solve(N, b[..., None])[..., 0]
    # the residual sum about the fit plus the prior's penalty: sum R^2 - beta . b (the normal
    # equations with the ridge make the two terms collapse to this)
    rss = (R * R).sum(axis=1) - (beta * b).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.maximum(rss, 0.0) / cnt


def match_dem(local: np.ndarray, local_geom: GridGeometry, reference: np.ndarray, ref_geom: GridGeometry,
              pivot: tuple[float, float], *, search_xy: float = 1.5, search_yaw: float = 8.0,
              step_xy: float | None = None, step_yaw: float = 1.0, sample: float | None = None,
              radius: float = 5.0, min_points: int = 50, max_sigma_xy: float = 0.5,
              tilt_sigma: float = TILT_SIGMA) -> MatchResult:
    """Where ``local`` lies on ``reference`` (both DEMs in one frame, heights up to an offset),
    searched within ``search_xy`` metres and ``search_yaw`` degrees of where it was placed.

    ``sample`` (default: a quarter of the reference cell, at least the local cell) is the block
    size the local DEM is reduced to; ``step_xy`` (default: half a reference cell, at most
    0.25 m) the grid search's step. A match whose refinement leaves the window, or whose sigma
    exceeds ``max_sigma_xy`` (flat or featureless ground: the heights do not say where), is
    returned with ``ok`` false, for the caller to keep its own estimate. Near the reference's
    edge the window narrows (halving ``search_xy``) until enough points stay on it.
    ``tilt_sigma`` (rise per metre) is the prior on the tilt between the two (0: none fitted)."""
    t0 = time.perf_counter()
    sample = sample or max(local_geom.cell, min(ref_geom.cell / 4.0, 0.25))
    step_xy = step_xy or min(ref_geom.cell / 2.0, 0.25)
    pts = sample_points(local, local_geom, pivot, radius, sample)
    pts = pts[np.isfinite(pts[:, 2])]
    ref = _Reference(reference, ref_geom)
    # Residuals are correlated over a reference cell (and over the local DEM's own footprint of a
    # rock): count independent samples, not points. The tilt's prior, set against the points'
    # residuals, weighs as much more (without, the match fitted 0.23 deg of tilt the hirise
    # patch did not have, and moved 2.5 cm off for it).
    per_cell = max(1.0, (max(ref_geom.cell, sample) / sample) ** 2)
    tilt_prior = tilt_sigma / math.sqrt(per_cell)

    def fail(reason: str, **kw: float) -> MatchResult:
        base = {"dx": 0.0, "dy": 0.0, "dyaw": 0.0, "dz": 0.0, "rms": math.nan, "rms_before": math.nan,
                "sigma_xy": math.inf, "sigma_yaw": math.inf}
        return MatchResult(**{**base, **kw}, points=len(pts), ok=False, reason=reason,
                           seconds=time.perf_counter() - t0)

    if len(pts) < min_points:
        return fail(f"{len(pts)} sample points, fewer than {min_points}")
    # Only points the reference shows under every candidate motion: where the overlap itself
    # changes with the motion (a scan on the previous scan's edge), a variance over whichever
    # points fall on defined ground would prefer motions that put them on its smoothest part.
    # The extremes of the window (corners, edges, the turn both ways) stand for the whole.
    def usable(search: float) -> np.ndarray:
        common = np.ones(len(pts), bool)
        for yaw in (-search_yaw, 0.0, search_yaw):
            for ox in (-search, 0.0, search):
                for oy in (-search, 0.0, search):
                    x, y = _moved(pts, pivot, ox, oy, yaw)
                    common &= np.isfinite(ref(x, y))
        return common

    common = usable(search_xy)
    # Near the reference's edge a wide window leaves too few such points: a narrower one still
    # matches when the offset lies inside it, and fails safely (the refinement leaves the
    # window) when it does not.
    while common.sum() < min_points and search_xy / 2.0 >= 2.0 * step_xy:
        search_xy /= 2.0
        common = usable(search_xy)
    if common.sum() < min_points:
        return fail(f"{int(common.sum())} points on ground the reference shows under every motion searched, "
                    f"fewer than {min_points}")
    pts = pts[common]
    before = _cost(pts, ref, pivot, 0.0, 0.0, 0.0, 0.5, tilt_prior)
    # grid search: every yaw, every offset, vectorised over the points of one yaw at a time
    offs = np.arange(-search_xy, search_xy + 1e-9, step_xy)
    yaws = np.arange(-search_yaw, search_yaw + 1e-9, step_yaw)
    best = (math.inf, 0.0, 0.0, 0.0)
    DX, DY = np.meshgrid(offs, offs, indexing="ij")
    n = len(pts)
    for yaw in yaws:
        x, y = _moved(pts, pivot, 0.0, 0.0, float(yaw))
        Z = ref(x[None, :] + DX.ravel()[:, None], y[None, :] + DY.ravel()[:, None])  # (candidates, n)
        R = pts[None, :, 2] - Z
        good = np.isfinite(R)
        cnt = good.sum(axis=1)
        var = _plane_variance(np.where(good, R, 0.0), good, pts, pivot, tilt_prior)
        var[cnt < max(8, 0.5 * n)] = np.inf
        i = int(np.argmin(var))
        if var[i] < best[0]:
            best = (float(var[i]), float(DX.ravel()[i]), float(DY.ravel()[i]), float(yaw))
    if not math.isfinite(best[0]):
        return fail("the local DEM lies outside the reference", rms_before=math.sqrt(before)
                    if math.isfinite(before) else math.nan)

    # robust Gauss-Newton refinement from the grid's best, with the height offset and the tilt
    # along x and y as unknowns 4-6 (the tilt's prior as two more residuals, scaled by the
    # residuals' sigma so that it weighs as in the grid search)
    p = np.array([best[1], best[2], best[3], 0.0, 0.0, 0.0])
    x, y = _moved(pts, pivot, p[0], p[1], p[2])
    p[3] = float(np.nanmedian(pts[:, 2] - ref(x, y)))
    keep = np.ones(n, bool)
    u, v = pts[:, 0] - pivot[0], pts[:, 1] - pivot[1]
    fit_tilt = tilt_sigma > 0
    prior_w = math.sqrt(max(best[0], 1e-6)) / tilt_prior if fit_tilt else 0.0

    def residuals(q: np.ndarray, idx: np.ndarray) -> np.ndarray:
        xq, yq = _moved(pts[idx], pivot, q[0], q[1], q[2])
        r = pts[idx, 2] - ref(xq, yq) - q[3]
        r = np.where(np.isfinite(r), r, 0.0)
        if not fit_tilt:
            return r
        return np.concatenate([r - q[4] * u[idx] - q[5] * v[idx], prior_w * q[4:6]])

    # imported here: the server and the CLIs start without scipy.optimize (0.2-0.3 s)
    from scipy import optimize

    sol = None
    unknowns = 6 if fit_tilt else 4
    for _ in range(3):
        idx = np.flatnonzero(keep)
        sol = optimize.least_squares(residuals, p[:unknowns], args=(idx,), method="lm",
                                     x_scale=[0.1, 0.1, 0.5, 0.05, 0.005, 0.005][:unknowns])
        p[:unknowns] = sol.x
        xa, ya = _moved(pts, pivot, p[0], p[1], p[2])
        r_all = pts[:, 2] - ref(xa, ya) - p[3] - p[4] * u - p[5] * v
        fin = np.isfinite(r_all)
        med = float(np.median(r_all[fin]))
        mad = 1.4826 * float(np.median(np.abs(r_all[fin] - med))) + 1e-4
        new_keep = fin & (np.abs(r_all - med) <= 3.0 * mad)
        if np.array_equal(new_keep, keep):
            break
        keep = new_keep
    assert sol is not None
    idx = np.flatnonzero(keep)
    m = len(idx)
    r = residuals(sol.x, idx)[:m]
    rms = float(np.sqrt(np.mean(r ** 2))) if m else math.nan
    J = sol.jac
    try:
        cov = np.linalg.inv(J.T @ J) * (rms ** 2)
    except np.linalg.LinAlgError:
        return fail("singular match (featureless ground)", rms=rms, rms_before=math.sqrt(before))
    cov *= per_cell  # independent samples, not points (above)
    sigma_xy = float(math.sqrt(max(np.linalg.eigvalsh(cov[:2, :2]).max(), 0.0)))
    sigma_yaw = float(math.sqrt(max(cov[2, 2], 0.0)))
    # a floor: no match places a DEM of block means better than a fifth of a block (the formal
    # covariance of thousands of points says millimetres, which no neighbour's fusion should trust)
    sigma_xy = max(sigma_xy, 0.2 * sample)
    sigma_yaw = max(sigma_yaw, math.degrees(0.2 * sample / max(radius, 1.0)))
    out = MatchResult(float(p[0]), float(p[1]), float(p[2]), float(p[3]), rms,
                      math.sqrt(before) if math.isfinite(before) else math.nan, sigma_xy, sigma_yaw, m,
                      ok=True, seconds=time.perf_counter() - t0, tilt_x=float(p[4]), tilt_y=float(p[5]))
    margin = 0.5 * step_xy
    if abs(p[0]) > search_xy + margin or abs(p[1]) > search_xy + margin or abs(p[2]) > search_yaw + step_yaw:
        return MatchResult(**{**out.__dict__, "ok": False, "reason": "the best match lies outside the search window"})
    if not sigma_xy <= max_sigma_xy:
        return MatchResult(**{**out.__dict__, "ok": False,
                              "reason": f"sigma {sigma_xy:.2f} m above {max_sigma_xy:g} m (the ground does not say where)"})
    return out


def transform_layers(layers: Layers, pivot: tuple[float, float], dx: float, dy: float, dyaw: float) -> Layers:
    """The layers moved by the rigid motion of a match (rotation ``dyaw`` about ``pivot``, then
    ``dx, dy``), resampled nearest-neighbour onto the same grid: a DEM placed with a drifted pose
    becomes one placed with the corrected pose, so the plan made on it and the corrected pose
    agree. Cells moved in from outside the grid are undefined (:func:`undefined_fill`)."""
    g = layers.geometry
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    # inverse motion: where each output cell came from
    c, s = math.cos(math.radians(-dyaw)), math.sin(math.radians(-dyaw))
    ux, uy = X - pivot[0] - dx, Y - pivot[1] - dy
    sx, sy = c * ux - s * uy + pivot[0], s * ux + c * uy + pivot[1]
    row, col = g.cell_of(sx, sy)
    inside = g.inside(row, col)
    rr, cc = np.clip(row, 0, g.height - 1), np.clip(col, 0, g.width - 1)
    out = Layers(g, meta=dict(layers.meta))
    for name, arr in layers.layers.items():
        moved = arr[rr, cc]
        if arr.ndim == 3:
            moved[~inside] = 0
        else:
            moved = np.where(inside, moved, undefined_fill(arr)).astype(arr.dtype)
        out.layers[name] = moved
    return out


def undefined_fill(arr: np.ndarray) -> np.ndarray:
    """The fill of an undefined cell of a layer: NaN, the hazard map's UNDEFINED for a uint8 map, 0 else."""
    if np.issubdtype(arr.dtype, np.floating):
        return np.asarray(np.nan, arr.dtype)
    return np.asarray(UNDEFINED if arr.dtype == np.uint8 and arr.ndim == 2 else 0, arr.dtype)


def overlay_layers(base: Layers | None, top: Layers) -> Layers:
    """``top`` over ``base`` on a grid covering both (same cell size, grids aligned to multiples
    of it): where the top's DEM is defined its layers win, elsewhere the base's stay. A leg's DEM,
    made alone so its placement could be matched and corrected, joins the maps of the legs before
    it this way (the newest view of a cell wins, as the rover's own drive changes nothing else)."""
    if base is None:
        return top
    gb, gt = base.geometry, top.geometry
    if abs(gb.cell - gt.cell) > 1e-9:
        return top
    g = GridGeometry.covering(min(gb.xmin, gt.xmin), min(gb.ymin, gt.ymin), max(gb.xmax, gt.xmax),
                              max(gb.ymax, gt.ymax), gt.cell, gt.crs)

    def offset(src: GridGeometry) -> tuple[int, int]:
        return int(round((g.ymax - src.ymax) / g.cell)), int(round((src.xmin - g.xmin) / g.cell))

    rb, cb = offset(gb)
    rt, ct = offset(gt)
    defined = np.isfinite(top["dem"]) if "dem" in top else np.ones(gt.shape, bool)
    out = Layers(g, meta=dict(top.meta))
    for name in dict.fromkeys([*base.layers, *top.layers]):
        ref = top.layers.get(name, base.layers.get(name))
        assert ref is not None
        arr = np.full((g.height, g.width, *ref.shape[2:]), undefined_fill(ref), dtype=ref.dtype)
        if name in base.layers:
            b = base.layers[name]
            arr[rb: rb + gb.height, cb: cb + gb.width] = b.astype(ref.dtype, copy=False)
        if name in top.layers:
            t = top.layers[name]
            view = arr[rt: rt + gt.height, ct: ct + gt.width]
            view[defined] = t[defined]
        out.layers[name] = arr
    return out
