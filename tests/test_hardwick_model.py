"""apac_mj/report/hardwick.py: Hardwick et al. (2019)'s model against hand computations, its own simulations and
(where the authors' files are at hand) the authors' fits on their data."""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from apac_mj.report import forced_response as fr
from apac_mj.report import hardwick as hw

#: μ_A = μ_B = 0.4 s with tiny spreads: at 0 s nothing is prepared, at 0.4 s each is with P 0.5, at 1 s both.
HAND = (0.4, 0.01, 0.4, 0.01, 0.9, 0.25, 0.2)
#: A 4-day-like participant (s): habit ready at 450 ms, goal at 560 ms, 5% of habits not replaced.
TRUE = (0.45, 0.07, 0.56, 0.08, 0.93, 0.25, 0.05)


def test_response_probabilities_match_the_hand_computation():
    p = hw.response_probs(np.array([0.0, 0.4, 1.0]), HAND, habit=True)
    # 0.4 s: events (!A!B, A!B, !AB, AB) 1/4 each; rho = 0.2 keeps A over B: 0.3, 0.3, 0.2, 0.2
    # correct 0.25*0.3 + (0.05/3)*0.3 + 0.9*0.4; habitual 0.25*0.3 + 0.95*0.3 + (0.1/3)*0.4; other the rest
    np.testing.assert_allclose(p[:, 1], [0.44, 0.373333333, 0.186666667], atol=1e-8)
    np.testing.assert_allclose(p[:, 0], [0.25, 0.25, 0.5], atol=1e-8)  # nothing prepared: q_I, q_I, 1 - 2q_I
    # 1 s: A!B with rho, AB with 1 - rho: correct 0.2*0.05/3 + 0.8*0.9, habitual 0.2*0.95 + 0.8*0.1/3
    np.testing.assert_allclose(p[:, 2], [0.723333333, 0.216666667, 0.06], atol=1e-8)
    q = hw.response_probs(np.array([0.4]), HAND[2:6], habit=False)  # no habit: B alone, P 0.5
    np.testing.assert_allclose(q[:, 0], [0.5 * 0.25 + 0.5 * 0.9, 0.5 * 0.25 + 0.5 * 0.1 / 3,
                                         0.5 * 0.5 + 0.5 * 0.2 / 3], atol=1e-8)


def test_log_likelihood_penalty_and_aic_on_a_small_case():
    t = np.array([0.4, 0.0, 1.0])
    counts = hw.trial_counts(np.array([1, 3, 2]))
    expected = math.log(0.44) + math.log(0.5) + math.log(0.216666667)
    assert hw.log_likelihood(t, counts, HAND) == pytest.approx(expected, abs=1e-7)
    # counts per time are the per-trial likelihood summed: two trials at 0.4 s, one correct, one habitual
    two = hw.log_likelihood(np.array([0.4]), np.array([[1.0, 1.0, 0.0]]), HAND)
    assert two == pytest.approx(math.log(0.44) + math.log(0.373333333), abs=1e-7)
    assert hw.penalty(HAND) == pytest.approx(500 * (0.09 ** 2 + 0.09 ** 2))
    fit = hw.Fit(True, HAND, -100.0, 3)
    assert fit.k == 7 and fit.aic == pytest.approx(214.0)
    assert hw.delta_aic(fit, hw.Fit(False, HAND[2:6], -104.0, 3)) == pytest.approx(216.0 - 214.0)


def _simulated(params, habit, n, seed):
    rng = np.random.default_rng(seed)
    t = rng.uniform(0.0, 1.2, n)
    return t, hw.trial_counts(hw.simulate(t, params, habit, rng))


