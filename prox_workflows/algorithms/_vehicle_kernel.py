"""The vehicle check's per-pose work as one compiled pass, in the subset of Python numba compiles.
:mod:`.vehicle` owns the definitions (what each limit means, the body's sample pattern, the
planes) and calls this; it lives in its own module so that importing :mod:`.vehicle` does not
import numba (~0.3 s) before the first check.

Why a kernel and not whole-array numpy: a pose reads a few thousand samples on the 1 cm truth
(2,888 for the P3-AT), and each limit is a handful of operations on them. As numpy over a batch of
poses that is some twenty passes over (poses, samples) float64 temporaries (the four gathers of
the bilinear read alone write six), and memory traffic, not arithmetic, is what they cost. Here a
pose's samples live in a few buffers that stay in cache, each limit is a loop over them, and work
whose result is not used is skipped (the ground under the belly over a plane the body does not
rest on). Every figure is computed in float64 in the order the numpy formulation computes it, so
the results are that formulation's to within rounding (``tools.bench.vehicle_check`` keeps it as
the reference; ``tests/prox/test_vehicle_check.py`` holds the two together).
"""

from __future__ import annotations

import math

import numpy as np

from rvs_params.jit import jit

# error_model="numpy": IEEE division (a level plane's tip-over reach divides by a zero slope and
# must give inf, as numpy does), no zero checks in the loops
_jit = jit(error_model="numpy")
_inline = jit(error_model="numpy", inline="always")
_DEG = 180.0 / math.pi


@_inline
def _read(h: np.ndarray, xmin: float, ymax: float, cell: float, x: float, y: float, cellwise: bool) -> float:
    """The height at (x, y): the bound of the cell that holds the point (``cellwise``: a bounds
    map's cell bounds every point in it), or bilinear between the cell centres (a height grid).
    NaN off the grid."""
    # the tests on the fractional indices (floor(f) < n iff f < n for f >= 0) keep NaN and far
    # coordinates out of the integer conversion (which truncates: the floor of f >= 0); unsigned
    # indices spare each read numba's wraparound of negative ones (a quarter of the read's time)
    if cellwise:
        fc = (x - xmin) / cell
        fr = (ymax - y) / cell
        if not (fc >= 0.0 and fr >= 0.0 and fc < h.shape[1] and fr < h.shape[0]):
            return np.nan
        return np.float64(h[np.uint64(fr), np.uint64(fc)])
    fc = (x - xmin) / cell - 0.5
    fr = (ymax - y) / cell - 0.5
    if not (fc >= 0.0 and fr >= 0.0 and fc < h.shape[1] - 1 and fr < h.shape[0] - 1):
        return np.nan
    c0, r0 = np.uint64(fc), np.uint64(fr)
    c1, r1 = c0 + np.uint64(1), r0 + np.uint64(1)
    tc, tr = fc - c0, fr - r0
    return ((h[r0, c0] * (1 - tc) + h[r0, c1] * tc) * (1 - tr)
            + (h[r1, c0] * (1 - tc) + h[r1, c1] * tc) * tr)


@_jit
def sample(h: np.ndarray, xmin: float, ymax: float, cell: float, x: np.ndarray, y: np.ndarray, cellwise: bool,
           out: np.ndarray) -> None:
    """:func:`_read` at every point of the flat arrays ``x``, ``y`` into ``out``."""
    for i in range(x.shape[0]):
        out[i] = _read(h, xmin, ymax, cell, x[i], y[i], cellwise)


@_inline
def _tip(a: float, b: float, fore: float, side: float, cog: float) -> float:
    """The static tip-over angle (deg) of the plane z = a x + b y, which leans toward -(a, b): the
    centre of gravity ``cog`` over it reaches the edge of the hubs' rectangle (``fore``, ``side``
    from the middle) after |(a, b)| min(fore / |a|, side / |b|). A level plane leans nowhere:
    its reach is inf (90 deg), as is a NaN plane's."""
    ra = fore / abs(a)
    rb = side / abs(b)
    m = ra if ra < rb else rb
    if math.isnan(ra) or math.isnan(rb):
        m = np.nan
    reach = math.hypot(a, b) * m
    if math.isnan(reach):
        reach = np.inf
    return math.atan(reach / cog) * _DEG


@_jit
def tips(a: np.ndarray, b: np.ndarray, fore: float, side: float, cog: float, out: np.ndarray) -> None:
    """:func:`_tip` of every plane (``a``, ``b`` flat) into ``out``."""
    for i in range(a.shape[0]):
        out[i] = _tip(a[i], b[i], fore, side, cog)


