"""apac-mj report: figures exist, and the key-number table holds the numbers of the results it was made from.

The results here are synthesized run directories with the contract's columns
(docs/architecture.md): random but known data, so the test recomputes every
checked number independently from the parquet files.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats as scipy_stats

from apac_mj import report
from apac_mj.cli import main
from apac_mj.experiments import grid
from apac_mj.experiments.presets import load_preset
from apac_mj.experiments.results import load_results, load_tests
from apac_mj.report import figures, labels, quantities, stats
from apac_mj.report.quantities import judged_reached, key_numbers, per_seed
from apac_mj.suite.task_spec import TaskSpec, load_task, register_task, unregister_task

FIGURES = ["fig3_training_success.png", "fig4_test.png", "fig5_arbitration.png", "fig6_steps_time.png",
           "fig7_trajectories.png", "fig8_generalization.png", "fig9_occluded.png", "fig10_losses.png",
           "fig11_scoreboard.png"]


def _metrics(rng: np.random.Generator, agent: str, seeds, episodes: int, timed: bool = False) -> pd.DataFrame:
    """Random training metrics; ``timed``: with the measured columns (habit_seconds, planning_seconds,
    plan_iterations; a planning action ~3-5 ms, a habitual one ~1 ms, 1-4 iterations per planning action)."""
    rows = []
    for seed in seeds:
        for ep in range(-2, episodes):
            steps = int(rng.integers(1, 31))
            habit = {"ddpg": steps, "spac": 0}.get(agent, int(rng.integers(0, steps + 1)))
            rows.append(dict(seed=seed, episode=ep, phase="babbling" if ep < 0 else "train",
                             success=bool(rng.random() < 0.6), steps=steps, **{"return": -float(rng.random() * 50)},
                             final_distance=float(rng.random() * 3), habit_actions=habit,
                             planning_actions=steps - habit, l1=5.0, l2=8.0,
                             target_x=float(rng.random() * 30), target_y=float(rng.random() * 30),
                             critic_loss=float(rng.random() * 10), actor_loss=float(rng.normal() * 5),
                             forward_loss=float(rng.random()), inverse_loss=float(rng.random() * 100),
                             estimate_error=float(rng.random() * 0.5)))
            if timed:
                plans = steps - habit
                rows[-1].update(habit_seconds=habit * 1e-3 * (0.8 + 0.4 * rng.random()),
                                planning_seconds=plans * 1e-3 * (3 + 2 * rng.random()),
                                plan_iterations=plans * int(rng.integers(1, 5)))
    return pd.DataFrame(rows)


def _eval(rng: np.random.Generator, seeds, n_targets: int, with_path: bool) -> pd.DataFrame:
    rows = []
    for seed in seeds:
        for t in range(n_targets):
            steps = int(rng.integers(1, 31))
            habit = int(rng.integers(0, steps + 1))
            row = dict(seed=seed, target_index=t, target_x=float(10 + t % 10), target_y=float(10 + t // 10),
                       success=bool(rng.random() < 0.7), steps=steps, final_distance=float(rng.random() * 2),
                       habit_actions=habit, planning_actions=steps - habit, time_cost=habit + 3 * (steps - habit),
                       judged_reached=bool(steps < 30 and rng.random() < 0.8),
                       estimate_error=float(rng.random() * 0.5))
            if with_path:
                row.update(path_x=list(rng.random(steps + 1) * 30), path_y=list(rng.random(steps + 1) * 30))
            rows.append(row)
    return pd.DataFrame(rows)


def make_results(root: Path, seed: int = 0, seeds=(0, 1, 2), episodes: int = 30, preset_name: str = "smoke",
                 conditions: str = "static_target,changing_target,changing_target_changing_kinematics",
                 timed: bool = False) -> Path:
    """A results directory with every cell of a small grid filled with random contract-shaped data
    (``timed``: the metrics with the measured decision-time columns)."""
    rng = np.random.default_rng(seed)
    preset = load_preset(preset_name, [f"seeds={list(seeds)}", f"episodes={episodes}", f"conditions={conditions}",
                                       "tests.generalization_conditions=static_target,changing_target"])
    for cell in grid.cells(preset):
        d = grid.prepare_cell(cell, preset, root)
        _metrics(rng, cell.agent, seeds, episodes, timed).to_parquet(d / "metrics.parquet")
        (d / "eval").mkdir()
        for protocol in cell.protocols:
            n = 39 if protocol == "generalization" else 12
            _eval(rng, seeds, n, protocol == "grid").to_parquet(d / "eval" / f"{protocol}.parquet")
        (d / "eval" / "summary.json").write_text("{}")
        (d / "DONE").write_text("")
    return root


def t_interval(values, level: float = 0.95) -> tuple[float, float, float]:
    """Mean and Student-t interval over seeds (NaN bounds with fewer than two values): the interval the
    report used before issue 11, the reference its bootstrap is checked against."""
    v = np.asarray([x for x in values if not math.isnan(x)], dtype=float)
    if v.size < 2:
        return (float(v.mean()) if v.size else math.nan), math.nan, math.nan
    half = float(scipy_stats.t.ppf(0.5 + level / 2, v.size - 1) * v.std(ddof=1) / math.sqrt(v.size))
    return float(v.mean()), float(v.mean()) - half, float(v.mean()) + half


def key_table(report_dir: Path) -> pd.DataFrame:
    return pd.read_csv(report_dir / "key_numbers.csv")


@pytest.fixture(scope="module")
def made(tmp_path_factory) -> tuple[Path, Path]:
    results = make_results(tmp_path_factory.mktemp("results"))
    assert main(["report", str(results)]) == 0
    return results, results / "report"


def test_figures_and_markdown_exist(made) -> None:
    _, out = made
    for f in FIGURES:
        data = (out / f).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000, f
        assert f"]({f})" in (out / "report.md").read_text()


def _row(table: pd.DataFrame, q: str, agent: str, cond: str) -> pd.Series:
    sel = table[(table["quantity"] == q) & (table["agent"] == agent) & (table["condition"] == cond)]
    assert len(sel) == 1, (q, agent, cond)
    return sel.iloc[0]


def test_test_success_matches_parquet(made) -> None:
    results, out = made
    table = key_table(out)
    md = (out / "report.md").read_text()
    for agent in ("ddpg", "spac", "apac"):
        for cond in ("static_target", "changing_target"):
            df = pd.read_parquet(results / f"{agent}__{cond}" / "eval" / "grid.parquet")
            per = [100 * g["success"].mean() for _, g in df.groupby("seed")]
            blo, bhi = stats.seed_interval(per, (0.0, 100.0))
            w = scipy_stats.binomtest(int(df["success"].sum()), len(df)).proportion_ci(0.95, method="wilson")
            m, lo, hi = np.mean(per), min(blo, 100 * w.low), max(bhi, 100 * w.high)
            r = _row(table, "test_success", agent, cond)
            assert (r["mean"], r["ci95_low"], r["ci95_high"]) == pytest.approx((m, lo, hi))
            assert f"| {m:.2f} | [{lo:.2f}, {hi:.2f}] |" in md


def test_training_and_arbitration_match_parquet(made) -> None:
    results, out = made
    table = key_table(out)
    df = pd.read_parquet(results / "apac__changing_target" / "metrics.parquet")
    late = df[(df["phase"] == "train") & (df["episode"] >= 24)]  # last 20% of 30 episodes
    per_seed = [100 * g["success"].mean() for _, g in late.groupby("seed")]
    assert _row(table, "train_success_late", "apac", "changing_target")["mean"] == pytest.approx(np.mean(per_seed))
    frac = [100 * g["habit_actions"].sum() / g["steps"].sum() for _, g in late.groupby("seed")]
    assert _row(table, "habit_fraction_late", "apac", "changing_target")["mean"] == pytest.approx(np.mean(frac))
    time = [(g["habit_actions"] + 3 * g["planning_actions"]).mean() for _, g in late.groupby("seed")]
    assert _row(table, "time_late", "apac", "changing_target")["mean"] == pytest.approx(np.mean(time))


def test_test_time_habit_share_and_estimate_error_match_parquet(made) -> None:
    """Fig. 11's quantities: per seed from the test grid's rows, then the mean over seeds."""
    results, out = made
    table = key_table(out)
    df = pd.read_parquet(results / "apac__changing_target" / "eval" / "grid.parquet")
    per = df.groupby("seed")
    time = [g["time_cost"].mean() for _, g in per]
    habit = [100 * g["habit_actions"].sum() / (g["habit_actions"] + g["planning_actions"]).sum() for _, g in per]
    error = [g["estimate_error"].mean() for _, g in per]
    assert _row(table, "test_time", "apac", "changing_target")["mean"] == pytest.approx(np.mean(time))
    assert _row(table, "test_habit_fraction", "apac", "changing_target")["mean"] == pytest.approx(np.mean(habit))
    assert _row(table, "test_estimate_error", "apac", "changing_target")["mean"] == pytest.approx(np.mean(error))
    assert not ((table["quantity"] == "test_habit_fraction") & (table["agent"] == "spac")).any(), \
        "a kind that never arbitrates has no habit share"
    metrics = pd.read_parquet(results / "apac__changing_target" / "metrics.parquet")
    late = metrics[(metrics["phase"] == "train") & (metrics["episode"] >= 24)]
    est = [g["estimate_error"].mean() for _, g in late.groupby("seed")]
    assert _row(table, "estimate_error_late", "apac", "changing_target")["mean"] == pytest.approx(np.mean(est))


def test_occluded_and_generalization_match_parquet(made) -> None:
    results, out = made
    table = key_table(out)
    occ = pd.read_parquet(results / "spac__changing_target_changing_kinematics" / "eval" / "occluded.parquet")
    r = _row(table, "occluded_distance", "spac", "changing_target_changing_kinematics")
    assert r["mean"] == pytest.approx(occ.groupby("seed")["final_distance"].mean().mean())
    judged = occ[occ["judged_reached"]]
    r = _row(table, "occluded_distance_judged", "spac", "changing_target_changing_kinematics")
    assert r["mean"] == pytest.approx(judged.groupby("seed")["final_distance"].mean().mean())
    assert r["paper"] == "~0.7 cm"  # the paper's band: distances when the forward model judged the target reached
    r = _row(table, "occluded_judged_rate", "spac", "changing_target_changing_kinematics")
    assert r["mean"] == pytest.approx(100 * occ.groupby("seed")["judged_reached"].mean().mean())
    assert not (table["quantity"].eq("occluded_distance") & table["agent"].eq("ddpg")).any()
    gen = pd.read_parquet(results / "ddpg__static_target_train_region" / "eval" / "generalization.parquet")
    r = _row(table, "generalization_success", "ddpg", "static_target")
    assert r["mean"] == pytest.approx(100 * gen.groupby("seed")["success"].mean().mean())
    assert _row(table, "generalization_targets", "ddpg", "static_target")["mean"] == 39


def test_load_results_is_tidy(made) -> None:
    results, _ = made
    df = load_results(results)
    assert not df.duplicated(["agent", "condition", "region", "seed", "episode"]).any()
    assert set(df["region"]) == {"all", "train"}
    tests = load_tests(results)
    assert set(tests["protocol"]) == {"grid", "occluded", "generalization"}
    assert set(tests.loc[tests["protocol"] == "occluded", "agent"]) == {"spac", "apac"}


def test_intervals_respect_the_quantity(made) -> None:
    """Rates stay in [0, 100] and distances >= 0 however few the seeds; rates contain the pooled count's
    Wilson interval (computed here by scipy)."""
    results, out = made
    table = key_table(out)
    for r in table.itertuples():
        if math.isnan(r.ci95_low):
            continue
        assert r.ci95_low <= r.mean <= r.ci95_high, r
        if r.unit == "%":
            assert 0 <= r.ci95_low and r.ci95_high <= 100, r
        if r.unit in ("cm", "steps", "habit-step units"):
            assert r.ci95_low >= 0, r
    df = pd.read_parquet(results / "apac__changing_target" / "eval" / "grid.parquet")
    wilson = scipy_stats.binomtest(int(df["success"].sum()), len(df)).proportion_ci(0.95, method="wilson")
    r = _row(table, "test_success", "apac", "changing_target")
    assert r["ci95_low"] <= 100 * wilson.low + 1e-9 and r["ci95_high"] >= 100 * wilson.high - 1e-9
    assert r["samples"] == len(df) and r["per_seed"].count(":") == 3


def test_extreme_rates_and_distances_stay_in_range() -> None:
    """What the Student-t interval got wrong (issue 11): [97.05, 101.83] %, [-2.56, 7.00] %, [-2.02, 13.59] cm."""
    assert t_interval([100, 100, 96.0])[2] > 100  # the old interval leaves the range
    m, lo, hi = stats.interval([100, 100, 96.0], k=[100, 100, 96], n=[100, 100, 100])
    assert m == pytest.approx(98.6667) and 0 <= lo < m and hi == 100
    m, lo, hi = stats.interval([0.0, 0.0, 4.0], k=[0, 0, 4], n=[100, 100, 100])
    assert lo == 0 and hi > 4 / 3
    assert t_interval([0.1, 0.2, 11.0])[1] < 0
    m, lo, hi = stats.interval([0.1, 0.2, 11.0], bounds=(0.0, math.inf))
    assert lo == 0 and hi >= 11.0  # issue 41: clipped to the range, not to the observed values
    m, lo, hi = stats.interval([100.0, 100.0], k=[100, 100], n=[100, 100])  # issue 41: too few seeds, rates too
    assert m == 100 and math.isnan(lo) and math.isnan(hi)
    assert math.isnan(stats.interval([3.0])[1])  # a single distance has none


def test_bootstrap_matches_the_t_interval_for_many_normal_seeds() -> None:
    v = np.random.default_rng(1).normal(10, 2, size=400)
    _, tlo, thi = t_interval(v)
    blo, bhi = stats.bootstrap_interval(v)
    assert blo == pytest.approx(tlo, abs=0.05) and bhi == pytest.approx(thi, abs=0.05)
    k1, n1, k2, n2 = 56, 70, 48, 80  # Newcombe (1998), example (method 10): 0.0524 to 0.3339
    assert stats.newcombe_interval(k1, n1, k2, n2) == pytest.approx((0.0524, 0.3339), abs=5e-4)


def test_few_samples_are_counted(made, tmp_path) -> None:
    """A mean over 1 of 12 targets says so: in the table (samples, samples_of) and in report.md."""
    results, _ = made
    f = results / "ddpg__changing_target" / "eval" / "grid.parquet"
    df = pd.read_parquet(f)
    df["success"] = False
    df.loc[df.index[0], "success"] = True
    copy = tmp_path / "r"
    import shutil
    shutil.copytree(results, copy)
    df.to_parquet(copy / "ddpg__changing_target" / "eval" / "grid.parquet")
    out = report.write_report(copy, draw=False)
    r = _row(key_table(out), "test_steps_to_reach", "ddpg", "changing_target")
    assert (r["samples"], r["samples_of"], r["n_seeds"]) == (1, 36, 1)
    assert "| 1 | 1* of 36 |" in (out / "report.md").read_text()


def test_differences_of_the_key_comparisons(made) -> None:
    results, out = made
    diffs = pd.read_csv(out / "differences.csv")
    row = diffs[(diffs["quantity"] == "test_success") & (diffs["comparison"] == "APAC cs - SPAC cs")].iloc[0]
    a = pd.read_parquet(results / "apac__changing_target" / "eval" / "grid.parquet").groupby("seed")["success"].mean()
    b = pd.read_parquet(results / "spac__changing_target" / "eval" / "grid.parquet").groupby("seed")["success"].mean()
    assert row["difference"] == pytest.approx(100 * (a - b).mean())
    assert -100 <= row["ci95_low"] <= row["difference"] <= row["ci95_high"] <= 100
    assert row["interval"].startswith("paired ")
    assert set(diffs["quantity"]) == {"train_success_late", "test_success", "habit_fraction_late", "time_late",
                                      "test_time"}
    assert "APAC cc - APAC ss" in set(diffs["comparison"])
    row = diffs[(diffs["quantity"] == "test_success") & (diffs["comparison"] == "SPAC cs - DDPG cs")].iloc[0]
    d = pd.read_parquet(results / "ddpg__changing_target" / "eval" / "grid.parquet").groupby("seed")["success"].mean()
    assert row["difference"] == pytest.approx(100 * (b - d).mean())
    row = diffs[(diffs["quantity"] == "test_time") & (diffs["comparison"] == "APAC cs - SPAC cs")].iloc[0]
    ta = pd.read_parquet(results / "apac__changing_target" / "eval" / "grid.parquet").groupby("seed")["time_cost"].mean()
    tb = pd.read_parquet(results / "spac__changing_target" / "eval" / "grid.parquet").groupby("seed")["time_cost"].mean()
    assert row["difference"] == pytest.approx((ta - tb).mean()) and row["unit"] == "habit-step units"
    assert row["ci95_low"] <= row["difference"] <= row["ci95_high"]
    assert "## Key differences" in (out / "report.md").read_text()


def test_figures_show_the_tables_numbers(made, tmp_path, monkeypatch) -> None:
    """Fig. 4's bars and error bars are the table's means and intervals (no clipping); Fig. 9's legend
    numbers are the table's; no title is cut off at the figure's edge."""
    import matplotlib.axes

    results, _ = made
    bars, hlines, figs = [], [], []
    real_bar, real_axhline, real_close = matplotlib.axes.Axes.bar, matplotlib.axes.Axes.axhline, figures.plt.close

    def bar(self, x, height, *a, yerr=None, **k):
        bars.append((np.atleast_1d(np.asarray(height, float)), np.asarray(yerr, float).reshape(2, -1), k.get("label")))
        return real_bar(self, x, height, *a, yerr=yerr, **k)

    def axhline(self, *a, **k):
        hlines.append(k.get("label"))
        return real_axhline(self, *a, **k)

    def close(fig):
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        w, h = fig.bbox.width, fig.bbox.height
        e = fig._suptitle.get_window_extent(renderer)
        figs.append((fig._suptitle.get_text(), e.x0 >= -1 and e.x1 <= w + 1 and e.y1 <= h + 1))
        for ax in fig.axes:  # a panel's title stays within the figure and (nearly) within its panel
            if ax.get_visible():
                e, box = ax.title.get_window_extent(renderer), ax.get_window_extent(renderer)
                figs.append((ax.title.get_text(), e.x0 >= -1 and e.x1 <= w + 1 and e.width <= 1.1 * box.width))
        real_close(fig)

    monkeypatch.setattr(matplotlib.axes.Axes, "bar", bar)
    monkeypatch.setattr(matplotlib.axes.Axes, "axhline", axhline)
    monkeypatch.setattr(figures.plt, "close", close)
    out = report.write_report(results, tmp_path / "rep")
    table = key_table(out)
    sel = table[(table["quantity"] == "test_success") & (table["condition"] == "static_target")]
    height, yerr, label = bars[0]  # Fig. 4's first bar: DDPG on the first condition
    r = sel[sel["agent"] == "ddpg"].iloc[0]
    assert label == "DDPG" and height[0] == pytest.approx(r["mean"])
    assert yerr[:, 0] == pytest.approx([r["mean"] - r["ci95_low"], r["ci95_high"] - r["mean"]])
    dist = _row(table, "occluded_distance_judged", "apac", "changing_target")["mean"]
    assert f"their distance: {dist:.2f} cm" in hlines
    cut = [t for t, inside in figs if not inside]
    assert not cut, cut


def test_no_typos_and_no_empty_panels(tmp_path, capsys) -> None:
    """Fig. 8 is not drawn without generalization cells (report.md says so); no 'kin..', 'over 1 episodes'."""
    results = make_results(tmp_path / "r", seeds=(0, 1), episodes=10)
    for d in results.glob("*_train_region"):
        import shutil
        shutil.rmtree(d)
    out = report.write_report(results)
    md = (out / "report.md").read_text()
    assert not (out / "fig8_generalization.png").exists() and "not drawn, these results have no data" in md
    assert "kin.." not in md and "static kinematics" in md
    assert labels.episodes(1) == "1 episode"
    with pytest.raises(SystemExit):
        main(["report", "--help"])
    assert "95%%" not in capsys.readouterr().out


def test_t_interval() -> None:
    assert t_interval([1.0, 2.0, 3.0]) == pytest.approx((2.0, 2 - 2.4841377, 2 + 2.4841377))
    m, lo, hi = t_interval([5.0])
    assert m == 5.0 and math.isnan(lo) and math.isnan(hi)


def test_report_on_missing_dir_is_a_clear_error(tmp_path, capsys) -> None:
    assert main(["report", str(tmp_path / "nope")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_paper_figures_go_through_the_registry(made, tmp_path) -> None:
    """The paper's figures are registered FigureSpecs, drawn and listed in the published order; a user's
    figure comes after them, and a paper figure can be taken out like any other."""
    results, out = made
    published = FIGURES[:7] + [FIGURES[8], FIGURES[7]]  # the scoreboard (Fig. 11) before the losses (Fig. 10)
    assert [f.file for f in figures.registered_figures()] == published
    md = (out / "report.md").read_text()
    where = [md.index(f"]({f})") for f in published]
    assert where == sorted(where)
    with pytest.raises(ValueError, match="already registered"):
        report.register_figure(figures.registered_figures()[0])
    with pytest.raises(ValueError, match="must end in .png"):
        report.register_figure(report.FigureSpec("fig.gif", "x", lambda data, path: None))
    losses = figures.registered_figures()[-1]
    mine = report.FigureSpec("fig12_mine.png", "Mine.", lambda data, path: path.write_bytes(b"drawn"))
    report.register_figure(mine)
    report.unregister_figure(losses.file)
    try:
        out2 = report.write_report(results, tmp_path / "rep", draw=False)
        md = (out2 / "report.md").read_text()
        assert "fig10_losses.png" not in md and md.index("fig11_scoreboard.png") < md.index("fig12_mine.png")
    finally:
        report.unregister_figure(mine.file)
        report.register_figure(losses)
    assert [f.file for f in figures.registered_figures()][-1] == "fig10_losses.png"
    with pytest.raises(KeyError, match="no figure 'fig12_mine.png' is registered"):
        report.unregister_figure(mine.file)


def test_old_results_without_losses_say_fig10_is_not_drawn(made, tmp_path) -> None:
    import shutil

    results, _ = made
    copy = tmp_path / "old"
    shutil.copytree(results, copy, ignore=shutil.ignore_patterns("report"))
    for f in copy.glob("*/metrics.parquet"):
        pd.read_parquet(f).drop(columns=[c for c, _ in figures.LOSSES]).to_parquet(f)
    md = (report.write_report(copy, draw=False) / "report.md").read_text()
    assert "*Training losses per episode: not drawn, these results have no data for it.*" in md


def test_a_generalization_only_grid_reports_fig8_and_skips_the_training_figures(tmp_path) -> None:
    """The generalization preset has no main-study cells: its report draws Fig. 8 and says the training
    figures have no data (it once stopped at Fig. 3 on an empty training table)."""
    results = make_results(tmp_path / "gen", preset_name="generalization", conditions="", seeds=(0, 1), episodes=6)
    assert not any(d.name.endswith(("__static_target", "__changing_target")) for d in results.iterdir())
    assert main(["report", str(results), "--out", str(tmp_path / "report")]) == 0
    out = tmp_path / "report"
    assert sorted(p.name for p in out.glob("*.png")) == ["fig8_generalization.png"]
    md = (out / "report.md").read_text()
    for skipped in ("Training success rate per episode", "APAC habitual vs planning actions per episode",
                    "Training losses per episode"):
        assert f"*{skipped}: not drawn, these results have no data for it.*" in md
    table = key_table(out)
    gen = table[table["quantity"] == "generalization_success"]
    assert set(gen["condition"]) == {"static_target", "changing_target"} and len(gen) == 6
    tests = load_tests(results)
    for _, row in gen.iterrows():
        sel = tests[(tests["agent"] == row["agent"]) & (tests["condition"] == row["condition"])]
        assert row["mean"] == pytest.approx(100 * sel.groupby("seed")["success"].mean().mean())


@pytest.fixture
def user_tasks():
    """Two user conditions whose names the old colour hash mapped to one colour, and a wider plane for
    changing_target (a task registered at run time shadows the file of the same name)."""
    specs = [TaskSpec(name="user_ab", description="User condition AB."), TaskSpec(name="user_ba", steps_per_episode=12)]
    for spec in specs:
        register_task(spec)
    register_task(load_task("changing_target").replace(plane_size=(40.0, 30.0), origin=(20.0, 15.0)), replace=True)
    yield specs
    for name in ("user_ab", "user_ba", "changing_target"):
        unregister_task(name)


def test_conditions_are_described_by_their_tasks(user_tasks) -> None:
    assert sum(map(ord, "user_ab")) % 6 == sum(map(ord, "user_ba")) % 6  # the collision of the old hash
    colors = labels.condition_colors(["user_ba", "changing_target", "user_ab", "static_target"])
    assert colors == {"static_target": "tab:purple", "changing_target": "tab:olive",
                      "user_ab": labels.EXTRA_COLORS[0], "user_ba": labels.EXTRA_COLORS[1]}
    assert labels.condition_label("user_ab") == "User condition AB." and labels.condition_label("user_ba") == "user_ba"
    assert labels.condition_short("user_ab") == "user_ab" and labels.condition_short("changing_target") == "cs"
    assert labels.condition_label("gone") == "gone"  # a task unknown here: its name and the default spec
    assert labels.condition_spec("gone").plane_size == TaskSpec(name="x").plane_size
    many = [f"user_{i:02d}" for i in range(len(labels.EXTRA_COLORS) + 1)]
    assert len(set(labels.condition_colors(many).values())) == len(labels.EXTRA_COLORS)


def test_judged_reached_of_old_results_uses_each_tasks_step_limit(user_tasks) -> None:
    old = pd.DataFrame({"condition": ["user_ba"] * 3 + ["static_target"] * 2, "steps": [11, 12, 30, 29, 30]})
    assert judged_reached(old).tolist() == [True, False, False, True, False]
    new = old.assign(judged_reached=[False, True, False, False, True])
    assert judged_reached(new).tolist() == new["judged_reached"].tolist()


def test_planes_and_region_maps_come_from_the_tasks(made, tmp_path, monkeypatch, user_tasks) -> None:
    """Fig. 7 spans each condition's plane; Fig. 8 maps the region of each geometry present (one map where
    the conditions agree, as in the paper)."""
    results, _ = made
    metrics, tests = load_results(results), load_tests(results)
    seed_values = per_seed(metrics, tests)
    data = report.ReportData(results, metrics, tests, seed_values, key_numbers(seed_values))
    drawn = []
    monkeypatch.setattr(figures.plt, "close", lambda fig: drawn.append(
        [(ax.get_title(), ax.get_xlim(), ax.get_ylim()) for ax in fig.axes if ax.get_visible()]))
    figures.fig_trajectories(data, tmp_path / "fig7.png")
    limits = {title.split(", ")[1].split(" (")[0]: (x, y) for title, x, y in drawn[-1]}
    assert limits == {"cs": ((0, 40), (0, 30)), "cc": ((0, 30), (0, 30))}  # static targets are not drawn
    figures.fig_generalization(data, tmp_path / "fig8.png")
    maps = [(title, x) for title, x, _ in drawn[-1] if title.endswith("cm")]
    assert maps == [("ss: reachable area, l = (5.0, 8.0) cm", (0, 30)),
                    ("cs: reachable area, l = (5.0, 8.0) cm", (0, 40))]


def test_the_report_leaves_the_matplotlib_backend_alone_at_import() -> None:
    import os
    import subprocess
    import sys

    code = "import apac_mj.report, matplotlib; print(matplotlib.get_backend())"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={**os.environ, "MPLBACKEND": "svg"})
    assert out.stdout.strip() == "svg"


def _split_cells(line: str) -> list[str]:
    """A Markdown table row's cells as a renderer splits them: at every ``|`` not escaped by a backslash."""
    import re

    return [c.strip() for c in re.split(r"(?<!\\)\|", line.strip())[1:-1]]