def test_parameters_are_recovered_from_data_simulated_by_the_model():
    t, counts = _simulated(TRUE, True, 4000, 1)
    got = hw.fit(t, counts, True).params
    tol = (0.015, 0.02, 0.015, 0.02, 0.03, 0.03, 0.04)  # s, s, s, s, P, P, P
    assert np.all(np.abs(np.subtract(got, TRUE)) < tol), (got, TRUE)
    t, counts = _simulated(TRUE[2:6], False, 3000, 2)
    got = hw.fit(t, counts, False).params
    assert np.all(np.abs(np.subtract(got, TRUE[2:6])) < (0.015, 0.02, 0.03, 0.03)), got


def test_the_fit_carries_the_authors_penalty_on_the_spreads():
    # a 0.3 s spread on 300 trials: the likelihood alone puts it at 0.32-0.39 s, the penalty 500 (σ - 0.1)^2
    # pulls it to 0.12-0.16 s (measured at these seeds)
    for seed in (0, 1):
        rng = np.random.default_rng(seed)
        t = rng.uniform(0.0, 1.2, 300)
        counts = hw.trial_counts(hw.simulate(t, (0.5, 0.3, 0.95, 0.25), False, rng))
        assert hw.fit(t, counts, False).params[1] < 0.2


def test_aic_prefers_the_habit_model_only_on_habit_data():
    for seed in (3, 4):
        t, counts = _simulated(TRUE, True, 800, seed)
        assert hw.delta_aic(*hw.fit_both(t, counts)) > 0
        t, counts = _simulated(TRUE[2:6], False, 800, seed)
        assert hw.delta_aic(*hw.fit_both(t, counts)) < 0


def test_guesses_and_the_window_on_counts():
    g = hw.guesses(np.array([[2.0, 0.0, 0.0]]), np.array([4.0]), keys=4)
    np.testing.assert_allclose(g, [[3.0, 1.0, 2.0]])
    # a window over counts equals the window over the trials they count
    t, c = np.array([0.30, 0.35]), np.array([[2.0, 1.0, 0.0], [0.0, 3.0, 1.0]])
    trials_t = np.repeat(t, c.sum(axis=1).astype(int))
    codes = np.concatenate([np.repeat([1, 2, 3], row.astype(int)) for row in c])
    a = hw.sliding_window(t, c, np.array([0.30, 0.325, 0.40]), 0.1)
    b = hw.sliding_window(trials_t, hw.trial_counts(codes), np.array([0.30, 0.325, 0.40]), 0.1)
    np.testing.assert_allclose(a, b)
    np.testing.assert_allclose(a[:, 0], [2 / 7, 4 / 7, 1 / 7])  # (0.25, 0.35]: both times
    assert np.isnan(a[:, 2]).all()  # (0.35, 0.45]: no trial
    # the agents' tests in ms on the window's own grid: centre 400 holds 400 and 450, not 350
    w = hw.sliding_window(np.array([350.0, 400.0, 450.0]), np.array([[4.0, 0, 0], [0, 4.0, 0], [0, 0, 4.0]]),
                          np.array([400.0]), 100.0)
    np.testing.assert_allclose(w[:, 0], [0.0, 0.5, 0.5])


def test_bad_input_is_refused():
    with pytest.raises(hw.FitInputError, match="codes 1"):
        hw.trial_counts(np.array([1, 2, 4]))
    with pytest.raises(hw.FitInputError, match="shape"):
        hw.fit(np.array([0.1, 0.2]), np.ones((3, 3)))
    with pytest.raises(hw.FitInputError, match=">= 0"):
        hw.fit(np.array([0.1]), np.array([[1.0, -1.0, 0.0]]))
    with pytest.raises(hw.FitInputError, match="3 keys"):
        hw.guesses(np.ones((1, 3)), np.ones(1), keys=2)


