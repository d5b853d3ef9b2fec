"""The bounds map: per cell a lower and an upper bound on the ground's height, the map a
worst-case (ACE-style) wheel and belly check runs on.

JPL's ENav on Perseverance (Otsu et al. 2020, "Approximate Clearance Evaluation") plans on such
bounds rather than on one height per cell: a clearance check on the highest the ground may be
under the belly, and the lowest and highest a wheel may rest, never accepts a false negative,
whatever the sensor missed. A mean per cell cannot give that: 5 cm cell means read rocks
1.1-2.5 cm low, and a window judged from its seen cells alone calls half-seen rocks safe.

What each observation says, and so what the map keeps:

- A frame's returns in a cell give the ground's mean height there, with the variance of that
  mean (the returns' height variance over their number), and how far the returns rise above and
  drop below the mean beyond what their noise explains (``rise``, ``drop``: a rock's flank or
  edge within the cell). Across frames the means are fused by their variance, as DemMosaik fuses
  heights, so repeated looks tighten the bounds; the rise and drop are averaged alike. A
  frame that disagrees beyond the gate (a rock dropped in, a frame placed with a drifted pose)
  widens the cell to the union of both: the map keeps what may be there, not an average of two
  stories. Bounds: ``mean + rise + k sigma`` and ``mean - drop - k sigma``.
- A stereo pair's frame is fused as its own kind of sensor (``sensor="stereo"``): its pixels in a
  cell share the matcher's window and its semi-global paths, so their errors are one error, not
  n (``stereo_correlation``: a cell's mean is no better than a pixel, and none of the spread
  within the cell is put down to noise). Its cells fuse with the ToF's by their variances, as two
  ToF frames' do. Left standing alone where a pair bounded a cell (``stereo_first``), the pair's
  cells replaced the ToF's averaged frames with wider ones whose tops stand high (its whole
  spread read as relief: within 1.5 m of the rover 1 cell in 100 reads its top 1.25 cm over the
  true top, where the ToF's read within 0.5 mm of it), and the chance check kept 7-14 points
  fewer truly safe poses for no lower stated risk (``python -m tools.bench.chance --risk --look
  approach+hazcam``, docs/NAVIGATE_BENCH.md). ``stereo_first`` is for the worst-case check on the
  mast's stereo, where a fused mean shrinks the bounds below what either sensor holds alone
  (docs/BENCHMARKS.md). Where a pair's reading and a ToF frame's disagree beyond the gate, the
  union of both is kept by default, as between two ToF frames; ``disagree`` lets the ToF's
  reading stand instead: the pair's disagreement is its own error far more often than the
  ground (dense, traced against the truth), and kept as a union it stood flat cells' tops up to
  19 cm high, but the missions moved both ways with it (docs/NAVIGATE_BENCH.md).
- A ray that passed over a cell without a return there bounds the ground from above at the ray's
  height (``ceiling``): ground behind a rock the rays skimmed, or between sparse far returns, is
  not known, but it is known not to stand higher than the ray. It gives no lower bound.
- A cell nothing saw has neither: no upper bound means nothing may be assumed about it; the
  check treats it as unknown, never as safe.

Memory: the see loop keeps a window that follows the rover (:meth:`BoundsMap.around`,
:meth:`BoundsMap.follow`), as wide as what its chooser judges and its frames reach: a map over a
whole 200 m mission's box would be 267 MB, and a choice reading it all 6x the work of a 20 m one.
Cells the window leaves are dropped, and what they held is lost: ground the rover comes back to
is unknown again until a frame shows it again (the chooser's coarse guidance keeps what it said
of them: :mod:`.coarse_memory`). A map made with :meth:`BoundsMap.covering` is fixed and keeps all.
A pose fix moves what the frames since the last fix placed (:meth:`BoundsMap.move`), as the
rolling map's.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from rvs_params import Settings, param

from ..grid import GridGeometry

__all__ = ["BoundsMap", "BoundsParams", "SENSORS", "contact_plane", "warm_up"]

# the kinds of frame the map fuses, in rising precedence (with ``stereo_first``)
SENSORS = ("tof", "stereo")


@dataclass
class BoundsParams(Settings):
    """The bounds map's cell and how wide its bounds are drawn."""

    cell: float = param(0.025, "side of a bounds-map cell; rocks are read by their top at this size",
                        unit="m", min=0.005, max=0.5)
    k: float = param(2.5, "bounds are drawn this many standard deviations out from a measurement",
                     min=0.0, max=10.0)
    gate: float = param(3.0, "a frame further than this many sigmas from the cell's bounds widens them "
                             "to the union instead of being averaged in", min=0.5, max=100.0)
    reach: float = param(0.5, "a ray bounds the ground only where it runs at most this high over its "
                              "return: higher, the bound is of no use to a rover", unit="m", min=0.05, max=10.0)
    min_returns: int = param(2, "a frame's returns in a cell give it bounds only from this many on: a lone "
                                "far return's range error moves it across cells, onto a rock's flank from the "
                                "ground before it", min=1, max=100)
    max_shift: int = param(4, "most cells a return's range error is taken to move it across (a far, "
                              "lone return moves further, and gives no bound: min_returns)", min=1, max=16)
    near: float = param(0.06, "a ray's last stretch before its return bounds nothing (it meets the "
                              "ground there at a grazing angle)", unit="m", min=0.0, max=1.0)
    stereo_correlation: float = param(1.0, "correlation of a stereo frame's height errors within a cell: its "
                                           "pixels share the matcher's window, so n of them are no better than one "
                                           "(0.9 already misses rock tops in the simulated rock fields)",
                                      min=0.0, max=1.0)
    disagree: str = param("union", "where a ToF frame and a stereo pair's reading of a cell disagree beyond the gate: "
                                   "union, both are kept, as between two ToF frames; pair_yields, a stereo frame "
                                   "leaves the cells a ToF frame bounded; tof_stands, that and a ToF frame replaces "
                                   "what only pairs said. On dense's mission 3 the pairs' disagreeing readings held "
                                   "the true ground in 12-21 % of cells, the ToF-bounded map's in 87-96 %, and with "
                                   "tof_stands dense 3 made 10.4 m good where it made 1.5; but over 14 missions it "
                                   "reached two more and lost three, and was slower on every mission reached both "
                                   "ways. Over two sensor noise draws of hirise and dense 0-4, pair_yields reached "
                                   "7 of 19 runs and the union 9 of 20, the noise draw alone flipping three "
                                   "missions, at the same stated risk (docs/NAVIGATE_BENCH.md)",
                          choices=("union", "pair_yields", "tof_stands"))
    stereo_first: bool = param(False, "where a stereo frame bounded a cell, its bounds stand alone: ToF frames no "
                                      "longer fuse into the cell (for the worst-case check on the mast's stereo: "
                                      "fused, a mean better than either sensor's shrinks the bounds below what "
                                      "each holds alone; the chance check on the hazard cameras' frames keeps "
                                      "fewer truly safe poses with it, at no lower risk)")
    edge: float = param(0.1, "a cell's top is raised by this share of the relief its 3 x 3 neighbourhood "
                             "spans: a rock's rim and peak that few returns met, and mixed pixels at its edge "
                             "(what averaging frames does not narrow; fitted with grain on the truth, "
                             "docs/BENCHMARKS.md)", min=0.0, max=2.0)
    grain: float = param(0.003, "and by this on every cell a frame bounded: the relief within a cell no return "
                                "met, which the k sigmas of frames averaged no longer cover", unit="m",
                         min=0.0, max=0.05)
    hang: float = param(0.025, "how far below the plane its attitude gives the ground under a standing wheel may "
                               "lie: a rigid body on four wheels rests on three, and the IMU does not tell which "
                               "one hangs, nor by how much, over lower ground", unit="m", min=0.0, max=0.5)
    changed: float = param(0.05, "a frame that reads a cell's ground this much over the highest the map held there "
                                 "(its top and k sigmas) finds the ground changed: a rock came since; 0: never "
                                 "(disagreeing frames keep the union of both, which covered a dropped rock's unseen "
                                 "flank only while frames disagreed by chance: navigate.see_register places them "
                                 "on the map's ground, to millimetres)", unit="m", min=0.0, max=1.0)
    changed_cells: int = param(16, "cells of one frame that must read the ground changed before the map drops what "
                                   "it held round them (fewer are a rock edge seen from a new side)", min=1,
                               max=10000)
    stale_radius: float = param(0.3, "what the map held within this of changed ground is dropped and unknown until "
                                     "a frame shows it again: the new rock's flank the frame did not see (its near "
                                     "rim below the mast's view) kept the ground seen before it came", unit="m",
                                min=0.0, max=2.0)
    under_sigma: float = param(0.01, "the ground under a standing rover's box that no frame bounded is taken as the "
                                     "framed ground under its body lies about its wheels' plane, within that "
                                     "ground's spread and at least this", unit="m", min=0.0, max=0.5)
    contact_sigma: float = param(0.001, "the ground under a standing wheel off the plane its pose and attitude put "
                                        "the four contacts on: the tyre's give and the grain it rests on (the "
                                        "attitude's own error is added to it)", unit="m", min=0.0, max=0.05)


