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
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch
from tqdm.auto import tqdm

from apac_mj.run import checkpoint
from apac_mj.agent.agent import Agent
from apac_mj.config import TrainConfig, migrate, task_spec, to_dict
from apac_mj.util.files import atomic_write_parquet
from apac_mj.kinds import arbitrator_for, check as check_kind
from apac_mj.kinematics import Geometry
from apac_mj.run.rollout import EpisodeLoop, EpisodeState, OnEpisodeStart, OnStep, running_statistics
from apac_mj.types import StepInfo
from apac_mj.suite.vec_env import VecEnv

#: Episodes (all seeds) in the progress bar's running success rate and habit share.
PROGRESS_WINDOW = 20
METRIC_COLUMNS = ("seed", "episode", "phase", "success", "steps", "return", "final_distance", "habit_actions",
                  "planning_actions", "l1", "l2", "target_x", "target_y", "critic_loss", "actor_loss",
                  "forward_loss", "inverse_loss", "estimate_error")
#: The agent's losses (``Agent.update``) in the order of the ``*_loss`` metric columns.
LOSS_NAMES = ("critic", "actor", "forward", "inverse")
CKPT_KEYS = ("config", "loop", "agent", "env", "babbling_generators", "metric_rows")


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
    def fresh(cls, E: int, babbling: int, device: torch.device) -> "LoopState":
        return cls(episode=np.full(E, -babbling, dtype=np.int64), need_reset=np.ones(E, dtype=bool),
                   **EpisodeState.fresh_fields(E, device))

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
          on_episode_start: OnEpisodeStart | None = None, record_every: int | None = None) -> Path:
    """Train ``cfg.seeds`` side by side on ``cfg.task``; write/resume/extend ``out_dir``; return it.

    Everything is validated before anything is written: a refused or failed start leaves no files.
    Resuming, extending a finished run (same config, more episodes) and finding a run already
    finished are said on stderr, as is a fallback to an older checkpoint.
    """
    out_dir = Path(out_dir)
    _check_record_every(record_every)
    config, run_episodes = _prepare_run_dir(cfg, out_dir)
    if run_episodes == cfg.episodes and _finished(out_dir):
        say(f"{out_dir} already finished {cfg.episodes} episodes; nothing to train "
            f"(a larger --episodes extends it)")
        return out_dir
    seeds = list(cfg.seeds)
    env = training_env(cfg)
    agent = Agent(cfg.agent, seeds, device=cfg.device, precision=cfg.precision,
                  geometry=Geometry.from_spec(task_spec(cfg)))
    babble_gens = babbling_generators(seeds)
    episodes = EpisodeLoop(agent, arbitrator_for(cfg.agent), env)
    loop, rows, saved_at = LoopState.fresh(len(seeds), cfg.agent.babbling_episodes, agent.device), [], None
    if checkpoint.run_checkpoints(out_dir / "checkpoints"):
        loop, rows = _restore(out_dir, config, episodes, babble_gens)
        saved_at = loop.slowest()
        _say_resume(out_dir, loop, run_episodes, cfg.episodes)
    _write_config(out_dir, config, run_episodes)
    recorder = _recorder(out_dir, record_every, config)
    episodes.on_step, episodes.on_episode_start = _chain_hooks(recorder, on_step, on_episode_start)
    bar, window = _progress_bar(cfg, loop, rows, progress)
    saved = _Saved(saved_at)
    try:
        _loop(cfg, out_dir, config, loop, rows, saved, episodes, babble_gens, bar, window)
        if saved.at != loop.slowest():  # not saved just now by the periodic checkpoint
            _save(out_dir, config, loop, episodes, babble_gens, rows)
        checkpoint.atomic_write_bytes(out_dir / "DONE", lambda f: f.write(b"done\n"))
    except KeyboardInterrupt:
        bar.close()
        _say_interrupted(out_dir, saved.at, cfg)
        raise
    finally:
        bar.close()
        if recorder is not None:
            recorder.close()
    return out_dir


def training_env(cfg: TrainConfig) -> VecEnv:
    """The run's environments as training builds them: changing kinematics start after
    ``growth_start_episode`` *training* episodes, so the environment's threshold (which counts every
    reset) is shifted by the babbling count here, and only here."""
    growth = task_spec(cfg).growth_start_episode + cfg.agent.babbling_episodes
    return VecEnv(cfg.task, list(cfg.seeds), cfg.actuation,
                  overrides={**cfg.task_overrides, "growth_start_episode": growth})


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
    return bar, window


