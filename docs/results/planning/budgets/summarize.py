"""Issue 41, item 5: the tables of docs/results/planning/budgets/README.md, from per-seed values.

Reads the shipped reports' key_numbers.csv (per-seed lists) and the per-seed CSVs of this directory, and writes
``time.csv`` (the graded rule's measured decision time against SPAC, APAC-MPC and SPAC-MPC, paired by seed) and
``success.csv`` (test success of each side of every equal-budget comparison, and paired differences).

Intervals: the report's (``apac_mj.report.stats.seed_interval``: ``mean ± t(0.9875, n-1) · s / sqrt(n)``, rates
clipped to [0, 100]; docs/statistics.md measured its coverage); paired differences by the same over the per-seed
differences. Run from the repository root:
``python docs/results/planning/budgets/summarize.py``.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from apac_mj.report.stats import seed_interval

HERE = Path(__file__).resolve().parent
PLANNING = HERE.parent
TIME_QUANTITIES = ("decision_ms_late", "plan_iterations_late", "steps_late", "test_success")
#: Reported: the shipped quantities and the decision time per step (decision_ms_late / steps_late, per seed).
REPORTED = (*TIME_QUANTITIES, "decision_ms_per_step_late")
#: (shipped report, the graded kind's rivals there)
TIME_SOURCES = (("stop", ("spac", "apac_mpc", "spac_mpc")), ("stop1000", ("spac", "spac_mpc")))


def t_interval(x: np.ndarray, bounds: tuple[float, float] | None = None) -> tuple[float, float, float]:
    """Mean and the report's 95% interval over seeds (``apac_mj.report.stats.seed_interval``: Student-t at the
    97.5% quantile, whose coverage docs/statistics.md measured; ``bounds``: clipped into them; NaN under 3 seeds)."""
    x = np.asarray(x, dtype=float)
    lo, hi = seed_interval(x, bounds)
    return float(x.mean()), lo, hi


def per_seed(cell: str) -> dict[int, float]:
    """``"0: 1.00; 1: 2.00"`` -> {0: 1.0, 1: 2.0}."""
    return {int(k): float(v) for k, v in (p.split(":") for p in cell.split(";"))}


def shipped(report: str) -> pd.DataFrame:
    """One row per (quantity, agent, seed) of a shipped report."""
    key = pd.read_csv(PLANNING / report / "key_numbers.csv")
    key = key[key.quantity.isin(TIME_QUANTITIES)]
    rows = [(q, a, s, v) for q, a, cell in zip(key.quantity, key.agent, key.per_seed)
            for s, v in per_seed(cell).items()]
    out = pd.DataFrame(rows, columns=["quantity", "agent", "seed", "value"])
    per_step = out.pivot_table(index=["agent", "seed"], columns="quantity", values="value")
    per_step = (per_step.decision_ms_late / per_step.steps_late).rename("value").reset_index()
    return pd.concat([out, per_step.assign(quantity="decision_ms_per_step_late")], ignore_index=True)


def time_table() -> pd.DataFrame:
    """APAC-VOC against each rival, paired by seed: the graded kind's value, the rival's, their difference
    and the ratio (per seed, then averaged), for each quantity."""
    out = []
    for report, rivals in TIME_SOURCES:
        data = shipped(report).pivot_table(index=["quantity", "seed"], columns="agent", values="value")
        for q in REPORTED:
            d = data.loc[q]
            for rival in rivals:
                voc, other = d["apac_voc"].to_numpy(), d[rival].to_numpy()
                bounds = (-100.0, 100.0) if q == "test_success" else None
                diff = t_interval(voc - other, bounds)
                ratio = t_interval(voc / other) if q != "test_success" and (other > 0).all() else (math.nan,) * 3
                out.append(dict(report=report, quantity=q, rival=rival, n_seeds=len(voc),
                                apac_voc=voc.mean(), rival_value=other.mean(), difference=diff[0],
                                diff_low=diff[1], diff_high=diff[2], ratio=ratio[0], ratio_low=ratio[1],
                                ratio_high=ratio[2], apac_voc_per_seed=_fmt(voc), rival_per_seed=_fmt(other)))
    return pd.DataFrame(out)


#: The published arms this study compares against: (task, arm, per-seed test success, its page, budget).
PAPER_BUDGET = "inverse 1 step/update, lr 1e-2, decay 1e-3; babbling 30; 200 episodes"
MPC_BUDGET = "dynamics 1+4 steps/update, lr 1e-3, decay 0 (inverse as the paper's, unused); babbling 30; 200 episodes"
EQUAL_BUDGET = "inverse 1+4 steps/update, lr 1e-3, decay 0; babbling 30; 200 episodes"
LR_DECAY_BUDGET = "inverse 1 step/update, lr 1e-3, decay 0; babbling 30; 200 episodes"
PUBLISHED = (
    ("changing_target_torque", "spac", "dynamics/key_numbers.csv", PAPER_BUDGET),
    ("changing_target_torque", "spac_babbling100_lr1e-3", "dynamics/README.md",
     "inverse 1 step/update, lr 1e-3, decay 1e-3; babbling 100; 200 episodes"),
    ("changing_target_torque", "spac_mpc", "planning/README.md", MPC_BUDGET),
    ("changing_target_torque_stop", "spac", "planning/stop/key_numbers.csv", PAPER_BUDGET),
    ("changing_target_torque_stop", "spac_mpc", "planning/stop/key_numbers.csv", MPC_BUDGET),
)
#: Per-seed values the pages print but no key_numbers.csv ships.
PRINTED = {("changing_target_torque", "spac_babbling100_lr1e-3"): (93, 86, 89, 96, 93),
           ("changing_target_torque", "spac_mpc"): (100, 99, 100, 100, 100)}


def published_rows() -> list[dict]:
    """The published arms' per-seed test success (%), read from the shipped reports or, where the page only
    prints them, from :data:`PRINTED`."""
    rows = []
    for task, arm, source, budget in PUBLISHED:
        if (task, arm) in PRINTED:
            values = dict(enumerate(PRINTED[task, arm]))
        else:
            key = pd.read_csv(PLANNING.parent / source)
            cell = key[(key.quantity == "test_success") & (key.agent == arm) & (key.condition == task)].per_seed
            values = per_seed(cell.iloc[0])
        rows += [dict(task=task, arm=arm, seed=s, success_pct=v, env_steps=math.nan, source=source,
                      budget=budget) for s, v in values.items()]
    return rows


def run_rows(cell: Path, arm: str, budget: str) -> list[dict]:
    """A cell of this study (``apac-mj grid`` output): per-seed test success (%: the hand inside the zone when
    the episode ended, what ``apac-mj evaluate`` calls success), reached (%: the episode ended by the task's own
    criterion; on the stop task inside the zone *and* stopped) and environment steps (babbling + training)."""
    import json

    test = pd.read_parquet(cell / "eval" / "grid.parquet").groupby("seed")
    success, reached = 100 * test.success.mean(), 100 * test.judged_reached.mean()
    steps = pd.read_parquet(cell / "metrics.parquet").groupby("seed").steps.sum()
    task = json.loads((cell / "cell.json").read_text())["condition"]
    return [dict(task=task, arm=arm, seed=int(s), success_pct=success[s], reached_pct=reached[s],
                 env_steps=int(steps[s]), source="this study", budget=budget) for s in success.index]


def success_table(per: pd.DataFrame) -> pd.DataFrame:
    """Each arm (mean, t-interval over seeds) and its paired differences to SPAC-MPC and to SPAC (same seeds)."""
    out = []
    for (task, arm), g in per.groupby(["task", "arm"], sort=False):
        g = g.sort_values("seed")
        m = t_interval(g.success_pct.to_numpy(), (0.0, 100.0))
        row = dict(task=task, arm=arm, n_seeds=len(g), mean=m[0], low=m[1], high=m[2],
                   per_seed=_fmt(g.success_pct.to_numpy()), env_steps_per_seed=g.env_steps.mean(),
                   budget=g.budget.iloc[0], source=g.source.iloc[0])
        if "reached_pct" in g and g.reached_pct.notna().all():
            r = t_interval(g.reached_pct.to_numpy(), (0.0, 100.0))
            row.update(reached=r[0], reached_low=r[1], reached_high=r[2],
                       reached_per_seed=_fmt(g.reached_pct.to_numpy()))
            b = per[(per.task == task) & (per.arm == "spac_mpc_rerun")].sort_values("seed")
            if arm != "spac_mpc_rerun" and list(b.seed) == list(g.seed):
                d = t_interval(g.reached_pct.to_numpy() - b.reached_pct.to_numpy(), (-100.0, 100.0))
                row.update(reached_minus_spac_mpc=d[0], reached_minus_spac_mpc_low=d[1],
                           reached_minus_spac_mpc_high=d[2])
        for base in ("spac_mpc", "spac"):
            b = per[(per.task == task) & (per.arm == base)].sort_values("seed")
            if base != arm and list(b.seed) == list(g.seed):
                d = t_interval(g.success_pct.to_numpy() - b.success_pct.to_numpy(), (-100.0, 100.0))
                row.update({f"minus_{base}": d[0], f"minus_{base}_low": d[1], f"minus_{base}_high": d[2]})
        out.append(row)
    return pd.DataFrame(out)


def figure(table: pd.DataFrame, path: Path) -> None:
    """Test success of every arm with its t-interval and per-seed points, one panel per task."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = list(dict.fromkeys(table.task))
    fig, axes = plt.subplots(1, len(tasks), figsize=(5.2 * len(tasks), 3.4), squeeze=False)
    for ax, task in zip(axes[0], tasks):
        t = table[table.task == task].reset_index(drop=True)
        ax.errorbar(t["mean"], t.index, xerr=[t["mean"] - t.low, t.high - t["mean"]], fmt="o", capsize=3)
        for i, cell in enumerate(t.per_seed):
            ax.plot([float(v) for v in str(cell).split(";")], [i] * len(str(cell).split(";")), "k.", alpha=0.4)
        ax.set_yticks(t.index, t.arm, fontsize=8)
        ax.set_xlim(-2, 102)
        ax.set_xlabel("test success, % (mean, 95% t-interval, seeds)")
        ax.set_title(task, fontsize=9)
        ax.invert_yaxis()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _fmt(x: np.ndarray) -> str:
    return "; ".join(f"{v:.4g}" for v in x)


def main(argv: list[str] | None = None) -> None:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", nargs=2, action="append", default=[], metavar=("ARM", "CELL"),
                    help="a cell of this study (its apac-mj grid cell directory) and the arm's name; repeatable")
    args = ap.parse_args(argv)
    time_table().round(4).to_csv(HERE / "time.csv", index=False)
    budgets = {"spac_equal": EQUAL_BUDGET, "spac_lr_decay": LR_DECAY_BUDGET,
               "spac_mpc_no_habit_seed": MPC_BUDGET.replace("(inverse", "habit_candidates 0 (inverse"),
               "spac_mpc_rerun": MPC_BUDGET}
    rows = published_rows()
    for arm, cell in args.run:
        rows += run_rows(Path(cell), arm, budgets.get(arm, "see README"))
    per = pd.DataFrame(rows)
    if args.run:
        per[per.source == "this study"].to_csv(HERE / "success_per_seed.csv", index=False)
    elif (HERE / "success_per_seed.csv").is_file():
        per = pd.concat([per, pd.read_csv(HERE / "success_per_seed.csv")], ignore_index=True)
    table = success_table(per)
    table.round(2).to_csv(HERE / "success.csv", index=False)
    figure(table, HERE / "success.png")


if __name__ == "__main__":
    main()
