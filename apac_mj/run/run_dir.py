"""The run directory: the one reader and writer of a run's files.

Layout (the column constants below; docs/architecture.md has the map)::

    RUN_DIR/
      config.json          the resolved TrainConfig, plus "git_commit", "task_spec" and "task_digest"
      metrics.parquet      one row per (seed, episode): METRIC_COLUMNS
      checkpoints/         latest.pt and the one before it, previous.pt (RunCheckpoint: what they hold)
      eval/                <protocol>.parquet and summary.json, from the frozen tests
      recordings/          *.rrd, when training records
      DONE                 written when training finished
      .lock                the lock of the one process writing the run (apac_mj.util.lock)

:class:`RunDir` reads and writes these files; :class:`RunCheckpoint` is a
loaded checkpoint read by name. Beside them: the config in its JSON form
(:func:`config_dict`), the config diff, the commit, and the one way to tell the
user something (:func:`say`, on stderr so that stdout stays machine-readable).
This module imports neither the plant nor the learner: a run is built from its
files in :mod:`apac_mj.run.build`.

One process writes a run: :meth:`RunDir.lock` (an advisory file lock the operating system releases
when its holder dies; a second writer is refused, naming the holder's PID), and the writer removes
the temporary files a killed writer left. The checkpoint is the truth: config.json, the episode count
and metrics.parquet are checked against what the checkpoint records (its config, and a digest and a
copy of the metric rows); a file that disagrees is a :class:`RunMismatch` naming it and the way out,
and damaged or edited metric rows are restored from the checkpoint's copy. config.json also records the task
the run trains (the resolved task and its digest, :func:`task_digest`): a task file edited since is a
:class:`TaskChanged` naming the file and the fields (:meth:`RunDir.check_task`).
"""
from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import io
import json
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable, Iterator

import numpy as np
import pandas as pd

from apac_mj.config import TrainConfig, migrate, to_dict, train_config_from_dict
from apac_mj.run import checkpoint
from apac_mj.types import TIMING_COLUMNS
from apac_mj.util.files import atomic_write_bytes, atomic_write_text, read_json, remove_stale_temporaries
from apac_mj.util.lock import locked

if TYPE_CHECKING:  # torch loads where a checkpoint is made or read, not where a run's files are listed
    import torch

CONFIG, METRICS, DONE = "config.json", "metrics.parquet", "DONE"
CHECKPOINTS, EVAL, RECORDINGS = "checkpoints", "eval", "recordings"
#: A run's checkpoints: the newest, and the one before it (older versions numbered theirs ``ckpt_*.pt``).
LATEST, PREVIOUS, OLD_CHECKPOINTS = "latest.pt", "previous.pt", "ckpt_*.pt"
#: The columns of metrics.parquet, in order.
METRIC_COLUMNS = ("seed", "episode", "phase", "success", "steps", "return", "final_distance", "habit_actions",
                  "planning_actions", "l1", "l2", "target_x", "target_y", "critic_loss", "actor_loss",
                  "forward_loss", "inverse_loss", "estimate_error")
