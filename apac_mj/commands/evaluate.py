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
seed and target) and RUN_DIR/eval/summary.json, and prints the summary.

examples:
  apac-mj evaluate runs/apac_ct
  apac-mj evaluate runs/apac_ct --limit 20          # a quick look: the first 20 targets per seed
  apac-mj evaluate runs/apac_ct_train_region --protocols generalization"""


def register(sub: argparse._SubParsersAction) -> None:
    from apac_mj.util.threads import DEFAULT_THREADS

    p = sub.add_parser("evaluate", help="frozen-network tests of a run: angle grid, occluded vision, generalization",
                       description="Freeze a trained run's networks and run the paper's tests on every seed at once.",
                       epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", help="a run directory written by apac-mj train")
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
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from apac_mj.commands.hints import results_dir_hint
    from apac_mj.run.evaluate import evaluate

    if (hint := results_dir_hint(args.run_dir, "evaluate")) is not None:
        raise FileNotFoundError(hint)
    if args.threads < 1:
        raise ValueError(f"--threads must be >= 1, got {args.threads}")
    protocols = tuple(p.strip() for p in args.protocols.split(",") if p.strip())
    summary = evaluate(args.run_dir, protocols=protocols, region=args.region, device=args.device,
                       progress=not args.no_progress, limit=args.limit, threads=args.threads)
    short = {name: {k: v for k, v in res.items() if not k.endswith("_per_seed")}
             for name, res in summary.get("protocols", {}).items() if name in protocols}
    print(json.dumps({"run_dir": summary["run_dir"], "agent": summary["agent"], "task": summary["task"],
                      "protocols": short}, indent=2))
    return 0
