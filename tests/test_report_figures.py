"""Issue 45: the report's colours and labels, the figures' layouts, --format/--dpi, one run's curves, evaluate's
table, and a report that refuses damaged tables and says when a grid is partial.

The figures are checked as objects (axes, lines, markers, legends), not as pixels. The results are synthesized
run directories (tests/test_report.py's helpers) with random but known data.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import matplotlib
import numpy as np
import pandas as pd
import pytest
from test_report import _eval, _metrics

from apac_mj import kinds
from apac_mj.agent.arbitration import DeltaArbitrator
from apac_mj.cli import main
from apac_mj.experiments import grid
from apac_mj.experiments.presets import load_preset
from apac_mj.experiments.results import load_results, load_tests
from apac_mj.report import figures, labels, write_report
from apac_mj.report.quantities import key_numbers, per_seed

matplotlib.use("Agg")

#: Okabe & Ito's and Paul Tol's "muted" colour-blind-safe palettes, as published (the test's own copy).
OKABE_ITO = {"#E69F00", "#56B4E9", "#009E73", "#F0E442", "#0072B2", "#D55E00", "#CC79A7", "#000000"}
TOL_MUTED = {"#332288", "#88CCEE", "#44AA99", "#117733", "#999933", "#DDCC77", "#CC6677", "#882255", "#AA4499"}


def make_grid(root: Path, agents: str = "ddpg,spac,apac", conditions: str = "changing_target",
              seeds=(0, 1), episodes: int = 8, manifest: bool = False) -> Path:
    """A small results directory of random contract-shaped data; ``manifest``: with the grid's manifest.json
    and each cell's eval/summary.json counting its test rows, as apac-mj grid writes them."""
    rng = np.random.default_rng(0)
    preset = load_preset("smoke", [f"seeds={list(seeds)}", f"episodes={episodes}", f"conditions={conditions}",
                                   f"agents={agents}"])
    cells = grid.cells(preset)
    for cell in cells:
        d = grid.prepare_cell(cell, preset, root)
        _metrics(rng, cell.agent, seeds, episodes).to_parquet(d / "metrics.parquet")
        (d / "eval").mkdir()
        summary: dict = {"protocols": {}}
        for protocol in cell.protocols:
            df = _eval(rng, seeds, 6, protocol == "grid")
            df.to_parquet(d / "eval" / f"{protocol}.parquet")
            summary["protocols"][protocol] = {"applicable": True, "episodes": len(df)}
        (d / "eval" / "summary.json").write_text(json.dumps(summary if manifest else {}))
        (d / "DONE").write_text("")
    if manifest:
        (root / "manifest.json").write_text(json.dumps(
            {"preset": {"name": "smoke"}, "cells": {c.name: {"agent": c.agent, "status": "done"} for c in cells}}))
    return root


def drawn(draw, results: Path, tmp_path: Path, monkeypatch, table_edit=None) -> matplotlib.figure.Figure:
    """The figure ``draw`` (a figures.fig_* function) makes of ``results``, left open."""
    metrics, tests = load_results(results), load_tests(results)
    seed_values = per_seed(metrics, tests)
    table = key_numbers(seed_values)
    table = table_edit(table) if table_edit else table
    closed = []
    monkeypatch.setattr(figures.plt, "close", lambda fig: closed.append(fig))
    draw(figures.ReportData(results, metrics, tests, seed_values, table), tmp_path / "figure.png")
    closed[0].canvas.draw()
    return closed[0]


def legend_texts(ax) -> list[str]:
    return [t.get_text() for t in ax.get_legend().get_texts()] if ax.get_legend() else []


@pytest.fixture(scope="module")
def three_agents(tmp_path_factory) -> Path:
    return make_grid(tmp_path_factory.mktemp("one_condition"))


# -- item 2 of the new user: colours ------------------------------------------------------

@pytest.fixture
def user_kind():
    kinds.register(kinds.AgentKind("apac_user45", "APAC (user)", "tab:purple", arbitrator=DeltaArbitrator))
    yield "apac_user45"
    kinds.unregister("apac_user45")


def test_every_registered_kind_has_its_own_colour_blind_safe_colour(user_kind) -> None:
    colors = {name: labels.AGENT_COLOR[name] for name in kinds.names()}
    assert user_kind in colors and len(colors) == len(kinds.names()) >= 11
    assert len(set(colors.values())) == len(colors), colors  # DDPG and APAC-VOC were both orange
    assert set(colors.values()) <= OKABE_ITO | TOL_MUTED, colors
    assert colors["ddpg"] != colors["apac_voc"]
    assert (colors["ddpg"], colors["spac"], colors["apac"]) == ("#E69F00", "#009E73", "#0072B2")


