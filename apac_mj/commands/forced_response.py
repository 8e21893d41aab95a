"""``apac-mj forced-response``: the forced-response test (Hardwick et al. 2019) on a cued task."""
from __future__ import annotations

import argparse

EPILOG = """\
The protocol (docs/forced_response.md): every agent kind trains on a cued task (tasks/cued_targets.toml: four
cues, each with its target) for each practice length, then its frozen networks are tested after the remap
(two cues' targets swapped) at a range of allowed preparation times, many trials per time. A trial's habit is
ready after a latency, its planner after its iterations (timing.*); at the deadline the arbitrator decides with
what is ready, and before anything is ready the arm does not move (a time-out).

`record` writes one remapped-cue trial at each of a few preparation times (the same trial's latencies) into a
Rerun recording, each episode's start event saying when the habit and the planner were ready and which acted.

STUDY/ gets runs/<kind>/ (resumable run directories), tests/p<episodes>/<kind>.parquet (outcome counts per seed,
variant, preparation time and cue) and report/ (curves.csv, peaks.csv, forced_response.png). Re-running the same
command resumes: finished tests are kept, runs resume from their checkpoints.

examples:
  apac-mj forced-response run --out results/forced_response
  apac-mj forced-response run --out results/fr_small --set seeds=0-2 --set practice=50,100 --set agents=ddpg,spac
  apac-mj forced-response test results/forced_response/runs/apac --out apac.parquet --set timing.habit_latency_ms=250
  apac-mj forced-response report results/forced_response
  apac-mj forced-response record results/forced_response/runs/apac_voc --out trials.rrd --prep-times 250,350,900"""


def register(sub: argparse._SubParsersAction) -> None:
    from apac_mj.experiments.forced_response import Protocol, study_run
    from apac_mj.run.timing import Timing
    from apac_mj.util.overrides import field_help

    p = sub.add_parser("forced-response", help="the forced-response test: habits unmasked under time pressure",
                       description="Train on a cued task, remap two cues, and test the frozen agents with a "
                                   "limited preparation time (Hardwick et al. 2019).",
                       epilog=EPILOG + "\n\nProtocol fields (--set NAME=VALUE):\n"
                       + field_help(Protocol, skip=("timing", "run"))
                       + "\n\nTiming fields (--set timing.NAME=VALUE, ms):\n"
                       + field_help(Timing) + "\n\nThe run every kind trains: the fields of `apac-mj train --help` "
                       "(--set task=..., seeds=0-9, batch_size=64, agent.mpc.horizon=4, ...; not episodes: the "
                       "practice lengths set them)", formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("action", choices=("run", "test", "report", "record"),
                   help="run: the whole protocol into --out; test: one trained run's test into --out (a .parquet); "
                        "report: the report of a study directory; record: trials of a trained run into --out (.rrd)")
    p.add_argument("path", nargs="?", default=None,
                   help="test, record: the run directory; report: the study directory")
    p.add_argument("--out", default=None,
                   help="run: the study directory; test: the table to write (.parquet); record: the recording (.rrd)")
    p.add_argument("--prep-times", default="250,450,900", metavar="MS,MS,...",
                   help="record: the preparation times (ms) of the recorded trials (default 250,450,900)")
    p.add_argument("--variant", default=None,
                   help="record: the tested variant (apac, apac_imagined, apac_voc, ...; default the kind's last)")
    p.add_argument("--cue", type=int, default=None, help="record: the cue shown (default the first remapped one)")
    p.add_argument("--member", type=int, default=0, help="record: which seed of the run (its index)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="a protocol, timing, run or agent field (repeatable): seeds=0-9, practice=100,400,1000, "
                        "trials=100, timing.habit_latency_ms=300, batch_size=64, ...")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


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


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from apac_mj.experiments import forced_response as fr

    proto = protocol(args.overrides)  # every setting checked before anything is read or written
    if args.action == "run":
        if args.path is not None or args.out is None:
            raise ValueError("forced-response run takes --out STUDY_DIR and no path")
        from apac_mj.report.forced_response import write_report

        print(write_report(fr.run(args.out, proto, progress=not args.no_progress)))
    elif args.action == "test":
        from apac_mj.run.forced_response import test_run

        if args.path is None or args.out is None or not args.out.endswith(".parquet"):
            raise ValueError("forced-response test takes a run directory and --out FILE.parquet")
        if Path(args.out).exists():
            raise FileExistsError(f"{args.out} exists; choose another --out (nothing was overwritten)")
        df = test_run(args.path, proto.prep_times_ms, proto.timing, proto.trials, proto.repeats)
        df.to_parquet(args.out)
        print(args.out)
    elif args.action == "record":
        if args.path is None or args.out is None or not args.out.endswith(".rrd"):
            raise ValueError("forced-response record takes a run directory and --out FILE.rrd")
        if Path(args.out).exists():
            raise FileExistsError(f"{args.out} exists; choose another --out (nothing was overwritten)")
        times = tuple(_ms(v) for v in args.prep_times.split(","))
        print(fr.record_trials(args.path, args.out, times, variant=args.variant, cue=args.cue,
                               member=args.member, timing=proto.timing))
    else:
        if args.path is None:
            raise ValueError("forced-response report takes the study directory")
        from apac_mj.report.forced_response import write_report

        print(write_report(args.path))
    return 0


def _ms(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"--prep-times: {text!r} is not a number of ms") from None
