"""The second fault campaign (issue 29, items 15-19): a task file edited between start and resume, a disk
that fills under a recording, memory limits, extending a grid, a grid worker killed with -9. Each test
reproduces the item's failure and checks the answer."""
from __future__ import annotations

import json
import shutil
from pathlib import Path
from types import SimpleNamespace

import pandas as pd
import pytest

from apac_mj.cli import main
from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.run import run_dir as rd
from apac_mj.run.evaluate import evaluate
from apac_mj.run.run_dir import RunDir, TaskChanged
from apac_mj.run.trainer import train
from apac_mj.util import paths

from conftest import TINY, TINY_SETS

ROOT = Path(__file__).resolve().parent.parent


def tiny(episodes: int = 4) -> TrainConfig:
    return TrainConfig(task="changing_target", seeds=(0, 1), episodes=episodes, checkpoint_every=1,
                       actuation="kinematic", agent=AgentConfig(kind="apac", **TINY))


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """An uninterrupted run of ``tiny()`` (4 episodes, a checkpoint after each)."""
    return train(tiny(), tmp_path_factory.mktemp("ref") / "run", progress=False)


# -- item 15: a task file edited between start and resume --------------------------------------------

@pytest.fixture()
def tasks(tmp_path, monkeypatch) -> Path:
    """A task directory of this test's own (a copy of changing_target.toml) that the test may edit."""
    folder = tmp_path / "tasks"
    folder.mkdir()
    shutil.copy(paths.tasks_dir() / "changing_target.toml", folder)
    monkeypatch.setattr(paths, "tasks_dir", lambda: folder)
    return folder / "changing_target.toml"


def stop_after_starts(n: int):
    """An ``on_episode_start`` that interrupts training at its ``n``-th call (a kill after a checkpoint)."""
    calls = []

    def on_episode_start(members, env) -> None:
        calls.append(1)
        if len(calls) == n:
            raise KeyboardInterrupt

    return on_episode_start


def files_of(run: Path) -> dict[str, bytes]:
    return {str(p.relative_to(run)): p.read_bytes() for p in sorted(run.rglob("*")) if p.is_file()}


def test_a_task_file_edited_before_resume_is_refused_naming_it_and_nothing_is_lost(tmp_path, tasks, reference):
    """Item 15: ``zone_radius = 2.0`` added to the task file after a kill; the same command resumed (exit 0) and
    trained the rest on the edited task, and evaluate ran on it too, silently."""
    out = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        train(tiny(), out, progress=False, on_episode_start=stop_after_starts(5))
    stored = json.loads((out / rd.CONFIG).read_text())
    assert stored[rd.TASK_SPEC]["zone_radius"] == 0.5 and stored[rd.TASK_DIGEST] == rd.task_digest(stored[rd.TASK_SPEC])
    assert RunDir(out).config() == rd.config_dict(tiny()), "the task record is beside the config, not in it"
    original = tasks.read_text()
    tasks.write_text(original.replace("[report]", "[target]\nzone_radius = 2.0\n\n[report]"))
    before = files_of(out)
    for go_on in (lambda: train(tiny(), out, progress=False), lambda: evaluate(out, limit=1)):
        with pytest.raises(TaskChanged, match=rf"task file {tasks} has changed since {out} was trained on it "
                                              r"\(zone_radius: 0.5 in the run, 2.0 now\)"):
            go_on()
    assert files_of(out) == before, "nothing was written"
    tasks.write_text(original.replace('color = "tab:olive"', 'color = "navy"'))  # only how reports draw it
    train(tiny(), out, progress=False)
    pd.testing.assert_frame_equal(*(pd.read_parquet(r / rd.METRICS)[list(rd.METRIC_COLUMNS)] for r in (out, reference)),
                                  check_exact=True)  # the computed columns (measured wall times differ)


