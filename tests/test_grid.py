"""The experiment grid: presets and their errors, cells, resume, kill -9 and resume, smoke grid + report."""
from __future__ import annotations

import re

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from apac_mj.config import AgentConfig
from apac_mj.experiments import grid
from apac_mj.experiments.presets import CONDITIONS, PresetError, load_preset
from apac_mj.experiments.results import load_results, load_tests
from apac_mj import report
from apac_mj.cli import main

from conftest import deterministic

ROOT = Path(__file__).resolve().parent.parent


# -- presets -------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["paper", "quick", "smoke", "demo"])
def test_shipped_presets_load(name: str) -> None:
    p = load_preset(name)
    assert p.name == name and p.agents and p.conditions and p.seeds


def test_paper_preset_is_the_papers_study() -> None:
    p = load_preset("paper")
    assert p.agents == ("ddpg", "spac", "apac") and p.conditions == CONDITIONS
    assert p.seeds == tuple(range(50)) and p.episodes == 1000 and p.run.agent == AgentConfig()
    cs = grid.cells(p)
    assert len(cs) == 12 + 12
    assert {c.protocols for c in cs if c.agent == "ddpg" and c.region == "all"} == {("grid",)}
    assert {c.protocols for c in cs if c.agent != "ddpg" and c.region == "all"} == {("grid", "occluded")}
    assert {c.name for c in cs if c.region == "train"} >= {"apac__changing_target_train_region"}


def test_overrides() -> None:
    p = load_preset("paper", ["seeds=3-5", "episodes=7", "agents=ddpg,apac", "agent.batch_size=64",
                                   "tests.occluded=false", "device=cpu"])
    assert p.seeds == (3, 4, 5) and p.episodes == 7 and p.agents == ("ddpg", "apac")
    assert p.run.agent == AgentConfig(batch_size=64) and not p.tests.occluded
    assert load_preset("smoke", ["seeds=[1, 4]"]).seeds == (1, 4)
    assert load_preset("smoke", ["seeds=4"]).seeds == (0, 1, 2, 3)
    cfg = grid.cells(p)[0].train_config(p)
    assert cfg.agent.batch_size == 64 and cfg.seeds == (3, 4, 5) and cfg.episodes == 7


@pytest.mark.parametrize("override, message", [
    ("agents=ddpg,sac", "agents has unknown value(s) ['sac']"),
    ("conditions=moving_target", "conditions has unknown value(s) ['moving_target']"),
    ("episodes=0", "episodes must be an int >= 1"),
    ("episodes=1.5", "episodes must be an int >= 1"),
    ("seeds=5-2", "seed range '5-2' is empty"),
    ("seeds=[1, 1]", "seeds must be distinct"),
    ("seeds=abc", "seeds must be an int N"),
    ("precision=fp8", "precision has unknown value(s) ['fp8']"),
    ("epochs=3", "unknown key(s) ['epochs']"),
    ("agent.batch=3", "unknown [agent] key(s) ['batch']"),
    ("batchsize=64", "unknown key(s) ['batchsize']; did you mean 'batch_size'? (--help"),  # the nearest, not all
    ("agent.batchsize=64", "unknown [agent] key(s) ['batchsize']; did you mean 'batch_size'?;"),
    ("episodez=3", "unknown key(s) ['episodez']; did you mean 'episodes'?"),
    ("agent.actor_lr=2.0", "actor_lr must be in (0, 1]"),
    ("tests.occluded=maybe", "tests.occluded must be true or false"),
    ("tests.vision=true", "[tests] keys must be among"),
    ("episodes", "must look like key=value"),
])
def test_bad_overrides_name_the_problem(override: str, message: str) -> None:
    with pytest.raises(PresetError) as e:
        load_preset("smoke", [override])
    assert message in str(e.value)


