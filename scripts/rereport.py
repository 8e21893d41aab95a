"""Re-report every published page's intervals from its shipped per-seed values (issue 41).

    python scripts/rereport.py [--results docs/results] [--check]

Reads the per-seed values the pages ship (``per_seed`` columns of key_numbers.csv, events/effects/probe
tables of the dynamics study, the precision comparison) and rewrites their intervals with the report's method
(:func:`apac_mj.report.stats.seed_interval`; rates widened to the pooled count's Wilson interval, rate
differences to Newcombe's), then the Key numbers and Key differences tables of each report.md. ``--check``
writes nothing and exits 1 if a file would change. A rate's pooled count is ``mean x samples / 100`` (the
per-seed counts are not shipped; the pooled proportion is exact where every seed has the same samples).
Values printed to 2 decimals (3 significant digits in the dynamics tables) are what the intervals rest on.
"""
from __future__ import annotations

import argparse
import math
import re
import sys
from pathlib import Path

import pandas as pd

from apac_mj.report import stats
from apac_mj.report.figures import LIST_SEEDS
from apac_mj.report.labels import AGENT_LABEL, condition_short
from apac_mj.report.markdown import _differences, _key_numbers

ROOT = Path(__file__).resolve().parents[1]
#: Studies made after issue 41 with the measured interval already; not rewritten here.
SKIP = ("planning/budgets",)
RATE_BOUNDS, POSITIVE = (0.0, 100.0), (0.0, math.inf)
#: Quantities of the dynamics tables that are fractions in [0, 1].
FRACTIONS = {"success", "habit_share"}


def parse_seeds(text: object) -> pd.Series:
    """``"0: 1.00; 1: 2.00"`` or ``"0:1 1:2"`` -> values indexed by seed (empty for none)."""
    pairs = re.findall(r"(\d+)\s*:\s*(-?[\d.]+(?:e-?\d+)?|nan)", str(text))
    return pd.Series({int(s): float(v) for s, v in pairs}, dtype=float)


def key_interval(row: pd.Series) -> tuple[float, float]:
    """One key number's interval from its per-seed values (a rate: and its pooled count)."""
    v = parse_seeds(row["per_seed"]).dropna()
    if row["unit"] == "%":
        k, n = row["mean"] * row["samples"] / 100, row["samples"]
        return stats.interval(v.tolist(), [k], [n])[1:]
    return stats.interval(v.tolist(), bounds=POSITIVE)[1:]


def rereport_key_numbers(table: pd.DataFrame) -> pd.DataFrame:
    """key_numbers.csv with every interval recomputed and the method named."""
    out = table.copy()
    for i, row in table.iterrows():
        out.loc[i, ["ci95_low", "ci95_high"]] = key_interval(row)
        out.loc[i, "interval"] = stats.RATE_METHOD if row["unit"] == "%" else stats.METHOD
    return out


def cells(table: pd.DataFrame) -> dict[tuple[str, str], pd.Series]:
    """(quantity, "AGENT cond") -> that key number's row, as differences.csv names the sides."""
    return {(r["quantity"], f"{AGENT_LABEL[r['agent']]} {condition_short(r['condition'])}"): r
            for _, r in table.iterrows()}


def difference_interval(q: str, one: pd.Series, other: pd.Series) -> tuple[float, float, int]:
    """``one - other`` on quantity ``q``: the report's interval and the seeds both sides have."""
    a, b = parse_seeds(one["per_seed"]).dropna(), parse_seeds(other["per_seed"]).dropna()
    rate = one["unit"] == "%"
    _, lo, hi, _ = stats.paired_difference(a, b, bounds=(-100.0, 100.0) if rate else None)
    if rate and not math.isnan(lo):
        nlo, nhi = stats.newcombe_interval(one["mean"] * one["samples"] / 100, one["samples"],
                                           other["mean"] * other["samples"] / 100, other["samples"])
        lo, hi = min(lo, 100 * nlo), max(hi, 100 * nhi)
    return lo, hi, int(min(a.size, b.size))


def rereport_differences(diffs: pd.DataFrame, table: pd.DataFrame) -> pd.DataFrame:
    """differences.csv with every interval recomputed from the two sides' per-seed values."""
    by, out = cells(table), diffs.copy()
    for i, row in diffs.iterrows():
        left, right = row["comparison"].split(" - ")
        one, other = by[(row["quantity"], left)], by[(row["quantity"], right)]
        lo, hi, _ = difference_interval(row["quantity"], one, other)
        paired = set(parse_seeds(one["per_seed"]).index) == set(parse_seeds(other["per_seed"]).index)
        out.loc[i, ["ci95_low", "ci95_high"]] = lo, hi
        out.loc[i, "interval"] = (("paired " + stats.METHOD) if paired else "Welch t over seeds (unpaired)") \
            + (" + Newcombe (pooled counts)" if row["unit"] == "points" else "")
    return out


