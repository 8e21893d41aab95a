"""The forced-response protocol (docs/forced_response.md): practice on a cued task, remap, test under time pressure.

For each agent kind one run directory ``STUDY/runs/<kind>`` trains every seed side by side with the original
mapping; at each practice length (ascending) the frozen networks take the forced-response test under the
remapped mapping (:func:`apac_mj.run.forced_response.test_run`), written to
``STUDY/tests/p<episodes>/<kind>.parquet``, and the run is then extended to the next length. Everything resumes:
a finished test is kept, a run resumes from its checkpoint. ``STUDY/report/`` gets the curves, the peak table and
the figure (:mod:`apac_mj.report.forced_response`).
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import TYPE_CHECKING, Callable

from apac_mj import kinds
from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.run.timing import TestPlan, Timing

#: The practice lengths of the published study (training episodes per seed): the "4 days" and "20 days" analogues
#: and the paper's length.
PRACTICE = (100, 400, 1000)
#: The agent kinds of the published study: the paper's three and the graded arbitrator (data, as a preset's list).
STUDY_KINDS = ("ddpg", "spac", "apac", "apac_voc")

if TYPE_CHECKING:
    from apac_mj.run.forced_response import Candidates, Schedule
    from apac_mj.run.rollout import EpisodeLoop


def study_run() -> TrainConfig:
    """The run every kind of the published study trains: the cued task, 10 seeds, and a minibatch of 64, not the
    paper's 500, for the study's time budget (6.5 ms against 35.0 ms per update per seed at the paper's sizes,
    docs/results/arbitrators/; docs/results/forced_response/)."""
    return TrainConfig(task="cued_targets", seeds=tuple(range(10)), agent=AgentConfig(batch_size=64))


@dataclasses.dataclass(frozen=True)
class Protocol:
    """What the study runs. The defaults are the published study's (docs/results/forced_response/)."""

    #: The agent kinds trained and tested (APAC's delta rule is also tested on the imagined transition's delta).
    agents: tuple[str, ...] = STUDY_KINDS
    #: Practice lengths (training episodes per seed, ascending), each followed by a test.
    practice: tuple[int, ...] = PRACTICE
    #: Allowed preparation times of the test (ms).
    prep_times_ms: tuple[float, ...] = tuple(float(t) for t in range(100, 1201, 50))
    #: Trials per seed, cue and preparation time.
    trials: int = 100
    #: Runs of the frozen agent per seed and cue (the model planner samples: each repeat is a fresh plan).
    repeats: int = 3
    #: Time in a decision.
    timing: Timing = Timing()
    #: The response when nothing is ready by the deadline: "guess" (a uniformly drawn cued target) or "still"
    #: (no movement: a time-out).
    default: str = "guess"
    #: The MPC planner closes its horizon with the critic of the cue the told target had; false (the default):
    #: the shown cue's, which after a remap values the old target (:attr:`TestPlan.told_value`).
    told_value: bool = False
    #: The run every kind trains (its kind and episodes are the study's): the cued task (its ``[cues] swap``
    #: names the remapped cues), the seeds (side by side in each kind's run) and every agent setting, as
    #: ``apac-mj train`` has them (``--set seeds=0-2``, ``--set batch_size=128``, ``--set agent.mpc.horizon=4``).
    run: TrainConfig = dataclasses.field(default_factory=study_run)

    def __post_init__(self) -> None:
        if not self.agents:
            raise ValueError("the protocol needs at least one agent kind")
        for kind in self.agents:
            kinds.check(dataclasses.replace(self.run.agent, kind=kind))
        p = list(self.practice)
        if not p or p != sorted(set(p)) or p[0] < 1:
            raise ValueError(f"practice must be ascending distinct episode counts >= 1, got {self.practice}")
        self.test_plan()  # the deadlines, trials and repeats: checked once, here

    def test_plan(self, seed: int = 0) -> TestPlan:
        """The test each practice length ends with."""
        return TestPlan(tuple(float(t) for t in self.prep_times_ms), self.trials, self.repeats, seed, self.timing,
                        self.default, self.told_value)

    def train_config(self, kind: str, episodes: int) -> TrainConfig:
        """The run of ``kind`` at a practice length of ``episodes``."""
        return dataclasses.replace(self.run, episodes=episodes, agent=dataclasses.replace(self.run.agent, kind=kind))