#: The per-trial columns a task with a ``[trials]`` table adds (apac_mj.suite.trials.TRIAL_COLUMNS, the same names;
#: docs/environment.md "Trial types"), after the others; no other task's metrics have them. In the rows' digest where
#: present.
TRIAL_COLUMNS = {
    #: the block's name (``[[trials.block]] name``)
    "trial_block": "block",
    #: "field", "null", "channel" or "catch"
    "trial_type": "type",
    #: the curl field's b applied in the episode (N·s/m; 0 in channel, catch and null trials)
    "trial_field_b": "N·s/m",
    #: signed largest perpendicular deviation from the straight line to the target (cm; + where the b > 0 field pushes)
    "lateral_error": "cm",
    #: the agent's lateral force against the channel, its signed peak (N; NaN off channel trials)
    "channel_force_peak": "N",
    #: the agent's lateral force against the channel at the movement's peak hand speed (N; NaN off channel trials)
    "channel_force_at_peak_speed": "N",
    #: the hand's peak speed in the movement (cm/s)
    "peak_speed": "cm/s",
    #: the hand moved more than ``trials.early_movement_cm`` before the go cue (False without a go cue)
    "early_movement": "bool",
    #: centre-out targets only (``trials.directions`` > 0): the target's direction index
    "trial_direction": "index",
}
# After them: the measured columns (issue 28; apac_mj.types.TIMING_COLUMNS), not in the rows' digest (wall times
# differ from run to run; runs from before them lack them: NaN when such a run is extended); then any further
# column of the rows (the dynamics model's ``dynamics_loss``, a new per-episode measure), in the rows' order.
#: What every training checkpoint holds (and what a finished run's latest.pt is checked for).
CHECKPOINT_KEYS = ("config", "loop", "agent", "env", "babbling_generators", "metric_rows")
#: What reading a run's networks and environments needs (the frozen tests, recordings).
NETWORK_KEYS = ("agent", "env")
#: The running statistics a checkpoint keeps (``EpisodeLoop.state_dict``; absent before they existed).
RUNNING_KEYS = ("arbitrator", "integrator", "planner")
#: config.json's keys beside the config: the commit the run started at, and the task it trains (the resolved
#: task in JSON form, :func:`apac_mj.run.build.task_record`, and its :func:`task_digest`; runs written before
#: these existed have neither, and their task is not checked).
COMMIT, TASK_SPEC, TASK_DIGEST = "git_commit", "task_spec", "task_digest"


class TaskChanged(ValueError):
    """The task a run trains has changed since the run started (its task file edited): the message names the
    file and the fields. Nothing was written."""


class RunMismatch(ValueError):
    """A run's files disagree with its checkpoint (edited or damaged); the message names the file and the way
    out. Unlike a damaged checkpoint (:class:`~apac_mj.run.checkpoint.CheckpointError`), no older
    checkpoint is tried: the checkpoints are intact."""


class StaleCheckpoint(RunMismatch):
    """A finished run's latest.pt holds a member short of the run's episode count: an older checkpoint was put
    in its place. The message names the file, the members and the way out; nothing was written."""


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
    """A config as a run stored it (config.json, a checkpoint) in this code's form: without its commit and
    task, and migrated from the shape older releases wrote (:func:`apac_mj.config.migrate`)."""
    return migrate({k: v for k, v in stored.items() if k not in (COMMIT, TASK_SPEC, TASK_DIGEST)})


def task_digest(task: dict[str, Any]) -> str:
    """A SHA-256 of a resolved task in JSON form (:func:`apac_mj.run.build.task_record`), keys sorted."""
    return hashlib.sha256(json.dumps(task, sort_keys=True, allow_nan=True).encode()).hexdigest()


def diff(old: dict[str, Any], new: dict[str, Any], where: str, prefix: str = "", now: str = "now") -> list[str]:
    """Every leaf that differs between two nested dicts: ``"a.b: OLD {where}, NEW {now}"``, sorted by key."""
    out = []
    for k in sorted(set(old) | set(new)):
        a, b = old.get(k, "<missing>"), new.get(k, "<missing>")
        if isinstance(a, dict) and isinstance(b, dict):
            out += diff(a, b, where, f"{prefix}{k}.", now)
        elif a != b:
            out.append(f"{prefix}{k}: {a!r} {where}, {b!r} {now}")
    return out


