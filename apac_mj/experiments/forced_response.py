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
from typing import Any, Callable

from apac_mj.run.timing import Timing

#: The practice lengths of the published study (training episodes per seed): the "4 days" and "20 days" analogues
#: and the paper's length.
PRACTICE = (100, 400, 1000)
#: The agent kinds of the published study: the paper's three and the graded arbitrator (data, as a preset's list).
STUDY_KINDS = ("ddpg", "spac", "apac", "apac_voc")


@dataclasses.dataclass(frozen=True)
class Protocol:
    """What the study runs. The defaults are the published study's (docs/results/forced_response/)."""

    #: The agent kinds trained and tested (APAC's delta rule is also tested on the imagined transition's delta).
    agents: tuple[str, ...] = STUDY_KINDS
    #: The cued task (its ``[cues] swap`` names the remapped cues).
    task: str = "cued_targets"
    #: Seeds, trained side by side in each kind's run.
    seeds: tuple[int, ...] = tuple(range(10))
    #: Practice lengths (training episodes per seed, ascending), each followed by a test.
    practice: tuple[int, ...] = PRACTICE
    #: Allowed preparation times of the test (ms).
    prep_times_ms: tuple[float, ...] = tuple(float(t) for t in range(100, 1201, 50))
    #: Trials per seed, cue and preparation time.
    trials: int = 100
    #: Runs of the frozen agent per seed and cue (the model planner samples: each repeat is a fresh plan).
    repeats: int = 3
    #: Minibatch of the updates: 64, not the paper's 500, for the study's time budget (6.5 ms against 35.0 ms
    #: per update per seed at the paper's sizes, docs/results/arbitrators/; docs/results/forced_response/).
    batch_size: int = 64
    #: Time in a decision.
    timing: Timing = Timing()

    def __post_init__(self) -> None:
        if not self.agents or not self.seeds:
            raise ValueError("the protocol needs at least one agent kind and one seed")
        p = list(self.practice)
        if not p or p != sorted(set(p)) or p[0] < 1:
            raise ValueError(f"practice must be ascending distinct episode counts >= 1, got {self.practice}")
        self.timing.check_deadlines(self.prep_times_ms)
        for name in ("trials", "repeats", "batch_size"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {v!r}")


def test_path(study: Path, practice: int, kind: str) -> Path:
    return study / "tests" / f"p{practice}" / f"{kind}.parquet"


def run(study: str | Path, protocol: Protocol, progress: bool = True, say: Callable[[str], None] = print) -> Path:
    """Train and test the whole protocol into ``study`` (tests already written are kept); returns ``study``.
    The report: :func:`apac_mj.report.forced_response.write_report`."""
    from apac_mj import kinds
    from apac_mj.config import AgentConfig, TrainConfig
    from apac_mj.run.forced_response import test_run
    from apac_mj.run.trainer import train
    from apac_mj.suite import load_spec

    spec = load_spec(protocol.task)
    if not spec.cued or not spec.cues.swap:
        raise ValueError(f"task {protocol.task!r} is not a cued task with remapped cues ([cues] targets and swap)")
    for kind in protocol.agents:
        kinds.get(kind)
    study = Path(study)
    study.mkdir(parents=True, exist_ok=True)
    (study / "protocol.json").write_text(json.dumps(dataclasses.asdict(protocol), indent=1))
    for kind in protocol.agents:
        run_dir = study / "runs" / kind
        for episodes in protocol.practice:
            out = test_path(study, episodes, kind)
            if out.is_file():
                continue
            cfg = TrainConfig(task=protocol.task, seeds=protocol.seeds, episodes=episodes,
                              agent=AgentConfig(kind=kind, batch_size=protocol.batch_size))
            train(cfg, run_dir, progress=progress)
            say(f"forced-response test: {kind} after {episodes} episodes")
            df = test_run(run_dir, protocol.prep_times_ms, protocol.timing, protocol.trials, protocol.repeats)
            out.parent.mkdir(parents=True, exist_ok=True)
            df.to_parquet(out.with_suffix(".tmp"))
            out.with_suffix(".tmp").replace(out)
    return study


def protocol_from(overrides: dict[str, Any]) -> Protocol:
    """A :class:`Protocol` with ``overrides`` (field -> value; ``timing.<field>`` for the timing's)."""
    timing = {k.split(".", 1)[1]: v for k, v in overrides.items() if k.startswith("timing.")}
    rest = {k: v for k, v in overrides.items() if not k.startswith("timing.")}
    unknown = set(rest) - {f.name for f in dataclasses.fields(Protocol)} - {"timing"}
    unknown |= {f"timing.{k}" for k in set(timing) - {f.name for f in dataclasses.fields(Timing)}}
    if unknown:
        raise ValueError(f"unknown setting(s) {sorted(unknown)}; known: "
                         f"{[f.name for f in dataclasses.fields(Protocol) if f.name != 'timing']} and "
                         f"{['timing.' + f.name for f in dataclasses.fields(Timing)]}")
    return Protocol(**rest, timing=Timing(**timing))


def record_trials(run_dir: str | Path, out: str | Path, prep_times_ms: tuple[float, ...] = (250.0, 450.0, 900.0),
                  variant: str | None = None, cue: int | None = None, member: int = 0, seed: int = 0,
                  timing: Timing = Timing(), say: Callable[[str], None] = print) -> Path:
    """One forced-response trial of a trained run's ``member`` at each of ``prep_times_ms`` (default: short,
    intermediate, long) into one Rerun recording ``out``: the same trial's latencies (drawn with ``seed``) at each
    deadline, a remapped ``cue`` (default the first), each episode's start event saying when the habit and the
    planner were ready and which acted (each also passed to ``say``); a time-out is one step without movement."""
    import numpy as np
    import torch

    from apac_mj.kinds import arbitrator_for, get as get_kind
    from apac_mj.recording.recording import EpisodeRecorder
    from apac_mj.run import forced_response as fr
    from apac_mj.run.build import load_run
    from apac_mj.run.evaluate import eval_env
    from apac_mj.run.rollout import EpisodeLoop
    from apac_mj.run.run_dir import config_dict
    from apac_mj.run.variants import label
    from apac_mj.suite import spec_for

    times = timing.check_deadlines(prep_times_ms)
    loaded = load_run(run_dir)
    cfg, spec = loaded.cfg, spec_for(loaded.cfg)
    if not spec.cued or not spec.cues.swap:
        raise ValueError(f"run {run_dir}: task {cfg.task!r} is not a cued task with remapped cues")
    cue = spec.cues.remapped[0] if cue is None else cue
    tested = fr.variants(cfg.agent)
    variant = variant or tested[-1]
    if variant not in tested:
        raise ValueError(f"variant {variant!r}: a {cfg.agent.kind} run is tested as {tested}")
    if not 0 <= cue < spec.cues.n:
        raise ValueError(f"cue {cue}: task {cfg.task!r} has cues 0..{spec.cues.n - 1}")
    if not 0 <= member < len(cfg.seeds):
        raise ValueError(f"member {member}: run {run_dir} has {len(cfg.seeds)} seed(s), members 0..{len(cfg.seeds) - 1}")
    kind = get_kind(cfg.agent.kind)
    env = eval_env(cfg, spec, loaded.ckpt.member_lengths(), occluded=False)
    loop = EpisodeLoop(loaded.agent, arbitrator_for(cfg.agent), env, zone_radius=spec.zone_radius, adapt=False)
    loop.load_state_dict(loaded.ckpt.running_statistics())
    c = fr.candidates(loop, cfg, variant, 1, timing)
    rng = np.random.default_rng(seed)
    H = max(rng.normal(timing.habit_latency_ms, timing.latency_sd_ms), 0.0)
    S = max(rng.normal(timing.planning_latency_ms, timing.latency_sd_ms), 0.0)
    K, iteration = loop.planner.max_iterations, fr.iteration_ms(cfg.agent, timing)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    everyone = np.ones(env.E, dtype=bool)
    with EpisodeRecorder(out.parent, out=out, member=member, config=config_dict(cfg)) as recorder:
        env.set_mapping_override(True)
        env.set_cue_override(np.full(env.E, cue))
        for t in times:
            plan, habit, k = fr.choose(t, np.array(H), np.array(S), c.rule_habit[member, cue, 0],
                                       c.rule_iterations[member, cue, 0], c.rule_ms, kind.uses_habit,
                                       kind.uses_planner, iteration, K)
            ready = int(np.clip(np.floor((t - S) / iteration), 0, K)) if kind.uses_planner else 0
            who = (f"the planner acts ({int(k)} iteration(s))" if plan else "the habit acts" if habit
                   else "nothing is ready: no movement (a time-out)")
            recorder.note = (f"deadline {t:.0f} ms: {who}; habit ready at {H:.0f} ms, planner from {S:.0f} ms "
                             f"({ready} of {K} iteration(s) by the deadline); {label(variant, tested)}, "
                             f"cue {cue} (remapped)")
            say(recorder.note)
            if plan or habit:
                fr.movement(loop, fr.Committed(bool(habit), int(k)), hooks=[recorder])
            else:
                run = EpisodeLoop(loop.agent, fr.Committed(True), env, zone_radius=loop.zone_radius,
                                  hooks=[recorder], adapt=False, integrator=loop.integrator, planner=loop.planner)
                st = run.begin(everyone)
                info = run.act(st, everyone, np.zeros(env.E, dtype=np.int64), explore=False,
                               override=lambda a, h: (torch.zeros_like(a), h))
                run.advance(st, info, everyone)
        env.set_cue_override(None)
        env.set_mapping_override(None)
    return out