def test_unknown_preset_lists_known_ones(tmp_path: Path) -> None:
    from apac_mj.util import paths

    known = ", ".join(sorted(p.stem for p in (paths.tasks_dir() / "presets").glob("*.toml")))
    assert {"demo", "fidelity", "paper", "quick", "smoke", "arbitrators"} <= set(known.split(", "))
    with pytest.raises(FileNotFoundError, match=re.escape(f"known presets: {known}")):
        load_preset("huge")
    bad = tmp_path / "bad.toml"
    bad.write_text("agents = [\n")
    with pytest.raises(PresetError, match="bad.toml"):
        load_preset(bad)


def test_cli_reports_preset_errors(capsys) -> None:
    assert main(["grid", "--preset", "smoke", "--set", "agents=sac", "--out", "/nonexistent/x"]) == 2
    assert "agents has unknown value(s) ['sac']" in capsys.readouterr().err


def test_changed_configuration_is_refused(tmp_path: Path) -> None:
    p = load_preset("smoke")
    cell = grid.cells(p)[0]
    grid.prepare_cell(cell, p, tmp_path)
    grid.prepare_cell(cell, p, tmp_path)  # same configuration: fine
    q = load_preset("smoke", ["agent.batch_size=9"])
    with pytest.raises(ValueError, match=r"different configuration \(train_config.agent.batch_size: 16 there, 9 now\)"):
        grid.prepare_cell(cell, q, tmp_path)
    assert grid.cell_status(cell, load_preset("smoke", ["episodes=9"]), tmp_path) == \
        ("to extend", "from 4 to 9 episodes")
    with pytest.raises(ValueError, match="its run has 4 episodes, more than the 3 asked for"):
        grid.prepare_cell(cell, load_preset("smoke", ["episodes=3"]), tmp_path)


def test_refused_grid_creates_nothing_and_dry_run_says_so(tmp_path: Path, capsys) -> None:
    p = load_preset("smoke")
    grid.prepare_cell(grid.cells(p)[1], p, tmp_path)  # results of the smoke preset, one cell started
    before = sorted(tmp_path.iterdir())
    args = ["grid", "--preset", "smoke", "--out", str(tmp_path), "--set", "agent.batch_size=9"]
    assert main(args + ["--dry-run"]) == 2
    captured = capsys.readouterr()
    refused = [line for line in captured.out.splitlines() if "refused" in line]
    assert len(refused) == 1 and grid.cells(p)[1].name in refused[0] and "batch_size: 16 there, 9 now" in refused[0]
    assert "1 of 9 cells refused, nothing run" in captured.err
    assert main(args + ["--no-progress"]) == 2
    assert sorted(tmp_path.iterdir()) == before  # no stray cell directories, no manifest


def test_grid_extends_finished_cells(tmp_path: Path, stack: None, capsys) -> None:
    """episodes=2, then episodes=4 on the same --out: the numbers of a clean 4-episode grid."""
    clean, ext = tmp_path / "clean", tmp_path / "ext"
    cmd = ["grid", "--preset", "smoke", "--no-progress", *[a for s in TINY for a in ("--set", s)]]
    assert main(cmd + ["--out", str(clean)]) == 0
    assert main(cmd + ["--out", str(ext), "--set", "episodes=2"]) == 0
    assert main(cmd + ["--out", str(ext), "--dry-run"]) == 0
    assert "to extend (from 2 to 4 episodes)" in capsys.readouterr().out
    assert main(cmd + ["--out", str(ext)]) == 0
    _assert_same_results(clean, ext)


def test_atomic_write_leaves_no_temporary_files(tmp_path: Path) -> None:
    target = tmp_path / "m.json"
    grid.atomic_write_text(target, "one")
    grid.atomic_write_text(target, "two")
    assert target.read_text() == "two" and [p.name for p in tmp_path.iterdir()] == ["m.json"]


# -- the Ray driver's watchdog (no Ray needed) -------------------------------------------

def _running(pid: int) -> bool:
    """``pid`` exists and is not a zombie (an orphan's zombie waits for a reaper that may never come)."""
    try:
        return (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="the watchdog reads /proc (Linux)")
