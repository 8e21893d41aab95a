"""The paper's results section from a grid's results directory: Figs. 3-9 and a key-number table.

Every number is computed per seed first, then summarized over seeds as a mean
with a 95% Student-t confidence interval; ``key_numbers.csv`` holds them all
and ``report.md`` shows them beside the values the paper states.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from scipy import stats  # noqa: E402

from apac_mj.grid import CONDITIONS, MANIFEST, load_results, load_tests, read_json  # noqa: E402

AGENT_ORDER = ("ddpg", "spac", "apac")
AGENT_LABEL = {"ddpg": "DDPG", "spac": "SPAC", "apac": "APAC"}
AGENT_COLOR = {"ddpg": "tab:orange", "spac": "tab:green", "apac": "tab:blue"}
#: The paper's abbreviations (Fig. 4): target / kinematics, s = static, c = changing.
COND_SHORT = {"static_target": "ss", "static_target_changing_kinematics": "sc",
              "changing_target": "cs", "changing_target_changing_kinematics": "cc"}
COND_LABEL = {"static_target": "static target / static kin.",
              "static_target_changing_kinematics": "static target / changing kin.",
              "changing_target": "changing target / static kin.",
              "changing_target_changing_kinematics": "changing target / changing kin."}
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
}


# -- statistics ----------------------------------------------------------------------

def t_interval(values: Sequence[float], level: float = 0.95) -> tuple[float, float, float]:
    """Mean and Student-t confidence interval over seeds; NaN bounds with fewer than two values."""
    v = np.asarray([x for x in values if not math.isnan(x)], dtype=float)
    if v.size == 0:
        return math.nan, math.nan, math.nan
    mean = float(v.mean())
    if v.size < 2:
        return mean, math.nan, math.nan
    half = float(stats.t.ppf(0.5 + level / 2, v.size - 1) * v.std(ddof=1) / math.sqrt(v.size))
    return mean, mean - half, mean + half


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
    """One row per (quantity, agent, condition, seed): every key number before averaging over seeds."""
    rows: list[pd.DataFrame] = []
    main = metrics[metrics["region"] == "all"]
    lt = late(main)
    g = lt.groupby(["agent", "condition", "seed"])
    rows.append(_q("train_success_late", 100 * g["success"].mean()))
    rows.append(_q("steps_late", g["steps"].mean()))
    rows.append(_q("time_late", (lt["habit_actions"] + PLANNING_COST * lt["planning_actions"]).groupby(
        [lt["agent"], lt["condition"], lt["seed"]]).mean()))
    apac = lt[lt["agent"] == "apac"].groupby(["agent", "condition", "seed"])
    rows.append(_q("habit_fraction_late", 100 * apac["habit_actions"].sum()
                   / (apac["habit_actions"].sum() + apac["planning_actions"].sum())))
    if not tests.empty:
        grid = tests[tests["protocol"] == "grid"].groupby(["agent", "condition", "seed"])
        rows.append(_q("test_success", 100 * grid["success"].mean()))
        reached = tests[(tests["protocol"] == "grid") & tests["success"].astype(bool)]
        rows.append(_q("test_steps_to_reach", reached.groupby(["agent", "condition", "seed"])["steps"].mean()))
        gen = tests[tests["protocol"] == "generalization"].groupby(["agent", "condition", "seed"])
        rows.append(_q("generalization_success", 100 * gen["success"].mean()))
        rows.append(_q("generalization_targets", gen["target_index"].nunique().astype(float)))
        occluded = tests[tests["protocol"] == "occluded"]
        occ = occluded.groupby(["agent", "condition", "seed"])
        rows.append(_q("occluded_distance", occ["final_distance"].mean()))
        if not occluded.empty:
            judged = occluded.assign(judged=judged_reached(occluded))
            g = judged.groupby(["agent", "condition", "seed"])
            rows.append(_q("occluded_judged_rate", 100 * g["judged"].mean()))
            # NaN for a seed whose forward model never judged a target reached
            rows.append(_q("occluded_distance_judged", judged["final_distance"].where(judged["judged"]).groupby(
                [judged["agent"], judged["condition"], judged["seed"]]).mean()))
    return pd.concat([r for r in rows if not r.empty], ignore_index=True)


def judged_reached(occluded: pd.DataFrame) -> pd.Series:
    """Episodes that ended because the forward model's estimate was inside the zone. Results written
    before the ``judged_reached`` column: episodes that ended before the 30-step limit."""
    if "judged_reached" in occluded and occluded["judged_reached"].notna().all():
        return occluded["judged_reached"].astype(bool)
    return occluded["steps"] < STEP_LIMIT


def _q(name: str, series: pd.Series) -> pd.DataFrame:
    df = series.rename("value").reset_index()
    df.insert(0, "quantity", name)
    return df


def key_numbers(seed_values: pd.DataFrame) -> pd.DataFrame:
    """Mean and 95% t-interval over seeds of every key number, with the paper's stated value."""
    out = []
    for (q, agent, cond), grp in seed_values.groupby(["quantity", "agent", "condition"], sort=False):
        mean, lo, hi = t_interval(grp["value"].tolist())
        fig, desc, unit = QUANTITIES[q]
        out.append({"figure": fig, "quantity": q, "description": desc, "unit": unit, "agent": agent,
                    "condition": cond, "n_seeds": int(grp["value"].notna().sum()), "mean": mean,
                    "ci95_low": lo, "ci95_high": hi, "paper": paper_value(q, agent, cond)})
    df = pd.DataFrame(out)
    order = {q: i for i, q in enumerate(QUANTITIES)}
    df["_o"] = df["quantity"].map(order) * 1000 + df["condition"].map(_rank(CONDITIONS)) * 10 \
        + df["agent"].map(_rank(AGENT_ORDER))
    return df.sort_values("_o").drop(columns="_o").reset_index(drop=True)


