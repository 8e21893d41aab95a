"""The key numbers: what is computed from the results, per seed first, then summarized over seeds.

:func:`per_seed` computes every quantity of :data:`QUANTITIES` per (agent, condition, seed) with the
samples behind it; :func:`key_numbers` summarizes them over seeds (mean and 95% interval,
:func:`apac_mj.report.stats.interval`) beside what the paper states (:data:`PAPER`); :func:`differences`
gives intervals of the key comparisons (APAC vs SPAC success, APAC's habit share across conditions).
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pandas as pd

from apac_mj import kinds
from apac_mj.report.labels import AGENT_LABEL, arbitrating, condition_order, condition_short, condition_spec
from apac_mj.report.stats import METHOD, RATE_METHOD, interval, newcombe_interval, paired_difference
from apac_mj.run.run_dir import TIMING_COLUMNS
from apac_mj.types import HABIT_COST, PLANNING_COST

#: Summary windows: the last LATE_FRACTION of training episodes.
LATE_FRACTION = 0.2

#: The paper's habit threshold (Fig. 5: "more than 80% of the actions are habitual after around 300 episodes").
HABIT_THRESHOLD = 0.8
#: Training episodes in the trailing window a seed's habit share is judged on for the first crossing.
CROSSING_WINDOW = 20


# What the paper states ("Results"), keyed by (quantity, agent, condition); "*" matches any.
PAPER = {
    ("train_success_late", "spac", "*"): "near perfect after ~ep. 100",
    ("train_success_late", "ddpg", "static_target"): "~100%",
    ("train_success_late", "ddpg", "changing_target"): "~20 points below static target",
    ("train_success_late", "ddpg", "changing_target_changing_kinematics"): "~20 points below static target",
    ("train_success_late", "apac", "*"): "almost all, as good as SPAC",
    ("test_success", "*", "static_target"): "100%",
    ("habit_fraction_late", "apac", "*"): ">80% after ~300 episodes",
    ("habit_crossing_episode", "apac", "*"): "around 300",
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
    ("measured_planning_ratio", "*", "*"): f"{PLANNING_COST} (assumed, Fig. 6)",
}
#: Every key number: quantity -> (the paper's figure, description, unit); "%" marks a rate.
QUANTITIES = {
    "train_success_late": ("Fig. 3", "training success rate, last 20% of episodes", "%"),
    "test_success": ("Fig. 4", "test success rate (angle-grid targets)", "%"),
    "test_steps_to_reach": ("Fig. 4", "test steps to reach (reached targets)", "steps"),
    "habit_fraction_late": ("Fig. 5", "APAC habitual share of actions, last 20% of episodes", "%"),
    "habit_crossing_episode": ("Fig. 5", f"first training episode with >= {HABIT_THRESHOLD:.0%} habitual actions over "
                               f"the last {CROSSING_WINDOW} (seeds that crossed; samples: episodes run)", "episode"),
    "steps_late": ("Fig. 6", "action steps per episode, last 20% of episodes", "steps"),
    "time_late": ("Fig. 6", f"time per episode (planning = {PLANNING_COST} x habit), last 20%", "habit-step units"),
    "decision_ms_late": ("Fig. 6", "measured decision time per episode (habit + planning), last 20%", "ms"),
    "planning_ms_late": ("Fig. 6", "measured decision time per episode where the planner acted, last 20%", "ms"),
    "plan_iterations_late": ("Fig. 6", "planning iterations per episode, last 20%", "iterations"),
    "measured_planning_ratio": ("Fig. 6", "measured time per planning action / per habitual action, last 20% "
                                f"(seeds with both; the paper assumes {PLANNING_COST}; samples: actions)", "x"),
    "generalization_targets": ("Fig. 8", "held-out-region test targets", "targets"),
    "generalization_success": ("Fig. 8", "generalization success rate (held-out region)", "%"),
    "occluded_distance": ("Fig. 9", "occluded vision: final distance to target, all episodes", "cm"),
    "occluded_judged_rate": ("Fig. 9", "occluded vision: episodes ended by the forward model judging the target reached",
                             "%"),
    "occluded_distance_judged": ("Fig. 9", "occluded vision: final distance when the forward model judged it reached",
                                 "cm"),
    "test_habit_fraction": ("Fig. 11", "habitual share of test actions (angle grid)", "%"),
    "test_time": ("Fig. 11", f"test time per episode (planning = {PLANNING_COST} x habit; angle grid)",
                  "habit-step units"),
    "estimate_error_late": ("Fig. 11", "state-estimate error |estimate - truth| (hand, elbow, target), last 20%", "cm"),
    "test_estimate_error": ("Fig. 11", "state-estimate error on the test grid", "cm"),
}
_KEYS = ["agent", "condition", "seed"]


def paper_value(quantity: str, agent: str, condition: str) -> str:
    """What the paper states for a key number ("" where it states nothing)."""
    for key in ((quantity, agent, condition), (quantity, agent, "*"), (quantity, "*", condition), (quantity, "*", "*")):
        if key in PAPER:
            return PAPER[key]
    return ""


def is_rate(quantity: str) -> bool:
    return QUANTITIES[quantity][2] == "%"


def time_cost(habit_actions: pd.Series, planning_actions: pd.Series) -> pd.Series:
    """Time per episode in habit steps (a planning action costs PLANNING_COST, a habitual one HABIT_COST)."""
    return HABIT_COST * habit_actions + PLANNING_COST * planning_actions


def measured(metrics: pd.DataFrame) -> bool:
    """The training metrics hold the measured decision times (TIMING_COLUMNS; results from before them
    lack the columns, and an older run extended since holds NaN in its earlier rows)."""
    return all(c in metrics for c in TIMING_COLUMNS) and metrics["habit_seconds"].notna().any()


def timed(metrics: pd.DataFrame) -> pd.DataFrame:
    """The rows of ``metrics`` with measured decision times, with ``decision_ms`` (habit + planning) and
    ``planning_ms`` (where the planner acted) per episode in ms; none where the columns are missing."""
    if not measured(metrics):
        return metrics.iloc[:0].assign(decision_ms=[], planning_ms=[])
    rows = metrics.dropna(subset=list(TIMING_COLUMNS))
    return rows.assign(decision_ms=1e3 * (rows["habit_seconds"] + rows["planning_seconds"]),
                       planning_ms=1e3 * rows["planning_seconds"])


def planning_ratio(metrics: pd.DataFrame) -> tuple[pd.Series, pd.Series]:
    """The measured counterpart of the paper's PLANNING_COST per (agent, condition, seed) of the timed
    ``metrics`` rows: (sum of planning_seconds / sum of planning_actions) / (sum of habit_seconds / sum of
    habit_actions), i.e. the mean decision time of a planning action over that of a habitual one. NaN for a
    seed without both kinds of action; cells where no seed has both (kinds that never arbitrate) are left
    out. Returns (ratio, the actions behind it), indexed by agent, condition, seed."""
    sums = metrics.groupby(_KEYS)[["habit_seconds", "planning_seconds", "habit_actions", "planning_actions"]].sum()
    both = (sums["habit_actions"] > 0) & (sums["planning_actions"] > 0) & (sums["habit_seconds"] > 0)
    per_habit = sums["habit_seconds"] / sums["habit_actions"].where(both)
    ratio = (sums["planning_seconds"] / sums["planning_actions"].where(both)) / per_habit.where(both)
    cell = ratio.notna().groupby(level=["agent", "condition"]).transform("any")
    return ratio[cell], (sums["habit_actions"] + sums["planning_actions"])[cell].astype(float)


def late(metrics: pd.DataFrame) -> pd.DataFrame:
    """Training episodes in the last LATE_FRACTION of each cell's run."""
    train = metrics[metrics["phase"] == "train"]
    n = train.groupby(["agent", "condition", "region"])["episode"].transform("max") + 1
    return train[train["episode"] >= n - np.ceil(n * LATE_FRACTION)]