def _loop(cfg: TrainConfig, out_dir: Path, config: dict[str, Any], loop: LoopState, rows: list[dict[str, Any]],
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
        if loop.slowest() // cfg.checkpoint_every > loop.checkpoints_done:
            loop.checkpoints_done = loop.slowest() // cfg.checkpoint_every
            _save(out_dir, config, loop, episodes, babble_gens, rows)
            saved.at = loop.slowest()


def say(message: str) -> None:
    """A message to the user about the run directory (stderr, so stdout stays machine-readable)."""
    print(message, file=sys.stderr, flush=True)


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


def _check_record_every(record_every: int | None) -> None:
    if record_every is not None and record_every < 1:
        raise ValueError(f"record_every must be >= 1, got {record_every}")


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
    override = (lambda a, h: _babbling_action(cfg, a, h, babbling, babble_gens)) if babbling.any() else None
    angles_before = env.joint_angles()
    info = episodes.act(loop, active, loop.episode, explore=True, override=override)
    s, s2, r, done = _transition(info, babbling)
    dev = agent.device
    executed = torch.as_tensor(info.joint_angles - angles_before, dtype=torch.float32, device=dev)
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


def _babbling_action(cfg: TrainConfig, action: torch.Tensor, habit: torch.Tensor, babbling: np.ndarray,
                     gens: list[torch.Generator]) -> tuple[torch.Tensor, torch.Tensor]:
    scale = cfg.agent.babbling_scale
    action = action.clone()
    for k in np.flatnonzero(babbling):
        action[k] = ((torch.rand(2, generator=gens[k]) * 2 - 1) * scale).to(action.device)
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
        s[b, 4:], s2[b, :4], s2[b, 4:] = reached_end, info.true_arm[b], reached_end
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


# -- run directory: config, metrics, checkpoints -----------------------------------------------
def git_commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=Path(__file__).resolve().parent,
                             capture_output=True, text=True, timeout=10)
        return out.stdout.strip() if out.returncode == 0 else "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def config_dict(cfg: TrainConfig) -> dict[str, Any]:
    """The resolved config in JSON form (tuples as lists)."""
    return json.loads(json.dumps(to_dict(cfg)))


def _prepare_run_dir(cfg: TrainConfig, out_dir: Path) -> tuple[dict[str, Any], int | None]:
    """Validate ``cfg`` against itself and the run already in ``out_dir``; write nothing.

    Returns the config and the episode count of the run already there (None: a new run). The same
    config with more episodes extends a run; any other difference is refused.
    """
    validate(cfg)
    config = config_dict(cfg)
    path = out_dir / "config.json"
    if not path.is_file():
        return config, None
    old = migrate(json.loads(path.read_text()))
    old.pop("git_commit", None)
    diff = _diff({**old, "episodes": None}, {**config, "episodes": None})
    if diff:
        raise ValueError(f"{out_dir} holds a run with a different config ({'; '.join(diff)}); "
                         "use another --out, or the same settings to resume (only the episode count may grow)")
    if cfg.episodes < old["episodes"]:
        raise ValueError(f"{out_dir} holds a run of {old['episodes']} episodes; it cannot be shortened to "
                         f"{cfg.episodes} (use another --out, or --episodes >= {old['episodes']})")
    return config, int(old["episodes"])


def _write_config(out_dir: Path, config: dict[str, Any], run_episodes: int | None) -> None:
    """Write config.json for a new run, or the new episode count of an extended one (DONE removed first)."""
    if run_episodes == config["episodes"]:
        return
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "DONE").unlink(missing_ok=True)
    path = out_dir / "config.json"
    commit = json.loads(path.read_text()).get("git_commit") if path.is_file() else git_commit()
    text = json.dumps({**config, "git_commit": commit}, indent=2) + "\n"
    checkpoint.atomic_write_bytes(path, lambda f: f.write(text.encode()))


def _finished(out_dir: Path) -> bool:
    """DONE is there and the final checkpoint loads; a damaged one un-finishes the run (with a warning)."""
    if not (out_dir / "DONE").is_file():
        return False
    try:
        checkpoint.load(out_dir / "checkpoints" / checkpoint.LATEST, required=CKPT_KEYS)
        return True
    except checkpoint.CheckpointError as e:
        say(f"warning: {out_dir} is marked finished but {e}; continuing from the newest intact checkpoint")
        (out_dir / "DONE").unlink()
        return False


