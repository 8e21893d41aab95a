"""The model-predictive planner (apac_mj.agent.planner) and the graded arbitrator: what planning needs to be right.

A point hand with a known model (the next hand is the hand plus the action) is planned through exactly, so the
optimizer is checked apart from any learned network; anytime budgets, per-member random streams, the warm start
and the settings' checks are checked on the real agent.
"""
from __future__ import annotations

import dataclasses
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from conftest import ExactPointHand, fill_and_update

from apac_mj.agent.agent import Agent
from apac_mj.agent.arbitrators import VOC_EDGES, ValueOfComputationArbitrator
from apac_mj.agent.planner import MPCPlanner
from apac_mj.config import AgentConfig
from apac_mj.layout import Sizes, StateLayout
from apac_mj.rules import MPCParams
from apac_mj.types import END, TARGET, ArbitrationContext, HabitProbe, StepInfo

ROOT = Path(__file__).resolve().parents[1]
TINY = dict(actor_hidden=(16, 16), critic_hidden=(16, 16), forward_hidden=(16, 16), inverse_hidden=(16, 16))


class PointHand(ExactPointHand):
    """An agent whose model is exact: the hand moves by the action (cm, at most ``scale`` per axis), the habit
    does nothing, the critic values every state 0."""

    def __init__(self, scale: float = 2.0, gamma: float = 0.99) -> None:
        self.cfg = dataclasses.replace(AgentConfig(), gamma=gamma)
        self.scale = scale
        self.sizes = Sizes(state_dim=8, extra_scale=(1.0, 1.0))  # two extra entries (joint velocities), no cue
        self.layout = StateLayout(self.sizes)

    def habit_u(self, s: torch.Tensor) -> torch.Tensor:
        return torch.zeros(*s.shape[:-1], 2)

    def value(self, s: torch.Tensor) -> torch.Tensor:
        return torch.zeros(s.shape[:-1])


def mpc_agent(cfg: AgentConfig, seeds, **kw) -> Agent:
    """An agent with the dynamics model its planner plans through (the builder's ``dynamics=``)."""
    return Agent(cfg, seeds, dynamics=cfg.params["mpc"], **kw)


def _ctx(state: torch.Tensor, zone_radius: float = 0.5) -> ArbitrationContext:
    E = len(state)
    return ArbitrationContext(episode=torch.zeros(E, dtype=torch.long), step=torch.zeros(E, dtype=torch.long),
                              last_delta=torch.zeros(E), state=state, zone_radius=zone_radius)


def _params(**kw) -> MPCParams:
    return MPCParams(**{**dict(horizon=3, candidates=64, elites=8, iterations=4), **kw})


def test_the_planner_reaches_a_target_through_the_true_model():
    """From (0, 0) to (3, 0) at most 2 cm per axis and step: the best plan arrives in two steps (the habit, doing
    nothing, never does) and its first action points at the target."""
    state = torch.tensor([[0.0, 0.0, 0.0, 0.0, 3.0, 0.0], [0.0, 0.0, 0.0, 0.0, 0.0, -3.0]])
    planner = MPCPlanner(_params(), seeds=[0, 1])
    plan = planner.propose(PointHand(), _ctx(state), torch.full((2,), 4))
    hands = planner.last_plan["hand"]
    arrived = torch.linalg.vector_norm(hands[:, 2] - state[:, None, TARGET].squeeze(1), dim=-1)
    assert (arrived <= 0.5).all(), hands
    direction = plan.action / torch.linalg.vector_norm(plan.action, dim=1, keepdim=True)
    assert direction[0, 0] > 0.9 and direction[1, 1] < -0.9
    habit = -3.0 * sum(0.99 ** t for t in range(3))  # the habit stays 3 cm away for 3 steps, value 0 after
    assert plan.habit_value.tolist() == pytest.approx([habit, habit], rel=1e-6)
    assert (plan.best_values[:, -1] > habit + 2).all()


