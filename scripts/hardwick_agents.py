#!/usr/bin/env python
"""Hardwick et al.'s model fitted to the agents' published forced-response curves (seed-pooled counts).

The published ``docs/results/forced_response/curves.csv`` holds each rate's mean over the seeds, not the seeds
(the study did not ship its per-seed tables). A mean rate x seeds x trials per seed is the seed-pooled count,
and a multinomial likelihood over those counts is the per-trial likelihood summed, so Hardwick et al.'s model
(:mod:`apac_mj.report.hardwick`) is fitted to the seed-pooled agent of each practice length and variant, time-outs
counted as guesses (:func:`apac_mj.report.forced_response.remapped_counts`). Intervals: a parametric bootstrap of
the trials (:func:`apac_mj.report.hardwick.bootstrap_fit`), which leaves out seed-to-seed variation: the
per-seed fits with the report's seed intervals are what ``apac-mj forced-response report`` writes
(``hardwick.csv``) for a study whose tables are at hand. The humans' 100 ms window is applied as to the humans.

Usage: ``python scripts/hardwick_agents.py --curves docs/results/forced_response/curves.csv --out DIR``
"""
from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from apac_mj.report import forced_response as fr
from apac_mj.report import hardwick
from apac_mj.util.progress import progress_iter

#: Trials per seed, cue type and preparation time of the published study (2 remapped cues x 100 trials).
TRIALS = 200


def pooled_table(curves: pd.DataFrame, trials: int, resamples: int, boot: list[str]) -> pd.DataFrame:
    """Per practice and variant: the habit model's parameters (ms), ΔAIC, the bootstrap intervals (variants in
    ``boot`` only), and the humans' windowed peak of P(habitual) of the seed-pooled agent."""
    seeds = fr.curves_as_counts(curves, trials)
    fits = fr.hardwick_fits(seeds).drop(columns="seed")
    peaks = fr.window_peaks(seeds)[["practice", "variant", "window_peak_ms", "window_peak", "window_50_150"]]
    rows = []
    for _, row in progress_iter(list(fits.iterrows()), len(fits), "bootstrap", "cell"):
        g = seeds[(seeds.practice == row.practice) & (seeds.variant == row.variant)]
        t, counts = fr.remapped_counts(g)
        ci = hardwick.bootstrap_fit(t, counts, resamples) if resamples and row.variant in boot else {}
        rows.append({**row.to_dict(), **{f"{q}_{e}": v[i] for q, v in ci.items() for i, e in enumerate(("lo", "hi"))}})
    return pd.DataFrame(rows).merge(peaks, on=["practice", "variant"])


def main() -> None:
    """Fit, bootstrap, write ``hardwick_agents.csv`` and ``hardwick_vs_humans.csv``."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--curves", type=Path, required=True, help="the study's curves.csv (means over seeds)")
    ap.add_argument("--out", type=Path, required=True, help="folder for hardwick_agents.csv")
    ap.add_argument("--humans", type=Path, default=Path(fr.HUMAN_FITS),
                    help="the humans' fits (scripts/hardwick_human.py --fits) to set beside (default: the published)")
    ap.add_argument("--trials", type=int, default=TRIALS, help="trials per seed, cue type and time (default 200)")
    ap.add_argument("--resamples", type=int, default=100, help="bootstrap resamples per cell (0: none)")
    ap.add_argument("--bootstrap", default="apac_imagined,apac_voc",
                    help="comma-separated variants given bootstrap intervals (default: the arbitrated ones)")
    args = ap.parse_args()
    if not args.curves.is_file():
        ap.error(f"--curves {args.curves}: no such file")
    if args.trials < 1 or args.resamples < 0:
        ap.error("--trials must be >= 1 and --resamples >= 0")
    curves = pd.read_csv(args.curves)
    table = pooled_table(curves, args.trials, args.resamples, [v for v in args.bootstrap.split(",") if v])
    args.out.mkdir(parents=True, exist_ok=True)
    table.round(4).to_csv(args.out / "hardwick_agents.csv", index=False)
    if args.humans.is_file():
        humans = pd.read_csv(args.humans)
        humans = humans[humans.condition.isin(fr.HUMAN_GROUPS)]
        boot = table[table.variant.isin(args.bootstrap.split(","))]
        hardwick.side_by_side(boot, humans).round(4).to_csv(args.out / "hardwick_vs_humans.csv", index=False)


if __name__ == "__main__":
    main()
