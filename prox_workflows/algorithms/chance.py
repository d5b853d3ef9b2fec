"""The vehicle check as a chance constraint: the probability, given the map, that the body at a pose
exceeds each of its physical limits, against a declared risk ``epsilon`` (p-ACE, Ghosh, Otsu and
Ono 2018, in place of ACE's hard bounds).

The worst-case check on a bounds map (:func:`vehicle.check_poses` on ``(lower, upper)``) puts every
one of the 100-500 cells under the body at its extreme at once, each ``k`` sigmas out and dilated
by the largest horizontal error in every direction: on flat ground known to +-3 cm it already
lifts the ground under the box into the belly over wheels resting 3 cm low, and refuses. Here each cell's ground is a distribution
(:func:`posterior`), and a pose is safe when P(any limit exceeded) <= epsilon.

**The cell's posterior** (:func:`posterior`, from :meth:`BoundsMap.statistics`): the cell's top,
mean + rise, with five variances:

- the fused mean's variance (``mean_var``: the returns' height variance over their number, fused
  over frames, so averaging frames narrows it);
- the range error along the ray: a mean read long or short stands for ground a little further or
  nearer along the ray, a height error of the ground's slope *along the ray* times that shift. The
  shift's sigma is the mean's own range error, horizontally: its height sigma over the tangent of
  the ray's elevation, seen from ``viewpoint`` (averaged, as the height is; never more than one
  return's horizontal sigma, ``shift / k``). Without a viewpoint (a map fused from many places)
  the map's own ``along_var`` gives it: the returns' horizontal errors along their rays averaged
  over the returns and frames as their heights are; the slope is then the steepest. One return's
  sigma would overstate it by the root of the returns fused: on hirise's 2.5 cm cells it puts
  1 % of the cells under a standing rover at 2-3 cm sigma where the truth is smooth, and the
  steps the draws make between such cells refuse turns on the spot the truth allows with 6 cm to
  spare (docs/NAVIGATE_BENCH.md). Across the ray, and on flat ground, it adds nothing;
- the relief no return met: the true top of a cell stands over the highest of its returns
  now and then by a few millimetres (``top_sigma``, on every cell);
- the rock edge: where the map's worst case allows ground J higher than the cell's top within
  its 3 x 3 neighbourhood (:func:`headroom`: a rock's edge, its bounds spread along the returns'
  horizontal errors, or ground behind it only a ray bounds), the cell reads its top
  ``edge_bias * J`` low, with a further sigma ``edge_sigma * J`` that is one error for every
  cell under the body (``Posterior.common``: drawn once per surface): a rock's top read low is
  read low in each of its cells, and the wheel resting on it, the step up to it and the belly over
  it move together (drawn apart per cell, the errors partly cancel between the cells a body
  sample reads and in the highest of a wheel's samples). Calibrated on the simulator's true
  surface so that the 99.9th percentile of the truth over the top is 3.09 sigmas in each
  band of J (``python -m tools.bench.chance --calibrate``, docs/BENCHMARKS.md): the cells' errors
  there have tails far heavier than a normal's (a rock top no return met), and a sigma fitted to
  their spread alone put the truth 10-20 sigmas out in 1 cell in 1,000;
- the rock's top: a rock's flat top, where J is small, is read low as a whole (the cells of an
  18 cm rock under a wheel 1-2 cm each), which no per-cell sigma carries: drawn apart, the cells'
  errors cancel in the contact and the belly's highest ground. A further common sigma
  ``rock_sigma * H``, H the cell's height over the lowest top within ``ROCK_WINDOW``
  (:func:`relief`). Its share is chosen at the pose level, on the false safes against the truth
  (docs/BENCHMARKS.md), not per cell: per cell the marginals above already hold. One common
  draw moves the wheels' rocks with the belly's, so it leaves the belly's margin where two rocks
  under one body are read apart (dense's misses: the belly's rock read 1.5-2.3 cm low, the
  wheels' contacts right); drawn as a field over 0.1-0.5 m it catches them, but keeps no more
  truly safe poses than a smaller epsilon catching as many (docs/NAVIGATE_BENCH.md, "Dense's
  false safes traced"), so it stays one draw.

**A prior's error** (a cell no frame bounded: the set-down's blind disc, the wheels' contacts) is
the ground's off the prior's plane, which the true ground shares with its neighbours (correlated
0.95-0.98 between neighbouring 2.5 cm cells, 1/e at 20-30 cm); the frames' averaged noise is each
cell's own (0.1-0.2 between neighbours near the sensor, gone by 7.5-10 cm far; ``python -m
tools.bench.chance --correlation``). So a prior's variance goes ``1 - prior_own`` into a field
shared by neighbouring cells (``Posterior.shared``: smoothed white noise, correlated 1/e at
``shared_length``), the rest its own: drawn apart, a prior known to 3 cm steps 4.3 cm (sd) between
neighbours and refuses every wheel on it. The rock edge and the rock's top are a frame's errors,
calibrated on frames: a prior's cells carry neither, nor lend their upper bound (the prior's own
sigma) to a framed neighbour's edge; its plane's slope is no rock.

**The probability** (:func:`chance_check`): surfaces are drawn from the cells' posteriors (seeded,
every cell's own error independently, the shared field, the common one once per surface;
``samples`` of them)
and each is judged by :func:`vehicle.check_poses`, the one definition of the limits: per pose and limit, the samples' excesses give the share over
the limit and a normal tail from their mean and spread, whichever is higher (``samples`` draws
alone cannot show a probability below about 1 / samples; the tail reaches epsilon, and it is
measured against the truth by the pose-level statistics). P(any) is the share of samples over
any limit or the sum of the four tails (the union bound), whichever is higher. A prior's draws
stop at its ceiling (the belly the rover stood over that ground with, or a ray), and the normal
fitted to the belly's intrusion does not: where the belly's tail alone decides, it is also fitted
to the same draws with those cells at their ceilings, an upper bound on each draw's intrusion
whose spread is the wheels', and the lower of the two counts (:func:`_ceiling_z`).

**Where a wheel rests** (``ChanceParams.within``): a cell's top is
its highest ground, the right ground for the belly and the wrong one for a wheel whose footprint's
end meets a rock's edge cell, and a ray's height is no ground for a wheel at all. Read as one
surface, both lift the wheels' resting plane over the belly's contact: the false safes on rock
draws no setting was tuned on are that (the trace in docs/NAVIGATE_BENCH.md, "The stated risk on
untuned draws" and "The stated risk on draws 70-92"), not an overconfident sigma. Above 0, each
drawn surface is judged as a pair (:func:`_judge`): the tops for the belly, and lows ``within``
times the cell's relief under them (none where only a ray bounds the ground) on which each wheel
rests, one plane per draw, read between the cell centres as one surface is. The relief is the
one each frame's returns show in the cell (the map's ``relief``), on cells a frame bounded: where
frames disagree the map's rise and drop also hold how far apart the frames put the same ground,
and taken as relief that lowered every wheel on ground read high and stopped marsyard's first
mission 0.19 m from its start. Not the worst corner of a box of rests
between the lows and the tops: a draw is one ground, and that worst case within every draw leaned
the box's edge 2-3 cm into the belly at the refused turns of marsyard's stops (docs/NAVIGATE_BENCH.md,
"The `within` 1 stops, traced against the truth"). Nor the steepest plane within every cell's
pair for the grade: a draw's grade is the plane fitted to its middles, as the truth's is to its
one grid (the steepest read a uniform 9 deg slope at 9.6).

Poses are first screened by the worst-case check on bounds :func:`screen_k` sigmas out (of both
errors), which makes the chance that any cell under the body lies outside them at most
``SCREEN * epsilon`` (a union bound over the cells): a pose safe there is safe with P below that,
and is not sampled. That check also says which poses are ``unknown``: ground under the body with no
upper bound (no return, no ray over it), or a wheel mostly over ground with no return, by the same
rule as the worst-case check. A ray's ceiling with no return stands in as the ground's height in
the samples: the highest it may be (``under_ray``: anywhere between the ground seen round it and
the ray, each draw its own).
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from functools import lru_cache
from statistics import NormalDist
from typing import Any

import numpy as np

from rvs_params import Settings, param
from rvs_params.deferred import deferred

from ..grid import GridGeometry
from .vehicle import LIMITS, PoseChecks, VehicleBody, _pattern, _sample, check_poses

ndimage = deferred("scipy.ndimage")
special = deferred("scipy.special")

__all__ = ["ChanceParams", "ChanceChecks", "Posterior", "posterior", "chance_check", "surfaces", "SCREEN"]

EARLY = 8  # draws between the checks for a pose already refused (``verdict_only``)
SCREEN = 0.1  # the share of epsilon the screen may spend: a pose it clears has P(any) below this times epsilon
ROCK_WINDOW = 0.2  # m: the ground round a cell its rock stands on
# m: a rock's back the mast cannot see goes on this far past its seen cells (dense draw 310: its
# hidden 20 cm step under rays 2.5-3.5 cm from the seen top, open ground 5-7.5 cm from it)
HIDDEN_BACK = 0.05
STORY_SEED = 7919  # the stories' coins are drawn from the seed this far on: a stream of their own
TILE = 256  # cells: the drawn errors repeat this far apart (6.4 m at 2.5 cm; a body reads less than 1 m)
_MIN_ELEVATION = 0.05  # tan: a ray grazing flatter than this is taken at it (its horizontal error is bounded by shift)


@dataclass
class ChanceParams(Settings):
    """The chance-constrained vehicle check: the risk it accepts and how its probabilities are made."""

    epsilon: float = param(3e-4, "a pose is safe when the probability that it exceeds any physical limit, "
                                 "given the map, is at most this. Chosen on the pose-level false safes against the "
                                 "truth (tools.bench.chance --risk --look approach, the chooser's posterior). On "
                                 "fresh draws 190-219: marsyard / hirise / dense 0 / 4 / 6 false safes in 48,158 / "
                                 "47,178 / 45,252 judged poses, 95 % bounds 6.2e-5 / 1.9e-4 / 2.6e-4, keeping "
                                 "59.8 / 46.6 / 40.9 % of all truly safe poses (dense over 125-139 and 190-219: "
                                 "3.4e-4). 5e-5 makes 0 / 3 / 3 (bounds up to 1.7e-4) and keeps 1.6-2.8 points "
                                 "fewer, but stops marsyard's mission 0 6.3 m short where 3e-4 reaches it: reach "
                                 "traded for margin (docs/NAVIGATE_BENCH.md, Dense's stated risk: epsilon chosen "
                                 "on the pose-level statistics). On fresh draws 310-337, 44,268 / 43,567 / 41,395 judged poses: "
                                 "2 / 2 / 10 false safes, 95 % bounds 1.4e-4 / 1.5e-4 / 4.1e-4 (dense's 14 looks "
                                 "324-337 alone: 5.7e-4)", min=1e-9, max=0.5)
    samples: int = param(64, "surfaces drawn from the cells' posteriors for each check (a normal tail over "
                             "their excesses reaches probabilities below 1 / samples)", min=8, max=4096)
    seed: int = param(0, "seed of the drawn surfaces: the same map and poses give the same verdict",
                      min=0, max=2**31 - 1)
    edge_bias: float = param(0.045, "a cell's top reads low by this share of how much higher the map's upper "
                                   "bound allows the ground within its 3 x 3 neighbourhood (a rock edge; "
                                   "calibrated on marsyard's true surface: python -m tools.bench.chance "
                                   "--calibrate)", min=0.0, max=1.0)
    top_sigma: float = param(0.005, "the true top of a cell stands over its returns' estimate by the relief no "
                                    "return met: this sigma on every cell (calibrated alike)", unit="m",
                             min=0.0, max=0.1)
    rock_sigma: float = param(0.2, "a rock's top is read low as a whole: a sigma common to the cells under a body, "
                                   "as a share of the cell's height over the lowest top within 0.2 m (chosen on "
                                   "the false safes against the truth of two marsyard draws: python -m "
                                   "tools.bench.chance --rock-sigma)", min=0.0, max=1.0)
    rock_sigma_max: float = param(1.0, "the rock top's common sigma (rock_sigma x H) at most this. Away from an "
                                       "edge a rock's top is read low by the apex its returns miss, which does not "
                                       "grow with the rock's height: p99.9 1.8-3.1 cm in every band of H from 2 cm "
                                       "to over 16 cm (python -m tools.bench.chance --rock-top, draws 1-6), where "
                                       "0.2 H declares up to 4.1 cm. But capped at 1.5 / 1 cm the stated risk on "
                                       "draws 240-249 kept 0.4-1.1 / 0.9-1.8 points more truly safe poses, and the "
                                       "false safes went from 3 to 5 / 6 on hirise (belly) and from 1 to 3 / 6 on "
                                       "dense (3.6 cm step misses: a wheel at a rock's back edge over a drop into "
                                       "ground only a ray bounds, a step the judged pair leaves out, which the tall "
                                       "rock's sigma had refused); with that step judged, still 3 to 4 / 5 on "
                                       "hirise: 1 m, none (docs/NAVIGATE_BENCH.md)", unit="m", min=0.0, max=1.0)
    shared_length: float = param(0.2, "a prior's error (the set-down's blind disc, the wheels' contacts: ground no "
                                      "frame bounded) is the ground's off the prior's plane, shared by neighbouring "
                                      "cells: drawn as smoothed white noise whose correlation falls to 1/e at this "
                                      "distance (m). The true ground off its plane over the blind disc is correlated "
                                      "0.95-0.98 between neighbouring 2.5 cm cells, 0.69-0.82 at 10 cm and 0.38-0.59 "
                                      "at 20 cm (python -m tools.bench.chance --correlation, 9 looks)", unit="m",
                                 min=0.0, max=2.0)
    prior_own: float = param(0.05, "the share of a prior's variance that each cell has of its own (drawn apart): "
                                   "the true ground's roughness at the cell's scale, which the shared field, "
                                   "smooth at a cell's scale, leaves out (with shared_length it puts the draws' "
                                   "correlation at 0.94 / 0.89 / 0.74 / 0.35 at 2.5 / 5 / 10 / 20 cm)",
                             min=0.0, max=1.0)
    edge_sigma: float = param(0.17, "a rock edge's further uncertainty (1 sigma), as a share of the same height "
                                    "(calibrated alike, on the 99.9th percentile)", min=0.0, max=2.0)
    within: float = param(1.0, "a cell's top holds somewhere in the cell, not all over it: above 0, a drawn surface "
                               "is judged as a pair, the belly over the tops and each wheel resting on the lows: the "
                               "top less this share of the cell's relief as its frames see it (its returns' rise "
                               "over their mean and drop under it, averaged over the frames; not the spread the "
                               "frames' disagreement adds) on cells a frame bounded, and on nothing where only a ray "
                               "bounds the ground; 0: one surface, the top and the ray's height read as the ground "
                               "all over each cell, which lifts the wheels' resting plane over rock edges and "
                               "unseen ground: 17 / 15 / 19 false safes in 30,545 / 28,928 / 28,322 judged poses of "
                               "marsyard / hirise / dense draws 125-139 where 1 has 0 / 4 / 9 in 24,121 / 23,072 / "
                               "22,456 (docs/NAVIGATE_BENCH.md, Dense's false safes traced)", min=0.0, max=1.0)

    under_ray: float = param(0.0, "where only a ray's ceiling bounds a cell (no return: a rock's shadow, the blind "
                                  "disc's rim), how far under the ceiling its ground may lie: 0, at the ceiling, the "
                                  "highest it may be; 1, anywhere between the lowest top seen within 0.2 m and the "
                                  "ceiling, uniformly (each draw its own; the best estimate halfway), except within "
                                  "5 cm of a seen rock standing over the middle of that depth, whose back may go on "
                                  "under the ray (the ceiling kept there). At the "
                                  "ceiling a shadow's edge reads as a step up to the ray, which refused 66 of "
                                  "marsyard mission 1's 74 section step refusals, all on truly safe ground; as no "
                                  "edge at all it let a rock's hidden back (a 20 cm step at dense draw 310) pass. "
                                  "Without the 5 cm rule, 1 kept 2-8 points more of the truly safe poses and "
                                  "raised dense's 95 % bound on draws 324-337 from 5.7e-4 to 7.5e-4; with it, the "
                                  "same false safes as 0 over draws 300-337 and 0.5-1.1 points more kept, the rim "
                                  "cells beside a standing rover read at the ceiling as before: off "
                                  "(docs/NAVIGATE_BENCH.md, A ray's ceiling: no ground, no edge, or between)",
                            min=0.0, max=1.0)
    rest_tops: bool = param(False, "with within above 0: stability is also judged with each wheel raised onto the "
                                   "top of every cell wholly inside its footprint (a cell's top lies somewhere in "
                                   "it; within's low is right for a cell the footprint's edge cuts, not for one the "
                                   "wheel covers whole), the worse plane counting; the belly keeps the lows' planes. "
                                   "On untuned draws 300-309: hirise's false safes 5 to 3 (95 % bound 6.5e-4 to "
                                   "4.8e-4, its two stability misses on rough 23-30 deg slopes gone), marsyard 0 "
                                   "and dense 1 as before, 0.1-0.2 points fewer truly safe kept; raised for the belly "
                                   "as well, hirise's belly misses rose 2 to 8 (docs/NAVIGATE_BENCH.md). Off: on fresh "
                                   "draws 310-323 it changes no false safe, and marsyard's missions 0-4 and hirise's "
                                   "0 run the same with it")
    stories: bool = param(False, "where two frames disagreed on a cell (the map's split), each draw takes the "
                                 "cell's ground as one frame's story or the other's, one story over a patch of "
                                 "shared_length, for the wheel and the belly alike; off: the union's top, the higher story, on "
                                 "which a wheel rests as high as either frame read it and lifts the plane over "
                                 "the belly (dense_fresh 0's false safes). On dense_fresh 5: 5 false safes in "
                                 "110,271 judged poses (the union 9 in 70,786), and a safe stop 8.1 m short where "
                                 "the union reached its goal (docs/NAVIGATE_BENCH.md, A disagreeing cell: either "
                                 "frame's story)")


@dataclass(frozen=True)
class Posterior:
    """Per cell of one grid: the ground's top (m; its best estimate, NaN where no return bounds it),
    the variance of its error of its own (m^2: independent of its neighbours'), the sigma of its
    share of an error common to the cells under a body (m; the rock edge's and the rock top's: a
    rock read low is read low in each of its cells), the lowest ray that passed over it (m; inf:
    none), and the sigma of its share of an error it shares with its neighbours (m; a prior's:
    drawn as a field correlated over ``ChanceParams.shared_length``). The top's variance is
    var + shared^2 + common^2. ``span`` (None: one surface): a drawn surface is then a pair of
    bounds, the top and ``span`` under it (none where only a ray bounds the ground), judged with the
    belly over the tops and each wheel resting on the lows (:func:`_judge`)."""

    mean: np.ndarray
    var: np.ndarray
    ceiling: np.ndarray
    common: np.ndarray | float = 0.0
    shared: np.ndarray | float = 0.0
    span: np.ndarray | None = None  # m: how far under its top the cell's ground may lie where a wheel rests
    # m: where frames disagreed, how far under the top the other frame's story puts it (each draw one)
    split: np.ndarray | None = None

    def best(self) -> np.ndarray:
        """The ground's best estimate: the top where a return bounds the cell, else the lowest ray
        that passed over it (the ground lies under it), NaN where neither; a prior's held under its
        ceiling (:func:`_under_roof`)."""
        best = np.where(np.isfinite(self.mean), self.mean, np.where(np.isfinite(self.ceiling), self.ceiling, np.nan))
        return _under_roof(best, self.shared, self.ceiling)

    def window(self, sl: tuple[slice, slice]) -> Posterior:
        """The posterior over the rows and columns ``sl`` (a window of its grid)."""
        def cut(a: np.ndarray | float) -> np.ndarray | float:
            return a if np.ndim(a) == 0 else a[sl]
        return Posterior(self.mean[sl], self.var[sl], self.ceiling[sl], cut(self.common), cut(self.shared),
                         None if self.span is None else self.span[sl], None if self.split is None else self.split[sl])


@dataclass
class ChanceChecks:
    """Per-pose results of :func:`chance_check` (N poses), shaped as :class:`vehicle.PoseChecks` is
    (``safe``, ``unsafe``, ``unknown``) so that a gate or a search takes either check."""

    prob: np.ndarray  # (N, 4) P(exceeding) per limit (LIMITS order); 0 where screened, NaN where unknown
    p_any: np.ndarray  # (N,) P(exceeding any limit); 0 where screened, NaN where unknown
    unknown: np.ndarray  # (N,) bool: ground under the body the map does not cover (never safe)
    screened: np.ndarray  # (N,) bool: cleared by the worst case screen_k sigmas out (P(any) < SCREEN * epsilon)
    nominal: PoseChecks  # the check on the posterior's best estimate (which limit is closest, by how much)
    epsilon: float
    z: np.ndarray  # (N, 4) the draws' mean excess over their spread per limit; -inf screened, NaN not drawn

    @property
    def unsafe(self) -> np.ndarray:
        return self.p_any > self.epsilon

    @property
    def safe(self) -> np.ndarray:
        """Judged, and within every limit with probability at least 1 - epsilon."""
        return ~self.unsafe & ~self.unknown

    def worst(self) -> tuple[np.ndarray, np.ndarray]:
        """Per pose, the limit most likely exceeded (LIMITS index) and that probability."""
        p = np.nan_to_num(self.prob, nan=-1.0)
        k = np.argmax(p, axis=1)
        return k, self.prob[np.arange(len(k)), k]

    def kind(self, i: int, k: int) -> str:
        return self.nominal.kind(i, k) if k == 0 else LIMITS[k]


def posterior(stats: dict[str, np.ndarray], geom: GridGeometry, k: float, params: ChanceParams | None = None,
              viewpoint: Any = None) -> Posterior:
    """Each cell's ground from a bounds map's statistics over ``geom`` (:meth:`BoundsMap.statistics`;
    ``k`` the map's, by which its ``shift`` is drawn), seen from ``viewpoint`` (x, y, z of the
    sensor; None: the ray's direction unknown, so the slope's steepest direction and one return's
    horizontal sigma stand in, averaged as the mean is where ``stats`` has ``along_var``). See the
    module's docstring for the five variances."""
    p = params or ChanceParams()
    mean = np.asarray(stats["mean"], np.float64)
    top = mean + np.asarray(stats["rise"], np.float64)
    var0 = np.asarray(stats["mean_var"], np.float64)
    per_return = np.asarray(stats["shift"], np.float64) / max(k, 1e-9)  # one return's horizontal sigma
    seen = np.isfinite(top)
    xs, ys = geom.centers()
    X, Y = np.meshgrid(xs, ys)
    c = geom.cell
    filled = np.where(seen, top, np.nan)
    if viewpoint is not None:
        v = np.asarray(viewpoint, np.float64)
        d = np.maximum(np.hypot(X - v[0], Y - v[1]), 1e-6)
        ux, uy = (X - v[0]) / d, (Y - v[1]) / d
        tan_elev = np.maximum((v[2] - np.where(seen, top, 0.0)) / d, _MIN_ELEVATION)
        along = np.minimum(np.sqrt(np.maximum(var0, 0.0)) / tan_elev, per_return)
        ahead = _sample(filled, geom, X + c * ux, Y + c * uy)
        behind = _sample(filled, geom, X - c * ux, Y - c * uy)
        with np.errstate(invalid="ignore"):
            slope = np.fmax(np.abs(ahead - top), np.abs(top - behind)) / c
    else:
        averaged = stats.get("along_var")
        along = per_return if averaged is None else \
            np.minimum(np.sqrt(np.maximum(np.asarray(averaged, np.float64), 0.0)), per_return)
        gy, gx = np.gradient(np.where(seen, top, np.nan), c)
        slope = np.hypot(gx, gy)
    slope = np.nan_to_num(slope, nan=0.0)
    # a prior's error (no frame bounded the cell: the set-down's plane, the wheels' contacts) is the
    # plane's and the ground's off it, shared with the cells round it; the frames' averaged noise
    # is each cell's own. A rock's edge or top read low is a frame's error, a framed cell's alone:
    # on a prior's cells it counted the prior's own sigma again as a rock edge and its plane's
    # slope as a rock's height, and refused the start's turn where the truth left the belly 6 cm
    # (docs/NAVIGATE_BENCH.md, A prior's cells carry the prior's error alone)
    prior = seen & ~np.asarray(stats.get("framed", seen), bool)
    framed = seen & ~prior
    jump = headroom(stats, top, prior)
    var = np.where(prior, p.prior_own, 1.0) * var0 + p.top_sigma**2 + (slope * along) ** 2
    mu = top + p.edge_bias * jump
    ceiling = np.asarray(stats.get("ceiling", np.full(mean.shape, np.inf)), np.float64)
    # a cell's relief as the frames see it: where frames disagree, rise and drop also hold how far
    # apart they put the same ground (the frames' height error, shared by a wheel and the belly
    # beside it), which lowered the wheels' rest under ground read high and refused the start of
    # marsyard's missions (docs/NAVIGATE_BENCH.md, The stated risk on draws 70-92)
    within = np.asarray(stats["relief"], np.float64) if "relief" in stats else \
        np.asarray(stats["rise"], np.float64) + np.asarray(stats["drop"], np.float64)
    return Posterior(np.where(seen, mu, np.nan), np.where(seen, var, np.nan), ceiling,
                     np.where(framed, np.hypot(p.edge_sigma * jump, rock_top_sigma(relief(top, geom), p)), 0.0),
                     np.where(prior, np.sqrt(np.maximum((1.0 - p.prior_own) * var0, 0.0)), 0.0),
                     np.where(framed, p.within * within, 0.0) if p.within > 0 else None,
                     np.where(seen, np.asarray(stats["split"], np.float64), 0.0)
                     if p.stories and "split" in stats else None)



def prior_correlation(d: np.ndarray | float, params: ChanceParams | None = None) -> np.ndarray:
    """How the draws correlate a prior's errors at two cells ``d`` m apart (0 < d): the shared
    field's Gaussian correlation times its share of the variance. What a prior conditioned on the
    ground seen beside it takes (:func:`prox_workflows.algorithms.set_down.set_down`)."""
    p = params or ChanceParams()
    length = max(p.shared_length, 1e-9)
    return (1.0 - p.prior_own) * np.exp(-(np.asarray(d, np.float64) / length) ** 2)


def rock_top_sigma(height: np.ndarray, p: ChanceParams) -> np.ndarray:
    """The sigma of the error a rock's top is read low by as a whole (common to the cells under a
    body), from its ``height`` over the ground it stands on (:func:`relief`): ``rock_sigma`` of
    it, at most ``rock_sigma_max``."""
    return np.minimum(p.rock_sigma * np.asarray(height, np.float64), p.rock_sigma_max)


def relief(top: np.ndarray, geom: GridGeometry) -> np.ndarray:
    """H per cell: how far its ``top`` stands over the lowest top within ROCK_WINDOW (0 where no
    top): a rock's height over the ground it stands on, or a slope's rise over the window."""
    low = _lowest_top(top, geom)
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(top), np.maximum(top - low, 0.0), 0.0)


