"""The arbitrators beyond the paper: each rule's decision against a hand computation of its equations,
their running statistics (learned in training, frozen in tests, saved in checkpoints), and the "why"
that recordings show."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
import torch

from apac_mj.run import checkpoint
from apac_mj import kinds
from apac_mj.types import HABIT_COST, PLANNING_COST, ArbitrationContext
from apac_mj.agent.arbitration import blend, ema
from apac_mj.agent.arbitrators import ReliabilityArbitrator, SpeedAccuracyArbitrator, UncertaintyArbitrator
from apac_mj.config import AgentConfig
from apac_mj.run.evaluate import evaluate
from apac_mj.run.build import load_run
from apac_mj.run.trainer import train

from conftest import deterministic
from test_trainer import tiny_config, train_killed_and_resumed

def same(a: torch.Tensor, b: torch.Tensor) -> bool:
    """Bit-equal, NaN equal to NaN."""
    return a.shape == b.shape and torch.allclose(a, b, rtol=0, atol=0, equal_nan=True)


NEW_KINDS = ("apac_uncertainty", "apac_reliability", "apac_speed_accuracy", "apac_vision")


def cfg(**tables) -> AgentConfig:
    """APAC's config without a planning phase, with the rule tables given (``uncertainty={"window": 2}``)."""
    return AgentConfig(kind="apac", planning_episodes=0, params=tables)


def ctx(E=2, episode=5, step=3, last_delta=0.0, recent=None, vision=True, state=None, habit_action=None,
        predict_end=None, zone_radius=0.5) -> ArbitrationContext:
    last = torch.full((E,), float(last_delta)) if np.isscalar(last_delta) else torch.as_tensor(last_delta).float()
    return ArbitrationContext(episode=torch.full((E,), episode), step=torch.full((E,), step), last_delta=last,
                              recent_deltas=None if recent is None else torch.as_tensor(recent, dtype=torch.float32),
                              vision=torch.full((E,), vision) if isinstance(vision, bool) else torch.as_tensor(vision),
                              state=torch.zeros(E, 6) if state is None else state, habit_action=habit_action,
                              predict_end=predict_end, zone_radius=zone_radius)


def step(delta, end_error=None, before=None, after=None, habit=None, vision=None, done=None,
         terminal=None, inputs=None) -> SimpleNamespace:
    """A StepInfo with what the running statistics read: the hand moves along x towards a target at 0."""
    delta = np.asarray(delta, dtype=np.float32)
    E = len(delta)
    before = np.full(E, 10.0) if before is None else np.asarray(before, dtype=np.float32)
    after = np.full(E, 5.0) if after is None else np.asarray(after, dtype=np.float32)
    end_error = np.zeros(E) if end_error is None else np.asarray(end_error, dtype=np.float32)
    state, nxt = np.zeros((E, 6), np.float32), np.zeros((E, 6), np.float32)
    state[:, 0], nxt[:, 0] = before, after
    predicted = np.zeros((E, 4), np.float32)
    predicted[:, 0] = after + end_error
    return SimpleNamespace(delta=delta, state=state, next_state=nxt, predicted_arm=predicted,
                           vision=np.ones(E, bool) if vision is None else np.asarray(vision),
                           habit=np.zeros(E, bool) if habit is None else np.asarray(habit),
                           done=np.zeros(E, bool) if done is None else np.asarray(done),
                           terminal=np.zeros(E, bool) if terminal is None else np.asarray(terminal),
                           episode=np.full(E, 200), zone_radius=0.5,
                           arbitration={k: v.numpy() for k, v in (inputs or {}).items()})


