"""The training loop (Algorithm 2's loops): babbling, episodes, metrics, checkpoints, resume.

Read top to bottom: :func:`train` builds the environments and the agent,
restores the last checkpoint if the run directory has one, then runs the
batched loop until every member finished ``cfg.episodes`` training episodes.

* Members run free: each member runs its own episode sequence; a member whose
  episode ended resets and continues; finished members are masked out (no
  environment step, no update).
* Motor babbling: the first ``cfg.agent.babbling_episodes`` episodes of every
  member take uniform random actions in ``±babbling_scale`` degrees. Each
  transition is stored with the target replaced by the reached end position
  (so it is terminal with the maximum reward, 0) and the agent is updated
  after every babbling step as after every training step. Babbling episodes
  have negative indices in the metrics (``phase="babbling"``) and see the arm.
* After every environment step: store ``(s_t, a_t, r_t, s_{t+1}, terminal)``
  for the stepping members, then one ``agent.update(active)``. The
  arbitrator's ``delta`` for the next step is this transition's TD error.
* The stored ``a_t`` is the *executed* action: the joint-angle change the
  plant actually made (Algorithm 2: "the actual action that transferred the
  plant from X_t to X_{t+1}"). A command beyond a joint limit is clamped by
  the plant; storing the command instead teaches the inverse model that
  saturated commands (e.g. (-180, +180) at the start pose (0, 180)) move
  nothing, a fixed point the paper-sized networks fall into and never leave.
* Occluded vision during training: the integrator uses the forward model's
  prediction wherever ``vision`` is 0 and the agent learns from the reward of
  its own estimate (see :mod:`apac_mj.run.rollout`). The paper trains with
  perfect vision and tests occlusion afterwards (:mod:`apac_mj.run.evaluate`); the
  grid does the same.
* Changing kinematics start after ``growth_start_episode`` *training*
  episodes: the environment's threshold is shifted by the babbling count.

Checkpoints (every ``cfg.checkpoint_every`` training episodes of the slowest
member, and at the end; ``checkpoints/latest.pt`` and the one before it,
``previous.pt``, which a damaged ``latest.pt`` falls back to) hold the agent (networks, optimizer, replay, noise,
generators), the environments (:meth:`VecEnv.get_state`), the loop's per-member
counters and the babbling generators, so a resumed run's numbers equal an
uninterrupted run's. ``metrics.parquet`` is rewritten (atomically) just before
each checkpoint; on resume it is cut back to the checkpoint's row count. A
finished run resumed with a larger ``episodes`` (and otherwise the same
config) continues from its final checkpoint exactly as an uninterrupted run of
that length would have.
"""
from __future__ import annotations

import collections
import dataclasses
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
from tqdm.auto import tqdm

from apac_mj.agent import precision as precisions
from apac_mj.agent.agent import Agent
from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.kinds import arbitrator_for
from apac_mj.kinematics import Geometry
from apac_mj.run.rollout import EpisodeLoop, EpisodeState, Hook, OnEpisodeStart, OnStep, as_hooks
from apac_mj.run.checkpoint import CheckpointError
from apac_mj.run.run_dir import RunCheckpoint, RunDir, RunMismatch, diff, say, task_sizes, training_env, validate
from apac_mj.suite import spec_for
from apac_mj.types import StepInfo

#: Episodes (all seeds) in the progress bar's running success rate and habit share.
PROGRESS_WINDOW = 20
#: The agent's losses (``Agent.update``) in the order of the ``*_loss`` metric columns.
LOSS_NAMES = ("critic", "actor", "forward", "inverse")


# -- seeding: the only place random streams are derived ---------------------------------------
def babbling_generators(seeds: list[int]) -> list[torch.Generator]:
    """One generator per member for babbling actions (the agent derives its own from the same seeds)."""
    return [torch.Generator().manual_seed(int(np.random.SeedSequence([int(s), 0xBAB]).generate_state(1)[0]))
            for s in seeds]