def _lowest_top(top: np.ndarray, geom: GridGeometry) -> np.ndarray:
    """The lowest ``top`` within ROCK_WINDOW of each cell (inf where none): the ground its rock stands on."""
    size = 2 * max(1, int(round(ROCK_WINDOW / 2 / geom.cell))) + 1
    return ndimage.minimum_filter(np.where(np.isfinite(top), top, np.inf), size=size, mode="nearest")


def headroom(stats: dict[str, np.ndarray], top: np.ndarray, prior: np.ndarray | None = None) -> np.ndarray:
    """J per cell: how much higher than the cell's ``top`` the worst case allows the ground within
    its 3 x 3 neighbourhood (the map's ``upper`` bound there, 0 where the cell has no top). A rock
    edge beside the cell shows in it (its bounds spread along the returns' horizontal errors), and
    so does ground behind the cell that only a ray bounds: where the truth differs from the cell's
    top by many sigmas, this is where (``python -m tools.bench.chance --calibrate``, on frames).
    A ``prior``'s cells neither have nor lend it: a prior's upper bound is its own sigma, which
    its variance carries, not a rock edge a frame read low."""
    upper = np.asarray(stats["upper"], np.float64)
    own = np.isfinite(top)
    if prior is not None:
        upper = np.where(prior, np.nan, upper)
        own &= ~prior
    near = ndimage.maximum_filter(np.where(np.isfinite(upper), upper, -np.inf), size=3, mode="nearest")
    with np.errstate(invalid="ignore"):
        return np.where(own, np.maximum(near - top, 0.0), 0.0)


