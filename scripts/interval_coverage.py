"""Measure the coverage of every interval method on shapes fitted to the published per-seed values.

    python scripts/interval_coverage.py [--replications 1000] [--resamples 2000] [--out docs/statistics_coverage.csv]

Prints the fitted shapes and a Markdown table (shape x method, columns 2/3/5/10 seeds) for docs/statistics.md,
and writes the long table to ``--out``. Same arguments, same numbers.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from apac_mj.report import coverage

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--results", type=Path, default=ROOT / "docs" / "results")
    p.add_argument("--replications", type=int, default=1000)
    p.add_argument("--resamples", type=int, default=2000)
    p.add_argument("--out", type=Path, default=ROOT / "docs" / "statistics_coverage.csv")
    a = p.parse_args(argv)
    if a.replications < 10 or a.resamples < 100:
        p.error("--replications must be >= 10 and --resamples >= 100 (a coverage needs data sets to count)")
    shapes = coverage.fitted_shapes(coverage.shipped_key_numbers(a.results))
    for s in shapes:
        print(f"* {s.name}: {s.fitted_to}")
    df = coverage.coverage(shapes, replications=a.replications, resamples=a.resamples)
    df.to_csv(a.out, index=False)
    wide = df.pivot_table(index=["shape", "method"], columns="seeds", values="coverage", sort=False)
    print("\n| shape | method | " + " | ".join(f"{c} seeds" for c in wide.columns) + " |")
    print("|---|---|" + "---|" * len(wide.columns))
    for (shape, method), row in wide.iterrows():
        print(f"| {shape} | {method} | " + " | ".join(f"{x:.3f}" for x in row) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
