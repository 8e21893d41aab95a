"""The forced-response study's report: curves over seeds, the peak table, the figure beside the human curves.

Input: the tests' tables (:data:`apac_mj.run.forced_response.COLUMNS`), one per practice length and kind,
``tests/p<episodes>/<kind>.parquet`` under a study directory (:mod:`apac_mj.experiments.forced_response`).
Per seed, cues of one type (remapped, unchanged) are pooled; intervals are the report's 95% seed interval
(:func:`apac_mj.report.stats.seed_interval`: Student-t over seeds, clipped to [0, 1]; its coverage measured).
"""
from __future__ import annotations

import warnings
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from apac_mj.run.variants import label, order

#: Preparation times that count as short and long in the peak table (ms).
SHORT_MS, LONG_MS = 150.0, 900.0
_RATES = ("correct", "habitual", "other", "timeout", "error")


class TestTableError(ValueError):
    """A test table (``tests/p<episodes>/<kind>.parquet``) that cannot be what a test wrote: the message names
    the file, the column and the rows. Nothing was written."""

    __test__ = False  # not a pytest class


#: A test table's count columns (integers >= 0): the outcomes and who acted, each set summing to the trials.
COUNTS = ("correct", "habitual", "other", "timeout", "habit_acted", "planner_acted", "default_acted")
#: What one row is: a seed's variant at a preparation time and cue.
ROW_KEY = ["seed", "variant", "prep_ms", "cue"]


def load_tests(study: str | Path) -> pd.DataFrame:
    """Every test table of a study, with its practice length (``practice`` column), each checked
    (:func:`check_table`); a folder under ``tests/`` that is not ``p<episodes>`` is refused."""
    frames = []
    for path in sorted(Path(study, "tests").glob("*/*.parquet")):
        name = path.parent.name
        if not (name.startswith("p") and name[1:].isdigit() and int(name[1:]) >= 1):
            raise TestTableError(f"{path}: {path.parent} is not a practice folder (p<episodes>, e.g. p100); move it "
                                 "out of tests/ (nothing was written)")
        df = pd.read_parquet(path)
        check_table(df, path, int(name[1:]))
        df["practice"] = int(name[1:])
        frames.append(df)
    if not frames:
        raise FileNotFoundError(f"{study}: no tests/p<episodes>/<kind>.parquet (run apac-mj forced-response run)")
    return pd.concat(frames, ignore_index=True)


def check_table(df: pd.DataFrame, path: Path, practice: int) -> None:
    """``df`` is a test table as :func:`apac_mj.run.forced_response.test_run` writes it: every column, finite
    counts >= 0 that sum to ``trials`` (>= 1) per row, outcomes and actors alike, one row per seed, variant,
    preparation time and cue, and (where recorded) networks from episode ``practice``; else
    :class:`TestTableError`."""
    from apac_mj.run.timing import COLUMNS

    def refuse(problem: str, rows: pd.Series | None = None) -> None:
        where = "" if rows is None else f" (rows {_rows(rows)})"
        raise TestTableError(f"{path}: {problem}{where}; the table was damaged or edited: remove it and run its "
                             "test again (apac-mj forced-response run --out STUDY resumes it); nothing was written")

    missing = [c for c in COLUMNS if c not in ("episode", "guessed") and c not in df.columns]  # absent before them
    if missing:
        refuse(f"missing column(s) {missing}")
    if df.empty:
        refuse("no rows")
    for c in ("seed", "cue", "trials", *COUNTS, "prep_ms"):
        v = pd.to_numeric(df[c], errors="coerce").astype(float)
        if (bad := ~np.isfinite(v)).any():
            refuse(f"column {c!r} is not a finite number", bad)
        if c != "prep_ms" and (bad := (v < (1 if c == "trials" else 0)) | (v != np.round(v))).any():
            refuse(f"column {c!r} must hold integers >= {1 if c == 'trials' else 0}", bad)
    if (bad := ~df["remapped"].isin([True, False])).any():
        refuse("column 'remapped' must be True or False", bad)
    if (bad := df["prep_ms"].astype(float) <= 0).any():
        refuse("column 'prep_ms' must be > 0 ms", bad)
    for group in (COUNTS[:4], COUNTS[4:]):
        if (bad := df[list(group)].sum(axis=1) != df["trials"]).any():
            refuse(f"the counts {list(group)} do not sum to 'trials'", bad)
    if (bad := df.duplicated(ROW_KEY, keep=False)).any():
        refuse(f"duplicated rows (one row per {', '.join(ROW_KEY)})", bad)
    if "episode" in df.columns and (bad := df["episode"] != practice).any():
        refuse(f"networks from episode(s) {sorted(set(df.episode[bad].tolist()))}, not this folder's {practice}", bad)