def _diff(old: dict[str, Any], new: dict[str, Any], prefix: str = "") -> list[str]:
    out = []
    for k in sorted(set(old) | set(new)):
        a, b = old.get(k, "<missing>"), new.get(k, "<missing>")
        if isinstance(a, dict) and isinstance(b, dict):
            out += _diff(a, b, f"{prefix}{k}.")
        elif a != b:
            out.append(f"{prefix}{k}: {a!r} in the run, {b!r} now")
    return out


def validate(cfg: TrainConfig) -> None:
    """Refuse a run configuration that cannot run here (a ValueError naming the field); writes nothing."""
    if not cfg.seeds:
        raise ValueError("at least one seed is needed")
    if any(not isinstance(s, (int, np.integer)) or s < 0 for s in cfg.seeds) or len(set(cfg.seeds)) != len(cfg.seeds):
        raise ValueError(f"seeds must be distinct non-negative integers, got {list(cfg.seeds)}")
    if cfg.episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {cfg.episodes}")
    if cfg.checkpoint_every < 1:
        raise ValueError(f"checkpoint_every must be >= 1, got {cfg.checkpoint_every}")
    if cfg.agent.babbling_episodes < 0:
        raise ValueError(f"babbling_episodes must be >= 0, got {cfg.agent.babbling_episodes}")
    if cfg.device not in ("cpu", "cuda") and not cfg.device.startswith("cuda:"):
        raise ValueError(f"device must be 'cpu' or 'cuda', got {cfg.device!r}")
    check_device(cfg.device)
    if cfg.precision not in ("fp32", "bf16"):
        raise ValueError(f"precision must be 'fp32' or 'bf16', got {cfg.precision!r}")
    if cfg.actuation not in ("servo", "kinematic"):
        raise ValueError(f"actuation must be 'servo' or 'kinematic', got {cfg.actuation!r}")
    check_kind(cfg.agent)  # an unknown kind: an error listing the registered ones
    task_spec(cfg)  # unknown task -> KeyError listing the known ones; bad override -> TaskSpecError


def check_device(device: str) -> None:
    """A CUDA device that this machine (or this torch build) lacks is an error naming the way out."""
    if not device.startswith("cuda"):
        return
    if not torch.cuda.is_available():
        build = "a CPU-only build" if torch.version.cuda is None else f"built for CUDA {torch.version.cuda}"
        raise ValueError(f"device {device!r}: CUDA is not available here (torch {torch.__version__}, {build}); "
                         "use --device cpu, or set up with APAC_MJ_TORCH=cuda on a machine with a GPU (README)")
    index = int(device.split(":")[1]) if ":" in device else 0
    if index >= torch.cuda.device_count():
        raise ValueError(f"device {device!r}: this machine has {torch.cuda.device_count()} CUDA device(s)")


def metric_rows(run_dir: str | Path) -> int:
    """Rows in RUN_DIR/metrics.parquet (0 if none yet), read from the file's footer."""
    import pyarrow.parquet as pq

    path = Path(run_dir) / "metrics.parquet"
    return pq.ParquetFile(path).metadata.num_rows if path.is_file() else 0


def run_summary(run_dir: str | Path, last: int = 100) -> dict[str, Any]:
    """Episodes, seeds, and the success rate and habit share over each seed's ``last`` training episodes."""
    df = pd.read_parquet(Path(run_dir) / "metrics.parquet")
    tr = df[df.phase == "train"]
    late = tr[tr.episode >= tr.episode.max() - (last - 1)]
    acts = late.habit_actions.sum() + late.planning_actions.sum()
    return {"episodes": int(tr.episode.max()) + 1, "seeds": int(df.seed.nunique()),
            f"success_rate_last_{last}": round(float(late.success.mean()), 4),
            f"habit_share_last_{last}": round(float(late.habit_actions.sum() / max(1, acts)), 4)}


def write_metrics(path: Path, rows: list[dict[str, Any]]) -> None:
    """Atomically write the metric rows as parquet (columns: METRIC_COLUMNS)."""
    atomic_write_parquet(path, pd.DataFrame(rows, columns=list(METRIC_COLUMNS)))


def _save(out_dir: Path, config: dict[str, Any], loop: LoopState, episodes: EpisodeLoop,
          babble_gens: list[torch.Generator], rows: list[dict[str, Any]]) -> None:
    """metrics.parquet, then the checkpoint as latest.pt (the one before it kept as previous.pt)."""
    write_metrics(out_dir / "metrics.parquet", rows)
    ckpt = {"config": config, "loop": loop.state_dict(), "agent": episodes.agent.state_dict(),
            "env": episodes.env.get_state(), **episodes.state_dict(),
            "babbling_generators": [g.get_state() for g in babble_gens], "metric_rows": len(rows),
            "torch_rng": torch.get_rng_state()}
    ckpt_dir = out_dir / "checkpoints"
    checkpoint.save_rotating(ckpt, ckpt_dir / checkpoint.LATEST, ckpt_dir / checkpoint.PREVIOUS)
    checkpoint.prune(ckpt_dir, "ckpt_*.pt", 0)  # the numbered checkpoints of older versions