@_inline
def _fill(lo: np.ndarray, hi: np.ndarray, mid: np.ndarray, half: np.ndarray, bounded: bool, holes: bool,
          wheel_of: np.ndarray, on_wheel: np.ndarray, nan_lo: np.ndarray) -> bool:
    """Fill the holes of one pose's samples as ``vehicle.check_poses`` says, and on bounds the
    middle and half spread the grade fits (one grid's are its heights); whether the pose is
    unknown (on bounds). ``holes``: whether any low is NaN."""
    s = lo.shape[0]
    if not bounded:
        if holes:  # ground off the grid takes the lowest height the pose sees
            low = np.inf
            for j in range(s):
                if lo[j] < low:
                    low = lo[j]
            if low == np.inf:
                low = 0.0
            for j in range(s):
                if math.isnan(lo[j]):
                    lo[j] = low
        return False
    unseen = False
    top = -np.inf
    nan_lo[:] = 0.0
    for j in range(s):
        if math.isnan(hi[j]):
            unseen = True
        elif hi[j] > top:
            top = hi[j]
        if wheel_of[j] >= 0 and math.isnan(lo[j]):
            nan_lo[wheel_of[j]] += 1
    for w in range(4):
        if nan_lo[w] / on_wheel[w] > 0.5:
            unseen = True
    if top == -np.inf:
        top = 0.0
    for j in range(s):
        if math.isnan(hi[j]):
            hi[j] = top
        if math.isnan(lo[j]):  # stands in by its high in the fitted plane
            mid[j] = (hi[j] + hi[j]) / 2
            half[j] = 0.0
        else:
            mid[j] = (lo[j] + hi[j]) / 2
            half[j] = (hi[j] - lo[j]) / 2
    return unseen


@_inline
def _grade(mid: np.ndarray, half: np.ndarray, bounded: bool, g0: np.ndarray, g1: np.ndarray, pull_a: np.ndarray,
           pull_b: np.ndarray, pulls_a: np.ndarray, pulls_b: np.ndarray) -> float:
    """The fitted plane's slope (deg), on bounds its steepest over the zonotope's vertices."""
    a, b = 0.0, 0.0
    for j in range(mid.shape[0]):
        a += mid[j] * g0[j]
        b += mid[j] * g1[j]
    if not bounded:
        return math.atan(math.hypot(a, b)) * _DEG
    # every direction's pull accumulates at once (the inner loop runs across directions, each a
    # sum over the samples in order: a loop the compiler vectorises)
    pulls_a[:] = 0.0
    pulls_b[:] = 0.0
    for j in range(mid.shape[0]):
        hj = half[j]
        for k in range(pulls_a.shape[0]):
            pulls_a[k] += hj * pull_a[j, k]
            pulls_b[k] += hj * pull_b[j, k]
    steep = -np.inf
    for k in range(pulls_a.shape[0]):
        pa, pb = pulls_a[k], pulls_b[k]
        steep = max(steep, math.hypot(a + pa, b + pb), math.hypot(a - pa, b - pb))
    return math.atan(steep) * _DEG


@_inline
def _edges(lo: np.ndarray, hi: np.ndarray, bounded: bool, pair_a: np.ndarray, pair_b: np.ndarray,
           pair_wheel: np.ndarray, out: np.ndarray) -> None:
    """Each wheel's greatest rise between paired samples, either way (NaN lows take no part;
    NaN: no pair judged)."""
    out[:] = -np.inf
    for q in range(pair_a.shape[0]):
        ia, ib = pair_a[q], pair_b[q]
        if bounded:
            up = hi[ib] - lo[ia]
            down = hi[ia] - lo[ib]
            if math.isnan(up) or down > up:  # fmax: the larger, a NaN skipped
                up = down
        else:
            up = abs(lo[ib] - lo[ia])
        w = pair_wheel[q]
        if up > out[w]:
            out[w] = up
    for w in range(4):
        if math.isinf(out[w]):
            out[w] = np.nan


@_inline
def _contacts(lo: np.ndarray, hi: np.ndarray, bounded: bool, wheel_of: np.ndarray, sag: np.ndarray,
              contact: np.ndarray) -> bool:
    """Each wheel's lowest and highest resting height (NaN: no ground under it); whether they are
    not pinned down (the contacts' box is open)."""
    contact[:, :] = -np.inf
    for j in range(lo.shape[0]):
        w = wheel_of[j]
        if w >= 0:
            v = lo[j] - sag[j]
            if v > contact[0, w]:
                contact[0, w] = v
            v = hi[j] - sag[j]
            if v > contact[1, w]:
                contact[1, w] = v
    open_box = False
    for w in range(4):
        if contact[0, w] == -np.inf:
            contact[0, w] = np.nan
        if not bounded:
            contact[1, w] = contact[0, w]
        if contact[1, w] - contact[0, w] > 1e-12:
            open_box = True
    return open_box


