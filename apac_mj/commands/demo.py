"""``apac-mj demo``: a small real experiment on this machine: grid, report and a Rerun recording of APAC."""
from __future__ import annotations

import argparse

DESCRIPTION = """\
A small, real version of the paper's study on this machine (no service needed):
DDPG, SPAC and APAC trained on changing_target for a few seeds and a few hundred
episodes (preset tasks/presets/demo.toml), tested on the angle-grid targets and
under occluded vision, reported as the paper's figures and key-number table,
and three episodes of the trained APAC recorded with Rerun. About 7 minutes on a
2-core CPU. Re-running resumes where it stopped; it prints where the figures,
the table and the recording are.

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
                   help="override a preset field, repeatable (e.g. seeds=3, episodes=300)")
    p.add_argument("--record-episodes", type=int, default=3,
                   help="episodes of the trained APAC to record (default 3; 0 = no recording)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import time
    from pathlib import Path

    from apac_mj import grid
    from apac_mj.cli import main as cli_main
    from apac_mj.executors import LocalExecutor
    from apac_mj.report import write_report

    if args.record_episodes < 0:
        raise ValueError(f"--record-episodes must be >= 0, got {args.record_episodes}")
    start = time.perf_counter()
    preset = grid.load_preset(args.preset, args.overrides)
    out = Path(args.out)
    print(grid.describe(preset))
    grid.run_grid(preset, out, LocalExecutor(), progress=not args.no_progress)
    report_dir = write_report(out)
    rrd = None
    apac = [c for c in grid.cells(preset) if c.agent == "apac" and c.region == "all"]
    if args.record_episodes and apac:
        rrd = out / f"{apac[0].name}.rrd"
        code = cli_main(["record", "--run", str(out / apac[0].name), "--episodes", str(args.record_episodes),
                         "--out", str(rrd)])
        if code != 0:
            raise RuntimeError(f"recording the trained APAC failed (exit {code})")
    print(f"\ndemo finished in {time.perf_counter() - start:.0f} s")
    print(f"figures:   {report_dir}/fig*.png")
    print(f"table:     {report_dir / 'report.md'} (and key_numbers.csv)")
    if rrd is not None:
        print(f"recording: {rrd}  (open with: rerun {rrd})")
    return 0