@dataclasses.dataclass(frozen=True)
class TaskRecord:
    """The task a run trains as config.json records it (:func:`apac_mj.run.build.task_record` makes it)."""

    #: The resolved task (file and overrides) in JSON form, without what only names or colours it in reports.
    spec: dict[str, Any]
    #: Where it was read, for messages: "task file tasks/NAME.toml" or "task 'NAME' (registered at run time)".
    source: str
    #: Every field's default in the same form: a field added since a run started counts as its default there.
    defaults: dict[str, Any] = dataclasses.field(default_factory=dict)

    @property
    def digest(self) -> str:
        return task_digest(self.spec)


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

    @staticmethod
    def with_metrics(layout: dict[str, Any], rows: list[dict[str, Any]], table: bytes) -> dict[str, Any]:
        """``layout`` with the metric rows' digest and a copy of them (``table``: metrics.parquet's bytes)."""
        import torch

        return {**layout, "metric_rows": len(rows), "metric_digest": metric_digest(rows),
                "metric_table": torch.frombuffer(bytearray(table), dtype=torch.uint8) if table else
                torch.zeros(0, dtype=torch.uint8)}

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
    def metric_digest(self) -> str | None:
        """The digest (:func:`metric_digest`) of those rows (None: a checkpoint from before digests)."""
        return self.data.get("metric_digest")

    def metric_table(self) -> list[dict[str, Any]] | None:
        """The checkpoint's own copy of its metric rows (None: a checkpoint from before copies)."""
        table = self.data.get("metric_table")
        if table is None:
            return None
        if self.metric_rows == 0:
            return []
        df = pd.read_parquet(io.BytesIO(table.numpy().tobytes()))
        return [_plain(r) for r in df.iloc[: self.metric_rows].to_dict("records")]

    @property
    def torch_rng(self) -> torch.Tensor:
        return self.data["torch_rng"]

    def running_statistics(self) -> dict[str, Any]:
        """The arbitrator's and the integrator's running statistics and a model planner's warm start and random
        streams (absent in checkpoints from before them, and for kinds without them)."""
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

    @contextlib.contextmanager
    def lock(self) -> Iterator[RunDir]:
        """Be the run's one writer for the ``with`` block (re-entrant in a process); another process holding
        it: :class:`~apac_mj.util.lock.DirectoryLocked` naming its PID. The temporary files of a killed
        writer are removed first. A directory this call created and left empty is removed again."""
        with locked(self.path, "run directory"):
            removed = remove_stale_temporaries(self.path)
            if removed:
                say(f"removed {len(removed)} temporary file(s) a killed writer left in {self.path}: "
                    + ", ".join(str(p.relative_to(self.path)) for p in removed))
            yield self

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
        return read_json(self.path / CONFIG, fix="put back the file as training wrote it (its checkpoint records "
                                                 "the same settings), or use another --out")

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

    def prepare(self, cfg: TrainConfig, task: TaskRecord | None = None) -> tuple[dict[str, Any], int | None]:
        """Check ``cfg`` (already valid in itself: :func:`apac_mj.run.build.check`) and its ``task`` against the run
        already here; write nothing.

        Returns the config and the episode count of the run already here (None: a new run). The same
        config with more episodes extends a run; any other difference is refused, and so is a task file
        edited since the run trained (:meth:`check_task`).
        """
        config = config_dict(cfg)
        if not self.exists():
            return config, None
        old = self.config()
        self._check_against_newest_checkpoint()  # an edited config.json: said as such, before comparing with it
        changed = diff({**old, "episodes": None}, {**config, "episodes": None}, "in the run")
        if changed:
            raise ValueError(f"{self.path} holds a run with a different config ({'; '.join(changed)}); "
                             "use another --out, or the same settings to resume (only the episode count may grow)")
        if cfg.episodes < old["episodes"]:
            raise ValueError(f"{self.path} holds a run of {old['episodes']} episodes; it cannot be shortened to "
                             f"{cfg.episodes} (use another --out, or --episodes >= {old['episodes']})")
        if task is not None and self.checkpoint_files():  # without a checkpoint nothing was trained: it starts over
            self.check_task(task, "training on would mix two tasks in one run")
        return config, int(old["episodes"])

    def write_config(self, config: dict[str, Any], run_episodes: int | None, task: TaskRecord | None = None) -> None:
        """Write config.json for a new run, or the new episode count of an extended one (DONE removed
        first); the commit is the one the run was started at, the task the one it trained (``task`` for a
        run that has not trained yet; a run from before task records gets none)."""
        stored = self._stored()
        records = self._records(stored, task)
        if run_episodes == config["episodes"] and all(stored.get(k) == v for k, v in records.items()):
            return
        self.path.mkdir(parents=True, exist_ok=True)
        (self.path / DONE).unlink(missing_ok=True)
        atomic_write_text(self.path / CONFIG, json.dumps({**config, **records}, indent=2) + "\n")

    def _records(self, stored: dict[str, Any] | None, task: TaskRecord | None) -> dict[str, Any]:
        """config.json's keys beside the config (COMMIT, TASK_SPEC, TASK_DIGEST) for the run to write."""
        if stored is not None and self.checkpoint_files():  # trained: what it recorded when it started
            return {k: stored[k] for k in (COMMIT, TASK_SPEC, TASK_DIGEST) if k in stored}
        commit = stored.get(COMMIT) if stored is not None else git_commit()
        return {COMMIT: commit, **({TASK_SPEC: task.spec, TASK_DIGEST: task.digest} if task is not None else {})}

    def check_task(self, task: TaskRecord, doing: str) -> None:
        """The task config.json records is ``task`` (a run from before task records: not checked); else
        :class:`TaskChanged` naming where the task is read, the fields that changed, and ``doing`` (what
        going on would do)."""
        stored = self._stored() or {}
        digest = stored.get(TASK_DIGEST)
        if digest is None or digest == task.digest:
            return
        changed = diff(_as_now(stored.get(TASK_SPEC) or {}, task.defaults or task.spec), task.spec, "in the run")
        if not changed:  # only fields added since the run started, at their defaults
            return
        raise TaskChanged(f"{task.source} has changed since {self.path} was trained on it ({'; '.join(changed)}): "
                          f"{doing}. Put the task back as it was (config.json's \"{TASK_SPEC}\" holds every value "
                          "the run trained with), or train the changed task into another --out (nothing was written)")

    def check_config(self, ckpt: RunCheckpoint) -> None:
        """config.json records the config ``ckpt`` was trained with (the episode count may be larger while an
        extension is under way, never smaller, and equal once finished); else :class:`RunMismatch`."""
        stored, trained = self.config(), ckpt.config
        changed = diff({**trained, "episodes": None}, {**stored, "episodes": None}, "in the checkpoint",
                       now="in config.json")
        if changed:
            raise RunMismatch(f"{self.path / CONFIG} disagrees with the run's checkpoint {ckpt.path} "
                              f"({'; '.join(changed)}): config.json was edited or replaced, and the checkpoint "
                              "records what was trained. Put config.json back to the checkpoint's values (nothing "
                              "was changed; the run is intact), or train into another --out")
        was, says = trained.get("episodes"), stored.get("episodes")
        final = self.is_final(ckpt)
        if says != was and (final or not isinstance(says, int) or says < was):
            raise RunMismatch(f"{self.path / CONFIG} says {says!r} episodes but the run's checkpoint {ckpt.path} "
                              f"holds a run of {was}{' (finished)' if final else ''}: config.json was "
                              f"edited. Put \"episodes\": {was} back (nothing was changed; the run is intact); a "
                              f"larger --episodes then extends it")
        if final:
            self.check_not_stale(ckpt)

    def is_final(self, ckpt: RunCheckpoint) -> bool:
        """``ckpt`` is the finished run's final checkpoint: DONE is there and ``ckpt`` is latest.pt. An older
        checkpoint loaded past a damaged latest.pt (previous.pt, say from before an extension) is not: the run
        is then resumed from it, and its episode count may be below config.json's."""
        return self.finished() and ckpt.path.name == LATEST

    def check_not_stale(self, ckpt: RunCheckpoint) -> None:
        """Every member of a finished run's latest.pt reached the run's episode count; else
        :class:`StaleCheckpoint` (an older checkpoint copied or restored over latest.pt)."""
        if "loop" not in ckpt.data:  # read for its networks only (config-only loads): nothing to compare
            return
        episodes = int(self.config()["episodes"])
        behind = {k: ckpt.member_episode(k) for k in range(len(ckpt.loop["episode"]))
                  if ckpt.member_episode(k) < episodes}
        if behind:
            at = ", ".join(f"seed index {k} at episode {e}" for k, e in behind.items())
            raise StaleCheckpoint(f"{ckpt.path} is older than the run: it holds {at}, but {self.path} finished "
                                  f"{episodes} episodes ({self.path / DONE} is there); an older checkpoint was "
                                  "copied or restored over latest.pt. Put the run's final latest.pt back, or delete "
                                  f"{self.path / DONE} and rerun apac-mj train with the same settings to train the "
                                  "missing episodes again from it (nothing was changed)")

    def _check_against_newest_checkpoint(self) -> None:
        """:meth:`check_config` with the newest checkpoint that loads (quietly: none loads, no check)."""
        found = self.checkpoint_files()
        if not found:
            return
        try:
            obj, path = checkpoint.load_newest_intact(found, required=("config",))
        except checkpoint.CheckpointError:
            return  # resuming says which file is damaged
        self.check_config(RunCheckpoint(obj, path))

    def discard_unstarted(self) -> None:
        """Remove what a new run wrote before it failed without a checkpoint (config.json, partial metrics), so
        that the corrected command is not refused as "a different config"."""
        if not self.checkpoint_files():
            for name in (CONFIG, METRICS, DONE):
                (self.path / name).unlink(missing_ok=True)

    # -- DONE ----------------------------------------------------------------------------------
    def finished(self) -> bool:
        """Training finished: DONE is there."""
        return (self.path / DONE).is_file()

    def check_finished(self) -> bool:
        """DONE is there and the final checkpoint loads; a damaged one un-finishes the run (with a warning).
        config.json must agree with it (:class:`RunMismatch`), and metrics.parquet with its rows (damaged or
        edited rows are restored from the checkpoint's copy, with a warning)."""
        if not self.finished():
            return False
        try:
            ckpt = RunCheckpoint(checkpoint.load(self.checkpoints / LATEST, required=CHECKPOINT_KEYS),
                                 self.checkpoints / LATEST)
        except checkpoint.CheckpointError as e:
            say(f"warning: {self.path} is marked finished but {e}; continuing from the newest intact checkpoint")
            (self.path / DONE).unlink()
            return False
        self.check_config(ckpt)
        self.read_metric_rows(ckpt)
        return True

    def mark_finished(self) -> None:
        atomic_write_text(self.path / DONE, "done\n")

    # -- metrics.parquet -----------------------------------------------------------------------
    def metric_rows(self) -> int:
        """Rows in metrics.parquet (0 if none yet, -1 if it cannot be read), read from the file's footer."""
        import pyarrow.parquet as pq

        path = self.path / METRICS
        try:
            return pq.ParquetFile(path).metadata.num_rows if path.is_file() else 0
        except MemoryError:
            raise  # out of memory is not a damaged file (apac_mj.util.memory)
        except Exception:  # noqa: BLE001 - a damaged file (resuming restores it from the checkpoint)
            return -1

    def has_metrics(self) -> bool:
        return (self.path / METRICS).is_file()

    def metrics(self) -> pd.DataFrame:
        """metrics.parquet: one row per (seed, episode)."""
        return pd.read_parquet(self.path / METRICS)

    def write_metrics(self, rows: list[dict[str, Any]]) -> bytes:
        """Atomically write the metric rows as metrics.parquet (columns: METRIC_COLUMNS, then TIMING_COLUMNS where the
        rows have them); return its bytes."""
        buf = io.BytesIO()
        pd.DataFrame(rows, columns=metric_columns(rows)).to_parquet(buf, index=False)
        table = buf.getvalue()
        atomic_write_bytes(self.path / METRICS, lambda f: f.write(table))
        return table

    def read_metric_rows(self, ckpt: RunCheckpoint) -> list[dict[str, Any]]:
        """The metric rows of checkpoint ``ckpt``: the first ``ckpt.metric_rows`` rows of metrics.parquet,
        checked against the checkpoint's digest. Missing, damaged, short or edited rows are restored from
        the checkpoint's copy (metrics.parquet rewritten, with a warning); a checkpoint from before copies
        cannot restore them: :class:`RunMismatch` naming the file."""
        path, n = self.path / METRICS, ckpt.metric_rows
        rows, problem = self._metric_rows(n)
        if problem is None and ckpt.metric_digest is not None and metric_digest(rows) != ckpt.metric_digest:
            problem = f"its first {n} rows differ from those checkpoint {ckpt.path} recorded (edited by hand?)"
        if problem is None:
            return rows
        kept = ckpt.metric_table()
        if kept is None:
            raise RunMismatch(f"{path} {problem}, and checkpoint {ckpt.path} was written by an older release that "
                              "kept no copy of the rows: restore metrics.parquet from a backup to resume this run "
                              "(its checkpoints are intact; apac-mj evaluate works without it)")
        say(f"warning: {path} {problem}; restored its {n} rows from checkpoint {ckpt.path}")
        self.write_metrics(kept)
        return kept

    def _metric_rows(self, n: int) -> tuple[list[dict[str, Any]], str | None]:
        """The first ``n`` rows of metrics.parquet, or why they cannot be read."""
        path = self.path / METRICS
        if n == 0:
            return [], None
        if not path.is_file():
            return [], f"is missing but the checkpoint expects {n} metric rows"
        try:
            df = pd.read_parquet(path)
        except MemoryError:
            raise  # out of memory is not a damaged file: nothing is restored or rewritten
        except Exception as e:  # noqa: BLE001 - pyarrow raises many types for a damaged file
            return [], f"cannot be read ({type(e).__name__}: {e})"
        if len(df) < n or list(df.columns)[:len(METRIC_COLUMNS)] != list(METRIC_COLUMNS):
            return [], (f"has {len(df)} rows, the checkpoint expects {n}" if len(df) < n
                        else f"has the columns {list(df.columns)}, not {list(METRIC_COLUMNS)} first")
        return [_plain(r) for r in df.iloc[:n].to_dict("records")], None

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
        buf = io.BytesIO()
        df.to_parquet(buf, index=False)
        atomic_write_bytes(self.eval_path(protocol), lambda f: f.write(buf.getvalue()))

    def evaluated(self) -> bool:
        """The frozen tests' summary (eval/summary.json) is there and reads (a damaged one: not evaluated)."""
        try:
            return bool(self.eval_summary())
        except ValueError:
            return False

    def eval_summary(self) -> dict[str, Any]:
        """eval/summary.json ({} if the run was not tested yet)."""
        return read_json(self.path / EVAL / "summary.json",
                         fix="run apac-mj evaluate on the run again: it rewrites the file") or {}

    def write_eval_summary(self, summary: dict[str, Any]) -> None:
        atomic_write_text(self.path / EVAL / "summary.json", json.dumps(summary, indent=2) + "\n")