def rereport_md(text: str, table: pd.DataFrame, diffs: pd.DataFrame) -> str:
    """report.md with the intervals' description and the two tables rewritten from the CSVs."""
    head = text[:text.index("## Key numbers")]
    head = re.sub(r"\*\*Intervals\*\*.*?\*\*samples\*\*", INTERVALS + " **samples**", head, flags=re.S)
    t = table.assign(paper=table["paper"].fillna(""))
    show = int(table["n_seeds"].max()) <= LIST_SEEDS
    return head + "\n".join(_key_numbers(t, show) + _differences(diffs)) + "\n"


INTERVALS = ("**Intervals** (95%): a Student-t interval over seeds at the 97.5% quantile, clipped to the "
             "quantity's range, whose coverage of a 95% was measured at >= 0.93 for 3, 5 and 10 seeds on values "
             "shaped like these (docs/statistics.md); for rates (%) widened to contain the Wilson score interval "
             f"of the count pooled over seeds. With fewer than {stats.MIN_SEEDS} seeds no interval is given "
             f"({stats.TOO_FEW}): read the per-seed values. Re-reported from the shipped per-seed values by "
             "`scripts/rereport.py` (issue 41); the figures' bands are the original percentile bootstraps.")


#: Dynamics summary tables: file -> (per-seed table, group keys, successes column, trials column, is an effect).
DYNAMICS = {"events.csv": ("windows.csv", ["agent", "condition", "window", "episodes"], "successes", "n", False),
            "probe_summary.csv": ("probes.csv", ["agent", "condition", "after_episode", "plant"], "successes",
                                  "targets", False),
            "effects.csv": (None, [], "", "", True), "probe_effects.csv": (None, [], "", "", True)}


def dynamics_bounds(q: str, effect: bool) -> tuple[float, float] | None:
    """A dynamics quantity's range: fractions in [0, 1] (differences in [-1, 1]); distances and errors
    non-negative; signed lateral deviations and other differences unbounded."""
    if q in FRACTIONS:
        return (-1.0, 1.0) if effect else (0.0, 1.0)
    return None if effect or q == "lateral_cm" else POSITIVE


def rereport_dynamics(summary: pd.DataFrame, per_seed: pd.DataFrame | None, keys: list[str], k: str, n: str,
                      effect: bool) -> pd.DataFrame:
    """A dynamics summary table with its intervals recomputed (success: widened to the pooled count's Wilson
    interval, the counts from the per-seed table)."""
    out = summary.copy()
    for i, row in summary.iterrows():
        v = parse_seeds(row["per_seed"]).dropna().tolist()
        if row["quantity"] == "success" and per_seed is not None:
            sel = per_seed.loc[(per_seed[keys] == row[keys]).all(axis=1)]
            lo, hi = stats.interval(v, [sel[k].sum()], [sel[n].sum()], scale=1.0)[1:]
        else:
            lo, hi = stats.interval(v, bounds=dynamics_bounds(row["quantity"], effect))[1:]
        out.loc[i, ["lo", "hi"]] = lo, hi
    return out


def rereport_compare(df: pd.DataFrame) -> pd.DataFrame:
    """The precision comparison: each side's interval and b - a's, from the per-seed values (pooled counts from
    the means; the samples per seed are not in this table, so the Wilson widening is left out)."""
    out = df.copy()
    for i, row in df.iterrows():
        a, b = parse_seeds(row["a_per_seed"]).dropna(), parse_seeds(row["b_per_seed"]).dropna()
        rate = row["unit"] == "%"
        bounds = RATE_BOUNDS if rate else POSITIVE
        out.loc[i, ["a_low", "a_high"]] = stats.interval(a.tolist(), bounds=bounds)[1:]
        out.loc[i, ["b_low", "b_high"]] = stats.interval(b.tolist(), bounds=bounds)[1:]
        _, lo, hi, _ = stats.paired_difference(b, a, bounds=(-100.0, 100.0) if rate else None)
        out.loc[i, ["diff_low", "diff_high"]] = lo, hi
        out.loc[i, "agree"] = bool(math.isnan(lo) or lo <= 0 <= hi)
    return out


INTERVAL = re.compile(r"\[([−-]?)(\d+(?:\.\d+)?)(%?), ([−-]?)(\d+(?:\.\d+)?)(%?)\]")


def interval_pairs(old: pd.DataFrame, new: pd.DataFrame, lo: str, hi: str, scales: tuple[float, ...] = (1.0,)
                   ) -> list[tuple[float, float, float, float]]:
    """(old low, old high, new low, new high) of each row, at each display scale."""
    return [(s * a, s * b, s * c, s * d) for s in scales
            for a, b, c, d in zip(old[lo], old[hi], new[lo], new[hi]) if not (math.isnan(a) or math.isnan(b))]


def _decimals(text: str) -> int:
    return len(text.split(".")[1]) if "." in text else 0


def _num(sign: str, text: str) -> float:
    return -float(text) if sign else float(text)


def _show(x: float, d: int, minus: str, pct: str) -> str:
    s = f"{abs(x):.{d}f}{pct}"
    return minus + s if round(x, d) < 0 else s