def test_path(study: Path, practice: int, kind: str) -> Path:
    return study / "tests" / f"p{practice}" / f"{kind}.parquet"


def run(study: str | Path, protocol: Protocol, progress: bool = True, say: Callable[[str], None] = print) -> Path:
    """Train and test the whole protocol into ``study`` (tests already written are kept) as the study's one
    writer (``STUDY/.lock``); returns ``study``. A rerun is checked against ``protocol.json`` first
    (:func:`check_rerun`). The report: :func:`apac_mj.report.forced_response.write_report`."""
    from apac_mj.run.build import task_record
    from apac_mj.suite import spec_for
    from apac_mj.util.files import atomic_write_text, remove_stale_temporaries
    from apac_mj.util.lock import locked

    spec = spec_for(protocol.run)
    if not spec.cued or not spec.cues.swap:
        raise ValueError(f"task {protocol.run.task!r} is not a cued task with remapped cues ([cues] targets and swap)")
    study = Path(study)
    record = protocol_record(protocol, task_record(protocol.run, spec).spec)
    with locked(study, "forced-response study"):
        for line in check_rerun(study, record):
            say(line)
        for stale in remove_stale_temporaries(study / "tests"):  # a killed writer's half-written table
            say(f"removed {stale}, a temporary file a killed writer left")
        atomic_write_text(study / PROTOCOL_FILE, json.dumps(record, indent=1) + "\n")
        for kind in protocol.agents:
            _kind(study, protocol, kind, progress, say)
    return study


def _kind(study: Path, protocol: Protocol, kind: str, progress: bool, say: Callable[[str], None]) -> None:
    """Every practice length of ``kind`` not tested yet: train (or extend) its run, then test it."""
    from apac_mj.run.forced_response import test_run
    from apac_mj.run.trainer import train
    from apac_mj.util.files import atomic_write_parquet

    plan = protocol.test_plan()
    run_dir = study / "runs" / kind
    for episodes in protocol.practice:
        out = test_path(study, episodes, kind)
        if out.is_file():
            continue
        train(protocol.train_config(kind, episodes), run_dir, progress=progress)
        say(f"forced-response test: {kind} after {episodes} episodes")
        df = test_run(run_dir, plan.prep_times_ms, plan.timing, plan.trials, plan.repeats, expect_episodes=episodes,
                      default=plan.default, told=plan.told_value)
        atomic_write_parquet(out, df)


#: The study's settings, as its tests were made (written before the first test, checked on every rerun).
PROTOCOL_FILE = "protocol.json"
#: The settings a rerun may extend (the others must be the same): agent kinds, and practice lengths above the last.
EXTENSIBLE = ("agents", "practice")


def protocol_record(protocol: Protocol, task: dict) -> dict:
    """``protocol`` in JSON form with the resolved task it trains (its cues and swap: what the tests mean)."""
    return {**json.loads(json.dumps(dataclasses.asdict(protocol), default=str)), "task_spec": task}