def test_the_best_value_never_falls_with_more_iterations_and_a_cut_budget_is_the_same_plan_cut():
    """Anytime: the best after each iteration is non-decreasing, and a member granted k iterations gets exactly
    the plan the full budget had after k (its stream is drawn only on the iterations it runs)."""
    state = torch.tensor([[0.0, 0.0, 0.0, 0.0, 5.0, 1.0], [1.0, 1.0, 0.0, 0.0, -4.0, 2.0]])
    full = MPCPlanner(_params(), seeds=[3, 4]).propose(PointHand(), _ctx(state), torch.tensor([4, 4]))
    assert (full.best_values.diff(dim=1) >= 0).all()
    cut = MPCPlanner(_params(), seeds=[3, 4]).propose(PointHand(), _ctx(state), torch.tensor([2, 4]))
    torch.testing.assert_close(cut.best_values[0, :2], full.best_values[0, :2], rtol=0, atol=0)
    assert torch.isnan(cut.best_values[0, 2:]).all()
    torch.testing.assert_close(cut.best_values[1], full.best_values[1], rtol=0, atol=0)
    assert cut.iterations.tolist() == [2, 4]


def test_a_member_plans_alike_alone_and_in_an_ensemble():
    state = torch.tensor([[0.0, 0.0, 0.0, 0.0, 5.0, 1.0], [1.0, 1.0, 0.0, 0.0, -4.0, 2.0]])
    both = MPCPlanner(_params(), seeds=[3, 4]).propose(PointHand(), _ctx(state), torch.tensor([0, 3]))
    alone = MPCPlanner(_params(), seeds=[4]).propose(PointHand(), _ctx(state[1:]), torch.tensor([3]))
    torch.testing.assert_close(both.action[1:], alone.action, rtol=0, atol=0)
    assert both.iterations.tolist() == [0, 3]


def test_the_warm_start_is_the_last_mean_shifted_and_a_new_episode_starts_cold():
    planner = MPCPlanner(_params(), seeds=[0, 1])
    state = torch.tensor([[0.0, 0.0, 0.0, 0.0, 5.0, 1.0], [1.0, 1.0, 0.0, 0.0, -4.0, 2.0]])
    planner.propose(PointHand(), _ctx(state), torch.tensor([4, 4]))
    assert (planner.mean[:, :-1].abs() > 0).any() and (planner.mean[:, -1] == 0).all()
    planner.reset(np.array([True, False]))
    assert (planner.mean[0] == 0).all() and (planner.mean[1, :-1].abs() > 0).any()
    saved = planner.state_dict()
    again = MPCPlanner(_params(), seeds=[0, 1])
    again.load_state_dict(saved)
    a = planner.propose(PointHand(), _ctx(state), torch.tensor([2, 2]))
    b = again.propose(PointHand(), _ctx(state), torch.tensor([2, 2]))
    torch.testing.assert_close(a.action, b.action, rtol=0, atol=0)


def test_the_planner_stops_only_where_the_stop_criterion_holds():
    """With a stop speed, an imagined arrival counts only when the state's extra entries (joint velocities) are
    slow: a fast state inside the zone keeps paying -distance, so its value is lower than a slow one's."""
    planner = MPCPlanner(_params(horizon=2), seeds=[0], stop_speed=10.0)
    agent = PointHand()
    slow = torch.tensor([[0.0, 0.0, 0.0, 0.0, 0.2, 0.0, 5.0, 5.0]])
    fast = torch.tensor([[0.0, 0.0, 0.0, 0.0, 0.2, 0.0, 50.0, 5.0]])
    v_slow, _, _ = planner.rollout(agent, slow)
    v_fast, _, _ = planner.rollout(agent, fast)
    assert v_slow.item() == pytest.approx(-0.2)          # arrived at the first step: no more reward
    assert v_fast.item() == pytest.approx(-0.2 - 0.99 * 0.2)


