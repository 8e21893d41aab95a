"""``apac-mj forced-response run|test|report|record``: the forced-response test (Hardwick et al. 2019) on a cued
task, one sub-command per action, each with only the options it acts on."""
from __future__ import annotations

import argparse

from apac_mj.commands import action_parser, study_arguments

PROTOCOL = """\
The protocol (docs/forced_response.md): every agent kind trains on a cued task (tasks/cued_targets.toml: four
cues, each with its target) for each practice length, then its frozen networks are tested after the remap
(two cues' targets swapped) at a range of allowed preparation times, many trials per time. A trial's habit is
ready after the cue's perception and one actor pass, its rule and its planner after the network passes they
compute, each at a measured price (timing.*; apac_mj.run.timing); at the deadline the arbitrator decides with
what is ready, and before anything is ready the agent guesses one of the cued targets (default=guess; "still":
no movement, a time-out)."""

RUN_EPILOG = PROTOCOL + """

STUDY/ gets protocol.json (the settings), runs/<kind>/ (resumable run directories), tests/p<episodes>/<kind>.parquet
(outcome counts per seed, variant, preparation time and cue; `episode`: the networks' training episode) and
report/ (curves.csv, peaks.csv, forced_response.png). Re-running the same command resumes: finished tests are
kept, runs resume from their checkpoints. On a rerun, agent kinds and practice lengths above the last one may be
added (said as such); any other change of a setting is refused naming it (nothing is written). One process
writes a study at a time (STUDY/.lock).

examples:
  apac-mj forced-response run --out results/forced_response
  apac-mj forced-response run --out results/fr_small --set seeds=0-2 --set practice=50,100 --set agents=ddpg,spac"""

TEST_EPILOG = """\
A run being trained is refused (its lock names the training's PID); one stopped or killed before its last episode
is tested with a warning naming the episode its networks are from. The table (one row per seed, variant,
preparation time and cue) records that episode in its `episode` column.

examples:
  apac-mj forced-response test results/forced_response/runs/apac --out apac.parquet
  apac-mj forced-response test RUN --out t.parquet --set prep_times_ms=250,450,900 --set timing.perception_ms=350"""

REPORT_EPILOG = """\
Reads STUDY/tests/p<episodes>/<kind>.parquet; every table is checked (columns, finite non-negative counts that
sum to the trials, no duplicated rows) and a damaged one refused naming the file, the column and the rows.

examples:
  apac-mj forced-response report results/forced_response
  apac-mj forced-response report results/forced_response --out /tmp/fr_report     # a read-only study"""

RECORD_EPILOG = """\
One trial of a remapped (or the given) cue at each preparation time, the same trial's latencies at every
deadline, into one Rerun recording; each trial's start event names it (trial i of n, its deadline and cue) and
says what the kind has ready by the deadline (its habit, its planner's iterations) and what acted.

examples:
  apac-mj forced-response record results/forced_response/runs/apac_voc --out trials.rrd --prep-times 250,350,900"""

#: The protocol fields a single test takes (the rest are the study's).
TEST_FIELDS = ("prep_times_ms", "trials", "repeats", "default", "told_value")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("forced-response", help="the forced-response test: habits unmasked under time pressure",
                       description="Train on a cued task, remap two cues, and test the frozen agents with a "
                                   "limited preparation time (Hardwick et al. 2019). `apac-mj forced-response "
                                   "ACTION --help` lists each action's options.",
                       epilog=PROTOCOL, formatter_class=argparse.RawDescriptionHelpFormatter)
    actions = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    _run_parser(actions)
    _test_parser(actions)
    _report_parser(actions)
    _record_parser(actions)


def _run_parser(actions: argparse._SubParsersAction) -> None:
    from apac_mj.experiments.forced_response import Protocol
    from apac_mj.run.timing import Timing
    from apac_mj.util.overrides import field_help

    p = action_parser(actions, "run", "train, remap, test and report the whole protocol into a study directory",
                RUN_EPILOG + "\n\nProtocol fields (--set NAME=VALUE):\n" + field_help(Protocol, skip=("timing", "run"))
                + "\n\nTiming fields (--set timing.NAME=VALUE, ms):\n" + field_help(Timing)
                + "\n\nThe run every kind trains: the fields of `apac-mj train --help` (--set task=..., seeds=0-9, "
                "batch_size=64, agent.mpc.horizon=4, ...; not episodes: the practice lengths set them)")
    study_arguments(p, "a protocol, timing, run or agent field (repeatable): seeds=0-9, practice=100,400,1000, "
                       "trials=100, timing.perception_ms=400, batch_size=64, ...")
    p.set_defaults(func=run_study)


