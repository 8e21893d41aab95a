"""The report's figures: one registry, the paper's figures registered in it like a user's.

A figure is a :class:`FigureSpec`: its file, its caption, ``draw(data, path)`` and ``applies(data)``,
all reading one :class:`ReportData`. :func:`register_figure` adds one; the paper's (Figs. 3-9, the
scoreboard Fig. 11 and the losses Fig. 10, in that order) are registered when this module loads, and
:func:`apac_mj.report.write_report` draws the registry in registration order. Every curve is a mean over
seeds of a per-seed moving average, every bar the key-number table's mean and 95% interval.
"""
from __future__ import annotations

import dataclasses
import math
import textwrap
from collections.abc import Callable, Sequence
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from apac_mj import kinds, types
from apac_mj.kinematics import motion_function
from apac_mj.report.labels import (AGENT_COLOR, AGENT_LABEL, agents, arbitrating, condition_colors, condition_label,
                                   condition_order, condition_short, condition_spec, episodes, planner_label)
from apac_mj.report.quantities import (CROSSING_WINDOW, HABIT_THRESHOLD, LATE_FRACTION, habit_crossing,
                                      judged_reached, measured, time_cost, timed)
from apac_mj.report.stats import BOOTSTRAP_SEED, LEVEL
from apac_mj.suite.task_spec import TaskSpec
from apac_mj.types import PLANNING_COST
from apac_mj.util.registry import Registry

#: Up to this many seeds each seed is drawn as a thin line (and listed in report.md), beyond it a band.
LIST_SEEDS = 10


@dataclasses.dataclass(frozen=True)
class ReportData:
    """What a figure is drawn from: the results directory and its tables (:func:`~apac_mj.report.write_report`
    builds it)."""

    results: Path
    #: Every cell's metrics.parquet (apac_mj.experiments.results.load_results).
    metrics: pd.DataFrame
    #: Every cell's eval/<protocol>.parquet (apac_mj.experiments.results.load_tests).
    tests: pd.DataFrame
    #: One row per (quantity, agent, condition, seed) (:func:`apac_mj.report.quantities.per_seed`).
    seed_values: pd.DataFrame
    #: The key-number table (:func:`apac_mj.report.quantities.key_numbers`).
    table: pd.DataFrame

    @property
    def protocols(self) -> set[str]:
        """The test protocols the results hold ("grid", "occluded", "generalization")."""
        return set(self.tests["protocol"]) if "protocol" in self.tests else set()


@dataclasses.dataclass(frozen=True)
class FigureSpec:
    """A figure of the report (:func:`register_figure`), listed in report.md with its caption."""

    #: File name in the report directory (e.g. "fig12_my_figure.png").
    file: str
    caption: str
    #: ``draw(data, path)`` writes the figure to ``path``.
    draw: Callable[[ReportData, Path], object]
    #: ``applies(data)``: these results hold something to draw (else the figure is skipped, and said so).
    applies: Callable[[ReportData], bool] = lambda data: True


_FIGURES: Registry[FigureSpec] = Registry(
    "figure", duplicate="a figure {name!r} is already registered (pass replace=True to redefine it)")


def register_figure(spec: FigureSpec, replace: bool = False) -> FigureSpec:
    """Add a figure to every report written from now on (in this process), after those already registered;
    ``replace=True`` redefines a registered one in its place."""
    if not replace:
        _FIGURES.check_new(spec.file)
    if not spec.file.endswith((".png", ".svg", ".pdf")):
        raise ValueError(f"figure file must end in .png, .svg or .pdf, got {spec.file!r}")
    if not (callable(spec.draw) and callable(spec.applies)):
        raise ValueError(f"figure {spec.file!r}: draw and applies must be callable")
    return _FIGURES.replace(spec.file, spec)


def unregister_figure(file: str) -> None:
    """Remove a registered figure (the paper's included) from the reports written from now on."""
    _FIGURES.unregister(file)


def registered_figures() -> list[FigureSpec]:
    """Every registered figure, in the order a report draws and lists them."""
    return _FIGURES.values()


# -- drawing helpers -------------------------------------------------------------------

def _train(metrics: pd.DataFrame) -> pd.DataFrame:
    """The main study's training episodes (no babbling, no generalization cells)."""
    return metrics[(metrics["phase"] == "train") & (metrics["region"] == "all")]


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
    """Suptitle wrapped to the figure's width (nothing cut off), constrained layout; the format is ``path``'s
    suffix, the resolution matplotlib's ``savefig.dpi`` (:func:`draw_figures` sets it; else :data:`DEFAULT_DPI`)."""
    width_in = fig.get_size_inches()[0]
    fig.suptitle(textwrap.fill(title, width=max(40, int(width_in * 11))), fontsize=11)
    dpi = plt.rcParams["savefig.dpi"]
    fig.savefig(path, dpi=DEFAULT_DPI if dpi == "figure" else dpi)
    plt.close(fig)
    return path