def metric_columns(rows: list[dict[str, Any]]) -> list[str]:
    """metrics.parquet's columns for ``rows``: :data:`METRIC_COLUMNS`, then :data:`TIMING_COLUMNS` where the last row
    has them, then every other key of the rows in the order first seen (rows without one: NaN)."""
    timed = any(c in r for r in rows[-1:] for c in TIMING_COLUMNS)
    columns = [*METRIC_COLUMNS, *(TIMING_COLUMNS if timed else ())]
    seen = set(columns) | set(TIMING_COLUMNS)
    for r in rows:
        for key in r:
            if key not in seen:
                seen.add(key)
                columns.append(key)
    return columns


def metric_digest(rows: list[dict[str, Any]]) -> str:
    """A SHA-256 of metric rows' values in METRIC_COLUMNS order (floats by their exact repr; NaN as NaN)."""
    values = [[_scalar(r.get(c)) for c in METRIC_COLUMNS] + [_scalar(r[c]) for c in TRIAL_COLUMNS if c in r]
              for r in rows]
    return hashlib.sha256(json.dumps(values, allow_nan=True).encode()).hexdigest()


def _as_now(stored: dict[str, Any], now: dict[str, Any]) -> dict[str, Any]:
    """A recorded task in today's fields (those of ``now``, nested): a field it lacks (added since) takes its
    value in ``now`` (its default), a field it has that today's lack (removed since) is left out."""
    return {k: _as_now(stored[k], v) if isinstance(v, dict) and isinstance(stored.get(k), dict) else stored.get(k, v)
            for k, v in now.items()}


def _scalar(v: Any) -> Any:
    return v.item() if isinstance(v, np.generic) else v


def _plain(row: dict[str, Any]) -> dict[str, Any]:
    """numpy scalars -> Python scalars (so rebuilt rows equal freshly made ones)."""
    return {k: (v.item() if isinstance(v, np.generic) else v) for k, v in row.items()}
