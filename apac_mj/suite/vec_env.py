"""VecEnv: E ``suite`` environments side by side, one per seed, with exact save/restore.

Member ``k`` is the task's environment seeded ``seeds[k]`` (what ``suite.load(task, task_kwargs={"random":
seeds[k], ...})`` builds), all from one resolved :class:`TaskSpec`; members share nothing. :meth:`VecEnv.step` and :meth:`VecEnv.reset` touch only
the members in a mask, so members run free (each its own episode sequence).
:meth:`VecEnv.get_state` captures everything needed to continue bit-exactly
mid-episode: MuJoCo's integration state (``mj_getState`` with
``mjSTATE_INTEGRATION``: positions, velocities, servo set-points, time,
warm-start), the model fields changed at run time (link lengths, target,
origin, zone radius), the task's state (episode, lengths, static target,
RandomState, the current step's view: seen flag and observation noise) and
step count, and ``control.Environment``'s own step counter and reset flag. All of it is plain numbers, lists and tensors, so a checkpoint
holding it loads with ``torch.load(weights_only=True)``.
"""
from __future__ import annotations

import contextlib
import dataclasses
from typing import Any, Iterator, Sequence

import mujoco
import numpy as np
import torch
from dm_control.rl import control

from apac_mj import suite
from apac_mj.layout import Sizes
from apac_mj.suite import deliberation, planar_arm
from apac_mj.suite.task_spec import TaskSpec
from apac_mj.types import Observation

#: The observations every task has: the paper's positions and the vision flag.
_PAPER_OBSERVATIONS = ("end_effector", "elbow", "target", "vision")
#: The MuJoCo state captured for an exact resume.
_SIG = int(mujoco.mjtState.mjSTATE_INTEGRATION)


