#!/usr/bin/env python
"""Human forced-response curves of Hardwick, Forrence, Krakauer & Haith (2019).

Source: github.com/adrianhaith/HabitTR, branch ``publication``, commit
0e0b08a4c9cc009c9a5646ffe11731995ec1d2f1. How each step follows the MATLAB code:

* Data layout -- ``Publication/preprocess_data.m`` wrote ``HabitData.mat`` holding a
  24 x 3 struct array ``data(subject, condition)``; condition 1/2/3 = minimal/4day/20day
  (l. 3, 8, 74). ``RT``/``response`` hold the remapped ("revised") symbols (l. 59-61,
  68-69), ``RT_unchanged``/``response_unchanged`` the unchanged ones (l. 64-66, 76-77).
  RT is preparation time in s (l. 47).
* Response coding -- raw code 0 (non-habitual error) was recoded to 3 (l. 49-55), so in
  the file 1 = correct, 2 = habitual error, 3 = other (non-habitual) error, as used by
  ``Publication/habit_lik.m`` l. 5-7.
* Exclusions -- subjects in ``d.e1.exclude``/``d.e2.exclude`` were never written
  (l. 9-16) and are empty entries; like ``Publication/fit_model_to_all_data.m`` l. 12,
  ``Publication/make_plots.m`` l. 14/40 and ``count_trials_in_window.m`` l. 5 we keep a
  subject iff ``RT`` is non-empty. Trials with RT = NaN are dropped
  (``Publication/fit_model.m`` l. 44-47). Nothing else is excluded (negative RTs stay).
* Remapped/unchanged split -- preprocess_data.m l. 59 and l. 64 select trials by
  ``ismember`` on RT *values*, so a trial whose RT (1 ms resolution) equals that of a
  trial of the other type lands in both lists. We keep this as written; ``--drop-shared``
  removes such trials from both lists as a sensitivity check.
* Window -- make_plots.m gives no width (it plots stored curves, l. 45-47). The stored
  ``sliding_window`` rows match a 100 ms window best, and the (commented) window in
  ``Publication/fit_speed_accuracy_AE2.m`` l. 38-41 is w = 0.1 s over (c-w/2, c+w/2];
  we use that. As in ``example/sliding_window.m`` l. 12-16, a window with <= 3 trials
  gives NaN for that subject.
* "Other" -- we report the total P(code 3); the authors' ``sliding_window(3,:)`` and
  make_plots.m (l. 54) halve it (per each of the two other keys). For unchanged
  stimuli p_habitual is left empty and p_other holds P(error) = 1 - P(correct).

Usage: ``python scripts/hardwick_human.py --mat HabitData.mat --out DIR``
"""
from __future__ import annotations

import argparse
import csv
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import scipy.io as sio

from apac_mj.report import hardwick
from apac_mj.util.progress import progress_iter

CONDITIONS = ("minimal", "4day", "20day")
STIMULI = ("remapped", "unchanged")
CENTRES_MS = np.arange(50, 1201, 25)
WIDTH_S = 0.100
N_BOOT = 2000
SEED = 0


def load_subjects(mat: Path, drop_shared: bool = False) -> dict[str, list[dict[str, np.ndarray]]]:
    """Per condition, a list of subjects with RT (s) and codes for both stimulus types."""
    data = sio.loadmat(str(mat))["data"]
    out: dict[str, list[dict[str, np.ndarray]]] = {}
    for c, name in enumerate(CONDITIONS):
        subs = []
        for s in range(data.shape[0]):
            e = data[s, c]
            if e["RT"].size == 0:
                continue
            rt_r, y_r = e["RT"].ravel().astype(float), e["response"].ravel().astype(int)
            rt_u, y_u = e["RT_unchanged"].ravel().astype(float), e["response_unchanged"].ravel().astype(int)
            shared_r, shared_u = np.isin(rt_r, rt_u), np.isin(rt_u, rt_r)
            keep_r = ~np.isnan(rt_r) & ~(drop_shared & shared_r)
            keep_u = ~np.isnan(rt_u) & ~(drop_shared & shared_u)
            subs.append({"rt_remapped": rt_r[keep_r], "y_remapped": y_r[keep_r],
                         "rt_unchanged": rt_u[keep_u], "y_unchanged": y_u[keep_u],
                         "n_shared": np.array(int(shared_r.sum()))})
        out[name] = subs
    return out


