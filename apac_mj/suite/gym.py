"""Gymnasium environments: ``import apac_mj.suite.gym`` registers every task as ``apac_mj/<task>-v0``.

    import gymnasium as gym
    import apac_mj.suite.gym  # noqa: F401  (registers the tasks)

    env = gym.make("apac_mj/changing_target-v0")
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

Each environment wraps the task's dm_control environment (:func:`apac_mj.suite.load`):

* observation: the agent's 6-D state ``[end_x, end_y, elbow_x, elbow_y, target_x, target_y]``
  in cm (float32; unbounded, as the links grow without limit under changing kinematics). Under occluded vision it is seen at the first step only and reads zero
  afterwards, as in the suite (intermittent vision: zero on the unseen steps; noisy vision: the
  noisy positions); ``info["vision"]`` says which. A task that observes the joint velocities
  (``[plant] observe_velocities``) appends them (deg/s): 8-D.
* action: the change of the (shoulder, elbow) joint angles in degrees, in ``[-180, 180]``;
  the plant clamps angles at the joint limits. A torque-driven task (``[plant] actuation = "torque"``):
  the joint torques in N·m, in ``[-max_torque, max_torque]``.
* reward: minus the distance to the target (cm).
* ``terminated``: the end effector is inside the target zone; ``truncated``: the task's step
  limit (30 steps) was hit. The environment applies its own limit, so no ``TimeLimit`` wrapper.
* ``info``: ``distance`` (cm), ``vision`` (bool), ``link_lengths`` (cm).

``reset(seed=s)`` rebuilds the task with seed ``s`` (targets and link-length schedule of that
seed). ``render_mode="rgb_array"`` renders the overhead camera. Gymnasium is an optional extra:
``pip install apac_mj[gym]``.
"""
from __future__ import annotations

from typing import Any

import numpy as np

try:
    import gymnasium
    from gymnasium import spaces
except ImportError as e:  # pragma: no cover - depends on the installation
    raise ImportError("apac_mj.suite.gym needs gymnasium, an optional extra: pip install 'apac_mj[gym]' "
                      "(or pip install gymnasium==1.3.0)") from e

from apac_mj import suite
from apac_mj.suite.planar_arm import action_bound

#: The namespace of the registered ids: ``apac_mj/<task>-v0``.
NAMESPACE = "apac_mj"
VERSION = 0


def env_id(task_name: str) -> str:
    """The Gymnasium id of a task: ``apac_mj/<task_name>-v0``."""
    return f"{NAMESPACE}/{task_name}-v{VERSION}"


class PlanarArmEnv(gymnasium.Env):
    """One task of :mod:`apac_mj.suite` as a ``gymnasium.Env`` (see the module docstring)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 5}

    def __init__(self, task_name: str = "changing_target", actuation: str = "servo",
                 render_mode: str | None = None) -> None:
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.task_name, self.actuation, self.render_mode = task_name, actuation, render_mode
        self.task_spec = suite.load_spec(task_name)  # unknown task -> KeyError listing the known ones
        # a task that observes joint velocities (its [plant]) has 8; one driven by torques, their bound
        dims = 8 if self.task_spec.plant.observe_velocities else 6
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(dims,), dtype=np.float32)
        bound = action_bound(self.task_spec)
        self.action_space = spaces.Box(-bound, bound, shape=(2,), dtype=np.float32)
        self._env: Any = None
        self._renderer: Any = None

    def _build(self, seed: int) -> None:
        self.close()
        self._env = suite.load("planar_arm", self.task_name,
                               task_kwargs={"random": seed, "actuation": self.actuation})

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        if seed is not None or self._env is None:
            self._build(int(self.np_random.integers(2**31 - 1)) if seed is None else int(seed))
        ts = self._env.reset()
        return _observation(ts.observation), self._info(ts.observation)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._env is None:
            raise RuntimeError("call reset() before step()")
        ts = self._env.step(np.asarray(action, dtype=np.float64))
        terminated = bool(ts.last() and ts.discount == 0.0)
        truncated = bool(ts.last() and not terminated)
        return _observation(ts.observation), float(ts.reward), terminated, truncated, self._info(ts.observation)

    def _info(self, obs: dict[str, np.ndarray]) -> dict[str, Any]:
        physics = self._env.physics
        return {"distance": float(physics.distance_to_target()), "vision": bool(obs["vision"][0] > 0),
                "link_lengths": physics.link_lengths().copy()}

    def render(self) -> np.ndarray | None:
        if self.render_mode is None or self._env is None:
            return None
        if self._renderer is None:
            from apac_mj.suite.render import Renderer

            self._renderer = Renderer(self._env.physics)
        return self._renderer.render()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


def _observation(obs: dict[str, np.ndarray]) -> np.ndarray:
    extra = [obs["joint_velocities"]] if "joint_velocities" in obs else []
    return np.concatenate([obs["end_effector"], obs["elbow"], obs["target"], *extra]).astype(np.float32)


def register_all() -> list[str]:
    """Register every task of :data:`apac_mj.suite.ALL_TASKS` (idempotent); returns the ids."""
    ids = []
    for _, task_name in suite.ALL_TASKS:
        ids.append(env_id(task_name))
        if ids[-1] not in gymnasium.registry:
            gymnasium.register(id=ids[-1], entry_point="apac_mj.suite.gym:PlanarArmEnv", kwargs={"task_name": task_name})
    return ids


ENV_IDS = register_all()

__all__ = ["ENV_IDS", "PlanarArmEnv", "env_id", "register_all"]
