"""The run directory: the one reader and writer of a run's files.

Layout (``docs/architecture.md`` has the columns)::

    RUN_DIR/
      config.json          the resolved TrainConfig, plus "git_commit"
      metrics.parquet      one row per (seed, episode): METRIC_COLUMNS
      checkpoints/         latest.pt and the one before it, previous.pt (RunCheckpoint: what they hold)
      eval/                <protocol>.parquet and summary.json, from the frozen tests
      recordings/          *.rrd, when training records
      DONE                 written when training finished

:class:`RunDir` reads and writes these files; :class:`RunCheckpoint` is a
loaded checkpoint read by name. Beside them: what a run is before it has
files (:func:`validate`, :func:`check_device`, :func:`config_dict`), the
run's environments and agent built from its files (:func:`training_env`,
:func:`load_run`), the config diff, the commit, and the one way to tell the
user something (:func:`say`, on stderr so that stdout stays machine-readable).
"""
from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable

import numpy as np
import pandas as pd

from apac_mj.config import TrainConfig, migrate, to_dict, train_config_from_dict
from apac_mj.kinematics import Geometry
from apac_mj.kinds import check as check_kind
from apac_mj.run import checkpoint
from apac_mj.suite import spec_for
from apac_mj.util.files import atomic_write_parquet, atomic_write_text, read_json

if TYPE_CHECKING:  # torch, the learner and the plant load where a run is built, not where it is read
    import torch

    from apac_mj.agent.agent import Agent
    from apac_mj.suite.vec_env import VecEnv

CONFIG, METRICS, DONE = "config.json", "metrics.parquet", "DONE"
CHECKPOINTS, EVAL, RECORDINGS = "checkpoints", "eval", "recordings"
#: A run's checkpoints: the newest, and the one before it (older versions numbered theirs ``ckpt_*.pt``).
LATEST, PREVIOUS, OLD_CHECKPOINTS = "latest.pt", "previous.pt", "ckpt_*.pt"
#: The columns of metrics.parquet, in order.
METRIC_COLUMNS = ("seed", "episode", "phase", "success", "steps", "return", "final_distance", "habit_actions",
                  "planning_actions", "l1", "l2", "target_x", "target_y", "critic_loss", "actor_loss",
                  "forward_loss", "inverse_loss", "estimate_error")
#: What every training checkpoint holds (and what a finished run's latest.pt is checked for).
CHECKPOINT_KEYS = ("config", "loop", "agent", "env", "babbling_generators", "metric_rows")
#: What reading a run's networks and environments needs (the frozen tests, recordings).
NETWORK_KEYS = ("agent", "env")
#: The running statistics a checkpoint keeps (``EpisodeLoop.state_dict``; absent before they existed).
RUNNING_KEYS = ("arbitrator", "integrator")


def say(message: str) -> None:
    """A message to the user about a run (stderr, so stdout stays machine-readable)."""
    print(message, file=sys.stderr, flush=True)


def git_commit() -> str:
    """The checkout's commit (with ``-dirty`` for local changes), or "unknown"."""
    try:
        out = subprocess.run(["git", "describe", "--always", "--dirty", "--abbrev=40"],
                             cwd=Path(__file__).resolve().parent, capture_output=True, text=True, timeout=10,
                             check=True)
        return out.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def config_dict(cfg: TrainConfig) -> dict[str, Any]:
    """The resolved config in JSON form (tuples as lists)."""
    return json.loads(json.dumps(to_dict(cfg)))


def stored_config(stored: dict[str, Any]) -> dict[str, Any]:
    """A config as a run stored it (config.json, a checkpoint) in this code's form: without its commit, and
    migrated from the shape older releases wrote (:func:`apac_mj.config.migrate`)."""
    return migrate({k: v for k, v in stored.items() if k != "git_commit"})


def diff(old: dict[str, Any], new: dict[str, Any], where: str, prefix: str = "") -> list[str]:
    """Every leaf that differs between two nested dicts: ``"a.b: OLD {where}, NEW now"``, sorted by key."""
    out = []
    for k in sorted(set(old) | set(new)):
        a, b = old.get(k, "<missing>"), new.get(k, "<missing>")
        if isinstance(a, dict) and isinstance(b, dict):
            out += diff(a, b, where, f"{prefix}{k}.")
        elif a != b:
            out.append(f"{prefix}{k}: {a!r} {where}, {b!r} now")
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
    if cfg.precision not in ("fp32", "bf16", "auto"):  # auto: resolved by the trainer before prepare()
        raise ValueError(f"precision must be 'fp32', 'bf16' or 'auto', got {cfg.precision!r}")
    if cfg.actuation not in ("servo", "kinematic"):
        raise ValueError(f"actuation must be 'servo' or 'kinematic', got {cfg.actuation!r}")
    check_kind(cfg.agent)  # an unknown kind: an error listing the registered ones
    spec_for(cfg)  # unknown task -> KeyError listing the known ones; bad override -> TaskSpecError