@pytest.mark.parametrize("field, value, message", [
    ("horizon", 0, "horizon must be an integer >= 1"),
    ("temperature", float("nan"), "temperature must be a finite number"),
    ("elites", 40, r"elites must be an integer in \[1, candidates = 32\]"),
    ("iterations", 0, "iterations must be an integer >= 1"),
    ("min_std", 2.0, r"min_std must be in \(0, max_std\]"),
    ("model_weight_decay", -1e-3, r"model_weight_decay must be in \[0, 1\]"),
    ("model_heads", 0, r"model_heads must be an integer in \[1, 32\]"),
])
def test_bad_planning_settings_are_refused(field, value, message):
    with pytest.raises(ValueError, match=f"agent.mpc.{message}"):
        AgentConfig(kind="spac_mpc", params={"mpc": {field: value}})


def test_bad_planning_settings_are_refused_before_anything_is_written(tmp_path):
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "apac_mj.cli", "train", "--agent", "spac_mpc", "--episodes", "1",
                           "--out", str(out), "--set", "agent.mpc.elites=100", "--no-progress"],
                          capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode != 0 and "agent.mpc.elites must be an integer in [1, candidates = 32]" in proc.stderr
    assert not out.exists()


def test_the_real_agents_imagined_step_is_its_forward_model():
    """``Agent.imagine`` ([E, B] batched) equals ``predict_arm`` ([E]) for the arm, keeps the target, and on a
    torque task de-normalizes the predicted velocities."""
    from apac_mj.layout import Sizes

    for sizes in (Sizes(), Sizes(state_dim=8, extra_scale=(500.0, 500.0), action_bound=2.0, angle_actions=False)):
        agent = Agent(AgentConfig(**TINY), [0, 1], sizes=sizes)
        g = torch.Generator().manual_seed(0)
        s = torch.cat([torch.rand(2, 6, generator=g) * 30, torch.randn(2, sizes.extra_dim, generator=g) * 300], 1)
        a = (torch.rand(2, 2, generator=g) * 2 - 1) * agent.cfg.action_scale
        nxt = agent.imagine(s[:, None].expand(2, 3, -1), a[:, None].expand(2, 3, -1))
        torch.testing.assert_close(nxt[:, 0, :4], agent.predict_arm(s, a))
        torch.testing.assert_close(nxt[:, :, TARGET], s[:, None, TARGET].expand(2, 3, 2))
        if sizes.extra_dim:
            x = agent.inputs.state(s)
            y = agent.forward_model(agent.inputs.model_input(x, a)[:, None])[:, 0]
            torch.testing.assert_close(nxt[:, 0, 6:] / 500.0, agent.inputs.forward_extra(y))


# -- the graded arbitrator -------------------------------------------------------------------------------
def _voc(iteration_cost: float = 10.0, decisions_per_step: float = 100.0, planning_episodes: int = 0):
    """A graded rule whose iteration costs 0.1 movement steps (10 habit decisions of 100 per step), learning on every
    planned step (``voc.learn_on = "planned"``; the re-explored learning: tests/test_voc_gain.py)."""
    cfg = AgentConfig(kind="apac_voc", planning_episodes=planning_episodes,
                      params={"voc": {"iteration_cost": iteration_cost, "decisions_per_step": decisions_per_step,
                                      "window": 1, "learn_on": "planned", "explore": 0.0}, "mpc": {"iterations": 4}})
    return ValueOfComputationArbitrator(cfg)


def _voc_ctx(final_distance: list[float], episode: int = 5, distance: float = 1.0) -> ArbitrationContext:
    """Members ``distance`` cm from their targets whose habits are imagined to end ``final_distance`` away."""
    E = len(final_distance)
    probe = HabitProbe(value=torch.full((E,), -3.0), final_distance=torch.tensor(final_distance))
    state = torch.zeros(E, 6)
    state[:, 4] = distance
    ctx = _ctx(state)
    ctx.episode = torch.full((E,), episode)
    ctx.habit_probe = lambda: probe
    return ctx