def _rank(order: Sequence[str]) -> dict[str, int]:
    return {k: i for i, k in enumerate(order)}


# -- figures -------------------------------------------------------------------------

def _agents(df: pd.DataFrame) -> list[str]:
    return [a for a in AGENT_ORDER if a in set(df["agent"])]


def _conditions(df: pd.DataFrame) -> list[str]:
    return [c for c in CONDITIONS if c in set(df["condition"])]


def _smooth_band(frame: pd.DataFrame, column: str, window: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-seed moving average of ``column`` over episodes, then mean and 95% t-band over seeds."""
    wide = frame.pivot_table(index="episode", columns="seed", values=column, aggfunc="mean").sort_index()
    wide = wide.astype(float).rolling(window, min_periods=1).mean()
    n = wide.notna().sum(axis=1).to_numpy()
    mean = wide.mean(axis=1).to_numpy()
    sd = wide.std(axis=1, ddof=1).to_numpy()
    tq = np.where(n > 1, stats.t.ppf(0.975, np.maximum(n - 1, 1)), np.nan)
    half = np.nan_to_num(tq * sd / np.sqrt(np.maximum(n, 1)))
    return wide.index.to_numpy(), mean, mean - half, mean + half


def _window(metrics: pd.DataFrame) -> int:
    return max(1, int(metrics["episode"].max() + 1) // 25)


def _line(ax: plt.Axes, frame: pd.DataFrame, column: str, window: int, label: str, color: str,
          scale: float = 1.0) -> None:
    x, m, lo, hi = _smooth_band(frame, column, window)
    upper = scale if column == "success" else np.inf  # bands clipped to the quantity's range
    ax.plot(x, scale * m, color=color, label=label, lw=1.4)
    ax.fill_between(x, np.clip(scale * lo, 0, upper), np.clip(scale * hi, 0, upper), color=color, alpha=0.2, lw=0)


def _save(fig: plt.Figure, path: Path, title: str) -> Path:
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _axes(nrows: int, ncols: int, w: float = 4.2, h: float = 3.4) -> np.ndarray:
    fig, axes = plt.subplots(nrows, ncols, figsize=(w * ncols, h * nrows), squeeze=False)
    return axes


def fig_training_success(metrics: pd.DataFrame, path: Path) -> Path:
    """Fig. 3: success rate during training per episode; top: per agent, bottom: per condition."""
    train = metrics[(metrics["phase"] == "train") & (metrics["region"] == "all")]
    agents, conds, w = _agents(train), _conditions(train), _window(train)
    ncols = max(len(agents), len(conds))
    axes = _axes(2, ncols)
    cmap = plt.get_cmap("tab10")
    for i, agent in enumerate(agents):
        ax = axes[0, i]
        for j, cond in enumerate(conds):
            sel = train[(train["agent"] == agent) & (train["condition"] == cond)]
            if len(sel):
                _line(ax, sel, "success", w, COND_SHORT[cond] + ": " + COND_LABEL[cond], cmap(j), 100)
        _style(ax, f"{AGENT_LABEL[agent]}", "training episode", "success rate (%)", ylim=(-2, 102))
    for j, cond in enumerate(conds):
        ax = axes[1, j]
        for agent in agents:
            sel = train[(train["agent"] == agent) & (train["condition"] == cond)]
            if len(sel):
                _line(ax, sel, "success", w, AGENT_LABEL[agent], AGENT_COLOR[agent], 100)
        _style(ax, COND_LABEL[cond], "training episode", "success rate (%)", ylim=(-2, 102))
    _hide_unused(axes, [len(agents), len(conds)])
    return _save(axes[0, 0].figure, path, f"Fig. 3: training success (moving average over {w} episodes; "
                                          "mean over seeds, 95% CI band)")


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
            _style(ax, f"{COND_LABEL[cond]}\n{label}", "training episode", "loss (mean over seeds)")
    return _save(axes[0, 0].figure, path, f"Training losses per episode (mean of the episode's updates; "
                                          f"moving average over {w} episodes, mean over seeds)")


def _style(ax: plt.Axes, title: str, xlabel: str, ylabel: str, ylim: tuple[float, float] | None = None) -> None:
    ax.set_title(title, fontsize=10)
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


def _bars(ax: plt.Axes, table: pd.DataFrame, quantity: str, conds: list[str], agents: list[str]) -> None:
    """Grouped bars (x: condition, one bar per agent) with 95% CI error bars."""
    width = 0.8 / max(len(agents), 1)
    sel = table[table["quantity"] == quantity]
    for k, agent in enumerate(agents):
        rows = [sel[(sel["agent"] == agent) & (sel["condition"] == c)] for c in conds]
        mean = np.array([r["mean"].iloc[0] if len(r) else np.nan for r in rows])
        lo = np.array([r["ci95_low"].iloc[0] if len(r) else np.nan for r in rows])
        hi = np.array([r["ci95_high"].iloc[0] if len(r) else np.nan for r in rows])
        upper = 100.0 if QUANTITIES[quantity][2] == "%" else np.inf  # error bars clipped to the quantity's range
        err = np.nan_to_num(np.vstack([mean - np.maximum(lo, 0), np.minimum(hi, upper) - mean]))
        x = np.arange(len(conds)) + (k - (len(agents) - 1) / 2) * width
        ax.bar(x, mean, width, yerr=err, capsize=3, color=AGENT_COLOR[agent], label=AGENT_LABEL[agent])
    ax.set_xticks(np.arange(len(conds)), [COND_SHORT[c] for c in conds])


def fig_test(table: pd.DataFrame, path: Path) -> Path:
    """Fig. 4: test success rate and mean steps to reach, per agent and condition."""
    sel = table[table["quantity"] == "test_success"]
    agents, conds = _agents(sel), _conditions(sel)
    axes = _axes(1, 2, w=5.5)
    _bars(axes[0, 0], table, "test_success", conds, agents)
    _style(axes[0, 0], "test success rate", "condition (target/kinematics: s = static, c = changing)",
           "success rate (%)", ylim=(0, 105))
    _bars(axes[0, 1], table, "test_steps_to_reach", conds, agents)
    _style(axes[0, 1], "mean steps to reach (reached targets)",
           "condition (target/kinematics: s = static, c = changing)", "action steps")
    return _save(axes[0, 0].figure, path, "Fig. 4: frozen-network tests (mean over seeds, 95% CI)")


def fig_arbitration(metrics: pd.DataFrame, path: Path) -> Path:
    """Fig. 5: APAC's habitual vs planning actions per episode, per condition."""
    apac = metrics[(metrics["agent"] == "apac") & (metrics["phase"] == "train") & (metrics["region"] == "all")]
    conds, w = _conditions(apac), _window(apac)
    axes = _axes(1, max(len(conds), 1))
    for j, cond in enumerate(conds):
        sel = apac[apac["condition"] == cond]
        _line(axes[0, j], sel, "habit_actions", w, "habitual (actor)", "tab:blue")
        _line(axes[0, j], sel, "planning_actions", w, "planning (inverse model)", "tab:red")
        _style(axes[0, j], COND_LABEL[cond], "training episode", "actions per episode")
    if not conds:
        axes[0, 0].text(0.5, 0.5, "no APAC cell in these results", ha="center", transform=axes[0, 0].transAxes)
        _style(axes[0, 0], "APAC", "training episode", "actions per episode")
    return _save(axes[0, 0].figure, path, f"Fig. 5: APAC arbitration (moving average over {w} episodes; "
                                          "mean over seeds, 95% CI band)")


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
        _style(axes[0, j], COND_LABEL[cond], "training episode", "action steps per episode")
        _style(axes[1, j], COND_LABEL[cond], "training episode",
               f"time per episode (habit steps; planning = {PLANNING_COST}x)")
    return _save(axes[0, 0].figure, path, f"Fig. 6: steps and time per episode (moving average over {w} "
                                          "episodes; mean over seeds, 95% CI band)")


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
            _style(ax, f"{AGENT_LABEL[agent]}, {COND_SHORT[cond]} ({sel['success'].mean():.0%} reached)",
                   "x (cm)", "y (cm)")
    if not conds:
        axes[0, 0].text(0.5, 0.5, "no changing-target test results", ha="center", transform=axes[0, 0].transAxes)
        _style(axes[0, 0], "trajectories", "x (cm)", "y (cm)")
    return _save(axes[0, 0].figure, path, "Fig. 7: reaching the test targets under changing targets (all seeds)")


def fig_generalization(table: pd.DataFrame, path: Path) -> Path:
    """Fig. 8: the train/test region map and the generalization success per agent and condition."""
    from apac_mj.kinematics import motion_function
    from apac_mj.suite.task_spec import load_task

    spec = load_task("changing_target")
    fig, (ax_map, ax_bar) = plt.subplots(1, 2, figsize=(11, 4.4), gridspec_kw={"width_ratios": [1, 1.4]})
    a, b = np.meshgrid(np.linspace(0, 180, 181), np.linspace(0, 180, 181), indexing="ij")
    end, _ = motion_function(a, b, *spec.link_lengths, origin=spec.origin)
    end = end.reshape(-1, 2)
    test = end[:, 1] >= spec.region.test_y_min
    ax_map.scatter(*end[~test].T, s=0.3, color="tab:red", label="train region")
    ax_map.scatter(*end[test].T, s=0.3, color="tab:blue", label=f"test region (y >= {spec.region.test_y_min} cm)")
    ax_map.set_aspect("equal")
    ax_map.set_xlim(0, 30)
    ax_map.set_ylim(0, 30)
    _style(ax_map, f"reachable area, l = {spec.link_lengths} cm", "x (cm)", "y (cm)")
    sel = table[table["quantity"] == "generalization_success"]
    _bars(ax_bar, table, "generalization_success", _conditions(sel), _agents(sel))
    _style(ax_bar, "success on held-out-region targets", "training condition (s = static, c = changing)",
           "success rate (%)", ylim=(0, 105))
    if sel.empty:
        ax_bar.text(0.5, 0.5, "no generalization cells in these results", ha="center", transform=ax_bar.transAxes)
    return _save(fig, path, "Fig. 8: generalization to the held-out region (mean over seeds, 95% CI)")


def fig_occluded(tests: pd.DataFrame, path: Path) -> Path:
    """Fig. 9: occluded vision, actual final distance per test target: mean over seeds, min-max band."""
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
                ax.scatter(judged["target_index"], judged["final_distance"], s=6, color="tab:green", zorder=3,
                           label=f"forward model judged reached ({len(judged) / len(sel):.0%})")
                ax.axhline(judged["final_distance"].mean(), color="tab:green", ls="--", lw=1.2,
                           label=f"their mean: {judged['final_distance'].mean():.2f} cm")
            ax.axhline(load_task(cond).zone_radius, color="red", lw=1.2, label="target-zone radius")
            _style(ax, f"{AGENT_LABEL[agent]}, {COND_LABEL[cond]}", "test target index", "final distance (cm)")
    if not agents:
        axes[0, 0].text(0.5, 0.5, "no occluded-vision results", ha="center", transform=axes[0, 0].transAxes)
        _style(axes[0, 0], "occluded vision", "test target index", "final distance (cm)")
    return _save(axes[0, 0].figure, path, "Fig. 9: occluded vision, actual final distance to the target (green: "
                                          "episodes ended because the forward model judged the target reached)")


# -- the report ----------------------------------------------------------------------

@dataclasses.dataclass
class Figure:
    file: str
    caption: str
    make: Callable[[], Path]


def write_report(results: str | Path, out: str | Path | None = None, title: str | None = None) -> Path:
    """Write every figure, key_numbers.csv and report.md; returns the output directory."""
    results = Path(results)
    metrics, tests = load_results(results), load_tests(results)
    out = Path(out) if out else results / "report"
    out.mkdir(parents=True, exist_ok=True)
    table = key_numbers(per_seed(metrics, tests))
    table.to_csv(out / "key_numbers.csv", index=False)
    figures = [
        Figure("fig3_training_success.png", "Training success rate per episode (paper Fig. 3).",
               lambda: fig_training_success(metrics, out / "fig3_training_success.png")),
        Figure("fig4_test.png", "Test success rate and steps to reach (paper Fig. 4).",
               lambda: fig_test(table, out / "fig4_test.png")),
        Figure("fig5_arbitration.png", "APAC habitual vs planning actions per episode (paper Fig. 5).",
               lambda: fig_arbitration(metrics, out / "fig5_arbitration.png")),
        Figure("fig6_steps_time.png", "Action steps and time per episode, planning = 3x habit (paper Fig. 6).",
               lambda: fig_steps_time(metrics, out / "fig6_steps_time.png")),
        Figure("fig7_trajectories.png", "Reaching trajectories to the test targets (paper Fig. 7).",
               lambda: fig_trajectories(tests, out / "fig7_trajectories.png")),
        Figure("fig8_generalization.png", "Held-out region and generalization success (paper Fig. 8).",
               lambda: fig_generalization(table, out / "fig8_generalization.png")),
        Figure("fig9_occluded.png", "Occluded vision: final distance to the target (paper Fig. 9).",
               lambda: fig_occluded(tests, out / "fig9_occluded.png")),
    ]
    if all(c in metrics and metrics[c].notna().any() for c, _ in LOSSES):  # older results lack the columns
        figures.append(Figure("fig10_losses.png", "Training losses per episode (not in the paper).",
                              lambda: fig_losses(metrics, out / "fig10_losses.png")))
    for f in figures:
        f.make()
    manifest = read_json(results / MANIFEST) or {}
    (out / "report.md").write_text(_markdown(title, manifest, metrics, table, figures))
    return out


def _markdown(title: str | None, manifest: dict, metrics: pd.DataFrame, table: pd.DataFrame,
              figures: list[Figure]) -> str:
    preset = manifest.get("preset", {})
    seeds = sorted(set(metrics["seed"]))
    episodes = int(metrics.loc[metrics["phase"] == "train", "episode"].max()) + 1
    lines = [f"# {title or 'APAC results: ' + str(preset.get('name', 'grid'))}", ""]
    if preset.get("description"):
        lines += [preset["description"], ""]
    lines += [f"Agents: {', '.join(AGENT_LABEL[a] for a in _agents(metrics))}. "
              f"Conditions: {', '.join(COND_SHORT[c] + ' = ' + COND_LABEL[c] for c in _conditions(metrics))}. "
              f"{len(seeds)} seeds, {episodes} training episodes per seed. Intervals are 95% Student-t intervals "
              "over seeds; 'paper' quotes what Fard & Trappenberg state in their Results section.", ""]
    lines += ["## Figures", ""]
    for f in figures:
        lines += [f"![{f.caption}]({f.file})", "", f"*{f.caption}*", ""]
    lines += ["## Key numbers", "", "| figure | quantity | agent | condition | seeds | mean | 95% CI | paper |",
              "|---|---|---|---|---|---|---|---|"]
    for r in table.itertuples():
        ci = "-" if math.isnan(r.ci95_low) else f"[{_fmt(r.ci95_low)}, {_fmt(r.ci95_high)}]"
        lines.append(f"| {r.figure} | {r.description} ({r.unit}) | {AGENT_LABEL[r.agent]} | {COND_SHORT[r.condition]} "
                     f"| {r.n_seeds} | {_fmt(r.mean)} | {ci} | {r.paper or '-'} |")
    return "\n".join(lines) + "\n"


def _fmt(x: float) -> str:
    return "nan" if math.isnan(x) else f"{x:.2f}"


def load_key_numbers(report_dir: str | Path) -> pd.DataFrame:
    return pd.read_csv(Path(report_dir) / "key_numbers.csv")


__all__ = ["write_report", "key_numbers", "per_seed", "t_interval", "load_key_numbers"]