def test_the_task_refusal_reaches_the_command_line(tmp_path, tasks, reference, capsys):
    out = Path(shutil.copytree(reference, tmp_path / "run"))
    tasks.write_text(tasks.read_text().replace("[report]", "[plant]\nfield_b = 0.0\n\n[vision]\nmode = 'occluded'\n\n"
                                                           "[report]"))
    assert main(["evaluate", str(out), "--limit", "1", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert f"task file {tasks} has changed" in err and "vision: 'perfect' in the run, 'occluded' now" in err, err
    assert "plant" not in err, "a key set to its default changes nothing"


def test_a_run_that_never_trained_takes_the_edited_task(tmp_path, tasks):
    """Killed before its first checkpoint, a run starts over: on the task file as it is now."""
    out = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        train(tiny(episodes=1), out, progress=False, on_episode_start=stop_after_starts(1))
    assert not RunDir(out).checkpoint_files()
    tasks.write_text(tasks.read_text().replace("[report]", "[target]\nzone_radius = 2.0\n\n[report]"))
    train(tiny(episodes=1), out, progress=False)
    assert json.loads((out / rd.CONFIG).read_text())[rd.TASK_SPEC]["zone_radius"] == 2.0


# -- item 16: a recording onto a disk that fills -------------------------------------------------------

#: Records EPISODES synthetic episodes (incompressible 20 KB frames, ~0.2 MB an episode) to OUT with the
#: process's files limited to LIMIT bytes (RLIMIT_FSIZE, SIGXFSZ ignored: a write past it fails as on a full
#: disk); prints what close raised.
CUT_SHORT = """
import resource, signal, sys
import numpy as np
from apac_mj.recording.recording import Recording, StepRecord
out, episodes, limit = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
rng = np.random.default_rng(0)
try:
    with Recording(out) as r:
        for e in range(episodes):
            r.start_episode(e, (20.0, 20.0), (5.0, 8.0))
            for k in range(10):
                r.log_step(StepRecord(episode=e, step=k, true_arm=np.array([20.0, 15, 18, 15]),
                                      joint_angles=np.array([0.0, 180]), link_lengths=np.array([5.0, 8.0]),
                                      target=np.array([20.0, 20])), rng.bytes(20_000))
    print("closed")
except Exception as e:
    print(f"{type(e).__name__}: {e}")
"""


def record_cut_short(out: Path, episodes: int, limit: int = 10**9) -> str:
    import os
    import subprocess
    import sys

    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, "-c", CUT_SHORT, str(out), str(episodes), str(limit)], env=env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout.strip()


def test_a_recording_the_disk_cuts_short_leaves_the_previous_file_and_no_temporary(tmp_path):
    """Item 16: onto a full disk the writer died and close raised "File-writer thread shut down prematurely",
    leaving a 2 MB temporary (or hung in its flush); or the file, cut, was renamed to its final name."""
    from apac_mj.recording.recording import read_recording, recording_complete

    out = tmp_path / "rollout.rrd"
    assert record_cut_short(out, 2) == "closed"
    before = out.read_bytes()
    for target in (out, tmp_path / "new.rrd"):  # over an existing recording, and to a new path
        said = record_cut_short(target, 8, limit=400_000)
        assert said.startswith(f"RecordingError: the recording {target} could not be written to its end"), said
        assert f"{target} was left as it was and no temporary file remains" in said
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rollout.rrd"], "no temporary, nothing under new.rrd"
    assert out.read_bytes() == before and recording_complete(out) is True and read_recording(out)[0]


def test_a_recording_cut_without_an_error_is_not_renamed_and_a_full_disk_is_named(tmp_path, monkeypatch):
    """Rerun's writer only logs a write that fails at the stream's end ("Failed to end log stream ... No space
    left on device"): the cut file was renamed to rollout.rrd, which the reader refused ("exceeds file size")."""
    import errno
    import os

    import rerun as rr

    from apac_mj.cli import os_error_message
    from apac_mj.recording import recording as rec

    disconnect = rr.RecordingStream.disconnect

    def cut(self) -> None:  # the stream ends, its last bytes lost
        disconnect(self)
        for f in tmp_path.glob(".*.tmp"):
            os.truncate(f, f.stat().st_size // 2)

    monkeypatch.setattr(rr.RecordingStream, "disconnect", cut)
    out = tmp_path / "rollout.rrd"
    with pytest.raises(rec.RecordingError, match=rf"the recording {out} could not be written to its end .*"
                                                 "does not read back"):
        with rec.Recording(out) as r:
            r.start_episode(0, (20.0, 20.0), (5.0, 8.0))
    assert list(tmp_path.iterdir()) == []
    monkeypatch.setattr(rec.shutil, "disk_usage", lambda p: SimpleNamespace(free=0))
    with pytest.raises(OSError) as e:
        with rec.Recording(out) as r:
            r.start_episode(0, (20.0, 20.0), (5.0, 8.0))
    assert e.value.errno == errno.ENOSPC and e.value.filename == str(out) and list(tmp_path.iterdir()) == []
    assert os_error_message(e.value).startswith(f"no space left on the device of {out}; free some space")


# -- item 19: a grid worker killed with -9 ---------------------------------------------------------------

#: Two cells in a pool of two workers, each making a progress bar (disabled, as with --no-progress); the cell
#: "die" kills its own worker with -9, as `kill -9 WORKER` did.
POOL_WITH_A_KILLED_WORKER = """
import os, signal, time
from apac_mj.experiments.executors import LocalExecutor

def cell(d, progress, threads):
    from tqdm.auto import tqdm
    with tqdm(total=1, disable=True):
        if d == "die":
            time.sleep(0.5)
            os.kill(os.getpid(), signal.SIGKILL)
        time.sleep(10)
    return {"cell": d, "status": "done"}

if __name__ == "__main__":
    try:
        LocalExecutor(workers=2).run(["live", "die"], cell, print, progress=False)
    except RuntimeError as e:
        print(e)
"""


def test_a_killed_grid_worker_leaves_no_leaked_semaphore(tmp_path):
    """Item 19: after kill -9 of a worker the grid said why in 0.4 s, then Python printed "resource_tracker:
    There appear to be 2 leaked semaphore objects": tqdm's lock in each worker (the killed one, and the one the
    grid stopped) was a named semaphore that only the worker's exit handlers release."""
    import os
    import subprocess
    import sys

    script = tmp_path / "pool.py"
    script.write_text(POOL_WITH_A_KILLED_WORKER)
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, str(script)], env=env, cwd=tmp_path, capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0 and "a grid worker process died" in proc.stdout, proc.stdout + proc.stderr
    assert "leaked" not in proc.stderr, proc.stderr


# -- item 17: memory limits ------------------------------------------------------------------------------

def limited(limit_kb: int, *args: str) -> "subprocess.CompletedProcess[str]":
    """``apac-mj ARGS`` under ``ulimit -v LIMIT_KB``."""
    import os
    import resource
    import subprocess
    import sys

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (limit_kb * 1024, resource.RLIM_INFINITY))

    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "apac_mj.cli", *args], env=env, cwd=ROOT, capture_output=True,
                          text=True, timeout=300, preexec_fn=limit)