def _test_parser(actions: argparse._SubParsersAction) -> None:
    from apac_mj.experiments.forced_response import Protocol
    from apac_mj.run.timing import Timing
    from apac_mj.util.overrides import field_help

    p = action_parser(actions, "test", "the forced-response test of one trained run on a cued task, into a table",
                TEST_EPILOG + "\n\nTest fields (--set NAME=VALUE):\n"
                + field_help(Protocol, skip=[n for n in _protocol_fields() if n not in TEST_FIELDS])
                + "\n\nTiming fields (--set timing.NAME=VALUE, ms):\n" + field_help(Timing))
    p.add_argument("run_dir", metavar="RUN_DIR", help="the trained run directory (a cued task), or a zoo cell "
                                                      "(zoo:NAME or its directory; docs/zoo.md)")
    p.add_argument("--out", required=True, metavar="FILE.parquet", help="the table to write (never overwritten)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="a test or timing field (repeatable): prep_times_ms=250,450,900, trials=100, repeats=3, "
                        "timing.perception_ms=350")
    p.set_defaults(func=run_test)


def _report_parser(actions: argparse._SubParsersAction) -> None:
    p = action_parser(actions, "report", "the report of a study's tests: curves, peak table and figure", REPORT_EPILOG)
    p.add_argument("study", metavar="STUDY_DIR", help="the study directory (its tests/)")
    p.add_argument("--out", default=None, metavar="DIR", help="where the report goes (default STUDY_DIR/report)")
    p.set_defaults(func=report)


def _record_parser(actions: argparse._SubParsersAction) -> None:
    from apac_mj.run.timing import Timing
    from apac_mj.util.overrides import field_help

    p = action_parser(actions, "record", "one trial per preparation time of a trained run, into a Rerun recording",
                RECORD_EPILOG + "\n\nTiming fields (--set timing.NAME=VALUE, ms):\n" + field_help(Timing))
    p.add_argument("run_dir", metavar="RUN_DIR", help="the trained run directory (a cued task), or a zoo cell "
                                                      "(zoo:NAME or its directory; docs/zoo.md)")
    p.add_argument("--out", required=True, metavar="FILE.rrd", help="the recording to write (never overwritten)")
    p.add_argument("--prep-times", default="250,450,900", metavar="MS,MS,...",
                   help="the preparation times (ms) of the recorded trials (default 250,450,900)")
    p.add_argument("--variant", default=None,
                   help="the tested variant (apac, apac_imagined, apac_voc, ...; default the kind's last)")
    p.add_argument("--cue", type=int, default=None, help="the cue shown (default the first remapped one)")
    p.add_argument("--member", type=int, default=0, help="which seed of the run (its index)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="timing.NAME=VALUE",
                   help="a timing field (repeatable): timing.perception_ms=350")
    p.set_defaults(func=record)


def _protocol_fields() -> list[str]:
    import dataclasses

    from apac_mj.experiments.forced_response import Protocol

    return [f.name for f in dataclasses.fields(Protocol)]