def rewrite_page(text: str, pairs: list[tuple[float, float, float, float]]) -> tuple[str, list[str], list[str]]:
    """``text`` with every printed interval that matches exactly one shipped interval (at the printed
    precision) replaced by its re-reported value; returns the text, what changed and what matched nothing
    or more than one."""
    changed, unmatched = [], []
    minus = "−" if "−" in text else "-"

    def sub(m: re.Match) -> str:
        a, b = _num(m[1], m[2]), _num(m[4], m[5])
        d = max(_decimals(m[2]), _decimals(m[5]))
        tol = 0.5 * 10 ** -d + 1e-9
        new = {(round(c, d), round(e, d)) if not math.isnan(c) else None
               for lo, hi, c, e in pairs if abs(lo - a) <= tol and abs(hi - b) <= tol}
        if len(new) != 1:
            unmatched.append(f"{m[0]} ({'no match' if not new else 'ambiguous'})")
            return m[0]
        (pair,) = new
        out = f"({stats.TOO_FEW})" if pair is None else \
            f"[{_show(pair[0], d, m[1] or m[4] or minus, m[3])}, {_show(pair[1], d, m[4] or m[1] or minus, m[6])}]"
        if out != m[0]:
            changed.append(f"{m[0]} -> {out}")
        return out
    return INTERVAL.sub(sub, text), changed, unmatched


def _skipped(path: Path, results: Path) -> bool:
    return any(path.relative_to(results).as_posix().startswith(s + "/") for s in SKIP)


def rereport_tables(results: Path) -> tuple[dict[Path, str], dict[Path, list]]:
    """Every rewritten file's new text and, per study directory, its (old, new) interval pairs."""
    files: dict[Path, str] = {}
    pairs: dict[Path, list] = {}
    for kn in sorted(results.rglob("key_numbers.csv")):
        if _skipped(kn, results):
            continue
        old = pd.read_csv(kn)
        new = rereport_key_numbers(old)
        files[kn] = new.to_csv(index=False)
        pairs.setdefault(kn.parent, []).extend(interval_pairs(old, new, "ci95_low", "ci95_high"))
        dpath = kn.parent / "differences.csv"
        dold = pd.read_csv(dpath) if dpath.is_file() else pd.DataFrame()
        dnew = rereport_differences(dold, old) if len(dold) else dold
        if len(dold):
            files[dpath] = dnew.to_csv(index=False)
            pairs[kn.parent].extend(interval_pairs(dold, dnew, "ci95_low", "ci95_high"))
        md = kn.parent / "report.md"
        if md.is_file():
            files[md] = rereport_md(md.read_text(), new, dnew if len(dold) else pd.DataFrame())
    for name, (per_name, keys, k, n, effect) in DYNAMICS.items():
        path = results / "dynamics" / name
        if path.is_file():
            old = pd.read_csv(path)
            per = pd.read_csv(results / "dynamics" / per_name) if per_name else None
            new = rereport_dynamics(old, per, keys, k, n, effect)
            files[path] = new.to_csv(index=False, float_format="%.4g")
            pairs.setdefault(path.parent, []).extend(interval_pairs(old, new, "lo", "hi", (1.0, 100.0)))
    for path in sorted((results / "precision").glob("compare*.csv")):
        old = pd.read_csv(path)
        new = rereport_compare(old)
        files[path] = new.to_csv(index=False)
        for lo, hi in (("a_low", "a_high"), ("b_low", "b_high"), ("diff_low", "diff_high")):
            pairs.setdefault(path.parent, []).extend(interval_pairs(old, new, lo, hi))
    return files, pairs


def rereport_pages(results: Path, pairs: dict[Path, list]) -> tuple[dict[Path, str], list[str]]:
    """Every hand-written page (README.md, extras.md) with its printed intervals re-reported from the
    intervals of the tables in its directory and below (the top README: every table)."""
    files, log = {}, []
    for page in sorted(results.rglob("*.md")):
        if page.name == "report.md" or _skipped(page, results):
            continue
        mine = [p for d, ps in pairs.items() if page.parent == results or d.is_relative_to(page.parent) for p in ps]
        text, changed, unmatched = rewrite_page(page.read_text(), mine)
        files[page] = text
        rel = page.relative_to(results)
        log += [f"{rel}: {c}" for c in changed] + [f"{rel}: left as printed: {u}" for u in unmatched]
    return files, log


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--results", type=Path, default=ROOT / "docs" / "results")
    p.add_argument("--check", action="store_true", help="write nothing; exit 1 if a file would change")
    a = p.parse_args(argv)
    if not (a.results / "README.md").is_file():
        p.error(f"{a.results}: not a results directory (no README.md); pass docs/results")
    tables, pairs = rereport_tables(a.results)
    pages, log = rereport_pages(a.results, pairs)
    stale = [f for f, text in {**tables, **pages}.items() if f.read_text() != text]
    print("\n".join(log))
    print(f"{len(stale)} file(s) {'would change' if a.check else 'rewritten'}: "
          + ", ".join(str(f.relative_to(a.results)) for f in stale))
    if a.check:
        return 1 if stale else 0
    for f in stale:
        f.write_text({**tables, **pages}[f])
    return 0


if __name__ == "__main__":
    sys.exit(main())