#: The formats a report's figures can be written in (``apac-mj report --format``) and the default resolution.
FORMATS, DEFAULT_DPI = ("png", "svg", "pdf"), 110


def check_format(fmt: str, dpi: int) -> None:
    """Refuse a figure format other than :data:`FORMATS` or a resolution outside [10, 1200] dpi."""
    if fmt not in FORMATS:
        raise ValueError(f"figure format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    if not 10 <= dpi <= 1200:
        raise ValueError(f"figure dpi must be in [10, 1200], got {dpi}")


def draw_figures(data: ReportData, out: Path, fmt: str = "png", dpi: int = DEFAULT_DPI,
                 draw: bool = True) -> list[tuple[FigureSpec, bool]]:
    """Draw (``draw=False``: only list) every registered figure that applies into ``out`` as ``fmt`` at ``dpi``;
    a figure without data this time leaves no file of any format behind. Returns each figure, named as
    written, and whether it applies."""
    check_format(fmt, dpi)
    drawn = []
    with plt.rc_context({"savefig.dpi": dpi}):
        for spec in registered_figures():
            stem = Path(spec.file).stem
            for suffix in FORMATS:
                (out / f"{stem}.{suffix}").unlink(missing_ok=True)
            spec = dataclasses.replace(spec, file=f"{stem}.{fmt}")
            applies = bool(spec.applies(data))
            if applies and draw:
                spec.draw(data, out / spec.file)
            drawn.append((spec, applies))
    return drawn


#: The narrowest figure (inches): one panel at 4.2 in cut its caption and labels.
MIN_FIGURE_WIDTH = 6.4


def _axes(nrows: int, ncols: int, w: float = 4.2, h: float = 3.4) -> np.ndarray:
    fig, axes = plt.subplots(nrows, ncols, figsize=(max(w * ncols, MIN_FIGURE_WIDTH), h * nrows), squeeze=False,
                             layout="constrained")
    return axes


def _rows(ncols: Sequence[int], w: float = 4.2, h: float = 3.4) -> tuple[plt.Figure, list[list[plt.Axes]]]:
    """A figure of rows with their own number of panels each (``ncols``): no empty slot in a shorter row."""
    fig = plt.figure(figsize=(max(w * max(ncols), MIN_FIGURE_WIDTH), h * len(ncols)), layout="constrained")
    subfigs = fig.subfigures(len(ncols), 1, squeeze=False)[:, 0]
    return fig, [list(sf.subplots(1, n, squeeze=False)[0]) for sf, n in zip(subfigs, ncols)]


def _style(ax: plt.Axes, title: str, xlabel: str, ylabel: str, ylim: tuple[float, float] | None = None) -> None:
    """Title (wrapped to the panel's width), labels, grid and legend of one panel."""
    width_in = ax.get_position().width * ax.get_figure(root=True).get_size_inches()[0]
    width = max(20, int(width_in * 12))
    ax.set_title("\n".join(textwrap.fill(line, width=width) for line in title.split("\n")), fontsize=10)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if ylim:
        ax.set_ylim(*ylim)
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7)


def _plane(ax: plt.Axes, spec: TaskSpec) -> None:
    """Equal axes over the task's plane [0, w] x [0, h] (cm)."""
    ax.set_aspect("equal")
    ax.set_xlim(0, spec.plane_size[0])
    ax.set_ylim(0, spec.plane_size[1])


#: Values in cm below this are float32 rounding, not a measured difference (positions of ~30 cm carry
#: ~2e-6 cm of float32 resolution; the target zone is 0.5 cm): the bars draw them as 0, the axis spans at
#: least :data:`CM_AXIS_MIN`.
CM_NOISE = 1e-4
CM_AXIS_MIN = 0.05


