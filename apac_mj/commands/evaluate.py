"""``apac-mj evaluate``: the paper's frozen-network tests of a trained run directory."""
from __future__ import annotations

import argparse
import json

EPILOG = """\
protocols:
  grid            the 100 angle-grid targets at each seed's end-of-training link lengths
                  (static-target runs: the seed's own target, 100 episodes); perfect vision
  occluded        the same targets, seen at step 0 only: the arm moves on the forward model's
                  estimate, stops when the estimate is inside the target zone (or at 30 steps);
                  the real final distance is recorded. SPAC and APAC only (DDPG: not applicable)
  generalization  the grid targets inside the task's held-out test region (y >= test_y_min)

Networks are frozen (no noise, no updates); APAC arbitrates as after its planning phase. Time cost:
a planning action costs 3, a habitual one 1. Writes RUN_DIR/eval/<protocol>.parquet (one row per
seed and target) and RUN_DIR/eval/summary.json, and prints the summary as a short table (--json: the
summary as JSON, for scripts). The run's learning curves: apac-mj report --run RUN_DIR.

examples:
  apac-mj evaluate runs/apac_ct
  apac-mj evaluate runs/apac_ct --limit 20          # a quick look: the first 20 targets per seed
  apac-mj evaluate runs/apac_ct_train_region --protocols generalization
  apac-mj evaluate runs/apac_ct --json > summary.json  # machine-readable"""


def register(sub: argparse._SubParsersAction) -> None:
    from apac_mj.util.threads import DEFAULT_THREADS

    p = sub.add_parser("evaluate", help="frozen-network tests of a run: angle grid, occluded vision, generalization",
                       description="Freeze a trained run's networks and run the paper's tests on every seed at once.",
                       epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", help="a run directory written by apac-mj train, or a zoo cell (zoo:NAME or its "
                                   "directory; docs/zoo.md)")
    p.add_argument("--protocols", default="grid,occluded",
                   help="comma-separated: grid, occluded, generalization (default grid,occluded)")
    p.add_argument("--region", choices=("test", "train"), default=None,
                   help="restrict the targets of every protocol to this part of the region split")
    p.add_argument("--device", default=None, help="cpu or cuda (default: the run's)")
    p.add_argument("--limit", type=int, default=None, metavar="N",
                   help="only the first N targets per seed (a quick look; not the paper's test)")
    p.add_argument("--threads", type=int, default=DEFAULT_THREADS,
                   help=f"torch CPU threads (default {DEFAULT_THREADS}, as apac_mj.evaluate: on a busy 2-core machine "
                        "2 threads measured 1.1-1.5 s per target against 0.08-0.15 s at 1; apac_mj/util/threads.py)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar (default: one per protocol)")
    p.add_argument("--json", action="store_true",
                   help="print the summary as JSON (full precision, for scripts) instead of the table")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from apac_mj.commands.hints import results_dir_hint
    from apac_mj.run.evaluate import evaluate
    from apac_mj.run.zoo import resolve_run

    args.run_dir = str(resolve_run(args.run_dir))  # a zoo cell: its networks as a run (docs/zoo.md)
    if (hint := results_dir_hint(args.run_dir, "evaluate")) is not None:
        raise FileNotFoundError(hint)
    if args.threads < 1:
        raise ValueError(f"--threads must be >= 1, got {args.threads}")
    protocols = tuple(p.strip() for p in args.protocols.split(",") if p.strip())
    summary = evaluate(args.run_dir, protocols=protocols, region=args.region, device=args.device,
                       progress=not args.no_progress, limit=args.limit, threads=args.threads)
    short = {name: {k: v for k, v in res.items() if not k.endswith("_per_seed")}
             for name, res in summary.get("protocols", {}).items() if name in protocols}
    if args.json:
        print(json.dumps({"run_dir": summary["run_dir"], "agent": summary["agent"], "task": summary["task"],
                          "protocols": short}, indent=2))
    else:
        print(summary_table(summary, protocols))
    return 0


#: The table's columns: (summary key, header, how a value is written).
COLUMNS = (("episodes", "episodes", "{:.0f}"), ("success_rate", "success %", "{:.1%}"),
           ("mean_steps_to_reach", "steps to reach", "{:.1f}"), ("habit_share", "habit %", "{:.1%}"),
           ("mean_time_cost", "time (habit steps)", "{:.1f}"), ("final_distance_mean", "final dist. cm", "{:.2f}"))


def summary_table(summary: dict, protocols: tuple[str, ...]) -> str:
    """The evaluation summary as a short aligned table: one row per protocol, rounded, "-" where a value does not
    exist (no target reached) and the reason where a protocol does not apply; then each seed's success."""
    header = ["protocol", *(h for _, h, _ in COLUMNS)]
    rows, notes = [], []
    for name in protocols:
        res = summary.get("protocols", {}).get(name, {})
        if not res:
            notes.append(f"{name}: no results in eval/summary.json")
            continue
        if not res.get("applicable", True):
            notes.append(f"{name}: not applicable ({res.get('reason', 'no reason given')})")
            continue
        rows.append([name, *(_cell(res.get(key), form) for key, _, form in COLUMNS)])
        per_seed = res.get("success_rate_per_seed") or {}
        if per_seed:
            notes.append(f"{name} success per seed: " + ", ".join(f"{s}: {v:.0%}" for s, v in per_seed.items()))
    widths = [max(len(str(r[i])) for r in [header, *rows]) for i in range(len(header))]
    lines = [f"{summary['run_dir']}: {summary['agent']} on {summary['task']}",
             "  ".join(h.ljust(w) for h, w in zip(header, widths))]
    lines += ["  ".join(c.rjust(w) if i else c.ljust(w) for i, (c, w) in enumerate(zip(r, widths))) for r in rows]
    return "\n".join(lines + notes)


def _cell(value: object, form: str) -> str:
    """``value`` written with ``form``; "-" for a missing value."""
    return "-" if value is None else form.format(value)
