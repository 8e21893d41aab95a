"""The adaptation study (issue 44): each agent kind learns to reach with the compliant arm in a null field, then,
learning on, runs a motor-control laboratory's adaptation protocol: baseline -> curl-field adaptation -> brief
reverse-field de-adaptation -> a block of force-channel trials (Smith et al. 2006's spontaneous recovery) ->
re-exposure (savings), with channel and catch trials drawn through.

The protocol is the task's ``[trials]`` table (:mod:`apac_mj.suite.trials`; the study's task is
``tasks/changing_target_compliant_adaptation.toml``): one episode is one trial, and the run trains straight
through its blocks, so the protocol is a continuation of training. For each kind one run directory
``STUDY/runs/<kind>`` trains every seed side by side (resumable, as ``apac-mj train``). :func:`trial_table`
turns a run's metrics into the per-trial table of :data:`TRIAL_COLUMNS`; :func:`signatures` measures, per seed,
what the report states (:mod:`apac_mj.report.adaptation`).
"""
from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from apac_mj import kinds
from apac_mj.config import AgentConfig, TrainConfig

#: The study's task (its [trials] blocks are the protocol) and the kinds of the published study: habit only,
#: internal model only, both.
TASK = "changing_target_compliant_adaptation"
STUDY_KINDS = ("ddpg", "spac", "apac")
#: The lesions of the published study: the arbitrated kind with one learner frozen from the adaptation block on
#: (``AgentConfig.frozen``): "habit" (actor and critic: only the internal models adapt) and "model" (forward,
#: inverse and dynamics models: only the habit adapts). Both controllers still act, arbitrated as before.
LESIONS = ("habit", "model")
#: The kind the published lesions are made in: the study's arbitrated kind (both controllers act).
LESIONED_KIND = STUDY_KINDS[-1]
#: The blocks the protocol needs, by name, in this order (others may come between them, e.g. "training").
BLOCKS = ("baseline", "adaptation", "reverse", "channel", "reexposure")
#: A per-trial table (one row per seed and trial): the block, the field in units of the adaptation field's b (+1
#: that field, -1 the reverse, 0 none: null, channel and catch trials), the trial type's flags, the lateral error
#: (cm, + where the adaptation field pushes; NaN on channel trials), the adaptation (channel trials: the learned
#: lateral force over the adaptation field's force at the peak hand speed; NaN elsewhere), the share of the
#: trial's actions the habit chose (NaN for a learner without arbitration, e.g. MotorNet) and the centre-out
#: direction's index (-1: targets anywhere; each trial is measured against its own direction's baseline).
TRIAL_COLUMNS = ("seed", "trial", "block", "field", "channel", "catch", "lateral_error", "adaptation", "habit_share",
                 "direction")
#: The study's settings, as its runs were made (written before the first run, checked on every rerun).
PROTOCOL_FILE = "protocol.json"


def study_run() -> TrainConfig:
    """The run every kind trains: the study's task for all its episodes, 10 seeds (docs/results/adaptation/), a
    minibatch of 64 (as the forced-response study), APAC's planning phase shortened to 40 of the 50 null-field
    training episodes, so that its habit may act before the field, and the exploration noise annealed to the
    paper's 2 degrees over those 50 episodes (not 150), so that it is constant from the baseline on: annealed
    through the protocol it fell from 11 to 5 degrees between the adaptation and the channel block, a trend in
    every measure that no field made (docs/results/adaptation/, "The exploration noise")."""
    return TrainConfig(task=TASK, seeds=tuple(range(10)),
                       agent=AgentConfig(batch_size=64, planning_episodes=40, ou_sigma_anneal_episodes=50))