# -- per-member loop state -----------------------------------------------------------------
@dataclasses.dataclass(kw_only=True)
class LoopState(EpisodeState):
    """The episode loop's per-member carry plus the trainer's counters; ``episode < 0`` is babbling."""

    episode: np.ndarray      # [E] current episode index (training episodes from 0, babbling negative)
    need_reset: np.ndarray   # [E] bool
    loss_sum: np.ndarray | None = None  # [E, 4] sums of this episode's losses (LOSS_NAMES order)
    loss_n: np.ndarray | None = None    # [E] updates counted in loss_sum
    checkpoints_done: int = 0

    def __post_init__(self) -> None:
        super().__post_init__()
        E = len(self.episode)
        self.loss_sum = np.zeros((E, len(LOSS_NAMES))) if self.loss_sum is None else self.loss_sum
        self.loss_n = np.zeros(E, dtype=np.int64) if self.loss_n is None else self.loss_n

    @classmethod
    def fresh(cls, E: int, babbling: int, device: torch.device, state_dim: int = 6) -> "LoopState":
        return cls(episode=np.full(E, -babbling, dtype=np.int64), need_reset=np.ones(E, dtype=bool),
                   **EpisodeState.fresh_fields(E, device, state_dim))

    def state_dict(self) -> dict[str, Any]:
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        return {k: (torch.from_numpy(v.copy()) if isinstance(v, np.ndarray) else
                    v.detach().cpu().clone() if isinstance(v, torch.Tensor) else v) for k, v in d.items()}

    @classmethod
    def from_state_dict(cls, d: dict[str, Any], device: torch.device) -> "LoopState":
        kw = {k: (v.numpy().copy() if isinstance(v, torch.Tensor) and k != "state" else v) for k, v in d.items()}
        kw["state"] = d["state"].to(device)
        return cls(**kw)

    def slowest(self) -> int:
        """Training episodes finished by the slowest member."""
        return int(max(0, self.episode.min()))


# -- the loop ----------------------------------------------------------------------------------
def train(cfg: TrainConfig, out_dir: str | Path, progress: bool = True, on_step: OnStep | None = None,
          on_episode_start: OnEpisodeStart | None = None, hooks: Sequence[Hook] = ()) -> Path:
    """Train ``cfg.seeds`` side by side on ``cfg.task``; write/resume/extend ``out_dir``; return it.

    ``hooks`` (then the plain ``on_step`` and ``on_episode_start`` functions) see every episode start
    and step. Everything is validated before anything is written: a refused or failed start leaves no
    files. Resuming, extending a finished run (same config, more episodes) and finding a run already
    finished are said on stderr, as is a fallback to an older checkpoint.
    """
    run = RunDir(out_dir)
    validate(cfg)  # before the directory (and its lock) exist
    with run.lock():  # one writer per run: another process writing it is refused, naming its PID
        return _train(cfg, run, progress, hooks, on_step, on_episode_start)


def _train(cfg: TrainConfig, run: RunDir, progress: bool, hooks: Sequence[Hook], on_step: OnStep | None,
           on_episode_start: OnEpisodeStart | None) -> Path:
    """:func:`train` as the run's one writer."""
    cfg = resolved_precision(cfg, run)
    config, run_episodes = run.prepare(cfg)
    if run_episodes == cfg.episodes and run.check_finished():
        say(f"{run.path} already finished {cfg.episodes} episodes; nothing to train "
            f"(a larger --episodes extends it)")
        return run.path
    seeds = list(cfg.seeds)
    env = training_env(cfg)
    agent = Agent(cfg.agent, seeds, device=cfg.device, precision=cfg.precision,
                  geometry=Geometry.from_spec(spec_for(cfg)), sizes=task_sizes(cfg))
    babble_gens = babbling_generators(seeds)
    episodes = EpisodeLoop(agent, arbitrator_for(cfg.agent), env, hooks=as_hooks(hooks, on_step, on_episode_start))
    loop, rows, saved_at = LoopState.fresh(len(seeds), cfg.agent.babbling_episodes, agent.device,
                                           agent.state_dim), [], None
    if run.checkpoint_files():
        loop, rows = _restore(run, config, episodes, babble_gens)
        saved_at = loop.slowest()
        _say_resume(run.path, loop, run_episodes, cfg.episodes)
    run.write_config(config, run_episodes)
    bar, window = _progress_bar(cfg, loop, rows, progress)
    saved = _Saved(saved_at)
    try:
        _loop(cfg, run, config, loop, rows, saved, episodes, babble_gens, bar, window)
        if saved.at != loop.slowest():  # not saved just now by the periodic checkpoint
            _save(run, config, loop, episodes, babble_gens, rows)
        run.mark_finished()
    except KeyboardInterrupt:
        bar.close()
        _say_interrupted(run.path, saved.at, cfg)
        raise
    except Exception:
        if run_episodes is None and saved.at is None:  # a new run that failed before its first checkpoint:
            run.discard_unstarted()                     # no config.json left to refuse the corrected command
        raise
    finally:
        bar.close()
    return run.path


