"""The task gives the agent its geometry (origin, plane, joint range); the plant and the agent agree on it."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from apac_mj.agent.agent import Agent
from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.suite import spec_for
from apac_mj.kinematics import Geometry
from apac_mj.suite.task_spec import TaskSpecError
from apac_mj.suite.vec_env import VecEnv

from conftest import TINY8

#: A task whose shoulder is off-centre and whose joints have another range than the paper's [0, 180].
ELSEWHERE = {"origin": (10.0, 12.0), "joint_range": (-30.0, 200.0)}


def _elsewhere_env(actuation: str = "kinematic") -> VecEnv:
    return VecEnv("changing_target", [0], actuation, overrides=ELSEWHERE)


def test_geometry_comes_from_the_task():
    g = Geometry.from_spec(spec_for(TrainConfig(task="changing_target", task_overrides=ELSEWHERE)))
    assert g.origin == (10.0, 12.0) and g.joint_range == (-30.0, 200.0) and g.plane_size == (30.0, 30.0)
    unbounded = spec_for(TrainConfig(task="changing_target", task_overrides={"at_limit": "unbounded"}))
    assert Geometry.from_spec(unbounded).joint_range is None


def test_the_agents_feasible_range_is_the_plants_at_another_origin_and_range():
    env = _elsewhere_env()
    obs = env.reset()
    state = torch.as_tensor(np.concatenate([obs.arm, obs.target], 1), dtype=torch.float32)
    spec = spec_for(TrainConfig(task="changing_target", task_overrides=ELSEWHERE))
    agent = Agent(AgentConfig(**TINY8), [0], geometry=Geometry.from_spec(spec))
    np.testing.assert_allclose(agent.geometry.joint_angles(state[:, 0:2], state[:, 2:4]).numpy(), [[0.0, 180.0]],
                               atol=1e-3)
    lo, hi = agent.feasible_range(state)
    np.testing.assert_allclose(lo.numpy(), [[-30.0, -180.0]], atol=1e-3)  # elbow: -210 clamped to the bound
    np.testing.assert_allclose(hi.numpy(), [[180.0, 20.0]], atol=1e-3)
    env.step(np.array([[-50.0, 50.0]]))  # past both limits: the plant clips at the task's range
    np.testing.assert_allclose(env.joint_angles(), [[-30.0, 200.0]], atol=1e-9)
    wrong = Agent(AgentConfig(**TINY8), [0])  # the paper's geometry: a different (wrong) answer here
    assert not torch.allclose(wrong.feasible_range(state)[1], hi, atol=1.0)


def test_servos_respect_the_tasks_joint_range():
    env = _elsewhere_env("servo")
    env.reset()
    for _ in range(3):
        env.step(np.array([[-50.0, 50.0]]))
    angles = env.joint_angles()[0]
    assert -30.5 <= angles[0] <= -29.0 and 199.0 <= angles[1] <= 200.5


def test_the_agent_takes_the_plane_from_the_task():
    big = Geometry(origin=(20.0, 20.0), plane_size=(40.0, 40.0))
    agent = Agent(AgentConfig(plane_scale=None, **TINY8), [0], geometry=big)
    assert agent.plane_scale == 40.0 and agent.forward_model.scale == 40.0
    with pytest.raises(ValueError, match="plane_scale = 30.0 but the task's plane is 40.0 x 40.0"):
        Agent(AgentConfig(**TINY8), [0], geometry=big)
    with pytest.raises(ValueError, match="square plane"):
        Agent(AgentConfig(plane_scale=None, **TINY8), [0], geometry=Geometry(plane_size=(30.0, 40.0)))


@pytest.mark.parametrize("joint_range, message", [((10.0, 180.0), "must hold the start pose"),
                                                  ((90.0, 0.0), "low < high")])
def test_a_joint_range_the_arm_cannot_start_in_is_refused(joint_range, message):
    with pytest.raises(TaskSpecError, match=message):
        spec_for(TrainConfig(task="changing_target", task_overrides={"joint_range": joint_range}))