@dataclasses.dataclass(frozen=True)
class Protocol:
    """What the study runs. The defaults are the published study's."""

    #: The agent kinds, each trained through the protocol in its own run directory.
    agents: tuple[str, ...] = STUDY_KINDS
    #: The run every kind trains (its kind and episodes are the study's: the episodes are the blocks' total):
    #: the task (a [trials] table with the blocks of :data:`BLOCKS`), the seeds and every agent setting, as
    #: ``apac-mj train`` has them (``--set seeds=0-2``, ``--set batch_size=128``).
    run: TrainConfig = dataclasses.field(default_factory=study_run)
    #: Lesions (:data:`LESIONS`): for each, one more run of :attr:`lesioned_kind` whose learner of that name stops
    #: learning at the adaptation block's first trial (``runs/<kind>_<lesion>_frozen``). () = none.
    lesions: tuple[str, ...] = LESIONS
    #: The kind the lesions are made in: one with a habit and an internal model that both act (the study's
    #: arbitrated kind, :data:`LESIONED_KIND`).
    lesioned_kind: str = LESIONED_KIND

    def __post_init__(self) -> None:
        if not self.agents or len(set(self.agents)) != len(self.agents):
            raise ValueError(f"the protocol needs distinct agent kinds, got {self.agents!r}")
        for kind in self.agents:
            kinds.check(dataclasses.replace(self.run.agent, kind=kind))
        if any(lesion not in LESIONS for lesion in self.lesions) or len(set(self.lesions)) != len(self.lesions):
            raise ValueError(f"lesions must be distinct names from {LESIONS}, got {self.lesions!r}")
        if self.lesions and not kinds.get(self.lesioned_kind).arbitrates:
            raise ValueError(f"lesioned_kind must be a kind whose habit and internal model both act "
                             f"({', '.join(k for k in kinds.names() if kinds.get(k).arbitrates)}), got "
                             f"{self.lesioned_kind!r}")

    def arms(self) -> dict[str, TrainConfig]:
        """Every run of the study by its label: the kinds, then the lesioned runs (:func:`lesion_label`)."""
        out = {kind: self.train_config(kind) for kind in self.agents}
        start = block_start(self.run, "adaptation")
        for lesion in self.lesions:
            cfg = self.train_config(self.lesioned_kind)
            agent = dataclasses.replace(cfg.agent, frozen=(lesion,), frozen_from_episode=start)
            out[lesion_label(self.lesioned_kind, lesion)] = dataclasses.replace(cfg, agent=agent)
        return out

    def episodes(self) -> int:
        """Training episodes per seed: the task's blocks, end to end."""
        return sum(b.episodes for b in check_task(self.run).blocks)

    def train_config(self, kind: str) -> TrainConfig:
        """The run of ``kind``."""
        return dataclasses.replace(self.run, episodes=self.episodes(),
                                   agent=dataclasses.replace(self.run.agent, kind=kind))


def check_task(run: TrainConfig):
    """The run's [trials] table, if it holds the protocol: the blocks of :data:`BLOCKS` in that order, a field in
    the adaptation and re-exposure blocks, the opposite field in the reverse block and channel trials only in the
    channel block; else ValueError naming what is missing."""
    from apac_mj.suite import spec_for

    spec = spec_for(run)
    where = f"task {run.task!r}"
    if spec.trials is None:
        raise ValueError(f"{where} has no [trials] table: the protocol is its blocks "
                         f"(see tasks/{TASK}.toml)")
    blocks = {b.name: b for b in spec.trials.blocks}
    names = [b.name for b in spec.trials.blocks if b.name in BLOCKS]
    if names != list(BLOCKS):
        raise ValueError(f"{where}: the protocol needs the blocks {list(BLOCKS)} in this order, once each; "
                         f"the task has {[b.name for b in spec.trials.blocks]}")
    b = blocks["adaptation"].field_b
    if b == 0 or blocks["reexposure"].field_b != b or blocks["reverse"].field_b * b >= 0:
        raise ValueError(f"{where}: the adaptation and re-exposure blocks need one field (b != 0) and the reverse "
                         "block the opposite sign")
    if not blocks["channel"].channel:
        raise ValueError(f"{where}: block 'channel' must be all channel trials (channel = true)")
    return spec.trials


def lesion_label(kind: str, lesion: str) -> str:
    """The run label of ``kind`` with ``lesion``'s learner frozen: ``apac_habit_frozen``, ``apac_model_frozen``."""
    return f"{kind}_{lesion}_frozen"


def block_start(run: TrainConfig, name: str) -> int:
    """The training episode at which block ``name`` of the run's protocol starts."""
    start = 0
    for block in check_task(run).blocks:
        if block.name == name:
            return start
        start += block.episodes
    raise ValueError(f"task {run.task!r} has no block {name!r}")


def adaptation_b(run: TrainConfig) -> float:
    """The adaptation field's b (N·s/m): the unit of the per-trial ``field`` and ``adaptation``."""
    return next(b.field_b for b in check_task(run).blocks if b.name == "adaptation")


def run_path(study: Path, kind: str) -> Path:
    return Path(study) / "runs" / kind


