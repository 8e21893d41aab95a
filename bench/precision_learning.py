"""Does bf16 learn what fp32 learns? Two grids that differ only in ``precision``, compared quantity by quantity.

    apac-mj grid --preset fidelity --set agents=ddpg,apac --set conditions=changing_target \\
                 --set precision=fp32 --out results/precision/fp32
    apac-mj grid --preset fidelity --set agents=ddpg,apac --set conditions=changing_target \\
                 --set precision=bf16 --out results/precision/bf16
    python bench/precision_learning.py results/precision/fp32 results/precision/bf16 [--csv out.csv]

For every key number of the report (training success and habit share over the last 20% of episodes,
steps and time per episode, test success on the angle grid and on occluded vision, ...) and every agent
and condition in both grids: each precision's mean over seeds with its 95% interval (the report's
:func:`apac_mj.report.quantities.key_numbers`), and the difference bf16 - fp32 with its 95% interval
(the report's paired bootstrap over seeds, for rates widened to Newcombe's interval of the pooled
counts). Seeds are paired: the same seed starts from the same weights, targets and noise in both
precisions, and the runs part where bf16's rounding first changes an action. "agree" means the
difference's interval contains 0.
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path

import pandas as pd

from apac_mj.experiments.results import load_results, load_tests
from apac_mj.report.markdown import table_row
from apac_mj.report.quantities import QUANTITIES, fmt, key_numbers, per_seed, seed_difference
from apac_mj.run.run_dir import RunDir

QUANTITY_ORDER = ("train_success_late", "habit_fraction_late", "steps_late", "time_late", "test_success",
                  "test_steps_to_reach", "test_habit_fraction", "test_time")


def seed_values(results: Path) -> pd.DataFrame:
    """The report's per-seed key numbers of one grid."""
    tests = load_tests(results) if any(results.glob("*/eval/*.parquet")) else pd.DataFrame()
    return per_seed(load_results(results), tests)


def precision_of(results: Path) -> str:
    found = {RunDir(d).train_config().precision for d in results.iterdir() if (d / "config.json").is_file()}
    if len(found) != 1:
        raise ValueError(f"{results}: expected one precision among its cells, found {sorted(found)}")
    return found.pop()


def compare(a: pd.DataFrame, b: pd.DataFrame) -> pd.DataFrame:
    """One row per (quantity, agent, condition) in both: each side's mean [interval] and b - a."""
    ka, kb = key_numbers(a).set_index(["quantity", "agent", "condition"]), \
        key_numbers(b).set_index(["quantity", "agent", "condition"])
    rows = []
    for key in ka.index.intersection(kb.index):
        q, agent, cond = key
        sa, sb = (s[(s.quantity == q) & (s.agent == agent) & (s.condition == cond)].set_index("seed")
                  for s in (a, b))
        diff, lo, hi, paired = seed_difference(q, sb, sa)
        rows.append({"quantity": q, "description": QUANTITIES[q][1], "unit": QUANTITIES[q][2], "agent": agent,
                     "condition": cond, "n_seeds": len(sa),
                     "a_mean": ka.loc[key, "mean"], "a_low": ka.loc[key, "ci95_low"], "a_high": ka.loc[key, "ci95_high"],
                     "a_per_seed": ka.loc[key, "per_seed"],
                     "b_mean": kb.loc[key, "mean"], "b_low": kb.loc[key, "ci95_low"], "b_high": kb.loc[key, "ci95_high"],
                     "b_per_seed": kb.loc[key, "per_seed"],
                     "difference": diff, "diff_low": lo, "diff_high": hi, "paired": paired,
                     "agree": bool(math.isnan(lo) or lo <= 0 <= hi)})
    df = pd.DataFrame(rows)
    order = {q: i for i, q in enumerate(QUANTITY_ORDER)}
    df["_o"] = df.quantity.map(lambda q: order.get(q, len(order)))
    return df.sort_values(["_o", "condition", "agent"]).drop(columns="_o").reset_index(drop=True)


def markdown(df: pd.DataFrame, a: str, b: str) -> str:
    lines = [f"| quantity | agent | condition | seeds | {a} | {b} | {b} - {a} [95% CI] | agree |",
             "|---|---|---|---|---|---|---|---|"]
    for r in df.itertuples():
        lines.append(table_row([f"{r.description} ({r.unit})", r.agent, r.condition, r.n_seeds,
                                f"{fmt(r.a_mean)} [{fmt(r.a_low)}, {fmt(r.a_high)}]",
                                f"{fmt(r.b_mean)} [{fmt(r.b_low)}, {fmt(r.b_high)}]",
                                f"{fmt(r.difference)} [{fmt(r.diff_low)}, {fmt(r.diff_high)}]",
                                "yes" if r.agree else "**no**"]))
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("reference", type=Path, help="the fp32 grid's results directory")
    ap.add_argument("other", type=Path, help="the same grid in bf16")
    ap.add_argument("--csv", type=Path, default=None, help="write the comparison here")
    args = ap.parse_args()
    pa, pb = precision_of(args.reference), precision_of(args.other)
    df = compare(seed_values(args.reference), seed_values(args.other))
    print(markdown(df, pa, pb))
    disagree = df[~df.agree]
    print(f"\n{len(df) - len(disagree)} of {len(df)} key numbers agree (the difference's 95% interval contains 0)"
          + (": " + "; ".join(f"{r.quantity} {r.agent} {r.condition}" for r in disagree.itertuples())
             if len(disagree) else ""))
    if args.csv is not None:
        df.to_csv(args.csv, index=False)


if __name__ == "__main__":
    main()