def test_ema_and_blend_by_hand():
    old = torch.tensor([float("nan"), 2.0, 2.0])
    new = torch.tensor([4.0, 4.0, float("nan")])
    assert torch.equal(ema(old, new, 0.25, torch.ones(3, dtype=torch.bool)), torch.tensor([4.0, 2.5, 2.0]))
    out = ema(old, new, 0.25, torch.tensor([False, True, True]))
    assert math.isnan(out[0]) and out[1:].tolist() == [2.5, 2.0]
    samples = torch.tensor([[float("nan"), 1.0, 3.0], [float("nan")] * 3, [5.0, 5.0, 5.0]])
    got = blend(torch.tensor([2.0, 2.0, float("nan")]), samples, 4.0)
    assert got.tolist() == pytest.approx([(4 * 2 + 4) / 6, 2.0, 5.0])
    assert math.isnan(blend(torch.tensor([float("nan")]), torch.full((1, 2), float("nan")), 4.0)[0])


def test_uncertainty_rule_prefers_the_less_uncertain_system():
    arb = UncertaintyArbitrator(cfg(uncertainty={"window": 2, "prior_weight": 4.0}))
    c = ctx(recent=torch.full((2, 3), float("nan")))
    assert not arb.use_habit(c).habit.any(), "no statistics yet: the planner acts"
    # member 0: the critic errs little, the forward model a lot; member 1 the reverse
    arb.observe(step([0.1, 2.0], end_error=[1.0, 0.1]), np.ones(2, bool))
    arb.observe(step([0.3, 2.0], end_error=[1.0, 0.1]), np.ones(2, bool))
    assert arb.stats["habit_var"].tolist() == pytest.approx([0.01 + 0.5 * (0.09 - 0.01), 4.0])
    assert arb.stats["planning_var"].tolist() == pytest.approx([1.0, 0.01], rel=1e-5)
    decision = arb.use_habit(c)
    assert decision.habit.tolist() == [True, False]
    assert set(decision.inputs) == {"habit_uncertainty", "planning_uncertainty"}
    # this episode's own large deltas outweigh a small prior once the prior has weight
    arb.prior_weight = 1.0
    assert arb.use_habit(ctx(recent=[[5.0, 5.0, 5.0], [float("nan")] * 3])).habit.tolist() == [False, False]
    # frozen (tests): observe without adapt leaves the statistics alone
    before = arb.state_dict()
    arb.observe(step([9.0, 9.0], end_error=[9.0, 9.0]), np.ones(2, bool), adapt=False)
    assert all(same(before[k], arb.stats[k]) for k in before)


def test_reliability_rule_moves_the_probability_of_planning_as_lee_et_al():
    arb = ReliabilityArbitrator(cfg(reliability={"window": 1, "prior_weight": 1.0, "rate": 0.5, "slope": 6.0}))
    c = ctx(E=1, recent=[[float("nan")] * 2])
    decision = arb.use_habit(c)
    assert decision.habit.tolist() == [False], "P(planning) starts at 1"
    arb.observe(step([0.2], end_error=[2.0], inputs=decision.inputs), np.ones(1, bool))  # small RPE, large SPE
    # chi's used for that step's transition were NaN (no statistics yet) -> 0: alpha = beta = A / 2
    p = 1.0 + 0.25 * (1 - 1.0) - 0.25 * 1.0
    assert arb.stats["p_planning"].item() == pytest.approx(p)
    assert arb.stats["habit_reliability"].item() == 1.0 and arb.stats["planning_reliability"].item() == 0.0
    for _ in range(3):
        arb.observe(step([0.2], end_error=[2.0], inputs=arb.use_habit(c).inputs), np.ones(1, bool))
        alpha, beta = 0.5 / (1 + math.exp(6.0 * 1.0)), 0.5 / (1 + math.exp(6.0 * 0.0))
        p = p + alpha * (1 - p) - beta * p
    assert arb.stats["p_planning"].item() == pytest.approx(p, rel=1e-6)
    decision = arb.use_habit(c)
    assert decision.habit.tolist() == [True], "a reliable habit and an unreliable model: the habit acts"
    assert set(decision.inputs) == {"habit_reliability", "planning_reliability", "p_planning"}
    # P moves by the reliabilities the step was decided on (its recorded inputs), not by later statistics
    p, moved = arb.stats["p_planning"].item(), dict(decision.inputs, habit_reliability=torch.zeros(1))
    arb.observe(step([0.2], end_error=[2.0], inputs=moved), np.ones(1, bool), adapt=False)
    alpha, beta = 0.5 / (1 + math.exp(0.0)), 0.5 / (1 + math.exp(6.0 * 0.0))
    assert arb.stats["p_planning"].item() == pytest.approx(p + alpha * (1 - p) - beta * p, rel=1e-6)