def test_table_cells_with_a_pipe_keep_the_columns(made) -> None:
    """'|estimate - truth|' in a description is escaped: every row has the header's columns, and the cell
    reads back as written."""
    _, out = made
    md = (out / "report.md").read_text().splitlines()
    for start in (md.index("## Key numbers"), md.index("## Key differences")):
        first = next(i for i in range(start, len(md)) if md[i].startswith("|"))
        end = next((i for i in range(first, len(md)) if not md[i].startswith("|")), len(md))
        rows = md[first:end]
        width = len(_split_cells(rows[0]))
        assert all(len(_split_cells(r)) == width for r in rows), [r for r in rows if len(_split_cells(r)) != width]
    error_rows = [r for r in md if "estimate - truth" in r]
    assert error_rows and all("\\|estimate - truth\\|" in r for r in error_rows)
    assert _split_cells(error_rows[0])[1].replace("\\|", "|").startswith("state-estimate error |estimate - truth|")


def test_repeated_identical_test_episodes_count_once(made, tmp_path) -> None:
    """A static target tested 100 times per seed by a frozen network is one outcome per seed: 3 seeds that
    all reach it give 3 samples and the Wilson interval of 3 of 3 ([43.85, 100]), not of 300 of 300
    ([98.74, 100]). Distinct targets, and noisy vision's episodes, keep counting each."""
    import shutil

    results, _ = made
    copy = tmp_path / "r"
    shutil.copytree(results, copy)
    f = copy / "ddpg__static_target" / "eval" / "grid.parquet"
    df = pd.read_parquet(f)
    same = pd.concat([df[df["seed"] == s].iloc[[0] * 100] for s in (0, 1, 2)], ignore_index=True)
    same["target_index"], same["success"] = np.tile(np.arange(100), 3), True
    same.to_parquet(f)
    out = report.write_report(copy, draw=False)
    table = key_table(out)
    r = _row(table, "test_success", "ddpg", "static_target")
    lo, hi = stats.wilson_interval(3, 3)
    assert (r["mean"], r["samples"]) == (100.0, 3)
    assert r["ci95_low"] == pytest.approx(100 * lo) and r["ci95_low"] == pytest.approx(43.85, abs=0.01)
    assert _row(table, "test_steps_to_reach", "ddpg", "static_target")["samples"] == 3
    assert _row(table, "test_success", "ddpg", "changing_target")["samples"] == 36  # 12 distinct targets x 3
    noisy = same.assign(condition="changing_target_noisy", agent="ddpg")  # repeated targets, noisy vision
    assert len(quantities.distinct_episodes(noisy)) == 300 and len(quantities.distinct_episodes(
        same.assign(condition="static_target", agent="ddpg"))) == 3