def check_rerun(study: Path, record: dict) -> list[str]:
    """What a rerun with ``record`` (:func:`protocol_record`) over ``study`` adds (lines to say), or a ValueError
    naming every setting that differs from ``protocol.json`` (old and new values): only agent kinds, and practice
    lengths above the study's last, may be added. Tests without a protocol.json are refused (their settings are
    unknown). Reads only."""
    from apac_mj.config import migrate_study
    from apac_mj.run.run_dir import diff
    from apac_mj.util.files import read_json

    stored = read_json(study / PROTOCOL_FILE, fix=f"remove {study / 'tests'} and rerun, or use another --out")
    if stored is None:
        if any((study / "tests").glob("p*/*.parquet")):
            raise ValueError(f"{study} holds tests but no {PROTOCOL_FILE} recording the settings they were made "
                             "with; use another --out (nothing was written)")
        return []
    stored = migrate_study(stored)  # fields added to the agent since the study was made: their old behaviour
    fixed = [k for k in stored if k not in EXTENSIBLE and k in record]  # a key the study predates: not checked
    changed = diff({k: stored[k] for k in fixed}, {k: record[k] for k in fixed}, "in the study")
    changed += _not_extended(stored, record)
    if changed:
        raise ValueError(f"{study} holds a forced-response study made with other settings ({'; '.join(changed)}); "
                         "its tests would be mixed with new ones. Use another --out, or the same settings to resume "
                         f"(agent kinds, and practice lengths above {max(stored['practice'])}, may be added; seeds "
                         "cannot: each kind's seeds train side by side in one run). Nothing was written")
    added = [k for k in record["agents"] if k not in stored["agents"]]
    longer = [p for p in record["practice"] if p not in stored["practice"]]
    return ([f"extending {study}: adding agent kind(s) {', '.join(added)}"] if added else []) + \
        ([f"extending {study}: adding practice length(s) {', '.join(map(str, longer))} episodes"] if longer else [])


def _not_extended(stored: dict, record: dict) -> list[str]:
    """The extensible settings that ``record`` changes other than by adding (kinds; practice above the last)."""
    out = []
    if not set(stored["agents"]) <= set(record["agents"]):
        out.append(f"agents: {stored['agents']!r} in the study, {record['agents']!r} now (kinds may be added, "
                   "not left out)")
    old, new = stored["practice"], record["practice"]
    if not set(old) <= set(new) or any(p < max(old) for p in new if p not in old):
        out.append(f"practice: {old!r} in the study, {new!r} now (lengths above {max(old)} may be added; "
                   "none left out)")
    return out


def record_trials(run_dir: str | Path, out: str | Path, prep_times_ms: tuple[float, ...] = (250.0, 450.0, 900.0),
                  variant: str | None = None, cue: int | None = None, member: int = 0, seed: int = 0,
                  timing: Timing = Timing(), say: Callable[[str], None] = print, default: str = "guess",
                  told: bool = False) -> Path:
    """One forced-response trial of a trained run's ``member`` at each of ``prep_times_ms`` (default: short,
    intermediate, long) into one Rerun recording ``out``: the same trial's latencies and guess (drawn with
    ``seed``) at each deadline, a remapped ``cue`` (default the first), each episode's start event saying when the
    habit and the planner were ready and which acted (each also passed to ``say``); where nothing is ready, one
    step without movement, captioned with the guessed target and its outcome (the test classifies a guess by its
    target and simulates no movement for it; ``default`` "still": a time-out); ``told``:
    :attr:`TestPlan.told_value`."""
    import numpy as np

    from apac_mj.recording.recording import EpisodeRecorder
    from apac_mj.run import forced_response as fr
    from apac_mj.run.run_dir import config_dict
    from apac_mj.run.variants import label

    plan = TestPlan(tuple(float(t) for t in prep_times_ms), 1, 1, seed, timing, default, told)
    loaded, loop = fr.frozen_loop(run_dir)
    cfg, cues = loaded.cfg, loaded.spec.cues
    cue = cues.remapped[0] if cue is None else cue
    tested = fr.variants(cfg.agent, loop.arbitrator)
    variant = _checked_trial(run_dir, cfg, tested, variant or tested[-1], cue, cues.n, member)
    cues_searched = cues.n if fr.told_value(loop, told) else 0
    c = fr.candidates(loop, cfg, variant, 1)
    sched = fr.schedule(variant, cfg.agent, timing, loop.planner.max_iterations, loop.arbitrator, cues_searched)
    rng = np.random.default_rng(seed)
    H, S = fr.latencies(sched, timing.latency_sd_ms, rng)
    guess = int(rng.integers(0, c.guess.shape[1])) if default == "guess" else None
    shown = f"cue {cue} ({'remapped' if cue in cues.remapped else 'unchanged'})"
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with EpisodeRecorder(out.parent, out=out, member=member, config=config_dict(cfg)) as recorder, \
            loop.env.overridden(cue=cue, remapped=True):
        for i, t in enumerate(plan.prep_times_ms):
            habit, k, recorder.note = _at_deadline(c, sched, t, float(H), float(S), member, cue,
                                                   f"{label(variant, tested)}, {shown}", guess,
                                                   kinds.get(cfg.agent.kind).label)
            recorder.title = f"trial {i + 1} of {len(plan.prep_times_ms)} (deadline {t:.0f} ms, {shown})"
            say(f"{recorder.title}: {recorder.note}")
            if k or habit:
                fr.movement(loop, fr.Committed(habit, k), hooks=[recorder], episode=i)
            else:
                fr.no_movement(loop, hooks=[recorder], episode=i)
    return out