def _bars(ax: plt.Axes, table: pd.DataFrame, seed_values: pd.DataFrame, quantity: str, conds: list[str],
          agents_: list[str], cm: bool = False) -> None:
    """Grouped bars (x: condition, one bar per agent with a value there, centred on the condition's tick):
    the table's mean and 95% interval, unclipped (the intervals respect the quantity's range), with each
    seed's value as a dot. A count behind a mean over some of the samples (e.g. reached targets) is written
    under its bar, below the axis. ``cm``: values below :data:`CM_NOISE` are drawn as 0."""
    sel = table[table["quantity"] == quantity]
    seeds = seed_values[seed_values["quantity"] == quantity]
    width = 0.8 / max(len(agents_), 1)
    floor = (lambda v: np.where(np.abs(v) < CM_NOISE, 0.0, v)) if cm else (lambda v: v)
    counts: list[tuple[float, str]] = []
    labelled: set[str] = set()
    for c, cond in enumerate(conds):
        rows = [(a, sel[(sel["agent"] == a) & (sel["condition"] == cond)]) for a in agents_]
        rows = [(a, r) for a, r in rows if len(r)]
        for k, (agent, r) in enumerate(rows):
            x = c + (k - (len(rows) - 1) / 2) * width
            mean, lo, hi = (float(floor(np.array(r[col].iloc[0]))) for col in ("mean", "ci95_low", "ci95_high"))
            err = np.nan_to_num([[mean - lo], [hi - mean]]).clip(min=0)
            ax.bar(x, mean, width, yerr=err, capsize=3, color=AGENT_COLOR[agent], alpha=0.85,
                   label=None if agent in labelled else AGENT_LABEL[agent])
            labelled.add(agent)
            if pd.notna(r["samples_of"].iloc[0]):
                counts.append((x, f"{int(r['samples'].iloc[0])}/{int(r['samples_of'].iloc[0])}"))
            v = floor(seeds[(seeds["agent"] == agent) & (seeds["condition"] == cond)]["value"].dropna().to_numpy())
            jitter = np.linspace(-width / 4, width / 4, len(v)) if len(v) > 1 else np.zeros(len(v))
            ax.scatter(x + jitter, v, s=9, color="black", zorder=3,
                       label="single seeds" if "seeds" not in labelled and len(v) else None)
            labelled |= {"seeds"} if len(v) else set()
    ax.set_xticks(np.arange(len(conds)), [condition_short(c) for c in conds])
    if counts:  # each count under its own bar, the condition names below them
        ax.xaxis.remove_overlapping_locs = False  # else the middle bar's count, on the condition's tick, is dropped
        ax.set_xticks([x for x, _ in counts], [t for _, t in counts], minor=True, rotation=90, fontsize=6)
        ax.tick_params(axis="x", which="major", pad=30, length=0)
    if cm:
        ax.set_ylim(bottom=0, top=max(ax.get_ylim()[1], CM_AXIS_MIN))


def _table_mean(table: pd.DataFrame, quantity: str, agent: str, cond: str) -> float:
    sel = table[(table["quantity"] == quantity) & (table["agent"] == agent) & (table["condition"] == cond)]
    return float(sel["mean"].iloc[0]) if len(sel) else math.nan


# -- the paper's figures ---------------------------------------------------------------

def fig_training_success(data: ReportData, path: Path) -> Path:
    """Fig. 3: success rate during training per episode; top: per agent (colour: condition), bottom: per
    condition (colour: agent). A row that would repeat the other's lines is left out: with one condition only
    the per-condition panel, with one agent only the per-agent one."""
    train = _train(data.metrics)
    agents_, conds, w = agents(train), condition_order(train["condition"]), _window(train)
    colors = condition_colors(data.metrics["condition"])
    rows = (["agent"] if len(conds) > 1 else []) + (["condition"] if len(agents_) > 1 or len(conds) == 1 else [])
    fig, axes = _rows([len(agents_) if r == "agent" else len(conds) for r in rows])
    by_row = dict(zip(rows, axes))
    for i, agent in enumerate(agents_ if "agent" in by_row else []):
        ax = by_row["agent"][i]
        for cond in conds:
            sel = train[(train["agent"] == agent) & (train["condition"] == cond)]
            if len(sel):
                _line(ax, sel, "success", w, condition_short(cond) + ": " + condition_label(cond), colors[cond], 100)
        _style(ax, f"{AGENT_LABEL[agent]} (colour: condition)", "training episode", "success rate (%)",
               ylim=(-2, 102))
    for j, cond in enumerate(conds if "condition" in by_row else []):
        ax = by_row["condition"][j]
        for agent in agents_:
            sel = train[(train["agent"] == agent) & (train["condition"] == cond)]
            if len(sel):
                _line(ax, sel, "success", w, AGENT_LABEL[agent], AGENT_COLOR[agent], 100)
        _style(ax, f"{condition_label(cond)} (colour: agent)", "training episode", "success rate (%)",
               ylim=(-2, 102))
    return _save(fig, path, f"Fig. 3: training success (moving average over {episodes(w)}; "
                            f"bold: mean over seeds, {_band_words(train)})")


