"""Learning checks: these fail if learning breaks (networks, update, replay, arbitration or the loop).

Fast (CI): SPAC on static_target, 4 seeds trained side by side for 20 episodes
with small networks. Asserts, for every seed: at least 8 of the last 10
episodes reach the target (measured: 10/10 for all seeds), the last 5 episodes
need at most 12 steps on average (measured ~4-5) and the mean final distance of
the last 5 episodes is below a third of the first 2 episodes' (learning
happened, it was not luck of the start pose).

Fast (CI): APAC on changing_target, 3 seeds x 80 episodes, planning phase
shortened to 20 episodes. Asserts: no habit before episode 20; afterwards the
arbitrator mixes both controllers (habit share of episodes 20-79 in [0.2, 0.95];
measured 0.41) and the last 10 episodes reach >= 75% of their targets pooled
over seeds (measured 97%), >= 50% for every seed (measured 90-100%). The
planning checks use a constant 2-degree OU sigma (PLANNING below).

Also (about 8 s): APAC with the paper's 100-episode planning phase on static_target,
3 seeds x 150 episodes, 64-unit networks: episodes 100-149 reach >= 85%
(measured ~97%) with a habit share >= 0.3 (measured ~0.5).

Slow (-m slow; about 2 minutes each on 2 cores): DDPG alone on static_target with the
paper's actor and critic sizes, every seed >= 90% of its last 50 episodes; the same with
the separable critic fails; DDPG on changing targets learns. Also slow (about 21 s): habit
formation (an extension) makes APAC mostly habitual. CI keeps the critic's
state-action interaction as a property (tests/test_update.py).
"""
from __future__ import annotations

import pandas as pd
import pytest

from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.run.trainer import train

from conftest import nets


#: The planning checks run with a constant 2-degree OU sigma: the default anneals from 18 degrees over 150
#: episodes (for DDPG's exploration), and noise that large keeps any controller out of the 0.5 cm zone
#: during these short runs whatever it has learned.
PLANNING = dict(ou_sigma_initial=None)
#: Not conftest's TINY: these checks must learn within a few dozen episodes, so 32-unit networks, minibatches
#: of 32 and three babbling episodes (the default replay memory), with the planning checks' noise.
SMALL = dict(nets(32, 32), batch_size=32, babbling_episodes=3, **PLANNING)


def run(tmp_path, agent: str, task: str, episodes: int, seeds=(0, 1, 2, 3), **kw) -> pd.DataFrame:
    cfg = TrainConfig(task=task, seeds=tuple(seeds), episodes=episodes, checkpoint_every=episodes,
                      actuation="kinematic", agent=AgentConfig(kind=agent, **{**SMALL, **kw}))
    df = pd.read_parquet(train(cfg, tmp_path / f"{agent}_{task}", progress=False) / "metrics.parquet")
    return df[df.phase == "train"]


def test_spac_learns_static_target_fast(tmp_path):
    df = run(tmp_path, "spac", "static_target", episodes=20)
    for seed, d in df.groupby("seed"):
        last10, last5, first2 = d[d.episode >= 10], d[d.episode >= 15], d[d.episode < 2]
        assert last10.success.sum() >= 8, f"seed {seed}: {last10.success.tolist()}"
        assert last5.steps.mean() <= 12, f"seed {seed}: steps {last5.steps.tolist()}"
        assert last5.final_distance.mean() < first2.final_distance.mean() / 3 or first2.success.all(), \
            f"seed {seed}: no improvement {first2.final_distance.tolist()} -> {last5.final_distance.tolist()}"


def test_apac_arbitrates_and_keeps_reaching(tmp_path):
    df = run(tmp_path, "apac", "changing_target", episodes=80, seeds=(0, 1, 2), planning_episodes=20)
    assert (df[df.episode < 20].habit_actions == 0).all()
    after = df[df.episode >= 20]
    share = after.habit_actions.sum() / (after.habit_actions + after.planning_actions).sum()
    assert 0.2 <= share <= 0.95, share
    last = df[df.episode >= 70]  # measured: 0.97 pooled, 0.9-1.0 per seed; habit share 0.41
    assert last.success.mean() >= 0.75, last.groupby("seed").success.mean().tolist()
    assert (last.groupby("seed").success.mean() >= 0.5).all(), last.groupby("seed").success.mean().tolist()


