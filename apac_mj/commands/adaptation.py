"""``apac-mj adaptation run|report``: the adaptation protocol of a motor-control laboratory (issue 44) on every
agent kind, and its report (signatures, the two-state model, which controller acted)."""
from __future__ import annotations

import argparse

from apac_mj.commands import action_parser, study_arguments

PROTOCOL = """\
The protocol (docs/results/adaptation/): each agent kind (ddpg: habit only; spac: internal model only; apac:
both, arbitrated), and APAC twice more with its habit or its internal model frozen from the adaptation block
on (the lesions: which learner carries what), learns centre-out reaches (8 directions, each trial measured
against its own direction's baseline) with the compliant arm in a null field, then, learning on, runs the blocks of
the task's [trials] table (tasks/changing_target_compliant_adaptation.toml): baseline -> curl-field adaptation ->
brief reverse field (de-adaptation) -> channel trials (Smith et al. 2006's spontaneous recovery) -> re-exposure
(savings), with channel trials (error clamps: the learned lateral force) and catch trials (the field off: the
after-effect) drawn through. One episode is one trial. Per trial: the lateral error, the channel force and the
habit's share of the actions (which controller acted)."""

RUN_EPILOG = PROTOCOL + """

STUDY/ gets protocol.json (the settings), runs/<kind>/ (resumable run directories, as apac-mj train) and report/
(apac-mj adaptation report). Re-running the same command resumes: finished runs are kept, the others resume from
their checkpoints; agent kinds may be added, any other change of a setting is refused naming it (nothing is
written). One process writes a study at a time (STUDY/.lock).

examples:
  apac-mj adaptation run --out results/adaptation/study
  apac-mj adaptation run --out results/adaptation/small --set seeds=0-2 --set agents=ddpg,apac
  apac-mj adaptation run --out results/adaptation/part2 --set seeds=10-19 --set lesions=habit"""

REPORT_EPILOG = """\
Reads STUDY/runs/<kind>/metrics.parquet (and MotorNet's trials.csv from bench/motornet_adaptation.py with
--motornet); writes trials.csv, signatures.csv, summary.csv, lesion_effects.csv (intact APAC minus each
lesioned run, paired by seed: what that learner's learning adds), carriers.csv, two_state.csv,
two_state_summary.csv, learning.png, channel.png, after_effects.png and report.md. Per seed: the after-effect (catch-trial lateral error minus the
baseline's; people: opposite the field), the adaptation on late adaptation-block channel trials, the spontaneous
recovery (channel-block adaptation after its first 3 trials minus in them) and the savings (lateral error on the
first 10 field trials of adaptation minus of re-exposure); the two-state model (Smith et al. 2006) fitted to each
seed's channel trials; intervals over seeds (apac_mj.report.stats.seed_interval).

examples:
  apac-mj adaptation report results/adaptation/study
  apac-mj adaptation report results/adaptation/study --motornet results/adaptation/motornet/trials.csv
  apac-mj adaptation report results/adaptation/study results/adaptation/part2   # seeds 0-9 and 10-19 as one"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("adaptation", help="the adaptation protocol: which controller carries which part of adaptation",
                       description="Baseline, curl-field adaptation, brief reverse field, channel trials and "
                                   "re-exposure on every agent kind, learning on; the report fits the two-state "
                                   "model. `apac-mj adaptation ACTION --help` lists each action's options.",
                       epilog=PROTOCOL, formatter_class=argparse.RawDescriptionHelpFormatter)
    actions = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    _run_parser(actions)
    _report_parser(actions)


def _run_parser(actions: argparse._SubParsersAction) -> None:
    from apac_mj.experiments.adaptation import Protocol
    from apac_mj.util.overrides import field_help

    p = action_parser(actions, "run", "train every kind through the protocol into a study directory, then report",
                RUN_EPILOG + "\n\nProtocol fields (--set NAME=VALUE):\n" + field_help(Protocol, skip=("run",))
                + "\n\nThe run every kind trains: the fields of `apac-mj train --help` (--set task=..., seeds=0-9, "
                "batch_size=64, ...; not episodes: the task's blocks set them)")
    study_arguments(p, "a protocol, run or agent field (repeatable): agents=ddpg,spac,apac, seeds=0-9, "
                       "batch_size=64, planning_episodes=40, ...")
    p.set_defaults(func=run_study)


def _report_parser(actions: argparse._SubParsersAction) -> None:
    p = action_parser(actions, "report", "the report of a study: signatures, two-state fits and figures", REPORT_EPILOG)
    p.add_argument("study", metavar="STUDY_DIR", nargs="+",
                   help="the study directory (its runs/); several: one protocol run in parts over disjoint seeds "
                        "(--set seeds=10-19), reported as one")
    p.add_argument("--out", default=None, metavar="DIR",
                   help="where the report goes (default the first STUDY_DIR's report/)")
    p.add_argument("--motornet", default=None, metavar="TRIALS.csv",
                   help="MotorNet's per-trial table (bench/motornet_adaptation.py), drawn beside the agents")
    p.set_defaults(func=report)


def protocol(items: list[str]):
    """The protocol from the --set items in the grammar of ``train`` and ``grid`` (:mod:`apac_mj.util.overrides`):
    ``agents``, a field of the run every kind trains (``task``, ``seeds``, ...) or an agent field
    (``batch_size``, ``agent.planning_episodes``); each typed and checked, the task's blocks included, before
    anything is written."""
    import dataclasses

    from apac_mj.config import AgentConfig, TrainConfig
    from apac_mj.experiments.adaptation import Protocol, check_task, study_run
    from apac_mj.util import overrides

    run = {f.name for f in dataclasses.fields(TrainConfig)} - {"agent", "episodes"}  # episodes: the blocks'
    own_fields = {"agents", "lesions", "lesioned_kind"}
    data = overrides.apply_sets({}, items, agent_fields=overrides.keys(AgentConfig), top_level=own_fields | run)
    if "seeds" in data:
        data["seeds"] = overrides.parse_seeds(data["seeds"])
    agent = overrides.typed_fields(AgentConfig, data.pop("agent", {}), "--set agent.", skip=("kind",))
    own = overrides.typed_fields(Protocol, {k: v for k, v in data.items() if k in own_fields}, "--set ", skip=("run",))
    base = study_run()
    cfg = dataclasses.replace(base, agent=dataclasses.replace(base.agent, **agent),
                              **overrides.typed_fields(TrainConfig, {k: v for k, v in data.items() if k in run},
                                                       "--set ", skip=("agent",)))
    proto = Protocol(**own, run=cfg)
    check_task(cfg)
    return proto


def run_study(args: argparse.Namespace) -> int:
    from apac_mj.experiments import adaptation as study
    from apac_mj.report.adaptation import write_report

    proto = protocol(args.overrides)  # every setting checked before anything is read or written
    print(write_report(study.run(args.out, proto, progress=not args.no_progress)))
    return 0


def report(args: argparse.Namespace) -> int:
    from apac_mj.report.adaptation import write_report

    print(write_report(args.study if len(args.study) > 1 else args.study[0], out=args.out, motornet=args.motornet))
    return 0