def screen_k(body: VehicleBody, cell: float, epsilon: float) -> float:
    """How many sigmas out the screen's bounds lie: the chance that any of the cells a pose reads
    (four per body sample, a generous count) lies beyond them is at most SCREEN * epsilon."""
    cells = 4 * len(_pattern(body, cell).pts) + 1  # and the common error
    return NormalDist().inv_cdf(1.0 - SCREEN * epsilon / (2 * cells))


def chance_check(post: Posterior, geom: GridGeometry, poses: np.ndarray, body: VehicleBody,
                 params: ChanceParams | None = None, step: float | None = None,
                 verdict_only: bool = False, runs: np.ndarray | None = None) -> ChanceChecks:
    """The probability that ``body`` exceeds each physical limit at each of ``poses`` ((N, 3): x, y,
    heading deg) on the ground ``post`` gives over ``geom``, and the verdict against epsilon (see
    the module's docstring). ``step``: the body's sample spacing (default the grid's cell), as
    :func:`vehicle.check_poses` takes it.

    ``verdict_only``: a pose whose best estimate already exceeds a limit is refused without
    sampling, its probability for each limit so exceeded put at 0.5 (at least about even: the
    draws scatter round that estimate) and 0 for the others. A planner's check wants the verdict
    alone, and near rocks most of its poses are such: the draws cost 64 checks of each.

    ``runs`` (with ``verdict_only``): the indices where runs of consecutive poses start (a path's
    poses in the order it is driven), of which only the first refused pose is wanted: a planner
    reads no further along a path that fails. Poses of a run after one already refused (unknown,
    over a limit on the best estimate, or over one in a draw so far) are drawn for no more and
    reported ``unknown`` (not judged: never safe). The poses up to each run's first refusal get
    the verdicts they get without ``runs`` (the same draws: a pose's draws do not depend on which
    other poses are drawn for); the draws for a path that fails at its fifth pose are not spent
    on its fiftieth.

    The draws are the map's, not the call's (:func:`_draw`): a cell's error in draw ``s`` is
    keyed by its place on the grid of cell multiples, so a pose gets the same verdict on the same
    map whatever window it is judged in and whatever else is judged with it. A planner judges a
    batch of paths in one window and the drive judges the chosen section again in another: drawn
    per window, a pose near the limit may pass in the one and fail in the other, and the rover
    would choose a section its drive refuses at once, again and again (docs/NAVIGATE_BENCH.md)."""
    p = params or ChanceParams()
    poses = np.atleast_2d(np.asarray(poses, float))
    n = len(poses)
    mu = post.mean
    seen = np.isfinite(mu)
    sd, shared, common, roof = _spreads(post)
    depth = _under_ray(post, geom, roof, p.under_ray)
    best = _under_roof(np.where(seen, mu, roof - depth / 2), shared, roof)
    span = None if post.span is None else np.where(seen, post.span, 0.0)
    ks = screen_k(body, step or geom.cell, p.epsilon)
    cell_sd = np.hypot(sd, shared) + common  # each cell's own and its neighbours' errors are one normal
    split = None if post.split is None else np.where(seen, post.split, 0.0)
    lower = np.where(seen, mu - ks * cell_sd - (0.0 if span is None else span) - (0.0 if split is None else split),
                     np.nan).astype(np.float32)
    upper = _under_roof(np.where(seen, mu + ks * cell_sd, roof), shared, roof).astype(np.float32)
    wide = check_poses((lower, upper), geom, poses, body, step)
    nominal = _judge(best, seen, span, geom, poses, body, step, p.rest_tops)
    # a pair read between the cell centres leaves a wheel over ground only a ray bounds nothing to
    # rest on: no plane, no belly judged in any draw, so such a pose is unknown, not safe
    unknown = wide.unknown | nominal.unknown
    screened = wide.safe & ~unknown
    prob = np.where(unknown[:, None], np.nan, np.zeros((n, 4)))
    p_any = np.where(unknown, np.nan, 0.0)
    zs = np.full((n, 4), np.nan)
    zs[screened] = -np.inf
    todo = ~unknown & ~screened
    if verdict_only:
        over_best = todo & nominal.unsafe
        prob[over_best] = np.where(nominal.excess[over_best] > 0, 0.5, 0.0)
        p_any[over_best] = 0.5
        todo &= ~over_best
    run_of = _run_of(runs, n) if verdict_only and runs is not None and n else None
    refused = unknown | over_best if verdict_only else unknown.copy()
    cut = np.zeros(n, bool)  # poses past their run's first refusal: not judged
    if run_of is not None:
        cut = todo & _past_first(refused, run_of)
        todo &= ~cut
    rest = np.flatnonzero(todo)
    if len(rest):
        excess = np.full((p.samples, len(rest), 4), -np.inf)
        live = np.ones(len(rest), bool)  # poses still drawn for
        early = verdict_only and 1.0 / p.samples > p.epsilon
        for s in range(p.samples):
            if not live.any():
                continue
            surface = _surface(mu, sd, shared, common, roof, _draw(p.seed, s, geom, p.shared_length), depth,
                               _story(split, p.seed, s, geom, p.shared_length))
            excess[s, live] = _judge(surface, seen, span, geom, poses[rest[live]], body, step, p.rest_tops).excess
            if early and s % EARLY == EARLY - 1:
                # one draw over a limit in ``samples`` is a share of at least 1 / samples, above
                # epsilon: that pose is refused whatever the later draws say
                hit = (np.nan_to_num(excess[s - EARLY + 1:s + 1], nan=-np.inf) > 0).any(axis=(0, 2))
                live &= ~hit
                if run_of is not None:
                    refused[rest[hit]] = True
                    past = live & _past_first(refused, run_of)[rest]
                    cut[rest[past]] = True
                    live &= ~past
        excess = np.nan_to_num(excess, nan=-np.inf)  # no resting plane judged: nothing to exceed
        over = excess > 0
        z = _fit_z(excess)
        tail = np.nan_to_num(special.ndtr(z), nan=0.0)
        # the belly's tail where no draw reached it and it alone may decide: ground held under a
        # ceiling within the screen's sigmas cannot stand over it, which the normal fitted to the
        # draws does not know
        with np.errstate(invalid="ignore"):
            held = (shared > 0) & (roof < mu + ks * cell_sd)
        rest_tail = tail.sum(axis=1) - tail[:, 1]
        ask = ~over.any(axis=(0, 2)) & (tail.sum(axis=1) > p.epsilon) & (rest_tail <= p.epsilon) & ~cut[rest]
        if held.any() and ask.any():
            capped = _ceiling_z(mu, sd, shared, common, roof, depth, split, held, span, geom, poses[rest[ask]], body,
                                step, p)
            z[ask, 1] = np.fmin(z[ask, 1], capped)
            tail[ask, 1] = np.nan_to_num(special.ndtr(z[ask, 1]), nan=0.0)
        per_limit = np.maximum(over.mean(axis=0), tail)
        prob[rest] = per_limit
        zs[rest] = z
        p_any[rest] = np.maximum(over.any(axis=2).mean(axis=0), np.minimum(tail.sum(axis=1), 1.0))
    if cut.any():
        prob[cut], p_any[cut], unknown[cut] = np.nan, np.nan, True
    return ChanceChecks(prob=prob, p_any=p_any, unknown=unknown, screened=screened, nominal=nominal,
                        epsilon=p.epsilon, z=zs)


