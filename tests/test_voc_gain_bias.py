"""bench/voc_gain_bias.py's statistics (issue 42 item 2): the bias's intervals over decisions, episodes and seeds,
its decomposition into the error on the chosen sequence and on the habit's (distance part and terminal value),
and the combination of runs of disjoint seeds, on rows whose answers are computed by hand."""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from conftest import bench_module

from apac_mj.agent.agent import Agent
from apac_mj.agent.planner import MPCPlanner
from apac_mj.config import AgentConfig
from apac_mj.report.stats import seed_interval

bias = bench_module("voc_gain_bias")

#: The Student-t quantile of the report's seed interval (97.5% nominal, 2 degrees of freedom), by table.
T_2DF = 6.2053


def rows(errors: dict[int, list[float]], target_of: int = 1) -> pd.DataFrame:
    """One row per decision at ``k`` = 1: seed -> the heldout estimate's errors (truth G = 10); ``target_of``
    decisions share an episode (target)."""
    out = []
    for seed, errs in errors.items():
        for j, e in enumerate(errs):
            out.append({"seed": seed, "target": j // target_of, "k": 1, "G": 10.0, "heldout": 10.0 + e})
    df = pd.DataFrame(out)
    for name in bias.ESTIMATES:
        if name not in df:
            df[name] = np.nan
    return df


def test_the_episode_interval_sums_each_episodes_deviations_before_squaring():
    """Errors 1, 3 (one episode) and 5, 7 (another): mean 4, episode sums -4 and +4, SE sqrt(32) / 4."""
    err = pd.Series([1.0, 3.0, 5.0, 7.0])
    assert bias.clustered_se(err, pd.Series([0, 0, 1, 1])) == pytest.approx(math.sqrt(32) / 4)
    # one decision an episode: the plain standard error's numerator (ddof 0): sqrt(20) / 4
    assert bias.clustered_se(err, pd.Series([0, 1, 2, 3])) == pytest.approx(math.sqrt(20) / 4)


def test_the_seed_interval_is_students_t_over_the_seeds_means_not_the_decisions():
    """Seeds with 2, 1 and 3 decisions (each its own episode) whose means are 1, 2, 3: the seed mean 2 (the
    decisions' mean 13/6), the interval 2 -+ t(2 df) * 1 / sqrt(3); with two seeds no interval."""
    df = rows({0: [0.0, 2.0], 1: [2.0], 2: [3.0, 3.0, 3.0]})
    row = bias.summary(df).set_index("estimate").loc["heldout"]
    assert row["bias"] == pytest.approx(13 / 6)
    assert row["seed_mean"] == pytest.approx(2.0)
    assert row["seeds"] == 3 and row["bias_per_seed"] == "+1.00 +2.00 +3.00"
    assert row["seed_lo"] == pytest.approx(2 - T_2DF / math.sqrt(3), abs=1e-3)
    assert row["seed_hi"] == pytest.approx(2 + T_2DF / math.sqrt(3), abs=1e-3)
    # the seeds' spread (sd 1) against their own standard errors (sqrt(2) / 2, 0, 0: root mean square sqrt(1/6))
    assert row["seed_sd"] == pytest.approx(1.0) and row["within_seed_se"] == pytest.approx(math.sqrt(1 / 6))
    two = bias.summary(rows({0: [1.0], 1: [3.0]})).iloc[0]
    assert np.isnan(two["seed_lo"]) and np.isnan(two["seed_hi"])


def test_the_decomposition_splits_each_sides_error_into_distance_and_terminal_value():
    """The held-out value of the chosen sequence 2 above its truth (0.5 of it in the distance part), the habit's 1
    below (all of it in the distance part): the gain's bias 3 = 1.5 (distance) + 1.5 (terminal value), and it is
    the summary's bias."""
    df = rows({0: [3.0, 3.0], 1: [3.0], 2: [3.0]})
    df["true_best"], df["true_habit"] = 20.0, 10.0
    df["true_best_distance"], df["true_habit_distance"] = -8.0, -12.0
    df["heldout_best"], df["heldout_habit"] = 22.0, 9.0
    df["heldout_best_distance"], df["heldout_habit_distance"] = -7.5, -13.0
    d = bias.decomposition(df).set_index(["side", "part"])["bias"]
    assert d[("best", "total")] == pytest.approx(2.0) and d[("habit", "total")] == pytest.approx(-1.0)
    assert d[("best", "distance")] == pytest.approx(0.5) and d[("best", "terminal")] == pytest.approx(1.5)
    assert d[("habit", "distance")] == pytest.approx(-1.0) and d[("habit", "terminal")] == pytest.approx(0.0)
    assert d[("gain", "distance")] == pytest.approx(1.5) and d[("gain", "terminal")] == pytest.approx(1.5)
    assert d[("gain", "total")] == pytest.approx(bias.summary(df).set_index("estimate").loc["heldout", "bias"])


def test_runs_of_disjoint_seeds_combine_and_a_shared_seed_is_refused(tmp_path):
    rows({0: [1.0], 1: [2.0]}).to_csv(tmp_path / "a.csv", index=False)
    rows({2: [3.0, 5.0]}).to_csv(tmp_path / "b.csv", index=False)
    rows({1: [0.0]}).to_csv(tmp_path / "c.csv", index=False)
    both = bias.combine([tmp_path / "a.csv", tmp_path / "b.csv"])
    assert sorted(both["seed"].unique()) == [0, 1, 2] and len(both) == 4
    with pytest.raises(ValueError, match="share a seed"):
        bias.combine([tmp_path / "a.csv", tmp_path / "c.csv"])


def test_a_rollout_without_the_terminal_value_is_the_value_less_the_discounted_critic():
    """A critic worth 5 everywhere and a target 100 cm away (no arrival in 3 steps): the planner's value less the
    view's is 0.99^3 * 5."""
    cfg = AgentConfig(kind="apac_voc", actor_hidden=(16, 16), critic_hidden=(16, 16), forward_hidden=(16, 16),
                      inverse_hidden=(16, 16), params={"mpc": {"horizon": 3, "candidates": 4, "elites": 2}})
    agent = Agent(cfg, [0, 1], dynamics=cfg.params["mpc"])
    agent.value = lambda s: torch.full(s.shape[:-1], 5.0)  # type: ignore[method-assign]
    state = torch.zeros(2, 6)
    state[:, 4] = 100.0  # target (100, 0) cm, hand and elbow at the origin
    u = torch.rand(2, 3, 3, 2, generator=torch.Generator().manual_seed(0)) * 2 - 1
    planner = MPCPlanner(cfg.params["mpc"], [0, 1], 2)
    full, _, _ = planner.rollout(agent, state, u)
    part, _, _ = planner.rollout(bias.NoTerminalView(agent), state, u)
    torch.testing.assert_close(full - part, torch.full((2, 3), 0.99 ** 3 * 5.0))
    assert bool((part < -250).all())  # the distance part: about -100 cm a step


PAGE = Path(__file__).resolve().parents[1] / "docs" / "results" / "planning" / "voc_gain.md"
NUM = r"([−+-]?\d+\.\d+)"


@pytest.mark.parametrize("label, estimate", [("imagined (the releases')", "imagined"),
                                             ("**heldout (new default)**", "heldout")])
def test_the_pages_headline_intervals_follow_from_the_shipped_per_seed_biases(label, estimate):
    """docs/results/planning/voc_gain.md's Run C row (k = 4): the bias, both half-widths, the seed interval and
    the per-seed biases it prints are the shipped summary's, and the seed interval is the report's t interval of
    those per-seed biases."""
    row = pd.read_csv(PAGE.parent / "voc_gain" / "held_out_head_10seeds_summary.csv")
    row = row[(row.estimate == estimate) & (row.k == 4)].iloc[0]
    pattern = (re.escape(f"| {label} | ") + r"\**" + NUM + r"\** \| " + NUM + r" \| " + NUM + r" \| \[" + NUM + ", "
               + NUM + r"\] \| ([^|]+) \|")
    m = re.search(pattern, PAGE.read_text())
    assert m, f"{PAGE.name}: no Run C row for {label}"
    bias_, dec, epi, lo, hi = (float(g.replace("−", "-")) for g in m.groups()[:5])
    per_seed = [float(v.replace("−", "-")) for v in m[6].split()]
    assert (bias_, dec, epi) == pytest.approx((row.bias, row.bias_half_width, row.bias_half_width_episodes),
                                              abs=0.006)
    assert per_seed == pytest.approx([float(v) for v in row.bias_per_seed.split()], abs=1e-9)
    assert (lo, hi) == pytest.approx(seed_interval(per_seed), abs=0.02)
    assert (lo, hi) == pytest.approx((row.seed_lo, row.seed_hi), abs=0.006)
