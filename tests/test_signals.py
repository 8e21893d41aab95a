"""Signals take time and are noisy (``[signals]``, apac_mj/suite/signals.py): known answers for the delays, the
motor and sensory noise, the refusals, and an all-zero table that changes nothing."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
import torch

from apac_mj import suite
from apac_mj.suite import planar_arm, signals, task_spec
from apac_mj.suite.task_spec import TaskSpecError
from apac_mj.suite.vec_env import VecEnv

from conftest import through_a_checkpoint

COMPLIANT = "changing_target_compliant_curl_field"
#: The compliant arm with its joint velocities observed and the curl field on from the first episode (so that
#: the field's own per-sub-step path, Plant.step, is the one the delays step through).
FIELD_ON = {"plant": {"observe_velocities": True, "field_on_episode": 0, "field_off_episode": -1}}


def spec_with(table: dict | None, task: str = COMPLIANT, **overrides) -> task_spec.TaskSpec:
    spec = suite.load_spec(task).replace(**overrides)
    return spec if table is None else spec.replace(signals=table)


def rows(obs) -> np.ndarray:
    """An observation's visual and proprioceptive values as one row (the DelayLine's order)."""
    return np.concatenate([obs[k] for k in ("end_effector", "elbow", "target", "joint_velocities")])


def play(env, actions) -> tuple[list[np.ndarray], list[float]]:
    """Reset, then each action: the observations (as rows, the reset's first) and rewards."""
    obs, rewards = [rows(env.reset().observation)], []
    for a in actions:
        ts = env.step(a)
        obs.append(rows(ts.observation))
        rewards.append(ts.reward)
    return obs, rewards


ACTIONS = np.random.default_rng(0).uniform(-40, 40, size=(8, 2))


def test_ideal_arm_constants_match_the_model():
    physics = planar_arm.make_physics()
    assert physics.model.opt.timestep == signals.IDEAL_TIMESTEP
    assert planar_arm.N_SUB_STEPS == signals.IDEAL_SUB_STEPS


@pytest.mark.parametrize("ms,timestep,n", [(70, 0.002, 35), (5, 0.002, 3), (3, 0.002, 2), (1, 0.01, 0),
                                           (15, 0.01, 2), (14.9, 0.01, 1), (100, 0.002, 50), (0, 0.002, 0)])
def test_delay_rounds_to_the_nearest_sub_step(ms, timestep, n):
    assert signals.delay_sub_steps(ms, timestep) == n


def test_one_step_delay_delivers_the_previous_true_state():
    """A delay of exactly one control step (100 ms = 50 sub-steps of 2 ms): the observation at step t is the
    true one at step t - 1, to the bit (stepping sub-step by sub-step changes no physics), the start before."""
    truth, true_rewards = play(planar_arm.make_environment(spec_with(None, **FIELD_ON), random=4), ACTIONS)
    delayed_env = planar_arm.make_environment(
        spec_with({"visual_delay_ms": 100, "proprioceptive_delay_ms": 100}, **FIELD_ON), random=4)
    seen, rewards = play(delayed_env, ACTIONS)
    assert np.array_equal(seen[0], truth[0]) and np.array_equal(seen[1], truth[0])
    for t in range(1, len(ACTIONS) + 1):
        assert np.array_equal(seen[t], truth[t - 1]), t
    assert rewards == true_rewards  # reward (and the physics) stay the true ones
    assert not np.array_equal(truth[2], truth[1])  # the arm moves: the comparison could fail


def true_sub_steps(spec, actions, seed: int) -> np.ndarray:
    """The true observed rows at the start and after every sub-step (a hook recording the physics)."""
    env = planar_arm.make_environment(spec, random=seed)
    recorded = []
    env.physics.sub_step_hook = lambda p: recorded.append(np.concatenate(
        [p.end_effector(), p.elbow(), p.target(), p.joint_velocities()]))
    recorded.append(rows(env.reset().observation))
    for a in actions:
        env.step(a)
    return np.array(recorded)


@pytest.mark.parametrize("visual_ms,proprio_ms", [(70, 20), (10, 130), (150, 0)])
def test_sub_step_delays_deliver_the_state_that_long_ago(visual_ms, proprio_ms):
    """Visual signals ``visual_ms`` and proprioceptive ``proprio_ms`` late, each to its own sub-step (2 ms):
    at step t (t x 50 sub-steps) the delivered row is the true one ``d / 2 ms`` sub-steps earlier, the start
    while the delay has not elapsed."""
    truth = true_sub_steps(spec_with(None, **FIELD_ON), ACTIONS, seed=9)
    seen, _ = play(planar_arm.make_environment(
        spec_with({"visual_delay_ms": visual_ms, "proprioceptive_delay_ms": proprio_ms}, **FIELD_ON), random=9),
        ACTIONS)
    for t in range(len(ACTIONS) + 1):
        v, p = max(0, 50 * t - visual_ms // 2), max(0, 50 * t - proprio_ms // 2)
        np.testing.assert_array_equal(seen[t][:6], truth[v][:6], err_msg=f"visual, step {t}")
        np.testing.assert_array_equal(seen[t][6:], truth[p][6:], err_msg=f"proprioceptive, step {t}")


def test_motor_noise_std_is_proportional_to_the_command():
    """Harris & Wolpert: std = k |u|. Over 20 000 draws per command the fitted slope is k within 3 %, the
    noise at a zero command exactly 0; a constant part c adds std c at 0 (sqrt((k u)^2 + c^2) elsewhere)."""
    k, c, n = 0.2, 0.5, 20_000
    commands = np.array([0.0, 5.0, 10.0, 20.0, 40.0])
    rng = np.random.RandomState(0)
    spec = signals.SignalSpec(motor_noise=k)
    stds = np.array([np.std([signals.motor_command(np.array([u, -u]), spec, rng)[0] for _ in range(n)])
                     for u in commands])
    assert stds[0] == 0.0
    slope = float(commands @ stds / (commands @ commands))
    assert abs(slope - k) < 0.03 * k
    spec = signals.SignalSpec(motor_noise=k, motor_noise_constant=c)
    for u, expected in ((0.0, c), (10.0, math.hypot(k * 10, c))):
        s = np.std([signals.motor_command(np.array([u, u]), spec, rng)[1] for _ in range(n)])
        assert abs(s - expected) < 0.03 * expected


def test_motor_noise_reaches_the_plant():
    """On the ideal arm (kinematic actuation writes the command exactly) a command (10, 0) from the start
    (0, 180) moves the shoulder by 10 deg with std k x 10 and leaves the elbow exactly at 180 (0 command, 0 noise)."""
    k = 0.1
    env = planar_arm.make_environment(spec_with({"motor_noise": k}, task="changing_target"), "kinematic", random=1)
    angles = []
    for _ in range(400):
        env.reset()
        env.step(np.array([10.0, 0.0]))
        angles.append(env.physics.joint_angles())
    angles = np.array(angles)
    assert np.allclose(angles[:, 1], 180.0, atol=1e-9)
    assert abs(angles[:, 0].std() - k * 10) < 0.15 * k * 10 and abs(angles[:, 0].mean() - 10) < 0.1


def test_sensory_noise_has_its_std_and_the_same_seed_the_same_noise():
    """Delivered minus true (the physics now, no delay) has the table's std: 0.5 cm and 20 deg/s within 10 %."""
    noisy_spec = spec_with({"visual_noise": 0.5, "proprioceptive_noise": 20.0}, **FIELD_ON)
    env = planar_arm.make_environment(noisy_spec, random=2)
    err = []
    for t in range(300):
        obs = env.reset().observation if t == 0 else env.step(ACTIONS[t % len(ACTIONS)]).observation
        p = env.physics
        err.append(rows(obs) - np.concatenate([p.end_effector(), p.elbow(), p.target(), p.joint_velocities()]))
    err = np.array(err)
    assert abs(err[:, :6].std() - 0.5) < 0.05 and abs(err[:, 6:].std() - 20.0) < 2.0
    seen, _ = play(planar_arm.make_environment(noisy_spec, random=2), np.zeros((300, 2)))
    again, _ = play(planar_arm.make_environment(noisy_spec, random=2), np.zeros((300, 2)))
    other, _ = play(planar_arm.make_environment(noisy_spec, random=3), np.zeros((300, 2)))
    assert np.array_equal(np.array(again), np.array(seen)) and not np.array_equal(np.array(other), np.array(seen))


def test_vec_env_state_roundtrip_with_signals():
    """A checkpoint mid-episode holds the delay line and the noise: the restored environments go on to the bit."""
    overrides = {**FIELD_ON, "signals": {"visual_delay_ms": 70, "proprioceptive_delay_ms": 30, "motor_noise": 0.1,
                                         "visual_noise": 0.2, "proprioceptive_noise": 5.0}}

    def go(env, actions):
        out = []
        for a in actions:
            o = env.step(a)
            out.append(np.concatenate([o.arm.ravel(), env.extra.ravel(), o.reward]))
            env.reset(o.last)
        return np.array(out)

    actions = np.random.default_rng(1).uniform(-30, 30, size=(12, 2, 2))
    env = VecEnv(COMPLIANT, [0, 1], overrides=overrides)
    env.reset()
    go(env, actions[:5])
    state = through_a_checkpoint(env.get_state())
    reference = go(env, actions[5:])
    restored = VecEnv(COMPLIANT, [0, 1], overrides=overrides)
    restored.set_state(state)
    np.testing.assert_array_equal(go(restored, actions[5:]), reference)


def test_the_table_parses_overrides_and_shows():
    spec = task_spec.parse_task({"plant": {"actuation": "compliant", "observe_velocities": True},
                                 "signals": {"visual_delay_ms": 70, "proprioceptive_noise": 2}}, "t")
    assert spec.signals == signals.SignalSpec(visual_delay_ms=70.0, proprioceptive_noise=2.0)
    merged = spec.replace(signals={"proprioceptive_delay_ms": 20})
    assert merged.signals == signals.SignalSpec(70.0, 20.0, proprioceptive_noise=2.0)
    assert spec.replace(signals=None).signals is None and task_spec.TaskSpec(name="x").signals is None
    shown = task_spec.describe(merged)
    assert "* signals.visual_delay_ms = 70.0  [ms]  (35 sub-steps of 2 ms = 70 ms; a step is 50)" in shown
    assert "* signals.proprioceptive_delay_ms = 20.0  [ms]  (10 sub-steps" in shown
    assert "  signals.motor_noise = 0.0  [x |command|]" in shown


def test_the_set_grammar_reaches_the_table():
    """``--set task_overrides={signals={visual_delay_ms=70}}``, read by the train command's one grammar."""
    import argparse

    from apac_mj.commands import train as train_cmd
    from apac_mj.config import TrainConfig

    d = TrainConfig()
    args = argparse.Namespace(task=COMPLIANT, episodes=d.episodes, device=d.device, precision=d.precision,
                              checkpoint_every=d.checkpoint_every, actuation=d.actuation, agent="apac", seeds=None,
                              overrides=["task_overrides={signals={visual_delay_ms=70}}"])
    cfg = train_cmd.train_config(args)
    assert cfg.task_overrides == {"signals": {"visual_delay_ms": 70}}
    assert suite.spec_for(cfg).signals == signals.SignalSpec(visual_delay_ms=70.0)


@pytest.mark.parametrize("table,task,match", [
    ({"visual_delay_ms": -1}, COMPLIANT, "visual_delay_ms must be a finite number >= 0"),
    ({"proprioceptive_delay_ms": float("nan")}, "changing_target_torque", "proprioceptive_delay_ms must be a finite"),
    ({"visual_delay_ms": float("inf")}, COMPLIANT, "visual_delay_ms must be a finite"),
    ({"visual_delay_ms": 3001}, COMPLIANT, "visual_delay_ms = 3001 ms is longer than an episode"),
    ({"visual_delay_ms": 12001}, "changing_target", r"longer than an episode \(30 steps of 400 ms"),
    ({"motor_noise": -0.1}, COMPLIANT, "motor_noise must be a finite number >= 0"),
    ({"visual_noise": -1}, COMPLIANT, "visual_noise must be"),
    ({"proprioceptive_delay_ms": 20}, COMPLIANT, "proprioceptive_delay_ms needs a proprioceptive signal"),
    ({"proprioceptive_noise": 1}, "changing_target", "proprioceptive_noise needs a proprioceptive signal"),
    ({"visual_noise": 0.3}, "changing_target_noisy", "visual_noise and \\[vision\\] noise_std are the same noise"),
    ({"visual_delay": 70}, COMPLIANT, r"unknown key\(s\) \['visual_delay'\]"),
    ({"motor_noise": True}, COMPLIANT, "signals.motor_noise must be a finite number"),
])
def test_bad_values_are_refused_naming_the_field(table, task, match):
    with pytest.raises(TaskSpecError, match=match):
        suite.load_spec(task).replace(signals=table)


def test_delays_on_kinematic_actuation_are_refused_before_anything_is_written(tmp_path):
    from apac_mj.config import AgentConfig, TrainConfig
    from apac_mj.run.trainer import train
    from conftest import TINY

    spec = spec_with({"visual_delay_ms": 70}, task="changing_target")
    planar_arm.make_environment(spec, "servo")  # the ideal arm's servos have sub-steps (10 ms)
    with pytest.raises(ValueError, match="delays need the plant's sub-steps; actuation 'kinematic'"):
        planar_arm.make_environment(spec, "kinematic")
    cfg = TrainConfig(task="changing_target", seeds=(0,), episodes=2, actuation="kinematic",
                      task_overrides={"signals": {"visual_delay_ms": 70}}, agent=AgentConfig(kind="apac", **TINY))
    with pytest.raises(ValueError, match="delays need the plant's sub-steps"):
        train(cfg, tmp_path / "run", progress=False)
    assert not (tmp_path / "run").exists()


def test_an_all_zero_table_reproduces_todays_run(tmp_path):
    """Zero delays and zero noise: the same metrics and final weights, to the bit, as no table at all."""
    from test_trainer import final_weights, tiny_config
    from apac_mj.run.trainer import train
    from conftest import deterministic
    import dataclasses

    zero = {k: 0.0 for k in signals.SIGNAL_KEYS}
    runs = {}
    for name, overrides in (("none", {}), ("zero", {"signals": zero})):
        cfg = dataclasses.replace(tiny_config((0, 1), episodes=3), task_overrides=overrides)
        runs[name] = train(cfg, tmp_path / name, progress=False)
    a, b = (pd.read_parquet(runs[n] / "metrics.parquet") for n in ("none", "zero"))
    pd.testing.assert_frame_equal(deterministic(a), deterministic(b), check_exact=True)
    wa, wb = final_weights(runs["none"]), final_weights(runs["zero"])
    assert wa.keys() == wb.keys() and all(torch.equal(wa[k], wb[k]) for k in wa)


def test_babbling_stores_the_arm_the_senses_delivered_where_it_was_seen():
    """Babbling's stored next arm (and the target it sets) is MuJoCo's arm without a ``[signals]`` table, and the
    delivered (delayed, noisy) arm with one, where vision showed it; an unseen step keeps MuJoCo's."""
    from types import SimpleNamespace

    from apac_mj.layout import ARM, END, TARGET
    from apac_mj.run.trainer import _transition

    delivered = torch.arange(24, dtype=torch.float32).reshape(3, 8)
    true_arm = -np.arange(12, dtype=np.float32).reshape(3, 4) - 1.0
    info = SimpleNamespace(tensors=SimpleNamespace(state=torch.zeros(3, 8), next_state=delivered,
                                                   reward=torch.ones(3), terminal=torch.zeros(3, dtype=torch.bool)),
                           true_arm=true_arm, vision=np.array([True, False, True]))
    babbling = np.array([True, True, False])
    _, plain, _, _ = _transition(info, babbling)
    _, sensed, r, done = _transition(info, babbling, sensed=True)
    assert torch.equal(plain[:2, ARM], torch.as_tensor(true_arm[:2]))
    assert torch.equal(sensed[0, ARM], delivered[0, ARM]) and torch.equal(sensed[0, TARGET], delivered[0, ARM][END])
    assert torch.equal(sensed[1, ARM], torch.as_tensor(true_arm[1]))  # not seen: MuJoCo's
    assert torch.equal(sensed[2], delivered[2]) and r[2] == 1 and done[:2].tolist() == [1.0, 1.0]
