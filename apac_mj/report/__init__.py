"""The paper's results section from a grid's results directory: Figs. 3-9 and a key-number table.

Every number is computed per seed first, then summarized over seeds as the
mean with a 95% interval that respects the quantity's range
(:func:`interval`): a percentile bootstrap over seeds, and for rates that
interval widened to contain the Wilson score interval of the pooled count, so
that a rate every seed hits (100 of 100) still shows its sampling
uncertainty. The same intervals are drawn in the figures. Beside every mean
the table gives the per-seed values and the count of samples (episodes,
targets, actions) it rests on; :func:`differences` gives intervals of the key
comparisons (APAC vs SPAC success, APAC's habit share across conditions).
``key_numbers.csv`` and ``differences.csv`` hold them all and ``report.md``
shows them beside the values the paper states.
"""
from __future__ import annotations

import dataclasses
import math
import textwrap
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from scipy import stats  # noqa: E402

from apac_mj import kinds  # noqa: E402
from apac_mj.util.files import read_json  # noqa: E402
from apac_mj.experiments.presets import CONDITIONS  # noqa: E402
from apac_mj.experiments.results import MANIFEST, load_results, load_tests  # noqa: E402



class _KindView(Mapping):
    """A live read-only view ``kind name -> AgentKind.<attr>`` of the registry (apac_mj.kinds)."""

    def __init__(self, attr: str) -> None:
        self.attr = attr

    def __getitem__(self, name: str) -> str:
        return getattr(kinds.get(name), self.attr)

    def __iter__(self) -> Iterator[str]:
        return iter(kinds.names())

    def __len__(self) -> int:
        return len(kinds.names())


#: Figure and table labels and colours of the agent kinds, read from the registry.
AGENT_LABEL, AGENT_COLOR = _KindView("label"), _KindView("color")
#: The paper's abbreviations (Fig. 4): target / kinematics, s = static, c = changing. Another condition
#: (a task of the user's) is called by its name, labelled by its description and coloured from EXTRA_COLORS.
COND_SHORT = {"static_target": "ss", "static_target_changing_kinematics": "sc",
              "changing_target": "cs", "changing_target_changing_kinematics": "cc",
              "changing_target_noisy": "cs noisy", "changing_target_intermittent": "cs interm."}
COND_LABEL = {"static_target": "static target / static kinematics",
              "static_target_changing_kinematics": "static target / changing kinematics",
              "changing_target": "changing target / static kinematics",
              "changing_target_changing_kinematics": "changing target / changing kinematics"}
#: Condition colours (Fig. 3, top row): none of them an agent's colour.
COND_COLOR = {"static_target": "tab:purple", "static_target_changing_kinematics": "tab:brown",
              "changing_target": "tab:olive", "changing_target_changing_kinematics": "tab:cyan"}
#: Colours for conditions beyond the paper's (none of them a built-in agent's or condition's).
EXTRA_COLORS = ("tab:gray", "tab:red", "gold", "navy", "teal", "darkred")


def _cond_color(cond: str) -> str:
    """A condition's colour: the paper's, else the next unused extra colour (stable per name)."""
    return COND_COLOR.get(cond) or EXTRA_COLORS[sum(map(ord, cond)) % len(EXTRA_COLORS)]


def _cond_short(cond: str) -> str:
    return COND_SHORT.get(cond, cond)


def _cond_label(cond: str) -> str:
    """The paper's label, or the task's own description for another condition."""
    if cond in COND_LABEL:
        return COND_LABEL[cond]
    from apac_mj.suite.task_spec import load_task

    try:
        return load_task(cond).description or cond
    except KeyError:
        return cond


#: Interval level, bootstrap resamples and the bootstrap's fixed seed (reports are reproducible).
LEVEL, BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED = 0.95, 10_000, 0
#: A mean resting on fewer samples than this is marked in report.md.
FEW_SAMPLES = 10
#: Per-seed values are listed in report.md up to this many seeds.
LIST_SEEDS = 10
#: Planning actions cost this many habitual ones (paper, Fig. 6).
PLANNING_COST = 3
#: Steps per episode (the task files' time limit), for results without the ``judged_reached`` column.
STEP_LIMIT = 30
#: Summary windows: the last LATE_FRACTION of training episodes.
LATE_FRACTION = 0.2

# What the paper states ("Results"), keyed by (quantity, agent, condition); "*" matches any.
PAPER = {
    ("train_success_late", "spac", "*"): "near perfect after ~ep. 100",
    ("train_success_late", "ddpg", "static_target"): "~100%",
    ("train_success_late", "ddpg", "changing_target"): "~20 points below static target",
    ("train_success_late", "ddpg", "changing_target_changing_kinematics"): "~20 points below static target",
    ("train_success_late", "apac", "*"): "almost all, as good as SPAC",
    ("test_success", "*", "static_target"): "100%",
    ("habit_fraction_late", "apac", "*"): ">80% after ~300 episodes",
    ("generalization_targets", "*", "static_target"): "~39",
    ("generalization_targets", "*", "static_target_changing_kinematics"): "~42",
    ("generalization_targets", "*", "changing_target"): "~39",
    ("generalization_targets", "*", "changing_target_changing_kinematics"): "~42",
    ("generalization_success", "*", "static_target"): "< 50%",
    ("generalization_success", "*", "static_target_changing_kinematics"): "< 50%",
    ("occluded_distance_judged", "spac", "changing_target"): "~0.4 cm",
    ("occluded_distance_judged", "apac", "changing_target"): "~1 cm",
    ("occluded_distance_judged", "spac", "changing_target_changing_kinematics"): "~0.7 cm",
    ("occluded_distance_judged", "apac", "changing_target_changing_kinematics"): "~1.5 cm",
}
QUANTITIES = {
    "train_success_late": ("Fig. 3", "training success rate, last 20% of episodes", "%"),
    "test_success": ("Fig. 4", "test success rate (angle-grid targets)", "%"),
    "test_steps_to_reach": ("Fig. 4", "test steps to reach (reached targets)", "steps"),
    "habit_fraction_late": ("Fig. 5", "APAC habitual share of actions, last 20% of episodes", "%"),
    "steps_late": ("Fig. 6", "action steps per episode, last 20% of episodes", "steps"),
    "time_late": ("Fig. 6", "time per episode (planning = 3 x habit), last 20%", "habit-step units"),
    "generalization_targets": ("Fig. 8", "held-out-region test targets", "targets"),
    "generalization_success": ("Fig. 8", "generalization success rate (held-out region)", "%"),
    "occluded_distance": ("Fig. 9", "occluded vision: final distance to target, all episodes", "cm"),
    "occluded_judged_rate": ("Fig. 9", "occluded vision: episodes ended by the forward model judging the target reached",
                             "%"),
    "occluded_distance_judged": ("Fig. 9", "occluded vision: final distance when the forward model judged it reached",
                                 "cm"),
    "test_habit_fraction": ("Fig. 11", "habitual share of test actions (angle grid)", "%"),
    "test_time": ("Fig. 11", "test time per episode (planning = 3 x habit; angle grid)", "habit-step units"),
    "estimate_error_late": ("Fig. 11", "state-estimate error |estimate - truth| (hand, elbow, target), last 20%", "cm"),
    "test_estimate_error": ("Fig. 11", "state-estimate error on the test grid", "cm"),
}