def test_a_kind_registered_with_a_palette_colour_keeps_it(user_kind) -> None:
    kinds.register(kinds.AgentKind("apac_user45", "APAC (user)", "#aa4499", arbitrator=DeltaArbitrator),
                   replace=True)
    assert labels.AGENT_COLOR["apac_user45"] == "#AA4499"
    assert len(set(labels.AGENT_COLOR.values())) == len(kinds.names())


# -- item 3: Fig. 5's planner label ---------------------------------------------------------

def test_fig5_names_each_kinds_own_planner(tmp_path, monkeypatch) -> None:
    results = make_grid(tmp_path / "r", agents="apac,apac_voc")
    fig = drawn(figures.fig_arbitration, results, tmp_path, monkeypatch)
    rows = {ax.get_title().split(",")[0]: legend_texts(ax) for ax in fig.axes}
    assert "planning (inverse model)" in rows["APAC"]
    voc = rows[labels.AGENT_LABEL["apac_voc"]]
    assert "planning (MPC through the forward model)" in voc and "planning (inverse model)" not in voc


# -- item 5: the figures ----------------------------------------------------------------------

def test_fig3_with_one_condition_is_one_panel_with_every_agent(three_agents, tmp_path, monkeypatch) -> None:
    fig = drawn(figures.fig_training_success, three_agents, tmp_path, monkeypatch)
    visible = [ax for ax in fig.get_axes() if ax.get_visible()]
    assert len(fig.get_axes()) == len(visible) == 1  # no repeated line in three panels, no empty slot
    assert legend_texts(visible[0]) == ["DDPG", "SPAC", "APAC"]


def test_fig3_rows_keep_their_own_width(tmp_path, monkeypatch) -> None:
    results = make_grid(tmp_path / "r", agents="spac,apac", conditions="static_target,changing_target,"
                                                                     "changing_target_changing_kinematics")
    fig = drawn(figures.fig_training_success, results, tmp_path, monkeypatch)
    assert len(fig.get_axes()) == 2 + 3 and all(ax.get_visible() for ax in fig.get_axes())
    one_agent = make_grid(tmp_path / "one", agents="apac", conditions="static_target,changing_target")
    fig = drawn(figures.fig_training_success, one_agent, tmp_path, monkeypatch)
    assert len(fig.get_axes()) == 1 and fig.get_axes()[0].get_title().startswith("APAC")


def test_fig7_draws_reached_and_missed_targets_differently(three_agents, tmp_path, monkeypatch) -> None:
    fig = drawn(figures.fig_trajectories, three_agents, tmp_path, monkeypatch)
    tests = load_tests(three_agents)
    for ax in fig.axes:
        texts = legend_texts(ax)
        reached = [t for t in texts if t.startswith("target reached")]
        missed = [t for t in texts if t.startswith("target missed")]
        agent = next(a for a in kinds.names() if ax.get_title().startswith(labels.AGENT_LABEL[a] + ","))
        sel = tests[(tests["protocol"] == "grid") & (tests["agent"] == agent)]
        assert reached == [f"target reached ({int(sel['success'].sum())} of {len(sel)})"]
        assert missed == [f"target missed ({int((~sel['success']).sum())} of {len(sel)})"]
        offsets = [len(c.get_offsets()) for c in ax.collections]
        assert sorted(offsets) == sorted([int(sel["success"].sum()), int((~sel["success"]).sum())])
        paths = {tuple(c.get_paths()[0].vertices.round(3).ravel()) for c in ax.collections}
        assert len(paths) == 2  # two marker shapes, not only two colours


def test_fig9_does_not_join_targets_and_shares_one_range(three_agents, tmp_path, monkeypatch) -> None:
    fig = drawn(figures.fig_occluded, three_agents, tmp_path, monkeypatch)
    assert len(fig.axes) == 2  # SPAC and APAC (DDPG cannot act in the dark)
    for ax in fig.axes:
        for line in ax.get_lines():
            joined = line.get_linestyle() not in ("None", "", " ")
            assert not joined or len(line.get_xdata()) == 2, line.get_label()  # only the horizontal references
        assert ax.collections  # the seeds' range as bars, the judged episodes as dots
    assert len({ax.get_ylim() for ax in fig.axes}) == 1


def test_fig10_says_how_to_read_a_climbing_critic_loss(three_agents, tmp_path, monkeypatch) -> None:
    fig = drawn(figures.fig_losses, three_agents, tmp_path, monkeypatch)
    title = fig.get_suptitle().replace("\n", " ")
    assert "Reading the critic" in title and "squared return units" in title and "not a supervised" in title
    assert "squared return units" in fig.axes[0].get_title().replace("\n", " ")


