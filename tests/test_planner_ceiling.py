"""bench/planner_ceiling.py: the agent's own planner through MuJoCo's own model (the decomposition of a
planning kind's shortfall into search and model): its imagined steps are the environment's steps, planning
leaves the environment as it was, and its rows."""
from __future__ import annotations

import csv

import numpy as np
import pytest
import torch
from conftest import bench_module

from apac_mj.rules import MPCParams


@pytest.fixture(scope="module")
def pc():
    return bench_module("planner_ceiling")


def test_imagined_steps_are_the_environments_and_planning_leaves_it_as_it_was(pc):
    env = pc.ceiling.make_env("torque_stop", 0)
    env.task.set_target_override(np.array([20.0, 22.0]))
    env.reset()
    for _ in range(2):  # a moving arm
        env.step(np.array([0.3, -0.2]))
    model = pc.ceiling.Model(env)
    ph = env.physics
    before = (ph.end_effector().copy(), ph.joint_velocities().copy())
    model.save()
    planner = pc.TrueModelPlanner(MPCParams(horizon=3), model, 0, "zero")
    agent = pc.TrueModelAgent(model)
    state = torch.as_tensor(np.concatenate([ph.end_effector(), ph.elbow(), ph.target(), ph.joint_velocities()]),
                            dtype=torch.float32)[None]
    u = torch.rand(1, 3, 3, 2, generator=torch.Generator().manual_seed(0)) * 2 - 1
    values, hands, _ = planner.rollout(agent, state, u)
    assert np.array_equal(ph.end_effector(), before[0]) and np.array_equal(ph.joint_velocities(), before[1])
    for b in range(3):
        model.restore()
        expected, v, alive = [], 0.0, 1.0
        for t in range(3):
            d = model.step(u[0, b, t].double().numpy() * 0.5)
            expected.append(ph.end_effector().copy())
            v -= 0.99 ** t * alive * d
            alive = 0.0 if model.reached(d) else alive
        np.testing.assert_allclose(hands[0, b, 1:].numpy(), np.array(expected), rtol=0, atol=1e-5)
        assert values[0, b].item() == pytest.approx(v, rel=1e-5)


def test_the_bench_writes_a_row_per_setting(pc, tmp_path):
    out = tmp_path / "rows.csv"
    rows = pc.main(["--episodes", "1", "--set", "candidates=4", "--set", "elites=2", "--set", "horizon=1,2",
                    "--set", "iterations=1", "--no-progress", "--out", str(out)])
    assert [r["horizon"] for r in rows] == [1, 2] and all(r["episodes"] == 1 for r in rows)
    with out.open() as f:
        assert [int(r["horizon"]) for r in csv.DictReader(f)] == [1, 2]
    with pytest.raises(ValueError, match="not an agent.mpc field"):
        pc.main(["--episodes", "1", "--set", "horizn=2", "--no-progress"])
