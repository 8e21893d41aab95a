"""How often each interval method of :mod:`apac_mj.report.stats` covers the true mean (docs/statistics.md).

Data sets are drawn from shapes fitted (:func:`fitted_shapes`) to the shipped per-seed values
(docs/results/**/key_numbers.csv): rates near 100% and near 50% (a seed's success probability drawn from a
Beta, then a binomial count of its episodes), a negatively skewed rate, right-skewed positive quantities (steps,
cm, ms: lognormal, median and 90th-percentile spread) and a paired difference of two correlated rates.
``scripts/interval_coverage.py`` prints the table. Each method
gets every data set; coverage is the share of data sets whose interval contains the true mean.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from apac_mj.report import stats

#: Seeds the coverage is measured at.
SEED_COUNTS = (2, 3, 5, 10)
#: The name of the report's own method in :func:`methods`.
THE_REPORT = "Student-t (97.5% quantile), clipped + pooled (the report)"


@dataclass(frozen=True)
class DataSet:
    """Per-seed values of one simulated cell, the truth they estimate and the counts behind a rate
    (``counts``: k, n per seed; a difference: k1, n1, k2, n2 per seed)."""
    values: np.ndarray
    truth: float
    bounds: tuple[float, float] | None
    counts: tuple[np.ndarray, ...] = ()


@dataclass(frozen=True)
class Shape:
    """A distribution of per-seed values: a name, how it was fitted, and a sampler ``(rng, seeds)``."""
    name: str
    fitted_to: str
    draw: Callable[[np.random.Generator, int], DataSet]


def _beta(mean: float, sd: float) -> tuple[float, float]:
    """Beta parameters of a given mean and standard deviation."""
    common = mean * (1 - mean) / sd ** 2 - 1
    return mean * common, (1 - mean) * common


def rate_shape(name: str, mean: float, sd: float, episodes: int, fitted_to: str) -> Shape:
    """A rate (%): each seed's probability ~ Beta(mean, sd), its count ~ Binomial(episodes, p)."""
    a, b = _beta(mean, sd)

    def draw(rng: np.random.Generator, seeds: int) -> DataSet:
        k = rng.binomial(episodes, rng.beta(a, b, seeds)).astype(float)
        n = np.full(seeds, float(episodes))
        return DataSet(100 * k / n, 100 * mean, (0.0, 100.0), (k, n))
    return Shape(name, fitted_to, draw)


def lognormal_shape(name: str, median: float, sigma: float, fitted_to: str) -> Shape:
    """A positive right-skewed quantity: lognormal with this median and log-sd."""
    def draw(rng: np.random.Generator, seeds: int) -> DataSet:
        return DataSet(median * np.exp(sigma * rng.standard_normal(seeds)), median * math.exp(sigma ** 2 / 2),
                       (0.0, math.inf))
    return Shape(name, fitted_to, draw)


def difference_shape(name: str, mean: float, shift: float, sd: float, rho: float, episodes: int,
                     fitted_to: str) -> Shape:
    """A paired difference of two rates (points): seed effects correlated ``rho`` on the logit scale, the two
    cells' probabilities ``mean + shift/2`` and ``mean - shift/2`` on average (sd ``sd``), binomial counts."""
    def probs(rng: np.random.Generator, seeds: int) -> tuple[np.ndarray, np.ndarray]:
        z = rng.standard_normal((2, seeds))
        z[1] = rho * z[0] + math.sqrt(1 - rho * rho) * z[1]
        return (np.clip(mean + shift / 2 + sd * z[0], 0, 1), np.clip(mean - shift / 2 + sd * z[1], 0, 1))

    truth = _difference_truth(probs)

    def draw(rng: np.random.Generator, seeds: int) -> DataSet:
        p1, p2 = probs(rng, seeds)
        n = np.full(seeds, float(episodes))
        k1, k2 = rng.binomial(episodes, p1).astype(float), rng.binomial(episodes, p2).astype(float)
        return DataSet(100 * (k1 - k2) / n, truth, (-100.0, 100.0), (k1, n, k2, n))
    return Shape(name, fitted_to, draw)