def fig_test(data: ReportData, path: Path) -> Path:
    """Fig. 4: test success rate and mean steps to reach, per agent and condition."""
    sel = data.table[data.table["quantity"] == "test_success"]
    agents_, conds = agents(sel), condition_order(sel["condition"])
    axes = _axes(1, 2, w=5.5)
    _bars(axes[0, 0], data.table, data.seed_values, "test_success", conds, agents_)
    _style(axes[0, 0], "test success rate", "condition (target/kinematics: s = static, c = changing)",
           "success rate (%)", ylim=(0, 105))
    _bars(axes[0, 1], data.table, data.seed_values, "test_steps_to_reach", conds, agents_)
    _style(axes[0, 1], "mean steps to reach (reached targets only; at the foot: reached/tested)",
           "condition (target/kinematics: s = static, c = changing)", "action steps")
    return _save(axes[0, 0].figure, path, "Fig. 4: frozen-network tests (bars: mean over seeds with the 95% "
                                          "interval of report.md; dots: single seeds)")


def fig_arbitration(data: ReportData, path: Path) -> Path:
    """Fig. 5: habitual vs planning actions per episode, per condition (one row per arbitrating kind: APAC)."""
    main = _train(data.metrics)
    arbitrating_kinds = arbitrating(main)
    sel_all = main[main["agent"].isin(arbitrating_kinds)]
    conds, w = condition_order(sel_all["condition"]), _window(sel_all)
    axes = _axes(max(len(arbitrating_kinds), 1), max(len(conds), 1))
    crossing = habit_crossing(data.metrics)
    for i, agent in enumerate(arbitrating_kinds):
        for j, cond in enumerate(conds):
            sel = sel_all[(sel_all["agent"] == agent) & (sel_all["condition"] == cond)]
            _line(axes[i, j], sel, "habit_actions", w, "habitual (actor)", "tab:blue")
            _line(axes[i, j], sel, "planning_actions", w, planner_label(agent), "tab:red")
            title = (condition_label(cond) if len(arbitrating_kinds) == 1
                     else f"{AGENT_LABEL[agent]}, {condition_label(cond)}")
            _style(axes[i, j], title, "training episode", "actions per episode")
            _mark_crossings(axes[i, j], crossing[(crossing["agent"] == agent) & (crossing["condition"] == cond)])
    if not conds:
        axes[0, 0].text(0.5, 0.5, "no arbitrating agent in these results", ha="center",
                        transform=axes[0, 0].transAxes)
        _style(axes[0, 0], "arbitration", "training episode", "actions per episode")
    names = ", ".join(AGENT_LABEL[a] for a in arbitrating_kinds) or "APAC"
    return _save(axes[0, 0].figure, path, f"Fig. 5: {names} arbitration (moving average over {episodes(w)}; "
                                          f"bold: mean over seeds, {_band_words(sel_all)}; ticks at the top: "
                                          f"the episode each seed first had >= {HABIT_THRESHOLD:.0%} habitual "
                                          f"actions over {CROSSING_WINDOW} episodes; the paper: after ~300)")


def _mark_crossings(ax: plt.Axes, crossing: pd.DataFrame) -> None:
    """Each seed's first crossing of the habit threshold (:func:`habit_crossing`) as a tick at the top of the
    panel, and in words under the x label: how many seeds crossed, the median episode and the range."""
    eps = crossing["episode"].dropna().to_numpy()
    if len(crossing) == 0:
        return
    if len(eps):  # an empty unclipped line spans the figure's corner: constrained layout would collapse
        ax.plot(eps, np.ones(len(eps)), "|", transform=ax.get_xaxis_transform(), color="black", ms=12, mew=1.2,
                clip_on=False)
    words = (f">= {HABIT_THRESHOLD:.0%} habitual: {len(eps)}/{len(crossing)} seeds"
             + (f", median ep. {np.median(eps):.0f} ({eps.min():.0f}-{eps.max():.0f})" if len(eps) else ""))
    ax.set_xlabel(f"{ax.get_xlabel()}\n{words}")


