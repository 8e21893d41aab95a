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

from apac_mj.util.progress import progress_bar

from apac_mj.agent import precision as precisions
from apac_mj.config import PRECISIONS, AgentConfig, TrainConfig
from apac_mj.run.build import Run, build, check, task_record
from apac_mj.run.checkpoint import CheckpointError
from apac_mj.run.rollout import EpisodeLoop, EpisodeState, Hook, OnEpisodeStart, OnStep, as_hooks
from apac_mj.run.run_dir import RunCheckpoint, RunDir, RunMismatch, config_dict, diff, say
from apac_mj.suite.task_spec import TaskSpec
from apac_mj.types import ARM, END, LOSSES, TARGET, StepInfo
from apac_mj.util.threads import torch_threads

#: Episodes (all seeds) in the progress bar's running success rate and habit share.
PROGRESS_WINDOW = 20


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
    loss_sum: np.ndarray | None = None  # [E, L] sums of this episode's losses (``Agent.loss_names`` order)
    loss_n: np.ndarray | None = None    # [E] updates counted in loss_sum
    checkpoints_done: int = 0

    def __post_init__(self) -> None:
        super().__post_init__()
        E = len(self.episode)
        self.loss_sum = np.zeros((E, len(LOSSES))) if self.loss_sum is None else self.loss_sum
        self.loss_n = np.zeros(E, dtype=np.int64) if self.loss_n is None else self.loss_n

    @classmethod
    def fresh(cls, E: int, babbling: int, device: torch.device, state_dim: int = 6, losses: int = len(LOSSES),
              ) -> "LoopState":
        """Every member before its first episode; ``losses``: how many losses the agent reports."""
        return cls(episode=np.full(E, -babbling, dtype=np.int64), need_reset=np.ones(E, dtype=bool),
                   loss_sum=np.zeros((E, losses)), **EpisodeState.fresh_fields(E, device, state_dim))

    def state_dict(self) -> dict[str, Any]:
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        return {k: (torch.from_numpy(v.copy()) if isinstance(v, np.ndarray) else
                    v.detach().cpu().clone() if isinstance(v, torch.Tensor) else v) for k, v in d.items()}

    @classmethod
    def from_state_dict(cls, d: dict[str, Any], device: torch.device, losses: int = len(LOSSES)) -> "LoopState":
        """A saved carry; a checkpoint from before the dynamics model's loss was reported (``losses`` more than it
        kept) gets NaN for it until the episode in progress ends."""
        kw = {k: (v.numpy().copy() if isinstance(v, torch.Tensor) and k != "state" else v) for k, v in d.items()}
        kw["state"] = d["state"].to(device)
        kept = kw["loss_sum"]
        if kept.shape[1] < losses:
            kw["loss_sum"] = np.concatenate([kept, np.full((len(kept), losses - kept.shape[1]), np.nan)], 1)
        return cls(**kw)

    def slowest(self) -> int:
        """Training episodes finished by the slowest member."""
        return int(max(0, self.episode.min()))


# -- the loop ----------------------------------------------------------------------------------
def train(cfg: TrainConfig, out_dir: str | Path, progress: bool = True, on_step: OnStep | None = None,
          on_episode_start: OnEpisodeStart | None = None, hooks: Sequence[Hook] = (),
          threads: int | None = None) -> Path:
    """Train ``cfg.seeds`` side by side on ``cfg.task``; write/resume/extend ``out_dir``; return it.

    ``hooks`` (then the plain ``on_step`` and ``on_episode_start`` functions) see every episode start
    and step. Everything is validated before anything is written: a refused or failed start leaves no
    files. Resuming, extending a finished run (same config, more episodes) and finding a run already
    finished are said on stderr, as is a fallback to an older checkpoint. ``threads``: torch CPU threads
    while it trains (None: 1, as ``apac-mj train``; :mod:`apac_mj.util.threads` says why), the caller's
    count restored after.
    """
    run_dir = RunDir(out_dir)
    spec = check(cfg)  # before the directory (and its lock) exist; the one read of the task file
    with torch_threads(threads), run_dir.lock():  # one writer per run: another process is refused, naming its PID
        return Trainer(cfg, spec, run_dir, as_hooks(hooks, on_step, on_episode_start), progress).train()