def _difference_truth(probs: Callable[[np.random.Generator, int], tuple[np.ndarray, np.ndarray]]) -> float:
    """The true mean difference (points) of clipped probabilities, by a large fixed-seed draw."""
    p1, p2 = probs(np.random.default_rng(12345), 2_000_000)
    return float(100 * (p1 - p2).mean())


def pooled(d: DataSet) -> tuple[float, float]:
    """Wilson's interval of the pooled count (a rate) or Newcombe's of the pooled counts (a difference)."""
    if len(d.counts) == 2:
        lo, hi = stats.wilson_interval(d.counts[0].sum(), d.counts[1].sum())
    elif len(d.counts) == 4:
        lo, hi = stats.newcombe_interval(*(c.sum() for c in d.counts))
    else:
        return stats.NAN2
    return 100 * lo, 100 * hi


def widened(method: Callable[[DataSet], tuple[float, float]]) -> Callable[[DataSet], tuple[float, float]]:
    """``method`` widened to contain the pooled counts' interval, as the report does for rates."""
    def wide(d: DataSet) -> tuple[float, float]:
        lo, hi = method(d)
        plo, phi = pooled(d)
        return (lo, hi) if math.isnan(plo) or math.isnan(lo) else (min(lo, plo), max(hi, phi))
    return wide


def the_report(d: DataSet) -> tuple[float, float]:
    """The report's interval: :func:`~apac_mj.report.stats.interval` for a rate, otherwise
    :func:`~apac_mj.report.stats.seed_interval` (a difference: widened to Newcombe's, as the report does)."""
    if len(d.counts) == 2:
        return stats.interval(d.values, d.counts[0], d.counts[1])[1:]
    return widened(lambda x: stats.seed_interval(x.values, x.bounds))(d)


def hull(*ms: Callable[[DataSet], tuple[float, float]]) -> Callable[[DataSet], tuple[float, float]]:
    """The smallest interval containing every defined interval of ``ms``."""
    def f(d: DataSet) -> tuple[float, float]:
        iv = [x for x in (m(d) for m in ms) if not math.isnan(x[0])]
        return (min(x[0] for x in iv), max(x[1] for x in iv)) if iv else stats.NAN2
    return f


def methods(resamples: int = 2000) -> dict[str, Callable[[DataSet], tuple[float, float]]]:
    """The interval methods compared, by name; "+ pooled" = widened to Wilson's/Newcombe's interval where the
    data set has counts (what the report does for rates)."""
    boot = lambda d: stats.bootstrap_interval(d.values, resamples=resamples)  # noqa: E731
    t = lambda d: stats.t_interval(d.values, bounds=d.bounds)  # noqa: E731
    bt = lambda d: stats.studentized_bootstrap_interval(d.values, bounds=d.bounds, resamples=resamples)  # noqa: E731
    return {"percentile bootstrap + pooled (the old report)": widened(boot),
            "percentile bootstrap": boot,
            "Wilson / Newcombe on pooled counts": pooled,
            "Student-t (95% quantile), clipped": t,
            "Student-t (95% quantile), clipped + pooled": widened(t),
            "studentized bootstrap": bt,
            "BCa bootstrap": lambda d: stats.bca_interval(d.values, resamples=resamples),
            "hull of t and studentized bootstrap + pooled": widened(hull(t, bt)),
            THE_REPORT: the_report}


def covers(interval: tuple[float, float], truth: float) -> bool:
    """Whether an interval contains the truth (to rounding); an undefined interval never does."""
    lo, hi = interval
    return not math.isnan(lo) and lo - 1e-9 <= truth <= hi + 1e-9