def test_fig11_leaves_out_a_quantity_without_values_and_no_slot_empty(three_agents, tmp_path, monkeypatch) -> None:
    def no_dark(table: pd.DataFrame) -> pd.DataFrame:
        table = table.copy()
        table.loc[table["quantity"] == "occluded_distance_judged", ["mean", "ci95_low", "ci95_high"]] = np.nan
        return table

    fig = drawn(figures.fig_scoreboard, three_agents, tmp_path, monkeypatch, no_dark)
    titles = [ax.get_title() for ax in fig.axes]
    assert not any("in the dark" in t for t in titles) and len(titles) == 5
    assert all(ax.get_visible() and ax.patches for ax in fig.axes)
    widths = sorted(round(ax.get_position().width, 2) for ax in fig.axes)
    assert widths[-1] > 1.8 * widths[0]  # the fifth panel spans both columns


def _only_fig4(monkeypatch) -> None:
    """Reports in these tests draw Fig. 4 only (a second each instead of ~25 s for every figure)."""
    monkeypatch.setattr(figures, "registered_figures", lambda: [figures.PAPER_FIGURES[1]])


def test_report_writes_vector_figures_and_any_dpi(three_agents, tmp_path, monkeypatch, capsys) -> None:
    _only_fig4(monkeypatch)
    assert main(["report", str(three_agents), "--out", str(tmp_path / "svg"), "--format", "svg"]) == 0
    assert (tmp_path / "svg" / "fig4_test.svg").read_text().lstrip().startswith("<?xml")
    assert not list((tmp_path / "svg").glob("*.png"))
    assert "(fig4_test.svg)" in (tmp_path / "svg" / "report.md").read_text()
    assert main(["report", str(three_agents), "--out", str(tmp_path / "svg"), "--format", "pdf"]) == 0
    assert (tmp_path / "svg" / "fig4_test.pdf").read_bytes()[:4] == b"%PDF"
    assert not (tmp_path / "svg" / "fig4_test.svg").exists()  # no stale figure of another format
    assert main(["report", str(three_agents), "--out", str(tmp_path / "50"), "--dpi", "50"]) == 0
    width_in = 11.0  # Fig. 4: two panels of 5.5 in
    assert matplotlib.image.imread(tmp_path / "50" / "fig4_test.png").shape[1] == pytest.approx(50 * width_in, abs=2)
    capsys.readouterr()
    assert main(["report", str(three_agents), "--out", str(tmp_path / "x"), "--dpi", "0"]) == 2
    assert "dpi must be in [10, 1200]" in capsys.readouterr().err and not (tmp_path / "x").exists()


# -- item 6: one run ----------------------------------------------------------------------------

def test_report_run_draws_one_runs_learning_curves(three_agents, tmp_path, monkeypatch, capsys) -> None:
    closed = []
    monkeypatch.setattr(figures.plt, "close", lambda fig: closed.append(fig))
    assert main(["report", "--run", str(three_agents / "apac__changing_target"), "--out", str(tmp_path)]) == 0
    assert (tmp_path / "learning_curves.png").is_file() and "learning_curves.png" in capsys.readouterr().out
    assert [ax.get_title() for ax in closed[0].axes] == ["training success", "action steps per episode",
                                                          "habitual share of the actions"]
    assert len(closed[0].axes[0].get_lines()) == 1 + 2  # the mean and two seeds
    assert main(["report", "--run", str(three_agents / "ddpg__changing_target"), "--out", str(tmp_path)]) == 0
    assert len(closed[1].axes) == 2  # DDPG does not arbitrate: no habit-share panel
    assert main(["report", str(three_agents), "--run", str(three_agents / "ddpg__changing_target")]) == 2
    assert "not both" in capsys.readouterr().err


SUMMARY = {"run_dir": "runs/x", "agent": "apac", "task": "changing_target",
           "protocols": {"grid": {"applicable": True, "episodes": 300, "success_rate": 0.8233333333333334,
                                  "mean_steps_to_reach": 2.4655870445344128, "habit_share": 0.7331081081081081,
                                  "mean_time_cost": 11.383333333333333, "final_distance_mean": 0.4123456789012,
                                  "success_rate_per_seed": {"0": 0.84, "1": 0.89}},
                         "occluded": {"applicable": False, "reason": "DDPG has no forward model to move on"}}}