def test_scoreboard_draws_float32_noise_as_zero_and_labels_each_bar(made, tmp_path, monkeypatch) -> None:
    """Fig. 11: a state-estimate error of 5e-7 cm (float32 rounding under perfect vision) is a zero bar on
    an axis of at least 0.05 cm, not a difference; each count sits under its own bar and no two overlap;
    every bar of a condition is centred on its tick."""
    import matplotlib.axes

    results, _ = made
    seed_values = per_seed(load_results(results), load_tests(results))
    tiny = (seed_values["quantity"] == "test_estimate_error") & (seed_values["condition"] == "static_target")
    seed_values.loc[tiny, "value"] = 5e-7 + 1e-8 * seed_values.loc[tiny, "seed"]
    table = key_numbers(seed_values)
    bars = []
    real_bar = matplotlib.axes.Axes.bar

    def bar(self, x, height, *a, **k):
        bars.append((self, float(x), float(height)))
        return real_bar(self, x, height, *a, **k)

    monkeypatch.setattr(matplotlib.axes.Axes, "bar", bar)
    closed = []
    monkeypatch.setattr(figures.plt, "close", lambda fig: closed.append(fig))
    rd = figures.ReportData(results=results, metrics=load_results(results), tests=load_tests(results),
                            seed_values=seed_values, table=table)
    figures.fig_scoreboard(rd, tmp_path / "fig11.png")
    fig = closed[0]
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    error_ax = next(ax for ax in fig.axes if ax.get_title().startswith("state-estimate error"))
    conds = [t.get_text() for t in error_ax.get_xticklabels()]
    first = [h for ax, x, h in bars if ax is error_ax and abs(x - 0) < 0.45]  # the static target's bars
    assert conds[0] == "ss" and first and all(h == 0.0 for h in first)
    assert error_ax.get_ylim()[1] >= figures.CM_AXIS_MIN
    for ax in fig.axes:
        xs = sorted(x for a, x, _ in bars if a is ax)
        for c in range(len(ax.get_xticks())):
            group = [x for x in xs if abs(x - c) < 0.45]
            assert not group or abs(np.mean(group) - c) < 1e-9  # centred on the condition's tick
        labels_ = [t for t in ax.get_xticklabels(minor=True) if t.get_text()]
        if labels_:
            assert sorted(t.get_position()[0] for t in labels_) == pytest.approx(xs)
            boxes = sorted((t.get_window_extent(renderer) for t in labels_), key=lambda b: b.x0)
            assert all(a.x1 <= b.x0 + 0.5 for a, b in zip(boxes, boxes[1:])), "count labels overlap"
    figures.plt.close("all")