def run(study: str | Path, protocol: Protocol, progress: bool = True, say: Callable[[str], None] = print) -> Path:
    """Train every kind through the protocol into ``study`` (finished runs kept, the others resumed) as the study's
    one writer (``STUDY/.lock``); returns ``study``. A rerun with other settings is refused (:func:`check_rerun`)
    before anything is written. The report: :func:`apac_mj.report.adaptation.write_report`."""
    from apac_mj.run.build import check as check_run
    from apac_mj.run.trainer import train
    from apac_mj.util.files import atomic_write_text
    from apac_mj.util.lock import locked

    study = Path(study)
    configs = protocol.arms()
    for cfg in configs.values():
        check_run(cfg)  # kind vs plant, memory, ...: refused before anything is written
    record = protocol_record(protocol)
    check_rerun(study, record)
    with locked(study, "adaptation study"):
        atomic_write_text(study / PROTOCOL_FILE, json.dumps(record, indent=1) + "\n")
        for i, (kind, cfg) in enumerate(configs.items()):
            say(f"[{i + 1}/{len(configs)}] {kind}: {cfg.episodes} episodes x {len(cfg.seeds)} seeds "
                f"-> {run_path(study, kind)}")
            train(cfg, run_path(study, kind), progress=progress)
    return study


def protocol_record(protocol: Protocol) -> dict:
    """``protocol`` in JSON form with the resolved task (its blocks: what the trials mean)."""
    from apac_mj.run.build import task_record
    from apac_mj.suite import spec_for

    task = task_record(protocol.run, spec_for(protocol.run)).spec
    return {**json.loads(json.dumps(dataclasses.asdict(protocol), default=str)), "task_spec": task}


def check_rerun(study: Path, record: dict) -> None:
    """A study already in ``study`` was made with ``record``'s settings (agent kinds may be added); else a
    ValueError naming the settings that differ. Reads only."""
    from apac_mj.config import migrate_study
    from apac_mj.util.files import read_json

    stored = read_json(Path(study) / PROTOCOL_FILE, fix=f"remove {study} or use another --out")
    if stored is None:
        if (Path(study) / "runs").is_dir():
            raise ValueError(f"{study} holds runs but no {PROTOCOL_FILE}; use another --out (nothing was written)")
        return
    stored = migrate_study(stored)  # fields added to the agent since the study was made: their old behaviour
    changed = [k for k in sorted({*stored, *record}) if k != "agents" and stored.get(k) != record.get(k)]
    if not set(stored["agents"]) <= set(record["agents"]):
        changed.append("agents (kinds may be added, not left out)")
    if changed:
        raise ValueError(f"{study} holds an adaptation study made with other settings ({', '.join(changed)}); use "
                         "another --out, or the same settings to resume. Nothing was written")


def trial_table(metrics: pd.DataFrame, b: float) -> pd.DataFrame:
    """A run's metrics (training rows with the [trials] columns) as the per-trial table (:data:`TRIAL_COLUMNS`):
    ``field`` is ``trial_field_b / b``; on a channel trial the adaptation is ``-channel_force_at_peak_speed /
    (b * peak_speed)`` (N over N·s/m x m/s: the agent's lateral force against the channel is negative where it
    compensates a b > 0 field, apac_mj.suite.trials)."""
    need = {"seed", "episode", "phase", "trial_block", "trial_type", "trial_field_b", "lateral_error",
            "channel_force_at_peak_speed", "peak_speed", "habit_actions", "planning_actions"}
    missing = sorted(need - set(metrics.columns))
    if missing:
        raise ValueError(f"the metrics lack {missing}: not a run of a task with a [trials] table")
    if not b:
        raise ValueError("the adaptation field's b must be nonzero")
    m = metrics[metrics["phase"] == "train"].sort_values(["seed", "episode"])
    channel = (m["trial_type"] == "channel").to_numpy()
    acts = (m["habit_actions"] + m["planning_actions"]).to_numpy(float)
    field_force = b * m["peak_speed"].to_numpy(float) / 100.0  # N: b (N·s/m) x the peak speed (cm/s -> m/s)
    adaptation = np.divide(-m["channel_force_at_peak_speed"].to_numpy(float), field_force,
                           out=np.full(len(m), np.nan), where=field_force != 0)  # a hand that never moved: NaN
    return pd.DataFrame({
        "seed": m["seed"].to_numpy(), "trial": m["episode"].to_numpy(), "block": m["trial_block"].to_numpy(),
        "field": m["trial_field_b"].to_numpy(float) / b, "channel": channel,
        "catch": (m["trial_type"] == "catch").to_numpy(),
        "lateral_error": np.where(channel, np.nan, m["lateral_error"].to_numpy(float) * math.copysign(1.0, b)),
        "adaptation": np.where(channel, adaptation, np.nan),
        "habit_share": np.divide(m["habit_actions"].to_numpy(float), acts, out=np.full(len(m), np.nan),
                                 where=acts > 0),
        "direction": m["trial_direction"].to_numpy(int) if "trial_direction" in m else np.full(len(m), -1)},
        columns=list(TRIAL_COLUMNS))