@pytest.mark.parametrize("limit_kb", [1_000_000, 1_500_000])
def test_a_resume_under_a_small_address_space_is_refused_as_such_and_loses_nothing(tmp_path, reference, limit_kb):
    """Item 17: under ulimit -v 1000000 a resume died in dm_control's "Cannot initialize a headless EGL display"
    (a traceback, and the wrong cause); under 1500000 one hung in pyarrow, and record --run hung too."""
    out = Path(shutil.copytree(reference, tmp_path / "run"))
    before = files_of(out)
    train_args = ["train", "--seeds", "0-1", "--episodes", "6", "--checkpoint-every", "1", "--actuation", "kinematic",
                  "--no-progress", "--out", str(out), *TINY_SETS]
    for args in (train_args, ["record", "--run", str(out), "--episodes", "1", "--out", str(tmp_path / "r.rrd")]):
        proc = limited(limit_kb, *args)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
        assert f"needs about" in proc.stderr and f"ulimit -v {limit_kb}" in proc.stderr, proc.stderr
    assert files_of(out) == before and not (tmp_path / "r.rrd").exists(), "nothing was written"
    assert main(train_args) == 0, "the limit lifted, the run goes on"


def test_out_of_memory_during_a_command_is_said_as_such(tmp_path, monkeypatch, capsys):
    """Past the start, a failed allocation names itself and the command, not a traceback of the library."""
    from apac_mj.commands import train as train_command
    from apac_mj.util import memory

    def run(args):
        raise ImportError("libarrow_compute.so.2600: failed to map segment from shared object")

    monkeypatch.setattr(train_command, "run", run)
    assert main(["train", "--out", str(tmp_path / "x"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"apac-mj train: error: out of memory while running apac-mj train --out {tmp_path / 'x'} "
                          "(ImportError: libarrow_compute.so.2600: failed to map segment"), err
    monkeypatch.setattr(memory, "address_space_limit", lambda: 1 << 30)
    assert "ulimit -v 1048576" in memory.out_of_memory(MemoryError(), "apac-mj evaluate runs/x")
    assert memory.is_out_of_memory(RuntimeError("DefaultCPUAllocator: can't allocate memory: you tried to allocate"))
    assert not memory.is_out_of_memory(RuntimeError("a grid worker process died"))


def test_out_of_memory_reading_the_metrics_is_not_taken_for_a_damaged_file(tmp_path, reference, monkeypatch,
                                                                            capsys):
    """A MemoryError reading metrics.parquet was "cannot be read (MemoryError)": the rows were restored from the
    checkpoint and the file rewritten, under the very memory pressure that failed the read."""
    out = Path(shutil.copytree(reference, tmp_path / "run"))
    before = (out / rd.METRICS).read_bytes()
    run = RunDir(out)
    ckpt = run.load_checkpoint()

    real = pd.read_parquet

    def read_parquet(source, *a, **k):  # the file fails, the checkpoint's copy (in memory) reads
        if source == out / rd.METRICS:
            raise MemoryError("malloc of size 1048576 failed")
        return real(source, *a, **k)

    monkeypatch.setattr(rd.pd, "read_parquet", read_parquet)
    with pytest.raises(MemoryError):
        run.read_metric_rows(ckpt)
    assert (out / rd.METRICS).read_bytes() == before and "restored" not in capsys.readouterr().err


# -- item 18: extending a finished run ---------------------------------------------------------------------

def test_an_extended_run_equals_a_longer_one_by_seed_and_episode_and_says_its_row_order_differs(tmp_path, reference,
                                                                                               capsys):
    """Item 18: a grid extended from 4 to 6 episodes had metrics.parquet rows "that differ from a 6-episode grid"
    (row 9 on): the same rows, in another order. At the old end the seed that finished first waited for the
    other (a longer run goes on), and rows are written as episodes end. The extension now says so."""
    out = tmp_path / "run"
    train(tiny(episodes=2), out, progress=False)
    capsys.readouterr()
    train(tiny(), out, progress=False)
    assert ("each seed's episodes will equal a run of 4 from the start, but metrics.parquet lists them in the order "
            "they end" in capsys.readouterr().err)
    by_seed = [pd.read_parquet(r / rd.METRICS)[list(rd.METRIC_COLUMNS)].sort_values(["seed", "episode"], kind="stable")
               .reset_index(drop=True) for r in (reference, out)]  # the computed columns (measured times differ)
    pd.testing.assert_frame_equal(*by_seed, check_exact=True)
    assert "the order episodes end" in (ROOT / "docs" / "experiments.md").read_text()
