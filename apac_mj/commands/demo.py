"""``apac-mj demo``: a small real experiment on this machine: grid, report and a Rerun recording of APAC."""
from __future__ import annotations

import argparse

DESCRIPTION = """\
A small, real version of the paper's study on this machine (no service needed):
DDPG, SPAC and APAC trained on changing_target for a few seeds and a few hundred
episodes (preset tasks/presets/demo.toml), tested on the angle-grid targets and
under occluded vision, reported as the paper's figures and key-number table,
and the trained APAC recorded with Rerun (episodes enough for at least 60
steps: six seconds of the arm, played at its 100 ms step). About 7 minutes of
one CPU core (420 s of CPU time on the 2-core Intel Xeon development machine;
the cells run one after another, so the wall time grows with the load: 406 s
in one run there, 13.3 min in another at load average 5-10). Re-running resumes where it
stopped; it prints where the figures, the table and the recording are.

examples:
  apac-mj demo
  apac-mj demo --out results/demo --set seeds=3 --set episodes=300
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="small real experiment: 3 agents on changing_target, report, APAC recording",
                       description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--preset", default="demo", help="preset name or .toml path (default: demo)")
    p.add_argument("--out", default="results/demo", help="results directory (default: results/demo)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a preset field, repeatable (the grammar of grid --set, fields listed in "
                        "apac-mj grid --help; e.g. seeds=3, episodes=300)")
    p.add_argument("--record-episodes", type=int, default=None,
                   help="episodes of the trained APAC to record (default: as many as take --record-steps "
                        "steps, at most 40; 0 = no recording)")
    p.add_argument("--record-steps", type=int, default=60,
                   help="with the default --record-episodes: steps the recording shows at least (default 60, "
                        "six seconds of the arm at its 100 ms step)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from apac_mj.demo import run_demo

    result = run_demo(args.preset, args.out, args.overrides, record_episodes=args.record_episodes,
                      progress=not args.no_progress, say=print, record_steps=args.record_steps)
    print(f"\ndemo finished in {result.wall_s:.0f} s")
    print(f"figures:   {result.report_dir}/fig*.png")
    print(f"table:     {result.report_dir / 'report.md'} (and key_numbers.csv)")
    if result.recording is not None:
        print(f"recording: {result.recording}  (open with: rerun {result.recording})")
    return 0