def _seed_table(params, seeds, trials=150):
    """A per_seed-like table of remapped-cue counts simulated by the model, with time-outs at the shortest time."""
    rows = []
    for seed in range(seeds):
        rng = np.random.default_rng(10 + seed)
        for prep in np.arange(100.0, 1201.0, 50.0):
            c = hw.trial_counts(hw.simulate(np.full(trials, prep / 1000), params, True, rng)).sum(axis=0)
            rows.append({"practice": 400, "variant": "apac_voc", "seed": seed, "remapped": True, "prep_ms": prep,
                         "correct": c[0], "habitual": c[1], "other": c[2], "timeout": 0.0})
    return pd.DataFrame(rows)


def test_the_study_fits_each_seed_and_gives_seed_intervals():
    seeds = _seed_table(TRUE, 3)
    fits = fr.hardwick_fits(seeds)
    assert len(fits) == 3 and (fits.habit_wins == 1).all()
    s = hw.summarize(fits, ["practice", "variant"]).iloc[0]
    assert s.n == 3 and s.habit_wins == 3
    assert s.mu_habit_lo <= s.mu_habit <= s.mu_habit_hi and abs(s.mu_habit - 450.0) < 20.0
    assert abs(s.mu_goal - 560.0) < 20.0 and np.isfinite(s.delta_aic_lo)
    # a time-out is a guess: 1/4 correct, 1/4 habitual, 1/2 other
    g = seeds[seeds.seed == 0].copy()
    g.loc[g.index[0], "timeout"] = 4.0
    _, counts = fr.remapped_counts(g)
    base = g.iloc[0][["correct", "habitual", "other"]].to_numpy(float)
    np.testing.assert_allclose(counts[0], base + [1.0, 1.0, 2.0])


def test_curves_as_counts_refuses_rates_that_are_not_counts():
    curve = pd.DataFrame({"practice": [400], "variant": ["apac"], "remapped": [True], "prep_ms": [300.0],
                          "seeds": [10], "correct": [0.5], "habitual": [0.25], "other": [0.25], "timeout": [0.0]})
    out = fr.curves_as_counts(curve, 200)
    assert out[["correct", "habitual", "other"]].iloc[0].tolist() == [1000.0, 500.0, 500.0]
    with pytest.raises(ValueError, match="not counts"):
        fr.curves_as_counts(curve.assign(correct=0.50033, other=0.24967), 200)


# --- the authors' own fits (HabitTR, branch publication, commit 0e0b08a); the repository carries no licence,
# so its files are not shipped: put model_pooled.mat, i_habitual.mat and Publication/HabitData.mat in
# $HABITTR_DIR (default results/hardwick/HabitTR) to run these.
_DIR = Path(os.environ.get("HABITTR_DIR", Path(__file__).resolve().parents[1] / "results/hardwick/HabitTR"))
#: The authors' pooled habit-model fits (model_pooled.mat, model 2; ρ = 1 − their params(8)), per condition.
AUTHORS_POOLED = {0: (0.437745, 0.01, 0.437745, 0.020669, 0.899982, 0.260506, 0.0),
                  1: (0.511580, 0.129848, 0.511826, 0.111008, 0.941593, 0.274907, 0.050973),
                  2: (0.351633, 0.073072, 0.451401, 0.110236, 0.915574, 0.250878, 0.056265)}
#: The authors' 4-day participants for whom the habit model has the lower AIC (i_habitual.mat, subject numbers).
AUTHORS_HABITUAL = {1, 2, 3, 5, 8, 9, 11, 12, 13, 14, 17, 18, 20, 22, 23, 24}


