"""Where the rover was set down: the plane of the ground round it, for the ground no sensor shows,
and how far that ground may stand off the plane.

The mast's blind disc (about 0.7 m round its foot) is never seen, and the rover must drive out
of it. A prior there taken level meets sloped seen ground in a step at the disc's edge (12 cm on
a 10 deg slope), which the vehicle check refuses at every pose that straddles it; the plane the
wheels rest on (the IMU's) tips with a rock under one wheel. The ring of seen ground just
outside the disc says how the ground round the rover runs: :func:`ring_plane` fits it.

A plane says where the ground runs, not that it lies on it: on the simulated scenes' true 1 cm
surfaces the ring's cells stand 2-3.7 cm (sd, rocks included) off their plane in marsyard,
hirise and dense alike, and the disc's ground 10 cm patches reach 4-10 cm off it (below it under
a wheel at dense mission 0's start, which the check then judged on a wheel 5 cm too high). So
the disc's ground is the plane within the ring's own spread (:meth:`RingPlane.sigma`: the
ring's cells' spread about the plane, rocks included, as likely in the disc as in the ring, and
the fit's error where it is extrapolated to), never a fixed sigma the ring does not show.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rvs_params.deferred import deferred

from .chance import prior_correlation
from .vehicle import reach

ndimage = deferred("scipy.ndimage")

__all__ = ["RingPlane", "ring_plane", "set_down", "FLOOR", "MIN_CELLS"]

MIN_CELLS = 50  # seen cells in the ring below which the plane is not fitted (level instead)
OUTLIER = 0.02  # m: cells further than this (or twice the residuals' sd) from the first fit are rocks
CONDITION_REACH = 0.4  # m round the unknown ground: the known cells that may condition it (the correlation is nil by 0.4 m)
FLOOR = 0.01  # m: the least sigma unseen ground is taken within, however smooth the ring: a hollow or a
# rock wholly inside the disc leaves no trace in the ring


@dataclass(frozen=True)
class RingPlane:
    """The plane z = z0 + gx (x - at_x) + gy (y - at_y) of the ring of seen ground round the blind
    disc, the spread of the ring's cells about it (m, sd, rocks included; inf: too few cells seen
    to say), the covariance of (z0, gx, gy) from the fit, and a sentence saying what it took."""

    z0: float
    gx: float
    gy: float
    at: tuple[float, float]
    spread: float
    said: str
    cov: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))

    @property
    def known(self) -> bool:
        """Whether the ring was seen enough to say anything of the disc's ground."""
        return math.isfinite(self.spread)

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return self.z0 + self.gx * (np.asarray(x) - self.at[0]) + self.gy * (np.asarray(y) - self.at[1])

    def sigma(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """How far the unseen ground at (x, y) may stand off the plane (1 sd): the ring's spread
        (what the ground round the rover does about its plane, rocks and dips alike) and the fit's
        own error there (it grows with the distance from the ring's centroid), never below
        :data:`FLOOR`."""
        dx, dy = np.asarray(x, np.float64) - self.at[0], np.asarray(y, np.float64) - self.at[1]
        c = self.cov
        fit = (c[0, 0] + 2 * c[0, 1] * dx + 2 * c[0, 2] * dy + c[1, 1] * dx * dx + 2 * c[1, 2] * dx * dy
               + c[2, 2] * dy * dy)
        return np.maximum(np.sqrt(self.spread**2 + np.maximum(fit, 0.0)), FLOOR)


def _level(said: str) -> RingPlane:
    return RingPlane(0.0, 0.0, 0.0, (0.0, 0.0), math.inf, said)


def ring_plane(bounds: Any, centre: tuple[float, float], inner: float, outer: float, at: tuple[float, float]
               ) -> RingPlane:
    """The plane fitted to the frames' mean heights of the bounds map's cells between ``inner`` and
    ``outer`` metres from ``centre`` (cells a frame bounded; rocks dropped from the fit as outliers
    of a first one, kept in the spread), expressed about ``at``. With fewer than
    :data:`MIN_CELLS` such cells: level at 0 (the frames' datum, the rover's own ground) and an
    unknown spread."""
    g = bounds.geometry
    c0 = max(0, int(math.floor((centre[0] - outer - g.xmin) / g.cell)))
    c1 = min(g.width, int(math.ceil((centre[0] + outer - g.xmin) / g.cell)))
    r0 = max(0, int(math.floor((g.ymax - centre[1] - outer) / g.cell)))
    r1 = min(g.height, int(math.ceil((g.ymax - centre[1] + outer) / g.cell)))
    if r1 <= r0 or c1 <= c0:
        return _level("level ground (the map does not reach round the rover)")
    rows, cols = np.mgrid[r0:r1, c0:c1]
    xs = g.xmin + (cols + 0.5) * g.cell
    ys = g.ymax - (rows + 0.5) * g.cell
    dist = np.hypot(xs - centre[0], ys - centre[1])
    z = bounds.mean[r0:r1, c0:c1].astype(np.float64)
    use = (dist >= inner) & (dist <= outer) & np.isfinite(z) & (bounds.stamp[r0:r1, c0:c1] > 0)
    if use.sum() < MIN_CELLS:
        return _level(f"level ground (only {int(use.sum())} cells seen round the blind disc)")
    dx, dy, h = xs[use] - at[0], ys[use] - at[1], z[use]
    a = np.column_stack([np.ones(len(h)), dx, dy])
    coef = np.linalg.lstsq(a, h, rcond=None)[0]
    res = h - a @ coef
    keep = np.abs(res) <= max(OUTLIER, 2.0 * float(np.std(res)))
    if keep.sum() >= MIN_CELLS:
        coef = np.linalg.lstsq(a[keep], h[keep], rcond=None)[0]
    z0, gx, gy = (float(v) for v in coef)
    res = h - a @ coef
    spread = float(np.sqrt(np.mean(res**2)))  # every seen cell: a rock or a dip is as likely inside
    fitted = a[keep] if keep.sum() >= MIN_CELLS else a
    kept_res = res[keep] if keep.sum() >= MIN_CELLS else res
    dof = max(len(kept_res) - 3, 1)
    cov = np.linalg.pinv(fitted.T @ fitted) * float(np.sum(kept_res**2)) / dof
    tilt = math.degrees(math.atan(math.hypot(gx, gy)))
    said = (f"the plane of {int(keep.sum())} seen cells round the blind disc ({tilt:.1f} deg), "
            f"the ground off it by {spread * 100:.1f} cm (sd)")
    return RingPlane(z0, gx, gy, (float(at[0]), float(at[1])), spread, said, cov)


def set_down(bounds: Any, pose: tuple[float, float, float], datum: float, body: Any,
             attitude: tuple[float, float, float] | None, disc: tuple[float, float, float], turn: float,
             ring_edge: float, ring_width: float) -> str:
    """What a rover set down at ``pose`` (x, y, heading deg) knows of the ground round it that no
    frame of ``bounds`` shows, each part from what shows it; returns what it took.

    - Under the wheels: their contacts from the pose and the IMU's ``attitude`` (roll, pitch and
      their sigma, deg; None: the GNC gives none), on the plane through ``datum`` (the frames'
      height of the rover's own ground at its centre), to a few millimetres; under the box, a
      ceiling at the belly (:meth:`BoundsMap.stood`), which the chance check's draws of unseen
      ground never pass. On the ring's plane instead, the wheels stood 4.5-5.7 cm off the truth at
      dense mission 0's start. Without an attitude they are on the plane through ``datum`` tipped
      as the ring's, within :data:`FLOOR`.
    - The rest of the mast's blind ``disc`` (x, y of the mast's foot, radius) and of the disc of
      radius ``turn`` the body turns in (at least to its wheels' outer corners,
      :func:`vehicle.reach`), the ground under the body between the wheels included: the plane of
      the ring of seen ground from ``ring_edge`` to ``ring_width`` past the disc
      (:func:`ring_plane`), within the ring's own spread about it (:meth:`RingPlane.sigma`),
      conditioned on the ground frames bounded beside it and on the wheels' (:func:`conditioned`).
      Taken instead as the wheels' plane within 1 cm, the ground under the start's body read
      3.7 cm high at the median (p95 7.7 cm) at hirise_fresh mission 4's start: wheels rest on the
      highest ground under them, and the ground between lies lower. The rover's first section
      there put its new wheels on that prior 1.3-6.1 cm high and its belly on a rock. With too
      little of the ring seen, that ground stays unknown.

    No pose is promised: the rover may turn where it was set down only where the check passes the
    turn. Promised, the turn at dense_fresh mission 6's start put the belly 1.5 mm into a rock
    at one heading."""
    x, y, _ = pose
    fx, fy, radius = disc
    # the turn's disc reaches the wheels' outer corners and the cells round them a sample reads
    turn = max(turn, reach(body) + 2 * bounds.geometry.cell)
    ring = ring_plane(bounds, (fx, fy), radius + ring_edge, radius + ring_width, (x, y))
    # the wheels first: the fill takes only blank cells, and meets the wheels' ground without a step
    # (sigma and tilt speak only where no attitude does)
    bounds.stood(pose, datum, body, attitude, sigma=FLOOR, tilt=(ring.gx, ring.gy), fill_under=False)
    if ring.known:
        blind = max(radius + ring_edge, math.hypot(x - fx, y - fy) + turn)
        height, sigma = conditioned(bounds, ring, (fx, fy), blind)
        bounds.set_down((fx, fy), blind, height, sigma=sigma)
    wheels = "the IMU's attitude" if attitude is not None else "the ring's plane (no attitude)"
    return f"{ring.said}; the wheels' ground from the pose and {wheels}"


def conditioned(bounds: Any, ring: RingPlane, centre: tuple[float, float], radius: float
                ) -> tuple[Callable[[np.ndarray, np.ndarray], np.ndarray], Callable[[np.ndarray, np.ndarray], np.ndarray]]:
    """The height and sigma of the unknown ground within ``radius`` of ``centre``, continuous with
    the ground the map already holds beside it (seen ground, and the wheels' contacts set before):
    the ring's plane plus the known cells' heights off it carried smoothly across the unknown
    cells (a harmonic fill: each unknown cell the mean of its four neighbours, the known ones
    fixed), within the ring's spread times sqrt(1 - rho(d)^2), d the distance to the nearest known
    cell and rho the correlation the chance check draws a prior with (:func:`chance.prior_correlation`,
    the truth's own off its plane), never below :data:`FLOOR`. The ground is continuous: the
    ring's plane alone meets the wheels' plane and the seen ground in steps of a few centimetres
    (3-4 cm at marsyard mission 0's start), steps the prior invents, on which the check refuses
    the wheels."""
    g = bounds.geometry
    pad = radius + CONDITION_REACH
    c0 = max(0, int(math.floor((centre[0] - pad - g.xmin) / g.cell)))
    c1 = min(g.width, int(math.ceil((centre[0] + pad - g.xmin) / g.cell)))
    r0 = max(0, int(math.floor((g.ymax - centre[1] - pad) / g.cell)))
    r1 = min(g.height, int(math.ceil((g.ymax - centre[1] + pad) / g.cell)))
    if r1 <= r0 or c1 <= c0:
        return ring.height, ring.sigma
    window = bounds.mean[r0:r1, c0:c1].astype(np.float64)
    known = np.isfinite(window)
    if not known.any():
        return ring.height, ring.sigma
    xs = g.xmin + (np.arange(c0, c1) + 0.5) * g.cell
    ys = g.ymax - (np.arange(r0, r1) + 0.5) * g.cell
    X, Y = np.meshgrid(xs, ys)
    off = np.where(known, window - ring.height(X, Y), 0.0)
    todo = ~known & (np.hypot(X - centre[0], Y - centre[1]) <= radius + g.cell)
    fill = np.zeros(window.shape)
    fill[todo] = _harmonic(off, known, todo)
    dist = ndimage.distance_transform_edt(~known, sampling=g.cell)

    def at(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        col = np.clip(np.floor((np.asarray(x) - g.xmin) / g.cell).astype(np.int64) - c0, 0, c1 - c0 - 1)
        row = np.clip(np.floor((g.ymax - np.asarray(y)) / g.cell).astype(np.int64) - r0, 0, r1 - r0 - 1)
        return prior_correlation(dist[row, col]), fill[row, col]

    def height(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return ring.height(x, y) + at(x, y)[1]

    def sigma(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        rho = at(x, y)[0]
        return np.maximum(ring.sigma(x, y) * np.sqrt(1.0 - rho * rho), FLOOR)

    return height, sigma


def _harmonic(value: np.ndarray, known: np.ndarray, todo: np.ndarray) -> np.ndarray:
    """The cells ``todo`` filled so that each is the mean of its four neighbours that are ``todo``
    or ``known`` (the known ones at ``value``; other neighbours left out), solved at once; a
    region with no known neighbour settles at 0 (the plane)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.linalg import spsolve

    idx = -np.ones(todo.shape, np.int64)
    n = int(todo.sum())
    idx[todo] = np.arange(n)
    rows, cols, vals = [np.arange(n)], [np.arange(n)], [np.full(n, 1e-6)]
    b = np.zeros(n)
    r, c = np.nonzero(todo)
    h, w = todo.shape
    for dr, dc in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        rr, cc = r + dr, c + dc
        inside = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
        rr, cc = np.where(inside, rr, 0), np.where(inside, cc, 0)
        unknown = inside & todo[rr, cc]
        fixed = inside & known[rr, cc]
        me = idx[r, c]
        rows += [me[unknown | fixed]]
        cols += [me[unknown | fixed]]
        vals += [np.ones(int((unknown | fixed).sum()))]
        rows += [me[unknown]]
        cols += [idx[rr, cc][unknown]]
        vals += [-np.ones(int(unknown.sum()))]
        np.add.at(b, me[fixed], value[rr, cc][fixed])
    a = coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)).tocsr()
    return spsolve(a, b)