def test_speed_accuracy_learns_the_time_cost_of_each_controller_by_sarsa():
    arb = SpeedAccuracyArbitrator(cfg(speed_accuracy={"window": 1}))  # rate 1: each entry is its last target
    one = np.ones(1, bool)
    HABIT, PLAN = 0, 1  # the table's columns
    # an episode: plan at 10 cm (bin 5, cost 3), then a habit step at 3 cm (bin 3, cost 1) reaches
    arb.observe(step([0.0], before=[10.0], habit=[False]), one)
    assert arb.stats["pending_bin"].item() == 5 and arb.stats["pending_cost"].item() == PLANNING_COST
    assert arb.stats["pending_controller"].item() == PLAN
    arb.observe(step([0.0], before=[3.0], habit=[True], done=[True], terminal=[True]), one)
    table = arb.stats["table"][0]
    assert table.shape == (len(arb.DISTANCE_EDGES) + 1, 2)
    assert table[5, PLAN].item() == PLANNING_COST + HABIT_COST  # 3 + T(3, habit) (untried: its cost)
    assert table[3, HABIT].item() == HABIT_COST  # reached: nothing remains
    assert arb.stats["pending_bin"].item() == -1
    # a time limit adds a planning step's cost
    arb.observe(step([0.0], before=[1.5], habit=[True], done=[True], terminal=[False]), one)
    assert arb.stats["table"][0, 2, HABIT].item() == HABIT_COST + PLANNING_COST
    # the planning phase teaches it nothing (the planner acts by schedule there, not by the rule's choice)
    scheduled = SpeedAccuracyArbitrator(AgentConfig(kind="apac_speed_accuracy", planning_episodes=100))
    early = step([0.0], before=[1.5], habit=[False], done=[True], terminal=[True])
    early.episode = np.full(1, 99)
    scheduled.observe(early, one)
    assert torch.isnan(scheduled.stats["table"]).all() and (scheduled.stats["pending_bin"] == -1).all()
    early.episode = np.full(1, 100)
    scheduled.observe(early, one)
    assert scheduled.stats["table"][0, 2, PLAN].item() == PLANNING_COST

    def decide(distance):
        state = torch.tensor([[distance, 0, 0, 0, 0, 0]], dtype=torch.float32)
        decision = arb.use_habit(ctx(E=1, state=state))
        return decision.habit.item(), decision.inputs["planning_gain"].item()

    assert decide(10.0)[0] is True, "an untried habit (1) against planning's learned 4: the habit is tried"
    arb.stats["table"][0, 5, HABIT] = 4.5
    assert decide(10.0) == (False, pytest.approx(4.5 - 1 - (4 - 3)))
    arb.stats["table"][0, 5, HABIT] = 4.0  # a tie: the gain equals the extra cost, the habit acts
    assert decide(10.0) == (True, PLANNING_COST - HABIT_COST)


def test_speed_accuracy_loads_the_flat_statistics_of_older_checkpoints():
    """Checkpoints up to 936695d keep the table as flat time_{c}_{b} [E] entries and NaN-encoded pending_*."""
    arb = SpeedAccuracyArbitrator(cfg())
    flat = {f"time_{c}_{b}": torch.tensor([float("nan"), 10.0 * b + i])
            for i, c in enumerate(("habit", "planning")) for b in range(6)}
    arb.load_state_dict({**flat, "pending_bin": torch.tensor([float("nan"), 4.0]),
                         "pending_habit": torch.tensor([float("nan"), 1.0]), "pending_cost": torch.tensor([0.5, 3.0])})
    assert torch.isnan(arb.stats["table"][0]).all() and arb.stats["table"][1, 4].tolist() == [40.0, 41.0]
    assert arb.stats["pending_bin"].tolist() == [-1, 4] and arb.stats["pending_controller"].tolist() == [-1, 1]
    assert arb.stats["pending_bin"].dtype == torch.int64 and same(arb.stats["pending_cost"], torch.tensor([0.5, 3.0]))
    assert set(arb.state_dict()) == {"table", "pending_bin", "pending_controller", "pending_cost"}