def test_apac_after_paper_planning_phase(tmp_path):
    nets = dict(actor_hidden=(64, 64), critic_hidden=(64, 64), forward_hidden=(64, 64), inverse_hidden=(64, 64),
                batch_size=64, babbling_episodes=10, **PLANNING)
    df = run(tmp_path, "apac", "static_target", episodes=150, seeds=(0, 1, 2), **nets)
    after = df[df.episode >= 100]
    assert after.success.mean() >= 0.85, after.groupby("seed").success.mean().tolist()
    share = after.habit_actions.sum() / (after.habit_actions + after.planning_actions).sum()
    assert share >= 0.3, share


@pytest.mark.slow  # 21 s of CI's 387 s: an extension's learning check; the paper's three stay in CI
def test_habit_formation_makes_apac_mostly_habitual(tmp_path):
    """habit_distillation_weight (an extension): APAC's actor imitates the planner and takes over.
    3 seeds x 100 episodes on changing targets (50 planning), weight 100 against weight 0: the habit share
    after the planning phase rises well above the default's, and most targets are still reached."""
    nets = dict(actor_hidden=(64, 64), critic_hidden=(64, 64), forward_hidden=(64, 64), inverse_hidden=(64, 64),
                batch_size=64, babbling_episodes=10, planning_episodes=50, **PLANNING)
    shares, success = {}, {}
    for w in (0.0, 100.0):
        df = run(tmp_path / f"w{w:g}", "apac", "changing_target", episodes=100, seeds=(0, 1, 2),
                 habit_distillation_weight=w, **nets)
        after = df[df.episode >= 50]
        shares[w] = after.habit_actions.sum() / (after.habit_actions + after.planning_actions).sum()
        success[w] = after.success.mean()
    # measured: habit share 0.55 -> 0.82, success 0.85 -> 0.73 (the habit is less precise than the planner
    # with these 64-unit networks; weight 10 moved the share only 0.55 -> 0.60 once the critic was fixed)
    assert shares[100.0] >= 0.7 and shares[100.0] >= shares[0.0] + 0.15, shares
    assert success[100.0] >= 0.6, success


PAPER_NETS = dict(actor_hidden=(400, 300), critic_hidden=(400, 600), forward_hidden=(64, 64),
                  inverse_hidden=(64, 64), batch_size=64, babbling_episodes=10, ou_sigma_initial=18.0)


def late_success(df, last: int = 50) -> pd.Series:
    """Success rate of each seed's last ``last`` training episodes."""
    return df.groupby("seed").apply(lambda d: d[d.episode >= d.episode.max() + 1 - last].success.mean())


@pytest.mark.slow  # 107 s of CI's 685 s; the critic's state-action interaction stays in CI (test_update.py)
def test_ddpg_learns_static_target(tmp_path):
    """DDPG alone (the habit system) on static_target: 3 seeds x 300 episodes, the paper's 400-300 actor and
    400-600 critic, minibatch 64. Every seed reaches >= 90% of its last 50 episodes (measured 1.00, 1.00, 1.00).
    Fails with the separable critic (test below) and with the paper-literal tanh x 180 squash and
    constant 2-degree noise (docs/paper-mapping.md)."""
    df = run(tmp_path, "ddpg", "static_target", episodes=300, seeds=(0, 1, 2), **PAPER_NETS)
    late = late_success(df)
    assert (late >= 0.9).all(), late.tolist()


@pytest.mark.slow
def test_ddpg_with_a_separable_critic_does_not_learn(tmp_path):
    """The negative control of the check above: the old critic Q = V(s) + A(a) (dQ/da the same in
    every state), everything else equal, reaches few of its static targets (measured: see docs)."""
    df = run(tmp_path, "ddpg", "static_target", episodes=300, seeds=(0, 1, 2), critic_form="separable",
             **PAPER_NETS)
    assert late_success(df).mean() <= 0.5, late_success(df).tolist()


@pytest.mark.slow
def test_ddpg_learns_changing_targets(tmp_path):
    """DDPG on changing_target (the paper: ~80%, lower than on a static target): 3 seeds x 300 episodes,
    the paper's 400-300 / 400-600 networks, minibatch 64; the last 50 episodes reach >= 50% pooled
    (measured: see docs/paper-mapping.md), far above its first 50."""
    df = run(tmp_path, "ddpg", "changing_target", episodes=300, seeds=(0, 1, 2), **PAPER_NETS)
    first = df[df.episode < 50].success.mean()
    assert late_success(df).mean() >= 0.5 and late_success(df).mean() >= first + 0.3, (first, late_success(df).tolist())