def contact_plane(heading: float, roll: float, pitch: float) -> tuple[float, float]:
    """The rise per metre along global x and y of the plane a rover's wheels stand on, from its
    heading and the roll (left side up, deg) and pitch (nose up, deg) its IMU gives (yaw, then
    pitch, then roll): along the body's x it rises tan(pitch), along its y tan(roll) / cos(pitch)."""
    a = math.tan(math.radians(pitch))
    b = math.tan(math.radians(roll)) / math.cos(math.radians(pitch))
    c, s = math.cos(math.radians(heading)), math.sin(math.radians(heading))
    return a * c - b * s, a * s + b * c


def attitude_at(heading: float, gx: float, gy: float, sigma: float) -> tuple[float, float, float]:
    """Roll and pitch (deg, and their ``sigma``) of a body facing ``heading`` on the plane rising
    ``gx``, ``gy`` per metre along global x and y: :func:`contact_plane` inverted."""
    c, s = math.cos(math.radians(heading)), math.sin(math.radians(heading))
    pitch = math.atan(gx * c + gy * s)
    return math.degrees(math.atan((-gx * s + gy * c) * math.cos(pitch))), math.degrees(pitch), sigma


SWEEP_STEP = 0.05  # m between the poses a drive's sweep stands the body at (a wheel's footprint is 0.2 m long)
SWEEP_TURN = 10.0  # deg between them turning (a corner 0.39 m out moves 7 cm)
SWEEP_MAX = 0.5  # m: a longer move between two stands is a fix or a new set-down, not a drive
SWEEP_TILT = 1.0  # deg added to the attitude's sigma away from where it was read (the ground's tilt varies)


def swept_poses(since: tuple[float, float, float] | None, pose: tuple[float, float, float],
                attitude: tuple[float, float, float] | None
                ) -> list[tuple[tuple[float, float, float], tuple[float, float, float] | None]]:
    """The poses a body passed between ``since`` and ``pose`` (x, y, heading deg; neither end),
    every :data:`SWEEP_STEP` and :data:`SWEEP_TURN`, each with the attitude it had there on the
    plane ``attitude`` (read at ``pose``) gives, within :data:`SWEEP_TILT` more. None where it
    did not drive: set down (``since`` None), or moved further than :data:`SWEEP_MAX` (a fix)."""
    if since is None:
        return []
    dx, dy = pose[0] - since[0], pose[1] - since[1]
    turn = (pose[2] - since[2] + 180.0) % 360.0 - 180.0
    run = math.hypot(dx, dy)
    if run > SWEEP_MAX:
        return []
    n = max(math.ceil(run / SWEEP_STEP), math.ceil(abs(turn) / SWEEP_TURN))
    plane = None if attitude is None else contact_plane(pose[2], attitude[0], attitude[1])
    out = []
    for i in range(1, n):
        f = i / n
        at = (since[0] + f * dx, since[1] + f * dy, since[2] + f * turn)
        out.append((at, None if plane is None else attitude_at(at[2], *plane, math.hypot(attitude[2], SWEEP_TILT))))
    return out


# what a cell nothing has bounded holds, per layer (0 where not named)
_FILLS = {"mean": np.nan, "mean_var": np.nan, "ceiling": np.inf}
# the layers a frame's bounds are held in (moved by a fix with the cell's ``stamp``)
_BOUND_LAYERS = ("mean", "mean_var", "rise", "drop", "relief", "split", "shift", "along_var", "spread", "sensors")
# every per-cell layer, with its fill (a window's recentring moves them all)
_LAYERS = tuple((name, _FILLS.get(name, 0)) for name in (*_BOUND_LAYERS, "ceiling", "stamp", "lowered"))

MIN_UNDER_CELLS = 20  # framed cells under a standing body that say how its unseen ground lies about its plane
ANGLE_BINS = 24  # bearings of a spread's ellipse, 7.5 deg apart: at 4 cells its end is off by at most 0.26 cell
_KERNELS: dict[int, np.ndarray] = {}


def _spread_shapes(spread: np.ndarray, k: float, cell: float, max_shift: int) -> np.ndarray:
    """Per cell the code of the ellipse its bounds spread over (:func:`_kernel`): ``k`` sigmas of
    the covariance ``spread`` (3 x H x W: xx, xy, yy, m^2) along its axes, in whole cells (at least
    one, at most ``max_shift``), and its bearing in :data:`ANGLE_BINS` steps (0 for a disc)."""
    xx, xy, yy = (np.asarray(a, np.float64) for a in spread)
    half = (xx + yy) / 2
    root = np.sqrt(((xx - yy) / 2) ** 2 + xy**2)
    major = np.sqrt(np.maximum(half + root, 0.0))
    minor = np.sqrt(np.maximum(half - root, 0.0))
    ra = np.clip(np.ceil(k * major / cell), 1, max_shift).astype(np.int64)
    rb = np.minimum(np.clip(np.ceil(k * minor / cell), 1, max_shift).astype(np.int64), ra)
    angle = np.mod(0.5 * np.arctan2(2 * xy, xx - yy), np.pi)
    bins = np.where(ra == rb, 0, np.rint(angle / np.pi * ANGLE_BINS).astype(np.int64) % ANGLE_BINS)
    return ((bins * 17 + rb) * 17 + ra).astype(np.int64)


def _kernel(code: int) -> np.ndarray:
    """The structuring element of a spread's code (:func:`_spread_shapes`): for a disc OpenCV's
    ellipse of that radius, else the cells within the ellipse of half-axes ``ra`` along the
    bearing and ``rb`` across it (rows run south, as the map's)."""
    kernel = _KERNELS.get(code)
    if kernel is not None:
        return kernel
    import cv2

    ra, rb, bins = code % 17, (code // 17) % 17, code // (17 * 17)
    if ra == rb:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * ra + 1, 2 * ra + 1))
    else:
        theta = bins * math.pi / ANGLE_BINS
        ux, uy = math.cos(theta), math.sin(theta)
        dr, dc = np.mgrid[-ra:ra + 1, -ra:ra + 1]
        x, y = dc.astype(np.float64), -dr.astype(np.float64)
        kernel = (((x * ux + y * uy) / ra) ** 2 + ((-x * uy + y * ux) / rb) ** 2 <= 1.0 + 1e-9).astype(np.uint8)
    _KERNELS[code] = kernel
    return kernel


