"""Rollouts of a trained run's (or untrained) networks into a Rerun recording and a video.

:func:`record` is what ``apac-mj record`` and ``apac-mj demo`` call: it loads
the agent (a run's latest checkpoint, or fresh networks), continues the run's
environments where training left off (or builds fresh ones), rolls out frozen
episodes with :class:`apac_mj.run.rollout.EpisodeLoop` and logs one member through
:class:`apac_mj.recording.recording.EpisodeRecorder`.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Callable

import numpy as np

from apac_mj import kinds
from apac_mj.agent.agent import Agent
from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.kinematics import Geometry
from apac_mj.recording.recording import RENDER, EpisodeRecorder, read_recording
from apac_mj.run.build import environments, episode_loop, load_run, make_agent
from apac_mj.run.rollout import FunctionHook, Hook
from apac_mj.run.run_dir import RunDir, config_dict, say
from apac_mj.suite import spec_for
from apac_mj.suite.render import write_video
from apac_mj.suite.vec_env import VecEnv
from apac_mj.types import StepInfo
from apac_mj.util.progress import progress_iter


@dataclasses.dataclass(frozen=True)
class Recorded:
    """What :func:`record` wrote."""

    rrd: Path
    #: Render frames in the recording.
    frames: int
    video: Path | None = None
    video_frames: int = 0


def record(out: str | Path, run: str | Path | None = None, task: str | None = None, agent: str | None = None,
           seed: int = 0, member: int = 0, episodes: int = 5, as_episode: int | None = None,
           video: str | Path | None = None, fps: int = 5, progress: bool = True, overwrite: bool = True) -> Recorded:
    """Roll out ``episodes`` frozen episodes (no noise, no learning) and save member ``member`` to ``out``.

    With ``run`` the networks are the run's latest checkpoint and the rollouts continue its environments
    (unless ``task`` names another task); without it the networks are untrained and seeded from ``seed``.
    ``agent`` re-arbitrates the networks as another kind; ``as_episode`` is the training episode the
    arbitrator sees first (default: the run's trained episodes, or ``planning_episodes``). ``overwrite=False``
    refuses an existing ``out`` or ``video`` (:class:`FileExistsError`) before anything is rolled out.
    """
    out, video = Path(out), None if video is None else Path(video)
    _check(out, run, video, episodes, fps, seed, member)
    if not overwrite:
        check_new(out, video)
    cfg, net, env, first, running = load_agent(run, task, agent, seed, member, as_episode)
    member = member if run is not None else 0
    with EpisodeRecorder(out.parent, 1, config_dict(cfg), member=member, out=out,
                         keep_frames=video is not None) as recorder:
        frozen_episodes(cfg, net, env, running, first, episodes, recorder, progress)
    if video is not None:
        write_video(video, recorder.frames, fps=fps)
    return Recorded(out, _frames(out), video, len(recorder.frames) if video is not None else 0)


@dataclasses.dataclass(frozen=True)
class Preview:
    """What :func:`record` would roll out from a run, for every member (``[E, episodes]`` each)."""

    #: The episode ended inside the target zone.
    reached: np.ndarray
    #: Steps the episode took (a recording shows one frame per step and one per episode start).
    steps: np.ndarray


def preview(run: str | Path, episodes: int, as_episode: int | None = None,
            until_steps: int | None = None) -> Preview:
    """The frozen episodes :func:`record` would roll out from ``run``, for every member at once (the
    rollouts are deterministic: no noise, no learning, the run's environments where training left off);
    ``until_steps``: stop early once every member's episodes so far took that many steps (the arrays then
    hold the episodes rolled out). Nothing is written."""
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    cfg, net, env, first, running = load_agent(run, None, None, 0, 0, as_episode)
    reached = np.zeros((env.E, episodes), dtype=bool)
    steps = np.zeros((env.E, episodes), dtype=int)

    def on_step(info: StepInfo, _: VecEnv) -> None:
        reached[:, k] |= info.active & info.done & info.reached
        steps[:, k] += info.active

    def on_episode_start(members: np.ndarray, _: VecEnv) -> None:
        nonlocal k
        k += 1

    def enough(done: int) -> bool:
        return until_steps is not None and steps[:, :done].sum(axis=1).min() >= until_steps

    k = -1
    frozen_episodes(cfg, net, env, running, first, episodes, FunctionHook(on_step, on_episode_start), False,
                    until=enough)
    return Preview(reached[:, :k + 1], steps[:, :k + 1])


def reached_targets(run: str | Path, episodes: int, as_episode: int | None = None) -> np.ndarray:
    """``[E, episodes]`` bool: which of the frozen episodes :func:`record` would roll out from ``run`` end
    inside the target zone (:func:`preview`'s ``reached``)."""
    return preview(run, episodes, as_episode).reached


def episodes_for_steps(steps: np.ndarray, min_steps: int) -> int:
    """The fewest leading episodes (of one member's ``steps``) that together take ``min_steps`` steps;
    all of them when they take fewer."""
    if min_steps < 1:
        raise ValueError(f"min_steps must be >= 1, got {min_steps}")
    total = np.cumsum(steps)
    return int(min(np.searchsorted(total, min_steps) + 1, len(steps)))


def frozen_episodes(cfg: TrainConfig, net: Agent, env: VecEnv, running: dict[str, Any], first: int, episodes: int,
                    hook: Hook, progress: bool, until: Callable[[int], bool] | None = None) -> None:
    """Roll out ``episodes`` frozen episodes of every member (no noise, no learning), the arbitrator seeing
    training episodes ``first``, ``first + 1``, ...; ``hook`` (a :class:`apac_mj.run.rollout.Hook`) sees them;
    ``until(n)``: stop early once it is true after ``n`` episodes."""
    loop = episode_loop(net, env, hooks=[hook], adapt=False)
    loop.load_state_dict(running)
    for k in progress_iter(range(episodes), episodes, "record", "episode", enabled=progress):
        loop.run_episode(np.ones(env.E, dtype=bool), first + k)
        if until is not None and until(k + 1):
            return


def showcase_member(reached: np.ndarray) -> int:
    """The member to show a new user: most targets reached, then the first episode reached (a recording
    opens on it), then the lowest index."""
    return int(min(range(len(reached)), key=lambda m: (-int(reached[m].sum()), not reached[m, 0], m)))


def _check(out: Path, run: str | Path | None, video: Path | None, episodes: int, fps: int, seed: int,
           member: int) -> None:
    if episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {episodes}")
    if out.suffix != ".rrd":
        raise ValueError(f"--out must end in .rrd, got {str(out)!r}")
    if video is not None and video.suffix.lower() not in (".mp4", ".gif"):
        raise ValueError(f"--video must end in .mp4 or .gif, got {str(video)!r}")
    if fps < 1:
        raise ValueError(f"--fps must be >= 1, got {fps}")
    if seed < 0 or member < 0:
        raise ValueError("--seed and --member must be >= 0")
    if run is not None and (problem := RunDir(run).problem()) is not None:
        raise FileNotFoundError(f"--run: {problem}")


def check_new(out: Path, video: Path | None) -> None:
    """``out`` and ``video`` do not exist yet; else a FileExistsError naming the file and the way out."""
    for path, option in ((out, "--out"), (video, "--video")):
        if path is not None and path.exists():
            raise FileExistsError(f"{path} exists; choose another {option}, or pass --force to replace it "
                                  "(nothing was written)")


def load_agent(run: str | Path | None, task: str | None, agent: str | None, seed: int, member: int,
               as_episode: int | None) -> tuple[TrainConfig, Agent, VecEnv, int, dict[str, Any]]:
    """(config, agent, environments, first arbitrator episode, the arbitrator's and the integrator's running
    statistics): from a run's newest checkpoint (on the CPU in fp32) in the run's environments where training
    left off (fresh ones seeded from ``seed`` when ``task`` names another task), or fresh networks seeded from
    ``seed`` in fresh environments."""
    if run is None:
        cfg = TrainConfig(task=task or "changing_target", seeds=(seed,), agent=AgentConfig(kind=agent or kinds.DEFAULT))
        spec = spec_for(cfg)
        env = environments(cfg, spec, training=False)
        net = make_agent(cfg, spec, env.sizes)
        return cfg, net, env, cfg.agent.planning_episodes if as_episode is None else as_episode, {}
    cfg = RunDir(run).train_config()
    if member >= len(cfg.seeds):
        raise ValueError(f"--member {member} out of range: the run has {len(cfg.seeds)} seeds {list(cfg.seeds)}")
    trained_kind = cfg.agent.kind
    _say_overrides(run, task, agent, seed, cfg)
    other_task = task not in (None, cfg.task)
    env = None
    if other_task:  # fresh environments of that task, seeded from --seed
        cfg = dataclasses.replace(cfg, task=task)
        env = environments(cfg, spec_for(cfg), seeds=[seed + k for k in range(len(cfg.seeds))], training=False)
    loaded = load_run(run, device="cpu", precision="fp32", env=env)
    if not other_task:  # the run's environments where training left off: lengths, targets, sequence
        loaded.env.set_state(loaded.ckpt.env)
    if agent is not None:  # the loop's arbitrator and planner are the agent's kind's (run.build.episode_loop)
        cfg = dataclasses.replace(cfg, agent=dataclasses.replace(cfg.agent, kind=kinds.get(agent).name))
        loaded.agent.cfg = dataclasses.replace(loaded.agent.cfg, kind=cfg.agent.kind)
    running = loaded.ckpt.running_statistics()
    if agent not in (None, trained_kind):
        running.pop("arbitrator", None)  # re-arbitrated as another kind: its own rule starts fresh
    first = max(loaded.ckpt.member_episode(member), 0) if as_episode is None else as_episode
    return cfg, loaded.agent, loaded.env, first, running


def _say_overrides(run: str | Path, task: str | None, agent: str | None, seed: int, cfg: TrainConfig) -> None:
    """With a run, an agent kind or task other than the run's is allowed but said."""
    if agent not in (None, cfg.agent.kind):
        trained, other = kinds.get(cfg.agent.kind), kinds.get(agent)
        planner = "" if other.planner == trained.planner else (
            f", planning with its {other.planner} planner through the run's forward model"
            if other.planner == "mpc" else f", planning with its {other.planner} planner")
        say(f"note: {run} trained {cfg.agent.kind}; recording its networks arbitrated as {agent} "
            f"(--agent {agent}){planner}")
    if task not in (None, cfg.task):
        trained = Geometry.from_spec(spec_for(cfg))
        other = Geometry.from_spec(spec_for(dataclasses.replace(cfg, task=task)))
        if other != trained:
            raise ValueError(f"--task {task}: its arm geometry (plane {other.plane_size}, shoulder {other.origin}, "
                             f"joint range {other.joint_range}) differs from the one {run} was trained on "
                             f"({cfg.task}: plane {trained.plane_size}, shoulder {trained.origin}, joint range "
                             f"{trained.joint_range}); the networks read positions and command angles in the "
                             "trained frame, so their actions there mean nothing. Record on a task with the "
                             "trained plane, shoulder and joint range, or train on this one")
        say(f"note: {run} trained on {cfg.task}; recording on {task} (--task) with fresh environments "
            f"seeded from --seed {seed}, not the run's")


def _frames(path: Path) -> int:
    entities, _, _ = read_recording(path)
    return len(entities[RENDER].times["frame"])
