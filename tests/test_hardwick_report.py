"""apac_mj/report/hardwick.py's report helpers (fit_row, nan_row, summarize, bootstrap_fit, verdict, side_by_side,
sliding_window, guesses) against answers computed by hand (issue 42, item 3: the mutation-testing gaps)."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from apac_mj.report import hardwick as hw

#: The Student-t quantile of the report's intervals at 3 values (2 degrees of freedom, p = 0.5 + 0.975 / 2):
#: in closed form for 2 degrees of freedom, t_p = (2p - 1) / sqrt(2 p (1 - p)) = 6.2054.
T2 = 0.975 / math.sqrt(2 * 0.9875 * 0.0125)
#: A habit-model fit (s) and a no-habit fit, their log-likelihoods chosen: AIC 2·7 + 200 = 214 and 2·4 + 207 = 215.
H_PARAMS, N_PARAMS = (0.45, 0.07, 0.56, 0.08, 0.93, 0.25, 0.05), (0.5, 0.09, 0.9, 0.3)
TRUE = (0.45, 0.07, 0.56, 0.08, 0.93, 0.25, 0.05)


def _fake_fits(monkeypatch, ll_nohabit: float, seen: list) -> None:
    def fit_both(t, counts):
        seen.append((t, counts))
        return hw.Fit(True, H_PARAMS, -100.0, 60.0), hw.Fit(False, N_PARAMS, ll_nohabit, 60.0)

    monkeypatch.setattr(hw, "fit_both", fit_both)


def test_fit_row_converts_times_to_ms_and_does_the_aic_arithmetic(monkeypatch):
    seen: list = []
    _fake_fits(monkeypatch, -103.5, seen)
    t, counts = np.array([0.3, 0.5]), np.array([[20.0, 5.0, 5.0], [25.0, 3.0, 2.0]])
    row = hw.fit_row(t, counts)
    assert seen[0][0] is t and seen[0][1] is counts
    expected = {"mu_habit": 450.0, "sigma_habit": 70.0, "mu_goal": 560.0, "sigma_goal": 80.0, "q_goal": 0.93,
                "q_init": 0.25, "rho": 0.05, "nohabit_mu_goal": 500.0, "nohabit_sigma_goal": 90.0,
                "nohabit_q_goal": 0.9, "nohabit_q_init": 0.3, "trials": 60.0, "ll_habit": -100.0,
                "ll_nohabit": -103.5, "aic_habit": 214.0, "aic_nohabit": 215.0, "delta_aic": 1.0, "habit_wins": 1.0}
    assert row == pytest.approx(expected, abs=1e-9) and set(row) == set(expected)
    assert list(row) == list(hw.nan_row())  # the same columns, in the same order


@pytest.mark.parametrize(("ll_nohabit", "delta", "wins"), [(-103.0, 0.0, 0.0), (-102.0, -2.0, 0.0)])
def test_a_tie_or_a_lower_no_habit_aic_is_no_habit_win(monkeypatch, ll_nohabit, delta, wins):
    _fake_fits(monkeypatch, ll_nohabit, [])
    row = hw.fit_row(np.array([0.3]), np.array([[1.0, 0.0, 0.0]]))
    assert row["delta_aic"] == pytest.approx(delta, abs=1e-12) and row["habit_wins"] == wins


def test_fit_row_on_a_real_fit_reports_that_fits_likelihood_and_aic():
    rng = np.random.default_rng(5)
    t = rng.uniform(0.0, 1.2, 600)
    counts = hw.trial_counts(hw.simulate(t, TRUE, True, rng))
    row = hw.fit_row(t, counts)
    params = [row[k] / (1000.0 if k.startswith(("mu", "sigma")) else 1.0) for k in hw.HABIT]
    assert row["ll_habit"] == pytest.approx(hw.log_likelihood(t, counts, params), abs=1e-9)
    assert row["aic_habit"] == pytest.approx(2 * 7 - 2 * row["ll_habit"])
    assert row["aic_nohabit"] == pytest.approx(2 * 4 - 2 * row["ll_nohabit"])
    assert row["delta_aic"] == pytest.approx(row["aic_nohabit"] - row["aic_habit"]) and row["trials"] == 600.0
    h, n = hw.fit_both(t, counts)
    assert (h.habit, n.habit, h.trials, n.trials) == (True, False, 600.0, 600.0)
    assert (h.ll, n.ll) == (row["ll_habit"], row["ll_nohabit"]) and n.params[0] * 1000.0 == row["nohabit_mu_goal"]


def test_nan_row_has_every_column_of_a_fit_row_and_nothing_else():
    row = hw.nan_row()
    assert list(row) == [*hw.HABIT, "nohabit_mu_goal", "nohabit_sigma_goal", "nohabit_q_goal", "nohabit_q_init",
                         "trials", "ll_habit", "ll_nohabit", "aic_habit", "aic_nohabit", "delta_aic", "habit_wins"]
    assert all(math.isnan(v) for v in row.values())


def _fits() -> pd.DataFrame:
    """Three groups, stored out of order: C (2 fits), B (3 equal but for mu_habit), A (3 fits and a failed one)."""
    a = {"mu_habit": [100.0, 400.0, 700.0], "sigma_habit": [20.0, 30000.0, 90000.0],
         "mu_goal": [100.0, 400.0, 700.0], "sigma_goal": [20.0, 30000.0, 90000.0], "q_goal": [0.55, 0.75, 0.95],
         "q_init": [0.05, 0.25, 0.45], "rho": [0.1, 0.5, 0.9], "delta_aic": [-10.0, 20.0, 50.0],
         "habit_wins": [1.0, 1.0, 0.0]}
    b = {**{q: [v[1]] * 3 for q, v in a.items()}, "mu_habit": [380.0, 400.0, 420.0], "habit_wins": [1.0] * 3}
    c = {**{q: [v[0], v[2]] for q, v in a.items()}, "habit_wins": [0.0, 0.0]}
    rows = [{"practice": 400, "variant": "apac", **{q: v[i] for q, v in c.items()}} for i in range(2)]
    rows += [{"practice": 100, "variant": "apac_voc", **{q: v[i] for q, v in b.items()}} for i in range(3)]
    rows += [{"practice": 100, "variant": "apac", **{q: v[i] for q, v in a.items()}} for i in range(3)]
    rows.append({"practice": 100, "variant": "apac", **hw.nan_row()})  # a failed fit: NaN, counted in n only
    return pd.DataFrame(rows)


def test_summarize_groups_in_sorted_order_and_counts_fits_and_habit_wins():
    s = hw.summarize(_fits(), ["practice", "variant"])
    assert s[["practice", "variant"]].values.tolist() == [[100, "apac"], [100, "apac_voc"], [400, "apac"]]
    assert s.n.tolist() == [4, 3, 2] and s.habit_wins.tolist() == [2, 3, 0]
    one = hw.summarize(_fits().assign(condition="x"), ["condition"])
    assert one.condition.tolist() == ["x"] and one.n.tolist() == [9] and one.habit_wins.tolist() == [5]


def test_summarize_gives_the_mean_and_the_t_interval_clipped_to_each_range():
    s = hw.summarize(_fits(), ["practice", "variant"])
    a, b, c = (s.iloc[i] for i in range(3))
    # A: every bounded quantity spreads past both ends of its range (t·sd/√3 > the distance to each bound)
    for q, (lo, hi) in {"mu_habit": (0.0, 750.0), "mu_goal": (0.0, 750.0), "sigma_habit": (10.0, 1e5),
                        "sigma_goal": (10.0, 1e5), "q_goal": (0.5, 1.0), "q_init": (0.0, 0.5),
                        "rho": (0.0, 1.0)}.items():
        assert (a[f"{q}_lo"], a[f"{q}_hi"]) == (lo, hi), q
    assert (a.mu_habit, a.sigma_habit, a.q_goal, a.rho) == pytest.approx((400.0, 40006.6666667, 0.75, 0.5))
    # ΔAIC is not clipped: mean 20, s.d. 30
    assert (a.delta_aic, a.delta_aic_lo, a.delta_aic_hi) == pytest.approx((20.0, 20 - T2 * 30 / math.sqrt(3),
                                                                           20 + T2 * 30 / math.sqrt(3)))
    # B: mu_habit s.d. 20 inside its range; equal values give a zero-width interval
    assert (b.mu_habit_lo, b.mu_habit_hi) == pytest.approx((400 - T2 * 20 / math.sqrt(3), 400 + T2 * 20 / math.sqrt(3)))
    assert (b.rho, b.rho_lo, b.rho_hi) == pytest.approx((0.5, 0.5, 0.5))
    # C: two fits give means and no interval
    assert c.mu_habit == pytest.approx(400.0) and c.delta_aic == pytest.approx(20.0)
    assert all(math.isnan(c[f"{q}_{e}"]) for q in hw.SUMMARY for e in ("lo", "hi"))
    assert list(s.columns) == ["practice", "variant", "n", "habit_wins",
                               *(f"{q}{e}" for q in hw.SUMMARY for e in ("", "_lo", "_hi"))]


class _Counter:
    """A stand-in for fit_row: records each resample and returns the call's number (NaN for the listed calls)."""

    def __init__(self, nan_calls=()):
        self.calls: list[tuple[np.ndarray, np.ndarray]] = []
        self.nan_calls = set(nan_calls)

    def __call__(self, t, c):
        self.calls.append((t, c))
        k = len(self.calls)
        v = math.nan if k in self.nan_calls else float(k)
        return {**dict.fromkeys(hw.SUMMARY, v), "delta_aic": -v}