def _checked_trial(run_dir: str | Path, cfg: TrainConfig, tested: tuple[str, ...], variant: str, cue: int,
                   n_cues: int, member: int) -> str:
    """``variant`` if the run was tested as it and ``cue`` and ``member`` exist; else a ValueError naming them."""
    if variant not in tested:
        raise ValueError(f"variant {variant!r}: a {cfg.agent.kind} run is tested as {tested}")
    if not 0 <= cue < n_cues:
        raise ValueError(f"cue {cue}: task {cfg.task!r} has cues 0..{n_cues - 1}")
    if not 0 <= member < len(cfg.seeds):
        raise ValueError(f"member {member}: run {run_dir} has {len(cfg.seeds)} seed(s), "
                         f"members 0..{len(cfg.seeds) - 1}")
    return variant


def _at_deadline(c: Candidates, sched: Schedule, t: float, H: float, S: float, member: int, cue: int, what: str,
                 guess: int | None, kind: str) -> tuple[bool, int, str]:
    """What acts at the deadline ``t`` in the trial whose habit is ready at ``H`` and planner starts at ``S``:
    the habit (True, 0), the planner with k iterations (False, k) or nothing (False, 0: the ``guess``-ed cued
    target, None: no movement), and the caption (``kind``: the kind's label)."""
    import numpy as np

    from apac_mj.run import forced_response as fr
    from apac_mj.run.timing import OUTCOMES

    K = len(sched.plan_ms)
    plan, habit, k = fr.choose(t, np.array(H), np.array(S), c.rule_habit[member, cue, 0],
                               c.rule_iterations[member, cue, 0], sched)
    ready = int(fr.ready_iterations(t, np.array(H), np.array(S), sched))
    nothing = ("nothing is ready: no movement (a time-out)" if guess is None else
               f"nothing is ready: a guess, target {guess} ({OUTCOMES[int(c.guess[cue, guess])]})")
    who = f"the planner acts ({int(k)} iteration(s))" if plan else "the habit acts" if habit else nothing
    has_habit = f"habit ready at {H:.0f} ms" if sched.uses_habit else f"no habit ({kind} has none)"
    start = f"after the habit's rollout from {H:.0f} ms" if sched.after_habit else f"from {S:.0f} ms"
    has_plan = (f"planner {start} ({ready} of {K} iteration(s) by the deadline)" if sched.uses_planner
                else f"no planner ({kind} has none)")
    caption = f"deadline {t:.0f} ms: {who}; {has_habit}, {has_plan}; {what}"
    return bool(habit), int(k) if plan else 0, caption