class Trainer:
    """One call of :func:`train` as the run's one writer (TD-MPC2's ``OnlineTrainer``): the run's parts, built
    once (:func:`apac_mj.run.build.build`), and what the loop carries between its steps."""

    def __init__(self, cfg: TrainConfig, spec: TaskSpec, run_dir: RunDir, hooks: Sequence[Hook] = (),
                 progress: bool = True) -> None:
        #: The config with ``precision = "auto"`` resolved.
        self.cfg = resolved_precision(cfg, run_dir)
        self.spec, self.run_dir, self.hooks, self.progress = spec, run_dir, list(hooks), progress
        #: The config as config.json and every checkpoint hold it.
        self.config: dict[str, Any] = config_dict(self.cfg)
        #: The environments, agent and episode loop (built when training starts).
        self.run: Run | None = None
        #: The per-member carry and counters (:class:`LoopState`).
        self.state: LoopState | None = None
        #: One metric row per finished episode (metrics.parquet).
        self.rows: list[dict[str, Any]] = []
        #: One generator per member for the babbling actions.
        self.babbling_generators: list[torch.Generator] = []
        #: Training episodes (of the slowest member) in this call's newest checkpoint; None: none yet.
        self.saved_at: int | None = None
        self.bar: tqdm | None = None
        #: The last episodes' (success, habit, planning) of all seeds, for the bar.
        self.window: collections.deque = collections.deque()

    def train(self) -> Path:
        """Build the run, restore its checkpoint if it has one, train until every member finished."""
        cfg, run_dir = self.cfg, self.run_dir
        task = task_record(cfg, self.spec)
        _, run_episodes = run_dir.prepare(cfg, task)  # the same JSON form as self.config
        if run_episodes == cfg.episodes and run_dir.check_finished():
            say(f"{run_dir.path} already finished {cfg.episodes} episodes; nothing to train "
                f"(a larger --episodes extends it)")
            return run_dir.path
        self.run = build(cfg, self.spec, self.hooks)
        self.babbling_generators = babbling_generators(list(cfg.seeds))
        self.state = LoopState.fresh(len(cfg.seeds), cfg.agent.babbling_episodes, self.run.agent.device,
                                     self.run.agent.state_dim, len(self.run.agent.loss_names))
        if run_dir.checkpoint_files():
            self._restore()
            self.saved_at = self.state.slowest()
            _say_resume(run_dir.path, self.state, run_episodes, cfg.episodes)
        run_dir.write_config(self.config, run_episodes, task)
        self.bar, self.window = _progress_bar(cfg, self.state, self.rows, self.progress)
        try:
            self._loop()
            if self.saved_at != self.state.slowest():  # not saved just now by the periodic checkpoint
                self._save()
            run_dir.mark_finished()
        except KeyboardInterrupt:
            self.bar.close()
            _say_interrupted(run_dir.path, self.saved_at, cfg)
            raise
        except Exception:
            if run_episodes is None and self.saved_at is None:  # a new run that failed before its first checkpoint:
                run_dir.discard_unstarted()                     # no config.json left to refuse the corrected command
            raise
        finally:
            self.bar.close()
        return run_dir.path

    def _loop(self) -> None:
        """Episodes until every member finished ``cfg.episodes``, with the periodic checkpoints."""
        cfg, st = self.cfg, self.state
        while (active := st.episode < cfg.episodes).any():
            _start_episodes(st, active, self.run.loop)
            info = self._step(active)
            for row in _finish_episodes(st, info, list(cfg.seeds), self.run.agent.loss_names):
                self.rows.append(row)
                if row["phase"] == "train":
                    self.window.append((row["success"], row["habit_actions"], row["planning_actions"]))
            _progress(self.bar, st, cfg.episodes, self.window)
            _say_babbling(self.bar, st, cfg.agent.babbling_episodes)
            if st.slowest() // cfg.checkpoint_every > st.checkpoints_done:
                st.checkpoints_done = st.slowest() // cfg.checkpoint_every
                self._save()
                self.saved_at = st.slowest()

    def _step(self, active: np.ndarray) -> StepInfo:
        """Act (arbitrated, or random while babbling), step, store, update once; advance the loop state."""
        st, agent, episodes = self.state, self.run.agent, self.run.loop
        babbling = active & (st.episode < 0)
        override = (lambda a, h: _babbling_action(agent.cfg, a, h, babbling, self.babbling_generators)) \
            if babbling.any() else None
        angles_before = self.run.env.joint_angles()
        info = episodes.act(st, active, st.episode, explore=True, override=override)
        s, s2, r, done = _transition(info, babbling, sensed=self.spec.signals is not None)
        if executed_is_joint_change(self.cfg.agent, self.spec):
            executed = torch.as_tensor(info.joint_angles - angles_before, dtype=torch.float32, device=agent.device)
        elif agent.sizes.angle_actions:  # the set-point change the servos received (the plant clips it alike)
            executed = agent.executable(info.tensors.action, s)
        else:  # torques: the plant applies the command as it is (select_action bounds it)
            executed = info.tensors.action
        learned = executed if self.cfg.agent.critic_action == "executed" else info.tensors.action
        agent.replay.add(s, learned, r, s2, done, torch.as_tensor(active), executed_action=executed)
        lesioned = (st.episode >= self.cfg.agent.frozen_from_episode) if self.cfg.agent.frozen else None
        for _ in range(self.cfg.agent.updates_per_step):
            self._update(active, lesioned)
        episodes.advance(st, info, active, counted=active & ~babbling, next_state=s2)
        return info

    def _update(self, active: np.ndarray, lesioned: np.ndarray | None = None) -> None:
        """One update of the agent (``lesioned``: the members whose ``agent.frozen`` learners no longer learn);
        this episode's loss sums of the members it updated."""
        agent, active = self.run.agent, torch.as_tensor(active)
        losses = agent.update(active) if lesioned is None else agent.update(active, torch.as_tensor(lesioned))
        names = self.run.agent.loss_names
        values = torch.stack([losses[n] for n in names], dim=1).float().cpu().numpy()  # one transfer
        updated = np.isfinite(values).all(axis=1)
        self.state.loss_sum[updated] += values[updated]
        self.state.loss_n += updated

    # -- checkpoints: save and restore -----------------------------------------------------------
    def _save(self) -> None:
        """metrics.parquet, then the checkpoint (the one before it kept) with the rows' digest and a copy of them."""
        episodes, rows = self.run.loop, self.rows
        table = self.run_dir.write_metrics(rows)
        self.run_dir.save_checkpoint(RunCheckpoint.with_metrics(RunCheckpoint.layout(
            self.config, self.state.state_dict(), episodes.agent.state_dict(), episodes.env.get_state(),
            episodes.state_dict(), [g.get_state() for g in self.babbling_generators], len(rows)), rows, table))

    def _restore(self) -> None:
        """Load the newest intact checkpoint (warning when it is not latest.pt) into the agent, the environments,
        the generators and the loop state; the metric rows with it."""
        ckpt = self.run_dir.load_checkpoint(check=self._check_and_apply)
        self.rows = self.run_dir.read_metric_rows(ckpt)

    def _check_and_apply(self, ckpt: RunCheckpoint) -> None:
        """Put a loaded checkpoint into the run (a CheckpointError: try an older one). config.json must agree
        with it (an edited one: :class:`RunMismatch`), and so must the settings asked for (same config but the
        episode count, which an extended run changes)."""
        self.run_dir.check_config(ckpt)
        changed = diff({**ckpt.config, "episodes": None}, {**self.config, "episodes": None}, "in the checkpoint")
        if changed:  # the run's files agree with it (RunDir.check_config): the settings asked for differ
            raise RunMismatch(f"checkpoint {ckpt.path} was trained with other settings than those asked for "
                              f"({'; '.join(changed)}): run with the run's settings, or use another --out")
        agent, env = self.run.agent, self.run.env
        try:
            agent.load_state_dict(_to_device(ckpt.agent, agent.device))
            env.set_state(ckpt.env)
            for g, s in zip(self.babbling_generators, ckpt.babbling_generators, strict=True):
                g.set_state(s)
            self.state = LoopState.from_state_dict(ckpt.loop, agent.device, len(agent.loss_names))
            self.run.loop.load_state_dict(ckpt.running_statistics())
        except (KeyError, ValueError, RuntimeError, TypeError, AttributeError) as e:
            raise CheckpointError(f"checkpoint {ckpt.path} is corrupt or incompatible: "
                                  f"{type(e).__name__}: {e}") from None
        torch.set_rng_state(ckpt.torch_rng)