T_BOOT = np.array([0.1, 0.2, 0.3, 0.4])
#: (n, 3) counts: none at 0.1 s, one habitual error, all correct, a mix; totals 0, 1, 5 and 100.
C_BOOT = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [5.0, 0.0, 0.0], [30.0, 10.0, 60.0]])


def test_bootstrap_fit_refits_100_resamples_and_takes_the_95_percent_percentiles(monkeypatch):
    fake = _Counter()
    monkeypatch.setattr(hw, "fit_row", fake)
    ci = hw.bootstrap_fit(T_BOOT, C_BOOT)
    assert len(fake.calls) == 100 and list(ci) == list(hw.SUMMARY)
    # numpy's linear percentiles of 1..100: 1 + 0.025·99 = 3.475 and 1 + 0.975·99 = 97.525
    assert ci["mu_habit"] == pytest.approx((3.475, 97.525)) and ci["rho"] == pytest.approx((3.475, 97.525))
    assert ci["delta_aic"] == pytest.approx((-97.525, -3.475))
    np.testing.assert_array_equal(fake.calls[0][0], T_BOOT)


def test_bootstrap_fit_level_and_failed_refits(monkeypatch):
    fake = _Counter(nan_calls=(1, 7))
    monkeypatch.setattr(hw, "fit_row", fake)
    ci = hw.bootstrap_fit(T_BOOT, C_BOOT, resamples=7, level=0.5)
    # the failed refits (calls 1 and 7) are left out: quartiles of 2..6 are 3 and 5
    assert len(fake.calls) == 7 and ci["q_goal"] == pytest.approx((3.0, 5.0))


