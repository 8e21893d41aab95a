"""bench/dynamics.py's multi-seed aggregation on synthetic training rows: per-seed windows from the schedule,
per-seed effects (window differences), the recovery episode per seed, and the summary over seeds."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats
from conftest import bench_module



@pytest.fixture(scope="module")
def dyn():
    return bench_module("dynamics")


CURL_SCHEDULE = {"field_on_episode": 110, "field_off_episode": 130, "load_change_episode": -1}
LOAD_SCHEDULE = {"field_on_episode": -1, "field_off_episode": -1, "load_change_episode": 110}


def _rows(dyn, condition: str, errors: dict[int, np.ndarray]) -> pd.DataFrame:
    """Training rows of agent 'apac': per seed an error per episode; the other quantities derived from it."""
    frames = []
    for seed, e in errors.items():
        n = len(e)
        frames.append(pd.DataFrame({"agent": "apac", "condition": condition, "seed": seed, "episode": np.arange(n),
                                    "error": e, "relative_error": e / 10, "final_distance": e / 2,
                                    "success": e < 2.0, "habit_share": np.full(n, 0.1 * seed)}))
    return pd.concat(frames, ignore_index=True)


def test_windows_follow_the_schedule_and_the_episode_count(dyn):
    curl = dyn.windows(dyn.CURL, CURL_SCHEDULE, 200)
    assert curl == {"before": (100, 109), "field early": (110, 114), "field late": (125, 129),
                    "after-effect": (130, 134), "after late": (195, 199), "last 30": (170, 199)}
    load = dyn.windows(dyn.LOAD, LOAD_SCHEDULE, 150)
    assert load == {"before": (100, 109), "right after": (110, 114), "late": (140, 149), "last 30": (120, 149)}
    assert dyn.windows(dyn.TORQUE, {}, 200) == {"late": (190, 199), "last 30": (170, 199)}


def test_per_seed_windows_and_the_after_effect_per_seed(dyn):
    # seed s: error 1 + s before the field, 5 + s in it, 3 + 2 s after it (the after-effect differs per seed)
    errors = {}
    for s in range(3):
        e = np.full(200, 1.0 + s)
        e[110:130], e[130:] = 5.0 + s, 3.0 + 2 * s
        errors[s] = e
    rows = _rows(dyn, dyn.CURL, errors)
    per = dyn.seed_windows(rows, {("apac", dyn.CURL): dyn.windows(dyn.CURL, CURL_SCHEDULE, 200)})
    w = per.set_index(["seed", "window"])
    for s in range(3):
        assert w.loc[(s, "before"), "error_cm"] == pytest.approx(1 + s)
        assert w.loc[(s, "field early"), "error_cm"] == pytest.approx(5 + s)
        assert w.loc[(s, "after-effect"), "error_cm"] == pytest.approx(3 + 2 * s)
        assert w.loc[(s, "before"), "successes"] == (10 if s == 0 else 0)  # error < 2 only for seed 0
        assert w.loc[(s, "before"), "habit_share"] == pytest.approx(0.1 * s)
    eff = dyn.seed_effects(per).set_index(["seed", "effect"])
    for s in range(3):
        assert eff.loc[(s, "after-effect"), "error_cm"] == pytest.approx((3 + 2 * s) - (1 + s))
        assert eff.loc[(s, "immediate cost"), "relative_error"] == pytest.approx(0.4)
    summary = dyn.summarize(eff.reset_index(), ["agent", "condition", "effect"], ["error_cm"])
    after = summary[summary.effect == "after-effect"].iloc[0]
    assert after["mean"] == pytest.approx(3.0)  # per-seed after-effects 2, 3, 4
    half = stats.t.ppf(0.9875, 2) * 1.0 / np.sqrt(3)  # the report's interval: t at 97.5%, sd 1 over 3 seeds
    assert (after.lo, after.hi) == pytest.approx((3.0 - half, 3.0 + half))
    assert after.seeds == 3 and after.per_seed == "0:2 1:3 2:4"


def test_an_untrained_window_is_incomplete_and_left_out_of_the_mean(dyn):
    errors = {0: np.ones(200), 1: np.ones(120)}  # seed 1 has not reached the field's switch-off yet
    per = dyn.seed_windows(_rows(dyn, dyn.CURL, errors),
                           {("apac", dyn.CURL): dyn.windows(dyn.CURL, CURL_SCHEDULE, 200)})
    w = per.set_index(["seed", "window"])
    assert w.loc[(1, "field early"), "complete"] and not w.loc[(1, "after-effect"), "complete"]
    assert np.isnan(w.loc[(1, "after-effect"), "error_cm"])
    s = dyn.summarize(per, ["window"], ["error_cm"]).set_index("window")
    assert s.loc["after-effect", "seeds"] == 1 and s.loc["before", "seeds"] == 2


def test_recovery_episode_per_seed(dyn):
    rng = np.random.default_rng(0)
    errors = {}
    for s, back_at in enumerate((120, 150, None)):
        e = 2.0 + 0.01 * rng.standard_normal(200)
        e[110:] = 6.0  # the load: error up
        if back_at is not None:
            e[back_at:] = 2.0  # back to the level before the change from episode back_at on
        errors[s] = e
    rec = dyn.recovery(_rows(dyn, dyn.LOAD, errors), change=110).set_index("seed")
    # the first 5-episode window entirely back ends 4 episodes after the return
    assert rec.loc[0, "recovered_at_episode"] == 124 and rec.loc[0, "episodes_to_recover"] == 14
    assert rec.loc[1, "recovered_at_episode"] == 154
    assert rec.loc[2, "recovered_at_episode"] is None or np.isnan(rec.loc[2, "recovered_at_episode"])
    assert rec.loc[0, "right_after_error_cm"] == pytest.approx(6.0)
    summary = dyn.recovery_summary(rec.reset_index()).iloc[0]
    assert (summary.seeds, summary.recovered, summary.recovered_at_range) == (3, 2, "124-154")
    assert summary.recovered_at_mean == pytest.approx(139.0)


def test_each_member_is_probed_at_its_own_checkpoint_not_past_the_moment(dyn):
    # checkpoints when the slowest member reaches 100, 110, 120; member 1 runs ahead of the others
    saved = {Path("a.pt"): [100, 107, 101], Path("b.pt"): [110, 118, 112], Path("c.pt"): [120, 131, 121]}
    chosen = dyn.member_checkpoints(saved, 110)
    assert chosen == {0: Path("b.pt"), 1: Path("a.pt"), 2: Path("a.pt")}
    assert dyn.member_checkpoints(saved, 99) == {}
    assert dyn.member_checkpoints(saved, 120) == {0: Path("c.pt"), 1: Path("b.pt"), 2: Path("b.pt")}
    # a cell still training: no member has reached 130 yet, so nothing stands in for the agent after 130
    assert dyn.member_checkpoints({Path("a.pt"): [100, 107, 101], Path("b.pt"): [110, 118, 112]}, 130) == {}
    assert dyn.member_checkpoints({Path("a.pt"): [100, 107, 101], Path("b.pt"): [110, 118, 112]}, 115) == {
        1: Path("a.pt")}  # only member 1 has trained past 115


def test_the_load_is_probed_at_the_change_thirty_episodes_later_and_at_the_end(dyn):
    load = {"load_change_episode": 110}
    assert dyn.probe_moments(dyn.LOAD, load, 200) == [110, 140, 200]
    assert dyn.probe_moments(dyn.LOAD, load, 120) == [110, 120]  # not trained that far: no recovery probe yet
    curl = {"field_on_episode": 110, "field_off_episode": 130}
    assert dyn.probe_moments(dyn.CURL, curl, 200) == [110, 130, 200]
    rows = [{"agent": "spac", "condition": dyn.LOAD, "seed": 0, "after_episode": e, "plant": p,
             "success": s, "relative_error": 0.0, "final_distance_cm": 0.0, "steps": 5.0}
            for e, p, s in ((110, "off", 0.9), (110, "on", 0.6), (140, "on", 0.85), (140, "off", 0.9),
                            (200, "on", 0.9), (200, "off", 0.9))]
    effects = dyn.probe_effects(pd.DataFrame(rows), {dyn.LOAD: [110, 140, 200]}).set_index("effect")
    recovery = effects.loc["recovery: loaded 30 episodes later - unloaded at the change"]
    assert recovery["between"] == "140on-110off" and recovery["success"] == pytest.approx(-0.05)
    assert effects.loc["cost at the change (on - off)"].success == pytest.approx(-0.3)


def test_the_lateral_deviation_is_signed_left_positive(dyn):
    # moving along +x towards (10, 0): a first step to (1, 0.5) is 0.5 cm left of the line, to (1, -0.5) right
    assert dyn.lateral_deviation([0, 1], [0, 0.5], 10, 0) == pytest.approx(0.5)
    assert dyn.lateral_deviation([0, 1, 5], [0, -0.5, 0], 10, 0) == pytest.approx(-0.5)
    # moving along +y: left is -x
    assert dyn.lateral_deviation([2, 1.7], [2, 3], 2, 12) == pytest.approx(0.3)
    assert np.isnan(dyn.lateral_deviation([0], [0], 1, 1))