def resolved_precision(cfg: TrainConfig, run: RunDir) -> TrainConfig:
    """``cfg`` with ``precision = "auto"`` resolved (:func:`apac_mj.agent.precision.resolve`), said on stderr:
    an existing run keeps the precision its config.json records (it continues as it started, on any
    machine); a new one gets what this machine's hardware supports. Other precisions pass unchanged."""
    if cfg.precision != "auto":
        return cfg
    if run.exists():
        stored = run.config().get("precision")
        if stored in ("fp32", "bf16"):
            say(f"precision {stored}: auto keeps the precision {run.path} was started with (config.json)")
            return dataclasses.replace(cfg, precision=stored)
    choice = precisions.resolve("auto", cfg.device)
    say(f"precision {choice.precision}: {choice.reason}")
    return dataclasses.replace(cfg, precision=choice.precision)


@dataclasses.dataclass
class _Saved:
    """Training episodes (of the slowest member) in the newest checkpoint of this call; None: none yet."""

    at: int | None


def _progress_bar(cfg: TrainConfig, loop: LoopState, rows: list[dict[str, Any]],
                  progress: bool) -> tuple[tqdm, collections.deque]:
    """The episode bar and its window of the last episodes' (success, habit, planning) of all seeds."""
    bar = tqdm(total=cfg.episodes, initial=min(loop.slowest(), cfg.episodes), disable=not progress,
               desc=f"{cfg.agent.kind} {cfg.task} x{len(cfg.seeds)}", unit="ep")
    window = collections.deque(((r["success"], r["habit_actions"], r["planning_actions"])
                                for r in rows if r["phase"] == "train"), maxlen=PROGRESS_WINDOW * len(cfg.seeds))
    _say_babbling(bar, loop, cfg.agent.babbling_episodes)
    return bar, window


def _say_babbling(bar: tqdm, loop: LoopState, babbling: int) -> None:
    """The bar's label while the slowest member is still in motor babbling (before training episode 0)."""
    if bar.disable:
        return
    first = int(loop.episode.min())
    label = f"motor babbling: episode {babbling + first + 1} of {babbling}"
    if first < 0 and bar.postfix != label:
        bar.set_postfix_str(label)
    elif str(bar.postfix or "").startswith("motor babbling"):
        bar.set_postfix_str("")


def _loop(cfg: TrainConfig, run: RunDir, config: dict[str, Any], loop: LoopState, rows: list[dict[str, Any]],
          saved: _Saved, episodes: EpisodeLoop, babble_gens: list[torch.Generator], bar: tqdm,
          window: collections.deque) -> None:
    """Episodes until every member finished ``cfg.episodes``, with the periodic checkpoints (``saved``)."""
    while (active := loop.episode < cfg.episodes).any():
        _start_episodes(loop, active, episodes)
        info = _step(cfg, loop, active, episodes, babble_gens)
        for row in _finish_episodes(loop, info, list(cfg.seeds)):
            rows.append(row)
            if row["phase"] == "train":
                window.append((row["success"], row["habit_actions"], row["planning_actions"]))
        _progress(bar, loop, cfg.episodes, window)
        _say_babbling(bar, loop, cfg.agent.babbling_episodes)
        if loop.slowest() // cfg.checkpoint_every > loop.checkpoints_done:
            loop.checkpoints_done = loop.slowest() // cfg.checkpoint_every
            _save(run, config, loop, episodes, babble_gens, rows)
            saved.at = loop.slowest()


def _say_resume(out_dir: Path, loop: LoopState, run_episodes: int | None, episodes: int) -> None:
    done = loop.slowest()
    if run_episodes is not None and run_episodes < episodes:
        say(f"extending {out_dir} from {run_episodes} to {episodes} episodes: resuming at episode {done}")
    else:
        say(f"resuming {out_dir} from its checkpoint: {done} of {episodes} episodes done (slowest seed)")


def _say_interrupted(out_dir: Path, saved_at: int | None, cfg: TrainConfig) -> None:
    if saved_at is None:
        say(f"interrupted: nothing saved yet in {out_dir} (the first checkpoint comes after "
            f"{cfg.checkpoint_every} episodes); the same command starts the run over")
    else:
        say(f"interrupted: {out_dir}/checkpoints/latest.pt holds the run after {saved_at} of {cfg.episodes} "
            f"episodes (the episodes since then are lost); run the same command again to resume from there")


