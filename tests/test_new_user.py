"""What a new user met on the command line: `report` on a train run, the train summary's window, a closed pipe."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from apac_mj.cli import main
from apac_mj.run.run_dir import METRIC_COLUMNS, RunDir

from conftest import TINY

EPISODES = 3
#: The exit status when stdout's reader goes away: 128 + SIGPIPE (apac_mj.cli.EXIT_BROKEN_PIPE).
BROKEN_PIPE = 141


@pytest.fixture(scope="module")
def train_run(tmp_path_factory) -> tuple[Path, dict]:
    """A tiny `apac-mj train` run directory and the JSON summary the command printed."""
    import contextlib
    import io

    run = tmp_path_factory.mktemp("train") / "run"
    tiny = [f"--set={k}={','.join(map(str, v)) if isinstance(v, tuple) else v}" for k, v in TINY.items()]
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["train", "--task", "static_target", "--agent", "spac", "--seeds", "0-1", "--episodes",
                     str(EPISODES), "--out", str(run), "--actuation", "kinematic", "--no-progress", *tiny]) == 0
    return run, json.loads(out.getvalue().splitlines()[0])


# -- report on a train run directory --------------------------------------------------------------

def test_report_on_a_train_run_says_what_to_run_instead(train_run, capsys) -> None:
    """`report RUN` on a train run (metrics.parquet at its top) once said 'no cell in RUN has a
    metrics.parquet yet'; it now says RUN is a run directory and points at `apac-mj evaluate RUN`."""
    run, _ = train_run
    assert main(["report", str(run)]) == 2
    err = capsys.readouterr().err
    assert "no cell" not in err and "Traceback" not in err
    assert f"{run} is a run directory, not a grid's results directory" in err
    assert f"apac-mj evaluate {run}" in err
    assert not (run / "report").exists()


def test_report_on_a_grid_cell_points_at_its_grid(tmp_path, capsys) -> None:
    """A cell of a grid given to `report`: the message names the grid's results directory to report."""
    from test_report import make_results

    results = make_results(tmp_path / "results", seeds=(0, 1), episodes=3)
    cell = results / "apac__static_target"
    assert main(["report", str(cell)]) == 2
    err = capsys.readouterr().err
    assert f"{cell} is a run directory" in err and f"apac-mj report {results} (its grid's results directory)" in err


# -- train's final summary ------------------------------------------------------------------------

def test_train_summary_names_its_window(train_run) -> None:
    """A 3-episode run's summary is over its 3 episodes and says so (it once printed success_rate_last_100)."""
    run, summary = train_run
    assert not any(k.endswith("_last_100") for k in summary)
    train = RunDir(run).metrics().query("phase == 'train'")
    assert summary["episodes"] == EPISODES
    assert summary[f"success_rate_last_{EPISODES}"] == pytest.approx(train["success"].mean(), abs=1e-4)
    acts = train["habit_actions"].sum() + train["planning_actions"].sum()
    assert summary[f"habit_share_last_{EPISODES}"] == pytest.approx(train["habit_actions"].sum() / acts, abs=1e-4)


def test_train_summary_of_a_long_run_keeps_the_last_100_keys(tmp_path) -> None:
    """From 100 episodes on, the window is the last 100 and the keys are the ones readers know."""
    from apac_mj.commands.train import run_summary

    rows = [dict.fromkeys(METRIC_COLUMNS, 0.0) | dict(seed=0, episode=ep, phase="train", success=ep >= 20,
                                                       habit_actions=1, planning_actions=1)
            for ep in range(120)]
    run = RunDir(tmp_path)
    run.write_metrics(rows)
    assert run_summary(run) == {"episodes": 120, "seeds": 1, "success_rate_last_100": 1.0,
                                "habit_share_last_100": 0.5}


# -- a reader that goes away -----------------------------------------------------------------------

def _apac_mj(*args: str) -> list[str]:
    """The installed `apac-mj` (the module where no script is installed)."""
    script = Path(sys.executable).parent / "apac-mj"
    return [str(script), *args] if script.is_file() else [sys.executable, "-m", "apac_mj.cli", *args]


def _env(buffered: bool) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    return env if buffered else env | {"PYTHONUNBUFFERED": "1"}


def _quiet(stderr: str) -> bool:
    return not any(w in stderr for w in ("Traceback", "Broken pipe", "BrokenPipeError", "Exception ignored", "error"))


def test_tasks_into_a_reader_that_reads_one_line(tmp_path) -> None:
    """`apac-mj tasks | head -1`: once 'error: [Errno 32] Broken pipe' and exit 2; now nothing on stderr and
    exit 141 (128 + SIGPIPE; 0 where every line was written before the reader went away)."""
    p = subprocess.Popen(_apac_mj("tasks"), stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=_env(buffered=False))
    first = p.stdout.readline()
    p.stdout.close()
    rc = p.wait(timeout=120)
    stderr = p.stderr.read().decode()
    p.stderr.close()
    assert first.startswith(b"changing_target ")
    assert _quiet(stderr), stderr
    assert rc in (0, BROKEN_PIPE)


@pytest.mark.parametrize("buffered", [True, False])
def test_tasks_into_a_reader_already_gone(buffered) -> None:
    """The reader gone before the first line (the broken pipe certain): exit 141, stderr empty of errors,
    whether stdout is block-buffered (the error once came at exit: 'Exception ignored', exit 120) or not."""
    read, write = os.pipe()
    os.close(read)
    try:
        p = subprocess.run(_apac_mj("tasks"), stdout=write, stderr=subprocess.PIPE, env=_env(buffered), timeout=120)
    finally:
        os.close(write)
    stderr = p.stderr.decode()
    assert _quiet(stderr), stderr
    assert p.returncode == BROKEN_PIPE



# -- the quick look arbitrates (issue 29, item 2) -----------------------------------------------------

def _quick_look_config(flags: list[str]):
    from apac_mj.cli import build_parser
    from apac_mj.commands.train import train_config

    args = build_parser().parse_args(["train", "--task", "changing_target", "--agent", "apac", *flags,
                                      "--out", "unused"])
    return train_config(args)


def test_the_readmes_quick_look_leaves_episodes_after_the_planning_phase() -> None:
    """The README's quick look once ran 100 episodes = the paper's 100-episode planning phase: APAC planned
    every step and the bar said habit=0.00 throughout. Its flags must leave the habit episodes to act in."""
    from apac_mj.commands.train import planning_phase_note

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    line = next(s for s in readme.splitlines() if "A quick look: --seeds" in s)
    cfg = _quick_look_config(line.split("A quick look:")[1].split())
    assert cfg.episodes - cfg.agent.planning_episodes >= 0.5 * cfg.episodes
    assert planning_phase_note(cfg) is None


def test_train_says_when_a_run_ends_inside_the_planning_phase() -> None:
    from apac_mj.commands.train import planning_phase_note

    note = planning_phase_note(_quick_look_config(["--episodes", "100"]))
    assert note is not None and "plans in all 100 episodes" in note and "agent.planning_episodes=40" in note
    assert planning_phase_note(_quick_look_config(["--episodes", "101"])) is None
    assert planning_phase_note(_quick_look_config(["--episodes", "30", "--agent", "spac"])) is None
    assert planning_phase_note(_quick_look_config(["--episodes", "30", "--set", "agent.planning_episodes=10"])) \
        is None