# -- statistics ----------------------------------------------------------------------

def t_interval(values: Sequence[float], level: float = 0.95) -> tuple[float, float, float]:
    """Mean and Student-t confidence interval over seeds; NaN bounds with fewer than two values.
    Kept for reference: it ignores a quantity's range (a rate's interval can leave [0, 100])."""
    v = np.asarray([x for x in values if not math.isnan(x)], dtype=float)
    if v.size == 0:
        return math.nan, math.nan, math.nan
    mean = float(v.mean())
    if v.size < 2:
        return mean, math.nan, math.nan
    half = float(stats.t.ppf(0.5 + level / 2, v.size - 1) * v.std(ddof=1) / math.sqrt(v.size))
    return mean, mean - half, mean + half


def wilson_interval(k: float, n: float, level: float = LEVEL) -> tuple[float, float]:
    """Wilson score interval of a proportion ``k / n`` (as fractions, inside [0, 1]); NaN if n = 0."""
    if n <= 0:
        return math.nan, math.nan
    z = float(stats.norm.ppf(0.5 + level / 2))
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def bootstrap_interval(values: Sequence[float], level: float = LEVEL, resamples: int = BOOTSTRAP_RESAMPLES,
                       seed: int = BOOTSTRAP_SEED) -> tuple[float, float]:
    """Percentile bootstrap interval of the mean over seeds; NaN with fewer than two values.
    Every resampled mean is a mean of observed values, so the interval stays in the quantity's range."""
    v = np.asarray([x for x in values if not math.isnan(x)], dtype=float)
    if v.size < 2:
        return math.nan, math.nan
    means = v[np.random.default_rng(seed).integers(0, v.size, size=(resamples, v.size))].mean(axis=1)
    lo, hi = np.quantile(means, [0.5 - level / 2, 0.5 + level / 2])
    return float(lo), float(hi)


def interval(values: Sequence[float], k: Sequence[float] | None = None, n: Sequence[float] | None = None,
             scale: float = 100.0) -> tuple[float, float, float]:
    """Mean over seeds and its 95% interval: bootstrap over seeds; for a rate (``k`` successes of ``n``
    per seed, values in units of ``scale``) widened to contain the pooled count's Wilson interval."""
    v = [x for x in values if not math.isnan(x)]
    if not v:
        return math.nan, math.nan, math.nan
    lo, hi = bootstrap_interval(v)
    if k is not None and n is not None and float(np.nansum(n)) > 0:
        wlo, whi = wilson_interval(float(np.nansum(k)), float(np.nansum(n)))
        lo, hi = (scale * wlo, scale * whi) if math.isnan(lo) else (min(lo, scale * wlo), max(hi, scale * whi))
    return float(np.mean(v)), lo, hi


def newcombe_interval(k1: float, n1: float, k2: float, n2: float, level: float = LEVEL) -> tuple[float, float]:
    """Newcombe's hybrid score interval of ``k1/n1 - k2/n2`` (fractions, inside [-1, 1]), from the two
    Wilson intervals; NaN if a count is empty."""
    if n1 <= 0 or n2 <= 0:
        return math.nan, math.nan
    p1, p2 = k1 / n1, k2 / n2
    (l1, u1), (l2, u2) = wilson_interval(k1, n1, level), wilson_interval(k2, n2, level)
    d = p1 - p2
    return max(-1.0, d - math.hypot(p1 - l1, u2 - p2)), min(1.0, d + math.hypot(u1 - p1, p2 - l2))


def paired_difference(a: pd.Series, b: pd.Series, level: float = LEVEL, resamples: int = BOOTSTRAP_RESAMPLES,
                      seed: int = BOOTSTRAP_SEED) -> tuple[float, float, float, bool]:
    """Mean(a) - mean(b) of per-seed values (indexed by seed) with a percentile bootstrap interval:
    seeds resampled jointly where both have the same seeds (paired), else each on its own."""
    a, b = a.dropna(), b.dropna()
    if a.empty or b.empty:
        return math.nan, math.nan, math.nan, False
    rng = np.random.default_rng(seed)
    paired = set(a.index) == set(b.index)
    if paired:
        d = (a - b.reindex(a.index)).to_numpy(float)
        boot = d[rng.integers(0, d.size, size=(resamples, d.size))].mean(axis=1)
    else:
        va, vb = a.to_numpy(float), b.to_numpy(float)
        boot = (va[rng.integers(0, va.size, size=(resamples, va.size))].mean(axis=1)
                - vb[rng.integers(0, vb.size, size=(resamples, vb.size))].mean(axis=1))
    diff = float(a.mean() - b.mean())
    if min(a.size, b.size) < 2:
        return diff, math.nan, math.nan, paired
    lo, hi = np.quantile(boot, [0.5 - level / 2, 0.5 + level / 2])
    return diff, float(lo), float(hi), paired


def paper_value(quantity: str, agent: str, condition: str) -> str:
    for key in ((quantity, agent, condition), (quantity, agent, "*"), (quantity, "*", condition)):
        if key in PAPER:
            return PAPER[key]
    return ""


def late(metrics: pd.DataFrame) -> pd.DataFrame:
    """Training episodes in the last LATE_FRACTION of each cell's run."""
    train = metrics[metrics["phase"] == "train"]
    n = train.groupby(["agent", "condition", "region"])["episode"].transform("max") + 1
    return train[train["episode"] >= n - np.ceil(n * LATE_FRACTION)]