def test_several_results_directories_report_as_one(tmp_path, capsys) -> None:
    """Cells of one study run as separate grids: `report A B --out R` equals the report of one directory
    holding all the cells; a cell in two of them, or several directories without --out, is refused."""
    import json
    import shutil

    results = make_results(tmp_path / "all", seeds=(0, 1), episodes=6)
    a, b = tmp_path / "a", tmp_path / "b"
    cells = sorted(d.name for d in results.iterdir() if (d / "cell.json").exists())
    for i, name in enumerate(cells):
        shutil.copytree(results / name, (a if i % 2 else b) / name)
    (a / "manifest.json").write_text(json.dumps({"preset": {"name": "smoke", "description": "half the cells"}}))
    both = report.write_report([a, b], tmp_path / "both", draw=False)
    one = report.write_report(results, tmp_path / "one", draw=False)
    pd.testing.assert_frame_equal(key_table(both), key_table(one))
    pd.testing.assert_frame_equal(pd.read_csv(both / "differences.csv"), pd.read_csv(one / "differences.csv"))
    assert "Read from 2 results directories, `a`: half the cells; `b`" in (both / "report.md").read_text()
    prepared = b / cells[1]  # a cell a stopped grid only prepared (cell.json, no metrics) gives way
    prepared.mkdir()
    shutil.copy(results / cells[1] / "cell.json", prepared / "cell.json")
    again = report.write_report([a, b], tmp_path / "again", draw=False)
    pd.testing.assert_frame_equal(key_table(again), key_table(one))
    shutil.copytree(results / cells[0], a / cells[0], dirs_exist_ok=True)  # now with results in both
    assert main(["report", str(a), str(b), "--out", str(tmp_path / "dup")]) == 2
    err = capsys.readouterr().err
    assert f"the cell {cells[0]} has results in two of the results directories given" in err
    assert not (tmp_path / "dup").exists()
    assert main(["report", str(a), str(b)]) == 2
    assert "several results directories need --out" in capsys.readouterr().err