def _planned_step(rule, final_distance: list[float], gains: np.ndarray) -> StepInfo:
    E = len(final_distance)
    z = np.zeros(E, dtype=bool)
    info = StepInfo(episode=np.full(E, 5), step=np.zeros(E, dtype=int), active=~z, state=np.zeros((E, 6)),
                    true_arm=np.zeros((E, 4)), target=np.zeros((E, 2)), action=np.zeros((E, 2)), habit=z,
                    delta=np.zeros(E), predicted_arm=np.zeros((E, 4)), reward=np.zeros(E), distance=np.zeros(E),
                    done=z, reached=z, vision=~z, joint_angles=np.zeros((E, 2)), link_lengths=np.ones((E, 2)),
                    next_state=np.zeros((E, 6)), terminal=z, zone_radius=0.5,
                    arbitration={"habit_final_distance": np.array(final_distance)},
                    decision_seconds=np.full(E, 0.01), plan_iterations=np.full(E, 4), plan_gains=gains)
    rule.observe(info, ~z, adapt=True)
    return info


def test_the_graded_rule_plans_fully_without_evidence_and_in_the_planning_phase():
    rule = _voc(planning_episodes=10)
    d = rule.use_habit(_voc_ctx([0.2, 0.7], episode=3))
    assert d.habit.tolist() == [False, False] and d.iterations.tolist() == [4, 4]
    d = _voc().use_habit(_voc_ctx([0.2, 0.7]))
    assert d.habit.tolist() == [False, False] and d.iterations.tolist() == [4, 4]


def test_the_graded_rule_buys_the_iterations_worth_their_cost():
    """An iteration takes 0.1 movement steps, and a step 1 cm from the target costs 1 cm of return: 0.1 cm per
    iteration. Member 0's bin (inside the zone) measured gains of at most 0.05, never worth it: the habit.
    Member 1's bin (a habit trap just outside the zone) measured 1.0, 1.5, 1.55, 1.6: net 0.9, 1.3, 1.25,
    1.2, so 2 iterations. Each member has its own table. Ten times further from the target, time costs ten
    times more (1 cm per iteration): the same gains buy nothing."""
    rule = _voc()
    gains = np.array([[0.01, 0.02, 0.05, 0.05], [1.0, 1.5, 1.55, 1.6]], dtype=np.float32)
    _planned_step(rule, [0.2, 0.7], gains)
    d = rule.use_habit(_voc_ctx([0.2, 0.7]))
    assert d.habit.tolist() == [True, False]
    assert d.iterations.tolist() == [0, 2]
    assert d.inputs["expected_gain"][1].item() == pytest.approx(1.5)
    assert d.inputs["planning_cost"][1].item() == pytest.approx(0.2)
    # another bin (far away: 20 radii) has no evidence yet: full planning; member 1's trap bin as before
    d = rule.use_habit(_voc_ctx([10.0, 0.7]))
    assert d.iterations.tolist() == [4, 2]
    d = rule.use_habit(_voc_ctx([0.2, 0.7], distance=10.0))
    assert d.habit.tolist() == [True, True] and d.iterations.tolist() == [0, 0]
    assert rule.bins(torch.tensor([0.2, 0.7, 10.0]), 0.5).tolist() == [0, 1, len(VOC_EDGES)]


def test_the_graded_rules_table_travels_in_a_checkpoint():
    rule = _voc()
    _planned_step(rule, [0.2, 0.7], np.array([[0.01] * 4, [1.0] * 4], dtype=np.float32))
    again = _voc()
    again.load_state_dict(rule.state_dict())
    a, b = rule.use_habit(_voc_ctx([0.2, 0.7])), again.use_habit(_voc_ctx([0.2, 0.7]))
    assert a.habit.tolist() == b.habit.tolist() and a.iterations.tolist() == b.iterations.tolist()
    assert math.isfinite(again.stats["habit_seconds"][0].item()) is False  # no habit step measured yet
    assert again.stats["iteration_seconds"][0].item() == pytest.approx(0.01 / 4)