def test_planning_phase_holds_for_every_new_rule():
    for name in NEW_KINDS:
        arb = kinds.get(name).arbitrator(AgentConfig(kind=name, planning_episodes=100))
        c = ctx(episode=99, last_delta=0.0, recent=torch.zeros(2, 3), state=torch.zeros(2, 6),
                habit_action=torch.zeros(2, 2), predict_end=lambda a: torch.zeros(2, 2))
        assert not arb.use_habit(c).habit.any(), name


def test_vision_aware_rule_suppresses_or_checks_the_habit_in_the_dark():
    vision = torch.tensor([True, False])
    arb = kinds.arbitrator_for(AgentConfig(kind="apac_vision", planning_episodes=0))
    decision = arb.use_habit(ctx(last_delta=0.0, vision=vision))
    assert decision.habit.tolist() == [True, False]
    assert decision.inputs["vision"].tolist() == [1.0, 0.0] and "abs_delta" in decision.inputs
    check = kinds.arbitrator_for(AgentConfig(kind="apac_vision", planning_episodes=0,
                                             params={"vision_aware": {"dark": "check", "check_ratio": 0.5}}))
    state = torch.tensor([[10.0, 0, 0, 0, 0, 0]] * 2)
    for predicted, expected in ((4.9, [True, True]), (5.1, [True, False])):
        c = ctx(last_delta=0.0, vision=vision, state=state, habit_action=torch.zeros(2, 2),
                predict_end=lambda a, x=predicted: torch.tensor([[x, 0.0]] * 2))
        assert check.use_habit(c).habit.tolist() == expected
    with pytest.raises(ValueError, match="itself vision-aware"):
        kinds.arbitrator_for(AgentConfig(kind="apac_vision", params={"vision_aware": {"base": "apac_vision"}}))
    with pytest.raises(ValueError, match="unknown agent kind 'nope'"):
        kinds.check(cfg(vision_aware={"base": "nope"}))
    with pytest.raises(ValueError, match=r"agent.vision_aware.dark must be 'suppress' or 'check', got 'peek'"):
        cfg(vision_aware={"dark": "peek"})


def test_state_dict_is_validated():
    arb = UncertaintyArbitrator(cfg())
    with pytest.raises(ValueError, match="unknown statistics"):
        arb.load_state_dict({"bogus": torch.zeros(2)})
    with pytest.raises(ValueError, match="one length"):
        arb.load_state_dict({"habit_var": torch.zeros(2), "planning_var": torch.zeros(3)})


@pytest.mark.parametrize("agent", ["apac_reliability", "apac_speed_accuracy"])
def test_statistics_are_checkpointed_and_frozen_in_the_tests(tmp_path, agent):
    run = train(tiny_config((0, 1), episodes=4, agent=agent), tmp_path / "run", progress=False)
    state = checkpoint.load(run / "checkpoints" / "latest.pt")["arbitrator"]
    assert state and any(torch.isfinite(v).any() for k, v in state.items() if "pending" not in k), state
    seen = []
    evaluate(run, protocols=("grid",), limit=2, on_step=lambda info, env: seen.append(info.arbitration))
    assert seen and all(set(s) for s in seen)
    loaded = load_run(run)
    cfg_, ckpt = loaded.cfg, loaded.ckpt
    arb = kinds.arbitrator_for(cfg_.agent, ckpt.running_statistics()["arbitrator"])
    assert all(same(arb.stats[k], state[k]) for k in state)
    # the test ran with the statistics frozen: the checkpoint is unchanged by it
    again = checkpoint.load(run / "checkpoints" / "latest.pt")["arbitrator"]
    assert all(same(again[k], state[k]) for k in state)