def _drawn(draw, results: Path, tmp_path: Path, monkeypatch, table_edit=None):
    """The figure ``draw`` (a figures.fig_* function) makes of ``results``, drawn and left open; ``table_edit``
    changes the key-number table first."""
    metrics, tests = load_results(results), load_tests(results)
    seed_values = per_seed(metrics, tests)
    table = key_numbers(seed_values)
    if table_edit is not None:
        table = table_edit(table)
    closed = []
    monkeypatch.setattr(figures.plt, "close", lambda fig: closed.append(fig))
    draw(figures.ReportData(results, metrics, tests, seed_values, table), tmp_path / "figure.png")
    closed[0].canvas.draw()
    return closed[0]


def test_fig4_shows_every_agents_reached_count(tmp_path, monkeypatch) -> None:
    """Fig. 4 writes reached/tested under every bar, the middle agent's (SPAC's) too: its bar sits on the
    condition's tick, where matplotlib drops a minor tick by default (4 of 12 counts were missing)."""
    import matplotlib.text

    results = make_results(tmp_path / "r", seeds=(0, 1), episodes=6)

    def distinct(table: pd.DataFrame) -> pd.DataFrame:  # a count per bar that no other bar has
        steps = table["quantity"] == "test_steps_to_reach"
        return table.assign(samples=np.where(steps, 100 + np.arange(len(table)), table["samples"]))

    fig = _drawn(figures.fig_test, results, tmp_path, monkeypatch, distinct)
    texts = {t.get_text() for t in fig.findobj(matplotlib.text.Text) if t.get_visible()}
    steps = distinct(key_numbers(per_seed(load_results(results), load_tests(results))))
    steps = steps[steps["quantity"] == "test_steps_to_reach"]
    assert set(steps["agent"]) == {"ddpg", "spac", "apac"} and len(steps) == 9
    missing = [(r["agent"], r["condition"]) for _, r in steps.iterrows()
               if f"{int(r['samples'])}/{int(r['samples_of'])}" not in texts]
    assert not missing, f"counts not shown: {missing}"
    figures.plt.close("all")