def fig_steps_time(data: ReportData, path: Path) -> Path:
    """Fig. 6: action steps per episode (top) and time with planning = 3 x habit (middle); where the runs
    measured it, the decision wall time per episode (bottom), titled with each agent's measured time per
    planning action over that per habitual action (the key-number table's ``measured_planning_ratio``)
    beside the paper's 3. Results without the measured columns: the top two rows only."""
    train = _train(data.metrics).copy()
    train["time"] = time_cost(train["habit_actions"], train["planning_actions"])
    agents_, conds, w = agents(train), condition_order(train["condition"]), _window(train)
    measured_rows = timed(train) if measured(train) else None
    axes = _axes(2 if measured_rows is None else 3, len(conds))
    for j, cond in enumerate(conds):
        for agent in agents_:
            sel = train[(train["agent"] == agent) & (train["condition"] == cond)]
            if len(sel):
                _line(axes[0, j], sel, "steps", w, AGENT_LABEL[agent], AGENT_COLOR[agent])
                _line(axes[1, j], sel, "time", w, AGENT_LABEL[agent], AGENT_COLOR[agent])
            if measured_rows is not None:
                sel = measured_rows[(measured_rows["agent"] == agent) & (measured_rows["condition"] == cond)]
                if len(sel):
                    _line(axes[2, j], sel, "decision_ms", w, AGENT_LABEL[agent], AGENT_COLOR[agent])
        _style(axes[0, j], condition_label(cond), "training episode", "action steps per episode")
        _style(axes[1, j], condition_label(cond), "training episode",
               f"time per episode (habit steps; planning = {PLANNING_COST}x)")
        if measured_rows is not None:
            _style(axes[2, j], f"{condition_label(cond)}\n{ratio_words(data.table, agents_, cond)}",
                   "training episode", "measured decision time per episode (ms)")
    title = f"Fig. 6: steps and time per episode (moving average over {episodes(w)}; bold: mean over seeds, " \
            f"{_band_words(train)})"
    if measured_rows is not None:
        title += (f"; bottom: the decisions' measured wall time per episode (habit + planning), with the measured "
                  f"time per planning action / per habitual action (mean over seeds, last {LATE_FRACTION:.0%})")
    return _save(axes[0, 0].figure, path, title)


def ratio_words(table: pd.DataFrame, agents_: Sequence[str], cond: str) -> str:
    """Each agent's measured planning/habit time per action in ``cond`` (the table's
    ``measured_planning_ratio``; agents that never used both are left out) beside the paper's assumption."""
    ratios = [(a, _table_mean(table, "measured_planning_ratio", a, cond)) for a in agents_]
    shown = ", ".join(f"{AGENT_LABEL[a]} {_times(r)}" for a, r in ratios if math.isfinite(r))
    return (f"measured planning/habit time per action: {shown or 'no agent used both'} "
            f"(paper: {PLANNING_COST}x)")


def _times(ratio: float) -> str:
    """A ratio as "0.9x", "3.1x", "60x"."""
    return f"{ratio:.0f}x" if ratio >= 10 else f"{ratio:.1f}x" if ratio >= 0.1 else f"{ratio:.2g}x"


def fig_trajectories(data: ReportData, path: Path) -> Path:
    """Fig. 7: end-effector paths to the test targets under the conditions whose target changes."""
    grid = data.tests[data.tests["protocol"] == "grid"]
    changing = [c for c in condition_order(grid["condition"]) if condition_spec(c).target_mode == "changing"]
    grid = grid[grid["condition"].isin(changing)]
    agents_, conds = agents(grid), condition_order(grid["condition"])
    axes = _axes(max(len(conds), 1), max(len(agents_), 1), w=3.8, h=3.8)
    for i, cond in enumerate(conds):
        for k, agent in enumerate(agents_):
            ax = axes[i, k]
            sel = grid[(grid["agent"] == agent) & (grid["condition"] == cond)]
            for j, (px, py) in enumerate(zip(sel["path_x"], sel["path_y"])):
                ax.plot(px, py, color="tab:blue", lw=0.4, alpha=0.35, label="end-effector path" if j == 0 else None)
            _targets(ax, sel)
            _plane(ax, condition_spec(cond))
            _style(ax, f"{AGENT_LABEL[agent]}, {condition_short(cond)} ({sel['success'].mean():.0%} reached)",
                   "x (cm)", "y (cm)")
    if not conds:
        axes[0, 0].text(0.5, 0.5, "no changing-target test results", ha="center", transform=axes[0, 0].transAxes)
        _style(axes[0, 0], "trajectories", "x (cm)", "y (cm)")
    return _save(axes[0, 0].figure, path, "Fig. 7: reaching the test targets under changing targets (all seeds)")


#: Fig. 7's test targets: reached (filled circle) and missed (cross), told apart by shape as well as colour.
REACHED_STYLE = {"marker": "o", "color": "#009E73", "s": 10}
MISSED_STYLE = {"marker": "x", "color": "#D55E00", "s": 14, "linewidths": 0.9}


def _targets(ax: plt.Axes, sel: pd.DataFrame) -> None:
    """Each test episode's target, drawn as reached or missed (one mark per seed and target)."""
    reached = sel["success"].astype(bool).to_numpy()
    for mask, style, word in ((reached, REACHED_STYLE, "reached"), (~reached, MISSED_STYLE, "missed")):
        if mask.any():
            ax.scatter(sel["target_x"][mask], sel["target_y"][mask], zorder=3,
                       label=f"target {word} ({int(mask.sum())} of {len(mask)})", **style)