@_inline
def _raise_on_tops(upper: np.ndarray, xmin: float, ymax: float, cell: float, x: float, y: float, c: float,
                   si: float, px: np.ndarray, py: np.ndarray, wheel_of: np.ndarray, hubs: np.ndarray,
                   radius: float, half_width: float, raised: np.ndarray) -> None:
    """Raise each wheel's rests in ``raised`` (as ``_contacts`` fills them) to the top of every
    cell of ``upper`` wholly inside its footprint, less the circle's sag at the cell's end
    farthest from the hub: a cell's top lies somewhere in the cell, so a cell the footprint holds
    whole holds its top under the wheel. The pose is at (``x``, ``y``), heading cos ``c``, sin ``si``."""
    for j in range(px.shape[0]):
        w = wheel_of[j]
        if w < 0:
            continue
        fc = (x + c * px[j] - si * py[j] - xmin) / cell
        fr = (ymax - (y + si * px[j] + c * py[j])) / cell
        if not (fc >= 0.0 and fr >= 0.0 and fc < upper.shape[1] and fr < upper.shape[0]):
            continue
        col, row = math.floor(fc), math.floor(fr)
        inside = True
        reach = 0.0
        for dc in range(2):
            for dr in range(2):
                ex = xmin + (col + dc) * cell - x
                ey = ymax - (row + dr) * cell - y
                lx = c * ex + si * ey - hubs[w, 0]
                ly = -si * ex + c * ey - hubs[w, 1]
                inside = inside and abs(lx) <= radius and abs(ly) <= half_width
                reach = max(reach, abs(lx))
        top = np.float64(upper[np.uint64(row), np.uint64(col)])
        if inside and not math.isnan(top):
            v = top - (radius - math.sqrt(max(radius * radius - reach * reach, 0.0)))
            raised[0, w] = max(raised[0, w], v)
            raised[1, w] = max(raised[1, w], v)


@jit(error_model="numpy", fastmath={"nnan", "ninf"})
def _under(hb: np.ndarray, bx: np.ndarray, by: np.ndarray, a: float, b: float, c: float) -> float:
    """The highest ground under the box over the plane z = a x + b y + c: ``hb`` the ground's
    (upper) heights at the belly's samples ``bx``, ``by``. Everything here is finite (the holes
    are filled and a plane the body rests on has finite contacts), which lets the compiler
    vectorise the maximum; the maximum is exact in any order."""
    under = -np.inf
    for i in range(hb.shape[0]):
        under = max(under, hb[i] - (a * bx[i] + b * by[i] + c))
    return under