def protocol(items: list[str]):
    """The protocol from the --set items in the grammar of ``train`` and ``grid`` (:mod:`apac_mj.util.overrides`):
    a protocol field, ``timing.NAME``, a field of the run every kind trains (``task``, ``seeds``, ...) or an agent
    field (``batch_size``, ``agent.mpc.horizon``); each typed and checked before anything is written."""
    import dataclasses

    from apac_mj.config import AgentConfig, TrainConfig
    from apac_mj.experiments.forced_response import Protocol, study_run
    from apac_mj.run.timing import Timing
    from apac_mj.util import overrides

    run = {f.name for f in dataclasses.fields(TrainConfig)} - {"agent", "episodes"}  # episodes: the practice's
    own = {f.name for f in dataclasses.fields(Protocol)} - {"run"}
    data = overrides.apply_sets({}, items, agent_fields=overrides.keys(AgentConfig), top_level=own | run)
    if "seeds" in data:
        data["seeds"] = overrides.parse_seeds(data["seeds"])
    agent = overrides.typed_fields(AgentConfig, data.pop("agent", {}), "--set agent.", skip=("kind",))
    timing = Timing(**overrides.typed_fields(Timing, data.pop("timing", {}), "--set timing."))
    fields = overrides.typed_fields(Protocol, {k: v for k, v in data.items() if k in own}, "--set ",
                                    skip=("run", "timing"))
    base = study_run()
    cfg = dataclasses.replace(base, agent=dataclasses.replace(base.agent, **agent),
                              **overrides.typed_fields(TrainConfig, {k: v for k, v in data.items() if k in run},
                                                       "--set ", skip=("agent",)))
    return Protocol(**fields, timing=timing, run=cfg)


def plan_from(items: list[str], fields: tuple[str, ...] = TEST_FIELDS):
    """The :class:`TestPlan` of a single test from ``--set`` items: only ``fields`` (of the protocol) and
    ``timing.NAME``; any other key is refused naming the ones this action takes."""
    from apac_mj.experiments.forced_response import Protocol
    from apac_mj.run.timing import TestPlan, Timing
    from apac_mj.util import overrides

    allowed = {*fields, "timing"}
    data = overrides.apply_sets({}, items, agent_fields=(), top_level=allowed)
    timing = Timing(**overrides.typed_fields(Timing, data.pop("timing", {}), "--set timing."))
    skip = [n for n in _protocol_fields() if n not in fields]
    given = overrides.typed_fields(Protocol, data, "--set ", skip=skip)
    defaults = Protocol.__dataclass_fields__
    values = {n: given.get(n, defaults[n].default) for n in TEST_FIELDS}
    return TestPlan(tuple(float(t) for t in values["prep_times_ms"]), values["trials"], values["repeats"], 0, timing,
                    values["default"], values["told_value"])


def run_study(args: argparse.Namespace) -> int:
    from apac_mj.experiments import forced_response as fr
    from apac_mj.report.forced_response import write_report

    proto = protocol(args.overrides)  # every setting checked before anything is read or written
    print(write_report(fr.run(args.out, proto, progress=not args.no_progress)))
    return 0


def run_test(args: argparse.Namespace) -> int:
    from apac_mj.run.forced_response import test_run
    from apac_mj.util.files import atomic_write_parquet

    from apac_mj.run.zoo import resolve_run

    plan = plan_from(args.overrides)
    _new_file(args.out, ".parquet")
    df = test_run(resolve_run(args.run_dir), plan.prep_times_ms, plan.timing, plan.trials, plan.repeats,
                  default=plan.default, told=plan.told_value)
    atomic_write_parquet(args.out, df)
    print(args.out)
    return 0


def report(args: argparse.Namespace) -> int:
    from apac_mj.report.forced_response import write_report

    print(write_report(args.study, out=args.out))
    return 0


def record(args: argparse.Namespace) -> int:
    from apac_mj.experiments import forced_response as fr
    from apac_mj.run.zoo import resolve_run

    plan = plan_from(args.overrides, fields=())
    times = tuple(_ms(v) for v in args.prep_times.split(","))
    _new_file(args.out, ".rrd")
    print(fr.record_trials(resolve_run(args.run_dir), args.out, times, variant=args.variant, cue=args.cue, member=args.member,
                           timing=plan.timing, default=plan.default, told=plan.told_value))
    return 0


def _new_file(out: str, suffix: str) -> None:
    """``out`` names a ``suffix`` file that does not exist yet; else a ValueError / FileExistsError."""
    from pathlib import Path

    if not out.endswith(suffix):
        raise ValueError(f"--out {out}: give a {suffix} file")
    if Path(out).exists():
        raise FileExistsError(f"{out} exists; choose another --out (nothing was overwritten)")


def _ms(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"--prep-times: {text!r} is not a number of ms") from None