def coverage(shapes: list[Shape], seed_counts: tuple[int, ...] = SEED_COUNTS, replications: int = 1000,
             resamples: int = 2000, seed: int = 0,
             only: tuple[str, ...] | None = None) -> pd.DataFrame:
    """Coverage of each method (or those named in ``only``) on ``replications`` data sets of each shape and
    seed count: one row per (shape, seeds, method) with the coverage and its binomial standard error."""
    ms = {k: v for k, v in methods(resamples).items() if only is None or k in only}
    rows = []
    for i, shape in enumerate(shapes):
        for seeds in seed_counts:
            rng = np.random.default_rng([seed, i, seeds])
            data = [shape.draw(rng, seeds) for _ in range(replications)]
            for name, method in ms.items():
                if name.startswith("Wilson") and not data[0].counts:
                    continue
                hit = np.mean([covers(method(d), d.truth) for d in data])
                rows.append({"shape": shape.name, "seeds": seeds, "method": name, "coverage": float(hit),
                             "se": math.sqrt(hit * (1 - hit) / replications)})
    return pd.DataFrame(rows)


def per_seed(table: pd.DataFrame) -> pd.DataFrame:
    """Each key_numbers.csv row with 3 or more seeds: its unit, per-seed values, their mean, standard
    deviation, skewness and the samples per seed."""
    rows = []
    for r in table.itertuples():
        v = np.array([float(x.split(":")[1]) for x in str(r.per_seed).split(";") if ":" in x])
        if v.size >= 3:
            rows.append({"unit": r.unit, "values": v, "mean": v.mean(), "sd": v.std(ddof=1),
                         "skew": float(pd.Series(v).skew()) if v.std() > 0 else 0.0, "per": r.samples / v.size})
    return pd.DataFrame(rows)


def fitted_shapes(table: pd.DataFrame) -> list[Shape]:
    """The six shapes, each fitted (medians over the matching rows) to the per-seed values of ``table``
    (key_numbers.csv rows of every published page)."""
    d = per_seed(table)
    rate = d[d["unit"] == "%"]
    high, mid = rate[rate["mean"] >= 90], rate[(rate["mean"] >= 20) & (rate["mean"] <= 80)]
    skewed = rate[(rate["skew"] <= -1) & (rate["mean"] > 50)]
    pos = d[(d["unit"] != "%") & (d["values"].map(lambda v: bool((v > 0).all())))]
    logsd = pos["values"].map(lambda v: np.log(v).std(ddof=1))
    sigma, heavy = float(logsd.median()), float(logsd.quantile(0.9))
    ep = int(rate["per"].median())

    def fit(rows: pd.DataFrame, name: str, what: str) -> Shape:
        m, sd = float(rows["mean"].median()) / 100, float(rows["sd"].median()) / 100
        return rate_shape(name, m, sd, ep, f"{what}: {len(rows)} rows, median mean {100 * m:.1f}%, "
                                           f"median sd {100 * sd:.1f} points, {ep} episodes a seed")
    mid_sd = float(mid["sd"].median()) / 100
    return [fit(high, "rate near 100%", "rates >= 90%"), fit(mid, "rate near 50%", "rates 20-80%"),
            fit(skewed, "skewed rate", "rates > 50% with skewness <= -1"),
            lognormal_shape("skewed positive (lognormal)", 1.0, sigma,
                            f"positive non-rates: {len(pos)} rows, median log-sd {sigma:.2f}"),
            lognormal_shape("heavily skewed positive (lognormal)", 1.0, heavy,
                            f"the same rows' 90th percentile log-sd {heavy:.2f}"),
            difference_shape("paired difference of rates", 0.5, 0.0, mid_sd, 0.5, ep,
                             f"two rates near 50% (sd {100 * mid_sd:.1f} points, as fitted), seed effects "
                             f"correlated 0.5 (assumed), {ep} episodes a seed")]


def shipped_key_numbers(results: Path) -> pd.DataFrame:
    """Every key_numbers.csv under ``results`` (docs/results), concatenated."""
    files = sorted(results.rglob("key_numbers.csv"))
    if not files:
        raise FileNotFoundError(f"{results}: no key_numbers.csv below it; pass the docs/results directory")
    return pd.concat([pd.read_csv(f) for f in files], ignore_index=True)