def _region_maps(conds: list[str]) -> dict[tuple, list[str]]:
    """The conditions grouped by what their region map shows: geometry, joint range, plane and split."""
    maps: dict[tuple, list[str]] = {}
    for cond in conds:
        s = condition_spec(cond)
        maps.setdefault((s.link_lengths, s.origin, s.joint_range, s.plane_size, s.region), []).append(cond)
    return maps


def _region_map(ax: plt.Axes, spec: TaskSpec, title: str) -> None:
    """The reachable area at the initial link lengths, train region red, held-out test region blue."""
    angles = np.linspace(*spec.joint_range, 181)
    a, b = np.meshgrid(angles, angles, indexing="ij")
    end, _ = motion_function(a, b, *spec.link_lengths, origin=spec.origin)
    end = end.reshape(-1, 2)
    test = spec.region.contains_test(end)
    ax.scatter(*end[~test].T, s=0.3, color="tab:red", label="train region")
    ax.scatter(*end[test].T, s=0.3, color="tab:blue", label=f"test region (y >= {spec.region.test_y_min} cm)")
    _plane(ax, spec)
    _style(ax, title, "x (cm)", "y (cm)")


def fig_generalization(data: ReportData, path: Path) -> Path:
    """Fig. 8: the train/test region map of each condition present (one map where they agree) and the
    generalization success per agent and condition."""
    sel = data.table[data.table["quantity"] == "generalization_success"]
    conds = condition_order(sel["condition"])
    maps = _region_maps(conds)
    fig, axes = plt.subplots(1, len(maps) + 1, figsize=(11 + 4.6 * (len(maps) - 1), 4.4), squeeze=False,
                             gridspec_kw={"width_ratios": [1] * len(maps) + [1.4]}, layout="constrained")
    axes = axes[0]
    for ax, group in zip(axes, maps.values()):
        spec = condition_spec(group[0])
        title = f"reachable area, l = {spec.link_lengths} cm"
        _region_map(ax, spec, title if len(maps) == 1 else f"{', '.join(map(condition_short, group))}: {title}")
    _bars(axes[-1], data.table, data.seed_values, "generalization_success", conds, agents(sel))
    _style(axes[-1], "success on held-out-region targets", "training condition (s = static, c = changing)",
           "success rate (%)", ylim=(0, 105))
    return _save(fig, path, "Fig. 8: generalization to the held-out region (bars: mean over seeds with the 95% "
                            "interval of report.md; dots: single seeds)")


def fig_occluded(data: ReportData, path: Path) -> Path:
    """Fig. 9: occluded vision, actual final distance per test target: mean over seeds, min-max band; the
    judged-reached episodes' share and mean distance are the table's (means over seeds)."""
    occ = data.tests[data.tests["protocol"] == "occluded"]
    agents_, conds = agents(occ), condition_order(occ["condition"])
    axes = _axes(max(len(agents_), 1), max(len(conds), 1))
    zones = [condition_spec(c).zone_radius for c in conds]
    top = 1.9 * float(np.nanmax([occ["final_distance"].max() if len(occ) else 0.0, *zones, CM_AXIS_MIN]))
    for i, agent in enumerate(agents_):
        for j, cond in enumerate(conds):
            _occluded_panel(axes[i, j], occ[(occ["agent"] == agent) & (occ["condition"] == cond)], data.table,
                            agent, cond)
            axes[i, j].set_ylim(0, top)  # one range for every panel (room above the data for the legend)
    if not agents_:
        axes[0, 0].text(0.5, 0.5, "no occluded-vision results", ha="center", transform=axes[0, 0].transAxes)
        _style(axes[0, 0], "occluded vision", "test target index", "final distance (cm)")
    return _save(axes[0, 0].figure, path, "Fig. 9: occluded vision, actual final distance to the target (green: "
                                          "episodes ended because the forward model judged the target reached; their "
                                          "share and distance are means over seeds, as in report.md)")