def _rows(mask: pd.Series) -> str:
    """The row numbers of ``mask`` (the first 5, and how many in all)."""
    rows = np.flatnonzero(np.asarray(mask))
    return ", ".join(map(str, rows[:5])) + (f", ... ({len(rows)} in all)" if len(rows) > 5 else "")


def per_seed(tests: pd.DataFrame) -> pd.DataFrame:
    """Rates per practice, variant, seed, cue type and preparation time (cues of the type pooled):
    P(correct), P(habitual error), P(other error), P(time-out), P(error) = habitual + other, and who acted."""
    keys = ["practice", "variant", "seed", "remapped", "prep_ms"]
    counts = tests.groupby(keys)[["trials", "correct", "habitual", "other", "timeout", "habit_acted",
                                  "planner_acted", "default_acted"]].sum().reset_index()
    n = counts["trials"]
    for name in ("correct", "habitual", "other", "timeout", "habit_acted", "planner_acted", "default_acted"):
        counts[f"p_{name}"] = counts[name] / n
    counts["p_error"] = counts["p_habitual"] + counts["p_other"]
    return counts


def bootstrap(values: np.ndarray, resamples: int = 2000, seed: int = 0) -> tuple[float, float, float]:
    """Mean and 95% interval of ``values`` (one per seed, probabilities): the report's measured interval
    (:func:`apac_mj.report.stats.seed_interval`, issue 41; a percentile bootstrap before, which undercovered);
    ``resamples`` and ``seed`` are kept for callers and unused."""
    from apac_mj.report.stats import seed_interval

    v = np.asarray(values, dtype=float)
    lo, hi = seed_interval(v, (0.0, 1.0))
    return float(v.mean()), lo, hi


def curves(seeds: pd.DataFrame) -> pd.DataFrame:
    """Mean and interval over seeds of every rate, per practice, variant, cue type and preparation time."""
    rows = []
    for key, g in seeds.groupby(["practice", "variant", "remapped", "prep_ms"]):
        row = dict(zip(["practice", "variant", "remapped", "prep_ms"], key), seeds=len(g))
        for r in (*_RATES, "habit_acted", "planner_acted"):
            row[r], row[f"{r}_lo"], row[f"{r}_hi"] = bootstrap(g[f"p_{r}"].to_numpy())
        rows.append(row)
    return pd.DataFrame(rows)