def check_device(device: str) -> None:
    """A CUDA device that this machine (or this torch build) lacks is an error naming the way out."""
    if not device.startswith("cuda"):
        return
    import torch

    if not torch.cuda.is_available():
        build = "a CPU-only build" if torch.version.cuda is None else f"built for CUDA {torch.version.cuda}"
        raise ValueError(f"device {device!r}: CUDA is not available here (torch {torch.__version__}, {build}); "
                         "use --device cpu, or set up with APAC_MJ_TORCH=cuda on a machine with a GPU (README)")
    index = int(device.split(":")[1]) if ":" in device else 0
    if index >= torch.cuda.device_count():
        raise ValueError(f"device {device!r}: this machine has {torch.cuda.device_count()} CUDA device(s)")


def training_env(cfg: TrainConfig) -> VecEnv:
    """The run's environments as training builds them: changing kinematics start after
    ``growth_start_episode`` *training* episodes, so the environment's threshold (which counts every
    reset) is shifted by the babbling count here, and only here."""
    from apac_mj.suite.vec_env import VecEnv  # the plant loads when a run is built, not when one is read

    growth = spec_for(cfg).growth_start_episode + cfg.agent.babbling_episodes
    return VecEnv(cfg.task, list(cfg.seeds), cfg.actuation,
                  overrides={**cfg.task_overrides, "growth_start_episode": growth})


def load_run(run_dir: str | Path, device: str | None = None,
             precision: str | None = None) -> tuple[TrainConfig, Agent, RunCheckpoint]:
    """The run's config, its agent (on ``device``, in ``precision``: default the run's) with the newest
    intact checkpoint's weights, and that checkpoint."""
    from apac_mj.agent.agent import Agent  # the learner loads when a run is built, not when one is read

    run = RunDir(run_dir)
    cfg = run.train_config()
    device = cfg.device if device is None else device
    check_device(device)  # a missing GPU: a clear error before anything is loaded
    ckpt = run.load_checkpoint(required=NETWORK_KEYS)
    agent = Agent(cfg.agent, list(cfg.seeds), device=device, precision=precision or cfg.precision,
                  geometry=Geometry.from_spec(spec_for(cfg)))
    agent.load_state_dict(ckpt.agent)
    return cfg, agent, ckpt


@dataclasses.dataclass(frozen=True)
class RunCheckpoint:
    """A loaded checkpoint of a run, read by name: the one place that knows its keys."""

    data: dict[str, Any]
    path: Path

    @staticmethod
    def layout(config: dict[str, Any], loop: dict[str, Any], agent: dict[str, Any], env: dict[str, Any],
               running: dict[str, Any], babbling_generators: list[torch.Tensor],
               metric_rows: int) -> dict[str, Any]:
        """The checkpoint to save: these parts and the global torch generator's state (taken now)."""
        import torch

        return {"config": config, "loop": loop, "agent": agent, "env": env, **running,
                "babbling_generators": babbling_generators, "metric_rows": metric_rows,
                "torch_rng": torch.get_rng_state()}

    @property
    def config(self) -> dict[str, Any]:
        return stored_config(self.data["config"])

    @property
    def agent(self) -> dict[str, Any]:
        return self.data["agent"]

    @property
    def env(self) -> dict[str, Any]:
        """The environments' state (``VecEnv.get_state``)."""
        return self.data["env"]

    @property
    def loop(self) -> dict[str, Any]:
        """The training loop's per-member carry and counters (``LoopState.state_dict``)."""
        return self.data["loop"]

    @property
    def babbling_generators(self) -> list[torch.Tensor]:
        return self.data["babbling_generators"]

    @property
    def metric_rows(self) -> int:
        """Rows of metrics.parquet that belong to this checkpoint."""
        return int(self.data["metric_rows"])

    @property
    def torch_rng(self) -> torch.Tensor:
        return self.data["torch_rng"]

    def running_statistics(self) -> dict[str, Any]:
        """The arbitrator's and the integrator's running statistics (absent in checkpoints from before them)."""
        return {k: self.data[k] for k in RUNNING_KEYS if k in self.data}

    def member_lengths(self) -> np.ndarray:
        """``[E, 2]`` every member's link lengths when the checkpoint was written (cm)."""
        return np.stack([m["task"]["lengths"].numpy() for m in self.env["members"]])

    def member_targets(self) -> list[Any]:
        """Every member's static target (None: the task has none, or it was not drawn yet)."""
        return [m["task"]["static_target"] for m in self.env["members"]]

    def member_episode(self, k: int) -> int:
        """The training episode member ``k`` was at (babbling negative)."""
        return int(self.loop["episode"][k])


