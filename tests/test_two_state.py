"""The two-state model (Smith et al. 2006): its recursion by hand, recovery of known parameters, spontaneous
recovery, and the fit's refusals."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from apac_mj.report import two_state as ts

SMITH = ts.TwoState(**ts.SMITH_2006)
#: Smith et al.'s paradigm, short: baseline, adaptation, brief reverse field, error-clamp block.
BLOCKS = [("null", 20), ("field", 150), ("reverse", 15), ("channel", 60)]


def test_recursion_by_hand():
    p = ts.TwoState(A_f=0.5, B_f=0.5, A_s=0.9, B_s=0.1)
    sim = ts.simulate(p, [1.0, 1.0, 0.0, 0.0], [False, False, True, False])
    # trial 0: x=0, e=1 -> x_f=0.5, x_s=0.1; trial 1: x=0.6, e=0.4 -> x_f=0.45, x_s=0.13;
    # trial 2 (channel): e=0 -> x_f=0.225, x_s=0.117; trial 3 (null): e = -0.342
    np.testing.assert_allclose(sim["x"], [0.0, 0.6, 0.58, 0.342])
    np.testing.assert_allclose(sim["e"], [1.0, 0.4, 0.0, -0.342])
    np.testing.assert_allclose(sim["x_f"], [0.0, 0.5, 0.45, 0.225])


def test_paradigm_blocks():
    f, c = ts.paradigm([("null", 2), ("field", 1), ("reverse", 1), ("channel", 2)])
    np.testing.assert_array_equal(f, [0, 0, 1, -1, 0, 0])
    np.testing.assert_array_equal(c, [False] * 4 + [True] * 2)
    with pytest.raises(ValueError, match="block"):
        ts.paradigm([("curl", 3)])


def test_noise_free_fit_recovers_the_parameters():
    f, c = ts.paradigm(BLOCKS)
    r = ts.fit(f, c, ts.simulate(SMITH, f, c)["x"])
    np.testing.assert_allclose(list(r.params.as_dict().values()), list(ts.SMITH_2006.values()), rtol=1e-4)
    assert r.rmse < 1e-6


def test_noisy_fit_recovers_the_parameters_over_seeds_and_ignoring_the_clamp_does_not():
    f, c = ts.paradigm(BLOCKS)
    x = ts.simulate(SMITH, f, c)["x"].to_numpy()
    rows = []
    for seed in range(4):
        y = x + np.random.default_rng(seed).normal(0.0, 0.02, x.size)
        rows.append(pd.DataFrame({"seed": seed, "trial": np.arange(x.size), "field": f, "channel": c,
                                  "adaptation": y}))
    per_seed = ts.fit_seeds(pd.concat(rows))
    summary = ts.summarize(per_seed).set_index("parameter")
    for name, true in ts.SMITH_2006.items():
        assert summary.loc[name, "mean"] == pytest.approx(true, rel=0.1), name
        assert summary.loc[name, "lo"] <= true <= summary.loc[name, "hi"], name
    assert (per_seed["A_s"] > per_seed["A_f"]).all() and (per_seed["B_f"] > per_seed["B_s"]).all()
    # a wrong method (errors on the clamped trials, as if they were null trials) lands far from the truth
    wrong = ts.fit(f, np.zeros_like(c), x + np.random.default_rng(0).normal(0.0, 0.02, x.size)).params.as_dict()
    assert any(wrong[name] != pytest.approx(true, rel=0.1) for name, true in ts.SMITH_2006.items())


def test_spontaneous_recovery_two_states_rebound_one_state_does_not():
    f, c = ts.paradigm(BLOCKS)
    block = slice(185, 245)
    two = ts.simulate(SMITH, f, c)["x"]
    assert abs(two[185]) < 0.1  # de-adapted to about zero
    assert ts.spontaneous_recovery(two, block) > 0.1
    one = ts.simulate(ts.TwoState(A_f=0.0, B_f=0.0, A_s=0.99, B_s=0.03), f, c)["x"]
    assert ts.spontaneous_recovery(one, block) == 0.0
    assert ts.spontaneous_recovery(-two, block, sign=-1.0) == pytest.approx(ts.spontaneous_recovery(two, block))


def test_fit_refuses_bad_input():
    with pytest.raises(ValueError, match="one length"):
        ts.fit([1.0, 1.0], [False], [0.1, 0.2])
    with pytest.raises(ValueError, match="at least 4"):
        ts.fit(np.ones(10), np.zeros(10, bool), [0.1, 0.2, 0.3] + [np.nan] * 7)
    with pytest.raises(ValueError, match="A_f"):
        ts.TwoState(A_f=1.5, B_f=0.1, A_s=0.9, B_s=0.01)


def test_lateral_error_sign_follows_the_curl_field():
    # moving +y from (0, 0): clockwise (the b > 0 curl field's push, F = (b v_y, -b v_x)) is +x
    path = np.array([[0.0, 0.0], [0.3, 1.0], [0.1, 2.0], [-0.2, 3.0]])
    assert ts.lateral_error(path, (0, 0), (0, 3)) == pytest.approx(0.3)
    assert ts.lateral_error(path, (0, 3), (0, 0)) == pytest.approx(-0.3)  # moving -y, clockwise is -x
    assert ts.lateral_error(np.array([[0, 0], [1, -0.5], [2, 0.2]]), (0, 0), (2, 0)) == pytest.approx(0.5)



def test_packed_coordinates_map_to_the_parameters_by_hand():
    """``A_s = A_f + (1 - A_f) z1``, ``B_f = B_s + (1 - B_s) z3``, each coordinate clipped to [0, 1]."""
    p = ts._unpack(np.array([0.5, 0.5, 0.2, 0.25]))
    assert (p.A_f, p.A_s, p.B_s, p.B_f) == pytest.approx((0.5, 0.75, 0.2, 0.4))
    assert ts._unpack(np.array([1.5, -0.5, 0.0, 1.0])).as_dict() == pytest.approx(
        {"A_f": 1.0, "B_f": 1.0, "A_s": 1.0, "B_s": 0.0})


def test_a_fit_reports_its_rmse_and_trials_by_hand():
    """Null trials keep x at 0 whatever the parameters, so measured values of +-1 leave residuals of exactly 1."""
    y = np.array([1.0, -1.0, np.nan, 1.0, -1.0, 1.0, np.nan])
    r = ts.fit(np.zeros(7), np.zeros(7, bool), y)
    assert r.rmse == pytest.approx(1.0, abs=1e-9) and r.trials == 5


def test_seeds_are_fitted_one_by_one_and_summarized_inside_the_unit_interval():
    f, c = ts.paradigm(BLOCKS)
    x = ts.simulate(SMITH, f, c)["x"].to_numpy()
    table = pd.concat([pd.DataFrame({"seed": s, "trial": np.arange(f.size), "field": f, "channel": c,
                                     "adaptation": np.where(c | (np.arange(f.size) % 5 == 0), x, np.nan)})
                       for s in (3, 7, 9)])
    per_seed = ts.fit_seeds(table)
    assert list(per_seed.columns) == ["seed", *ts.PARAMETERS, "rmse", "trials"]
    assert per_seed.seed.tolist() == [3, 7, 9] and (per_seed.trials == int(np.isfinite(table.adaptation).sum() / 3)).all()
    assert (per_seed.rmse < 1e-6).all() and per_seed.A_s.to_numpy() == pytest.approx(SMITH.A_s, rel=1e-3)
    near_one = per_seed.assign(A_s=[0.999, 1.0, 0.98])
    summary = ts.summarize(near_one).set_index("parameter")
    assert list(summary.columns) == ["mean", "lo", "hi", "seeds"] and (summary.seeds == 3).all()
    assert summary.loc["A_s", "mean"] == pytest.approx(np.mean([0.999, 1.0, 0.98]))
    assert summary.loc["A_s", "hi"] == 1.0 and 0.9 < summary.loc["A_s", "lo"] < 0.98  # clipped to [0, 1]


def test_spontaneous_recovery_and_lateral_error_by_hand():
    x = np.array([5.0, 0.0, 0.2, 0.5, 0.3])
    assert ts.spontaneous_recovery(x, slice(1, 5)) == pytest.approx(0.5)
    assert ts.spontaneous_recovery(-x, slice(1, 5), sign=-1.0) == pytest.approx(0.5)
    assert ts.spontaneous_recovery(np.array([0.4, 0.9]), slice(0, 2)) == pytest.approx(0.5)  # from where it began
    with pytest.raises(ValueError, match="empty"):
        ts.spontaneous_recovery(x, slice(5, 5))
    # start (1, 2) -> target (4, 6): direction (0.6, 0.8), clockwise (0.8, -0.6); a point 0.5 along it
    path = np.array([[1.0, 2.0], [1.4, 1.7], [4.0, 6.0]])
    assert ts.lateral_error(path, (1, 2), (4, 6)) == pytest.approx(0.5)


def test_one_trial_and_an_empty_block_are_a_schedule():
    f, c = ts.paradigm([("null", 0), ("channel", 1)])
    assert f.tolist() == [0.0] and c.tolist() == [True]
    with pytest.raises(ValueError, match="trials >= 0"):
        ts.paradigm([("null", -1)])
    with pytest.raises(ValueError, match="one length >= 1"):
        ts.check_schedule([], [])