def _restore(out_dir: Path, config: dict[str, Any], episodes: EpisodeLoop,
             babble_gens: list[torch.Generator]) -> tuple[LoopState, list[dict[str, Any]]]:
    """Load the newest intact checkpoint (warning when it is not latest.pt) into the agent and env."""
    metrics = out_dir / "metrics.parquet"
    restored: dict[str, Any] = {}

    def check(ckpt: dict[str, Any], path: Path) -> None:
        restored["rows"] = read_metric_rows(metrics, int(ckpt["metric_rows"]))
        restored["loop"] = _apply(ckpt, path, config, episodes, babble_gens)

    checkpoint.load_newest_intact(checkpoint.run_checkpoints(out_dir / "checkpoints"), required=CKPT_KEYS,
                                  check=check, warn=say)
    return restored["loop"], restored["rows"]


def _apply(ckpt: dict[str, Any], path: Path, config: dict[str, Any], episodes: EpisodeLoop,
           babble_gens: list[torch.Generator]) -> LoopState:
    """Put a loaded checkpoint into the agent, the environments and the generators (same config but
    the episode count, which an extended run changes)."""
    agent, env = episodes.agent, episodes.env
    diff = _diff({**migrate(ckpt["config"]), "episodes": None}, {**config, "episodes": None})
    if diff:
        raise checkpoint.CheckpointError(f"checkpoint {path} is corrupt or incompatible: it was written with a "
                                         f"different config ({'; '.join(diff)})")
    try:
        agent.load_state_dict(_to_device(ckpt["agent"], agent.device))
        env.set_state(ckpt["env"])
        for g, s in zip(babble_gens, ckpt["babbling_generators"], strict=True):
            g.set_state(s)
        loop = LoopState.from_state_dict(ckpt["loop"], agent.device)
        episodes.load_state_dict(running_statistics(ckpt))
    except (KeyError, ValueError, RuntimeError, TypeError, AttributeError) as e:
        raise checkpoint.CheckpointError(f"checkpoint {path} is corrupt or incompatible: "
                                         f"{type(e).__name__}: {e}") from None
    torch.set_rng_state(ckpt["torch_rng"])
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


def read_metric_rows(path: Path, n: int) -> list[dict[str, Any]]:
    """The first ``n`` rows of metrics.parquet (the checkpoint's); error if fewer are there."""
    if n == 0:
        return []
    if not path.is_file():
        raise checkpoint.CheckpointError(f"{path} is missing but the checkpoint expects {n} metric rows")
    df = pd.read_parquet(path)
    if len(df) < n:
        raise checkpoint.CheckpointError(f"{path} has {len(df)} rows, the checkpoint expects {n}")
    return [_plain(r) for r in df.iloc[:n].to_dict("records")]


def _plain(row: dict[str, Any]) -> dict[str, Any]:
    """numpy scalars -> Python scalars (so rebuilt rows equal freshly made ones)."""
    return {k: (v.item() if hasattr(v, "item") else v) for k, v in row.items()}


# -- recordings (apac_mj.recording.recording) ----------------------------------------------------------------
def _recorder(out_dir: Path, record_every: int | None, config: dict[str, Any]) -> Any:
    """``apac_mj.recording.recording.EpisodeRecorder(out_dir / "recordings", record_every, config)`` if asked for."""
    if record_every is None:
        return None
    from apac_mj.recording import recording

    return recording.EpisodeRecorder(out_dir / "recordings", record_every=record_every, config=config)


def _chain_hooks(recorder: Any, on_step: OnStep | None,
                 on_episode_start: OnEpisodeStart | None) -> tuple[OnStep | None, OnEpisodeStart | None]:
    if recorder is None:
        return on_step, on_episode_start
    hooks_step = [h for h in (recorder.on_step, on_step) if h is not None]
    hooks_start = [h for h in (recorder.on_episode_start, on_episode_start) if h is not None]

    def step_all(info: StepInfo, env: VecEnv) -> None:
        for h in hooks_step:
            h(info, env)

    def start_all(members: np.ndarray, env: VecEnv) -> None:
        for h in hooks_start:
            h(members, env)

    return step_all, start_all

