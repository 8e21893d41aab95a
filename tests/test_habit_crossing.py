"""The episode at which each seed first becomes habitual (the paper: > 80% after around 300 episodes)."""
from __future__ import annotations

import math

import pandas as pd

from apac_mj.report.quantities import habit_crossing


def rows(agent: str, seed: int, habit_from: int, habit_per_10: int, episodes: int = 200) -> list[dict]:
    """10 actions per episode: all planning before ``habit_from``, then ``habit_per_10`` habitual."""
    return [{"agent": agent, "condition": "changing_target", "region": "all", "phase": "train", "seed": seed,
             "episode": e, "habit_actions": habit_per_10 if e >= habit_from else 0,
             "planning_actions": 10 - (habit_per_10 if e >= habit_from else 0)} for e in range(episodes)]


def test_first_crossing_of_80_percent_over_a_20_episode_window():
    metrics = pd.DataFrame(rows("apac", 0, 100, 9) + rows("apac", 1, 0, 7) + rows("apac", 2, 50, 10)
                           + rows("ddpg", 0, 0, 10)
                           + [{**r, "phase": "babbling", "episode": -1} for r in rows("apac", 1, 0, 10, 1)])
    got = habit_crossing(metrics).set_index("seed")
    assert list(got["agent"]) == ["apac"] * 3  # DDPG never arbitrates; babbling does not count
    # seed 0: 90% from episode 100; a 20-episode window needs 18 such episodes (162/200 >= 80%): episode 117
    assert got.loc[0, "episode"] == 117
    assert math.isnan(got.loc[1, "episode"])  # 70% throughout: never
    assert got.loc[2, "episode"] == 65  # 100% from 50: 16 of 20 episodes
    assert (got["episodes"] == 200).all()
    # a stricter threshold is crossed later or not at all
    strict = habit_crossing(metrics, threshold=0.95).set_index("seed")
    assert math.isnan(strict.loc[0, "episode"]) and strict.loc[2, "episode"] == 68


def test_crossing_is_a_key_number_over_the_seeds_that_crossed():
    """report.md's Fig. 5 rows carry the crossing episode: the mean over the seeds that crossed, with the
    seeds that never did left out of the mean and listed as nan."""
    from apac_mj.report.quantities import _training, key_numbers

    metrics = pd.DataFrame(rows("apac", 0, 100, 9) + rows("apac", 1, 0, 7) + rows("apac", 2, 50, 10))
    metrics["success"], metrics["steps"] = True, 10
    seed_values = pd.concat(_training(metrics), ignore_index=True)
    kn = key_numbers(seed_values).set_index("quantity").loc["habit_crossing_episode"]
    assert kn["mean"] == (117 + 65) / 2 and kn["n_seeds"] == 2 and kn["samples"] == 600
    assert kn["per_seed"] == "0: 117.00; 1: nan; 2: 65.00" and kn["paper"] == "around 300"
