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
from scipy import stats

from apac_mj import grid, report
from apac_mj.cli import main

FIGURES = ["fig3_training_success.png", "fig4_test.png", "fig5_arbitration.png", "fig6_steps_time.png",
           "fig7_trajectories.png", "fig8_generalization.png", "fig9_occluded.png", "fig10_losses.png"]


def _metrics(rng: np.random.Generator, agent: str, seeds, episodes: int) -> pd.DataFrame:
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
                             forward_loss=float(rng.random()), inverse_loss=float(rng.random() * 100)))
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
                       judged_reached=bool(steps < 30 and rng.random() < 0.8))
            if with_path:
                row.update(path_x=list(rng.random(steps + 1) * 30), path_y=list(rng.random(steps + 1) * 30))
            rows.append(row)
    return pd.DataFrame(rows)


def make_results(root: Path, seed: int = 0, seeds=(0, 1, 2), episodes: int = 30) -> Path:
    """A results directory with every cell of a small grid filled with random contract-shaped data."""
    rng = np.random.default_rng(seed)
    preset = grid.load_preset("smoke", [f"seeds={list(seeds)}", f"episodes={episodes}",
                                        "conditions=static_target,changing_target,changing_target_changing_kinematics",
                                        "tests.generalization_conditions=static_target,changing_target"])
    for cell in grid.cells(preset):
        d = grid.prepare_cell(cell, preset, root)
        _metrics(rng, cell.agent, seeds, episodes).to_parquet(d / "metrics.parquet")
        (d / "eval").mkdir()
        for protocol in cell.protocols:
            n = 39 if protocol == "generalization" else 12
            _eval(rng, seeds, n, protocol == "grid").to_parquet(d / "eval" / f"{protocol}.parquet")
        (d / "eval" / "summary.json").write_text("{}")
        (d / "DONE").write_text("")
    return root


def _ci(values) -> tuple[float, float, float]:
    v = np.asarray(values, float)
    h = stats.t.ppf(0.975, len(v) - 1) * v.std(ddof=1) / math.sqrt(len(v))
    return v.mean(), v.mean() - h, v.mean() + h


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
    table = report.load_key_numbers(out)
    md = (out / "report.md").read_text()
    for agent in ("ddpg", "spac", "apac"):
        for cond in ("static_target", "changing_target"):
            df = pd.read_parquet(results / f"{agent}__{cond}" / "eval" / "grid.parquet")
            m, lo, hi = _ci([100 * g["success"].mean() for _, g in df.groupby("seed")])
            r = _row(table, "test_success", agent, cond)
            assert (r["mean"], r["ci95_low"], r["ci95_high"]) == pytest.approx((m, lo, hi))
            assert f"| {m:.2f} | [{lo:.2f}, {hi:.2f}] |" in md


def test_training_and_arbitration_match_parquet(made) -> None:
    results, out = made
    table = report.load_key_numbers(out)
    df = pd.read_parquet(results / "apac__changing_target" / "metrics.parquet")
    late = df[(df["phase"] == "train") & (df["episode"] >= 24)]  # last 20% of 30 episodes
    per_seed = [100 * g["success"].mean() for _, g in late.groupby("seed")]
    assert _row(table, "train_success_late", "apac", "changing_target")["mean"] == pytest.approx(np.mean(per_seed))
    frac = [100 * g["habit_actions"].sum() / g["steps"].sum() for _, g in late.groupby("seed")]
    assert _row(table, "habit_fraction_late", "apac", "changing_target")["mean"] == pytest.approx(np.mean(frac))
    time = [(g["habit_actions"] + 3 * g["planning_actions"]).mean() for _, g in late.groupby("seed")]
    assert _row(table, "time_late", "apac", "changing_target")["mean"] == pytest.approx(np.mean(time))


def test_occluded_and_generalization_match_parquet(made) -> None:
    results, out = made
    table = report.load_key_numbers(out)
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
    df = grid.load_results(results)
    assert not df.duplicated(["agent", "condition", "region", "seed", "episode"]).any()
    assert set(df["region"]) == {"all", "train"}
    tests = grid.load_tests(results)
    assert set(tests["protocol"]) == {"grid", "occluded", "generalization"}
    assert set(tests.loc[tests["protocol"] == "occluded", "agent"]) == {"spac", "apac"}


def test_t_interval() -> None:
    assert report.t_interval([1.0, 2.0, 3.0]) == pytest.approx((2.0, 2 - 2.4841377, 2 + 2.4841377))
    m, lo, hi = report.t_interval([5.0])
    assert m == 5.0 and math.isnan(lo) and math.isnan(hi)


def test_report_on_missing_dir_is_a_clear_error(tmp_path, capsys) -> None:
    assert main(["report", str(tmp_path / "nope")]) == 2
    assert "does not exist" in capsys.readouterr().err