def peaks(seeds: pd.DataFrame) -> pd.DataFrame:
    """Per practice and variant: where the mean P(habitual error) of the remapped cues peaks, its height and
    interval there, beside its level at short (<= SHORT_MS) and long (>= LONG_MS) preparation times; the
    unchanged cues' largest P(error); whether the peak's interval lies above both ends' intervals; when each
    stimulus's P(correct) reaches 0.5 (:func:`t50`)."""
    rows = []
    for (practice, variant), g in seeds.groupby(["practice", "variant"]):
        rem, unc = g[g.remapped], g[~g.remapped]
        mean = rem.groupby("prep_ms")["p_habitual"].mean()
        at = float(mean.idxmax())
        peak = bootstrap(rem[rem.prep_ms == at]["p_habitual"].to_numpy())
        short = bootstrap(rem[rem.prep_ms <= SHORT_MS].groupby("seed")["p_habitual"].mean().to_numpy())
        long = bootstrap(rem[rem.prep_ms >= LONG_MS].groupby("seed")["p_habitual"].mean().to_numpy())
        unc_mean = unc.groupby("prep_ms")["p_error"].mean()
        unc_at = float(unc_mean.idxmax())
        unc_peak = bootstrap(unc[unc.prep_ms == unc_at]["p_error"].to_numpy())
        correct_long = bootstrap(rem[rem.prep_ms >= LONG_MS].groupby("seed")["p_correct"].mean().to_numpy())
        rows.append({"practice": practice, "variant": variant, "seeds": rem.seed.nunique(), "peak_ms": at,
                     "peak": peak[0], "peak_lo": peak[1], "peak_hi": peak[2],
                     "short": short[0], "short_lo": short[1], "short_hi": short[2],
                     "long": long[0], "long_lo": long[1], "long_hi": long[2],
                     "separated": bool(peak[1] > max(short[2], long[2])),
                     "unchanged_error_peak_ms": unc_at, "unchanged_error_peak": unc_peak[0],
                     "unchanged_error_peak_hi": unc_peak[2],
                     "remapped_correct_long": correct_long[0],
                     "t50_correct_remapped_ms": t50(rem.groupby("prep_ms")["p_correct"].mean()),
                     "t50_correct_unchanged_ms": t50(unc.groupby("prep_ms")["p_correct"].mean())})
    return pd.DataFrame(rows)


#: The human curves' window (scripts/hardwick_human.py): centres every 25 ms from 50 to 1200 ms, 100 ms wide.
WINDOW_CENTRES_MS, WINDOW_MS = np.arange(50, 1201, 25), 100.0
#: Keys a guess picks among: the cued task's four targets, as the humans' four keys.
KEYS = 4
#: The humans' fits of Hardwick et al.'s model (scripts/hardwick_human.py --fits), from the checkout's root.
HUMAN_FITS = "docs/results/forced_response/human/hardwick_fits.csv"
#: The human groups the agents are set beside (minimal practice has no habit to express).
HUMAN_GROUPS = ("4day", "20day")