def _ceiling_z(mu: np.ndarray, sd: np.ndarray, shared: np.ndarray, common: np.ndarray, roof: np.ndarray,
               depth: np.ndarray | float, split: np.ndarray | None, held: np.ndarray, span: np.ndarray | None,
               geom: GridGeometry, poses: np.ndarray, body: VehicleBody, step: float | None,
               p: ChanceParams) -> np.ndarray:
    """The belly's z at ``poses`` over the very draws :func:`chance_check` judged, with the cells
    ``held`` under a ceiling raised to it and the wheels resting where the draw put them: an upper
    bound on each draw's intrusion, and so on its probability. A prior's draws stop at the ceiling
    (the belly the rover stood over that ground with, or a ray), but the normal fitted to the
    intrusion they give runs on past it: at dense_fresh 0's start it refused the rover's own pose,
    P 2.1e-3 with no draw of 64 nearer than 1.3 cm, where the truth allowed the whole turn
    (docs/NAVIGATE_BENCH.md, Dense starts that stop cold). The bound's own spread is the wheels'."""
    seen = np.isfinite(mu)
    excess = np.empty((p.samples, len(poses)))
    for s in range(p.samples):
        surface = _surface(mu, sd, shared, common, roof, _draw(p.seed, s, geom, p.shared_length), depth,
                           _story(split, p.seed, s, geom, p.shared_length))
        high = np.where(held, roof, surface).astype(np.float32)
        low = surface if span is None else np.where(seen, surface - span, np.nan).astype(np.float32)
        excess[s] = check_poses((low, high), geom, poses, body, step or geom.cell, cellwise=False, rest_low=True,
                                rest_tops=p.rest_tops).excess[:, 1]
    return _fit_z(excess)