def resolved_precision(cfg: TrainConfig, run: RunDir) -> TrainConfig:
    """``cfg`` with ``precision = "auto"`` resolved (:func:`apac_mj.agent.precision.resolve`), said on stderr:
    an existing run keeps the precision its config.json records (it continues as it started, on any
    machine); a new one gets what this machine's hardware supports. Other precisions pass unchanged."""
    if cfg.precision != "auto":
        return cfg
    if run.exists():
        stored = run.config().get("precision")
        if stored in PRECISIONS:
            say(f"precision {stored}: auto keeps the precision {run.path} was started with (config.json)")
            return dataclasses.replace(cfg, precision=stored)
    choice = precisions.resolve("auto", cfg.device)
    say(f"precision {choice.precision}: {choice.reason}")
    return dataclasses.replace(cfg, precision=choice.precision)


def _progress_bar(cfg: TrainConfig, loop: LoopState, rows: list[dict[str, Any]],
                  progress: bool) -> tuple[tqdm, collections.deque]:
    """The episode bar and its window of the last episodes' (success, habit, planning) of all seeds."""
    bar = progress_bar(cfg.episodes, f"{cfg.agent.kind} {cfg.task} x{len(cfg.seeds)}", "ep",
                       initial=min(loop.slowest(), cfg.episodes), enabled=progress)  # plain lines off a terminal
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
    if first < 0:  # the label once per babbling episode (it was cleared and set again at every step)
        if bar.postfix != label:
            bar.set_postfix_str(label)
    elif str(bar.postfix or "").startswith("motor babbling"):
        bar.set_postfix_str("")