def remapped_counts(g: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Preparation times (s) and (n, 3) counts of correct, habitual, other responses of the remapped cues of
    ``g`` (one seed, rows per preparation time), time-outs counted as guesses among :data:`KEYS` keys (people
    must respond; :func:`apac_mj.report.hardwick.guesses`)."""
    from apac_mj.report import hardwick

    rem = g[g.remapped.astype(bool)].groupby("prep_ms")[["correct", "habitual", "other", "timeout"]].sum()
    rem = rem.sort_index()
    counts = hardwick.guesses(rem[["correct", "habitual", "other"]].to_numpy(float), rem["timeout"].to_numpy(float),
                              KEYS)
    return rem.index.to_numpy(dtype=float) / 1000.0, counts


def hardwick_fits(seeds: pd.DataFrame) -> pd.DataFrame:
    """Hardwick et al.'s habit and no-habit models fitted to each seed's remapped-cue counts (per practice and
    variant; :func:`remapped_counts`): one :func:`apac_mj.report.hardwick.fit_row` per seed (times in ms)."""
    from apac_mj.report import hardwick

    rows = []
    for (practice, variant, seed), g in seeds.groupby(["practice", "variant", "seed"]):
        t, counts = remapped_counts(g)
        rows.append({"practice": practice, "variant": variant, "seed": seed, **hardwick.fit_row(t, counts)})
    return pd.DataFrame(rows)


def window_peaks(seeds: pd.DataFrame) -> pd.DataFrame:
    """The humans' analysis on the agents' remapped-cue trials (time-outs as guesses): per seed the 100 ms
    sliding window of P(habitual) on the humans' grid (:data:`WINDOW_CENTRES_MS`), then per practice and variant
    where the mean over seeds peaks (the mean of tied centres: on a 50 ms test grid two centres hold the same
    tests), its height with the report's interval there, and the mean at 50-150 ms."""
    from apac_mj.report import hardwick
    from apac_mj.report.stats import seed_interval

    rows = []
    for (practice, variant), g in seeds.groupby(["practice", "variant"]):
        cur = []
        for _, s in g.groupby("seed"):
            t, counts = remapped_counts(s)
            cur.append(hardwick.sliding_window(t * 1000.0, counts, WINDOW_CENTRES_MS, WINDOW_MS)[1])
        cur = np.asarray(cur)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # windows without a test are NaN for every seed
            mean = np.nanmean(cur, axis=0)
        if not np.isfinite(mean).any():
            continue
        j = int(np.nanargmax(mean))
        tied = WINDOW_CENTRES_MS[np.isclose(mean, mean[j], rtol=0, atol=1e-12)]  # windows holding the same tests
        lo, hi = seed_interval(cur[:, j], (0.0, 1.0))
        short = (WINDOW_CENTRES_MS >= 50) & (WINDOW_CENTRES_MS <= 150)
        rows.append({"practice": practice, "variant": variant, "seeds": len(cur),
                     "window_peak_ms": float(tied.mean()), "window_peak": float(mean[j]),
                     "window_peak_lo": lo, "window_peak_hi": hi,
                     "window_50_150": float(np.nanmean(mean[short])) if np.isfinite(mean[short]).any() else np.nan})
    return pd.DataFrame(rows)


def curves_as_counts(curve: pd.DataFrame, trials: int) -> pd.DataFrame:
    """A :func:`per_seed`-like table with one pseudo-seed (``"pooled"``) per practice, variant, cue type and time
    from a published ``curves.csv`` (means over ``seeds``): counts = mean rate × seeds × ``trials`` per seed,
    for reports made before the per-seed tables were shipped; the fits of it are the seed-pooled agent's."""
    rate = curve[["correct", "habitual", "other", "timeout"]].to_numpy(float)
    n = curve["seeds"].to_numpy(float)[:, None] * trials
    counts = np.round(rate * n)
    if np.abs(rate * n - counts).max() > 0.25:  # 4-decimal rates of a few thousand trials are within 0.25
        raise ValueError(f"curves.csv: rates x seeds x {trials} trials are not counts; give the trials per seed, "
                         "cue type and time the test ran")
    out = curve[["practice", "variant", "remapped", "prep_ms"]].copy()
    out["seed"] = "pooled"
    out[["correct", "habitual", "other", "timeout"]] = counts
    return out


def t50(p_correct: pd.Series) -> float:
    """The preparation time (ms; linear between tested times) where the mean P(correct), indexed by time,
    first reaches 0.5 (the human summary's ``t50_correct_*``); NaN if it never does."""
    p = p_correct.sort_index()
    t, v = p.index.to_numpy(dtype=float), p.to_numpy(dtype=float)
    above = np.flatnonzero(v >= 0.5)
    if above.size == 0:
        return float("nan")
    i = int(above[0])
    if i == 0:
        return float(t[0])
    return float(t[i - 1] + (0.5 - v[i - 1]) / (v[i] - v[i - 1]) * (t[i] - t[i - 1]))


def figure(curve: pd.DataFrame, out: str | Path, human: pd.DataFrame | None = None,
           variants: Sequence[str] | None = None) -> Path:
    """Rows: the variants; columns: remapped and unchanged cues; P(correct) and P(habitual error) (unchanged:
    P(error)) against preparation time, each practice length a shade, the human curves (4-day, 20-day) in grey."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tested = order(curve.variant)
    variants = list(variants or tested)
    practices = sorted(curve.practice.unique())
    fig, axes = plt.subplots(len(variants), 2, figsize=(10, 2.3 * len(variants)), sharex=True, sharey=True,
                             squeeze=False)
    shades = np.linspace(0.45, 1.0, len(practices))
    for i, v in enumerate(variants):
        for j, remapped in enumerate((True, False)):
            ax = axes[i, j]
            _human(ax, human, remapped)
            for p, shade in zip(practices, shades):
                g = curve[(curve.variant == v) & (curve.remapped == remapped) & (curve.practice == p)]
                g = g.sort_values("prep_ms")
                for rate, color in (("correct", "#0072B2"), ("habitual" if remapped else "error", "#D55E00")):
                    ax.plot(g.prep_ms, g[rate], color=color, alpha=shade, lw=1.6,
                            label=f"{'P(correct)' if rate == 'correct' else 'P(habitual error)' if remapped else 'P(error)'}"
                                  f", {p} episodes")
                    ax.fill_between(g.prep_ms, g[f"{rate}_lo"], g[f"{rate}_hi"], color=color, alpha=0.15 * shade)
                ax.plot(g.prep_ms, g["timeout"], color="0.3", ls=":", alpha=shade, lw=1)
            ax.set_title(f"{label(v, tested)}: {'remapped' if remapped else 'unchanged'} cues", fontsize=9)
            ax.set_ylim(-0.02, 1.02)
            ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("preparation time (ms)")
    axes[0, 0].legend(fontsize=6, loc="center right")
    fig.suptitle("Forced response after the remap. Model: colours, 95% seed interval (Student-t), dotted: time-outs.\n"
                 "Humans (Hardwick et al. 2019): grey, 4-day dashed, 20-day solid; light: P(correct), dark: "
                 "P(habitual error) / P(error)", fontsize=9)
    fig.tight_layout()
    path = Path(out)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _human(ax, human: pd.DataFrame | None, remapped: bool) -> None:
    """The human curves (P(correct), P(habitual error) or P(error)) of the 4-day and 20-day groups, in grey."""
    if human is None:
        return
    stim = "remapped" if remapped else "unchanged"
    for condition, ls in (("4day", "--"), ("20day", "-")):
        g = human[(human.condition == condition) & (human.stimulus == stim)].sort_values("prep_ms")
        if g.empty:
            continue
        ax.plot(g.prep_ms, g.p_correct, color="0.55", ls=ls, lw=1)
        wrong = g.p_habitual if remapped else 1 - g.p_correct
        ax.plot(g.prep_ms, wrong, color="0.35", ls=ls, lw=1)


def write_report(study: str | Path, human: str | Path | None = None, out: str | Path | None = None) -> Path:
    """The report of a study's tests (each checked first: :func:`load_tests`): ``curves.csv``, ``peaks.csv``,
    ``forced_response.png`` under ``out`` (default ``study/report``); ``human``: the human curves' CSV (default:
    the published one, if present)."""
    from apac_mj.util import paths

    seeds = per_seed(load_tests(study))
    out = Path(study) / "report" if out is None else Path(out)
    out.mkdir(parents=True, exist_ok=True)
    curve, peak = curves(seeds), peaks(seeds)
    curve.round(4).to_csv(out / "curves.csv", index=False)
    peak.round(4).to_csv(out / "peaks.csv", index=False)
    write_hardwick(seeds, out, paths.repo_root() / HUMAN_FITS)
    human = Path(human) if human else paths.repo_root() / "docs/results/forced_response/human/human_curves.csv"
    figure(curve, out / "forced_response.png", pd.read_csv(human) if human.is_file() else None)
    return out


def write_hardwick(seeds: pd.DataFrame, out: str | Path, human: str | Path | None = None) -> None:
    """Hardwick et al.'s model per seed (``hardwick_fits.csv``), its summary per practice and variant with the
    report's intervals (``hardwick.csv``), the humans' windowed peaks of the agents (``window_peaks.csv``) and,
    given the humans' fits (``human``: scripts/hardwick_human.py's ``hardwick_fits.csv``), both side by side
    (``hardwick_vs_humans.csv``, :func:`apac_mj.report.hardwick.side_by_side`)."""
    from apac_mj.report import hardwick

    fits = hardwick_fits(seeds)
    fits.round(6).to_csv(Path(out) / "hardwick_fits.csv", index=False)
    summary = hardwick.summarize(fits, ["practice", "variant"])
    summary.round(4).to_csv(Path(out) / "hardwick.csv", index=False)
    window_peaks(seeds).round(4).to_csv(Path(out) / "window_peaks.csv", index=False)
    if human is not None and Path(human).is_file():
        humans = pd.read_csv(human)
        humans = humans[humans.condition.isin(HUMAN_GROUPS)]
        hardwick.side_by_side(summary, humans).round(4).to_csv(Path(out) / "hardwick_vs_humans.csv", index=False)
