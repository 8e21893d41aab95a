"""``apac-mj report``: the paper's results section (Figs. 3-9 and a key-number table) from a results directory,
or the learning curves of one run (``--run``)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

#: Figure formats and the default resolution (apac_mj.report.figures.FORMATS, DEFAULT_DPI; not imported here,
#: to keep ``apac-mj --help`` free of matplotlib).
FORMATS, DEFAULT_DPI = ("png", "svg", "pdf"), 110


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("report", help="figures and a markdown summary from a grid's results directory, or one "
                                      "run's learning curves (--run)",
                       description="Write the paper's result figures (training success, test success, arbitration, "
                                   "steps and time, trajectories, generalization, occluded vision; then the "
                                   "scoreboard, the losses and any figure registered with "
                                   "apac_mj.report.register_figure) and report.md "
                                   "with every key number, its 95% interval (bootstrap over seeds; rates also Wilson), the per-seed values, the "
                                   "count behind it, intervals of the key differences and the paper's "
                                   "stated value, into RESULTS_DIR/report/ (or --out). Damaged tables (a missing "
                                   "column, NaN or inf values, a training episode twice, fewer test rows than "
                                   "eval/summary.json counts) are refused naming the file and column; a grid not "
                                   "complete is reported with a 'partial: N of M cells' notice. With --run RUN_DIR: "
                                   "the learning curves of one run (training success, steps, habit share) as "
                                   "RUN_DIR/report/learning_curves.<format>.",
                       epilog="examples:\n"
                              "  apac-mj report results/fidelity\n"
                              "  apac-mj report results/fidelity --format pdf            # vector figures\n"
                              "  apac-mj report results/fidelity --dpi 300\n"
                              "  apac-mj report --run runs/apac_ct                       # one run's learning curves\n"
                              "  apac-mj report results/contested results/contested_cc --out reports/contested",
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("results", metavar="RESULTS_DIR", nargs="*",
                   help="a results directory written by apac-mj grid, or several read as one (cells of one study "
                        "run as separate grids; each cell in only one of them; --out required)")
    p.add_argument("--run", metavar="RUN_DIR", default=None,
                   help="instead of a grid: the learning curves of one run directory (apac-mj train's, or a cell)")
    p.add_argument("--out", default=None, help="where the figures and report.md go (default: RESULTS_DIR/report, "
                                               "or RUN_DIR/report with --run)")
    p.add_argument("--title", default=None, help="report title (default: from the grid's preset)")
    p.add_argument("--format", dest="fmt", choices=FORMATS, default="png",
                   help="figure file format: png (default), or svg / pdf (vector, for papers)")
    p.add_argument("--dpi", type=int, default=DEFAULT_DPI,
                   help=f"resolution of the figures in dots per inch, 10-1200 (default {DEFAULT_DPI}; raster "
                        "parts of svg/pdf too)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from apac_mj.commands.hints import run_dir_hint
    from apac_mj.experiments.results import completeness
    from apac_mj.report import write_report

    if args.run is not None:
        if args.results:
            raise ValueError("give either RESULTS_DIR (a grid's report) or --run RUN_DIR (one run's curves), not both")
        print(f"figure: {write_run_curves(args.run, args.out, args.fmt, args.dpi)}")
        return 0
    if not args.results:
        raise ValueError("give a RESULTS_DIR (apac-mj grid's output) or --run RUN_DIR (one run's learning curves)")
    for path in args.results:
        if (hint := run_dir_hint(path, "report")) is not None:
            raise FileNotFoundError(f"{hint}; or apac-mj report --run {path} for its learning curves")
    out = write_report(args.results, args.out, title=args.title, fmt=args.fmt, dpi=args.dpi)
    notice = completeness(args.results).notice()
    if notice:
        print(notice, file=sys.stderr)
    print(f"report: {out / 'report.md'}")
    for f in sorted(out.glob(f"*.{args.fmt}")):
        print(f"figure: {f}")
    print(f"table:  {out / 'key_numbers.csv'}")
    return 0


def write_run_curves(run_dir: str | Path, out: str | Path | None = None, fmt: str = "png",
                     dpi: int = DEFAULT_DPI) -> Path:
    """One run's learning curves (:func:`apac_mj.report.figures.fig_run`) as ``out/learning_curves.<fmt>``
    (default ``out``: RUN_DIR/report); its metrics are checked first. Returns the figure's path."""
    import matplotlib
    import matplotlib.pyplot as plt

    from apac_mj.experiments.results import check_metrics
    from apac_mj.report.figures import check_format, fig_run
    from apac_mj.run.run_dir import METRICS, RunDir

    check_format(fmt, dpi)
    run = RunDir(run_dir)
    if not run.has_metrics():
        raise FileNotFoundError(f"{run_dir} holds no metrics.parquet: give a run directory written by apac-mj train "
                                "(or one cell of a grid) once training has started")
    metrics = check_metrics(run.metrics(), Path(run_dir) / METRICS)
    kind, task = _kind_and_task(Path(run_dir))
    out = Path(out) if out else Path(run_dir) / "report"
    out.mkdir(parents=True, exist_ok=True)
    matplotlib.use("Agg")
    with plt.rc_context({"savefig.dpi": dpi}):
        return fig_run(metrics, kind, task, Path(run_dir).name, out / f"learning_curves.{fmt}")


def _kind_and_task(run_dir: Path) -> tuple[str, str]:
    """The run's agent kind and task: from config.json, else (a grid cell not started yet) from cell.json."""
    from apac_mj.experiments.results import CELL_FILE
    from apac_mj.run.run_dir import RunDir
    from apac_mj.util.files import read_json

    if RunDir(run_dir).exists():
        config = RunDir(run_dir).config()
        return config["agent"]["kind"], config["task"]
    info = read_json(run_dir / CELL_FILE) or {}
    if "agent" not in info or "condition" not in info:
        raise FileNotFoundError(f"{run_dir} has neither config.json nor a {CELL_FILE} naming its agent and task: "
                                "give a run directory written by apac-mj train or apac-mj grid")
    return info["agent"], info["condition"]