def habit_crossing(metrics: pd.DataFrame, threshold: float = HABIT_THRESHOLD,
                   window: int = CROSSING_WINDOW) -> pd.DataFrame:
    """When each seed of an arbitrating kind first became habitual: one row per (agent, condition, seed) of
    the main study's training with ``episode``, the first training episode at which the habitual share of
    the actions of the trailing ``window`` episodes (that episode and the ``window - 1`` before it; habit
    actions / all actions) is at least ``threshold`` (NaN: never), and ``episodes``, the run's length."""
    train = metrics[(metrics["phase"] == "train") & (metrics["region"] == "all")]
    train = train[train["agent"].isin(arbitrating(train))].sort_values([*_KEYS, "episode"])
    rows = []
    for (agent, condition, seed), d in train.groupby(_KEYS, sort=True):
        habit = d["habit_actions"].rolling(window, min_periods=window).sum()
        actions = (d["habit_actions"] + d["planning_actions"]).rolling(window, min_periods=window).sum()
        crossed = d["episode"][(habit >= threshold * actions) & (actions > 0)]
        rows.append({"agent": agent, "condition": condition, "seed": seed,
                     "episode": float(crossed.iloc[0]) if len(crossed) else math.nan,
                     "episodes": int(d["episode"].max()) + 1})
    return pd.DataFrame(rows, columns=[*_KEYS, "episode", "episodes"])