def _fit_z(excess: np.ndarray) -> np.ndarray:
    """The draws' mean excess over their spread (axis 0: the draws), from the finite draws; where
    none is finite, NaN: a limit with no finite sample has no tail."""
    finite = np.where(np.isfinite(excess), excess, np.nan)
    with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        m = np.nanmean(finite, axis=0)
        spread = np.nanstd(finite, axis=0, ddof=1)
        return np.where(spread > 0, m / spread, np.where(m > 0, np.inf, -np.inf))


def _judge(top: np.ndarray, seen: np.ndarray, span: np.ndarray | None, geom: GridGeometry, poses: np.ndarray,
           body: VehicleBody, step: float | None, rest_tops: bool = False) -> PoseChecks:
    """:func:`vehicle.check_poses` on a surface of cell tops (the ray's height where ``seen`` is
    False): the tops alone, or with ``span`` the pair (tops less span, tops), the low NaN where
    only a ray bounds the ground, each read between the cell centres as one surface is, each wheel
    resting on the lows (one plane, not the worst of a box of rests). A cell's
    top is its highest ground: read as the ground all over the cell, a wheel whose footprint's end
    meets a rock's edge cell, or a ray's height over ground no return met, rests on it and lifts
    the resting plane over a belly whose ground is read at its top (the misses traced in
    docs/NAVIGATE_BENCH.md, The stated risk on untuned draws)."""
    high = top.astype(np.float32)
    if span is None:
        return check_poses(high, geom, poses, body, step)
    low = np.where(seen, top - span, np.nan).astype(np.float32)
    return check_poses((low, high), geom, poses, body, step or geom.cell, cellwise=False, rest_low=True,
                       rest_tops=rest_tops)