#: Trials that open the channel block (the state de-adaptation left) and field trials compared for savings.
CHANNEL_START, SAVINGS_TRIALS = 3, 10
#: The per-seed signatures (:func:`signatures`), with their units and what sign shows the human signature.
SIGNATURES = {
    "field_push": "cm; lateral error on the first 10 field trials of adaptation, each minus its direction's "
                  "baseline: > 0 (the field felt)",
    "error_reduction": "cm; lateral error on the first minus the last 10 field trials of adaptation: > 0",
    "after_effect": "cm; catch-trial lateral error minus its direction's baseline: < 0 (opposite the field) in people",
    "adaptation_late": "adaptation on the channel trials of the adaptation block's second half, minus the "
                       "direction's baseline channel trials: > 0",
    "spontaneous_recovery": "adaptation in the channel block after its first 3 trials minus in them (or 0 if "
                            "they are below 0): > 0",
    "savings": "cm; lateral error on the first 10 field trials of adaptation minus of re-exposure: > 0",
}


def baseline_corrected(t: pd.DataFrame) -> pd.DataFrame:
    """One seed's trials with each lateral error and channel adaptation taken relative to its direction's
    baseline: the mean of the baseline block's null trials (lateral error) and channel trials (adaptation) of
    the same direction; a direction without such a trial takes the mean over all directions (none at all: 0).
    With one direction (or targets anywhere, -1) this subtracts the baseline block's mean."""
    base = t[t["block"] == "baseline"]
    out = t.copy()
    for column, rows in (("lateral_error", base[~base["channel"]]), ("adaptation", base[base["channel"]])):
        overall = _mean(rows[column])
        by_direction = rows.groupby("direction")[column].apply(_mean)
        offset = t["direction"].map(by_direction).to_numpy(float)
        offset = np.where(np.isfinite(offset), offset, overall if math.isfinite(overall) else 0.0)
        out[column] = t[column].to_numpy(float) - offset
    return out


def signatures(table: pd.DataFrame) -> pd.DataFrame:
    """Per seed of a per-trial table (:data:`TRIAL_COLUMNS`): the :data:`SIGNATURES` and the habit's share of
    the actions in each block (``habit_<block>``); one row per seed. Lateral errors and adaptations are taken
    relative to each direction's baseline (:func:`baseline_corrected`). Spontaneous recovery counts a rise above
    zero only: a one-state learner de-adapted below zero also rises in the channel block, by decaying to 0."""
    rows = []
    for seed, t in table.sort_values(["seed", "trial"]).groupby("seed"):
        t = baseline_corrected(t)
        block = {name: t[t["block"] == name] for name in BLOCKS}
        catch = t[t["catch"] & t["block"].isin(["adaptation", "reexposure"])]
        adapt_channel = block["adaptation"][block["adaptation"]["channel"]]
        late = adapt_channel[adapt_channel["trial"] >= block["adaptation"]["trial"].median()]
        clamp = block["channel"]["adaptation"].to_numpy(float)
        row = {"seed": seed, "field_push": _first_field(block["adaptation"]),
               "error_reduction": _first_field(block["adaptation"]) - _first_field(block["adaptation"], last=True),
               "after_effect": _mean(catch["lateral_error"]),
               "adaptation_late": _mean(late["adaptation"]),
               "spontaneous_recovery": _mean(clamp[CHANNEL_START:]) - max(_mean(clamp[:CHANNEL_START]), 0.0),
               "savings": _first_field(block["adaptation"]) - _first_field(block["reexposure"])}
        row.update({f"habit_{name}": _mean(block[name]["habit_share"]) for name in BLOCKS})
        rows.append(row)
    return pd.DataFrame(rows)


def _mean(values) -> float:
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else math.nan


def _first_field(block: pd.DataFrame, last: bool = False) -> float:
    """Mean lateral error of a block's first (``last``: last) :data:`SAVINGS_TRIALS` field trials (neither channel
    nor catch)."""
    field = block[(block["field"] != 0) & ~block["channel"] & ~block["catch"]]["lateral_error"]
    return _mean(field.tail(SAVINGS_TRIALS) if last else field.head(SAVINGS_TRIALS))