def test_the_ray_watchdog_kills_what_a_killed_driver_left_and_exits() -> None:
    """The executor starts ``python -m apac_mj.experiments.watchdog DRIVER_PID`` (the driver's child, in its own
    session); while the driver lives it leaves the driver's processes alone, after the driver's kill -9 it
    kills them (here a ``sleep``) and exits."""
    from apac_mj.experiments import watchdog

    script = ("import subprocess, time\nfrom apac_mj.experiments import executors\n"
              "w = executors._ray_watchdog()\nchild = subprocess.Popen(['sleep', '120'])\n"
              "print(w.args[1:3], w.pid, child.pid, flush=True)\ntime.sleep(120)\n")
    driver = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True, cwd=ROOT)
    pids: list[int] = []
    try:
        line = driver.stdout.readline()
        assert line.startswith("['-m', 'apac_mj.experiments.watchdog'] "), line
        pids = [int(p) for p in line.split("] ")[1].split()]
        time.sleep(3.0)  # the watchdog notes the driver's descendants every second
        assert all(_running(p) for p in pids), "the watchdog or the child stopped while the driver lives"
        os.kill(driver.pid, signal.SIGKILL)  # not reaped yet: the watchdog sees a zombie driver as gone
        deadline = time.monotonic() + 15
        while any(_running(p) for p in pids) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _running(pids[1]), "the killed driver's child is still running"
        assert not _running(pids[0]), "the watchdog did not exit"
    finally:
        for p in pids[::-1]:
            if _running(p):
                os.kill(p, signal.SIGKILL)
        driver.kill()
        driver.wait()
    no_such_pid = int(Path("/proc/sys/kernel/pid_max").read_text()) + 1
    watchdog.main([str(no_such_pid)])  # no driver (gone before the watchdog started): returns at once


# -- running the grid (needs the trainer) ---------------------------------------------

@pytest.fixture
def stack() -> None:
    """Skip the grid runs until the trainer and the evaluation exist."""
    pytest.importorskip("apac_mj.run.trainer", reason="the trainer has not landed yet")
    pytest.importorskip("apac_mj.run.evaluate", reason="the evaluation has not landed yet")

TINY = ["seeds=2", "episodes=4", "checkpoint_every=1", "conditions=changing_target", "agents=apac",
        "tests.generalization=false"]