def judged_reached(occluded: pd.DataFrame) -> pd.Series:
    """Episodes that ended because the forward model's estimate was inside the zone. Results written
    before the ``judged_reached`` column: episodes that ended before their task's step limit."""
    if "judged_reached" in occluded and occluded["judged_reached"].notna().all():
        return occluded["judged_reached"].astype(bool)
    limit = occluded["condition"].map(lambda c: condition_spec(c).steps_per_episode)
    return occluded["steps"] < limit


def per_seed(metrics: pd.DataFrame, tests: pd.DataFrame) -> pd.DataFrame:
    """One row per (quantity, agent, condition, seed): every key number before averaging over seeds,
    with ``n`` (the samples behind it: episodes, targets or actions), ``k`` (a rate's successes) and
    ``of`` (for a mean over some of the samples, e.g. steps of the reached targets: of how many)."""
    rows = _training(metrics[metrics["region"] == "all"])
    if not tests.empty:
        rows += _grid_tests(distinct_episodes(tests[tests["protocol"] == "grid"]))
        rows += _generalization(tests[tests["protocol"] == "generalization"])
        rows += _occluded(distinct_episodes(tests[tests["protocol"] == "occluded"], always_seen_clean=True))
    return pd.concat([r for r in rows if not r.empty], ignore_index=True)


def distinct_episodes(tests: pd.DataFrame, always_seen_clean: bool = False) -> pd.DataFrame:
    """The test episodes that are distinct samples: a frozen network from the same start pose towards the
    same target with noise-free observations runs the same episode every time, so of a seed's repeated
    targets (a static-target task tests its one target 100 times) only the first counts. Conditions whose
    test observations are noisy or intermittent (the grid protocol keeps the task's vision) keep every
    episode; ``always_seen_clean``: the protocol's observations are noise-free whatever the task (occluded)."""
    if tests.empty:
        return tests
    def deterministic(condition: str) -> bool:
        spec = condition_spec(condition)
        return always_seen_clean or (spec.vision in ("perfect", "occluded") and spec.vision_noise_std == 0)

    keep = tests["condition"].map(deterministic).astype(bool)
    repeated = tests.duplicated(subset=[*_KEYS, "target_x", "target_y"])
    return tests[~(keep & repeated)]


def _training(main: pd.DataFrame) -> list[pd.DataFrame]:
    """The late-training quantities of the main study (Figs. 3, 5, 6 and the estimate error)."""
    lt = late(main).assign(time=lambda d: time_cost(d["habit_actions"], d["planning_actions"]))
    g = lt.groupby(_KEYS)
    rows = [_rate("train_success_late", g["success"]), _q("steps_late", g["steps"].mean(), g.size()),
            _q("time_late", g["time"].mean(), g.size())]
    arb = lt[lt["agent"].isin(arbitrating(lt))].groupby(_KEYS)
    habit, actions = arb["habit_actions"].sum(), arb["habit_actions"].sum() + arb["planning_actions"].sum()
    rows.append(_q("habit_fraction_late", 100 * habit / actions, actions, k=habit))
    crossing = habit_crossing(main).set_index(_KEYS)
    if len(crossing):
        rows.append(_q("habit_crossing_episode", crossing["episode"], crossing["episodes"]))
    if "estimate_error" in lt and lt["estimate_error"].notna().any():  # results from before it lack the column
        rows.append(_q("estimate_error_late", g["estimate_error"].mean(), g.size()))
    return rows + _decision_times(lt)


def _decision_times(lt: pd.DataFrame) -> list[pd.DataFrame]:
    """Fig. 6's measured decision times of the late training episodes (results from before them: none)."""
    rows_timed = timed(lt)
    if rows_timed.empty:
        return []
    g = rows_timed.groupby(_KEYS)
    rows = [_q("decision_ms_late", g["decision_ms"].mean(), g.size()),
            _q("planning_ms_late", g["planning_ms"].mean(), g.size()),
            _q("plan_iterations_late", g["plan_iterations"].mean().astype(float), g.size())]
    ratio, actions = planning_ratio(rows_timed)
    if len(ratio):
        rows.append(_q("measured_planning_ratio", ratio, actions))
    return rows