def per_seed(metrics: pd.DataFrame, tests: pd.DataFrame) -> pd.DataFrame:
    """One row per (quantity, agent, condition, seed): every key number before averaging over seeds,
    with ``n`` (the samples behind it: episodes, targets or actions), ``k`` (a rate's successes) and
    ``of`` (for a mean over some of the samples, e.g. steps of the reached targets: of how many)."""
    keys = ["agent", "condition", "seed"]
    rows: list[pd.DataFrame] = []
    main = metrics[metrics["region"] == "all"]
    lt = late(main).assign(time=lambda d: d["habit_actions"] + PLANNING_COST * d["planning_actions"])
    g = lt.groupby(keys)
    rows.append(_rate("train_success_late", g["success"]))
    rows.append(_q("steps_late", g["steps"].mean(), g.size()))
    rows.append(_q("time_late", g["time"].mean(), g.size()))
    arb = lt[lt["agent"].isin(_arbitrating(lt))].groupby(keys)
    habit, actions = arb["habit_actions"].sum(), arb["habit_actions"].sum() + arb["planning_actions"].sum()
    rows.append(_q("habit_fraction_late", 100 * habit / actions, actions, k=habit))
    if "estimate_error" in lt and lt["estimate_error"].notna().any():  # results from before it lack the column
        rows.append(_q("estimate_error_late", g["estimate_error"].mean(), g.size()))
    if not tests.empty:
        grid_tests = tests[tests["protocol"] == "grid"]
        grid = grid_tests.groupby(keys)
        rows.append(_rate("test_success", grid["success"]))
        reached = grid_tests[grid_tests["success"].astype(bool)].groupby(keys)
        every = grid.size().index  # seeds that reached nothing: NaN value, 0 samples, their targets counted in "of"
        rows.append(_q("test_steps_to_reach", reached["steps"].mean().reindex(every),
                       reached.size().reindex(every).fillna(0), of=grid.size()))
        rows.append(_q("test_time", grid["time_cost"].mean(), grid.size()))
        arb_tests = grid_tests[grid_tests["agent"].isin(_arbitrating(grid_tests))].groupby(keys)
        t_habit = arb_tests["habit_actions"].sum()
        t_actions = t_habit + arb_tests["planning_actions"].sum()
        rows.append(_q("test_habit_fraction", 100 * t_habit / t_actions, t_actions, k=t_habit))
        if "estimate_error" in grid_tests and grid_tests["estimate_error"].notna().any():
            rows.append(_q("test_estimate_error", grid["estimate_error"].mean(), grid.size()))
        gen = tests[tests["protocol"] == "generalization"].groupby(keys)
        rows.append(_rate("generalization_success", gen["success"]))
        rows.append(_q("generalization_targets", gen["target_index"].nunique().astype(float), gen.size()))
        occluded = tests[tests["protocol"] == "occluded"]
        occ = occluded.groupby(keys)
        rows.append(_q("occluded_distance", occ["final_distance"].mean(), occ.size()))
        if not occluded.empty:
            judged = occluded.assign(judged=judged_reached(occluded))
            g = judged.groupby(keys)
            rows.append(_rate("occluded_judged_rate", g["judged"]))
            # NaN for a seed whose forward model never judged a target reached
            jg = judged[judged["judged"]].groupby(keys)
            rows.append(_q("occluded_distance_judged", jg["final_distance"].mean().reindex(g.size().index),
                           jg.size().reindex(g.size().index).fillna(0), of=g.size()))
    return pd.concat([r for r in rows if not r.empty], ignore_index=True)


def _rate(name: str, flags: "pd.core.groupby.SeriesGroupBy") -> pd.DataFrame:
    """A per-seed success rate (%) of boolean ``flags``, with its count k of n."""
    k, n = flags.sum().astype(float), flags.size().astype(float)
    return _q(name, 100 * k / n, n, k=k)


def judged_reached(occluded: pd.DataFrame) -> pd.Series:
    """Episodes that ended because the forward model's estimate was inside the zone. Results written
    before the ``judged_reached`` column: episodes that ended before the 30-step limit."""
    if "judged_reached" in occluded and occluded["judged_reached"].notna().all():
        return occluded["judged_reached"].astype(bool)
    return occluded["steps"] < STEP_LIMIT


def _q(name: str, series: pd.Series, n: pd.Series, k: pd.Series | None = None,
       of: pd.Series | None = None) -> pd.DataFrame:
    df = series.rename("value").reset_index()
    df.insert(0, "quantity", name)
    df["n"] = n.reindex(series.index).to_numpy(float)
    df["k"] = np.nan if k is None else k.reindex(series.index).to_numpy(float)
    df["of"] = np.nan if of is None else of.reindex(series.index).to_numpy(float)
    return df


def is_rate(quantity: str) -> bool:
    return QUANTITIES[quantity][2] == "%"


def key_numbers(seed_values: pd.DataFrame) -> pd.DataFrame:
    """Mean and 95% interval (:func:`interval`) over seeds of every key number, the samples behind it,
    the per-seed values and the paper's stated value."""
    out = []
    for (q, agent, cond), grp in seed_values.groupby(["quantity", "agent", "condition"], sort=False):
        rate = is_rate(q)
        mean, lo, hi = interval(grp["value"].tolist(), grp["k"] if rate else None, grp["n"] if rate else None)
        fig, desc, unit = QUANTITIES[q]
        per = grp.sort_values("seed")
        out.append({"figure": fig, "quantity": q, "description": desc, "unit": unit, "agent": agent,
                    "condition": cond, "n_seeds": int(grp["value"].notna().sum()), "samples": int(grp["n"].sum()),
                    "samples_of": int(grp["of"].sum()) if grp["of"].notna().any() else None,
                    "mean": mean, "ci95_low": lo, "ci95_high": hi,
                    "interval": "bootstrap over seeds + Wilson (pooled count)" if rate else "bootstrap over seeds",
                    "per_seed": "; ".join(f"{int(s)}: {_fmt(v)}" for s, v in zip(per["seed"], per["value"])),
                    "paper": paper_value(q, agent, cond)})
    df = pd.DataFrame(out)
    order = {q: i for i, q in enumerate(QUANTITIES)}
    df["_o"] = df["quantity"].map(order) * 1000 + df["condition"].map(_rank(_condition_order(df["condition"]))) * 10 \
        + df["agent"].map(_rank(kinds.names()))
    return df.sort_values("_o").drop(columns="_o").reset_index(drop=True)