def test_evaluate_prints_a_rounded_table_and_json_on_request(tmp_path, monkeypatch, capsys) -> None:
    monkeypatch.setattr("apac_mj.run.evaluate.evaluate", lambda run_dir, **kw: SUMMARY)
    monkeypatch.setattr("apac_mj.commands.hints.results_dir_hint", lambda *a: None)
    assert main(["evaluate", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert lines[1].split()[:3] == ["protocol", "episodes", "success"]
    assert lines[2].split() == ["grid", "300", "82.3%", "2.5", "73.3%", "11.4", "0.41"]
    assert "occluded: not applicable (DDPG has no forward model to move on)" in out
    assert "0: 84%, 1: 89%" in out and "0.8233" not in out and "{" not in out
    assert main(["evaluate", str(tmp_path), "--json"]) == 0
    parsed = json.loads(capsys.readouterr().out)
    assert parsed["protocols"]["grid"]["success_rate"] == SUMMARY["protocols"]["grid"]["success_rate"]


# -- fault campaign F4: a report of damaged or partial results --------------------------------

@pytest.fixture(scope="module")
def complete(tmp_path_factory) -> Path:
    return make_grid(tmp_path_factory.mktemp("complete"), conditions="static_target,changing_target",
                     manifest=True)


def _damaged(complete: Path, tmp_path: Path, cell: str, file: str, damage) -> Path:
    copy = tmp_path / "g"
    shutil.copytree(complete, copy)
    path = copy / cell / file
    damage(pd.read_parquet(path)).to_parquet(path)
    return copy


def _nan_rows(df: pd.DataFrame) -> pd.DataFrame:  # REP-3
    return pd.concat([df, pd.DataFrame(np.nan, index=range(3), columns=df.columns)], ignore_index=True)


def _nan_values(df: pd.DataFrame) -> pd.DataFrame:  # REP-4
    return df.assign(success=df["success"].astype(object).where(df.index >= 3, np.nan))


def _inf_values(df: pd.DataFrame) -> pd.DataFrame:  # REP-13
    return df.assign(final_distance=df["final_distance"].where(df.index >= 3, np.inf))


@pytest.mark.parametrize("file,damage,words", [
    ("metrics.parquet", _nan_rows, "column 'seed' is NaN in 3 of"),
    ("metrics.parquet", lambda df: pd.concat([df, df], ignore_index=True), "columns 'seed', 'episode' repeat"),
    ("metrics.parquet", lambda df: df.drop(columns="habit_actions"), "has no column habit_actions"),
    ("metrics.parquet", lambda df: df.iloc[:0], "holds no rows"),
    ("eval/grid.parquet", _nan_values, "column 'success' is NaN in 3 of"),
    ("eval/grid.parquet", _inf_values, "column 'final_distance' is infinite in 3 of"),
    ("eval/grid.parquet", lambda df: df.iloc[: len(df) // 2],
     "holds 6 test episodes, but eval/summary.json counted 12"),
], ids=["REP-3 nan rows", "REP-10 duplicated rows", "missing column", "no rows", "REP-4 nan values",
        "REP-13 inf values", "REP-5 half the rows"])
def test_a_damaged_table_is_refused_naming_file_and_column(complete, tmp_path, capsys, file, damage, words) -> None:
    damaged = _damaged(complete, tmp_path, "apac__changing_target", file, damage)
    assert main(["report", str(damaged), "--out", str(tmp_path / "rep")]) == 2
    err = capsys.readouterr().err
    assert words in err and str(damaged / "apac__changing_target" / file) in err, err
    assert not (tmp_path / "rep").exists()  # refused before anything is written


def test_a_partial_grid_is_reported_and_says_so(complete, tmp_path, monkeypatch, capsys) -> None:
    _only_fig4(monkeypatch)
    assert main(["report", str(complete), "--out", str(tmp_path / "full")]) == 0
    assert "partial" not in (tmp_path / "full" / "report.md").read_text() + capsys.readouterr().err
    copy = tmp_path / "g"
    shutil.copytree(complete, copy)
    shutil.rmtree(copy / "spac__static_target")  # REP-6: a cell deleted (the manifest lists it)
    shutil.rmtree(copy / "apac__changing_target" / "eval")  # REP-2: a cell's tests deleted
    (copy / "ddpg__changing_target" / "DONE").unlink()  # REP-16: a cell still training
    assert main(["report", str(copy), "--out", str(tmp_path / "part")]) == 0
    notice = ("partial: 6 of 9 cells complete, the numbers cover only the cells there are (apac__changing_target: "
              "no test results for grid, occluded; ddpg__changing_target: training not finished; "
              "spac__static_target: no directory)")
    assert notice in capsys.readouterr().err
    assert f"**{notice}.**" in (tmp_path / "part" / "report.md").read_text()