def _occluded_panel(ax: plt.Axes, sel: pd.DataFrame, table: pd.DataFrame, agent: str, cond: str) -> None:
    """One agent and condition of Fig. 9: each test target on its own (targets are categories, so nothing joins
    them): the mean over seeds as a dot, the seeds' range as a vertical bar."""
    by = sel.groupby("target_index")["final_distance"]
    x = by.mean().index.to_numpy()
    ax.vlines(x, by.min().to_numpy(), by.max().to_numpy(), color="tab:blue", alpha=0.5, lw=1.5,
              label="min-max over seeds")
    ax.plot(x, by.mean().to_numpy(), "o", ls="none", color="black", ms=2.5, label="mean over seeds")
    judged = sel[judged_reached(sel).to_numpy()]
    if len(judged):  # the episodes the paper's blue band describes
        share = _table_mean(table, "occluded_judged_rate", agent, cond)
        dist = _table_mean(table, "occluded_distance_judged", agent, cond)
        ax.scatter(judged["target_index"], judged["final_distance"], s=6, color="tab:green", zorder=3,
                   label=f"judged reached ({share:.0f}%)")
        ax.axhline(dist, color="tab:green", ls="--", lw=1.2, label=f"their distance: {dist:.2f} cm")
    zone = condition_spec(cond).zone_radius
    ax.axhline(zone, color="red", lw=1.2, label="target-zone radius")
    _style(ax, f"{AGENT_LABEL[agent]}, {condition_label(cond)}", "test target index", "final distance (cm)")
    ax.legend(fontsize=6.5, loc="upper left", framealpha=0.9)


#: The scoreboard's panels: (quantity, title, y label, y limits or None).
SCOREBOARD = (
    ("train_success_late", f"training success, last {LATE_FRACTION:.0%}", "success rate (%)", (0, 105)),
    ("test_success", "test success (angle grid)", "success rate (%)", (0, 105)),
    ("test_habit_fraction", "habitual share of test actions", "habit share (%)", (0, 105)),
    ("test_time", f"test time per episode (planning = {PLANNING_COST} x habit)", "habit-step units", None),
    ("occluded_distance_judged", "in the dark: final distance when judged reached", "cm", None),
    ("test_estimate_error", "state-estimate error on the test grid", "cm", None),
)


def fig_scoreboard(data: ReportData, path: Path) -> Path:
    """Fig. 11: every agent x condition on the quantities that weigh arbitrators and integrators; only the
    quantities with a value (a panel of NaN would be empty), in two columns, an odd last one spanning both."""
    table = data.table
    panels = [p for p in SCOREBOARD
              if np.isfinite(table.loc[table["quantity"] == p[0], "mean"].to_numpy(dtype=float)).any()]
    sel = table[table["quantity"].isin([p[0] for p in panels])]
    agents_, conds = agents(sel), condition_order(sel["condition"])
    ncols = 2 if len(panels) > 1 else 1
    w = min(9.0, max(4.2, 0.3 * len(agents_) * len(conds) + 1.5))
    mosaic = [[f"p{min(i + c, len(panels) - 1)}" for c in range(ncols)] for i in range(0, len(panels), ncols)]
    fig = plt.figure(figsize=(max(w * ncols, MIN_FIGURE_WIDTH), 3.4 * len(mosaic)), layout="constrained")
    by_name = fig.subplot_mosaic(mosaic)
    axes = [by_name[f"p{i}"] for i in range(len(panels))]
    for ax, (q, title, ylabel, ylim) in zip(axes, panels):
        _bars(ax, table, data.seed_values, q, conds, agents_, cm=ylabel == "cm")
        _style(ax, title, "condition", ylabel, ylim=ylim)
    for ax in axes[1:]:
        if ax.get_legend():
            ax.get_legend().remove()
    return _save(fig, path, "Fig. 11: scoreboard (bars: mean over seeds with the 95% interval of report.md; dots: "
                            "single seeds)")


#: The training losses of Fig. 10: (metrics column, panel label).
LOSSES = tuple((f"{name}_loss", label) for name, label in zip(
    types.LOSSES, ("critic: TD loss (squared return units)", "actor: -Q(s, pi(s)) (+ penalty)",
                   "forward model: MSE (cm^2)", "inverse model: MSE (deg^2)"), strict=True))


def fig_losses(data: ReportData, path: Path) -> Path:
    """Training losses per episode (mean of the episode's updates): rows conditions, columns networks."""
    train = _train(data.metrics)
    agents_, conds, w = agents(train), condition_order(train["condition"]), _window(train)
    axes = _axes(len(conds), len(LOSSES), h=2.9)
    for r, cond in enumerate(conds):
        for c, (column, label) in enumerate(LOSSES):
            ax = axes[r, c]
            for agent in agents_:
                sel = train[(train["agent"] == agent) & (train["condition"] == cond)]
                if len(sel) and sel[column].notna().any():
                    x, m, _, _ = _smooth_band(sel, column, w)
                    ax.plot(x, m, color=AGENT_COLOR[agent], label=AGENT_LABEL[agent], lw=1.2)
            if column != "actor_loss":
                ax.set_yscale("log")
            _style(ax, f"{condition_label(cond)}\n{label}", "training episode", "loss (mean over seeds)")
    return _save(axes[0, 0].figure, path, f"Training losses per episode (mean of the episode's updates; "
                                          f"moving average over {episodes(w)}, mean over seeds). {CRITIC_READING}")