def _say_resume(out_dir: Path, loop: LoopState, run_episodes: int | None, episodes: int) -> None:
    done = loop.slowest()
    if run_episodes is not None and run_episodes < episodes:
        say(f"extending {out_dir} from {run_episodes} to {episodes} episodes: resuming at episode {done}; each seed's "
            f"episodes will equal a run of {episodes} from the start, but metrics.parquet lists them in the order "
            "they end, which differs from that run's (compare by seed and episode)")
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


def _transition(info: StepInfo, babbling: np.ndarray, sensed: bool = False
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(s, s2, r, terminal)`` to store, on the agent's device; babbling: target := reached end position, r = 0,
    terminal.

    Babbling sees the arm, so its next state is MuJoCo's arm even under occluded vision; ``sensed`` (a task with
    a ``[signals]`` table): the arm as the delayed, noisy signals delivered it, where vision showed it.
    """
    t = info.tensors
    s, s2, r, done = t.state.clone(), t.next_state.clone(), t.reward.clone(), t.terminal.float()
    if babbling.any():
        rows = torch.as_tensor(np.flatnonzero(babbling), device=s.device)
        arm = torch.as_tensor(info.true_arm[babbling], dtype=s.dtype, device=s.device)  # MuJoCo's, one transfer
        if sensed:  # what the senses delivered, where the arm was seen
            seen = torch.as_tensor(info.vision[babbling], device=s.device)[:, None]
            arm = torch.where(seen, s2[rows][:, ARM], arm)
        s[rows, TARGET], s2[rows, ARM], s2[rows, TARGET] = arm[:, END], arm, arm[:, END]
        r[rows], done[rows] = 0.0, 1.0
    return s, s2, r, done


def _finish_episodes(loop: LoopState, info: StepInfo, seeds: list[int],
                     names: Sequence[str] = LOSSES) -> list[dict[str, Any]]:
    """Metric rows of the members whose episode ended at this step (the losses ``names``, the agent's
    ``loss_names``); mark them for reset."""
    rows = []
    for k in np.flatnonzero(info.active & info.done):
        ep = int(loop.episode[k])
        rows.append({"seed": seeds[k], "episode": ep, "phase": "babbling" if ep < 0 else "train",
                     "success": bool(info.reached[k]), "return": float(loop.ret[k]),
                     "final_distance": float(info.distance[k]), "l1": float(info.link_lengths[k, 0]),
                     "l2": float(info.link_lengths[k, 1]), "target_x": float(info.target[k, 0]),
                     "target_y": float(info.target[k, 1]), **loop.summary(k),
                     **{f"{n}_loss": float(loop.loss_sum[k, i] / loop.loss_n[k]) if loop.loss_n[k] else float("nan")
                        for i, n in enumerate(names)}})
        loop.episode[k] += 1
        loop.need_reset[k] = True
    return rows


def _progress(bar: tqdm, loop: LoopState, episodes: int, window: collections.deque) -> None:
    done = min(loop.slowest(), episodes)
    if done > bar.n:
        if window:  # the postfix first: a plain line (off a terminal) is written by the update
            success = np.mean([w[0] for w in window])
            habit, plan = sum(w[1] for w in window), sum(w[2] for w in window)
            bar.set_postfix(success=f"{success:.2f}", habit=f"{habit / max(1, habit + plan):.2f}", refresh=False)
        bar.update(done - bar.n)


def _to_device(obj: Any, device: torch.device) -> Any:
    """Move tensors (not generator states, which are CPU byte tensors) to ``device``."""
    if isinstance(obj, torch.Tensor):
        return obj if obj.dtype == torch.uint8 else obj.to(device)
    if isinstance(obj, dict):
        return {k: _to_device(v, device) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_to_device(v, device) for v in obj]
    return obj


def executed_is_joint_change(agent: AgentConfig, spec: TaskSpec) -> bool:
    """The executed action is the arm's measured joint-angle change (``AgentConfig.executed_action``; "auto":
    on the ideal plant, whose servos reach every command within the step), else the command as received."""
    if agent.executed_action == "auto":
        return not spec.plant.dynamic
    return agent.executed_action == "joint_change"
