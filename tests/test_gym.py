"""apac_mj.suite.gym: every suite task as a registered gymnasium.Env that passes Gymnasium's own checker."""
from __future__ import annotations

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")

import apac_mj.suite.gym as apac_gym  # noqa: E402
from apac_mj import suite  # noqa: E402


def test_every_task_is_registered():
    assert apac_gym.ENV_IDS == [f"apac_mj/{t}-v0" for _, t in suite.ALL_TASKS]
    assert len(apac_gym.ENV_IDS) == 24 and all(i in gymnasium.registry for i in apac_gym.ENV_IDS)
    assert apac_gym.register_all() == apac_gym.ENV_IDS  # idempotent


@pytest.mark.parametrize("task", [t for _, t in suite.ALL_TASKS])
def test_check_env(task, recwarn):
    """Gymnasium's checker passes on every task, warning only of the unbounded observations that noisy
    vision and growing links really have; the default action space is [-1, 1] per joint."""
    from gymnasium.utils.env_checker import check_env

    plant = suite.load_spec(task).plant  # a task with dynamics runs its own servos (or torques)
    env = gymnasium.make(apac_gym.env_id(task), actuation="servo" if plant.dynamic else "kinematic")
    assert env.spec.max_episode_steps == suite.load_spec(task).steps_per_episode == 30
    check_env(env.unwrapped, skip_render_check=True)
    spec = env.unwrapped.task_spec
    unbounded = spec.kinematics_mode == "changing" or spec.vision_noise_std > 0 or spec.plant.observe_velocities
    messages = [str(w.message) for w in recwarn]
    assert all("infinity" in m for m in messages) and (len(messages) > 0) == unbounded, messages
    assert env.action_space.low.tolist() == [-1, -1] and env.action_space.high.tolist() == [1, 1]
    obs, info = env.reset(seed=3)
    assert obs.shape == (8 if plant.observe_velocities else 6,) and obs.dtype == np.float32 and info["vision"]
    env.close()


def test_sb3_checker_passes_without_warnings():
    sb3_checker = pytest.importorskip("stable_baselines3.common.env_checker")
    import warnings

    for task in ("static_target", "changing_target"):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            sb3_checker.check_env(gymnasium.make(apac_gym.env_id(task), actuation="kinematic").unwrapped)
    with pytest.warns(UserWarning, match="symmetric and normalized"):  # the paper's raw command
        sb3_checker.check_env(apac_gym.PlanarArmEnv("static_target", actuation="kinematic", action="degrees"))


def _end_after(action, seed=0):
    env = apac_gym.PlanarArmEnv("changing_target", actuation="kinematic", action="degrees", observation="cm")
    env.reset(seed=seed)
    obs, *_ = env.step(np.asarray(action, dtype=np.float32))
    return obs[:2].astype(np.float64)


def test_terminated_and_truncated_are_kept_apart():
    env = apac_gym.PlanarArmEnv("changing_target", actuation="kinematic", action="degrees", observation="cm")
    env.reset(seed=0)
    target = _end_after([30.0, -45.0])
    env._env.task.set_target_override(target)  # the next episode's target: where that action leads
    obs, info = env.reset()
    np.testing.assert_allclose(obs[4:], target, atol=1e-5)
    obs, reward, terminated, truncated, info = env.step(np.array([30.0, -45.0], dtype=np.float32))
    assert (terminated, truncated) == (True, False) and info["distance"] <= 0.5 and reward == -info["distance"]
    env._env.task.set_target_override(None)
    env.reset(seed=1)
    flags = [env.step(np.zeros(2, dtype=np.float32))[2:4] for _ in range(30)]
    assert flags[:-1] == [(False, False)] * 29 and flags[-1] == (False, True)


@pytest.mark.parametrize("terminate", [False, True])
def test_step_after_the_episode_ended_is_a_clear_error_and_changes_nothing(terminate):
    """F22: after terminated/truncated, step() without reset() raises (Gymnasium's convention: the
    episode is over) instead of a TypeError and a silent reset of the task."""
    env = gymnasium.make("apac_mj/changing_target-v0", actuation="kinematic", action="degrees")
    env.reset(seed=1)
    raw = env.unwrapped
    if terminate:
        raw._env.task.set_target_override(_end_after([30.0, -45.0], seed=1))
        env.reset()
        assert env.step(np.array([30.0, -45.0], dtype=np.float32))[2:4] == (True, False)
    else:
        while not any(env.step(np.array([5.0, -5.0], dtype=np.float32))[2:4]):
            pass
    episode, target = raw._env.task.episode, raw._env.physics.target()
    for _ in range(2):
        with pytest.raises(RuntimeError, match="episode has ended.*call reset"):
            env.step(np.array([5.0, 5.0], dtype=np.float32))
    assert raw._env.task.episode == episode and np.array_equal(raw._env.physics.target(), target)
    env.reset()
    assert raw._env.task.episode == episode + 1
    assert env.step(np.zeros(2, dtype=np.float32))[2:4] == (False, False)


