"""The agent sees the arm's motion (issue 27): on a task that observes the joint velocities every network reads
them by their own scale, the forward model predicts them and the inverse model takes them; the paper's tasks keep
the paper's inputs; a dynamic plant's executed action is the command it received; the Gym adapter scales alike."""
import numpy as np
import pytest
import torch

from conftest import TINY, nets

from apac_mj.agent.agent import Agent
from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.layout import Sizes
from apac_mj.suite.task_spec import load_task
from apac_mj.types import ARM, EXTRA, POSITIONS

TORQUE = "changing_target_torque"
GRAVITY = "changing_target_compliant_gravity"
VELOCITY_SIZES = Sizes(8, 2, 0.5, False, (500.0, 500.0))


def agent(sizes: Sizes = VELOCITY_SIZES, **cfg) -> Agent:
    return Agent(AgentConfig(**nets(16, 16), **cfg), seeds=[0, 1], sizes=sizes)


def states(v: float, E: int = 2) -> torch.Tensor:
    s = torch.tensor([[20.0, 15.0, 17.0, 11.0, 8.0, 22.0, v, -v]] * E)
    return s


def test_velocities_enter_the_networks_by_their_own_scale():
    a = agent()
    x = a.inputs.state(states(250.0))
    assert torch.allclose(x[:, EXTRA], torch.tensor([[0.5, -0.5]] * 2))  # 250 deg/s of a 500 deg/s scale
    assert torch.allclose(x[:, POSITIONS], a.inputs.pos(states(250.0)[:, POSITIONS]))  # positions as on the paper's tasks
    assert x.abs().max() <= 1.0
    raw = agent(normalize_inputs=False).inputs.state(states(250.0))  # the paper's raw inputs: everything raw
    assert torch.equal(raw, states(250.0))


def test_the_internal_models_read_the_motion_and_the_forward_model_predicts_it():
    a = agent()
    assert a.forward_model.layers[0].in_features == 4 + 2 + 2 and a.forward_model.layers[-1].out_features == 4 + 2
    assert a.inverse_model.layers[0].in_features == 6 + 2
    slow, fast = states(0.0), states(400.0)
    action = torch.full((2, 2), 0.2)
    assert not torch.allclose(a.inverse_action(slow), a.inverse_action(fast))
    assert not torch.allclose(a.predict_arm(slow, action), a.predict_arm(fast, action))
    assert a.predict_arm(slow, action).shape == (2, 4)


def test_the_paper_tasks_keep_the_paper_inputs():
    a = agent(Sizes())
    assert a.forward_model.layers[0].in_features == 6 and a.forward_model.layers[-1].out_features == 4
    assert a.inverse_model.layers[0].in_features == 6 and a.actor.layers[0].in_features == 6
    s = states(0.0)[:, POSITIONS]
    assert torch.equal(a.inputs.state(s), a.inputs.pos(s))


def test_the_forward_loss_counts_the_velocity_error_in_half_planes_per_scale():
    a = agent()
    y = torch.zeros(2, 1, 6)
    y[..., ARM] = torch.tensor([20.0, 15.0, 17.0, 11.0])
    y[..., 4:] = a.plane_scale * 0.75  # sigmoid 0.75 -> 2 (2 * 0.75 - 1) = 1: one scale, 500 deg/s
    s2 = states(250.0)[:, None]
    err = a._forward_error(y, s2)
    assert torch.allclose(err[..., ARM], torch.zeros(2, 1, 4))
    half = a.plane_scale / 2  # predicted 500, seen 250 and -250: (1 - 0.5) and (1 + 0.5) scales
    assert torch.allclose(err[..., 4:], torch.tensor([0.5 * half, 1.5 * half]).expand(2, 1, 2))