def _spreads(post: Posterior) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The sigmas a surface is drawn with per cell (its own, the shared field's, the common one's;
    0 where no return) and the ray's ceiling where no return (NaN: none)."""
    seen = np.isfinite(post.mean)
    return (np.sqrt(np.where(seen, post.var, 0.0)), np.where(seen, post.shared, 0.0),
            np.where(seen, post.common, 0.0), np.where(np.isfinite(post.ceiling), post.ceiling, np.nan))


def _under_ray(post: Posterior, geom: GridGeometry, roof: np.ndarray, share: float) -> np.ndarray | float:
    """How far under its ceiling a cell no return bounded may lie (``ChanceParams.under_ray``
    times the ceiling's height over the lowest top seen within ROCK_WINDOW; 0 where a return
    bounds the cell, none is seen near, or a rock seen within HIDDEN_BACK may go on under the
    ray; 0.0 when ``share`` is: the draws read the ceiling)."""
    if share <= 0:
        return 0.0
    seen = np.isfinite(post.mean)
    floor = _lowest_top(post.mean, geom)
    near = 2 * max(1, int(round(HIDDEN_BACK / geom.cell))) + 1
    top = ndimage.maximum_filter(np.where(seen, post.mean, -np.inf), size=near, mode="nearest")
    with np.errstate(invalid="ignore"):
        depth = np.where(~seen & np.isfinite(roof) & np.isfinite(floor), np.maximum(roof - floor, 0.0), 0.0)
        # a rock seen within HIDDEN_BACK standing over the middle of that depth may go on under the ray
        depth[top > floor + depth / 2] = 0.0
    return share * depth