def test_fig5_of_a_short_run_lays_out_without_warnings(tmp_path, monkeypatch) -> None:
    """Fig. 5 of a run too short for any seed to turn habitual: constrained layout applies (no 'not applied'
    warning; an empty unclipped line of crossing ticks once collapsed it) and the suptitle sits above every
    panel's title."""
    import warnings

    results = make_results(tmp_path / "r", seeds=(0, 1), episodes=6)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fig = _drawn(figures.fig_arbitration, results, tmp_path, monkeypatch)
        fig.savefig(tmp_path / "again.png")
    renderer = fig.canvas.get_renderer()
    suptitle = fig._suptitle.get_window_extent(renderer)
    titles = [ax.title.get_window_extent(renderer) for ax in fig.axes if ax.get_visible()]
    assert len(titles) == 3 and all(t.y1 <= suptitle.y0 for t in titles)
    figures.plt.close("all")


# -- measured decision times (issue 28) -----------------------------------------------------------------

MEASURED_QUANTITIES = {"decision_ms_late", "planning_ms_late", "plan_iterations_late", "measured_planning_ratio"}


def test_measured_planning_ratio_of_a_hand_made_frame() -> None:
    """The late window (last 20% of 10 episodes: 8 and 9) of a hand-made metrics frame, computed by hand:
    per seed the mean decision time per episode (ms), its planning part, the iterations per episode and
    (planning seconds / planning actions) / (habit seconds / habit actions). A seed that never planned has
    no ratio; SPAC, which never acts by habit, has none at all; rows before the timing (NaN) do not count."""
    rows = []
    for agent in ("apac", "spac"):
        for seed in (0, 1):
            for ep in range(10):
                rows.append(dict(agent=agent, condition="changing_target", region="all", seed=seed, episode=ep,
                                 phase="train", success=True, steps=5, habit_actions=5 if agent == "apac" else 0,
                                 planning_actions=0 if agent == "apac" else 5, habit_seconds=math.nan,
                                 planning_seconds=math.nan, plan_iterations=math.nan))
    m = pd.DataFrame(rows)
    late = {(0, 8): (3, 2, 0.003, 0.012, 2), (0, 9): (4, 1, 0.005, 0.004, 1),  # seed 0 of APAC used both kinds
            (1, 8): (5, 0, 0.006, 0.0, 0), (1, 9): (5, 0, 0.004, 0.0, 0)}      # seed 1 only the habit
    for (seed, ep), (h, p, hs, ps, it) in late.items():
        sel = (m.agent == "apac") & (m.seed == seed) & (m.episode == ep)
        m.loc[sel, ["habit_actions", "planning_actions", "habit_seconds", "planning_seconds", "plan_iterations"]] = \
            [h, p, hs, ps, it]
    spac_late = (m.agent == "spac") & (m.episode >= 8)
    m.loc[spac_late, ["habit_seconds", "planning_seconds", "plan_iterations"]] = [0.0, 0.02, 5]
    m.loc[(m.agent == "apac") & (m.episode == 3), ["habit_seconds", "planning_seconds", "plan_iterations"]] = \
        [9.0, 9.0, 99]  # before the late window: does not count
    values = per_seed(m, pd.DataFrame())

    def value(q: str, agent: str, seed: int) -> float:
        sel = values[(values.quantity == q) & (values.agent == agent) & (values.seed == seed)]
        assert len(sel) == 1, (q, agent, seed)
        return float(sel["value"].iloc[0])

    assert value("measured_planning_ratio", "apac", 0) == pytest.approx((0.016 / 3) / (0.008 / 7))  # 4.667
    assert math.isnan(value("measured_planning_ratio", "apac", 1))
    assert not ((values.quantity == "measured_planning_ratio") & (values.agent == "spac")).any()
    assert value("decision_ms_late", "apac", 0) == pytest.approx((15 + 9) / 2)
    assert value("planning_ms_late", "apac", 0) == pytest.approx((12 + 4) / 2)
    assert value("plan_iterations_late", "apac", 0) == pytest.approx(1.5)
    assert value("decision_ms_late", "apac", 1) == pytest.approx(5.0)
    assert value("decision_ms_late", "spac", 0) == pytest.approx(20.0)
    assert value("plan_iterations_late", "spac", 1) == pytest.approx(5.0)
    ratio = values[(values.quantity == "measured_planning_ratio") & (values.seed == 0)].iloc[0]
    assert ratio["n"] == 10  # the actions behind it
    table = key_numbers(values)
    r = _row(table, "measured_planning_ratio", "apac", "changing_target")
    assert (r["figure"], r["unit"], r["n_seeds"]) == ("Fig. 6", "x", 1) and r["paper"].startswith("3")
    assert r["mean"] == pytest.approx(0.112 / 0.024) and r["per_seed"] == "0: 4.67; 1: nan"