def differences(seed_values: pd.DataFrame) -> pd.DataFrame:
    """Intervals of the key differences, per condition: each arbitrating kind (APAC) - each planning-only
    kind (SPAC) training and test success, and each arbitrating kind's habit share in each condition
    minus its share on the static target (percentage points)."""
    def rows(q: str, agent: str, cond: str) -> pd.DataFrame:
        sel = seed_values[(seed_values["quantity"] == q) & (seed_values["agent"] == agent)
                          & (seed_values["condition"] == cond)]
        return sel.set_index("seed")

    conds = _condition_order(seed_values["condition"])
    present = [a for a in kinds.names() if a in set(seed_values["agent"])]
    arbitrating = [a for a in present if kinds.get(a).arbitrates]
    planning = [a for a in present if not kinds.get(a).uses_habit]
    pairs = [(q, (a, c), (b, c)) for q in ("train_success_late", "test_success") for c in conds
             for a in arbitrating for b in planning]
    pairs += [("habit_fraction_late", (a, c), (a, "static_target")) for c in conds if c != "static_target"
              for a in arbitrating]
    out = []
    for q, (a1, c1), (a2, c2) in pairs:
        ra, rb = rows(q, a1, c1), rows(q, a2, c2)
        if ra.empty or rb.empty:
            continue
        diff, lo, hi, paired = paired_difference(ra["value"], rb["value"])
        if is_rate(q):  # widened to contain the pooled counts' Newcombe interval, as rates are in key_numbers
            nlo, nhi = newcombe_interval(ra["k"].sum(), ra["n"].sum(), rb["k"].sum(), rb["n"].sum())
            lo, hi = (100 * nlo, 100 * nhi) if math.isnan(lo) else (min(lo, 100 * nlo), max(hi, 100 * nhi))
        out.append({"quantity": q, "description": QUANTITIES[q][1],
                    "comparison": f"{AGENT_LABEL[a1]} {_cond_short(c1)} - {AGENT_LABEL[a2]} {_cond_short(c2)}",
                    "unit": "points" if is_rate(q) else QUANTITIES[q][2], "n_seeds": int(min(ra["value"].notna().sum(), rb["value"].notna().sum())),
                    "difference": diff, "ci95_low": lo, "ci95_high": hi,
                    "interval": ("paired bootstrap over seeds" if paired else "bootstrap over seeds (unpaired)")
                    + (" + Newcombe (pooled counts)" if is_rate(q) else "")})
    return pd.DataFrame(out, columns=["quantity", "description", "comparison", "unit", "n_seeds", "difference",
                                      "ci95_low", "ci95_high", "interval"])


def _rank(order: Sequence[str]) -> dict[str, int]:
    return {k: i for i, k in enumerate(order)}


# -- figures -------------------------------------------------------------------------

def _agents(df: pd.DataFrame) -> list[str]:
    """The registered kinds present in ``df``, in registry order; an unregistered one is an error."""
    check_kinds(df)
    return [a for a in kinds.names() if a in set(df["agent"])]


def _arbitrating(df: pd.DataFrame) -> list[str]:
    """The kinds in ``df`` whose arbitrator chooses between habit and planning (APAC)."""
    return [a for a in _agents(df) if kinds.get(a).arbitrates]


def check_kinds(df: pd.DataFrame) -> None:
    """Every agent kind in the results is registered (else it would vanish from the figures)."""
    unknown = sorted(set(df["agent"]) - set(kinds.names()))
    if unknown:
        raise kinds.UnknownKindError(
            f"the results hold agent kind(s) {unknown} that are not registered (registered: "
            f"{', '.join(kinds.names())}); register them with apac_mj.kinds.register before reporting")


def _conditions(df: pd.DataFrame) -> list[str]:
    return _condition_order(df["condition"])


def _condition_order(conditions: Iterable[str]) -> list[str]:
    """The conditions present: the paper's in its order, then any other (a user's task) by name."""
    present = set(conditions)
    return [c for c in CONDITIONS if c in present] + sorted(present - set(CONDITIONS))


def _seed_curves(frame: pd.DataFrame, column: str, window: int) -> pd.DataFrame:
    """Per-seed moving average of ``column`` over episodes: index episode, one column per seed."""
    wide = frame.pivot_table(index="episode", columns="seed", values=column, aggfunc="mean").sort_index()
    return wide.astype(float).rolling(window, min_periods=1).mean()