def _grid_tests(grid_tests: pd.DataFrame) -> list[pd.DataFrame]:
    """The angle-grid test quantities (Figs. 4 and 11)."""
    grid = grid_tests.groupby(_KEYS)
    reached = grid_tests[grid_tests["success"].astype(bool)].groupby(_KEYS)
    every = grid.size().index  # seeds that reached nothing: NaN value, 0 samples, their targets counted in "of"
    rows = [_rate("test_success", grid["success"]),
            _q("test_steps_to_reach", reached["steps"].mean().reindex(every),
               reached.size().reindex(every).fillna(0), of=grid.size()),
            _q("test_time", grid["time_cost"].mean(), grid.size())]
    arb_tests = grid_tests[grid_tests["agent"].isin(arbitrating(grid_tests))].groupby(_KEYS)
    t_habit = arb_tests["habit_actions"].sum()
    t_actions = t_habit + arb_tests["planning_actions"].sum()
    rows.append(_q("test_habit_fraction", 100 * t_habit / t_actions, t_actions, k=t_habit))
    if "estimate_error" in grid_tests and grid_tests["estimate_error"].notna().any():
        rows.append(_q("test_estimate_error", grid["estimate_error"].mean(), grid.size()))
    return rows


def _generalization(gen_tests: pd.DataFrame) -> list[pd.DataFrame]:
    """The held-out-region quantities (Fig. 8)."""
    gen = gen_tests.groupby(_KEYS)
    return [_rate("generalization_success", gen["success"]),
            _q("generalization_targets", gen["target_index"].nunique().astype(float), gen.size())]


def _occluded(occluded: pd.DataFrame) -> list[pd.DataFrame]:
    """The occluded-vision quantities (Fig. 9)."""
    occ = occluded.groupby(_KEYS)
    rows = [_q("occluded_distance", occ["final_distance"].mean(), occ.size())]
    if not occluded.empty:
        judged = occluded.assign(judged=judged_reached(occluded))
        g = judged.groupby(_KEYS)
        rows.append(_rate("occluded_judged_rate", g["judged"]))
        # NaN for a seed whose forward model never judged a target reached
        jg = judged[judged["judged"]].groupby(_KEYS)
        rows.append(_q("occluded_distance_judged", jg["final_distance"].mean().reindex(g.size().index),
                       jg.size().reindex(g.size().index).fillna(0), of=g.size()))
    return rows


def _rate(name: str, flags: "pd.core.groupby.SeriesGroupBy") -> pd.DataFrame:
    """A per-seed success rate (%) of boolean ``flags``, with its count k of n."""
    k, n = flags.sum().astype(float), flags.size().astype(float)
    return _q(name, 100 * k / n, n, k=k)


def _q(name: str, series: pd.Series, n: pd.Series, k: pd.Series | None = None,
       of: pd.Series | None = None) -> pd.DataFrame:
    """One quantity's per-seed rows: value, samples ``n``, successes ``k``, of how many ``of``."""
    df = series.rename("value").reset_index()
    df.insert(0, "quantity", name)
    df["n"] = n.reindex(series.index).to_numpy(float)
    df["k"] = np.nan if k is None else k.reindex(series.index).to_numpy(float)
    df["of"] = np.nan if of is None else of.reindex(series.index).to_numpy(float)
    return df


def key_numbers(seed_values: pd.DataFrame) -> pd.DataFrame:
    """Mean and 95% interval (:func:`~apac_mj.report.stats.interval`) over seeds of every key number, the
    samples behind it, the per-seed values and the paper's stated value."""
    out = []
    for (q, agent, cond), grp in seed_values.groupby(["quantity", "agent", "condition"], sort=False):
        rate = is_rate(q)
        mean, lo, hi = interval(grp["value"].tolist(), grp["k"] if rate else None, grp["n"] if rate else None,
                                bounds=(0.0, math.inf))  # every key number is non-negative
        fig, desc, unit = QUANTITIES[q]
        per = grp.sort_values("seed")
        out.append({"figure": fig, "quantity": q, "description": desc, "unit": unit, "agent": agent,
                    "condition": cond, "n_seeds": int(grp["value"].notna().sum()), "samples": int(grp["n"].sum()),
                    "samples_of": int(grp["of"].sum()) if grp["of"].notna().any() else None,
                    "mean": mean, "ci95_low": lo, "ci95_high": hi,
                    "interval": RATE_METHOD if rate else METHOD,
                    "per_seed": "; ".join(f"{int(s)}: {fmt(v)}" for s, v in zip(per["seed"], per["value"])),
                    "paper": paper_value(q, agent, cond)})
    df = pd.DataFrame(out)
    order = {q: i for i, q in enumerate(QUANTITIES)}
    df["_o"] = df["quantity"].map(order) * 1000 + df["condition"].map(_rank(condition_order(df["condition"]))) * 10 \
        + df["agent"].map(_rank(kinds.names()))
    return df.sort_values("_o").drop(columns="_o").reset_index(drop=True)