def _surface(mu: np.ndarray, sd: np.ndarray, shared: np.ndarray, common: np.ndarray, roof: np.ndarray,
             drawn: tuple[np.ndarray, np.ndarray, float], depth: np.ndarray | float = 0.0,
             story: np.ndarray | float = 0.0) -> np.ndarray:
    z, field, once = drawn
    mu = mu - story
    # a cell only a ray bounds: its ground uniformly within ``depth`` under the ray (its own normal,
    # unused there, made uniform)
    under = roof - depth * special.ndtr(-z) if np.ndim(depth) else roof
    return _under_roof(np.where(np.isfinite(mu), mu + sd * z + shared * field + common * once, under), shared,
                       roof).astype(np.float32)


def _under_roof(z: np.ndarray, shared: np.ndarray, roof: np.ndarray) -> np.ndarray:
    """Heights ``z`` with a prior's cells (``shared`` above 0: ground no frame bounded) held under
    their ceiling: the belly the rover stood over them with (:meth:`.bounds_map.BoundsMap.stood`)
    or a ray that passed over. A prior as wide as unseen ground may be otherwise puts some draws
    through the belly of the very pose that ground was felt under."""
    return np.where(shared > 0, np.fmin(z, roof), z)


def surfaces(post: Posterior, geom: GridGeometry, params: ChanceParams | None = None) -> Iterator[np.ndarray]:
    """The surfaces :func:`chance_check` judges ``post`` on over ``geom``, one per sample, in order
    (a trace reads the very draws the check refused on)."""
    p = params or ChanceParams()
    sd, shared, common, roof = _spreads(post)
    depth = _under_ray(post, geom, roof, p.under_ray)
    split = None if post.split is None else np.where(np.isfinite(post.mean), post.split, 0.0)
    for s in range(p.samples):
        yield _surface(post.mean, sd, shared, common, roof, _draw(p.seed, s, geom, p.shared_length), depth,
                       _story(split, p.seed, s, geom, p.shared_length))