# -- in training ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("agent", ["spac_mpc", "apac_voc"])
def test_a_planning_run_killed_and_resumed_equals_the_uninterrupted_one(tmp_path, agent):
    """The planner's warm start and random streams and the graded rule's gain table travel in the checkpoint:
    a run killed mid-episode and resumed gives the uninterrupted run's numbers (the measured seconds aside)."""
    from conftest import deterministic
    from test_trainer import final_weights, tiny_config, train_killed_and_resumed

    from apac_mj.run import checkpoint
    from apac_mj.run.trainer import train

    from conftest import TINY_MPC

    cfg = tiny_config((0, 1), episodes=4, agent=agent, planning_episodes=2, params=TINY_MPC)
    full = train(cfg, tmp_path / "full", progress=False)
    resumed = train_killed_and_resumed(cfg, tmp_path / "cut", 3)
    a, b = (pd.read_parquet(r / "metrics.parquet") for r in (full, resumed))
    pd.testing.assert_frame_equal(deterministic(a), deterministic(b), check_exact=True)
    assert (a[(a.phase == "train") & (a.episode < 2)].plan_iterations > 0).all(), "the planning phase plans"
    wa, wb = final_weights(full), final_weights(resumed)
    assert all(torch.equal(wa[k], wb[k]) for k in wa)
    ca, cb = (checkpoint.load(r / "checkpoints" / "latest.pt") for r in (full, resumed))
    torch.testing.assert_close(ca["planner"]["mean"], cb["planner"]["mean"], rtol=0, atol=0)
    if agent == "apac_voc":
        torch.testing.assert_close(ca["arbitrator"]["gain"], cb["arbitrator"]["gain"], rtol=0, atol=0, equal_nan=True)
        assert torch.isfinite(ca["arbitrator"]["gain"]).any(), "the rule measured gains"


def test_the_dynamics_model_is_planned_through_and_leaves_the_other_networks_as_in_every_kind():
    """A planning kind's agent has a residual dynamics model (built last: its other networks start as the
    paper's kinds' do); ``imagine`` steps it: the next normalized motion is the motion plus its output; one
    update lowers its loss on a batch of a linear system it can fit."""
    from apac_mj.layout import Sizes

    sizes = Sizes(state_dim=8, extra_scale=(500.0, 500.0), action_bound=2.0, angle_actions=False)
    mpc = mpc_agent(AgentConfig(kind="spac_mpc", **TINY), [0, 1], sizes=sizes)
    paper = Agent(AgentConfig(kind="spac", **TINY), [0, 1], sizes=sizes)
    assert paper.dynamics_model is None and mpc.dynamics_model is not None
    for name in ("actor", "critic", "forward_model", "inverse_model"):
        for p, q in zip(getattr(mpc, name).parameters(), getattr(paper, name).parameters()):
            assert torch.equal(p, q), name
    g = torch.Generator().manual_seed(1)
    s = torch.cat([torch.rand(2, 6, generator=g) * 30, torch.randn(2, 2, generator=g) * 300], 1)
    a = torch.rand(2, 2, generator=g) * 4 - 2
    nxt = mpc.imagine(s[:, None], a[:, None])[:, 0]
    x = mpc.inputs.state(s)
    change = mpc.dynamics_model(torch.cat([x[:, None, :4], x[:, None, 6:], a[:, None] / 2.0], -1))[:, 0]
    torch.testing.assert_close(mpc.inputs.state(nxt)[:, :4], x[:, :4] + change[:, :4])
    torch.testing.assert_close(mpc.inputs.state(nxt)[:, 6:], x[:, 6:] + change[:, 4:])
    torch.testing.assert_close(nxt[:, 4:6], s[:, 4:6])
    batch = {"state": s[:, None].expand(2, 16, 8).clone(), "action": a[:, None].expand(2, 16, 2).clone(),
             "next_state": (s + 1.0)[:, None].expand(2, 16, 8).clone(), "reward": torch.zeros(2, 16),
             "done": torch.zeros(2, 16), "executed_action": a[:, None].expand(2, 16, 2).clone()}
    before = mpc.gradients(batch, [0, 1])["dynamics"]
    mpc.optimizer.step()
    after = mpc.losses(batch)["dynamics"].detach()
    assert (after < before).all()