def differences(seed_values: pd.DataFrame) -> pd.DataFrame:
    """Intervals of the key differences, per condition, for the paper's claims: each arbitrating kind
    (APAC) - each planning-only kind (SPAC) on training and test success ("as good as SPAC") and on time
    per episode in training and on the test ("faster"); each kind that plans - each habit-only kind (DDPG)
    on test success ("DDPG lowest"); each arbitrating kind's habit share in each condition minus its
    share on the static target (percentage points)."""
    out = [_difference(seed_values, q, one, other) for q, one, other in _comparisons(seed_values)]
    return pd.DataFrame([row for row in out if row], columns=["quantity", "description", "comparison", "unit",
                                                               "n_seeds", "difference", "ci95_low", "ci95_high",
                                                               "interval"])


def _comparisons(seed_values: pd.DataFrame) -> list[tuple[str, tuple[str, str], tuple[str, str]]]:
    """The key comparisons ``(quantity, (agent, condition), (agent, condition))`` of the kinds present."""
    conds = condition_order(seed_values["condition"])
    present = [a for a in kinds.names() if a in set(seed_values["agent"])]
    arbitrating_kinds = [a for a in present if kinds.get(a).arbitrates]
    planning_kinds = [a for a in present if not kinds.get(a).uses_habit]
    habit_kinds = [a for a in present if not kinds.get(a).uses_planner]
    pairs = [(q, (a, c), (b, c)) for q in ("train_success_late", "test_success", "time_late", "test_time")
             for c in conds for a in arbitrating_kinds for b in planning_kinds]
    pairs += [("test_success", (a, c), (d, c)) for c in conds for a in planning_kinds + arbitrating_kinds
              for d in habit_kinds]
    pairs += [("habit_fraction_late", (a, c), (a, "static_target")) for c in conds if c != "static_target"
              for a in arbitrating_kinds]
    return pairs


def _difference(seed_values: pd.DataFrame, q: str, one: tuple[str, str], other: tuple[str, str]) -> dict | None:
    """One row of :func:`differences`: ``one - other`` on quantity ``q``; None if a side has no values."""
    def rows(agent: str, cond: str) -> pd.DataFrame:
        sel = seed_values[(seed_values["quantity"] == q) & (seed_values["agent"] == agent)
                          & (seed_values["condition"] == cond)]
        return sel.set_index("seed")

    (a1, c1), (a2, c2) = one, other
    ra, rb = rows(a1, c1), rows(a2, c2)
    if ra.empty or rb.empty:
        return None
    diff, lo, hi, paired = seed_difference(q, ra, rb)
    return {"quantity": q, "description": QUANTITIES[q][1],
            "comparison": f"{AGENT_LABEL[a1]} {condition_short(c1)} - {AGENT_LABEL[a2]} {condition_short(c2)}",
            "unit": "points" if is_rate(q) else QUANTITIES[q][2],
            "n_seeds": int(min(ra["value"].notna().sum(), rb["value"].notna().sum())),
            "difference": diff, "ci95_low": lo, "ci95_high": hi,
            "interval": ("paired " + METHOD if paired else "Welch t over seeds (unpaired)")
            + (" + Newcombe (pooled counts)" if is_rate(q) else "")}


def seed_difference(q: str, a: pd.DataFrame, b: pd.DataFrame) -> tuple[float, float, float, bool]:
    """``a - b`` of quantity ``q``'s per-seed rows (indexed by seed; ``value``, ``k``, ``n``): the paired
    interval over seeds (:func:`~apac_mj.report.stats.paired_difference`), for a rate widened to contain the
    pooled counts' Newcombe interval, as rates are in :func:`key_numbers`; none with too few seeds.
    Returns (difference, low, high, paired)."""
    diff, lo, hi, paired = paired_difference(a["value"], b["value"], bounds=(-100.0, 100.0) if is_rate(q) else None)
    if is_rate(q) and not math.isnan(lo):
        nlo, nhi = newcombe_interval(a["k"].sum(), a["n"].sum(), b["k"].sum(), b["n"].sum())
        lo, hi = min(lo, 100 * nlo), max(hi, 100 * nhi)
    return diff, lo, hi, paired


def _rank(order: Sequence[str]) -> dict[str, int]:
    return {k: i for i, k in enumerate(order)}


def fmt(x: float) -> str:
    """A number as the report prints it: two decimals, "nan" for none."""
    return "nan" if math.isnan(x) else f"{x:.2f}"
