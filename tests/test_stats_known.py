"""The report's interval functions against known answers (issue 41, item 3): published Wilson and Newcombe
intervals, SciPy's Welch test for unpaired seeds, the seed-count boundaries and the rate rule of
:func:`apac_mj.report.stats.interval`. Written to kill the survivors of mutation testing (docs/mutation.md)."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats as sps

from apac_mj.report import stats


def test_wilson_against_newcombes_published_values():
    """Newcombe (1998), Table I: 5/10 -> 0.2366-0.7634, 0/10 -> 0-0.2775; one trial, one success -> 0.2065-1;
    no trials -> NaN (not a division by zero)."""
    assert stats.wilson_interval(5, 10) == pytest.approx((0.2366, 0.7634), abs=1e-4)
    assert stats.wilson_interval(0, 10) == pytest.approx((0.0, 0.2775), abs=1e-4)
    assert stats.wilson_interval(1, 1) == pytest.approx((0.2065, 1.0), abs=1e-4)
    assert all(math.isnan(x) for x in stats.wilson_interval(0, 0))


def test_newcombe_against_his_worked_example_and_its_level():
    """Newcombe (1998), method 10: 56/70 - 48/80 = 0.2, interval 0.0524-0.3339; a count of one is an interval,
    an empty count NaN on either side; the level reaches both Wilson intervals (0.90 narrower on both ends)."""
    assert stats.newcombe_interval(56, 70, 48, 80) == pytest.approx((0.0524, 0.3339), abs=1e-4)
    assert all(np.isfinite(stats.newcombe_interval(1, 1, 0, 1)))
    for counts in ((1, 0, 1, 5), (1, 5, 1, 0)):
        assert all(math.isnan(x) for x in stats.newcombe_interval(*counts))
    lo95, hi95 = stats.newcombe_interval(56, 70, 48, 80)
    lo90, hi90 = stats.newcombe_interval(56, 70, 48, 80, level=0.90)
    (l1, u1), (l2, u2) = stats.wilson_interval(56, 70, 0.90), stats.wilson_interval(48, 80, 0.90)
    p1, p2 = 56 / 70, 48 / 80
    assert (lo90, hi90) == pytest.approx((p1 - p2 - math.hypot(p1 - l1, u2 - p2), p1 - p2 + math.hypot(u1 - p1, p2 - l2)))
    assert lo95 < lo90 and hi90 < hi95


@pytest.mark.filterwarnings("ignore:Precision loss occurred")  # SciPy on the constant side: its variance is 0
@pytest.mark.parametrize("a, b", [([1.0, 2.0, 3.0, 4.0], [2.0, 4.0, 6.0]), ([-1.0, 1.0], [5.0, 5.0, 5.0])])
@pytest.mark.parametrize("level", [0.95, 0.975])
def test_welch_against_scipy(a, b, level):
    """Welch's interval equals SciPy's unequal-variance t-test interval (the second pair: a standard error of
    exactly 1, with one side constant)."""
    ref = sps.ttest_ind(a, b, equal_var=False).confidence_interval(level)
    assert stats.welch_interval(np.array(a), np.array(b), level) == pytest.approx((ref.low, ref.high))


def test_welch_of_two_constant_sides_is_the_difference():
    assert stats.welch_interval(np.array([1.0, 1.0, 1.0]), np.array([3.0, 3.0, 3.0])) == (-2.0, -2.0)


def test_paired_difference_of_unpaired_seeds_is_welch_clipped():
    """Different seeds on the two sides: Welch's t at the difference's level, clipped to the bounds; not paired."""
    a = pd.Series([1.0, 2.0, 3.0, 4.0], index=[0, 1, 2, 3])
    b = pd.Series([2.0, 4.0, 6.0], index=[10, 11, 12])
    ref = sps.ttest_ind(a, b, equal_var=False).confidence_interval(stats.T_LEVEL)
    diff, lo, hi, paired = stats.paired_difference(a, b)
    assert not paired and diff == pytest.approx(a.mean() - b.mean())
    assert (lo, hi) == pytest.approx((ref.low, ref.high))
    assert stats.paired_difference(a, b, bounds=(-3.0, 1.0))[1:3] == pytest.approx((-3.0, 1.0))


def test_paired_difference_of_paired_seeds_at_three_seeds_and_another_level():
    """The same three seeds: the interval of the per-seed differences at the level asked for; one side empty:
    NaN and not paired; two seeds: the difference without an interval."""
    a = pd.Series([3.0, 5.0, 10.0], index=[0, 1, 2])
    b = pd.Series([1.0, 2.0, 3.0], index=[2, 1, 0])  # another order: paired by seed, not by position
    d = np.array([3.0 - 3.0, 5.0 - 2.0, 10.0 - 1.0])
    for level in (stats.T_LEVEL, 0.90):
        diff, lo, hi, paired = stats.paired_difference(a, b, level=level)
        half = sps.t.ppf(0.5 + level / 2, 2) * d.std(ddof=1) / math.sqrt(3)
        assert paired and diff == pytest.approx(d.mean()) and (lo, hi) == pytest.approx((d.mean() - half, d.mean() + half))
    empty = stats.paired_difference(pd.Series([], dtype=float), b)
    assert all(math.isnan(x) for x in empty[:3]) and empty[3] is False
    two = stats.paired_difference(a.iloc[:2], b.loc[[0, 1]])
    assert two[0] == pytest.approx(a.iloc[:2].mean() - b.loc[[0, 1]].mean()) and math.isnan(two[1])


def test_t_interval_from_two_values_and_seed_interval_from_three():
    """Student-t needs two values (one degree of freedom); the report's interval needs MIN_SEEDS = 3."""
    half = sps.t.ppf(0.975, 1) * np.std([1.0, 3.0], ddof=1) / math.sqrt(2)
    assert stats.t_interval([1.0, 3.0]) == pytest.approx((2.0 - half, 2.0 + half))
    assert all(math.isnan(x) for x in stats.t_interval([1.0]))
    assert all(math.isnan(x) for x in stats.seed_interval([1.0, 3.0]))
    assert all(np.isfinite(stats.seed_interval([1.0, 3.0, 2.0])))


def test_interval_rate_rule():
    """One seed: its value, no bounds. Counts without trials are not a rate (the bounds hold, not [0, 100]);
    a pooled count of one trial is; three seeds that agree are widened to the pooled Wilson interval."""
    mean, lo, hi = stats.interval([7.0])
    assert mean == 7.0 and math.isnan(lo) and math.isnan(hi)
    v = [-5.0, 5.0, 10.0]
    assert stats.interval(v, k=[0, 0, 0], n=[0, 0, 0])[1:] == pytest.approx(stats.seed_interval(v))
    assert stats.interval(v, k=[1, 2, 3], bounds=(-50.0, 50.0))[1:] == pytest.approx(stats.seed_interval(v, (-50.0, 50.0)))
    assert stats.interval([50.0, 100.0, 0.0], k=[1, 0, 0], n=[1, 0, 0])[1:] == (0.0, 100.0)
    mean, lo, hi = stats.interval([100.0, 100.0, 100.0], k=[10, 10, 10], n=[10, 10, 10])
    assert mean == 100.0 and lo == pytest.approx(100 * stats.wilson_interval(30, 30)[0]) and hi == 100.0


def test_bootstrap_is_reproducible():
    """The figure bands' bootstrap draws from its fixed seed: the same values give the same interval."""
    v = [1.0, 4.0, 2.0, 8.0, 5.0]
    assert stats.bootstrap_interval(v, resamples=500) == stats.bootstrap_interval(v, resamples=500)
