"""Gymnasium environments: ``import apac_mj.suite.gym`` registers every task as ``apac_mj/<task>-v0``.

    import gymnasium as gym
    import apac_mj.suite.gym  # noqa: F401  (registers the tasks)

    env = gym.make("apac_mj/changing_target-v0")
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

Each environment wraps the task's dm_control environment (:func:`apac_mj.suite.load`). Two
arguments of ``gym.make`` choose how an agent sees and commands the arm:

* ``action`` (:data:`ACTIONS`):

  - ``"feasible"`` (the default): a normalized command ``u`` in ``[-1, 1]`` per joint, mapped onto
    the joint-angle changes the current pose allows, ``lo + (hi - lo)(u + 1)/2`` with ``[lo, hi]``
    the changes that keep the joint inside its range (within ±180°). Every action moves the arm
    (unless it asks for the pose it is in); with the paper's joint range [0°, 180°] ``u`` is the
    target angle itself, ``-1`` → 0°, ``+1`` → 180°. It is the project's own agent's
    ``action_squash = "feasible"``. Under unbounded joints it is ``180 u``.
  - ``"degrees"``: the paper's raw command, the change of the (shoulder, elbow) angles in degrees in
    ``[-180, 180]``; the plant clamps the angles at the joint limits, so from the start pose
    (0°, 180°) 29 of 100 uniformly drawn commands move nothing. Standard agents (SB3 TD3/DDPG) park on
    the limits with it and learn nothing (docs/gym.md).

* ``observation`` (:data:`OBSERVATIONS`): the agent's 6-D state
  ``[end_x, end_y, elbow_x, elbow_y, target_x, target_y]``, float32,

  - ``"normalized"`` (the default): ``(x - c) / (w / 2)`` per axis with ``c`` the plane's centre and
    ``w`` its size: the plane is ``[-1, 1]²`` (SB3 TD3 with its defaults: 0 of 50 targets with cm, 50 of 50
    normalized, docs/gym.md);
  - ``"cm"``: positions in cm, the suite's own observation.

  Bounds: the arm's reach around the shoulder and the plane; unbounded under noisy vision and
  changing kinematics (the links grow). Under occluded vision the state is seen at the first step
  only and the positions read 0 cm (normalized: -1) afterwards, as in the suite (intermittent
  vision: on the unseen steps; noisy vision: the noisy positions); ``info["vision"]`` says which.

Further:

* a task with dynamics (``[plant]``): under torque actuation the action is the joint torques,
  ``u`` in ``[-1, 1]`` scaled by ``max_torque`` (``"feasible"``) or the torques in N·m in
  ``[-max_torque, max_torque]`` (``"degrees"``, the raw command); a task that observes the joint
  velocities (``observe_velocities``) appends them, 8-D: divided by the plant's ``velocity_scale``
  (500 deg/s) under ``"normalized"`` (order 1, as the agent's networks read them; SB3 SAC with its
  defaults: 1% of the grid with raw deg/s, docs/gym.md), in deg/s under ``"cm"``; unbounded either way.
* reward: minus the distance to the target (cm), in either parameterization.
* ``terminated``: the end effector is inside the target zone; ``truncated``: the task's step
  limit (30 steps) was hit; ``env.spec.max_episode_steps`` is that limit (``gym.make`` adds its
  ``TimeLimit`` at the same step). ``step`` after either without ``reset`` raises RuntimeError.
* ``info``: ``distance`` (cm), ``vision`` (bool), ``link_lengths`` (cm); after a step also
  ``command`` (the joint-angle change sent to the plant, degrees) and ``executable`` (its part the
  joint limits let through: zero means the command moved nothing).

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
from apac_mj.suite.planar_arm import ACTION_BOUND, action_bound
from apac_mj.suite.task_spec import TaskSpec

#: The namespace of the registered ids: ``apac_mj/<task>-v0``.
NAMESPACE = "apac_mj"
VERSION = 0
#: The action parameterizations (the module docstring): the default first.
ACTIONS = ("feasible", "degrees")
#: What an action is, by (parameterization, torque actuation), for the error an action of the wrong shape raises.
ACTION_WORDS = {("feasible", False): "shoulder, elbow u in [-1, 1], mapped onto the feasible angle changes",
                ("feasible", True): "shoulder, elbow u in [-1, 1], scaled to torques in N·m",
                ("degrees", False): "shoulder, elbow change in degrees",
                ("degrees", True): "shoulder, elbow torque in N·m"}
#: The observation parameterizations: the default first.
OBSERVATIONS = ("normalized", "cm")


def env_id(task_name: str) -> str:
    """The Gymnasium id of a task: ``apac_mj/<task_name>-v0``."""
    return f"{NAMESPACE}/{task_name}-v{VERSION}"


class PlanarArmEnv(gymnasium.Env):
    """One task of :mod:`apac_mj.suite` as a ``gymnasium.Env`` (see the module docstring)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 5}

    def __init__(self, task_name: str = "changing_target", actuation: str = "servo",
                 render_mode: str | None = None, action: str = ACTIONS[0],
                 observation: str = OBSERVATIONS[0]) -> None:
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if action not in ACTIONS:
            raise ValueError(f"action must be one of {ACTIONS} (normalized onto the pose's feasible changes, "
                             f"or the paper's ±180° change), got {action!r}")
        if observation not in OBSERVATIONS:
            raise ValueError(f"observation must be one of {OBSERVATIONS}, got {observation!r}")
        self.task_name, self.actuation, self.render_mode = task_name, actuation, render_mode
        self.action, self.observation = action, observation
        self.task_spec = suite.load_spec(task_name)  # unknown task -> KeyError listing the known ones
        centre = np.asarray(self.task_spec.plane_size, dtype=np.float64) / 2
        # obs = (cm - shift) / scale, per coordinate of [end, elbow, target]
        self._shift = np.tile(centre, 3) if observation == "normalized" else np.zeros(6)
        self._scale = np.tile(centre, 3) if observation == "normalized" else np.ones(6)
        high = (observation_bound_cm(self.task_spec) - self._shift) / self._scale
        low = (-observation_bound_cm(self.task_spec, low=True) - self._shift) / self._scale
        #: The joint velocities' divisor: the plant's velocity_scale (deg/s) when normalized, else 1 (deg/s).
        self._velocity_scale = self.task_spec.plant.velocity_scale if observation == "normalized" else 1.0
        if self.task_spec.plant.observe_velocities:  # joint velocities, appended (unbounded)
            high, low = np.concatenate([high, np.full(2, np.inf)]), np.concatenate([low, np.full(2, -np.inf)])
        self.observation_space = spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)
        self._torque = self.task_spec.plant.actuation == "torque"
        bound = 1.0 if action == "feasible" else action_bound(self.task_spec)
        self.action_space = spaces.Box(-bound, bound, shape=(2,), dtype=np.float32)
        self._env: Any = None
        self._renderer: Any = None
        self._ended = False

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
        self._ended = False
        return self._observe(ts.observation), self._info(ts.observation)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._env is None:
            raise RuntimeError("call reset() before step()")
        if self._ended:
            raise RuntimeError("the episode has ended (terminated or truncated was True); call reset() "
                               "before step()")
        command = self.command(action)
        executable = self.executable(command)
        ts = self._env.step(command)
        terminated = bool(ts.last() and ts.discount == 0.0)
        truncated = bool(ts.last() and not terminated)
        self._ended = terminated or truncated
        info = self._info(ts.observation) | {"command": command, "executable": executable}
        return self._observe(ts.observation), float(ts.reward), terminated, truncated, info

    def feasible_changes(self) -> tuple[np.ndarray, np.ndarray]:
        """The joint-angle changes ``(lo, hi)`` (degrees, per joint) that keep both joints in range from
        the current pose, within ±180°; ±180° under unbounded joints."""
        if self.task_spec.at_limit != "clip":
            return np.full(2, -ACTION_BOUND), np.full(2, ACTION_BOUND)
        angles = self._env.physics.joint_angles()
        lo_j, hi_j = self.task_spec.joint_range
        return (np.clip(lo_j - angles, -ACTION_BOUND, ACTION_BOUND),
                np.clip(hi_j - angles, -ACTION_BOUND, ACTION_BOUND))

    def command(self, action: np.ndarray) -> np.ndarray:
        """The joint-angle change (degrees) that ``action`` sends to the plant."""
        a = np.asarray(action, dtype=np.float64)
        if a.shape != (2,):
            what = ACTION_WORDS[self.action, self._torque]
            raise ValueError(f"action must have shape (2,) ({what}), got shape {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"action must be finite, got {a.tolist()}")
        if self.action == "degrees":
            return a
        if self._torque:  # joint torques, u scaled by the task's bound
            return np.clip(a, -1.0, 1.0) * action_bound(self.task_spec)
        lo, hi = self.feasible_changes()
        u = np.clip(a, -1.0, 1.0)
        return lo + (hi - lo) * (u + 1.0) / 2.0

    def executable(self, command: np.ndarray) -> np.ndarray:
        """The part of ``command`` (degrees) the joint limits let through from the current pose (under
        torque actuation: the torque, clipped to its bound)."""
        if self._torque:
            return np.clip(command, -action_bound(self.task_spec), action_bound(self.task_spec))
        lo, hi = self.feasible_changes()
        return np.clip(np.clip(command, -ACTION_BOUND, ACTION_BOUND), lo, hi)

    def _observe(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        cm = np.concatenate([obs["end_effector"], obs["elbow"], obs["target"]])
        extra = [obs["joint_velocities"] / self._velocity_scale] if "joint_velocities" in obs else []
        return np.concatenate([(cm - self._shift) / self._scale, *extra]).astype(np.float32)

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


def observation_bound_cm(spec: TaskSpec, low: bool = False) -> np.ndarray:
    """The upper (``low``: minus the lower) bound of the 6-D observation in cm: the arm's reach around
    the shoulder (end effector: l1 + l2, elbow: l1), the plane (target), and 0 (an unseen step);
    infinite under noisy vision (Gaussian noise) and changing kinematics (the links grow)."""
    if spec.kinematics_mode == "changing" or spec.vision_noise_std > 0:
        return np.full(6, np.inf)
    sign = -1.0 if low else 1.0
    origin = sign * np.asarray(spec.origin, dtype=np.float64)
    l1, l2 = spec.link_lengths
    plane = np.asarray(spec.plane_size, dtype=np.float64) if not low else np.zeros(2)
    end, elbow = origin + l1 + l2, origin + l1
    return np.maximum(np.concatenate([end, elbow, plane]), 0.0)


def register_all() -> list[str]:
    """Register every task of :data:`apac_mj.suite.ALL_TASKS` (idempotent); returns the ids."""
    ids = []
    for _, task_name in suite.ALL_TASKS:
        ids.append(env_id(task_name))
        if ids[-1] not in gymnasium.registry:
            gymnasium.register(id=ids[-1], entry_point="apac_mj.suite.gym:PlanarArmEnv",
                               max_episode_steps=suite.load_spec(task_name).steps_per_episode,
                               kwargs={"task_name": task_name})
    return ids


ENV_IDS = register_all()

__all__ = ["ACTIONS", "ENV_IDS", "OBSERVATIONS", "PlanarArmEnv", "env_id", "observation_bound_cm", "register_all"]