class VecEnv:
    """E environments of one task (one per seed), stepped under a member mask."""

    def __init__(self, task: str | TaskSpec, seeds: Sequence[int], actuation: str = "servo",
                 overrides: dict[str, Any] | None = None, episode_offset: int = 0) -> None:
        """``task``: a resolved :class:`TaskSpec` (built once by the caller), or a task name (read here), with
        ``overrides`` (TaskSpec fields) applied. ``episode_offset``: the episodes each member runs before its
        episode 0 (a run's motor babbling): its count starts at ``-episode_offset``, so changing kinematics
        (``growth_start_episode``) and the plant's schedule count from episode 0 (:meth:`episode`)."""
        seeds = [int(s) for s in seeds]
        if not seeds:
            raise ValueError("VecEnv needs at least one seed")
        if len(set(seeds)) != len(seeds):
            raise ValueError(f"seeds must be distinct, got {seeds}")
        if isinstance(episode_offset, bool) or not isinstance(episode_offset, int) or episode_offset < 0:
            raise ValueError(f"episode_offset must be an int >= 0, got {episode_offset!r}")
        spec = suite.load_spec(task) if isinstance(task, str) else task
        spec = spec.replace(**overrides) if overrides else spec
        if episode_offset:  # the environment counts every reset: its schedule moves by the offset, here only
            spec = spec.replace(growth_start_episode=spec.growth_start_episode + episode_offset,
                                **({"plant": spec.plant.shifted(episode_offset)} if spec.plant.dynamic else {}),
                                **({"cues": dataclasses.replace(spec.cues, remap_episode=spec.cues.remap_episode
                                                                + episode_offset)}
                                   if spec.cued and spec.cues.remap_episode is not None else {}),
                                **({"trials": spec.trials.shifted(episode_offset)} if spec.trials is not None else {}))
        self.seeds, self.actuation, self.episode_offset = seeds, actuation, episode_offset
        self.envs = [planar_arm.make_environment(spec, actuation=actuation, random=s) for s in seeds]
        self.E = len(seeds)
        #: The task as the environments run it (the offset applied).
        self.spec: TaskSpec = spec
        #: Names of the observed arrays beyond the paper's positions and vision flag (e.g. joint_velocities),
        #: in the observation's order, and their latest values ``[E, n]`` (read like ``obs``; not part of
        #: :meth:`get_state`: a step or reset writes them before they are read).
        obs_spec = self.envs[0].observation_spec()
        self.extra_names = [k for k in obs_spec if k not in _PAPER_OBSERVATIONS]
        self.extra = np.zeros((self.E, sum(int(np.prod(obs_spec[k].shape)) for k in self.extra_names)))
        #: The agent's sizes, read from the environments' dm_env specs.
        self.sizes = Sizes.from_specs(obs_spec, self.envs[0].action_spec())
        self.obs = Observation(arm=np.zeros((self.E, 4)), target=np.zeros((self.E, 2)),
                               vision=np.zeros(self.E, dtype=bool), reward=np.zeros(self.E),
                               last=np.zeros(self.E, dtype=bool), reached=np.zeros(self.E, dtype=bool))

    @property
    def task(self) -> str:
        """The task's name."""
        return self.spec.name

    # -- stepping -----------------------------------------------------------------
    def _mask(self, mask: Sequence[bool] | np.ndarray | None) -> np.ndarray:
        m = np.ones(self.E, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
        if m.shape != (self.E,):
            raise ValueError(f"mask must have shape ({self.E},), got {m.shape}")
        return m

    def _record(self, k: int, ts) -> None:
        o = ts.observation
        self.obs.arm[k, :2], self.obs.arm[k, 2:] = o["end_effector"], o["elbow"]
        self.obs.target[k] = o["target"]
        self.obs.vision[k] = bool(o["vision"][0] > 0.5)
        self.obs.reward[k] = 0.0 if ts.reward is None else ts.reward
        self.obs.last[k] = ts.last()
        self.obs.reached[k] = ts.last() and ts.discount == 0.0
        if self.extra_names:
            self.extra[k] = np.concatenate([np.ravel(o[name]) for name in self.extra_names])

    def reset(self, mask: Sequence[bool] | np.ndarray | None = None) -> Observation:
        """Start a new episode for the members in ``mask`` (all if None)."""
        for k in np.flatnonzero(self._mask(mask)):
            self._record(k, self.envs[k].reset())
        return self.obs

    def step(self, actions: np.ndarray, mask: Sequence[bool] | np.ndarray | None = None) -> Observation:
        """Apply ``actions`` ``[E, 2]`` (degrees) to the members in ``mask``; the others stay still."""
        actions = np.asarray(actions, dtype=np.float64)
        if actions.shape != (self.E, 2):
            raise ValueError(f"actions must have shape ({self.E}, 2), got {actions.shape}")
        for k in np.flatnonzero(self._mask(mask)):
            if episode_ended(self.envs[k]):
                raise RuntimeError(f"member {k} (seed {self.seeds[k]}) stepped after its episode ended; "
                                   "reset it first")
            self._record(k, self.envs[k].step(actions[k]))
        return self.obs

    # -- run-time controls and true state (for metrics, evaluation and recordings) ---
    def physics(self, k: int):
        return self.envs[k].physics

    def reach_task(self, k: int):
        return self.envs[k].task

    def episode(self, k: int) -> int:
        """Member ``k``'s current episode, counted from its first episode after the offset (babbling negative)."""
        return self.envs[k].task.episode - self.episode_offset

    def set_target_override(self, targets: np.ndarray | None, mask: Sequence[bool] | np.ndarray | None = None) -> None:
        """Targets ``[E, 2]`` for the next episodes of the members in ``mask`` (None: sample again)."""
        for k in np.flatnonzero(self._mask(mask)):
            self.envs[k].task.set_target_override(None if targets is None else targets[k])

    def set_cue_override(self, cues: Sequence[int] | np.ndarray | None, mask: Sequence[bool] | np.ndarray | None = None) -> None:
        """Cues ``[E]`` shown in the next episodes of the members in ``mask`` (None: drawn again); a cued task."""
        for k in np.flatnonzero(self._mask(mask)):
            self.envs[k].task.set_cue_override(None if cues is None else int(cues[k]))

    def set_mapping_override(self, remapped: bool | None) -> None:
        """Every member's cue mapping from its next episode: original (False), swapped (True), or the task's
        schedule (None)."""
        for env in self.envs:
            env.task.set_mapping_override(remapped)

    @contextlib.contextmanager
    def overridden(self, cue: int | None = None, remapped: bool | None = None) -> Iterator["VecEnv"]:
        """Within the block, every member's next episodes show ``cue`` (None: drawn) under the ``remapped``
        mapping (None: the task's schedule); both overrides are cleared on leaving, also on an error."""
        try:
            if remapped is not None:
                self.set_mapping_override(remapped)
            if cue is not None:
                self.set_cue_override(np.full(self.E, cue))
            yield self
        finally:
            self.set_cue_override(None)
            self.set_mapping_override(None)

    def trial_record(self, k: int) -> dict[str, Any]:
        """Member ``k``'s trial this episode as metrics columns (``suite.trials.TRIAL_COLUMNS``; {} without a
        ``[trials]`` table)."""
        trials = self.envs[k].task.trials
        return {} if trials is None else trials.record()

    def trial_view(self, k: int) -> dict[str, Any] | None:
        """Member ``k``'s trial as a recording shows it (``suite.trials.TrialRunner.view``; None without a table)."""
        trials = self.envs[k].task.trials
        return None if trials is None else trials.view()

    def cues(self) -> np.ndarray:
        """``[E]`` each member's cue this episode (-1: not a cued task)."""
        return np.array([env.task.cue for env in self.envs])

    def set_link_lengths(self, lengths: np.ndarray) -> None:
        """Link lengths ``[E, 2]`` used from each member's next reset on."""
        for k in range(self.E):
            self.envs[k].task.set_link_lengths(float(lengths[k, 0]), float(lengths[k, 1]))

    def snapshot(self) -> dict[str, np.ndarray]:
        """All true-state queries below in one pass over the members (the per-step record)."""
        arm, target, dist = np.empty((self.E, 4)), np.empty((self.E, 2)), np.empty(self.E)
        angles, lengths = np.empty((self.E, 2)), np.empty((self.E, 2))
        for k, e in enumerate(self.envs):
            p = e.physics
            arm[k, :2], arm[k, 2:], target[k] = p.end_effector(), p.elbow(), p.target()
            dist[k], angles[k], lengths[k] = p.distance_to_target(), p.joint_angles(), p.link_lengths()
        return {"true_arm": arm, "target": target, "distance": dist, "joint_angles": angles, "link_lengths": lengths}

    def true_arm(self) -> np.ndarray:
        """``[E, 4]`` the arm as MuJoCo has it: [end_x, end_y, elbow_x, elbow_y]."""
        return np.stack([np.concatenate([e.physics.end_effector(), e.physics.elbow()]) for e in self.envs])

    def targets(self) -> np.ndarray:
        return np.stack([e.physics.target() for e in self.envs])

    def distances(self) -> np.ndarray:
        return np.array([e.physics.distance_to_target() for e in self.envs])

    def stopped(self, stop_speed: float) -> np.ndarray:
        """``[E]`` every joint of each member at most ``stop_speed`` deg/s, as observed (the stop criterion's
        speed part: ``planar_arm.stopped``)."""
        return np.array([planar_arm.stopped(e.physics, stop_speed) for e in self.envs], dtype=bool)

    def in_time(self) -> np.ndarray:
        """``[E]`` each member's plant time within its task's deadline (``[deliberation]``; no table: all True)."""
        return np.array([deliberation.in_time(self.spec, e.physics) for e in self.envs], dtype=bool)

    def joint_angles(self) -> np.ndarray:
        return np.stack([e.physics.joint_angles() for e in self.envs])

    def link_lengths(self) -> np.ndarray:
        """``[E, 2]`` the lengths the physics has now (they grow under changing kinematics)."""
        return np.stack([e.physics.link_lengths() for e in self.envs])

    # -- exact save / restore ----------------------------------------------------------
    def get_state(self) -> dict[str, Any]:
        """Everything that evolves, as tensors and lists (``weights_only``-safe)."""
        return {"seeds": list(self.seeds), "members": [_member_state(e) for e in self.envs],
                "obs": {f.name: torch.from_numpy(getattr(self.obs, f.name).copy())
                        for f in dataclasses.fields(Observation)}}

    def set_state(self, state: dict[str, Any]) -> None:
        if list(state["seeds"]) != self.seeds:
            raise ValueError(f"environment state is for seeds {list(state['seeds'])}, this VecEnv has {self.seeds}")
        for env, s in zip(self.envs, state["members"]):
            _set_member_state(env, s)
        for name, t in state["obs"].items():
            getattr(self.obs, name)[...] = t.numpy()


def _member_state(env) -> dict[str, Any]:
    p, task = env.physics, env.task
    ts = task.get_state()
    kind, keys, pos, has_gauss, gauss = ts["random"]
    return {
        "mj_state": torch.from_numpy(p.get_state(sig=_SIG).copy()),
        "link_lengths": torch.from_numpy(p.link_lengths()), "target": torch.from_numpy(p.target()),
        "origin": torch.from_numpy(p.origin()), "zone_radius": float(p.model.site_size[p.ids.zone_site, 0]),
        "task": {"episode": int(ts["episode"]), "lengths": torch.from_numpy(ts["lengths"].copy()),
                 "static_target": None if ts["static_target"] is None else torch.from_numpy(ts["static_target"]),
                 "random": [str(kind), torch.from_numpy(keys.astype(np.int64)), int(pos), int(has_gauss),
                            float(gauss)],
                 "target_override": None if task._target_override is None
                 else torch.from_numpy(task._target_override.copy()),
                 "step_count": int(task.step_count), "seen": bool(ts["seen"]),
                 "noise": None if ts["noise"] is None else torch.from_numpy(ts["noise"].copy()),
                 "cue": int(ts["cue"]), "cue_override": ts["cue_override"], "mapping_override": ts["mapping_override"],
                 **({"senses": _tensors(ts["senses"])} if ts.get("senses") is not None else {}),
                 **({"trials": ts["trials"]} if ts.get("trials") is not None else {})},
        **_environment_counters(env),
    }


def _tensors(d: dict[str, Any]) -> dict[str, Any]:
    """A task's ``[signals]`` state (:class:`~apac_mj.suite.signals.Senses`) with its arrays as tensors."""
    return {k: torch.from_numpy(v.copy()) if isinstance(v, np.ndarray) else v for k, v in d.items()}


def _arrays(d: dict[str, Any]) -> dict[str, Any]:
    """:func:`_tensors` undone."""
    return {k: v.numpy().astype(np.float64) if isinstance(v, torch.Tensor) else v for k, v in d.items()}


def _set_member_state(env, s: dict[str, Any]) -> None:
    p, task, t = env.physics, env.task, s["task"]
    kind, keys, pos, has_gauss, gauss = t["random"]
    task.set_state({"episode": t["episode"], "lengths": t["lengths"].numpy().astype(np.float64),
                    "static_target": None if t["static_target"] is None else t["static_target"].numpy(),
                    "random": (kind, keys.numpy().astype(np.uint32), pos, has_gauss, gauss),
                    "seen": t.get("seen", True),
                    "noise": None if t.get("noise") is None else t["noise"].numpy(),
                    "cue": t.get("cue", -1), "cue_override": t.get("cue_override"),
                    "mapping_override": t.get("mapping_override"),
                    "senses": None if t.get("senses") is None else _arrays(t["senses"]),
                    "trials": t.get("trials")})
    task.set_target_override(None if t["target_override"] is None else t["target_override"].numpy())
    task.step_count = int(t["step_count"])
    p.plane_size = task.spec.plane_size
    p.set_origin(s["origin"].numpy())
    p.set_zone_radius(float(s["zone_radius"]))
    p.set_joint_limits(task.spec.at_limit == "clip", task.spec.joint_range)
    task.apply_episode_plant(p)
    p.set_link_lengths(*(float(v) for v in s["link_lengths"]))
    p.set_target(s["target"].numpy())
    p.set_state(s["mj_state"].numpy(), sig=_SIG)
    mujoco.mj_forward(p.model.ptr, p.data.ptr)
    _set_environment_counters(env, s)


# -- dm_control's control.Environment keeps its step counter and reset flag in private attributes (dm_control
# 1.0.50: ``_step_count``, ``_reset_next_step``); these three functions are the only readers and writers, and
# tests/test_suite.py pins them.
def episode_ended(env: control.Environment) -> bool:
    """The environment's episode ended: its next ``step`` would reset it (dm_control's ``_reset_next_step``)."""
    return bool(env._reset_next_step)


def _environment_counters(env: control.Environment) -> dict[str, Any]:
    return {"env_step_count": int(env._step_count), "reset_next_step": bool(env._reset_next_step)}


def _set_environment_counters(env: control.Environment, s: dict[str, Any]) -> None:
    env._step_count = int(s["env_step_count"])
    env._reset_next_step = bool(s["reset_next_step"])