def test_the_extra_model_steps_move_only_the_dynamics_model():
    """``mpc.model_updates`` extra steps train the dynamics model alone: after an update with 2 of them the
    other networks are where an update without them leaves them, the dynamics model is not."""
    from apac_mj.layout import Sizes

    sizes = Sizes(state_dim=8, extra_scale=(500.0, 500.0), action_bound=2.0, angle_actions=False)

    def updated(extra: int) -> Agent:
        return fill_and_update(mpc_agent(AgentConfig(kind="spac_mpc", **TINY, batch_size=4,
                                                     params={"mpc": {"model_updates": extra}}), [0, 1], sizes=sizes))

    plain, more = updated(0), updated(2)
    for name in ("actor", "critic", "forward_model", "inverse_model"):
        for p, q in zip(getattr(plain, name).parameters(), getattr(more, name).parameters()):
            assert torch.equal(p, q), name
    moved = [not torch.equal(p[0], q[0]) for p, q in zip(plain.dynamics_model.parameters(),
                                                        more.dynamics_model.parameters())]
    assert all(moved)
    untouched = [torch.equal(p[1], q[1]) for p, q in zip(plain.dynamics_model.parameters(),
                                                        more.dynamics_model.parameters())]
    assert all(untouched), "the inactive member is left alone"


def test_the_dynamics_model_has_its_own_weight_decay_and_old_runs_keep_theirs():
    """The paper's L2 (1e-3, Adam's) on every network it has; the dynamics model's ``mpc.model_weight_decay``
    (0: under 1e-3 its one-step error stalled at 1.04 cm / 47 deg/s on the stop task). A config written before
    the field (its ``mpc`` table without it) migrates to the decay its run had: the agent's ``weight_decay``."""
    from apac_mj.config import migrate, to_dict, train_config_from_dict, TrainConfig
    from apac_mj.layout import Sizes

    sizes = Sizes(state_dim=8, extra_scale=(500.0, 500.0), action_bound=2.0, angle_actions=False)
    agent = mpc_agent(AgentConfig(kind="spac_mpc", **TINY), [0, 1], sizes=sizes)
    decay = {name: g["weight_decay"] for name, g in zip(agent.trained, agent.optimizer.param_groups)}
    assert decay == {"actor": 1e-3, "critic": 1e-3, "forward_model": 1e-3, "inverse_model": 1e-3,
                     "dynamics_model": 0.0}
    old = to_dict(TrainConfig(agent=AgentConfig(kind="spac_mpc", weight_decay=2e-3)))
    del old["agent"]["mpc"]["model_weight_decay"], old["agent"]["mpc"]["model_heads"]
    migrated = train_config_from_dict(migrate(old))
    assert migrated.agent.params["mpc"].model_weight_decay == 2e-3
    assert migrated.agent.params["mpc"].model_heads == 1
    assert train_config_from_dict(migrate(to_dict(TrainConfig()))).agent.params["mpc"].model_weight_decay == 0.0


