"""How much a count of judged poses says about a rate: the exact binomial bound on a failure rate
and the correlation that decides how many of the poses are independent trials.

A safety figure is stated as p-ACE (Ghosh, Otsu, Ono 2018) states it: a measured probability of
a false safe verdict with its 95 % upper bound. Zero failures in n trials bound the rate at
``1 - 0.05 ** (1 / n)`` (about 3 / n, the rule of three), and only if the trials are independent;
poses every 2 cm along a path are not, so :func:`poses_per_trial` measures how many make one.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.stats import beta

__all__ = ["clopper_pearson_upper", "poses_per_trial", "events_per_distance_upper"]


def clopper_pearson_upper(k: int, n: float, confidence: float = 0.95) -> float:
    """The one-sided Clopper-Pearson (exact binomial) upper bound on a rate after ``k`` failures
    in ``n`` trials: the rate at which ``k`` or fewer failures would happen with probability
    ``1 - confidence``. One-sided because a safety statement needs only "at most"; the two-sided
    95 % interval's upper end is this at ``confidence`` 0.975. ``n`` may be fractional (an
    effective count of independent trials). 0 of n: ``1 - (1 - confidence) ** (1 / n)``."""
    if n <= 0 or not 0 <= k <= n:
        raise ValueError(f"need 0 <= k <= n and n > 0, got k={k}, n={n}")
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence}")
    if k >= n:
        return 1.0
    return float(beta.ppf(confidence, k + 1, n - k))


def poses_per_trial(paths: Sequence[np.ndarray], max_lag: int = 500) -> float:
    """How many consecutive poses along a path make one independent trial: the integrated
    autocorrelation time ``1 + 2 * sum(rho(lag))`` of 0/1 verdicts along ``paths`` (each a 1-D
    array in the order driven; NaN where the pose was not judged, which takes it out of every
    pair), pooled over the paths, the sum stopping at the first lag whose correlation is no longer
    positive (past it the estimate is noise). NaN when the verdicts never vary (nothing to
    measure)."""
    seqs = [np.asarray(p, float) for p in paths if len(p)]
    if not seqs:
        return float("nan")
    allv = np.concatenate(seqs)
    allv = allv[np.isfinite(allv)]
    if len(allv) < 2:
        return float("nan")
    mu, var = float(allv.mean()), float(allv.var())
    if var == 0.0:
        return float("nan")
    centred = [np.where(np.isfinite(s), s - mu, np.nan) for s in seqs]
    tau = 1.0
    for lag in range(1, max_lag + 1):
        num, pairs = 0.0, 0
        for c in centred:
            if len(c) <= lag:
                continue
            prod = c[:-lag] * c[lag:]
            ok = np.isfinite(prod)
            num += float(prod[ok].sum())
            pairs += int(ok.sum())
        if pairs == 0:
            break
        rho = num / pairs / var
        if rho <= 0.0:
            break
        tau += 2.0 * rho
    return tau


def events_per_distance_upper(events: int, poses: int, per_trial: float, spacing: float,
                              distance: float = 100.0, confidence: float = 0.95) -> float:
    """The upper bound on unsafe events per ``distance`` driven that ``events`` in ``poses``
    judged poses ``spacing`` apart along paths allow, when ``per_trial`` consecutive poses make one
    independent trial: the Clopper-Pearson bound on the per-trial rate over ``poses / per_trial``
    trials, times the trials in ``distance``. With no event it is about ``3 * distance /
    (poses * spacing)``, whatever the correlation: correlated poses are fewer trials, each longer."""
    trials = poses / per_trial
    return clopper_pearson_upper(min(events, int(trials)), trials, confidence) * distance / (per_trial * spacing)
