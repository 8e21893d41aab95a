"""bench/planner_ceiling.py: the agent's own planner (``MPCPlanner``, its ``rollout`` unchanged) through MuJoCo's
own model (the decomposition of a planning kind's shortfall into search and model): its imagined steps are the
environment's steps, its values the environment's discounted return, planning leaves the environment as it was,
and its rows."""
from __future__ import annotations

import csv

import numpy as np
import pytest
import torch
from conftest import bench_module

from apac_mj.agent.planner import MPCPlanner
from apac_mj.rules import MPCParams
from apac_mj.types import ArbitrationContext


@pytest.fixture(scope="module")
def pc():
    return bench_module("planner_ceiling")


def _moving_arm(pc):
    env = pc.ceiling.make_env("torque_stop", 0)
    env.task.set_target_override(np.array([20.0, 22.0]))
    env.reset()
    for _ in range(2):  # a moving arm
        env.step(np.array([0.3, -0.2]))
    model = pc.ceiling.Model(env)
    model.save()
    return model


def _by_the_environment(model, torques: np.ndarray, gamma: float, speed: bool) -> tuple[float, np.ndarray]:
    """From the saved state: ``sum_t gamma^t (-d_t)`` until the episode would end, the hand after each step,
    and (``speed``) minus the next step's hand travel discounted ``gamma^H`` unless it ended."""
    model.restore()
    v, alive, hands = 0.0, 1.0, []
    for t, torque in enumerate(torques):
        d = model.step(torque)
        hands.append(model.physics.end_effector().copy())
        v -= gamma ** t * alive * d
        alive = 0.0 if model.reached(d) else alive
    if speed:
        v -= gamma ** len(torques) * alive * float(np.hypot(*model.physics.hand_velocity())) * model.dt
    return v, np.array(hands)


@pytest.mark.parametrize("value", ["zero", "speed"])
def test_the_agents_rollout_through_the_environment_is_the_environments_return(pc, value):
    """``MPCPlanner.rollout`` itself (counted) values sequences through ``TrueModelAgent``: every imagined hand is
    the environment's, every value its discounted return (plus the speed term), and the physics is as it was."""
    model = _moving_arm(pc)
    ph = model.physics
    before = (ph.end_effector().copy(), ph.joint_velocities().copy())
    agent = pc.TrueModelAgent(model, value)
    planner = MPCPlanner(MPCParams(horizon=3), [0], 2, model.zone, model.stop_speed)
    u = torch.rand(1, 3, 3, 2, generator=torch.Generator().manual_seed(0)) * 2 - 1
    values, hands, _ = planner.rollout(agent, agent.observe()[None], u)
    assert np.array_equal(ph.end_effector(), before[0]) and np.array_equal(ph.joint_velocities(), before[1])
    for b in range(3):
        v, expected = _by_the_environment(model, u[0, b].double().numpy() * agent.bound, 0.99, value == "speed")
        np.testing.assert_allclose(hands[0, b, 1:].numpy(), expected, rtol=0, atol=1e-5)
        assert values[0, b].item() == pytest.approx(v, rel=1e-5)
    model.restore()


def test_the_bench_plans_with_the_agents_mpc_planner_unchanged(pc, monkeypatch):
    """The controller's planner is an ``MPCPlanner`` (no override), and a decision runs its ``rollout``."""
    model = _moving_arm(pc)
    calls = []
    rollout = MPCPlanner.rollout
    monkeypatch.setattr(MPCPlanner, "rollout", lambda self, *a, **k: calls.append(1) or rollout(self, *a, **k))
    ctrl = pc.PlannerController(MPCParams(horizon=2, candidates=4, elites=2, iterations=2), 0, "zero")
    ctrl.reset(model, np.random.default_rng(0))
    assert type(ctrl.planner) is MPCPlanner and type(ctrl.planner).rollout is MPCPlanner.rollout
    action = ctrl.act()
    assert action.shape == (2,) and np.all(np.abs(action) <= model.high) and len(calls) == 1 + 1 + 2
    state = ctrl.agent.observe()[None]
    ctx = ArbitrationContext(episode=torch.zeros(1, dtype=torch.long), step=torch.zeros(1, dtype=torch.long),
                             last_delta=torch.zeros(1), state=state)
    assert ctrl.planner.propose(ctrl.agent, ctx, torch.ones(1, dtype=torch.long)).habit_value.item() < 0


def test_the_bench_writes_a_row_per_setting(pc, tmp_path):
    out = tmp_path / "rows.csv"
    rows = pc.main(["--episodes", "1", "--set", "candidates=4", "--set", "elites=2", "--set", "horizon=1,2",
                    "--set", "iterations=1", "--no-progress", "--out", str(out)])
    assert [r["horizon"] for r in rows] == [1, 2] and all(r["episodes"] == 1 for r in rows)
    with out.open() as f:
        assert [int(r["horizon"]) for r in csv.DictReader(f)] == [1, 2]
    with pytest.raises(ValueError, match="not an agent.mpc field"):
        pc.main(["--episodes", "1", "--set", "horizn=2", "--no-progress"])