def _smooth_band(frame: pd.DataFrame, column: str, window: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-seed moving average of ``column``, then the mean over seeds and a 95% percentile-bootstrap
    band over seeds (inside the range of the seeds' values; NaN with one seed)."""
    wide = _seed_curves(frame, column, window)
    values = wide.to_numpy()
    mean = np.nanmean(values, axis=1)
    if values.shape[1] < 2:
        return wide.index.to_numpy(), mean, np.full_like(mean, np.nan), np.full_like(mean, np.nan)
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    boot = np.stack([np.nanmean(values[:, rng.integers(0, values.shape[1], values.shape[1])], axis=1)
                     for _ in range(200)])
    lo, hi = np.nanquantile(boot, [0.5 - LEVEL / 2, 0.5 + LEVEL / 2], axis=0)
    return wide.index.to_numpy(), mean, lo, hi


def _window(metrics: pd.DataFrame) -> int:
    return max(1, int(metrics["episode"].max() + 1) // 25)


def _episodes(n: int) -> str:
    return f"{n} episode" + ("" if n == 1 else "s")


def _line(ax: plt.Axes, frame: pd.DataFrame, column: str, window: int, label: str, color: str,
          scale: float = 1.0, ls: str = "-") -> None:
    """Mean over seeds (bold) with each seed as a thin line (up to LIST_SEEDS seeds), else a bootstrap band."""
    x, m, lo, hi = _smooth_band(frame, column, window)
    ax.plot(x, scale * m, color=color, label=label, lw=1.6, ls=ls)
    wide = _seed_curves(frame, column, window)
    if wide.shape[1] <= LIST_SEEDS:
        for seed in wide.columns:
            ax.plot(wide.index, scale * wide[seed], color=color, lw=0.6, alpha=0.35, ls=ls)
    else:
        ax.fill_between(x, scale * lo, scale * hi, color=color, alpha=0.2, lw=0)


def _band_words(metrics: pd.DataFrame) -> str:
    """What the thin lines or the band around a curve are."""
    return ("thin lines: single seeds" if metrics["seed"].nunique() <= LIST_SEEDS
            else "band: 95% bootstrap interval over seeds")


def _save(fig: plt.Figure, path: Path, title: str) -> Path:
    """Suptitle wrapped to the figure's width (nothing cut off), constrained layout, 110 dpi."""
    width_in = fig.get_size_inches()[0]
    fig.suptitle(textwrap.fill(title, width=max(40, int(width_in * 11))), fontsize=11)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _axes(nrows: int, ncols: int, w: float = 4.2, h: float = 3.4) -> np.ndarray:
    fig, axes = plt.subplots(nrows, ncols, figsize=(w * ncols, h * nrows), squeeze=False, layout="constrained")
    return axes


def fig_training_success(metrics: pd.DataFrame, path: Path) -> Path:
    """Fig. 3: success rate during training per episode; top: per agent, bottom: per condition."""
    train = metrics[(metrics["phase"] == "train") & (metrics["region"] == "all")]
    agents, conds, w = _agents(train), _conditions(train), _window(train)
    ncols = max(len(agents), len(conds))
    axes = _axes(2, ncols)
    for i, agent in enumerate(agents):
        ax = axes[0, i]
        for cond in conds:
            sel = train[(train["agent"] == agent) & (train["condition"] == cond)]
            if len(sel):
                _line(ax, sel, "success", w, _cond_short(cond) + ": " + _cond_label(cond), _cond_color(cond), 100)
        _style(ax, f"{AGENT_LABEL[agent]} (colour: condition)", "training episode", "success rate (%)",
               ylim=(-2, 102))
    for j, cond in enumerate(conds):
        ax = axes[1, j]
        for agent in agents:
            sel = train[(train["agent"] == agent) & (train["condition"] == cond)]
            if len(sel):
                _line(ax, sel, "success", w, AGENT_LABEL[agent], AGENT_COLOR[agent], 100)
        _style(ax, f"{_cond_label(cond)} (colour: agent)", "training episode", "success rate (%)", ylim=(-2, 102))
    _hide_unused(axes, [len(agents), len(conds)])
    return _save(axes[0, 0].figure, path, f"Fig. 3: training success (moving average over {_episodes(w)}; "
                                          f"bold: mean over seeds, {_band_words(train)})")


LOSSES = (("critic_loss", "critic: TD loss"), ("actor_loss", "actor: -Q(s, pi(s)) (+ penalty)"),
          ("forward_loss", "forward model: MSE (cm^2)"), ("inverse_loss", "inverse model: MSE (deg^2)"))


def fig_losses(metrics: pd.DataFrame, path: Path) -> Path:
    """Training losses per episode (mean of the episode's updates): rows conditions, columns networks."""
    train = metrics[(metrics["phase"] == "train") & (metrics["region"] == "all")]
    agents, conds, w = _agents(train), _conditions(train), _window(train)
    axes = _axes(len(conds), len(LOSSES), h=2.9)
    for r, cond in enumerate(conds):
        for c, (column, label) in enumerate(LOSSES):
            ax = axes[r, c]
            for agent in agents:
                sel = train[(train["agent"] == agent) & (train["condition"] == cond)]
                if len(sel) and sel[column].notna().any():
                    x, m, _, _ = _smooth_band(sel, column, w)
                    ax.plot(x, m, color=AGENT_COLOR[agent], label=AGENT_LABEL[agent], lw=1.2)
            if column != "actor_loss":
                ax.set_yscale("log")
            _style(ax, f"{_cond_label(cond)}\n{label}", "training episode", "loss (mean over seeds)")
    return _save(axes[0, 0].figure, path, f"Training losses per episode (mean of the episode's updates; "
                                          f"moving average over {_episodes(w)}, mean over seeds)")


def _style(ax: plt.Axes, title: str, xlabel: str, ylabel: str, ylim: tuple[float, float] | None = None) -> None:
    """Title (wrapped to the panel's width), labels, grid and legend of one panel."""
    width_in = ax.get_position().width * ax.figure.get_size_inches()[0]
    width = max(20, int(width_in * 12))
    ax.set_title("\n".join(textwrap.fill(line, width=width) for line in title.split("\n")), fontsize=10)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if ylim:
        ax.set_ylim(*ylim)
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7)


def _hide_unused(axes: np.ndarray, used_per_row: Sequence[int]) -> None:
    for r, used in enumerate(used_per_row):
        for ax in axes[r, used:]:
            ax.set_visible(False)


def _bars(ax: plt.Axes, table: pd.DataFrame, seed_values: pd.DataFrame, quantity: str, conds: list[str],
          agents: list[str]) -> None:
    """Grouped bars (x: condition, one bar per agent): the table's mean and 95% interval, unclipped (the
    intervals respect the quantity's range), with each seed's value as a dot."""
    width = 0.8 / max(len(agents), 1)
    sel = table[table["quantity"] == quantity]
    seeds = seed_values[seed_values["quantity"] == quantity]
    for k, agent in enumerate(agents):
        rows = [sel[(sel["agent"] == agent) & (sel["condition"] == c)] for c in conds]
        mean = np.array([r["mean"].iloc[0] if len(r) else np.nan for r in rows])
        lo = np.array([r["ci95_low"].iloc[0] if len(r) else np.nan for r in rows])
        hi = np.array([r["ci95_high"].iloc[0] if len(r) else np.nan for r in rows])
        err = np.nan_to_num(np.vstack([mean - lo, hi - mean]))
        x = np.arange(len(conds)) + (k - (len(agents) - 1) / 2) * width
        ax.bar(x, mean, width, yerr=err, capsize=3, color=AGENT_COLOR[agent], label=AGENT_LABEL[agent], alpha=0.85)
        for xi, r in zip(x, rows):  # the count behind a mean over some of the samples (e.g. reached targets)
            if len(r) and pd.notna(r["samples_of"].iloc[0]):
                ax.annotate(f"{int(r['samples'].iloc[0])}/{int(r['samples_of'].iloc[0])}", (xi, 0), ha="center",
                            va="bottom", fontsize=7, rotation=90, xytext=(0, 2), textcoords="offset points")
        for xi, cond in zip(x, conds):
            v = seeds[(seeds["agent"] == agent) & (seeds["condition"] == cond)]["value"].dropna().to_numpy()
            jitter = np.linspace(-width / 4, width / 4, len(v)) if len(v) > 1 else np.zeros(len(v))
            ax.scatter(xi + jitter, v, s=9, color="black", zorder=3, label="single seeds" if k == 0 and
                       cond == conds[0] and len(v) else None)
    ax.set_xticks(np.arange(len(conds)), [_cond_short(c) for c in conds])


def fig_test(table: pd.DataFrame, seed_values: pd.DataFrame, path: Path) -> Path:
    """Fig. 4: test success rate and mean steps to reach, per agent and condition."""
    sel = table[table["quantity"] == "test_success"]
    agents, conds = _agents(sel), _conditions(sel)
    axes = _axes(1, 2, w=5.5)
    _bars(axes[0, 0], table, seed_values, "test_success", conds, agents)
    _style(axes[0, 0], "test success rate", "condition (target/kinematics: s = static, c = changing)",
           "success rate (%)", ylim=(0, 105))
    _bars(axes[0, 1], table, seed_values, "test_steps_to_reach", conds, agents)
    _style(axes[0, 1], "mean steps to reach (reached targets only; at the foot: reached/tested)",
           "condition (target/kinematics: s = static, c = changing)", "action steps")
    return _save(axes[0, 0].figure, path, "Fig. 4: frozen-network tests (bars: mean over seeds with the 95% "
                                          "interval of report.md; dots: single seeds)")


def fig_arbitration(metrics: pd.DataFrame, path: Path) -> Path:
    """Fig. 5: habitual vs planning actions per episode, per condition (one row per arbitrating kind: APAC)."""
    main = metrics[(metrics["phase"] == "train") & (metrics["region"] == "all")]
    arbitrating = _arbitrating(main)
    sel_all = main[main["agent"].isin(arbitrating)]
    conds, w = _conditions(sel_all), _window(sel_all)
    axes = _axes(max(len(arbitrating), 1), max(len(conds), 1))
    for i, agent in enumerate(arbitrating):
        for j, cond in enumerate(conds):
            sel = sel_all[(sel_all["agent"] == agent) & (sel_all["condition"] == cond)]
            _line(axes[i, j], sel, "habit_actions", w, "habitual (actor)", "tab:blue")
            _line(axes[i, j], sel, "planning_actions", w, "planning (inverse model)", "tab:red")
            title = _cond_label(cond) if len(arbitrating) == 1 else f"{AGENT_LABEL[agent]}, {_cond_label(cond)}"
            _style(axes[i, j], title, "training episode", "actions per episode")
    if not conds:
        axes[0, 0].text(0.5, 0.5, "no arbitrating agent in these results", ha="center",
                        transform=axes[0, 0].transAxes)
        _style(axes[0, 0], "arbitration", "training episode", "actions per episode")
    names = ", ".join(AGENT_LABEL[a] for a in arbitrating) or "APAC"
    return _save(axes[0, 0].figure, path, f"Fig. 5: {names} arbitration (moving average over {_episodes(w)}; "
                                          f"bold: mean over seeds, {_band_words(sel_all)})")


def fig_steps_time(metrics: pd.DataFrame, path: Path) -> Path:
    """Fig. 6: action steps per episode (top) and time with planning = 3 x habit (bottom)."""
    train = metrics[(metrics["phase"] == "train") & (metrics["region"] == "all")].copy()
    train["time"] = train["habit_actions"] + PLANNING_COST * train["planning_actions"]
    agents, conds, w = _agents(train), _conditions(train), _window(train)
    axes = _axes(2, len(conds))
    for j, cond in enumerate(conds):
        for agent in agents:
            sel = train[(train["agent"] == agent) & (train["condition"] == cond)]
            if len(sel):
                _line(axes[0, j], sel, "steps", w, AGENT_LABEL[agent], AGENT_COLOR[agent])
                _line(axes[1, j], sel, "time", w, AGENT_LABEL[agent], AGENT_COLOR[agent])
        _style(axes[0, j], _cond_label(cond), "training episode", "action steps per episode")
        _style(axes[1, j], _cond_label(cond), "training episode",
               f"time per episode (habit steps; planning = {PLANNING_COST}x)")
    return _save(axes[0, 0].figure, path, f"Fig. 6: steps and time per episode (moving average over "
                                          f"{_episodes(w)}; bold: mean over seeds, {_band_words(train)})")


def fig_trajectories(tests: pd.DataFrame, path: Path) -> Path:
    """Fig. 7: end-effector paths to the test targets under changing-target conditions."""
    grid = tests[(tests["protocol"] == "grid") & tests["condition"].str.startswith("changing_target")]
    agents, conds = _agents(grid), _conditions(grid)
    axes = _axes(max(len(conds), 1), max(len(agents), 1), w=3.8, h=3.8)
    for i, cond in enumerate(conds):
        for k, agent in enumerate(agents):
            ax = axes[i, k]
            sel = grid[(grid["agent"] == agent) & (grid["condition"] == cond)]
            for j, (px, py) in enumerate(zip(sel["path_x"], sel["path_y"])):
                ax.plot(px, py, color="tab:blue", lw=0.4, alpha=0.35, label="end-effector path" if j == 0 else None)
            ax.scatter(sel["target_x"], sel["target_y"], s=6, color="red", zorder=3, label="test target")
            ax.set_aspect("equal")
            ax.set_xlim(0, 30)
            ax.set_ylim(0, 30)
            _style(ax, f"{AGENT_LABEL[agent]}, {_cond_short(cond)} ({sel['success'].mean():.0%} reached)",
                   "x (cm)", "y (cm)")
    if not conds:
        axes[0, 0].text(0.5, 0.5, "no changing-target test results", ha="center", transform=axes[0, 0].transAxes)
        _style(axes[0, 0], "trajectories", "x (cm)", "y (cm)")
    return _save(axes[0, 0].figure, path, "Fig. 7: reaching the test targets under changing targets (all seeds)")


def fig_generalization(table: pd.DataFrame, seed_values: pd.DataFrame, path: Path) -> Path:
    """Fig. 8: the train/test region map and the generalization success per agent and condition."""
    from apac_mj.kinematics import motion_function
    from apac_mj.suite.task_spec import load_task

    spec = load_task("changing_target")
    fig, (ax_map, ax_bar) = plt.subplots(1, 2, figsize=(11, 4.4), gridspec_kw={"width_ratios": [1, 1.4]},
                                         layout="constrained")
    a, b = np.meshgrid(np.linspace(0, 180, 181), np.linspace(0, 180, 181), indexing="ij")
    end, _ = motion_function(a, b, *spec.link_lengths, origin=spec.origin)
    end = end.reshape(-1, 2)
    test = spec.region.contains_test(end)
    ax_map.scatter(*end[~test].T, s=0.3, color="tab:red", label="train region")
    ax_map.scatter(*end[test].T, s=0.3, color="tab:blue", label=f"test region (y >= {spec.region.test_y_min} cm)")
    ax_map.set_aspect("equal")
    ax_map.set_xlim(0, 30)
    ax_map.set_ylim(0, 30)
    _style(ax_map, f"reachable area, l = {spec.link_lengths} cm", "x (cm)", "y (cm)")
    sel = table[table["quantity"] == "generalization_success"]
    _bars(ax_bar, table, seed_values, "generalization_success", _conditions(sel), _agents(sel))
    _style(ax_bar, "success on held-out-region targets", "training condition (s = static, c = changing)",
           "success rate (%)", ylim=(0, 105))
    return _save(fig, path, "Fig. 8: generalization to the held-out region (bars: mean over seeds with the 95% "
                            "interval of report.md; dots: single seeds)")


def fig_occluded(tests: pd.DataFrame, table: pd.DataFrame, path: Path) -> Path:
    """Fig. 9: occluded vision, actual final distance per test target: mean over seeds, min-max band; the
    judged-reached episodes' share and mean distance are the table's (means over seeds)."""
    from apac_mj.suite.task_spec import load_task

    occ = tests[tests["protocol"] == "occluded"]
    agents, conds = _agents(occ), _conditions(occ)
    axes = _axes(max(len(agents), 1), max(len(conds), 1))
    for i, agent in enumerate(agents):
        for j, cond in enumerate(conds):
            ax = axes[i, j]
            sel = occ[(occ["agent"] == agent) & (occ["condition"] == cond)]
            by = sel.groupby("target_index")["final_distance"]
            x = by.mean().index.to_numpy()
            ax.fill_between(x, by.min().to_numpy(), by.max().to_numpy(), color="tab:blue", alpha=0.35,
                            label="min-max over seeds")
            ax.plot(x, by.mean().to_numpy(), color="black", lw=1, label="mean over seeds")
            judged = sel[judged_reached(sel).to_numpy()]
            if len(judged):  # the episodes the paper's blue band describes
                share = _table_mean(table, "occluded_judged_rate", agent, cond)
                dist = _table_mean(table, "occluded_distance_judged", agent, cond)
                ax.scatter(judged["target_index"], judged["final_distance"], s=6, color="tab:green", zorder=3,
                           label=f"judged reached ({share:.0f}%)")
                ax.axhline(dist, color="tab:green", ls="--", lw=1.2,
                           label=f"their distance: {dist:.2f} cm")
            ax.axhline(load_task(cond).zone_radius, color="red", lw=1.2, label="target-zone radius")
            _style(ax, f"{AGENT_LABEL[agent]}, {_cond_label(cond)}", "test target index", "final distance (cm)")
            top = float(np.nanmax([sel["final_distance"].max(), load_task(cond).zone_radius]))
            ax.set_ylim(0, 1.9 * top)  # room above the data for the legend
            ax.legend(fontsize=6.5, loc="upper left", framealpha=0.9)
    if not agents:
        axes[0, 0].text(0.5, 0.5, "no occluded-vision results", ha="center", transform=axes[0, 0].transAxes)
        _style(axes[0, 0], "occluded vision", "test target index", "final distance (cm)")
    return _save(axes[0, 0].figure, path, "Fig. 9: occluded vision, actual final distance to the target (green: "
                                          "episodes ended because the forward model judged the target reached; their "
                                          "share and distance are means over seeds, as in report.md)")


#: The scoreboard's panels: (quantity, title, y label, y limits or None).
SCOREBOARD = (
    ("train_success_late", "training success, last 20%", "success rate (%)", (0, 105)),
    ("test_success", "test success (angle grid)", "success rate (%)", (0, 105)),
    ("test_habit_fraction", "habitual share of test actions", "habit share (%)", (0, 105)),
    ("test_time", "test time per episode (planning = 3 x habit)", "habit-step units", None),
    ("occluded_distance_judged", "in the dark: final distance when judged reached", "cm", None),
    ("test_estimate_error", "state-estimate error on the test grid", "cm", None),
)


def fig_scoreboard(table: pd.DataFrame, seed_values: pd.DataFrame, path: Path) -> Path:
    """Fig. 11: every agent x condition on the quantities that weigh arbitrators and integrators."""
    panels = [p for p in SCOREBOARD if (table["quantity"] == p[0]).any()]
    sel = table[table["quantity"].isin([p[0] for p in panels])]
    agents, conds = _agents(sel), _conditions(sel)
    ncols = 2
    axes = _axes((len(panels) + ncols - 1) // ncols, ncols, w=min(9.0, max(4.2, 0.3 * len(agents) * len(conds) + 1.5)))
    for ax, (q, title, ylabel, ylim) in zip(axes.flat, panels):
        _bars(ax, table, seed_values, q, conds, agents)
        _style(ax, title, "condition", ylabel, ylim=ylim)
    for ax in list(axes.flat)[len(panels):]:
        ax.set_visible(False)
    for ax in list(axes.flat)[1:len(panels)]:
        if ax.get_legend():
            ax.get_legend().remove()
    return _save(axes[0, 0].figure, path, "Fig. 11: scoreboard (bars: mean over seeds with the 95% interval of "
                                          "report.md; dots: single seeds)")


def _table_mean(table: pd.DataFrame, quantity: str, agent: str, cond: str) -> float:
    sel = table[(table["quantity"] == quantity) & (table["agent"] == agent) & (table["condition"] == cond)]
    return float(sel["mean"].iloc[0]) if len(sel) else math.nan


# -- the report ----------------------------------------------------------------------

@dataclasses.dataclass
class Figure:
    """One figure of this report: its file, its caption and how to draw it."""

    file: str
    caption: str
    make: Callable[[], Path]
    #: False: these results hold nothing to draw; the figure is skipped and report.md says so.
    has_data: bool = True


@dataclasses.dataclass(frozen=True)
class ReportData:
    """What a figure is drawn from: the results directory and its tables (:func:`write_report` builds it)."""

    results: Path
    #: Every cell's metrics.parquet (apac_mj.experiments.results.load_results).
    metrics: pd.DataFrame
    #: Every cell's eval/<protocol>.parquet (apac_mj.experiments.results.load_tests).
    tests: pd.DataFrame
    #: One row per (quantity, agent, condition, seed) (:func:`per_seed`).
    seed_values: pd.DataFrame
    #: The key-number table (:func:`key_numbers`).
    table: pd.DataFrame


@dataclasses.dataclass(frozen=True)
class FigureSpec:
    """A figure added from user code (:func:`register_figure`): drawn after the paper's, listed in report.md."""

    #: File name in the report directory (e.g. "fig11_my_figure.png").
    file: str
    caption: str
    #: ``draw(data, path)`` writes the figure to ``path``.
    draw: Callable[[ReportData, Path], object]
    #: ``applies(data)``: these results hold something to draw (else the figure is skipped, and said so).
    applies: Callable[[ReportData], bool] = lambda data: True


_FIGURES: dict[str, FigureSpec] = {}


def register_figure(spec: FigureSpec, replace: bool = False) -> FigureSpec:
    """Add a figure to every report written from now on (in this process)."""
    if spec.file in _FIGURES and not replace:
        raise ValueError(f"a figure {spec.file!r} is already registered (pass replace=True to redefine it)")
    if not spec.file.endswith((".png", ".svg", ".pdf")):
        raise ValueError(f"figure file must end in .png, .svg or .pdf, got {spec.file!r}")
    _FIGURES[spec.file] = spec
    return spec


def unregister_figure(file: str) -> None:
    """Remove a figure added by :func:`register_figure`."""
    if file not in _FIGURES:
        raise KeyError(f"no figure {file!r} is registered; registered: {', '.join(_FIGURES) or 'none'}")
    del _FIGURES[file]


def write_report(results: str | Path, out: str | Path | None = None, title: str | None = None,
                 draw: bool = True) -> Path:
    """Write every figure that has data (``draw=False``: none, the tables only), key_numbers.csv,
    differences.csv and report.md; returns the directory."""
    results = Path(results)
    metrics, tests = load_results(results), load_tests(results)
    check_kinds(metrics)  # before anything is written
    out = Path(out) if out else results / "report"
    out.mkdir(parents=True, exist_ok=True)
    seed_values = per_seed(metrics, tests)
    table, diffs = key_numbers(seed_values), differences(seed_values)
    table.to_csv(out / "key_numbers.csv", index=False)
    diffs.to_csv(out / "differences.csv", index=False)
    protocols = set(tests["protocol"]) if "protocol" in tests else set()
    figures = [
        Figure("fig3_training_success.png", "Training success rate per episode (paper Fig. 3).",
               lambda: fig_training_success(metrics, out / "fig3_training_success.png")),
        Figure("fig4_test.png", "Test success rate and steps to reach (paper Fig. 4).",
               lambda: fig_test(table, seed_values, out / "fig4_test.png"), "grid" in protocols),
        Figure("fig5_arbitration.png", "APAC habitual vs planning actions per episode (paper Fig. 5).",
               lambda: fig_arbitration(metrics, out / "fig5_arbitration.png"), bool(_arbitrating(metrics))),
        Figure("fig6_steps_time.png", "Action steps and time per episode, planning = 3x habit (paper Fig. 6).",
               lambda: fig_steps_time(metrics, out / "fig6_steps_time.png")),
        Figure("fig7_trajectories.png", "Reaching trajectories to the test targets (paper Fig. 7).",
               lambda: fig_trajectories(tests, out / "fig7_trajectories.png"), "grid" in protocols),
        Figure("fig8_generalization.png", "Held-out region and generalization success (paper Fig. 8).",
               lambda: fig_generalization(table, seed_values, out / "fig8_generalization.png"),
               "generalization" in protocols),
        Figure("fig9_occluded.png", "Occluded vision: final distance to the target (paper Fig. 9).",
               lambda: fig_occluded(tests, table, out / "fig9_occluded.png"), "occluded" in protocols),
    ]
    figures.append(Figure("fig11_scoreboard.png", "Scoreboard: success, habit share, time, distance in the dark, "
                          "state-estimate error (not in the paper).",
                          lambda: fig_scoreboard(table, seed_values, out / "fig11_scoreboard.png"),
                          "grid" in protocols))
    if all(c in metrics and metrics[c].notna().any() for c, _ in LOSSES):  # older results lack the columns
        figures.append(Figure("fig10_losses.png", "Training losses per episode (not in the paper).",
                              lambda: fig_losses(metrics, out / "fig10_losses.png")))
    data = ReportData(results, metrics, tests, seed_values, table)
    figures += [Figure(f.file, f.caption, lambda f=f: f.draw(data, out / f.file), bool(f.applies(data)))
                for f in _FIGURES.values()]
    for f in figures:
        (out / f.file).unlink(missing_ok=True)  # a figure without data this time must not linger
        if f.has_data and draw:
            f.make()
    manifest = read_json(results / MANIFEST) or {}
    (out / "report.md").write_text(_markdown(title, manifest, metrics, table, diffs, figures))
    return out


def _markdown(title: str | None, manifest: dict, metrics: pd.DataFrame, table: pd.DataFrame, diffs: pd.DataFrame,
              figures: list[Figure]) -> str:
    preset = manifest.get("preset", {})
    seeds = sorted(set(metrics["seed"]))
    episodes = int(metrics.loc[metrics["phase"] == "train", "episode"].max()) + 1
    lines = [f"# {title or 'APAC results: ' + str(preset.get('name', 'grid'))}", ""]
    if preset.get("description"):
        lines += [preset["description"], ""]
    lines += [f"Agents: {', '.join(AGENT_LABEL[a] for a in _agents(metrics))}. "
              f"Conditions: {'; '.join(_cond_short(c) + ' = ' + _cond_label(c) for c in _conditions(metrics))}. "
              f"{len(seeds)} seeds, {_episodes(episodes)} of training per seed.", "",
              "Every number is computed per seed, then averaged over seeds. **Intervals** (95%, the same in the "
              f"figures): a percentile bootstrap over seeds ({BOOTSTRAP_RESAMPLES} resamples), which stays inside "
              "the quantity's range; for rates (%) widened to contain the Wilson score interval of the count "
              "pooled over seeds, so a rate every seed hits still shows its sampling uncertainty. With one seed "
              "only rates get an interval. **samples**: the episodes, targets or actions behind a mean (`k of n` "
              f"where only some count, e.g. steps of the reached targets); fewer than {FEW_SAMPLES} are marked "
              "with `*`. 'paper' quotes what Fard & Trappenberg state in their Results section.", ""]
    lines += ["## Figures", ""]
    for f in figures:
        if f.has_data:
            lines += [f"![{f.caption}]({f.file})", "", f"*{f.caption}*", ""]
        else:
            lines += [f"*{f.caption.split(' (')[0]}: not drawn, these results have no data for it.*", ""]
    show_seeds = len(seeds) <= LIST_SEEDS
    head = "| figure | quantity | agent | condition | seeds | samples | mean | 95% CI |"
    head += " per seed |" if show_seeds else ""
    lines += ["## Key numbers", "", head + " paper |", "|---" * (head.count("|")) + "|"]
    for r in table.itertuples():
        ci = "-" if math.isnan(r.ci95_low) else f"[{_fmt(r.ci95_low)}, {_fmt(r.ci95_high)}]"
        samples = _samples(r.samples, r.samples_of)
        row = (f"| {r.figure} | {r.description} ({r.unit}) | {AGENT_LABEL[r.agent]} | {_cond_short(r.condition)} "
               f"| {r.n_seeds} | {samples} | {_fmt(r.mean)} | {ci} |")
        row += f" {r.per_seed} |" if show_seeds else ""
        lines.append(row + f" {r.paper or '-'} |")
    lines += ["", "## Key differences", ""]
    if diffs.empty:
        lines += ["*No pair of cells to compare in these results.*"]
    else:
        lines += ["Per-seed values subtracted, seeds paired where both sides have the same seeds; 95% percentile "
                  "bootstrap interval over seeds, for rates widened to contain Newcombe's score interval of the "
                  "pooled counts. An interval that excludes 0 is a difference these seeds resolve.",
                  "", "| quantity | comparison | seeds | difference | 95% CI |", "|---|---|---|---|---|"]
        for r in diffs.itertuples():
            ci = "-" if math.isnan(r.ci95_low) else f"[{_fmt(r.ci95_low)}, {_fmt(r.ci95_high)}]"
            lines.append(f"| {r.description} ({r.unit}) | {r.comparison} | {r.n_seeds} | {_fmt(r.difference)} "
                         f"| {ci} |")
    return "\n".join(lines) + "\n"


def _samples(n: float, of: float | None) -> str:
    mark = "*" if n < FEW_SAMPLES else ""
    if of is None or (isinstance(of, float) and math.isnan(of)):
        return f"{int(n)}{mark}"
    return f"{int(n)}{mark} of {int(of)}"


def _fmt(x: float) -> str:
    return "nan" if math.isnan(x) else f"{x:.2f}"


def load_key_numbers(report_dir: str | Path) -> pd.DataFrame:
    return pd.read_csv(Path(report_dir) / "key_numbers.csv")


__all__ = ["write_report", "key_numbers", "differences", "per_seed", "interval", "wilson_interval",
           "bootstrap_interval", "newcombe_interval", "paired_difference", "t_interval", "load_key_numbers"]