def test_feasible_action_moves_the_arm_where_the_paper_command_is_clamped_away():
    """From the start pose (0, 180) degrees the raw ±180° command loses everything past the limits (about
    30% of uniform actions move nothing); the default normalized action is the target angle in the
    joint range, so no action moves nothing, and -1 / +1 reach the limits."""
    rng = np.random.default_rng(0)
    moved = {}
    for action in apac_gym.ACTIONS:
        env = apac_gym.PlanarArmEnv("static_target", actuation="kinematic", action=action)
        env.reset(seed=0)
        actions = rng.uniform(env.action_space.low, env.action_space.high, size=(400, 2))
        moved[action] = np.mean([np.any(np.abs(env.executable(env.command(a))) > 1e-6) for a in actions])
    assert moved["feasible"] == 1.0 and 0.6 < moved["degrees"] < 0.8
    env = apac_gym.PlanarArmEnv("static_target", actuation="kinematic")
    env.reset(seed=0)
    np.testing.assert_allclose(env.unwrapped._env.physics.joint_angles(), [0.0, 180.0], atol=1e-9)
    _, _, _, _, info = env.step(np.array([1.0, -1.0], dtype=np.float32))
    np.testing.assert_allclose(info["command"], [180.0, -180.0])
    np.testing.assert_allclose(env._env.physics.joint_angles(), [180.0, 0.0], atol=1e-6)
    _, _, _, _, info = env.step(np.array([0.0, 0.0], dtype=np.float32))  # the middle of the range
    np.testing.assert_allclose(env._env.physics.joint_angles(), [90.0, 90.0], atol=1e-6)
    np.testing.assert_allclose(info["executable"], info["command"])


def test_normalized_observation_is_the_plane_mapped_onto_the_unit_square():
    cm = apac_gym.PlanarArmEnv("changing_target", actuation="kinematic", observation="cm")
    unit = apac_gym.PlanarArmEnv("changing_target", actuation="kinematic")
    a, _ = cm.reset(seed=4)
    b, _ = unit.reset(seed=4)
    np.testing.assert_allclose(b, (a - 15.0) / 15.0, atol=1e-6)
    for env, obs in ((cm, a), (unit, b)):
        assert env.observation_space.contains(obs)
    # the bounds hold the whole reach: the stretched arm at (90, 0) and a target in a corner
    for angles in ([90.0, 0.0], [0.0, 0.0], [180.0, 0.0]):
        unit._env.physics.write_joint_angles(np.array(angles))
        assert unit.observation_space.contains(unit._observe(unit._env.task.get_observation(unit._env.physics)))


def test_bad_parameterization_names_the_choices():
    with pytest.raises(ValueError, match="action must be one of .*feasible.*degrees"):
        gymnasium.make("apac_mj/static_target-v0", action="normalised")
    with pytest.raises(ValueError, match="observation must be one of .*normalized.*cm"):
        apac_gym.PlanarArmEnv("static_target", observation="pixels")


@pytest.mark.parametrize("task, action, words", [
    ("changing_target", "degrees", "shoulder, elbow change in degrees"),
    ("changing_target_torque", "degrees", "shoulder, elbow torque in N·m"),
    ("changing_target", "feasible", "shoulder, elbow u in [-1, 1], mapped onto the feasible angle changes"),
    ("changing_target_torque", "feasible", "shoulder, elbow u in [-1, 1], scaled to torques in N·m")])
def test_wrong_action_shape_names_what_the_action_is(task, action, words):
    """The refusal of an action of the wrong shape says what the action is in this task and parameterization
    (it once said only '(shoulder, elbow)', whatever the units)."""
    env = gymnasium.make(apac_gym.env_id(task), action=action)
    env.reset(seed=0)
    with pytest.raises(ValueError) as e:
        env.step(np.zeros(3, dtype=np.float32))
    assert str(e.value) == f"action must have shape (2,) ({words}), got shape (3,)"


def test_occluded_observation_and_seeding():
    env = gymnasium.make("apac_mj/changing_target_occluded-v0", actuation="kinematic")
    first, info = env.reset(seed=5)
    assert info["vision"] and np.any(first != 0)
    obs, *_, info = env.step(np.array([0.1, 0.1], dtype=np.float32))
    assert not info["vision"] and np.all(obs == -1)  # 0 cm: the plane's corner, normalized
    again, _ = env.reset(seed=5)
    np.testing.assert_array_equal(first, again)
    other, _ = env.reset(seed=6)
    assert not np.array_equal(first[4:], other[4:])  # another seed, another target


def test_unknown_task_names_the_known_ones():
    with pytest.raises(KeyError, match="unknown task"):
        apac_gym.PlanarArmEnv("no_such_task")


@pytest.mark.slow
def test_sb3_td3_learns_commands_that_move_the_arm():
    """Stable-Baselines3's TD3, trained briefly through the adapter's defaults (normalized action and
    observation) on the static target: its frozen policy's commands move the arm (the raw ±180° command's
    failure: parking on the joint limits, every command clamped away) and bring the hand near the target."""
    sb3 = pytest.importorskip("stable_baselines3")
    import torch
    from stable_baselines3.common.noise import NormalActionNoise

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        env = gymnasium.make("apac_mj/static_target-v0", actuation="kinematic")
        env.reset(seed=0)
        model = sb3.TD3("MlpPolicy", env, seed=0, device="cpu", learning_starts=100, batch_size=64,
                        buffer_size=2000, action_noise=NormalActionNoise(np.zeros(2), 0.1 * np.ones(2)),
                        policy_kwargs={"net_arch": [64, 64]})
        model.learn(total_timesteps=1500)
    finally:
        torch.set_num_threads(threads)
    moved, final = [], []
    for _ in range(5):
        obs, info = env.reset()
        start = info["distance"]
        done = False
        while not done:
            obs, _, terminated, truncated, info = env.step(model.predict(obs, deterministic=True)[0])
            moved.append(bool(np.any(np.abs(info["executable"]) > 1e-6)))
            done = terminated or truncated
        final.append(info["distance"])
    assert np.mean(moved) > 0.9, f"{1 - np.mean(moved):.0%} of the policy's commands moved nothing"
    assert np.mean(final) < 0.5 * start, (final, start)