@_jit
def check(lower: np.ndarray, upper: np.ndarray, bounded: bool, cellwise: bool, xmin: float, ymax: float,
          cell: float,
          poses: np.ndarray, px: np.ndarray, py: np.ndarray, wheel_of: np.ndarray, belly: np.ndarray,
          sag: np.ndarray, pair_a: np.ndarray, pair_b: np.ndarray, pair_wheel: np.ndarray, g0: np.ndarray,
          g1: np.ndarray, pull_a: np.ndarray, pull_b: np.ndarray, inv: np.ndarray, triplets: np.ndarray,
          corners: np.ndarray, hubs: np.ndarray, fore: float, side: float, cog: float, safety: float,
          edge: np.ndarray, intrusion: np.ndarray, tilt: np.ndarray, tip: np.ndarray, grade: np.ndarray,
          stability: np.ndarray, unknown: np.ndarray, rest_tops: bool = False, radius: float = 0.0,
          half_width: float = 0.0, fit_grade: bool = False) -> None:
    """Every limit at every pose ((N, 3): x, y, heading deg) into the output arrays; see
    ``vehicle.check_poses`` for what each is. The pattern: sample offsets ``px``, ``py`` (S,), each
    one's wheel (-1: none), the belly's samples (indices), each wheel sample's ``sag`` (the
    circle's rise there); the step's sample pairs (indices, and the wheel of each); the ground
    plane's pseudo-inverse rows ``g0``, ``g1`` (S,) and on bounds the zonotope's signed pulls
    ``pull_a``, ``pull_b`` (S, D); the resting planes' inverses (P, 3, 3) and their ``triplets``
    (P, 4: three wheels, the fourth last); the contacts' ``corners`` (C, 3: 0 lowest, 1 highest).
    ``rest_tops``: the resting planes are judged again with each wheel raised onto the tops of the
    cells wholly under it (``radius``, ``half_width``: the wheel's footprint), for stability only;
    the belly keeps the planes on the contacts as read. ``fit_grade`` (on a pair): the grade is the
    plane fitted to the pair's middles, not the steepest the pair allows."""
    s = px.shape[0]
    lo, hi, mid, half = np.empty(s), np.empty(s), np.empty(s), np.empty(s)
    pulls_a, pulls_b = np.empty(pull_a.shape[1]), np.empty(pull_a.shape[1])
    contact = np.empty((2, 4))
    raised = np.empty((2, 4))
    hb, bx, by = np.empty(belly.shape[0]), px[belly], py[belly]
    nan_lo = np.zeros(4)
    on_wheel = np.zeros(4)
    for j in range(s):
        if wheel_of[j] >= 0:
            on_wheel[wheel_of[j]] += 1
    for p in range(poses.shape[0]):
        rad = math.radians(poses[p, 2])
        c, si = math.cos(rad), math.sin(rad)
        holes = False
        for j in range(s):  # in the order numpy's broadcast forms them: (x0 + c px) - s py
            wx = poses[p, 0] + c * px[j] - si * py[j]
            wy = poses[p, 1] + si * px[j] + c * py[j]
            lo[j] = _read(lower, xmin, ymax, cell, wx, wy, cellwise)
            holes |= math.isnan(lo[j])
            if bounded:
                hi[j] = _read(upper, xmin, ymax, cell, wx, wy, cellwise)
        unknown[p] = _fill(lo, hi, mid, half, bounded, holes, wheel_of, on_wheel, nan_lo)
        highs, middles = (hi, mid) if bounded else (lo, lo)  # one grid: the heights are all three
        grade[p] = _grade(middles, half, bounded and not fit_grade, g0, g1, pull_a, pull_b, pulls_a, pulls_b)
        _edges(lo, highs, bounded, pair_a, pair_b, pair_wheel, edge[p])
        # one corner (a pair whose wheels rest on its lows): the contacts are pinned to it
        open_box = _contacts(lo, highs, bounded, wheel_of, sag, contact) and corners.shape[0] > 1
        if rest_tops:
            raised[:, :] = contact
            _raise_on_tops(upper, xmin, ymax, cell, poses[p, 0], poses[p, 1], c, si, px, py, wheel_of, hubs,
                           radius, half_width, raised)
        for i in range(belly.shape[0]):
            hb[i] = highs[belly[i]]
        worst_in, worst_st, worst_tilt, worst_tip = -np.inf, -np.inf, 0.0, 90.0
        for q in range(2 if rest_tops else 1):
            rest = contact if q == 0 else raised
            for t in range(triplets.shape[0]):
                fx, fy = hubs[triplets[t, 3], 0], hubs[triplets[t, 3], 1]
                for k in range(corners.shape[0]):
                    z0 = rest[corners[k, 0], triplets[t, 0]]
                    z1 = rest[corners[k, 1], triplets[t, 1]]
                    z2 = rest[corners[k, 2], triplets[t, 2]]
                    pa = z0 * inv[t, 0, 0] + z1 * inv[t, 0, 1] + z2 * inv[t, 0, 2]
                    pb = z0 * inv[t, 1, 0] + z1 * inv[t, 1, 1] + z2 * inv[t, 1, 2]
                    pc = z0 * inv[t, 2, 0] + z1 * inv[t, 2, 1] + z2 * inv[t, 2, 2]
                    rests = rest[0, triplets[t, 3]] <= pa * fx + pb * fy + pc + 1e-9
                    if rests and q == 0:  # the belly's ground counts only over a plane the body may rest on
                        worst_in = max(worst_in, _under(hb, bx, by, pa, pb, pc))
                    angle = math.atan(math.hypot(pa, pb)) * _DEG
                    limit = _tip(pa, pb, fore, side, cog)
                    margin = angle - limit / safety
                    # the lean is worst at a corner of the contacts' box; which plane the body rests
                    # on there is not known, so every one counts
                    if (rests or open_box) and margin > worst_st:
                        worst_st, worst_tilt, worst_tip = margin, angle, limit
        intrusion[p] = worst_in
        stability[p] = np.nan if worst_st == -np.inf else worst_st
        tilt[p] = worst_tilt
        tip[p] = worst_tip