def _story(split: np.ndarray | None, seed: int, s: int, geom: GridGeometry, length: float) -> np.ndarray | float:
    """How far under its top draw ``s`` puts each cell's ground: its ``split`` where the draw says
    the other frame's story, else 0. The coin is the sign of a field smoothed over ``length`` m
    (:func:`_field`, keyed by the cell's place as :func:`_draw`'s errors are): one frame's story
    holds over a patch, as a frame's error does, so a wheel's few cells take one story together
    (a coin per cell would find a high one under every wheel) while the body's length may span
    both."""
    if split is None:
        return 0.0
    return np.where(_field(seed + STORY_SEED, s, _smoothing(length, geom.cell))[_on_tile(geom)] < 0.0, split, 0.0)


def _draw(seed: int, s: int, geom: GridGeometry, length: float = 0.0) -> tuple[np.ndarray, np.ndarray, float]:
    """Draw ``s``'s standard normal errors of the cells of ``geom``: their own, the shared field
    (correlated over ``length`` m, :func:`_field`) and the one common to a surface. The first two
    are read from tiles of :data:`TILE` x :data:`TILE` cells repeated over the plane, indexed by
    each cell's row and column on the grid of cell multiples (``geom`` is aligned to it, as
    :meth:`GridGeometry.covering` and the windows of a map are). Every window of a map reads the
    same errors at the same cell; cells a tile apart share them, and no body reads two such
    cells."""
    tile, once = _tile(seed, s)
    field = _field(seed, s, _smoothing(length, geom.cell))
    at = _on_tile(geom)
    return tile[at].astype(np.float64), field[at].astype(np.float64), once


def _on_tile(geom: GridGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Where each cell of ``geom`` reads a tile: its row and column on the grid of cell multiples."""
    r0 = int(round(-geom.ymax / geom.cell))
    c0 = int(round(geom.xmin / geom.cell))
    return np.ix_((r0 + np.arange(geom.height)) % TILE, (c0 + np.arange(geom.width)) % TILE)


def _smoothing(length: float, cell: float) -> float:
    """The Gaussian kernel's sigma in cells whose smoothed white noise is correlated by 1/e at
    ``length`` m (its correlation falls as exp(-d^2 / 4 sigma^2)), to a tenth of a cell so that
    the cache keys on it."""
    return round(length / (2.0 * cell), 1)


@lru_cache(maxsize=128)
def _tile(seed: int, s: int) -> tuple[np.ndarray, float]:
    rng = np.random.default_rng((seed, s))
    tile = rng.standard_normal((TILE, TILE)).astype(np.float32)
    tile.setflags(write=False)
    return tile, float(rng.standard_normal())


@lru_cache(maxsize=128)
def _field(seed: int, s: int, sigma: float) -> np.ndarray:
    """Draw ``s``'s field of errors shared by neighbouring cells: white noise of its own stream
    smoothed by a Gaussian of ``sigma`` cells, wrapped round the tile so that it repeats without
    a seam, and scaled to unit variance (each cell's marginal is the posterior's ``shared``)."""
    noise = np.random.default_rng((seed, s, 1)).standard_normal((TILE, TILE))
    field = ndimage.gaussian_filter(noise, sigma, mode="wrap") if sigma > 0 else noise
    field = (field / field.std()).astype(np.float32)
    field.setflags(write=False)
    return field


def _run_of(runs: np.ndarray, n: int) -> np.ndarray:
    """Per pose, the index of the run it is in (``runs``: where runs start; poses before the first
    start are a run of their own)."""
    start = np.zeros(n, bool)
    start[0] = True
    start[np.asarray(runs, np.int64)[(np.asarray(runs) >= 0) & (np.asarray(runs) < n)]] = True
    return np.cumsum(start) - 1


def _past_first(refused: np.ndarray, run_of: np.ndarray) -> np.ndarray:
    """Per pose, whether an earlier pose of its run is ``refused``."""
    idx = np.arange(len(run_of))
    first = np.full(int(run_of[-1]) + 1, len(run_of))
    np.minimum.at(first, run_of[refused], idx[refused])
    return idx > first[run_of]