def _start_episodes(loop: LoopState, active: np.ndarray, episodes: EpisodeLoop) -> None:
    """Reset the members whose episode ended: environment, state estimate, noise, counters."""
    starting = active & loop.need_reset
    if not starting.any():
        return
    episodes.start(loop, starting)
    loop.need_reset[starting] = False
    loop.loss_sum[starting], loop.loss_n[starting] = 0.0, 0


def _step(cfg: TrainConfig, loop: LoopState, active: np.ndarray, episodes: EpisodeLoop,
          babble_gens: list[torch.Generator]) -> StepInfo:
    """Act (arbitrated, or random while babbling), step, store, update once; advance the loop state."""
    agent, env = episodes.agent, episodes.env
    babbling = active & (loop.episode < 0)
    override = (lambda a, h: _babbling_action(agent.cfg, a, h, babbling, babble_gens)) if babbling.any() else None
    angles_before = env.joint_angles()
    info = episodes.act(loop, active, loop.episode, explore=True, override=override)
    s, s2, r, done = _transition(info, babbling)
    dev = agent.device
    if agent.sizes.angle_actions:
        executed = torch.as_tensor(info.joint_angles - angles_before, dtype=torch.float32, device=dev)
    else:  # torques: the plant applies the command as it is (select_action bounds it)
        executed = torch.as_tensor(info.action, dtype=torch.float32, device=dev)
    learned = executed if cfg.agent.critic_action == "executed" else torch.as_tensor(info.action, device=dev)
    agent.replay.add(torch.as_tensor(s, device=dev), learned, torch.as_tensor(r, device=dev),
                     torch.as_tensor(s2, device=dev), torch.as_tensor(done, device=dev), torch.as_tensor(active),
                     executed_action=executed)
    for _ in range(cfg.agent.updates_per_step):
        losses = agent.update(torch.as_tensor(active))
        values = torch.stack([losses[n] for n in LOSS_NAMES], dim=1).float().cpu().numpy()  # one transfer
        updated = np.isfinite(values).all(axis=1)
        loop.loss_sum[updated] += values[updated]
        loop.loss_n += updated
    episodes.advance(loop, info, active, counted=active & ~babbling, next_state=s2)
    return info


def _babbling_action(cfg: AgentConfig, action: torch.Tensor, habit: torch.Tensor, babbling: np.ndarray,
                     gens: list[torch.Generator]) -> tuple[torch.Tensor, torch.Tensor]:
    """Uniform actions in ``±cfg.babbling_scale`` (the agent's config: in the task's action units)."""
    scale = cfg.babbling_scale
    members = np.flatnonzero(babbling)
    draws = torch.stack([(torch.rand(action.shape[1], generator=gens[k]) * 2 - 1) * scale
                         for k in members])  # on the CPU
    action = action.clone()
    action[torch.as_tensor(members, device=action.device)] = draws.to(action.device)  # one transfer for all
    return action, habit & ~torch.as_tensor(babbling, device=habit.device)