@pytest.fixture(scope="module")
def timed_results(tmp_path_factory) -> Path:
    return make_results(tmp_path_factory.mktemp("timed"), seeds=(0, 1), episodes=10, timed=True)


def test_measured_decision_times_reach_the_table(timed_results) -> None:
    """Results with the measured columns: each (agent, condition) gets the decision times, iterations and
    (where it used both kinds of action: the arbitrating kinds) the measured planning/habit ratio, each a
    mean over seeds of the per-seed values with the report's bootstrap interval; report.md lists them."""
    out = report.write_report(timed_results, draw=False)
    table = key_table(out)
    assert MEASURED_QUANTITIES <= set(table["quantity"])
    assert set(table.loc[table["quantity"] == "measured_planning_ratio", "agent"]) == {"apac"}
    assert {"ddpg", "spac", "apac"} == set(table.loc[table["quantity"] == "decision_ms_late", "agent"])
    df = pd.read_parquet(timed_results / "apac__changing_target" / "metrics.parquet")
    late = df[(df["phase"] == "train") & (df["episode"] >= 8)]
    per = late.groupby("seed")
    ms = [1e3 * (g["habit_seconds"] + g["planning_seconds"]).mean() for _, g in per]
    ratio = [(g["planning_seconds"].sum() / g["planning_actions"].sum())
             / (g["habit_seconds"].sum() / g["habit_actions"].sum()) for _, g in per]
    r = _row(table, "decision_ms_late", "apac", "changing_target")
    assert (r["mean"], r["unit"], r["samples"]) == (pytest.approx(np.mean(ms)), "ms", len(late))
    assert (r["ci95_low"], r["ci95_high"]) == pytest.approx(stats.seed_interval(ms, (0.0, math.inf)), nan_ok=True)
    r = _row(table, "measured_planning_ratio", "apac", "changing_target")
    assert r["mean"] == pytest.approx(np.mean(ratio)) and 1 < r["mean"] < 10
    assert _row(table, "planning_ms_late", "apac", "changing_target")["mean"] == pytest.approx(
        np.mean([1e3 * g["planning_seconds"].mean() for _, g in per]))
    assert _row(table, "plan_iterations_late", "apac", "changing_target")["mean"] == pytest.approx(
        np.mean([g["plan_iterations"].mean() for _, g in per]))
    assert _row(table, "planning_ms_late", "ddpg", "changing_target")["mean"] == 0
    md = (out / "report.md").read_text()
    assert "measured time per planning action / per habitual action" in md