def _replay(tmp_path, task, executed_action):
    from apac_mj.run.trainer import train

    cfg = TrainConfig(task=task, seeds=(0,), episodes=1, agent=AgentConfig(**TINY, executed_action=executed_action),
                      task_overrides={"steps_per_episode": 5})
    seen = []
    run = train(cfg, tmp_path / executed_action, progress=False,
                on_step=lambda info, env: seen.append((info.action[0].copy(), info.joint_angles[0].copy(),
                                                       int(info.step[0]))))
    ckpt = torch.load(run / "checkpoints" / "latest.pt", weights_only=True)
    data = ckpt["agent"]["replay"]["data"]
    n = ckpt["agent"]["replay"]["count"][0]
    return seen, data["action"][0, :n], data["executed_action"][0, :n]


def test_a_compliant_arm_learns_from_the_command_it_received(tmp_path):
    """Under gravity the servo falls short of its set-point: the measured joint change is not what was commanded,
    and "auto" (a dynamic plant: "command") stores the command (clipped to the joint range), "joint_change" the
    measured change (the paper's reading, exact on its ideal arm)."""
    seen, action, executed = _replay(tmp_path, GRAVITY, "auto")
    assert len(seen) == len(executed) == 10  # one babbling and one training episode of 5 steps
    commands = torch.tensor(np.array([a for a, _, _ in seen]), dtype=torch.float32)
    assert torch.equal(executed, action)  # critic_action = "executed": the critic learns the same action
    later = [i for i, (_, _, step) in enumerate(seen) if step > 0]  # the angles before a step: the last step's
    lo, hi = load_task(GRAVITY).joint_range
    for i in later:  # the command, or where it leaves the joint range the set-point at the limit
        setpoint = seen[i - 1][1] + executed[i].numpy()
        assert np.all((setpoint >= lo - 1e-2) & (setpoint <= hi + 1e-2))
        kept = np.isclose(executed[i].numpy(), commands[i].numpy(), atol=1e-3)
        assert np.all(kept | np.isclose(setpoint, lo, atol=1e-2) | np.isclose(setpoint, hi, atol=1e-2))
    assert sum(np.allclose(executed[i].numpy(), commands[i].numpy(), atol=1e-3) for i in later) >= 3
    seen, _, measured = _replay(tmp_path, GRAVITY, "joint_change")
    changes = np.array([seen[i][1] - seen[i - 1][1] for i in later])
    assert np.allclose(measured[later].numpy(), changes, atol=1e-3)  # the measured joint-angle change
    assert (measured - executed).abs().max() > 1.0  # and the two differ by degrees: the servo lags and sags


def test_joint_change_is_refused_for_torques():
    from apac_mj.run.build import check

    with pytest.raises(ValueError, match="executed_action"):
        check(TrainConfig(task=TORQUE, agent=AgentConfig(executed_action="joint_change")))
    with pytest.raises(ValueError, match="executed_action"):
        AgentConfig(executed_action="measured")


def test_the_gym_adapter_scales_the_velocities_when_normalized():
    pytest.importorskip("gymnasium")
    from apac_mj.suite import gym as apac_gym

    envs = {o: apac_gym.PlanarArmEnv(TORQUE, observation=o) for o in ("normalized", "cm")}
    obs = {}
    for o, env in envs.items():
        env.reset(seed=3)
        obs[o], *_ = env.step(np.array([1.0, -1.0], dtype=np.float32))
    raw = envs["cm"]._env.physics.joint_velocities()
    assert np.allclose(obs["cm"][6:], raw, rtol=1e-5) and np.abs(raw).max() > 50  # deg/s
    assert np.allclose(obs["normalized"][6:], obs["cm"][6:] / 500.0, rtol=1e-5)


def test_the_velocity_spec_carries_its_scale_and_bounds_nothing():
    """dm_env checks observations against a bounded spec, and the arm may move faster than its scale."""
    from apac_mj import suite
    from apac_mj.suite.planar_arm import ScaledArray

    env = suite.load("planar_arm", TORQUE, task_kwargs={"random": 0})
    spec = env.observation_spec()["joint_velocities"]
    assert isinstance(spec, ScaledArray) and spec.scale == 500.0
    spec.validate(np.array([-545.0, 900.0]))  # beyond the scale: still a valid observation
    assert Sizes.from_specs(env.observation_spec(), env.action_spec()).extra_scale == (500.0, 500.0)
    import pickle

    assert pickle.loads(pickle.dumps(spec)).scale == 500.0
