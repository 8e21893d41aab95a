"""apac_mj.suite.gym: every suite task as a registered gymnasium.Env that passes Gymnasium's own checker."""
from __future__ import annotations

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")

import apac_mj.suite.gym as apac_gym  # noqa: E402
from apac_mj import suite  # noqa: E402


def test_every_task_is_registered():
    assert apac_gym.ENV_IDS == [f"apac_mj/{t}-v0" for _, t in suite.ALL_TASKS]
    assert len(apac_gym.ENV_IDS) == 18 and all(i in gymnasium.registry for i in apac_gym.ENV_IDS)
    assert apac_gym.register_all() == apac_gym.ENV_IDS  # idempotent


@pytest.mark.filterwarnings("ignore:.*(Box observation space|symmetric and normalized):UserWarning")
@pytest.mark.parametrize("task", [t for _, t in suite.ALL_TASKS])
def test_check_env(task):
    from gymnasium.utils.env_checker import check_env

    plant = suite.load_spec(task).plant  # a task with dynamics runs its own servos (or torques)
    env = gymnasium.make(apac_gym.env_id(task), actuation="servo" if plant.dynamic else "kinematic")
    check_env(env.unwrapped, skip_render_check=True)
    obs, info = env.reset(seed=3)
    assert obs.shape == (8 if plant.observe_velocities else 6,) and obs.dtype == np.float32 and info["vision"]
    env.close()


def _end_after(action, seed=0):
    env = apac_gym.PlanarArmEnv("changing_target", actuation="kinematic")
    env.reset(seed=seed)
    obs, *_ = env.step(np.asarray(action, dtype=np.float32))
    return obs[:2].astype(np.float64)


def test_terminated_and_truncated_are_kept_apart():
    env = apac_gym.PlanarArmEnv("changing_target", actuation="kinematic")
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


def test_occluded_observation_and_seeding():
    env = gymnasium.make("apac_mj/changing_target_occluded-v0", actuation="kinematic")
    first, info = env.reset(seed=5)
    assert info["vision"] and np.any(first != 0)
    obs, *_, info = env.step(np.array([10.0, 10.0], dtype=np.float32))
    assert not info["vision"] and np.all(obs == 0)
    again, _ = env.reset(seed=5)
    np.testing.assert_array_equal(first, again)
    other, _ = env.reset(seed=6)
    assert not np.array_equal(first[4:], other[4:])  # another seed, another target


def test_unknown_task_names_the_known_ones():
    with pytest.raises(KeyError, match="unknown task"):
        apac_gym.PlanarArmEnv("no_such_task")