def window_probs(rt: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(3, n_centres) sliding-window P(code 1), P(code 2), P(code 3); NaN if <= 3 trials
    (:func:`apac_mj.report.hardwick.sliding_window`, the same window the agents' trials are analysed with)."""
    onehot = (np.asarray(y)[:, None] == np.arange(1, 4)[None, :]).astype(float)
    return hardwick.sliding_window(rt, onehot, CENTRES_MS / 1000.0, WIDTH_S)


def fit_subjects(data: dict[str, list[dict[str, np.ndarray]]]) -> pd.DataFrame:
    """Hardwick et al.'s habit and no-habit models fitted to each subject's remapped-symbol trials, as
    ``Publication/fit_model_to_all_data.m`` does (``data(subject, c).RT`` / ``.response``; RT = NaN dropped):
    one :func:`apac_mj.report.hardwick.fit_row` per subject and condition (times in ms)."""
    todo = [(cond, i, s) for cond in CONDITIONS for i, s in enumerate(data[cond])]
    rows = []
    for cond, i, s in progress_iter(todo, len(todo), "Hardwick fits", "subject"):
        row = hardwick.fit_row(s["rt_remapped"], hardwick.trial_counts(s["y_remapped"]))
        rows.append({"condition": cond, "subject": i, **row})
    return pd.DataFrame(rows)


def write_fits(data: dict[str, list[dict[str, np.ndarray]]], out: Path, subjects_out: Path | None) -> None:
    """The fits' summary per condition (``hardwick_fits.csv`` in ``out``: mean and interval over subjects, how
    many favour the habit model); the per-subject fits only to ``subjects_out`` (the data carry no licence)."""
    fits = fit_subjects(data)
    if subjects_out is not None:
        subjects_out.parent.mkdir(parents=True, exist_ok=True)
        fits.round(6).to_csv(subjects_out, index=False)
    summ = hardwick.summarize(fits, ["condition"])
    summ["condition"] = pd.Categorical(summ["condition"], CONDITIONS, ordered=True)
    summ.sort_values("condition").round(4).to_csv(out / "hardwick_fits.csv", index=False)


def subject_curves(subs: list[dict[str, np.ndarray]], stim: str) -> np.ndarray:
    """(n_subjects, 3, n_centres): P(correct), P(habitual), P(other) per subject."""
    cur = np.stack([window_probs(s[f"rt_{stim}"], s[f"y_{stim}"]) for s in subs])
    if stim == "unchanged":
        cur[:, 1] = np.nan
        cur[:, 2] = 1.0 - cur[:, 0]
    return cur


def bootstrap_means(cur: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(N_BOOT, 3, n_centres) subject-resampled mean curves."""
    idx = rng.integers(0, cur.shape[0], size=(N_BOOT, cur.shape[0]))
    return np.nanmean(cur[idx], axis=1)


def first_crossing(p: np.ndarray, level: float = 0.5) -> float:
    """Prep time (ms, linear interpolation) at which curve p first reaches level."""
    hit = np.flatnonzero(p >= level)
    if hit.size == 0:
        return float("nan")
    i = int(hit[0])
    if i == 0 or np.isnan(p[i - 1]):
        return float(CENTRES_MS[i])
    return float(CENTRES_MS[i - 1] + (level - p[i - 1]) / (p[i] - p[i - 1]) * 25.0)


def ci(x: np.ndarray) -> tuple[float, float]:
    """95% percentile interval, ignoring NaN."""
    lo, hi = np.nanpercentile(x, [2.5, 97.5])
    return float(lo), float(hi)


def fmt(x: float) -> str:
    """3-decimal string, empty for NaN."""
    return "" if np.isnan(x) else f"{x:.3f}"


def parse_args() -> argparse.Namespace:
    """The command line, checked (a missing file or --subject-fits without --fits is refused)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--mat", type=Path, required=True,
                    help="HabitData.mat from github.com/adrianhaith/HabitTR (branch publication, Publication/)")
    ap.add_argument("--out", type=Path, required=True,
                    help="folder for human_curves.csv, human_summary.csv and human_curves.png")
    ap.add_argument("--drop-shared", action="store_true", help="drop trials whose RT occurs in both lists")
    ap.add_argument("--fits", action="store_true",
                    help="also fit Hardwick et al.'s habit and no-habit models per subject (hardwick_fits.csv)")
    ap.add_argument("--subject-fits", type=Path, default=None,
                    help="with --fits: write the per-subject fits here (keep it out of git: the data have no licence)")
    args = ap.parse_args()
    if not args.mat.is_file():
        ap.error(f"--mat {args.mat}: no such file (download HabitData.mat from the HabitTR repository)")
    if args.subject_fits is not None and not args.fits:
        ap.error("--subject-fits needs --fits")
    return args


def main() -> None:
    """Compute curves and summary (and with --fits the model's fits), write CSVs and figure."""
    args = parse_args()
    warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN windows/slices are expected
    args.out.mkdir(parents=True, exist_ok=True)
    data = load_subjects(args.mat, args.drop_shared)
    if args.fits:
        write_fits(data, args.out, args.subject_fits)
    rng = np.random.default_rng(SEED)
    res: dict[tuple[str, str], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    rows, summ = [], []
    for cond in CONDITIONS:
        for stim in STIMULI:
            cur = subject_curves(data[cond], stim)
            mean = np.nanmean(cur, axis=0)
            boot = bootstrap_means(cur, rng)
            res[cond, stim] = (cur, mean, boot)
            nsub = np.sum(~np.isnan(cur[:, 0]), axis=0)
            for j, t in enumerate(CENTRES_MS):
                row = [cond, stim, int(t), int(nsub[j])]
                for k in range(3):
                    row += [fmt(mean[k, j]), *map(fmt, ci(boot[:, k, j]) if not np.all(np.isnan(boot[:, k, j])) else (np.nan, np.nan))]
                rows.append(row)
        _, m_r, b_r = res[cond, "remapped"]
        _, m_u, b_u = res[cond, "unchanged"]
        ok = ~np.isnan(m_r[1])
        j = int(np.nanargmax(m_r[1]))
        bj = np.nanargmax(b_r[:, 1], axis=1)
        long_, short = (CENTRES_MS >= 900) & (CENTRES_MS <= 1200), (CENTRES_MS >= 50) & (CENTRES_MS <= 150)
        t50r = np.array([first_crossing(b[0]) for b in b_r])
        t50u = np.array([first_crossing(b[0]) for b in b_u])
        subs = data[cond]
        summ.append([cond, len(subs), sum(s["rt_remapped"].size for s in subs), sum(s["rt_unchanged"].size for s in subs),
                     sum(int(s["n_shared"]) for s in subs),
                     int(CENTRES_MS[j]), *map(fmt, ci(CENTRES_MS[bj].astype(float))),
                     fmt(m_r[1, j]), *map(fmt, ci(b_r[np.arange(N_BOOT), 1, bj])),
                     fmt(np.nanmean(m_r[1, long_ & ok])), *map(fmt, ci(np.nanmean(b_r[:, 1, long_], axis=1))),
                     fmt(np.nanmean(m_r[1, short & ok])), *map(fmt, ci(np.nanmean(b_r[:, 1, short], axis=1))),
                     fmt(first_crossing(m_r[0])), *map(fmt, ci(t50r)),
                     fmt(first_crossing(m_u[0])), *map(fmt, ci(t50u))])
    write_tables(args.out, rows, summ)
    plot(res, args.out / "human_curves.png")


def write_tables(out: Path, rows: list[list], summ: list[list]) -> None:
    """``human_curves.csv`` and ``human_summary.csv`` with their headers."""
    head = ["condition", "stimulus", "prep_ms", "n_subjects"] + [
        f"p_{q}{s}" for q in ("correct", "habitual", "other") for s in ("", "_lo", "_hi")]
    with open(out / "human_curves.csv", "w", newline="") as f:
        csv.writer(f).writerows([head, *rows])
    shead = ["condition", "n_subjects", "n_trials_remapped", "n_trials_unchanged", "n_trials_rt_shared",
             "habit_peak_ms", "habit_peak_ms_lo", "habit_peak_ms_hi",
             "habit_peak_height", "habit_peak_height_lo", "habit_peak_height_hi",
             "habit_900_1200", "habit_900_1200_lo", "habit_900_1200_hi",
             "habit_50_150", "habit_50_150_lo", "habit_50_150_hi",
             "t50_correct_remapped_ms", "t50_correct_remapped_ms_lo", "t50_correct_remapped_ms_hi",
             "t50_correct_unchanged_ms", "t50_correct_unchanged_ms_lo", "t50_correct_unchanged_ms_hi"]
    with open(out / "human_summary.csv", "w", newline="") as f:
        csv.writer(f).writerows([shead, *summ])


def plot(res: dict[tuple[str, str], tuple[np.ndarray, np.ndarray, np.ndarray]], path: Path) -> None:
    """Two panels (remapped, unchanged): P(correct) and P(habitual) / P(error), 4-day and 20-day."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    colours = {"4day": ("tab:cyan", "tab:orange"), "20day": ("tab:blue", "tab:red")}
    for ax, stim in zip(axes, STIMULI):
        for cond, (cc, ch) in colours.items():
            _, mean, boot = res[cond, stim]
            k2, lab2 = (1, "P(habitual error)") if stim == "remapped" else (2, "P(error)")
            for k, col, lab in ((0, cc, "P(correct)"), (k2, ch, lab2)):
                lo, hi = np.nanpercentile(boot[:, k], [2.5, 97.5], axis=0)
                ax.fill_between(CENTRES_MS, lo, hi, color=col, alpha=0.2, lw=0)
                ax.plot(CENTRES_MS, mean[k], color=col, label=f"{cond} {lab}")
        ax.set(title=f"{stim} stimuli", xlabel="preparation time (ms)", xlim=(0, 1200), ylim=(0, 1))
        ax.legend(fontsize=7)
    axes[0].set_ylabel("probability (mean over subjects, 95% bootstrap)")
    fig.tight_layout()
    fig.savefig(path, dpi=120, metadata={"Software": None})
    plt.close(fig)


if __name__ == "__main__":
    main()
