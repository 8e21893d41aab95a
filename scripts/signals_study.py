"""The signals study (docs/environment.md, "Signals: delays and noise"): APAC on the compliant arm with its
joint velocities observed (``changing_target_compliant_delayed``), feedback delays none / MotorNet's default
(10 ms each) / one control step (100 ms), 3 seeds x 20 episodes each (planning phase 8 episodes); prints the
table of success and final distance over each seed's last 10 episodes, means over seeds with the report's
95 % intervals (apac_mj.report.stats.interval).

    python scripts/signals_study.py --out results/signals      # trains what is missing, then the table
"""
from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import pandas as pd

from apac_mj.report.stats import interval

TASK = "changing_target_compliant_delayed"
#: condition -> (visual, proprioceptive) delay in ms.
CONDITIONS = {"none": (0, 0), "motornet": (10, 10), "step": (100, 100)}
EPISODES, LAST = 20, 10


def train(out: Path, name: str, visual: int, proprio: int) -> Path:
    """``apac-mj train`` of one condition into ``out/name`` (a finished run is left as it is)."""
    run = out / name
    print(f"[{name}] training {TASK} with delays {visual}/{proprio} ms into {run}", file=sys.stderr, flush=True)
    subprocess.run(["apac-mj", "train", "--task", TASK, "--agent", "apac", "--seeds", "0-2", "--episodes",
                    str(EPISODES), "--out", str(run), "--no-progress", "--set", "agent.planning_episodes=8", "--set",
                    f"task_overrides={{signals={{visual_delay_ms={visual},proprioceptive_delay_ms={proprio}}}}}"],
                   check=True)
    return run


def row(name: str, run: Path) -> str:
    """One table row: each seed's last LAST training episodes, success % and final distance (cm)."""
    df = pd.read_parquet(run / "metrics.parquet")
    df = df[(df.phase == "train") & (df.episode >= EPISODES - LAST)]
    per_seed = df.groupby("seed").agg(k=("success", "sum"), n=("success", "size"), d=("final_distance", "mean"))
    s, s_lo, s_hi = interval(100 * per_seed.k / per_seed.n, per_seed.k, per_seed.n)
    d, d_lo, d_hi = interval(per_seed.d, bounds=(0.0, float("inf")))
    v, p = CONDITIONS[name]
    return f"| {name} | {v} / {p} | {s:.0f} [{s_lo:.0f}, {s_hi:.0f}] | {d:.2f} [{d_lo:.2f}, {d_hi:.2f}] |"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/signals"))
    args = parser.parse_args()
    runs = {name: args.out / name if (args.out / name / "DONE").is_file() else train(args.out, name, *d)
            for name, d in CONDITIONS.items()}
    print("| delays | visual / proprioceptive (ms) | success, last 10 episodes (%) | final distance (cm) |")
    print("|---|---|---|---|")
    for name, run in runs.items():
        print(row(name, run))


if __name__ == "__main__":
    main()
