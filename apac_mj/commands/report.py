"""``apac-mj report``: the paper's results section (Figs. 3-9 and a key-number table) from a results directory."""
from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("report", help="figures (PNG) and a markdown summary from a grid's results directory",
                       description="Write the paper's result figures (training success, test success, arbitration, "
                                   "steps and time, trajectories, generalization, occluded vision; then the "
                                   "scoreboard, the losses and any figure registered with "
                                   "apac_mj.report.register_figure) and report.md "
                                   "with every key number, its 95% interval (bootstrap over seeds; rates also Wilson), the per-seed values, the "
                                   "count behind it, intervals of the key differences and the paper's "
                                   "stated value, into RESULTS_DIR/report/ (or --out).",
                       epilog="examples:\n"
                              "  apac-mj report results/fidelity\n"
                              "  apac-mj report results/contested results/contested_cc --out reports/contested",
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("results", metavar="RESULTS_DIR", nargs="+",
                   help="a results directory written by apac-mj grid, or several read as one (cells of one study "
                        "run as separate grids; each cell in only one of them; --out required)")
    p.add_argument("--out", default=None, help="where the figures and report.md go (default: RESULTS_DIR/report)")
    p.add_argument("--title", default=None, help="report title (default: from the grid's preset)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from apac_mj.commands.hints import run_dir_hint
    from apac_mj.report import write_report

    for path in args.results:
        if (hint := run_dir_hint(path, "report")) is not None:
            raise FileNotFoundError(hint)
    out = write_report(args.results, args.out, title=args.title)
    print(f"report: {out / 'report.md'}")
    for f in sorted(out.glob("*.png")):
        print(f"figure: {f}")
    print(f"table:  {out / 'key_numbers.csv'}")
    return 0
