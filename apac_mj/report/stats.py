"""Intervals over seeds whose coverage is measured (docs/statistics.md).

A mean over seeds gets a Student-t interval over its seeds, clipped to the quantity's range, whose quantile is
that of a nominal :data:`T_LEVEL` (97.5%) interval (:func:`seed_interval`): on values shaped like the project's
(:mod:`apac_mj.report.coverage`) the t interval at the 95% quantile covered only 0.88-0.92 on rates near 100%
and heavily skewed values at 5 and 10 seeds, the 97.5% quantile at least 0.93 on every shape, the percentile
bootstrap (:func:`bootstrap_interval`, the report's method before issue 41) 0.82-0.85 at 5 seeds. It is reported
as the 95% interval it was measured to be. With fewer than :data:`MIN_SEEDS` seeds no interval is given (the
report prints the per-seed values and :data:`TOO_FEW`). A rate's interval is widened to contain the Wilson score
interval of the count pooled over seeds (:func:`interval`), so a rate every seed hits still shows its sampling
uncertainty. A difference of two cells' means gets the same interval of its per-seed differences (Welch's t
where the seeds differ; :func:`paired_difference`), a difference of two rates also Newcombe's score interval
(:func:`newcombe_interval`). Bootstraps (kept as the candidates the coverage study measures) have a fixed seed.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pandas as pd
from scipy import stats

#: Interval level, bootstrap resamples and the bootstrap's fixed seed (reports are reproducible).
LEVEL, BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED = 0.95, 10_000, 0
#: Fewest seeds an interval over seeds is given for: at 2 the bootstraps collapse and a t interval covers only by
#: spanning most of the range (docs/statistics.md).
MIN_SEEDS = 3
#: The nominal level whose t quantile the report's 95% interval uses: chosen by the coverage study.
T_LEVEL = 0.975
#: What the report prints instead of an interval with fewer than MIN_SEEDS seeds.
TOO_FEW = "too few seeds for an interval"
#: How the report's intervals are made, as the tables name them.
METHOD = "Student-t over seeds (97.5% quantile, measured 95% coverage)"
RATE_METHOD = METHOD + " + Wilson (pooled count)"
NAN2 = (math.nan, math.nan)

Bounds = tuple[float, float]


def _clean(values: Sequence[float]) -> np.ndarray:
    return np.asarray([x for x in values if not math.isnan(x)], dtype=float)


def _clip(lo: float, hi: float, bounds: Bounds | None) -> tuple[float, float]:
    if bounds is None:
        return float(lo), float(hi)
    return float(min(max(lo, bounds[0]), bounds[1])), float(max(min(hi, bounds[1]), bounds[0]))


def wilson_interval(k: float, n: float, level: float = LEVEL) -> tuple[float, float]:
    """Wilson score interval of a proportion ``k / n`` (as fractions, inside [0, 1]); NaN if n = 0."""
    if n <= 0:
        return NAN2
    z = float(stats.norm.ppf(0.5 + level / 2))
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def t_interval(values: Sequence[float], level: float = LEVEL, bounds: Bounds | None = None) -> tuple[float, float]:
    """Student-t interval of the mean over seeds, clipped to ``bounds`` (the quantity's range); NaN with fewer
    than two values. Seeds that agree exactly give a zero-width interval."""
    v = _clean(values)
    if v.size < 2:
        return NAN2
    half = float(stats.t.ppf(0.5 + level / 2, v.size - 1)) * float(v.std(ddof=1)) / math.sqrt(v.size)
    return _clip(v.mean() - half, v.mean() + half, bounds)


def _resamples(v: np.ndarray, resamples: int, seed: int) -> np.ndarray:
    return v[np.random.default_rng(seed).integers(0, v.size, size=(resamples, v.size))]


def bootstrap_interval(values: Sequence[float], level: float = LEVEL, resamples: int = BOOTSTRAP_RESAMPLES,
                       seed: int = BOOTSTRAP_SEED) -> tuple[float, float]:
    """Percentile bootstrap interval of the mean over seeds; NaN with fewer than two values. Stays in the
    range, but covers a nominal 95% only 0.84-0.88 of the time at 5 seeds (docs/statistics.md)."""
    v = _clean(values)
    if v.size < 2:
        return NAN2
    lo, hi = np.quantile(_resamples(v, resamples, seed).mean(axis=1), [0.5 - level / 2, 0.5 + level / 2])
    return float(lo), float(hi)


def studentized_bootstrap_interval(values: Sequence[float], level: float = LEVEL, bounds: Bounds | None = None,
                                   resamples: int = BOOTSTRAP_RESAMPLES, seed: int = BOOTSTRAP_SEED
                                   ) -> tuple[float, float]:
    """Bootstrap-t interval of the mean (each resample studentized by its own standard error), clipped to
    ``bounds``; resamples of identical values are dropped. NaN with fewer than two distinct values."""
    v = _clean(values)
    if v.size < 2 or v.std() == 0:
        return NAN2
    b = _resamples(v, resamples, seed)
    se = b.std(axis=1, ddof=1) / math.sqrt(v.size)
    ok = b.max(axis=1) > b.min(axis=1)  # not se > 0: identical draws leave a rounding-sized se
    t = (b.mean(axis=1)[ok] - v.mean()) / se[ok]
    s = float(v.std(ddof=1)) / math.sqrt(v.size)
    qlo, qhi = np.quantile(t, [0.5 - level / 2, 0.5 + level / 2])
    return _clip(v.mean() - qhi * s, v.mean() - qlo * s, bounds)


def bca_interval(values: Sequence[float], level: float = LEVEL, resamples: int = BOOTSTRAP_RESAMPLES,
                 seed: int = BOOTSTRAP_SEED) -> tuple[float, float]:
    """Bias-corrected and accelerated (BCa) bootstrap interval of the mean (Efron 1987); NaN with fewer than
    two distinct values. Like the percentile bootstrap it stays in the observed range."""
    v = _clean(values)
    if v.size < 2 or v.std() == 0:
        return NAN2
    means = np.sort(_resamples(v, resamples, seed).mean(axis=1))
    p0 = np.clip(np.mean(means < v.mean()), 1 / resamples, 1 - 1 / resamples)
    z0 = float(stats.norm.ppf(p0))
    jack = (v.sum() - v) / (v.size - 1)
    d = jack.mean() - jack
    accel = float((d ** 3).sum() / (6 * (d ** 2).sum() ** 1.5)) if (d ** 2).sum() > 0 else 0.0
    z = stats.norm.ppf([0.5 - level / 2, 0.5 + level / 2])
    q = stats.norm.cdf(z0 + (z0 + z) / (1 - accel * (z0 + z)))
    lo, hi = np.quantile(means, q)
    return float(lo), float(hi)


def seed_interval(values: Sequence[float], bounds: Bounds | None = None,
                  level: float = T_LEVEL) -> tuple[float, float]:
    """The report's 95% interval of a mean over seeds: :func:`t_interval` at the quantile of ``level``
    (:data:`T_LEVEL`), clipped to ``bounds``; NaN with fewer than :data:`MIN_SEEDS` seeds (:data:`TOO_FEW`)."""
    return NAN2 if _clean(values).size < MIN_SEEDS else t_interval(values, level, bounds)


def interval(values: Sequence[float], k: Sequence[float] | None = None, n: Sequence[float] | None = None,
             scale: float = 100.0, bounds: Bounds | None = None) -> tuple[float, float, float]:
    """Mean over seeds and its 95% interval (:func:`seed_interval`); a rate (``k`` successes of ``n`` per seed,
    values in units of ``scale``) is clipped to [0, scale] (any other quantity to ``bounds``) and widened to
    contain the pooled count's Wilson interval. With fewer than MIN_SEEDS seeds: the mean and NaN bounds, rates
    included."""
    v = _clean(values)
    if v.size == 0:
        return math.nan, math.nan, math.nan
    rate = k is not None and n is not None and float(np.nansum(n)) > 0
    lo, hi = seed_interval(v, (0.0, scale) if rate else bounds)
    if rate and v.size >= MIN_SEEDS:
        wlo, whi = wilson_interval(float(np.nansum(k)), float(np.nansum(n)))
        lo, hi = min(lo, scale * wlo), max(hi, scale * whi)
    return float(v.mean()), lo, hi


def newcombe_interval(k1: float, n1: float, k2: float, n2: float, level: float = LEVEL) -> tuple[float, float]:
    """Newcombe's hybrid score interval of ``k1/n1 - k2/n2`` (fractions, inside [-1, 1]), from the two
    Wilson intervals; NaN if a count is empty."""
    if n1 <= 0 or n2 <= 0:
        return NAN2
    p1, p2 = k1 / n1, k2 / n2
    (l1, u1), (l2, u2) = wilson_interval(k1, n1, level), wilson_interval(k2, n2, level)
    d = p1 - p2
    return max(-1.0, d - math.hypot(p1 - l1, u2 - p2)), min(1.0, d + math.hypot(u1 - p1, p2 - l2))


def welch_interval(a: np.ndarray, b: np.ndarray, level: float = LEVEL) -> tuple[float, float]:
    """Welch's t interval of mean(a) - mean(b) for unpaired seeds."""
    va, vb = a.var(ddof=1) / a.size, b.var(ddof=1) / b.size
    se = math.sqrt(va + vb)
    if se == 0:
        return float(a.mean() - b.mean()), float(a.mean() - b.mean())
    df = (va + vb) ** 2 / (va ** 2 / (a.size - 1) + vb ** 2 / (b.size - 1))
    half = float(stats.t.ppf(0.5 + level / 2, df)) * se
    return float(a.mean() - b.mean() - half), float(a.mean() - b.mean() + half)


def paired_difference(a: pd.Series, b: pd.Series, level: float = T_LEVEL, bounds: Bounds | None = None
                      ) -> tuple[float, float, float, bool]:
    """Mean(a) - mean(b) of per-seed values (indexed by seed) with an interval clipped to ``bounds``: the
    :func:`seed_interval` of the per-seed differences where both have the same seeds, else Welch's t. NaN
    bounds with fewer than MIN_SEEDS seeds on a side."""
    a, b = a.dropna(), b.dropna()
    if a.empty or b.empty:
        return math.nan, math.nan, math.nan, False
    paired = set(a.index) == set(b.index)
    diff = float(a.mean() - b.mean())
    if min(a.size, b.size) < MIN_SEEDS:
        return diff, math.nan, math.nan, paired
    if paired:
        lo, hi = seed_interval((a - b.reindex(a.index)).to_numpy(float), bounds, level)
    else:
        lo, hi = _clip(*welch_interval(a.to_numpy(float), b.to_numpy(float), level), bounds)
    return diff, lo, hi, paired