def _spread(top: np.ndarray, bottom: np.ndarray, seen: np.ndarray, shape: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """The highest ``top`` and the lowest ``bottom`` (float32) that reach each cell: every ``seen``
    cell's over the structuring element of its ``shape`` code (:func:`_kernel`; code 0 its own
    cell only), -inf and inf where none reaches. One compiled pass over the seen cells
    (:func:`._bounds_kernels.spread_extremes`): a map holds tens of shapes, each scattered over
    the whole map, and as image morphology each shape would pass over the whole grid
    (``tools.bench.choice`` keeps that form as the reference; the two give the same bits)."""
    from ._bounds_kernels import spread_extremes

    codes, inverse = np.unique(shape[seen], return_inverse=True)
    index = np.full(top.shape, -1, np.int64)
    index[seen] = inverse.ravel()
    start, dr, dc = [0], [], []
    for code in codes:
        if code == 0:
            rows, cols = np.zeros(1, np.int64), np.zeros(1, np.int64)
        else:
            kernel = _kernel(int(code))
            # a dilation's output at (y, x) is the most over its element of the input at
            # (y + i - a, x + j - a): the input at (r, c) reaches (r - i + a, c - j + a)
            i, j = np.nonzero(kernel)
            rows, cols = kernel.shape[0] // 2 - i, kernel.shape[1] // 2 - j
        dr.append(rows)
        dc.append(cols)
        start.append(start[-1] + len(rows))
    up = np.full(top.shape, -np.inf, np.float32)
    lo = np.full(top.shape, np.inf, np.float32)
    if len(codes):
        spread_extremes(np.ascontiguousarray(top, np.float32), np.ascontiguousarray(bottom, np.float32), index,
                        np.asarray(start, np.int64), np.concatenate(dr).astype(np.int64),
                        np.concatenate(dc).astype(np.int64), up, lo)
    return up, lo


def _cell_moments(pts: np.ndarray, sig: np.ndarray, sig_xy: np.ndarray, across: np.ndarray,
                  origin: np.ndarray | None, max_range: float | None, across_rays: bool, g: GridGeometry
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One frame's returns summed per cell (:func:`._bounds_kernels.cell_moments`: the cells in
    ascending order, their counts, and the (cells, 9) sums, highest and lowest): one compiled pass
    where the numpy reduction (a sort and nine segment sums, ``tools.bench.choice.reference_moments``,
    the same to within rounding) took 30 ms of a pair's 141,000 returns. A cell the range cut
    crosses takes none."""
    from ._bounds_kernels import cell_moments

    o = (0.0, 0.0, 0.0) if origin is None else tuple(float(v) for v in origin)
    cut = np.inf if origin is None or max_range is None else float(max_range)
    return cell_moments(np.ascontiguousarray(pts[:, 0]), np.ascontiguousarray(pts[:, 1]),
                        np.ascontiguousarray(pts[:, 2]), np.ascontiguousarray(sig), np.ascontiguousarray(sig_xy),
                        np.ascontiguousarray(across), *o, cut, across_rays and origin is not None, float(g.xmin),
                        float(g.ymax), float(g.cell), g.height, g.width)


class BoundsMap:
    """Lower and upper ground-height bounds on a fixed grid, fused frame by frame."""

    def __init__(self, geometry: GridGeometry, params: BoundsParams | None = None) -> None:
        self.geometry = geometry
        self.params = params or BoundsParams()
        shape = geometry.shape
        self.mean = np.full(shape, np.nan, np.float32)  # fused mean ground height (m)
        self.mean_var = np.full(shape, np.nan, np.float32)  # its variance (m^2)
        self.rise = np.zeros(shape, np.float32)  # ground above the mean within the cell (m)
        self.drop = np.zeros(shape, np.float32)  # ground below it (m)
        # the returns' own rise plus drop within each frame, averaged as rise and drop are (m): the
        # cell's relief as one frame sees it (a rock's edge in the cell). Where frames disagree,
        # rise and drop take the union of both frames' intervals and also hold how far apart the
        # frames put the same ground, which is the frames' error, not the cell's relief
        self.relief = np.zeros(shape, np.float32)
        # where frames disagreed: how far under the union's top the other frame's top stands (m),
        # blended away as agreeing frames come: the top is one frame's story or the other's, and a
        # wheel resting on the higher one lifts the plane over a belly (chance.ChanceParams.stories)
        self.split = np.zeros(shape, np.float32)
        self.shift = np.zeros(shape, np.float32)  # how far (m) the cell's returns may lie from their ground
        # the fused mean's own horizontal error along the rays (m^2): one return's, averaged over the
        # returns and frames as the mean's height error is (a check weighing the slope's share of
        # the mean's error reads this, not one return's ``shift``)
        self.along_var = np.zeros(shape, np.float32)
        # one return's horizontal error covariance (m^2: xx, xy, yy): an ellipse along the rays that
        # gave the cell its returns, which the bounds spread over (see bounds)
        self.spread = np.zeros((3, *shape), np.float32)
        self.ceiling = np.full(shape, np.inf, np.float32)  # lowest ray that passed over (m)
        self.stamp = np.zeros(shape, np.int32)  # the frame (1, 2, ...) that last touched the cell
        self.lowered = np.zeros(shape, np.int32)  # the frame that last lowered the cell's ceiling
        self.sensors = np.zeros(shape, np.uint8)  # bit i: a frame of SENSORS[i] bounded the cell
        self.frames = 0
        # a window's grid moves in whole multiples of this many cells (:meth:`follow`): its
        # origin stays on the coarse grid the chooser's guidance is kept on
        self.align = 1
        # the whole map's bounds as :meth:`whole` last gave them, with the parameters and the
        # inputs they were computed from
        self._whole: tuple[tuple, tuple[np.ndarray, ...], np.ndarray, np.ndarray] | None = None

    @classmethod
    def covering(cls, points: Any, pad: float, params: BoundsParams | None = None) -> BoundsMap:
        """A map over the box of ``points`` (x, y) grown by ``pad`` metres (a mission's start,
        goal and the ground around them), bounded as a plan's grid is."""
        from .planner import check_plan_size

        p = params or BoundsParams()
        xy = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        g = GridGeometry.covering(xy[:, 0].min() - pad, xy[:, 1].min() - pad, xy[:, 0].max() + pad,
                                  xy[:, 1].max() + pad, p.cell)
        check_plan_size(g, "bounds map")
        return cls(g, p)

    @classmethod
    def around(cls, centre: tuple[float, float], half: float, align: float, params: BoundsParams | None = None
               ) -> BoundsMap:
        """A window of side ``2 * half`` (grown to whole multiples of ``align`` metres) round
        ``centre``, its origin on multiples of ``align`` from the frame's origin: it follows the
        rover (:meth:`follow`), so its size and a choice's work do not grow with the mission."""
        p = params or BoundsParams()
        k = max(1, round(align / p.cell))
        step = k * p.cell
        n = k * math.ceil(2 * half / step - 1e-9)
        m = cls(GridGeometry(p.cell, *cls._origin(centre, n, k, p.cell), n, n), p)
        m.align = k
        return m

    @staticmethod
    def _origin(centre: tuple[float, float], n: int, k: int, cell: float) -> tuple[float, float]:
        """(xmin, ymax) of an ``n``-cell square window nearest centred on ``centre``, on multiples
        of ``k`` cells."""
        step = k * cell
        return (round((centre[0] - n * cell / 2) / step) * step,
                round((centre[1] + n * cell / 2) / step) * step)

    def follow(self, x: float, y: float, slack: float) -> bool:
        """Recentre the window on (x, y) once the rover is more than ``slack`` metres from its
        centre either way: the cells that stay inside keep what they hold, the rest are dropped
        and the ground newly inside is unknown. Returns whether the window moved."""
        g = self.geometry
        cx, cy = g.xmin + g.width * g.cell / 2, g.ymax - g.height * g.cell / 2
        if abs(x - cx) <= slack and abs(y - cy) <= slack:
            return False
        xmin, ymax = self._origin((x, y), g.width, self.align, g.cell)
        dc, dr = round((xmin - g.xmin) / g.cell), round((g.ymax - ymax) / g.cell)
        if dc == 0 and dr == 0:
            return False
        self.geometry = GridGeometry(g.cell, xmin, ymax, g.width, g.height, g.crs)
        for name, fill in _LAYERS:
            a = getattr(self, name)
            out = np.full_like(a, fill)
            h, w = a.shape[-2:]
            # the new cell (r, c) is the old (r + dr, c + dc)
            src = (slice(max(0, dr), min(h, h + dr)), slice(max(0, dc), min(w, w + dc)))
            dst = (slice(max(0, -dr), min(h, h - dr)), slice(max(0, -dc), min(w, w - dc)))
            if src[0].start < src[0].stop and src[1].start < src[1].stop:
                out[..., dst[0], dst[1]] = a[..., src[0], src[1]]
            setattr(self, name, out)
        self._whole = None
        return True

    def move(self, pivot: tuple[float, float], dx: float, dy: float, dyaw: float, since: int) -> None:
        """Move what frames after ``since`` (a frame count) placed by a pose fix (rotation ``dyaw``
        degrees about ``pivot``, then ``dx, dy``; nearest cell), as the rolling map's frames move:
        they were placed with the pose the fix corrects. A cell's bounds move where a later frame
        bounded it (``stamp``), its ray ceiling where a later frame's ray lowered it (``lowered``);
        where they land they replace what earlier frames left, and where they leave nothing is
        known (what the later frame's fusion overwrote there is gone). The error ellipses turn
        with the fix."""
        g = self.geometry
        xs, ys = g.centers()
        X, Y = np.meshgrid(xs, ys)
        c, s = math.cos(math.radians(-dyaw)), math.sin(math.radians(-dyaw))
        ux, uy = X - pivot[0] - dx, Y - pivot[1] - dy
        row, col = g.cell_of(c * ux - s * uy + pivot[0], s * ux + c * uy + pivot[1])
        inside = g.inside(row, col)
        rr, cc = np.clip(row, 0, g.height - 1), np.clip(col, 0, g.width - 1)
        for mark, names in (("stamp", _BOUND_LAYERS), ("lowered", ("ceiling",))):
            recent = getattr(self, mark) > since
            lands = inside & recent[rr, cc]
            for name in (mark, *names):
                a = getattr(self, name)
                fill = _FILLS.get(name, 0)
                out = np.where(recent, np.asarray(fill, a.dtype), a)  # what leaves: unknown
                out[..., lands] = a[..., rr[lands], cc[lands]]
                setattr(self, name, out)
        if dyaw:
            # the ellipses (xx, xy, yy) of the moved cells turn by dyaw: R S R^T
            moved = self.stamp > since
            xx, xy, yy = (self.spread[i][moved].astype(np.float64) for i in range(3))
            c, s = math.cos(math.radians(dyaw)), math.sin(math.radians(dyaw))
            self.spread[0][moved] = c * c * xx - 2 * c * s * xy + s * s * yy
            self.spread[1][moved] = c * s * (xx - yy) + (c * c - s * s) * xy
            self.spread[2][moved] = s * s * xx + 2 * c * s * xy + c * c * yy

    # ------------------------------------------------------------------ what the map says

    @property
    def upper(self) -> np.ndarray:
        """The highest the ground may be per cell (NaN: no bound, nothing may be assumed)."""
        return self.bounds((slice(0, self.geometry.height), slice(0, self.geometry.width)))[1]

    @property
    def lower(self) -> np.ndarray:
        """The lowest the ground may be per cell (NaN: no bound, a hole cannot be ruled out)."""
        return self.bounds((slice(0, self.geometry.height), slice(0, self.geometry.width)))[0]

    def bounds(self, sl: tuple[slice, slice]) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) over the rows and columns ``sl`` (slices with explicit ends).

        A return's range error moves it along its ray, so across cells: the ground before a rock,
        read a few centimetres long, lands on the rock's flank and reads it low; the rock's own
        returns land on the ground around it. So a cell's bounds are the extremes of its own and
        of every cell whose returns may have moved to it, each cell spreading ``k`` sigmas of its
        returns' horizontal error (``spread``) over an ellipse: long along the rays that gave it its
        returns (the range error), narrow across them (the lateral error), a disc where frames
        from other bearings blended it round; at least one cell each way (a rock's flank inside a
        cell shows in its neighbour), at most ``max_shift``."""
        return self._bounds(sl, False)

    def _bounds(self, sl: tuple[slice, slice], as_whole: bool) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`bounds`; ``as_whole``: each cell's edge allowance read from its neighbours on the
        whole map, so that the result is bit for bit the whole map's bounds over ``sl`` (a window
        reads the allowance of its outermost cells from the window alone)."""
        g, p = self.geometry, self.params
        pad = p.max_shift
        r0, r1 = max(0, sl[0].start - pad), min(g.height, sl[0].stop + pad)
        c0, c1 = max(0, sl[1].start - pad), min(g.width, sl[1].stop + pad)
        big = (slice(r0, r1), slice(c0, c1))
        sd = p.k * np.sqrt(self.mean_var[big])
        if as_whole:
            e0, e1 = max(0, r0 - 1), min(g.height, r1 + 1)
            f0, f1 = max(0, c0 - 1), min(g.width, c1 + 1)
            allowance = self.edge_allowance((slice(e0, e1), slice(f0, f1)))[r0 - e0:r1 - e0, c0 - f0:c1 - f0]
        else:
            allowance = self.edge_allowance(big)
        top = self.mean[big] + self.rise[big] + sd + allowance
        bottom = self.mean[big] - self.drop[big] - sd
        seen = np.isfinite(top)
        shape = _spread_shapes(self.spread[:, big[0], big[1]], p.k, g.cell, p.max_shift)
        # a cell no frame gave bounds to (the set-down, the wheels' contacts) holds no return that a
        # range error could have moved: it spreads to no neighbour
        shape = np.where(self.stamp[big] > 0, shape, 0)
        up, lo = _spread(top.astype(np.float32), bottom.astype(np.float32), seen, shape)
        inner = (slice(sl[0].start - r0, sl[0].stop - r0), slice(sl[1].start - c0, sl[1].stop - c0))
        up, lo, seen = up[inner], lo[inner], seen[inner]
        ceiling = self.ceiling[sl]
        upper = np.where(seen, up, np.where(np.isfinite(ceiling), ceiling, np.nan))
        lower = np.where(seen, lo, np.nan)
        return lower.astype(np.float32), upper.astype(np.float32)

    def edge_allowance(self, sl: tuple[slice, slice]) -> np.ndarray:
        """How far a cell's true top may stand over its returns' highest, over the rows and columns
        ``sl``, where a frame bounded it: ``grain`` (the relief within the cell no return met), and
        at a rock's edge ``edge`` times the relief the cell and its 8 neighbours span (the highest
        top less the lowest bottom of their best estimates): a rock's rim and its peak are met by
        few returns, and a return that meets the rim half on it reads a mix of the rim and the
        ground behind (a mixed pixel). Averaging frames narrows the noise but not these, so they
        are what is left when the frames' sigma is small. Fitted on the simulator's truth
        (``python -m tools.bench.bounds --calibrate-edge``, docs/BENCHMARKS.md). The ground the
        body or the set-down bounds has none: no return was drawn there."""
        p = self.params
        framed = self.stamp[sl] > 0
        if p.edge <= 0:
            return np.where(framed, p.grain, 0.0).astype(np.float32)
        from scipy.ndimage import maximum_filter, minimum_filter

        top = np.where(np.isfinite(self.mean[sl]), self.mean[sl] + self.rise[sl], -np.inf)
        bottom = np.where(np.isfinite(self.mean[sl]), self.mean[sl] - self.drop[sl], np.inf)
        span = maximum_filter(top, 3, mode="nearest") - minimum_filter(bottom, 3, mode="nearest")
        return np.where(framed, p.grain + np.where(np.isfinite(span), p.edge * span, 0.0), 0.0).astype(np.float32)

    def bounded(self) -> np.ndarray:
        """Cells with an upper bound: ground the belly may pass over."""
        return np.isfinite(self.mean) | np.isfinite(self.ceiling)

    def rocks(self, centre: tuple[float, float], radius: float, height: float, window: float = 0.3
              ) -> np.ndarray:
        """Global (x, y) of the cells within ``radius`` of ``centre`` whose top stands more than
        ``height`` over the ground round them (the median of the cells' bottoms within
        ``window``, which on a plane slope is the plane under the cell, so a slope alone flags
        nothing): rocks the body cannot pass over or climb, for a planner that keeps its footprint
        off them. The top and bottom are the cell's best estimates (the fused mean with the
        relief within the cell above and below it), not its bounds: the plan is a proposal, and
        the gate checks the worst case from close by, where the bounds are tight; planned on the
        bounds, the far ground's wide ones close every way (the bounds of the mast's frames at
        1.5-3 m stand 2.7 cm over the true tops at p50)."""
        g = self.geometry
        c0 = max(0, int((centre[0] - radius - window - g.xmin) / g.cell))
        c1 = min(g.width, int(math.ceil((centre[0] + radius + window - g.xmin) / g.cell)))
        r0 = max(0, int((g.ymax - centre[1] - radius - window) / g.cell))
        r1 = min(g.height, int(math.ceil((g.ymax - centre[1] + radius + window) / g.cell)))
        if r1 <= r0 or c1 <= c0:
            return np.zeros((0, 2))
        sl = (slice(r0, r1), slice(c0, c1))
        upper, lower = self.mean[sl] + self.rise[sl], self.mean[sl] - self.drop[sl]
        half = max(1, int(round(window / 2 / g.cell)))
        padded = np.pad(lower, half, constant_values=np.nan)
        windows = np.lib.stride_tricks.sliding_window_view(padded, (2 * half + 1, 2 * half + 1))
        with np.errstate(all="ignore"):
            import warnings

            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN windows: unseen ground, no verdict
                ground = np.nanmedian(windows[:, :, ::2, ::2].reshape(*lower.shape, -1), axis=2)
            rock = (upper - ground > height) & np.isfinite(lower)
        rr, cc = np.nonzero(rock)
        x = g.xmin + (c0 + cc + 0.5) * g.cell
        y = g.ymax - (r0 + rr + 0.5) * g.cell
        near = np.hypot(x - centre[0], y - centre[1]) <= radius
        return np.column_stack([x[near], y[near]])

    # ------------------------------------------------------------------ what the rover's body says

    def stood(self, pose: tuple[float, float, float], z: float, body: Any,
              attitude: tuple[float, float, float] | None = None, sigma: float = 0.005,
              tilt: tuple[float, float] = (0.0, 0.0), fill_under: bool = True,
              since: tuple[float, float, float] | None = None) -> None:
        """The rover stands at ``pose`` (x, y, heading deg) with its centre's ground at height ``z``:
        its body is a sensor too, for the ground no frame bounded (the mast never sees within
        about 0.7 m of its foot). Frames outrank it: a cell a frame bounded keeps its bounds.

        - Under each wheel the ground is at the wheel's contact. With ``attitude`` (roll, pitch and
          their 1-sigma, deg, as the rover's IMU gives them: :func:`contact_plane`) the body's
          plane is tipped by it and rests on the ground frames bounded under three or more wheels
          (:meth:`_rest`), else runs through ``z``; no wheel's ground stands above it by more
          than ``contact_sigma`` and the attitude's error over its lever from the centre (a few
          millimetres: the wheel's circle rests on the highest ground under it). A rigid body
          on four wheels rests on three: the fourth may hang over lower ground, which the IMU
          does not show (4.4 cm at marsyard mission 0's start), so the ground under each wheel
          reaches ``hang`` below the plane. This overrides the set-down's prior there, but not
          an earlier stand's reading: back where it stood, a frame's height is off the last one's
          by the frames' disagreement, and moved with it the wheels' ground sank 1.6 cm under the
          framed ground between them, which refused the pose the rover stood on. Without
          an attitude the contacts are taken on the plane through ``z`` rising ``tilt`` (per metre
          along x and y; level by default) within ``sigma``, where nothing else bounds them.
        - Under the box between the wheels proprioception says only that nothing reaches the
          belly: the ground there is bounded from above (a ceiling) at the belly over that plane,
          drawn ``3 k`` contact sigmas lower so that the worst-case check of this very pose, its
          contacts at their extremes, passes. It gives no lower bound (a hole under the box is
          not felt), and it does not replace what the set-down assumed there
          (:meth:`set_down`). With ``fill_under`` the cells nothing holds there are taken as the
          framed ground under the body lies about the plane (:meth:`_fill_under`); a set-down
          fills them from the ring round the blind disc instead.
        - ``since``: the pose the rover stood at for the last call (None: it was set down here).
          Its body passed over the ground between the two, and so stood on it too: each pose
          :func:`swept_poses` takes between them, on the plane the attitude gives here. A frame
          comes every 10 cm of a drive and none during a turn on the spot, so the corners of a
          turn and of an arc passed over ground no frame or stand held; the mast cannot see it
          behind the body, and the rays over it, taken as ground, passed 12 deg left and 4 right
          of a turn on the spot the truth allowed whole."""
        from .vehicle import _pattern

        gx, gy = tilt if attitude is None else contact_plane(pose[2], attitude[0], attitude[1])
        for passed, tipped in swept_poses(since, pose, attitude):
            self.stood(passed, z + gx * (passed[0] - pose[0]) + gy * (passed[1] - pose[1]), body, tipped, sigma, tilt,
                       fill_under)

        g, k = self.geometry, self.params.k
        pat = _pattern(body, g.cell / 2)
        pts, wheel_of, belly = pat.pts, pat.wheel_of, pat.belly
        c, s = math.cos(math.radians(pose[2])), math.sin(math.radians(pose[2]))
        wx = pose[0] + c * pts[:, 0] - s * pts[:, 1]
        wy = pose[1] + s * pts[:, 0] + c * pts[:, 1]
        # every cell a sample's bilinear read touches: the check reads between cell centres
        c0 = np.floor((wx - g.xmin) / g.cell - 0.5).astype(np.int64)
        r0 = np.floor((g.ymax - wy) / g.cell - 0.5).astype(np.int64)
        r = np.concatenate([r0, r0, r0 + 1, r0 + 1])
        col = np.concatenate([c0, c0 + 1, c0, c0 + 1])
        wheel_of, belly = np.tile(wheel_of, 4), np.tile(belly, 4)
        inside = g.inside(r, col)
        flat = r * g.width + col
        on_wheel = inside & (wheel_of >= 0)
        wheels = np.unique(flat[on_wheel])
        xs = g.xmin + (wheels % g.width + 0.5) * g.cell
        ys = g.ymax - (wheels // g.width + 0.5) * g.cell
        rest_var = 0.0
        if attitude is not None:
            rest = self._rest(flat[on_wheel], wheel_of[on_wheel], pose, gx, gy)
            if rest is not None:
                z, rest_var = rest
        if attitude is None:
            blank = ~np.isfinite(self.mean.flat[wheels])
            wheels, xs, ys = wheels[blank], xs[blank], ys[blank]
            height, var = z + gx * (xs - pose[0]) + gy * (ys - pose[1]), np.full(len(wheels), sigma * sigma)
            spread = sigma
        else:
            keep = self.stamp.flat[wheels] == 0  # no frame bounded it
            wheels, xs, ys = wheels[keep], xs[keep], ys[keep]
            height = z + gx * (xs - pose[0]) + gy * (ys - pose[1])
            lever = np.hypot(xs - pose[0], ys - pose[1])
            spread = math.sqrt(self.params.contact_sigma ** 2 + rest_var)
            var = spread ** 2 + (lever * math.tan(math.radians(attitude[2]))) ** 2
            # a stand already there read that ground as well as this one; a prior (twice the sigma
            # or more) gives way
            new = ~(self.mean_var.flat[wheels] <= 4 * var)
            wheels, height, var = wheels[new], height[new], var[new]
        # with the attitude: no higher than the plane (the wheel's circle rests on the highest ground
        # under it), down to ``hang`` below it (the wheel the body does not rest on)
        sag = 0.0 if attitude is None else self.params.hang / 2
        self.mean.flat[wheels] = height - sag
        self.mean_var.flat[wheels] = var
        self.rise.flat[wheels] = sag
        self.drop.flat[wheels] = sag
        self.relief.flat[wheels] = 2 * sag
        self.split.flat[wheels] = 0.0
        self.shift.flat[wheels] = 0.0
        self.along_var.flat[wheels] = 0.0
        under = np.setdiff1d(np.unique(flat[inside & belly]), wheels)
        under = under[self.stamp.flat[under] == 0]
        ux = g.xmin + (under % g.width + 0.5) * g.cell
        uy = g.ymax - (under // g.width + 0.5) * g.cell
        plane = z + gx * (ux - pose[0]) + gy * (uy - pose[1])
        roof = (plane + body.clearance - 3 * k * spread).astype(np.float32)
        self.ceiling.flat[under] = np.minimum(self.ceiling.flat[under], roof)
        if fill_under:
            self._fill_under(under, plane, np.unique(flat[inside]), pose, z, gx, gy)

    def _fill_under(self, under: np.ndarray, plane: np.ndarray, body_cells: np.ndarray,
                    pose: tuple[float, float, float], z: float, gx: float, gy: float) -> None:
        """The ground under the box that nothing holds (``under``: no frame, no prior; ``plane``
        the resting plane over each) is taken as the framed ground under the body (``body_cells``)
        lies about that plane: offset by its median, within its spread (at least
        ``under_sigma``), below the belly's roof. Left with the roof alone, a cell reads as
        ground at the roof (a ceiling with no return), just under the belly, and the chance
        check refused the pose the rover stood on (P 0.9 on the belly, where the truth kept
        7 cm under it)."""
        blank = ~np.isfinite(self.mean.flat[under])
        under, plane = under[blank], plane[blank]
        if not len(under):
            return
        g = self.geometry
        seen = body_cells[(self.stamp.flat[body_cells] > 0) & np.isfinite(self.mean.flat[body_cells])]
        sx = g.xmin + (seen % g.width + 0.5) * g.cell
        sy = g.ymax - (seen // g.width + 0.5) * g.cell
        off = self.mean.flat[seen] - (z + gx * (sx - pose[0]) + gy * (sy - pose[1]))
        enough = len(off) >= MIN_UNDER_CELLS
        sigma = max(self.params.under_sigma, float(np.std(off)) if enough else 0.0)
        self.mean.flat[under] = plane + (float(np.median(off)) if enough else 0.0)
        self.mean_var.flat[under] = sigma * sigma
        for layer in (self.rise, self.drop, self.relief, self.split, self.shift, self.along_var):
            layer.flat[under] = 0.0

    def _rest(self, cells: np.ndarray, wheel_of: np.ndarray, pose: tuple[float, float, float], gx: float,
              gy: float) -> tuple[float, float] | None:
        """The height at the pose's centre of the plane rising (``gx``, ``gy``) the body rests on,
        and its variance, from the ground frames bounded under the wheels (``cells``, each read of
        wheel ``wheel_of``): each wheel's circle rests on the highest ground under it, and a rigid
        body rests on three of its four, so the plane is at the median of the wheels' tops. None
        where frames bounded fewer than three wheels' ground: a frame's own height is then all
        there is, and it stood 7 cm off the truth under a wheel once its registration jumped."""
        framed = (self.stamp.flat[cells] > 0) & np.isfinite(self.mean.flat[cells])
        if not framed.any():
            return None
        g = self.geometry
        cells, wheel_of = cells[framed], wheel_of[framed]
        xs = g.xmin + (cells % g.width + 0.5) * g.cell
        ys = g.ymax - (cells // g.width + 0.5) * g.cell
        off = self.mean.flat[cells] - gx * (xs - pose[0]) - gy * (ys - pose[1])
        tops, var = [], []
        for w in np.unique(wheel_of):
            mine = wheel_of == w
            if np.count_nonzero(mine) < 2:
                continue
            top = int(np.argmax(np.where(mine, off, -np.inf)))
            tops.append(float(off[top]))
            var.append(float(self.mean_var.flat[cells[top]]))
        if len(tops) < 3:
            return None
        order = np.argsort(tops)
        middle = order[len(order) // 2 - (1 - len(order) % 2):len(order) // 2 + 1]
        return float(np.mean(np.asarray(tops)[middle])), float(np.mean(np.asarray(var)[middle]))

    def set_down(self, centre: tuple[float, float], radius: float,
                 z: float | Callable[[np.ndarray, np.ndarray], np.ndarray],
                 sigma: float | Callable[[np.ndarray, np.ndarray], np.ndarray] = 0.01,
                 plane: tuple[float, float, float, float] | None = None) -> None:
        """The ground within ``radius`` of ``centre`` that no frame bounded is taken as level at
        ``z`` (within ``sigma``), or on ``plane`` (x0, y0 where it is at ``z``, and its rise per
        metre along x and y: the plane the rover's attitude says it stands on, or the seen ring's
        round the blind disc): where the rover was set down, or stands for a 360-degree scan, the
        ground round the mast's foot that no tilt shows. ``sigma`` is a height sigma (m) or, per
        cell, a function of the cells' x and y (the ring's spread: :meth:`RingPlane.sigma
        <prox_workflows.algorithms.set_down.RingPlane.sigma>`): how far the ground may stand off
        that plane is what the seen ground round it shows, not what is hoped. Never assumed while
        driving. The wheels' own ground is then known better (:meth:`stood`). ``z`` may also be a
        function of the cells' x and y (``plane`` then unused): the plane conditioned on the ground
        seen beside the cell (:func:`prox_workflows.algorithms.set_down.set_down`)."""
        g = self.geometry
        xs, ys = g.centers()
        near = np.hypot(xs[None, :] - centre[0], ys[:, None] - centre[1]) <= radius
        blank = near & ~np.isfinite(self.mean)
        rows, cols = np.nonzero(blank)
        bx, by = xs[cols], ys[rows]
        if callable(z):
            height = np.asarray(z(bx, by), np.float64)
        elif plane is None:
            height = np.full(len(rows), z)
        else:
            height = z + plane[2] * (bx - plane[0]) + plane[3] * (by - plane[1])
        sd = np.broadcast_to(np.asarray(sigma(bx, by) if callable(sigma) else sigma, np.float64), (len(rows),))
        self.mean[rows, cols] = height
        self.mean_var[rows, cols] = sd * sd
        self.rise[rows, cols] = 0.0
        self.drop[rows, cols] = 0.0
        self.relief[rows, cols] = 0.0
        self.split[rows, cols] = 0.0

    def offset(self, points: np.ndarray, min_cells: int = 100, flat: float = 0.01) -> float | None:
        """How far (m) a frame's returns (global, N x 3), placed at the height its pose gives the
        rover, stand over the ground the map's earlier frames hold: the median, over the cells both
        bound, of the frame's cell mean less the map's. A frame is placed at a height read off the
        map round the rover's centre, which is not where the body rests (its camera rides with the
        plane its wheels rest on, which meets the centre up to 7 cm over the ground there in dense
        rock): frames placed 1-4 cm apart that way
        disagree on the same ground, and the union the fusion keeps of disagreeing frames reads
        as relief no rock has. Only ground the map knows to ``flat`` (its mean's sigma and the
        relief its frames saw within the cell) is compared, where a height error along the ray moves
        no height; a rock dropped onto known ground since is a minority of the overlap, which the
        median ignores. None where fewer than ``min_cells`` compare (the frame is then placed as
        its pose says)."""
        g = self.geometry
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        pts = pts[np.isfinite(pts).all(axis=1)]
        r, c = g.cell_of(pts[:, 0], pts[:, 1])
        inside = g.inside(r, c)
        flat_idx = (r[inside] * g.width + c[inside]).astype(np.int64)
        if not len(flat_idx):
            return None
        cells, index, n = np.unique(flat_idx, return_inverse=True, return_counts=True)
        mean = np.bincount(index, pts[inside, 2], len(cells)) / n
        known = (self.stamp.flat[cells] > 0) & (n >= self.params.min_returns)
        with np.errstate(invalid="ignore"):
            known &= np.sqrt(self.mean_var.flat[cells]) + self.relief.flat[cells] <= flat
        if np.count_nonzero(known) < min_cells:
            return None
        return float(np.median(mean[known] - self.mean.flat[cells[known]]))

    # ------------------------------------------------------------------ fusion

    def fuse(self, points: np.ndarray, sigma: np.ndarray | float, origin: np.ndarray | None = None,
             max_range: float | None = None, sigma_xy: np.ndarray | float = 0.0, sensor: str = "tof",
             sigma_across: np.ndarray | float | None = None) -> int:
        """One frame: global-frame returns ``points`` (N x 3) with their height sigmas ``sigma`` and
        horizontal sigmas ``sigma_xy`` (m; the range error's share along the ground), and the
        sensor's position ``origin`` (3,) for the rays' ceilings (None: returns only). With
        ``sigma_across`` (and ``origin``), ``sigma_xy`` is the horizontal error along each return's
        ray and ``sigma_across`` the error across it (``noise.ray_spread``): the cell's bounds
        spread along the rays; without, ``sigma_xy`` either way (a disc). With
        ``max_range`` (the range the frame was cut at; needs ``origin``), a cell the cut crosses
        takes no bounds from the frame: its returns come from its near part only, and the rest
        (a rock's top beyond the cut) is unseen; their rays still bound the cells they crossed.
        ``sensor`` (one of SENSORS) says how the returns' errors go together (see the module's
        docstring). Returns the cells the frame gave bounds to."""
        if sensor not in SENSORS:
            raise ValueError(f"sensor {sensor!r} is not one of {', '.join(SENSORS)}")
        rho = self.params.stereo_correlation if sensor == "stereo" else 0.0
        g = self.geometry
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        sig = np.broadcast_to(np.asarray(sigma, dtype=np.float64), (len(pts),))
        sig_xy = np.broadcast_to(np.asarray(sigma_xy, dtype=np.float64), (len(pts),))
        across = sig_xy if sigma_across is None or origin is None else \
            np.broadcast_to(np.asarray(sigma_across, dtype=np.float64), (len(pts),))
        keep = np.isfinite(pts).all(axis=1) & np.isfinite(sig) & np.isfinite(sig_xy) & np.isfinite(across)
        if not keep.all():
            pts, sig, sig_xy, across = pts[keep], sig[keep], sig_xy[keep], across[keep]
        self.frames += 1
        if origin is not None and len(pts):
            self._pass_over(np.asarray(origin, dtype=np.float64), pts, sig)
        # each return's horizontal error as a covariance: sig_xy along its ray's bearing, across at
        # right angles (without ``sigma_across``, the same both ways: a disc)
        cells, count, acc = _cell_moments(pts, sig, sig_xy, across, origin, max_range, sigma_across is not None, g)
        n = count.astype(np.float64)
        enough = n >= self.params.min_returns
        if not enough.any():
            return 0
        mean = acc[:, 0] / n
        point_var = acc[:, 1] / n
        # the noise alone makes the highest of n returns stand about sqrt(2 ln n) sigmas over their
        # mean, of its share that is not common to them all; what stands higher is the ground's own
        # relief within the cell. The mean of n returns whose errors correlate by rho has the
        # variance of one times (1 + rho (n - 1)) / n
        allowance = np.sqrt(2.0 * np.log(n) * (1.0 - rho) * point_var)
        mean_var = point_var * (1.0 + rho * (n - 1.0)) / n
        # the mean's horizontal error along the rays averages as its height error does
        along_var = acc[:, 2] / n * (1.0 + rho * (n - 1.0)) / n
        rise = np.maximum(acc[:, 7] - mean - allowance, 0.0)
        drop = np.maximum(mean - acc[:, 8] - allowance, 0.0)
        shift = self.params.k * np.sqrt(acc[:, 3] / n)
        spread = acc[:, 4:7].T / n
        bit = 1 << SENSORS.index(sensor)
        if self.params.stereo_first:
            held = self.sensors.flat[cells]
            enough &= held < bit << 1  # a cell the stereo bounded takes no ToF frame
            self._forget(cells[enough & (held != 0) & (held < bit)])
        self._changed(cells[enough], mean[enough])
        if self.params.disagree != "union":
            enough[enough] = self._settle(cells[enough], mean[enough], mean_var[enough], rise[enough], drop[enough],
                                          sensor)
        cells = cells[enough]
        self._fuse_cells(cells, mean[enough], mean_var[enough], rise[enough], drop[enough], shift[enough],
                         spread[:, enough], along_var[enough])
        self.sensors.flat[cells] |= np.uint8(bit)
        self.stamp.flat[cells] = self.frames
        return int(len(cells))

    def _settle(self, cells: np.ndarray, mean: np.ndarray, var: np.ndarray, rise: np.ndarray, drop: np.ndarray,
                sensor: str) -> np.ndarray:
        """Where a ToF frame and a stereo pair's reading of a cell disagree beyond the gate, the
        ToF's stands (``disagree``): a stereo frame leaves the cells a ToF frame bounded that it
        disagrees with (returned False), and with ``tof_stands`` a ToF frame also replaces what
        only pairs said of the cells it disagrees with. A pair's disagreement with a ToF-bounded
        cell is its own error four times in five, not the ground: kept as the union of both, it
        stood a flat cell's top up to 19 cm over ground a ray had passed 3 cm over, under the
        belly of every path the rover had (docs/NAVIGATE_BENCH.md). Where only pairs bounded the
        cell the log does not tell which is right: near the body a pair's cells are within 2 mm
        of the truth, and a ToF frame taken while driving may be the worse reading, hence the two
        halves apart. Two ToF frames that disagree keep the union."""
        tof = np.uint8(1 << SENSORS.index("tof"))
        held = self.sensors.flat[cells]
        differ = ~self._agrees(cells, mean, var, rise, drop)
        if sensor != "tof":
            return ~(differ & ((held & tof) != 0))
        if self.params.disagree == "tof_stands":
            self._forget(cells[differ & (held != 0) & ((held & tof) == 0)])
        return np.ones(len(cells), bool)

    def _changed(self, cells: np.ndarray, mean: np.ndarray) -> None:
        """Where a frame reads the ground of at least ``changed_cells`` cells ``changed`` over the
        highest the map allowed there, the ground changed (a rock came), and what earlier frames
        said within ``stale_radius`` of those cells is dropped: the frame's own cells take its word
        alone, the rest are unknown until a frame shows them (the chooser refuses or looks first).
        Fused as a disagreement, the union of both stories kept the rock, but the rock's flank
        the frame did not see kept the flat ground seen before, and a turn on the spot swung a
        wheel onto it. Priors (the set-down's, the wheels' under the standing rover) are kept:
        they are what the body feels, not what a frame saw."""
        p = self.params
        if p.changed <= 0.0:
            return
        old = self.mean.flat[cells].astype(np.float64)
        with np.errstate(invalid="ignore"):
            top = old + self.rise.flat[cells] + p.k * np.sqrt(self.mean_var.flat[cells].astype(np.float64))
            risen = (self.stamp.flat[cells] > 0) & (mean - top > p.changed)
        if np.count_nonzero(risen) < p.changed_cells:
            return
        from scipy.ndimage import binary_dilation

        g = self.geometry
        n = int(math.ceil(p.stale_radius / g.cell))
        yy, xx = np.mgrid[-n:n + 1, -n:n + 1]
        near = np.zeros(g.shape, bool)
        near.flat[cells[risen]] = True
        near = binary_dilation(near, structure=xx * xx + yy * yy <= n * n) & (self.stamp > 0)
        # every layer back to what a cell nothing bounded holds, but a ray of this very frame
        rows, cols = np.nonzero(near)
        ray = self.lowered[rows, cols] == self.frames
        for name, fill in _LAYERS:
            if name in ("ceiling", "lowered"):
                getattr(self, name)[rows[~ray], cols[~ray]] = fill
            else:
                getattr(self, name)[..., rows, cols] = fill

    def _forget(self, cells: np.ndarray) -> None:
        """Drop what the frames gave ``cells`` (another sensor's frame takes them over)."""
        self.mean.flat[cells] = np.nan
        self.mean_var.flat[cells] = np.nan
        self.sensors.flat[cells] = 0
        for layer in (self.rise, self.drop, self.relief, self.split, self.shift, self.along_var, *self.spread):
            layer.flat[cells] = 0.0

    def _agrees(self, cells: np.ndarray, mean: np.ndarray, var: np.ndarray, rise: np.ndarray, drop: np.ndarray
                ) -> np.ndarray:
        """Whether one frame's reading of each of ``cells`` lies within ``gate`` sigmas of the
        map's, the cell's relief (as the fusion would blend it) allowed: a frame's mean may differ
        from the map's by other returns of the same cell. A cell no frame bounded agrees."""
        old = self.mean.flat[cells].astype(np.float64)
        old_var = self.mean_var.flat[cells].astype(np.float64)
        first = ~np.isfinite(old)
        with np.errstate(invalid="ignore", divide="ignore"):
            share = np.where(first, 1.0, old_var / (old_var + var))
            room = self.params.gate * np.sqrt(np.where(first, 0.0, old_var) + var)
            for name, new in (("rise", rise), ("drop", drop)):
                before = getattr(self, name).flat[cells].astype(np.float64)
                room = room + before + share * (new - before)
            return first | (np.abs(mean - np.where(first, mean, old)) <= room)

    def _fuse_cells(self, cells: np.ndarray, mean: np.ndarray, var: np.ndarray, rise: np.ndarray,
                    drop: np.ndarray, shift: np.ndarray, spread: np.ndarray, along_var: np.ndarray) -> None:
        """One frame's per-cell mean, its variance, rise, drop, shift, error ellipse and the mean's
        horizontal variance along the rays into the map."""
        k = self.params.k
        old = self.mean.flat[cells].astype(np.float64)
        old_var = self.mean_var.flat[cells].astype(np.float64)
        first = ~np.isfinite(old)
        old = np.where(first, mean, old)
        old_var = np.where(first, np.inf, old_var)
        fused_var = 1.0 / (1.0 / old_var + 1.0 / var)
        fused = (old / old_var + mean / var) * fused_var
        # rise, drop and shift are averaged as the mean is: a frame's noise lifts its own highest
        # return past the allowance now and then, and a running maximum would keep every such lift
        share = np.where(first, 1.0, fused_var / var)
        # the fused mean is the map's and the frame's weighted by their height variances: its
        # horizontal error is theirs in those weights (independent frames)
        old_along = self.along_var.flat[cells].astype(np.float64)
        self.along_var.flat[cells] = share**2 * along_var + np.where(first, 0.0, (1.0 - share) ** 2 * old_along)
        blended = {}
        for name, new in (("rise", rise), ("drop", drop), ("shift", shift)):
            before = getattr(self, name).flat[cells].astype(np.float64)
            blended[name] = before + share * (new - before)
        old_rise, old_drop = self.rise.flat[cells], self.drop.flat[cells]
        agree = self._agrees(cells, mean, var, rise, drop)
        before = self.relief.flat[cells].astype(np.float64)
        self.relief.flat[cells] = before + share * (rise + drop - before)
        # disagreeing: the union of both intervals, around the fused mean, and how far apart the two
        # stories' tops stand (agreeing, that fades as the rise does)
        with np.errstate(invalid="ignore"):
            tops = (old + old_rise + k * np.sqrt(old_var), mean + rise + k * np.sqrt(var))
            up = np.maximum(*tops)
            lo = np.minimum(old - old_drop - k * np.sqrt(old_var), mean - drop - k * np.sqrt(var))
            apart = np.nan_to_num(np.abs(tops[0] - tops[1]), nan=0.0, posinf=0.0)
        before = self.split.flat[cells].astype(np.float64)
        self.split.flat[cells] = np.where(agree, before * (1.0 - share), apart)
        sd = np.sqrt(fused_var)
        self.mean.flat[cells] = fused
        self.mean_var.flat[cells] = fused_var
        self.rise.flat[cells] = np.where(agree, blended["rise"], np.maximum(up - fused - k * sd, 0.0))
        self.drop.flat[cells] = np.where(agree, blended["drop"], np.maximum(fused - lo - k * sd, 0.0))
        self.shift.flat[cells] = np.where(agree, blended["shift"], np.maximum(self.shift.flat[cells], shift))
        # the error ellipse is blended as the shift is (frames from other bearings round it); where
        # the frame disagrees, both ellipses' extents are kept (their sum holds each)
        for i in range(3):
            before = self.spread[i].flat[cells].astype(np.float64)
            self.spread[i].flat[cells] = np.where(agree, before + share * (spread[i] - before), before + spread[i])

    def _pass_over(self, origin: np.ndarray, pts: np.ndarray, sig: np.ndarray) -> None:
        from ._bounds_kernels import lower_ceiling

        g = self.geometry
        heights = pts[:, 2] + self.params.k * sig  # the ray's height may be off as its return's is
        before = self.ceiling.copy()
        lower_ceiling(float(origin[0]), float(origin[1]), float(origin[2]),
                      np.ascontiguousarray(pts[:, 0]), np.ascontiguousarray(pts[:, 1]),
                      np.ascontiguousarray(heights), float(g.xmin), float(g.ymax), float(g.cell),
                      float(max(self.params.near, g.cell)), float(self.params.reach), self.ceiling)
        self.lowered[self.ceiling < before] = self.frames

    def whole(self) -> tuple[np.ndarray, np.ndarray]:
        """The lower and upper bounds over the whole map (read-only), as :meth:`bounds` over it
        gives them. Kept between calls (``_whole``): the inputs are compared with those of the last
        call, and only the cells a changed cell's spread and edge allowance reach are computed again.
        A choice reads the whole map (its cost to go) and a frame changes a few square metres of
        it: this is a tenth of the work of the whole map (``python -m tools.bench.choice``)."""
        g, p = self.geometry, self.params
        inputs = self._bound_inputs()
        key = (p.k, p.max_shift, p.edge, p.grain, g.cell, g.shape, g.xmin, g.ymax)
        held = getattr(self, "_whole", None)  # (none on a map unpickled from a dump without the field)
        if held is None or held[0] != key:
            lower, upper = self.bounds((slice(0, g.height), slice(0, g.width)))
        else:
            _, before, lower, upper = held
            changed = np.zeros(g.shape, bool)
            for now, then in zip(inputs, before, strict=True):
                diff = now.view(np.uint32) != then.view(np.uint32)
                changed |= diff.any(axis=0) if diff.ndim == 3 else diff
            rows, cols = np.flatnonzero(changed.any(axis=1)), np.flatnonzero(changed.any(axis=0))
            if len(rows):
                # a changed cell moves its own bounds, its neighbours' edge allowance (3 x 3) and
                # the bounds of every cell their spread reaches (at most max_shift cells)
                reach = p.max_shift + 1
                sl = (slice(max(0, rows[0] - reach), min(g.height, rows[-1] + 1 + reach)),
                      slice(max(0, cols[0] - reach), min(g.width, cols[-1] + 1 + reach)))
                lower, upper = lower.copy(), upper.copy()
                lower[sl], upper[sl] = self._bounds(sl, True)
        lower.setflags(write=False)
        upper.setflags(write=False)
        self._whole = (key, inputs, lower, upper)
        return lower, upper

    def _bound_inputs(self) -> tuple[np.ndarray, ...]:
        """Copies of every layer :meth:`bounds` reads (as 32-bit words: compared bit for bit)."""
        return tuple(a.copy() for a in (self.mean, self.mean_var, self.rise, self.drop, self.spread, self.stamp,
                                        self.ceiling))

    def window(self, xmin: float, ymin: float, xmax: float, ymax: float
               ) -> tuple[np.ndarray, np.ndarray, GridGeometry]:
        """The lower and upper bounds over a box (clipped to the map), with its grid: what a
        check of the motions inside the box reads."""
        sl, sub = self._box(xmin, ymin, xmax, ymax)
        if sl is None:
            empty = np.full((0, 0), np.nan, np.float32)
            return empty, empty, sub
        lower, upper = self.bounds(sl)
        return lower, upper, sub

    def statistics(self, xmin: float, ymin: float, xmax: float, ymax: float
                   ) -> tuple[dict[str, np.ndarray], GridGeometry]:
        """What the bounds are drawn from over a box (copies, clipped to the map), with its grid:
        ``mean``, ``mean_var`` (the fused mean's variance), ``rise``, ``drop``, ``relief`` (the
        returns' rise plus drop within a frame, averaged: the part of the spread frames agree on),
        ``split`` (where frames disagreed, how far under the top the other frame's top stands), ``shift``,
        ``along_var`` (the fused mean's horizontal variance along the rays), ``ceiling`` and
        ``framed`` (a frame bounded it; else its mean is a prior's: the set-down's, the wheels'
        contacts) per cell. A check that weighs how likely the ground is rather than its extremes
        reads these (``chance.posterior``), and the bounds drawn from them (``lower``, ``upper``)."""
        sl, sub = self._box(xmin, ymin, xmax, ymax)
        names = ("mean", "mean_var", "rise", "drop", "relief", "split", "shift", "along_var", "ceiling")
        if sl is None:
            return {name: np.full((0, 0), np.nan, np.float32) for name in (*names, "lower", "upper")} | \
                {"framed": np.zeros((0, 0), bool)}, sub
        out = {name: getattr(self, name)[sl].copy() for name in names}
        out["framed"] = self.stamp[sl] > 0
        out["lower"], out["upper"] = self.bounds(sl)
        return out, sub

    def _box(self, xmin: float, ymin: float, xmax: float, ymax: float
             ) -> tuple[tuple[slice, slice] | None, GridGeometry]:
        """The rows and columns of the map over a box and their grid (None and a 1-cell grid
        where the box misses the map)."""
        g = self.geometry
        c0 = max(0, int(math.floor((xmin - g.xmin) / g.cell)))
        c1 = min(g.width, int(math.ceil((xmax - g.xmin) / g.cell)))
        r0 = max(0, int(math.floor((g.ymax - ymax) / g.cell)))
        r1 = min(g.height, int(math.ceil((g.ymax - ymin) / g.cell)))
        if r1 <= r0 or c1 <= c0:
            return None, GridGeometry(g.cell, g.xmin, g.ymax, 1, 1, g.crs)
        sub = GridGeometry(g.cell, g.xmin + c0 * g.cell, g.ymax - r0 * g.cell, c1 - c0, r1 - r0, g.crs)
        return (slice(r0, r1), slice(c0, c1)), sub


def warm_up() -> None:
    """Compile (or load from numba's cache) the fusion's kernels now, rather than in the see loop's
    first cycle: a frame's sums, its rays' ceilings and the bounds' spread."""
    bounds = BoundsMap(GridGeometry(0.025, 0.0, 0.25, 10, 10))
    points = np.array([[0.10, 0.10, 0.00], [0.15, 0.12, 0.01], [0.20, 0.05, 0.02]])
    bounds.fuse(points, 0.005, origin=np.array([-1.0, 0.1, 1.0]), sigma_xy=0.01, sigma_across=0.005)
    bounds.whole()