def _tables(results: Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    return load_results(results), load_tests(results)


def _assert_same_results(a: Path, b: Path) -> None:
    (ma, ta), (mb, tb) = _tables(a), _tables(b)
    pd.testing.assert_frame_equal(deterministic(ma), deterministic(mb), check_exact=True)  # wall times differ
    pd.testing.assert_frame_equal(deterministic(ta), deterministic(tb), check_exact=True)


def test_smoke_grid_then_report(tmp_path: Path, stack: None) -> None:
    out = tmp_path / "smoke"
    assert main(["grid", "--preset", "smoke", "--out", str(out), "--no-progress"]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert all(c["status"] == "done" for c in manifest["cells"].values())
    assert len(manifest["cells"]) == 3 * 2 + 3
    metrics, tests = _tables(out)
    p = load_preset("smoke")
    train = metrics[metrics["phase"] == "train"]
    assert train.groupby(["agent", "condition", "region", "seed"]).size().eq(p.episodes).all()
    assert set(tests["protocol"]) == {"grid", "occluded", "generalization"}
    assert main(["report", str(out)]) == 0
    table = pd.read_csv(out / "report" / "key_numbers.csv")
    assert set(table["quantity"]) == set(report.QUANTITIES)
    late = metrics[(metrics["phase"] == "train") & (metrics["episode"] == p.episodes - 1)]  # last 20% of 4 = 1 episode
    late = late[(late["agent"] == "ddpg") & (late["condition"] == "static_target") & (late["region"] == "all")]
    row = table[(table["quantity"] == "steps_late") & (table["agent"] == "ddpg")
                & (table["condition"] == "static_target")].iloc[0]
    assert row["mean"] == pytest.approx(late["steps"].mean())
    row = table[(table["quantity"] == "test_success") & (table["agent"] == "apac")
                & (table["condition"] == "changing_target")].iloc[0]
    grid_test = pd.read_parquet(out / "apac__changing_target" / "eval" / "grid.parquet")
    assert row["mean"] == pytest.approx(100 * grid_test.groupby("seed")["success"].mean().mean())
    # re-running skips every finished cell
    before = {p: p.stat().st_mtime_ns for p in out.glob("*/metrics.parquet")}
    assert main(["grid", "--preset", "smoke", "--out", str(out), "--no-progress"]) == 0
    assert before == {p: p.stat().st_mtime_ns for p in out.glob("*/metrics.parquet")}


def _grid_cmd(out: Path, extra: list[str] = []) -> list[str]:
    sets = [a for s in TINY + extra for a in ("--set", s)]
    return [sys.executable, "-m", "apac_mj.cli", "grid", "--preset", "smoke", "--out", str(out), "--no-progress", *sets]


def test_kill_9_and_resume_equals_uninterrupted(tmp_path: Path, stack: None) -> None:
    """kill -9 the grid after the cell's first checkpoint, re-run: the same numbers as one clean run."""
    env = dict(os.environ, OMP_NUM_THREADS="1")
    clean, killed = tmp_path / "clean", tmp_path / "killed"
    subprocess.run(_grid_cmd(clean), check=True, env=env, cwd=ROOT, timeout=600)
    proc = subprocess.Popen(_grid_cmd(killed), env=env, cwd=ROOT, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    ckpt = killed / "apac__changing_target" / "checkpoints" / "latest.pt"
    deadline = time.monotonic() + 300
    while not ckpt.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert proc.poll() is None, "the grid finished before it could be killed; make TINY longer"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not (killed / "apac__changing_target" / "DONE").exists()
    subprocess.run(_grid_cmd(killed), check=True, env=env, cwd=ROOT, timeout=600)
    _assert_same_results(clean, killed)


def test_demo_writes_report_and_recording(tmp_path: Path, stack: None, capsys) -> None:
    out = tmp_path / "demo"
    assert main(["demo", "--preset", "smoke", "--out", str(out), "--no-progress", "--set", "agents=apac",
                 "--set", "conditions=changing_target", "--set", "tests.generalization=false"]) == 0
    printed = capsys.readouterr().out
    rrd = out / "apac__changing_target.rrd"
    assert "preset 'smoke'" in printed.splitlines()[0]
    assert rrd.stat().st_size > 10_000 and f"recording: {rrd}" in printed
    assert (out / "report" / "report.md").exists() and f"{out / 'report'}/fig*.png" in printed
    assert list((out / "report").glob("fig*.png"))


@pytest.mark.parametrize("command", [["evaluate"], ["record", "--run"]])
def test_evaluate_and_record_on_a_grid_directory_list_its_cells(tmp_path: Path, capsys, command) -> None:
    p = load_preset("smoke")
    for c in grid.cells(p)[:2]:
        (grid.prepare_cell(c, p, tmp_path) / "config.json").write_text("{}")
    assert main(command + [str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "is a grid's results directory, not a run directory" in err
    assert all(str(tmp_path / c.name) in err for c in grid.cells(p)[:2])


def test_demo_duration_is_stated_once() -> None:
    """README, `apac-mj demo --help` and demo.toml give the same duration."""
    import re

    from apac_mj.commands import demo

    texts = {"README": (ROOT / "README.md").read_text().split("## Quick tour")[0], "demo --help": demo.DESCRIPTION,
             "demo.toml": (ROOT / "tasks" / "presets" / "demo.toml").read_text()}
    found = {k: set(re.findall(r"about (\d+) minutes", t.replace("\n", " "), flags=re.I)) for k, t in texts.items()}
    assert all(len(v) == 1 for v in found.values()) and len(set.union(*found.values())) == 1, found
