"""``apac-mj record`` and what a recording shows (issue 45): an existing file is refused unless --force, a run
re-arbitrated as the graded rule records (F13), the plane view has a legend and the plan its own colour, the
"why" inputs are drawn one plot per unit, and docs/recording.md lists every entity path a recording logs."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from apac_mj.cli import main
from apac_mj.recording import recording as R

DOC = Path(__file__).resolve().parents[1] / "docs" / "recording.md"


@pytest.fixture(scope="module")
def apac_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished 1-seed APAC run with small networks (3 episodes)."""
    from apac_mj.config import AgentConfig, TrainConfig
    from apac_mj.run.trainer import train

    from conftest import TINY

    cfg = TrainConfig(task="changing_target", seeds=(0,), episodes=3, actuation="kinematic",
                      agent=AgentConfig(**{**TINY, "planning_episodes": 1}))
    return train(cfg, tmp_path_factory.mktemp("run") / "apac", progress=False)


def static_labels(path: Path) -> dict[str, str]:
    """The labels of the recording's static entities: entity path -> label."""
    from rerun.chunk import RrdReader

    labels = {}
    for chunk in RrdReader(str(path)).stream():
        if chunk.is_static:
            for col, values in chunk.to_record_batch().to_pydict().items():
                if col.endswith(":labels") and values and values[0]:
                    labels[chunk.entity_path.lstrip("/")] = values[0][0]
    return labels


def test_record_refuses_an_existing_file_and_force_replaces_it(tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    """Item 7: `record` silently overwrote an existing .rrd (the forced-response commands refuse)."""
    out, video = tmp_path / "r.rrd", tmp_path / "r.gif"
    args = ["record", "--episodes", "1", "--out", str(out)]
    assert main(args) == 0
    before = out.read_bytes()
    capsys.readouterr()
    assert main(args) == 2
    assert f"{out} exists; choose another --out, or pass --force to replace it (nothing was written)" \
        in capsys.readouterr().err
    assert out.read_bytes() == before
    video.write_bytes(b"an older video")
    assert main(args + ["--video", str(video), "--force"]) == 0
    assert out.is_file() and video.read_bytes() != b"an older video", "--force replaces --out and --video"
    out.unlink()
    video.write_bytes(b"an older video")
    assert main(args + ["--video", str(video)]) == 2
    assert f"{video} exists; choose another --video" in capsys.readouterr().err
    assert not out.exists() and video.read_bytes() == b"an older video"


def test_a_delta_rule_run_records_arbitrated_by_the_graded_rule(apac_run: Path, tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    """F13: `record --run <apac run> --agent apac_voc` ended in an AttributeError (no habit probe), and on a later
    commit recorded APAC's rule under the name apac_voc: the recording must be the graded rule's, planning
    with the MPC planner through the run's forward model."""
    out = tmp_path / "voc.rrd"
    assert main(["record", "--run", str(apac_run), "--agent", "apac_voc", "--episodes", "1", "--out", str(out)]) == 0
    assert "arbitrated as apac_voc (--agent apac_voc), planning with its mpc planner" in capsys.readouterr().err
    entities, props, _ = R.read_recording(out)
    inputs = {p.rsplit("/", 1)[-1] for p in entities if p.startswith(R.ARBITRATION_INPUTS + "/")}
    assert {"habit_final_distance", "habit_value", "planning_cost", "iterations"} <= inputs
    assert "abs_delta" not in inputs and props["agent.kind"] == ["apac_voc"]
    assert R.PLAN in entities and R.PLAN_ITERATIONS in entities
    legend = set(static_labels(out).values())
    assert {"MuJoCo arm", "target and zone", "MPC plan", "plan candidates"} <= legend
    assert "commanded arm, dashed" not in legend, "the legend names only what the recording drew"


def test_the_plan_has_its_own_colour_and_every_legend_colour_differs() -> None:
    """New-user item 4: the MPC plan was drawn in the target's red (and the field force too)."""
    colours = {name: R._RED if path == R.TARGET else R._STRIP_STYLES[path][0] for path, name in R.LEGEND_ENTRIES}
    assert len(set(colours.values())) == len(colours), colours
    assert R._STRIP_STYLES[R.PLAN][0] != R._RED and R._STRIP_STYLES[R.HAND_FORCE][0] != R._RED


def test_the_why_panel_draws_one_unit_per_plot() -> None:
    """New-user item 4: the graded rule's "why" panel drew cm, values and gains on one axis."""
    voc = ["habit_final_distance", "habit_value", "distance", "expected_gain", "planning_cost", "iterations"]
    groups = dict(R.why_groups(voc))
    assert groups == {"cm": ["habit_final_distance", "distance"],
                      "value (reward units)": ["habit_value", "expected_gain", "planning_cost"],
                      "iterations": ["iterations"]}
    assert dict(R.why_groups(["abs_delta", "threshold"])) == {"|δ| (reward units)": ["abs_delta", "threshold"]}
    assert R.why_groups(["a_new_input"]) == [("a_new_input", ["a_new_input"])]
    assert isinstance(R.why_view(voc), R.rrb.Tabs) and isinstance(R.why_view(["abs_delta"]), R.rrb.TimeSeriesView)


def documented_paths() -> set[str]:
    """The entity paths docs/recording.md's panel table names (in backticks)."""
    table = "\n".join(line for line in DOC.read_text().splitlines() if line.startswith("|"))
    return set(re.findall(r"`((?:render|plane|series|events|legend)[A-Za-z0-9_/<>*]*)`", table))


def test_the_docs_list_every_entity_path_a_recording_logs(apac_run: Path, tmp_path: Path) -> None:
    """New-user item 4: docs/recording.md did not list the plan entities."""
    documented = documented_paths()
    placeholders = {f"{R.ARBITRATION_INPUTS}/<name>", f"{R.LEGEND}/<n>", f"{R.PLANE}/**"}
    assert set(R.ALL_ENTITY_PATHS) - documented == set(), "undocumented"
    assert documented - set(R.ALL_ENTITY_PATHS) - placeholders == set(), "documented but never logged"
    out = tmp_path / "voc.rrd"
    assert main(["record", "--run", str(apac_run), "--agent", "apac_voc", "--episodes", "1", "--out", str(out)]) == 0
    logged = set(R.read_recording(out)[0]) | set(static_labels(out))
    unknown = {p for p in logged if p not in R.ALL_ENTITY_PATHS and not p.startswith((R.ARBITRATION_INPUTS + "/",
                                                                                       R.LEGEND + "/"))}
    assert unknown == set()