def test_dynamics_heads_are_planned_through_by_their_mean_and_each_learns():
    """``mpc.model_heads`` = 3: three models per member from their own initializations (the other networks as
    with one); ``imagine`` steps their mean; the loss is the mean of each head's own error; an update lowers
    every head's error on a batch it can fit."""
    from apac_mj.agent.networks import DynamicsHeads
    from apac_mj.layout import Sizes

    sizes = Sizes(state_dim=8, extra_scale=(500.0, 500.0), action_bound=2.0, angle_actions=False)
    one = mpc_agent(AgentConfig(kind="spac_mpc", **TINY), [0, 1], sizes=sizes)
    three = mpc_agent(AgentConfig(kind="spac_mpc", **TINY, params={"mpc": {"model_heads": 3}}), [0, 1], sizes=sizes)
    model = three.dynamics_model
    assert isinstance(model, DynamicsHeads) and len(model.heads) == 3
    for p, q in zip(one.dynamics_model.parameters(), model.heads[0].parameters()):
        assert torch.equal(p, q), "the first head is the single model"
    assert not torch.equal(model.heads[0].layers[0].weight, model.heads[1].layers[0].weight)
    for name in ("actor", "critic", "forward_model", "inverse_model"):
        for p, q in zip(getattr(one, name).parameters(), getattr(three, name).parameters()):
            assert torch.equal(p, q), name
    g = torch.Generator().manual_seed(1)
    s = torch.cat([torch.rand(2, 16, 6, generator=g) * 30, torch.randn(2, 16, 2, generator=g) * 300], -1)
    a = torch.rand(2, 16, 2, generator=g) * 4 - 2
    x = three.inputs.state(s)
    inputs = torch.cat([x[..., :4], x[..., 6:], a / 2.0], -1)
    each = model.each(inputs)
    nxt = three.imagine(s, a)
    torch.testing.assert_close(three.inputs.state(nxt)[..., :4], x[..., :4] + each.mean(0)[..., :4])
    s2 = s + 1.0
    target = three.inputs.motion_x(three.inputs.state(s2)) - three.inputs.motion_x(x)
    per_head = (each - target).pow(2).mean((2, 3))
    torch.testing.assert_close(three._dynamics_loss(x, a, s2), per_head.mean(0))
    batch = {"state": s, "action": a, "next_state": s2, "reward": torch.zeros(2, 16), "done": torch.zeros(2, 16),
             "executed_action": a}
    three.gradients(batch, [0, 1])
    three.optimizer.step()
    with torch.no_grad():
        after = (model.each(inputs) - target).pow(2).mean((2, 3))
    assert (after < per_head.detach()).all(), "every head of every member learned"


def test_the_planning_bench_times_every_operation_side_by_side():
    from conftest import bench_module

    bench = bench_module("planning")
    agent, planner, ctx = bench.setup("changing_target", 2)
    times = bench.timings(agent, planner, ctx, rounds=2)
    assert set(times) == {"habit (actor)", "inverse model", "habit probe", "MPC 1 iteration", "MPC 2 iterations",
                          "MPC 3 iterations", "MPC 4 iterations", "training update"}
    assert all(len(v) == 2 and min(v) > 0 for v in times.values())


def test_every_timed_plan_of_the_planning_bench_rolls_the_habit_out_from_a_fresh_state():
    """The bench's rows share no state object: each MPC row and the probe row roll the habit out themselves (a
    run's every step has a new state, so the planner's per-state cache never serves a decision's first plan)."""
    from conftest import bench_module

    bench = bench_module("planning")
    agent, planner, ctx = bench.setup("changing_target", 2)
    habit_rollouts, states = [], []
    rollout = planner.rollout

    def counted(agent_, state, u=None):
        if u is None:
            habit_rollouts.append(state)
        states.append(state)
        return rollout(agent_, state, u)

    planner.rollout = counted
    bench.timings(agent, planner, ctx, rounds=2)
    assert len(habit_rollouts) == 2 * (1 + planner.max_iterations)
    assert all(s is not ctx.state for s in states)
    assert len({id(s) for s in habit_rollouts}) == len(habit_rollouts)