def test_bootstrap_fit_redraws_each_times_total_from_its_proportions(monkeypatch):
    fake = _Counter()
    monkeypatch.setattr(hw, "fit_row", fake)
    hw.bootstrap_fit(T_BOOT, C_BOOT, resamples=400)
    c = np.stack([k[1] for k in fake.calls])
    assert c.shape == (400, 4, 3)
    np.testing.assert_array_equal(c[:, :3], np.broadcast_to(C_BOOT[:3], (400, 3, 3)))  # 0, 1 and 5 all one code
    np.testing.assert_array_equal(c[:, 3].sum(axis=1), 100.0)
    # the mix's mean over 400 draws: standard errors sqrt(100·p(1-p)/400) = 0.23, 0.15, 0.24
    np.testing.assert_allclose(c[:, 3].mean(axis=0), [30.0, 10.0, 60.0], atol=1.0)
    assert c[:, 3, 0].std() == pytest.approx(math.sqrt(100 * 0.3 * 0.7), rel=0.15)  # multinomial, not fixed


def test_bootstrap_fit_rounds_expected_counts_to_whole_trials(monkeypatch):
    fake = _Counter()
    monkeypatch.setattr(hw, "fit_row", fake)
    # time-outs as guesses give fractions: 1.75 trials redrawn as 2, 0.6 as 1, each of the one code observed
    hw.bootstrap_fit(np.array([0.1, 0.2]), np.array([[1.75, 0.0, 0.0], [0.0, 0.6, 0.0]]), resamples=20)
    for _, c in fake.calls:
        np.testing.assert_array_equal(c, [[2.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def _draws(monkeypatch, **kw) -> np.ndarray:
    fake = _Counter()
    monkeypatch.setattr(hw, "fit_row", fake)
    hw.bootstrap_fit(T_BOOT, C_BOOT, resamples=5, **kw)
    return np.stack([k[1] for k in fake.calls])


def test_bootstrap_fit_same_seed_same_resamples_another_seed_others(monkeypatch):
    first = _draws(monkeypatch, seed=3)
    np.testing.assert_array_equal(first, _draws(monkeypatch, seed=3))
    assert not np.array_equal(first, _draws(monkeypatch, seed=4))
    np.testing.assert_array_equal(_draws(monkeypatch), _draws(monkeypatch, seed=0))  # the default seed is 0
    assert not np.array_equal(_draws(monkeypatch), _draws(monkeypatch, seed=1))


def test_bootstrap_fit_interval_holds_the_fit_and_excludes_a_wrong_value():
    rng = np.random.default_rng(7)
    t = np.repeat(np.arange(0.1, 1.21, 0.05), 40)
    counts = hw.trial_counts(hw.simulate(t, TRUE, True, rng))
    grid = np.unique(t)
    per_time = np.stack([counts[t == g].sum(axis=0) for g in grid])
    point = hw.fit_row(grid, per_time)
    ci = hw.bootstrap_fit(grid, per_time, resamples=12, seed=1)
    for q in hw.SUMMARY:
        assert ci[q][0] <= point[q] <= ci[q][1], (q, ci[q], point[q])
    # true 450 ms (point fit 474): a minimal-practice-like 300 ms and the goal's 560 ms are excluded
    assert ci["mu_habit"][0] > 380.0 and ci["mu_habit"][1] < 540.0
    assert ci["mu_goal"][0] > 500.0 and ci["delta_aic"][0] > 0.0


def test_verdict_at_the_boundaries():
    h = (1.4, 1.2, 1.6)
    assert hw.verdict((1.0, 0.5, 1.2), h) == "overlaps"  # touching at the human lower bound
    assert hw.verdict((1.0, 0.5, 1.1999), h) == "below"
    assert hw.verdict((1.8, 1.6, 2.0), h) == "overlaps"  # touching at the human upper bound
    assert hw.verdict((1.8, 1.6001, 2.0), h) == "above"
    assert hw.verdict((math.nan, 1.3, 1.5), (math.nan, 1.2, 1.6)) == "overlaps"  # the means play no part
    for i in (1, 2):
        a, hh = [1.0, 0.5, 1.1], [1.4, 1.2, 1.6]
        a[i] = math.nan
        assert hw.verdict(tuple(a), h) == "no interval"
        hh[i] = math.inf
        assert hw.verdict((1.0, 0.5, 1.1), tuple(hh)) == "no interval"


def _humans() -> pd.DataFrame:
    rows = []
    for cond, mu, rho in (("4day", (480.0, 440.0, 520.0), (0.05, 0.02, 0.08)),
                          ("20day", (390.0, 330.0, 445.0), (0.15, 0.11, 0.20))):
        row = {"condition": cond}
        for q in hw.COMPARED:
            row.update({q: 1.0, f"{q}_lo": 0.5, f"{q}_hi": 1.5})
        row.update(mu_habit=mu[0], mu_habit_lo=mu[1], mu_habit_hi=mu[2], rho=rho[0], rho_lo=rho[1], rho_hi=rho[2])
        rows.append(row)
    return pd.DataFrame(rows)


def test_side_by_side_one_row_per_agent_group_and_parameter():
    agents = pd.DataFrame({"practice": [100, 400], "variant": ["apac", "apac_voc"], "seeds": [5, 5],
                           "mu_habit": [300.0, 420.0], "mu_habit_lo": [290.0, 400.0], "mu_habit_hi": [310.0, 440.0],
                           "rho": [0.3, 0.09], "rho_lo": [0.21, 0.08], "rho_hi": [0.4, 0.1]})
    t = hw.side_by_side(agents, _humans(), keys=("practice", "variant"), params=("mu_habit", "rho"))
    assert list(t.columns) == ["practice", "variant", "condition", "parameter", "agent", "agent_lo", "agent_hi",
                               "human", "human_lo", "human_hi", "verdict"]
    assert t.practice.tolist() == [100] * 4 + [400] * 4 and t.variant.tolist() == ["apac"] * 4 + ["apac_voc"] * 4
    assert t.condition.tolist() == ["4day", "4day", "20day", "20day"] * 2
    assert t.parameter.tolist() == ["mu_habit", "rho"] * 4
    # agent 100: mu 290-310 below both groups; rho 0.21-0.40 above both. agent 400: mu 400-440 overlaps
    # 4day's 440-520 (touching) and 20day's; rho 0.08-0.10 overlaps 4day's 0.02-0.08 (touching), below 0.11-0.20
    assert t.verdict.tolist() == ["below", "above", "below", "above", "overlaps", "overlaps", "overlaps", "below"]
    assert t.iloc[5][["agent", "agent_lo", "agent_hi", "human", "human_lo", "human_hi"]].tolist() == \
        [0.09, 0.08, 0.1, 0.05, 0.02, 0.08]


def test_side_by_side_of_point_estimates_has_no_interval():
    agents = pd.DataFrame([{"practice": 400, "variant": "apac", **dict.fromkeys(hw.COMPARED, 1.0)}])
    t = hw.side_by_side(agents, _humans())  # the default keys and parameters
    assert t.parameter.tolist() == list(hw.COMPARED) * 2 and (t.verdict == "no interval").all()
    assert t.agent_lo.isna().all() and t.agent_hi.isna().all() and (t.practice == 400).all()
    assert (t.variant == "apac").all() and t.human.tolist()[:2] == [480.0, 1.0]


def test_sliding_window_trial_count_rule_and_denominator():
    t = np.array([0.31, 0.32, 0.33, 0.34, 0.61])
    counts = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [1.0, 0, 0], [0, 1.0, 0]])
    p = hw.sliding_window(t, counts, np.array([0.3, 0.6]), 0.1)
    np.testing.assert_allclose(p[:, 0], [0.5, 0.25, 0.25])  # exactly 4 trials: enough by default
    assert np.isnan(p[:, 1]).all()
    np.testing.assert_allclose(hw.sliding_window(t, counts, np.array([0.6]), 0.1, min_trials=1)[:, 0], [0, 1, 0])
    assert np.isnan(hw.sliding_window(t, counts, np.array([0.3]), 0.1, min_trials=5)).all()
    # width 0.24 at 0.5: (0.38, 0.62] holds 0.61 only; width 0.02 at 0.335: (0.325, 0.345] holds 0.33 and 0.34
    np.testing.assert_allclose(hw.sliding_window(t, counts, np.array([0.5]), 0.24, min_trials=1)[:, 0], [0, 1, 0])
    np.testing.assert_allclose(hw.sliding_window(t, counts, np.array([0.335]), 0.02, min_trials=2)[:, 0],
                               [0.5, 0.0, 0.5])


def test_guesses_split_time_outs_among_the_keys():
    c = np.array([[2.0, 0.0, 0.0], [0.0, 1.0, 1.0]])
    np.testing.assert_allclose(hw.guesses(c, np.array([4.0, 8.0])), [[3.0, 1.0, 2.0], [2.0, 3.0, 5.0]])  # 4 keys
    np.testing.assert_allclose(hw.guesses(c, np.array([3.0, 0.0]), keys=3), [[3.0, 1.0, 1.0], [0.0, 1.0, 1.0]])
    np.testing.assert_allclose(hw.guesses(c, np.array([5.0, 0.0]), keys=5), [[3.0, 1.0, 3.0], [0.0, 1.0, 1.0]])
    msg = r"^a guess needs at least 3 keys \(correct, habitual, other\); got 2$"
    with pytest.raises(hw.FitInputError, match=msg):
        hw.guesses(c, np.ones(2), keys=2)


def test_response_probs_default_to_the_habit_model_and_sum_to_one():
    hand = (0.4, 0.01, 0.4, 0.01, 0.9, 0.25, 0.2)
    t = np.array([0.0, 0.4, 1.0])
    np.testing.assert_allclose(hw.response_probs(t, hand), hw.response_probs(t, hand, habit=True))
    np.testing.assert_allclose(hw.response_probs(t, hand).sum(axis=0), 1.0)
    codes = hw.simulate(t, hand, True, np.random.default_rng(0))
    assert codes.dtype.kind == "i" and set(codes.tolist()) <= {1, 2, 3}


def test_the_no_habit_penalty_counts_its_one_spread_only():
    assert hw.penalty((0.5, 0.3, 0.9, 0.25), habit=False) == pytest.approx(500 * 0.2 ** 2)  # not q_init's 0.25
    assert hw.penalty((0.4, 0.3, 0.5, 0.05, 0.9, 0.25, 0.1)) == pytest.approx(500 * (0.2 ** 2 + 0.05 ** 2))


def test_trial_counts_names_the_first_five_bad_codes():
    msg = r"^responses must be the codes 1 \(correct\), 2 \(habitual\), 3 \(other\); got \[0, 5, 6, 7, 8\]$"
    with pytest.raises(hw.FitInputError, match=msg):
        hw.trial_counts(np.array([1, 9, 0, 2, 8, 7, 6, 5, 3]))


def test_fit_refuses_non_finite_times_or_counts_and_no_trials_but_fits_one():
    one = np.array([[1.0, 0.0, 0.0]])
    finite = r"^times and counts must be finite, counts >= 0$"
    with pytest.raises(hw.FitInputError, match=finite):
        hw.fit(np.array([math.nan]), one)  # counts finite, a time not
    with pytest.raises(hw.FitInputError, match=finite):
        hw.fit(np.array([0.3]), np.array([[math.inf, 0.0, 0.0]]))  # times finite, a count not
    with pytest.raises(hw.FitInputError, match=r"^no trials to fit$"):
        hw.fit(np.array([0.3]), np.zeros((1, 3)))
    f = hw.fit(np.array([0.3]), one)  # the default is the habit model; one trial is enough
    assert f.habit is True and len(f.params) == 7 and f.trials == 1.0


def _objective_gain(t, counts, f, h=1e-3) -> float:
    """The largest drop of the penalized objective from a step h along each parameter (and μ_A, μ_B together)
    that stays within the bounds and μ_A <= μ_B: 0 at a local optimum. The fit itself must be feasible."""
    x, idx = np.asarray(f.params), slice(None) if f.habit else hw._NO_HABIT_INDEX
    lo, hi = np.asarray(hw.LOWER)[idx], np.asarray(hw.UPPER)[idx]
    ordered = (lambda p: p[0] <= p[2]) if f.habit else (lambda p: True)  # noqa: E731
    assert np.all(x >= lo) and np.all(x <= hi) and ordered(x), x
    obj = lambda p: -hw.log_likelihood(t, counts, p, f.habit) + hw.penalty(p, f.habit)  # noqa: E731
    base, eye, best = obj(x), np.eye(x.size), 0.0
    for d in [*eye, eye[0] + eye[2]] if f.habit else eye:
        for y in (x + h * d, x - h * d):
            if np.all(y >= lo) and np.all(y <= hi) and ordered(y):
                best = max(best, base - obj(y))
    return best


def test_each_fit_is_a_feasible_local_optimum_where_the_order_or_a_bound_binds():
    rng = np.random.default_rng(0)
    t = np.repeat(np.arange(0.1, 1.21, 0.05), 30)
    # the habit prepared after the goal (650 vs 400 ms): μ_A <= μ_B binds. Measured: no step gains > 5e-6,
    # while the fit without the constraint (projected) or with the projection's mean miscomputed gains 0.12-0.47
    late_habit = hw.trial_counts(hw.simulate(t, (0.65, 0.05, 0.4, 0.05, 0.95, 0.25, 0.3), True, rng))
    f = hw.fit(t, late_habit)
    assert f.params[0] == f.params[2] and _objective_gain(t, late_habit, f) < 1e-4
    # the goal at 900 ms: its bound 750 ms binds (the fit without bounds, clipped, gains 1.6)
    late_goal = hw.trial_counts(hw.simulate(t, (0.5, 0.05, 0.9, 0.05, 0.95, 0.25, 0.05), True, rng))
    f = hw.fit(t, late_goal)
    assert f.params[2] == pytest.approx(0.75) and _objective_gain(t, late_goal, f) < 1e-4
    # no habit, the goal at 700 ms with q_B 0.55 (μ_B > q_B: the habit model's order constraint read on the
    # no-habit parameters would bind; σ_A's penalty read on q_I would pull it): gains 0.05 and 0.12 then
    no_habit = hw.trial_counts(hw.simulate(t, (0.7, 0.05, 0.55, 0.25), False, rng))
    f = hw.fit(t, no_habit, False)
    assert f.params[0] > f.params[2] and _objective_gain(t, no_habit, f) < 1e-4


def test_the_habit_fit_penalizes_the_goals_spread_too():
    # σ_B = 0.3 s on 300 trials: the likelihood alone puts it at 0.30-0.36 s, the penalty pulls it to 0.16-0.17 s
    for seed in (0, 1):
        rng = np.random.default_rng(seed)
        t = rng.uniform(0.0, 1.2, 300)
        counts = hw.trial_counts(hw.simulate(t, (0.3, 0.05, 0.55, 0.3, 0.95, 0.25, 0.05), True, rng))
        assert hw.fit(t, counts).params[3] < 0.2