def _fig6_rows(fig) -> list[list[str]]:
    """Fig. 6's visible panels' titles, row by row (top first)."""
    panels = [ax for ax in fig.axes if ax.get_visible()]
    tops = sorted({round(ax.get_position().y0, 3) for ax in panels}, reverse=True)
    return [[ax.get_title() for ax in panels if round(ax.get_position().y0, 3) == y] for y in tops]


def test_fig6_adds_the_measured_row_with_each_agents_ratio(timed_results, tmp_path, monkeypatch) -> None:
    """With the measured columns Fig. 6 has a third row: the decision time per episode (ms) per agent, titled
    with each agent's measured planning/habit time per action (the table's) beside the paper's 3."""
    import matplotlib.lines

    fig = _drawn(figures.fig_steps_time, timed_results, tmp_path, monkeypatch)
    rows = _fig6_rows(fig)
    assert len(rows) == 3 and all(len(r) == 3 for r in rows)
    table = key_numbers(per_seed(load_results(timed_results), load_tests(timed_results)))
    for title, cond in zip(rows[2], ("static_target", "changing_target", "changing_target_changing_kinematics")):
        ratio = _row(table, "measured_planning_ratio", "apac", cond)["mean"]
        words = " ".join(title.split())
        assert f"measured planning/habit time per action: APAC {ratio:.1f}x (paper: 3x)" in words, words
    bottom = [ax for ax in fig.axes if ax.get_visible() and ax.get_ylabel().startswith("measured decision time")]
    assert len(bottom) == 3
    metrics = load_results(timed_results)
    top = metrics[(metrics["phase"] == "train") & (metrics["agent"] == "spac")
                  & (metrics["condition"] == "changing_target") & (metrics["region"] == "all")]
    mean_ms = 1e3 * (top["habit_seconds"] + top["planning_seconds"]).groupby(top["episode"]).mean()
    spac = [ln for ln in bottom[1].get_lines() if ln.get_label() == "SPAC"]
    assert len(spac) == 1 and isinstance(spac[0], matplotlib.lines.Line2D)
    assert spac[0].get_ydata()[0] == pytest.approx(mean_ms.iloc[0])  # the moving average starts at episode 0's mean
    assert "measured" in fig._suptitle.get_text()
    figures.plt.close("all")


def test_results_without_measured_times_keep_fig6_and_the_table_as_they_were(made, tmp_path, monkeypatch) -> None:
    """Results from before the measured columns: no measured quantity, Fig. 6 the paper's two rows with its
    old title; a cell without them among cells with them (an older run in the grid) gets no measured line."""
    results, out = made
    assert not MEASURED_QUANTITIES & set(key_table(out)["quantity"])
    fig = _drawn(figures.fig_steps_time, results, tmp_path, monkeypatch)
    assert len(_fig6_rows(fig)) == 2
    assert fig._suptitle.get_text().replace("\n", " ").startswith("Fig. 6: steps and time per episode")
    assert "measured" not in fig._suptitle.get_text()
    figures.plt.close("all")
    import shutil

    mixed = tmp_path / "mixed"
    shutil.copytree(results, mixed, ignore=shutil.ignore_patterns("report"))
    f = mixed / "apac__changing_target" / "metrics.parquet"
    m = pd.read_parquet(f)
    m.assign(habit_seconds=1e-3 * m["habit_actions"], planning_seconds=4e-3 * m["planning_actions"],
             plan_iterations=m["planning_actions"]).to_parquet(f)
    table = key_numbers(per_seed(load_results(mixed), load_tests(mixed)))
    cells = table[table["quantity"] == "decision_ms_late"][["agent", "condition"]].values.tolist()
    assert cells == [["apac", "changing_target"]]
    assert _row(table, "measured_planning_ratio", "apac", "changing_target")["mean"] == pytest.approx(4.0)
    fig = _drawn(figures.fig_steps_time, mixed, tmp_path, monkeypatch)
    rows = _fig6_rows(fig)
    assert len(rows) == 3 and "APAC 4.0x (paper: 3x)" in " ".join(rows[2][1].split())
    assert "no agent used both" in " ".join(rows[2][0].split())
    figures.plt.close("all")
