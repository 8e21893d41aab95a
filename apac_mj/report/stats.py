"""Intervals over seeds that respect a quantity's range.

A mean over seeds gets a percentile bootstrap interval (:func:`bootstrap_interval`): every resampled mean
is a mean of observed values, so the interval never leaves the quantity's range. A rate's interval is
widened to contain the Wilson score interval of the count pooled over seeds (:func:`interval`), so a rate
every seed hits still shows its sampling uncertainty. A difference of two cells' means gets a (paired)
bootstrap interval (:func:`paired_difference`), a difference of two rates also Newcombe's score interval
(:func:`newcombe_interval`). The bootstrap's seed is fixed: a report is reproducible.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pandas as pd
from scipy import stats

#: Interval level, bootstrap resamples and the bootstrap's fixed seed (reports are reproducible).
LEVEL, BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED = 0.95, 10_000, 0


def wilson_interval(k: float, n: float, level: float = LEVEL) -> tuple[float, float]:
    """Wilson score interval of a proportion ``k / n`` (as fractions, inside [0, 1]); NaN if n = 0."""
    if n <= 0:
        return math.nan, math.nan
    z = float(stats.norm.ppf(0.5 + level / 2))
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def bootstrap_interval(values: Sequence[float], level: float = LEVEL, resamples: int = BOOTSTRAP_RESAMPLES,
                       seed: int = BOOTSTRAP_SEED) -> tuple[float, float]:
    """Percentile bootstrap interval of the mean over seeds; NaN with fewer than two values.
    Every resampled mean is a mean of observed values, so the interval stays in the quantity's range."""
    v = np.asarray([x for x in values if not math.isnan(x)], dtype=float)
    if v.size < 2:
        return math.nan, math.nan
    means = v[np.random.default_rng(seed).integers(0, v.size, size=(resamples, v.size))].mean(axis=1)
    lo, hi = np.quantile(means, [0.5 - level / 2, 0.5 + level / 2])
    return float(lo), float(hi)


def interval(values: Sequence[float], k: Sequence[float] | None = None, n: Sequence[float] | None = None,
             scale: float = 100.0) -> tuple[float, float, float]:
    """Mean over seeds and its 95% interval: bootstrap over seeds; for a rate (``k`` successes of ``n``
    per seed, values in units of ``scale``) widened to contain the pooled count's Wilson interval."""
    v = [x for x in values if not math.isnan(x)]
    if not v:
        return math.nan, math.nan, math.nan
    lo, hi = bootstrap_interval(v)
    if k is not None and n is not None and float(np.nansum(n)) > 0:
        wlo, whi = wilson_interval(float(np.nansum(k)), float(np.nansum(n)))
        lo, hi = (scale * wlo, scale * whi) if math.isnan(lo) else (min(lo, scale * wlo), max(hi, scale * whi))
    return float(np.mean(v)), lo, hi


def newcombe_interval(k1: float, n1: float, k2: float, n2: float, level: float = LEVEL) -> tuple[float, float]:
    """Newcombe's hybrid score interval of ``k1/n1 - k2/n2`` (fractions, inside [-1, 1]), from the two
    Wilson intervals; NaN if a count is empty."""
    if n1 <= 0 or n2 <= 0:
        return math.nan, math.nan
    p1, p2 = k1 / n1, k2 / n2
    (l1, u1), (l2, u2) = wilson_interval(k1, n1, level), wilson_interval(k2, n2, level)
    d = p1 - p2
    return max(-1.0, d - math.hypot(p1 - l1, u2 - p2)), min(1.0, d + math.hypot(u1 - p1, p2 - l2))


def paired_difference(a: pd.Series, b: pd.Series, level: float = LEVEL, resamples: int = BOOTSTRAP_RESAMPLES,
                      seed: int = BOOTSTRAP_SEED) -> tuple[float, float, float, bool]:
    """Mean(a) - mean(b) of per-seed values (indexed by seed) with a percentile bootstrap interval:
    seeds resampled jointly where both have the same seeds (paired), else each on its own."""
    a, b = a.dropna(), b.dropna()
    if a.empty or b.empty:
        return math.nan, math.nan, math.nan, False
    rng = np.random.default_rng(seed)
    paired = set(a.index) == set(b.index)
    if paired:
        d = (a - b.reindex(a.index)).to_numpy(float)
        boot = d[rng.integers(0, d.size, size=(resamples, d.size))].mean(axis=1)
    else:
        va, vb = a.to_numpy(float), b.to_numpy(float)
        boot = (va[rng.integers(0, va.size, size=(resamples, va.size))].mean(axis=1)
                - vb[rng.integers(0, vb.size, size=(resamples, vb.size))].mean(axis=1))
    diff = float(a.mean() - b.mean())
    if min(a.size, b.size) < 2:
        return diff, math.nan, math.nan, paired
    lo, hi = np.quantile(boot, [0.5 - level / 2, 0.5 + level / 2])
    return diff, float(lo), float(hi), paired