def _transition(info: StepInfo, babbling: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(s, s2, r, terminal)`` to store; babbling: target := reached end position, r = 0, terminal.

    Babbling sees the arm, so its next state is MuJoCo's arm even under occluded vision.
    """
    s, s2 = info.state.copy(), info.next_state.copy()
    r, done = info.reward.copy(), info.terminal.astype(np.float32)
    b = babbling
    if b.any():
        reached_end = info.true_arm[b, :2]
        s[b, 4:6], s2[b, :4], s2[b, 4:6] = reached_end, info.true_arm[b], reached_end
        r[b], done[b] = 0.0, 1.0
    return s, s2, r, done


def _finish_episodes(loop: LoopState, info: StepInfo, seeds: list[int]) -> list[dict[str, Any]]:
    """Metric rows of the members whose episode ended at this step; mark them for reset."""
    rows = []
    for k in np.flatnonzero(info.active & info.done):
        ep = int(loop.episode[k])
        rows.append({"seed": seeds[k], "episode": ep, "phase": "babbling" if ep < 0 else "train",
                     "success": bool(info.reached[k]), "steps": int(loop.step[k]), "return": float(loop.ret[k]),
                     "final_distance": float(info.distance[k]), "habit_actions": int(loop.habit_n[k]),
                     "planning_actions": int(loop.plan_n[k]), "l1": float(info.link_lengths[k, 0]),
                     "l2": float(info.link_lengths[k, 1]), "target_x": float(info.target[k, 0]),
                     "target_y": float(info.target[k, 1]),
                     "estimate_error": float(loop.estimate_error_sum[k] / max(1, loop.step[k])),
                     **{f"{n}_loss": float(loop.loss_sum[k, i] / loop.loss_n[k]) if loop.loss_n[k] else float("nan")
                        for i, n in enumerate(LOSS_NAMES)}})
        loop.episode[k] += 1
        loop.need_reset[k] = True
    return rows


def _progress(bar: tqdm, loop: LoopState, episodes: int, window: collections.deque) -> None:
    done = min(loop.slowest(), episodes)
    if done > bar.n:
        bar.update(done - bar.n)
        if window:
            success = np.mean([w[0] for w in window])
            habit, plan = sum(w[1] for w in window), sum(w[2] for w in window)
            bar.set_postfix(success=f"{success:.2f}", habit=f"{habit / max(1, habit + plan):.2f}")


# -- checkpoints: save and restore ---------------------------------------------------------------
def _save(run: RunDir, config: dict[str, Any], loop: LoopState, episodes: EpisodeLoop,
          babble_gens: list[torch.Generator], rows: list[dict[str, Any]]) -> None:
    """metrics.parquet, then the checkpoint (the one before it kept) with the rows' digest and a copy of them."""
    table = run.write_metrics(rows)
    run.save_checkpoint(RunCheckpoint.with_metrics(RunCheckpoint.layout(
        config, loop.state_dict(), episodes.agent.state_dict(), episodes.env.get_state(), episodes.state_dict(),
        [g.get_state() for g in babble_gens], len(rows)), rows, table))


def _restore(run: RunDir, config: dict[str, Any], episodes: EpisodeLoop,
             babble_gens: list[torch.Generator]) -> tuple[LoopState, list[dict[str, Any]]]:
    """Load the newest intact checkpoint (warning when it is not latest.pt) into the agent and env."""
    restored: dict[str, Any] = {}

    def check(ckpt: RunCheckpoint) -> None:
        run.check_config(ckpt)  # an edited config.json: said as such (the checkpoint records what was trained)
        restored["loop"] = _apply(ckpt, config, episodes, babble_gens)
        restored["rows"] = run.read_metric_rows(ckpt)

    run.load_checkpoint(check=check)
    return restored["loop"], restored["rows"]


def _apply(ckpt: RunCheckpoint, config: dict[str, Any], episodes: EpisodeLoop,
           babble_gens: list[torch.Generator]) -> LoopState:
    """Put a loaded checkpoint into the agent, the environments and the generators (same config but
    the episode count, which an extended run changes)."""
    agent, env = episodes.agent, episodes.env
    changed = diff({**ckpt.config, "episodes": None}, {**config, "episodes": None}, "in the checkpoint")
    if changed:  # the run's files agree with it (RunDir.check_config): the settings asked for differ
        raise RunMismatch(f"checkpoint {ckpt.path} was trained with other settings than those asked for "
                          f"({'; '.join(changed)}): run with the run's settings, or use another --out")
    try:
        agent.load_state_dict(_to_device(ckpt.agent, agent.device))
        env.set_state(ckpt.env)
        for g, s in zip(babble_gens, ckpt.babbling_generators, strict=True):
            g.set_state(s)
        loop = LoopState.from_state_dict(ckpt.loop, agent.device)
        episodes.load_state_dict(ckpt.running_statistics())
    except (KeyError, ValueError, RuntimeError, TypeError, AttributeError) as e:
        raise CheckpointError(f"checkpoint {ckpt.path} is corrupt or incompatible: "
                              f"{type(e).__name__}: {e}") from None
    torch.set_rng_state(ckpt.torch_rng)
    return loop


def _to_device(obj: Any, device: torch.device) -> Any:
    """Move tensors (not generator states, which are CPU byte tensors) to ``device``."""
    if isinstance(obj, torch.Tensor):
        return obj if obj.dtype == torch.uint8 else obj.to(device)
    if isinstance(obj, dict):
        return {k: _to_device(v, device) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_to_device(v, device) for v in obj]
    return obj