@pytest.mark.skipif(not (_DIR / "model_pooled.mat").is_file(), reason="the authors' model_pooled.mat is not here")
def test_the_authors_pooled_habit_fits_are_reproduced():
    import scipy.io as sio

    data = sio.loadmat(str(_DIR / "model_pooled.mat"))["data_all"]
    # the likelihood at their parameters is their LL (model_pooled.mat's LL, to 1e-6)
    rt, y = data[0, 1]["RT"].ravel().astype(float), data[0, 1]["response"].ravel().astype(int)
    assert hw.log_likelihood(rt, hw.trial_counts(y), AUTHORS_POOLED[1]) == pytest.approx(-4173.714147, abs=1e-5)
    for c, theirs in AUTHORS_POOLED.items():
        rt, y = data[0, c]["RT"].ravel().astype(float), data[0, c]["response"].ravel().astype(int)
        ok = ~np.isnan(rt)
        ours = hw.fit(rt[ok], hw.trial_counts(y[ok]), True).params
        # within 0.5 ms and 0.0005 in probability (measured: 0.1 ms / 0.0001 at most; their minimal-practice
        # ρ = 0 lies below the published lower bound 1e-4)
        assert np.all(np.abs(np.subtract(ours, theirs)) < 5e-4), (c, ours, theirs)


@pytest.mark.skipif(not (_DIR / "Publication/HabitData.mat").is_file(), reason="the authors' HabitData.mat is not here")
def test_the_authors_habit_favoured_participants_are_reproduced():
    import scipy.io as sio

    data = sio.loadmat(str(_DIR / "Publication/HabitData.mat"))["data"]
    favoured = set()
    for s in range(data.shape[0]):
        e = data[s, 1]  # the 4-day group
        if e["RT"].size == 0:
            continue
        rt, y = e["RT"].ravel().astype(float), e["response"].ravel().astype(int)
        ok = ~np.isnan(rt)
        if hw.delta_aic(*hw.fit_both(rt[ok], hw.trial_counts(y[ok]))) > 0:
            favoured.add(s + 1)
    assert favoured == AUTHORS_HABITUAL


def test_the_report_writes_the_fits_and_the_humans_window_of_the_agents(tmp_path):
    # habitual errors only at 400 and 450 ms (8 of 10 trials): the windows centred at 400 and 425 ms hold both
    rows = []
    for seed in range(3):
        for prep in np.arange(100.0, 1201.0, 50.0):
            hab = 8 if prep in (400.0, 450.0) else 0
            rows.append({"practice": 100, "variant": "apac_voc", "seed": seed, "remapped": True, "prep_ms": prep,
                         "correct": 0 if prep < 300 else 10 - hab, "habitual": hab, "other": 0,
                         "timeout": (prep < 300) * 10})
    fr.write_hardwick(pd.DataFrame(rows), tmp_path)
    peaks = pd.read_csv(tmp_path / "window_peaks.csv").iloc[0]
    assert peaks.window_peak_ms == 412.5 and peaks.window_peak == pytest.approx(0.8)
    assert peaks.window_50_150 == pytest.approx(0.25)  # time-outs are guesses: 1 of 4 keys is the old target
    assert len(pd.read_csv(tmp_path / "hardwick_fits.csv")) == 3
    assert pd.read_csv(tmp_path / "hardwick.csv").n.tolist() == [3]


def test_side_by_side_says_overlap_or_which_side():
    assert hw.verdict((1.0, 0.5, 1.5), (1.4, 1.2, 1.6)) == "overlaps"
    assert hw.verdict((1.0, 0.5, 1.1), (1.4, 1.2, 1.6)) == "below"
    assert hw.verdict((2.0, 1.7, 2.1), (1.4, 1.2, 1.6)) == "above"
    assert hw.verdict((2.0, math.nan, math.nan), (1.4, 1.2, 1.6)) == "no interval"
    agents = pd.DataFrame({"practice": [400], "variant": ["apac_voc"], "mu_habit": [300.0], "mu_habit_lo": [290.0],
                           "mu_habit_hi": [310.0]})
    humans = pd.DataFrame({"condition": ["4day", "20day"], "mu_habit": [480.0, 390.0], "mu_habit_lo": [440.0, 330.0],
                           "mu_habit_hi": [520.0, 445.0]})
    t = hw.side_by_side(agents, humans, params=("mu_habit",))
    assert t.verdict.tolist() == ["below", "below"] and t.condition.tolist() == ["4day", "20day"]