#: How to read Fig. 10's critic loss, which climbs while the agent learns (e.g. 0.5 -> 10).
CRITIC_READING = ("Reading the critic: its TD loss, the mean of (r + gamma Q'(s', pi'(s')) - Q(s, a))^2 over replayed "
                  "minibatches, is in squared return units (reward = -distance, cm per step) and is not a supervised "
                  "loss that falls to 0: its targets move with the target networks, its minibatches with the replay "
                  "buffer, and it scales with the size of Q, which the actor panel shows (-Q(s, pi(s))). Read a "
                  "climb against that panel: sqrt(TD loss) small beside |Q| is a critic that fits; a climb while "
                  "success falls is one that diverges.")


def _has_training(data: ReportData) -> bool:
    """The results hold main-study training episodes (a generalization-only grid holds none)."""
    return not _train(data.metrics).empty


def _has_losses(data: ReportData) -> bool:
    """Main-study training episodes whose metrics hold every loss column (results written before the losses
    were recorded do not)."""
    train = _train(data.metrics)
    return not train.empty and all(c in train and train[c].notna().any() for c, _ in LOSSES)


def _has(protocol: str) -> Callable[[ReportData], bool]:
    return lambda data: protocol in data.protocols


#: The paper's figures (and two beyond it), in the order a report draws and lists them.
PAPER_FIGURES = (
    FigureSpec("fig3_training_success.png", "Training success rate per episode (paper Fig. 3).", fig_training_success,
               _has_training),
    FigureSpec("fig4_test.png", "Test success rate and steps to reach (paper Fig. 4).", fig_test, _has("grid")),
    FigureSpec("fig5_arbitration.png", "APAC habitual vs planning actions per episode (paper Fig. 5).",
               fig_arbitration, lambda data: bool(arbitrating(_train(data.metrics)))),
    FigureSpec("fig6_steps_time.png",
               f"Action steps and time per episode, planning = {PLANNING_COST}x habit (paper Fig. 6); where the runs "
               "measured it, the decisions' wall time per episode and each agent's measured time per planning "
               f"action / per habitual action beside the paper's {PLANNING_COST}.", fig_steps_time, _has_training),
    FigureSpec("fig7_trajectories.png", "Reaching trajectories to the test targets (paper Fig. 7).", fig_trajectories,
               _has("grid")),
    FigureSpec("fig8_generalization.png", "Held-out region and generalization success (paper Fig. 8).",
               fig_generalization, _has("generalization")),
    FigureSpec("fig9_occluded.png", "Occluded vision: final distance to the target (paper Fig. 9).", fig_occluded,
               _has("occluded")),
    FigureSpec("fig11_scoreboard.png", "Scoreboard: success, habit share, time, distance in the dark, "
               "state-estimate error (not in the paper).", fig_scoreboard, _has("grid")),
    FigureSpec("fig10_losses.png", "Training losses per episode (not in the paper).", fig_losses, _has_losses),
)
for _spec in PAPER_FIGURES:
    register_figure(_spec)


# -- one run -----------------------------------------------------------------------------

def fig_run(metrics: pd.DataFrame, kind: str, task: str, name: str, path: Path) -> Path:
    """Learning curves of one run (``apac-mj report --run``): training success, steps per episode and, for a
    kind that arbitrates, its habitual share of the actions; moving averages per seed, bold the mean over seeds."""
    train = metrics[metrics["phase"] == "train"].copy()
    if train.empty:
        raise ValueError(f"run {name} has no training episode yet (only babbling): nothing to plot; "
                         "rerun apac-mj report --run once training has started")
    train["habit_share"] = train["habit_actions"] / (train["habit_actions"] + train["planning_actions"]).clip(lower=1)
    w, color = _window(train), AGENT_COLOR[kind]
    panels = [("success", "training success", "success rate (%)", 100, (-2, 102)),
              ("steps", "action steps per episode", "action steps", 1, None)]
    if kinds.get(kind).arbitrates:
        panels.append(("habit_share", "habitual share of the actions", "habit share (%)", 100, (-2, 102)))
    axes = _axes(1, len(panels), w=4.0)[0]
    for ax, (column, title, ylabel, scale, ylim) in zip(axes, panels):
        _line(ax, train, column, w, "mean over seeds", color, scale)
        _style(ax, title, "training episode", ylabel, ylim=ylim)
    return _save(axes[0].figure, path, f"{name}: {AGENT_LABEL[kind]} on {condition_label(task)}, "
                                       f"{train['seed'].nunique()} seed(s), {episodes(int(train['episode'].max()) + 1)}"
                                       f" (moving average over {episodes(w)}; {_band_words(train)})")