@pytest.mark.parametrize("agent,task,extra", [("apac_reliability", "changing_target", {}),
                                              ("apac_speed_accuracy", "changing_target_noisy", {"integrator": "kalman"})])
def test_resume_with_running_statistics_equals_uninterrupted(tmp_path, agent, task, extra):
    """A run killed mid-episode after a checkpoint and resumed equals the uninterrupted one, running
    statistics (arbitrator, Kalman filter) included."""
    cfg_ = tiny_config((0, 1), episodes=6, agent=agent, task=task, **extra)
    full = train(cfg_, tmp_path / "full", progress=False)
    resumed = train_killed_and_resumed(cfg_, tmp_path / "cut", 5)
    a, b = pd.read_parquet(full / "metrics.parquet"), pd.read_parquet(resumed / "metrics.parquet")
    pd.testing.assert_frame_equal(deterministic(a), deterministic(b), check_exact=True)
    ca, cb = (checkpoint.load(r / "checkpoints" / "latest.pt") for r in (full, resumed))
    for part in ("arbitrator", "integrator"):
        assert ca[part].keys() == cb[part].keys() and all(same(ca[part][k], cb[part][k]) for k in ca[part])
    assert ca["arbitrator"], "the rule keeps statistics"
    if extra:
        assert ca["integrator"] and (ca["integrator"]["count"] > 0).all(), "the filter learned from innovations"


def test_a_kind_without_statistics_refuses_a_state():
    with pytest.raises(ValueError, match="keeps no statistics"):
        kinds.arbitrator_for(AgentConfig(kind="apac"), {"habit_var": torch.zeros(2)})


def test_recordings_show_which_controller_acted_and_why(tmp_path):
    """The rule's inputs of every decision are series in the recording, one per input, and each step's
    event names the controller and the inputs; the state-estimate error is a series too."""
    from apac_mj.recording import recording as R
    from apac_mj.recording.record import record

    out = record(tmp_path / "sa.rrd", task="changing_target_noisy", agent="apac_speed_accuracy", episodes=1,
                 progress=False)
    entities, _, _ = R.read_recording(out.rrd)
    inputs = {p.rsplit("/", 1)[-1] for p in entities if p.startswith(R.ARBITRATION_INPUTS + "/")}
    assert inputs == {"distance", "time_if_habit", "time_if_planning", "planning_gain", "planning_extra_cost"}
    _, extra = R.scalar_series(entities[f"{R.ARBITRATION_INPUTS}/planning_extra_cost"])
    _, habit_time = R.scalar_series(entities[f"{R.ARBITRATION_INPUTS}/time_if_habit"])
    _, controller = R.scalar_series(entities[R.CONTROLLER])
    assert np.all(extra == 2.0) and len(extra) == len(controller)
    assert np.all(habit_time == 1.0) and np.all(controller == R.HABIT), "untrained: every entry untried, optimistic"
    texts = [t[0] for t in entities[R.EVENTS].components["TextLog:text"]]
    assert sum("habit acted (distance" in t for t in texts) == len(controller)
    _, err = R.scalar_series(entities[R.ESTIMATE_ERROR])
    assert len(err) == len(controller) and np.all(err > 0), "noisy vision: the estimate is off MuJoCo's arm"


def test_state_estimate_error_is_zero_with_perfect_vision_and_the_noise_without(tmp_path):
    """The metric rows' estimate_error: 0 (float32 rounding) when the arm is seen without noise; under noisy vision
    the pass-through carries the noise (hand, elbow and target each off by ~0.5 sqrt(pi/2) cm)."""
    perfect = train(tiny_config((0,), episodes=2, agent="spac"), tmp_path / "p", progress=False)
    noisy = train(tiny_config((0,), episodes=2, agent="spac", task="changing_target_noisy"), tmp_path / "n",
                  progress=False)
    assert (pd.read_parquet(perfect / "metrics.parquet").estimate_error < 1e-5).all()
    err = pd.read_parquet(noisy / "metrics.parquet").estimate_error
    assert 0.3 < err.mean() < 0.9, err.tolist()