class RunDir:
    """A run directory (existing or to be written): every read and write of its files."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    def __repr__(self) -> str:
        return f"RunDir({str(self.path)!r})"

    @property
    def checkpoints(self) -> Path:
        return self.path / CHECKPOINTS

    @property
    def recordings(self) -> Path:
        """Where training's recordings go (``EpisodeRecorder``'s directory)."""
        return self.path / RECORDINGS

    # -- config.json ---------------------------------------------------------------------------
    def exists(self) -> bool:
        """A run directory: config.json is there."""
        return (self.path / CONFIG).is_file()

    def problem(self) -> str | None:
        """Why this is not a run directory (None: it is one)."""
        if not self.path.is_dir():
            return f"{self.path} does not exist"
        if not self.exists():
            return f"{self.path} is not a run directory (no config.json); train one with apac-mj train"
        return None

    def _stored(self) -> dict[str, Any] | None:
        return read_json(self.path / CONFIG)

    def config(self) -> dict[str, Any]:
        """The run's config as config.json holds it (without its commit); an error naming the problem
        if this is not a run directory."""
        stored = self._stored()
        if stored is None:
            raise FileNotFoundError(self.problem())
        return stored_config(stored)

    def train_config(self) -> TrainConfig:
        return train_config_from_dict(self.config())

    def episodes(self) -> int | None:
        """The episode count config.json records (None: no run here yet)."""
        return self.config().get("episodes") if self.exists() else None

    def prepare(self, cfg: TrainConfig) -> tuple[dict[str, Any], int | None]:
        """Validate ``cfg`` against itself and the run already here; write nothing.

        Returns the config and the episode count of the run already here (None: a new run). The same
        config with more episodes extends a run; any other difference is refused.
        """
        validate(cfg)
        config = config_dict(cfg)
        if not self.exists():
            return config, None
        old = self.config()
        changed = diff({**old, "episodes": None}, {**config, "episodes": None}, "in the run")
        if changed:
            raise ValueError(f"{self.path} holds a run with a different config ({'; '.join(changed)}); "
                             "use another --out, or the same settings to resume (only the episode count may grow)")
        if cfg.episodes < old["episodes"]:
            raise ValueError(f"{self.path} holds a run of {old['episodes']} episodes; it cannot be shortened to "
                             f"{cfg.episodes} (use another --out, or --episodes >= {old['episodes']})")
        return config, int(old["episodes"])

    def write_config(self, config: dict[str, Any], run_episodes: int | None) -> None:
        """Write config.json for a new run, or the new episode count of an extended one (DONE removed
        first); the commit is the one the run was started at."""
        if run_episodes == config["episodes"]:
            return
        self.path.mkdir(parents=True, exist_ok=True)
        (self.path / DONE).unlink(missing_ok=True)
        stored = self._stored()
        commit = stored.get("git_commit") if stored is not None else git_commit()
        atomic_write_text(self.path / CONFIG, json.dumps({**config, "git_commit": commit}, indent=2) + "\n")

    # -- DONE ----------------------------------------------------------------------------------
    def finished(self) -> bool:
        """Training finished: DONE is there."""
        return (self.path / DONE).is_file()

    def check_finished(self) -> bool:
        """DONE is there and the final checkpoint loads; a damaged one un-finishes the run (with a warning)."""
        if not self.finished():
            return False
        try:
            checkpoint.load(self.checkpoints / LATEST, required=CHECKPOINT_KEYS)
            return True
        except checkpoint.CheckpointError as e:
            say(f"warning: {self.path} is marked finished but {e}; continuing from the newest intact checkpoint")
            (self.path / DONE).unlink()
            return False

    def mark_finished(self) -> None:
        atomic_write_text(self.path / DONE, "done\n")

    # -- metrics.parquet -----------------------------------------------------------------------
    def metric_rows(self) -> int:
        """Rows in metrics.parquet (0 if none yet), read from the file's footer."""
        import pyarrow.parquet as pq

        path = self.path / METRICS
        return pq.ParquetFile(path).metadata.num_rows if path.is_file() else 0

    def has_metrics(self) -> bool:
        return (self.path / METRICS).is_file()

    def metrics(self) -> pd.DataFrame:
        """metrics.parquet: one row per (seed, episode)."""
        return pd.read_parquet(self.path / METRICS)

    def write_metrics(self, rows: list[dict[str, Any]]) -> None:
        """Atomically write the metric rows as metrics.parquet (columns: METRIC_COLUMNS)."""
        atomic_write_parquet(self.path / METRICS, pd.DataFrame(rows, columns=list(METRIC_COLUMNS)))

    def read_metric_rows(self, n: int) -> list[dict[str, Any]]:
        """The first ``n`` rows of metrics.parquet (a checkpoint's); a CheckpointError if fewer are there."""
        path = self.path / METRICS
        if n == 0:
            return []
        if not path.is_file():
            raise checkpoint.CheckpointError(f"{path} is missing but the checkpoint expects {n} metric rows")
        df = pd.read_parquet(path)
        if len(df) < n:
            raise checkpoint.CheckpointError(f"{path} has {len(df)} rows, the checkpoint expects {n}")
        return [_plain(r) for r in df.iloc[:n].to_dict("records")]

    def summary(self, last: int = 100) -> dict[str, Any]:
        """Episodes, seeds, and the success rate and habit share over each seed's ``last`` training episodes."""
        df = self.metrics()
        tr = df[df.phase == "train"]
        late = tr[tr.episode >= tr.episode.max() - (last - 1)]
        acts = late.habit_actions.sum() + late.planning_actions.sum()
        return {"episodes": int(tr.episode.max()) + 1, "seeds": int(df.seed.nunique()),
                f"success_rate_last_{last}": round(float(late.success.mean()), 4),
                f"habit_share_last_{last}": round(float(late.habit_actions.sum() / max(1, acts)), 4)}

    # -- checkpoints/ --------------------------------------------------------------------------
    def checkpoint_files(self) -> list[Path]:
        """The run's checkpoint files, newest first: latest.pt, previous.pt, then older versions' ``ckpt_*.pt``."""
        named = [self.checkpoints / LATEST, self.checkpoints / PREVIOUS]
        return [p for p in named + sorted(self.checkpoints.glob(OLD_CHECKPOINTS), reverse=True) if p.is_file()]

    def save_checkpoint(self, ckpt: dict[str, Any]) -> None:
        """Write ``ckpt`` (:meth:`RunCheckpoint.layout`) as latest.pt, the one before it kept as previous.pt."""
        checkpoint.save_rotating(ckpt, self.checkpoints / LATEST, self.checkpoints / PREVIOUS)
        checkpoint.prune(self.checkpoints, OLD_CHECKPOINTS, 0)

    def load_checkpoint(self, required: Iterable[str] = CHECKPOINT_KEYS,
                        check: Callable[[RunCheckpoint], None] | None = None) -> RunCheckpoint:
        """The newest checkpoint that loads, has the ``required`` keys and passes ``check`` (which raises
        CheckpointError); a fallback past a damaged one is said."""
        found = self.checkpoint_files()
        if not found:
            raise checkpoint.CheckpointError(f"checkpoint {self.checkpoints / LATEST} does not exist: {self.path} "
                                             "has no checkpoint yet (train it first)")

        def fits(obj: dict[str, Any], path: Path) -> None:
            if check is not None:
                check(RunCheckpoint(obj, path))

        return RunCheckpoint(*checkpoint.load_newest_intact(found, required=required, check=fits, warn=say))

    # -- eval/ ---------------------------------------------------------------------------------
    def eval_path(self, protocol: str) -> Path:
        """The results of one frozen-test protocol: ``eval/<protocol>.parquet``."""
        return self.path / EVAL / f"{protocol}.parquet"

    def eval_paths(self) -> list[Path]:
        """Every protocol's results there are, by name."""
        return sorted((self.path / EVAL).glob("*.parquet"))

    def write_eval(self, protocol: str, df: pd.DataFrame) -> None:
        atomic_write_parquet(self.eval_path(protocol), df)

    def evaluated(self) -> bool:
        """The frozen tests' summary (eval/summary.json) is there."""
        return (self.path / EVAL / "summary.json").is_file()

    def eval_summary(self) -> dict[str, Any]:
        """eval/summary.json ({} if the run was not tested yet)."""
        return read_json(self.path / EVAL / "summary.json") or {}

    def write_eval_summary(self, summary: dict[str, Any]) -> None:
        atomic_write_text(self.path / EVAL / "summary.json", json.dumps(summary, indent=2) + "\n")


def _plain(row: dict[str, Any]) -> dict[str, Any]:
    """numpy scalars -> Python scalars (so rebuilt rows equal freshly made ones)."""
    return {k: (v.item() if isinstance(v, np.generic) else v) for k, v in row.items()}
