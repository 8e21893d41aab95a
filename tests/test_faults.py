"""Faults and bad input (issue 18; the review docs/reliability.md points to): one writer per run directory,
kills and signals at any moment, damaged and edited files, and every input checked before anything is
written. Each test reproduces one failure of the review (F1-F21) and checks the answer; the kill tests
compare the resumed numbers with an uninterrupted run's."""
from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from apac_mj.cli import main, os_error_message
from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.run import checkpoint
from apac_mj.run import run_dir as rd
from apac_mj.run.evaluate import evaluate
from apac_mj.run.run_dir import RunDir, RunMismatch
from apac_mj.run.trainer import train
from apac_mj.suite.task_spec import TaskSpecError, load_task, load_task_file
from apac_mj.util import files
from apac_mj.util.lock import DirectoryLocked, locked
from apac_mj.util.overrides import OverrideError, parse_seeds

from conftest import TINY, TINY_SETS, deterministic

ROOT = Path(__file__).resolve().parent.parent
ENV = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=str(ROOT))


def tiny(episodes: int = 4, agent: str = "apac", seeds=(0, 1), **kw) -> TrainConfig:
    return TrainConfig(task="changing_target", seeds=tuple(seeds), episodes=episodes, checkpoint_every=1,
                       actuation="kinematic", agent=AgentConfig(kind=agent, **{**TINY, **kw}))


def train_args(out: Path, episodes: int = 4, agent: str = "apac") -> list[str]:
    return ["train", "--task", "changing_target", "--agent", agent, "--seeds", "0-1", "--episodes", str(episodes),
            "--checkpoint-every", "1", "--actuation", "kinematic", "--no-progress", "--out", str(out), *TINY_SETS]


def same_run(a: Path, b: Path, by_seed: bool = False) -> None:
    """Identical metric rows (``by_seed``: in (seed, episode) order: an extended run's members finish their
    last episodes in another order than a longer run's) and final networks."""
    ma, mb = pd.read_parquet(a / "metrics.parquet"), pd.read_parquet(b / "metrics.parquet")
    if by_seed:
        ma, mb = (m.sort_values(["seed", "episode"], kind="stable").reset_index(drop=True) for m in (ma, mb))
    pd.testing.assert_frame_equal(deterministic(ma), deterministic(mb), check_exact=True)
    wa = checkpoint.load(a / "checkpoints" / "latest.pt")["agent"]["networks"]
    wb = checkpoint.load(b / "checkpoints" / "latest.pt")["agent"]["networks"]
    for net in wa:
        assert all(torch.equal(wa[net][k], wb[net][k]) for k in wa[net]), net


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """An uninterrupted run of ``tiny()`` (4 episodes, a checkpoint after each)."""
    return train(tiny(), tmp_path_factory.mktemp("ref") / "run", progress=False)


def finished_copy(reference: Path, tmp_path: Path) -> Path:
    import shutil

    return Path(shutil.copytree(reference, tmp_path / "run"))


# -- F7: one writer per run directory ----------------------------------------------------------

HOLD_LOCK = ("import sys, time\nfrom apac_mj.util.lock import locked\n"
             "with locked(sys.argv[1]):\n    print('locked', flush=True)\n    time.sleep(120)\n")


def hold_lock(directory: Path) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", HOLD_LOCK, str(directory)], env=ENV, stdout=subprocess.PIPE,
                            text=True)
    assert proc.stdout.readline().strip() == "locked"
    return proc


def test_a_second_writer_is_refused_naming_the_holder_and_a_killed_holder_leaves_no_lock(tmp_path, reference):
    out = finished_copy(reference, tmp_path)
    before = sorted(p.name for p in out.rglob("*"))
    holder = hold_lock(out)
    try:
        for write in (lambda: train(tiny(episodes=6), out, progress=False), lambda: evaluate(out, limit=1)):
            with pytest.raises(DirectoryLocked, match=rf"{out} is in use: PID {holder.pid} .*kill {holder.pid}"):
                write()
        assert sorted(p.name for p in out.rglob("*")) == before, "the refused writers wrote nothing"
    finally:
        holder.send_signal(signal.SIGKILL)  # the OS releases its lock: nothing stale is left
        holder.wait()
    evaluate(out, limit=1, protocols=("grid",))
    assert RunDir(out).evaluated()


def test_the_lock_is_reentrant_in_a_process_and_a_failed_start_leaves_nothing(tmp_path):
    out = tmp_path / "new"
    with locked(out):
        with locked(out):
            assert (out / ".lock").read_text().startswith(f"{os.getpid()}\n")
    assert not out.exists(), "a directory the lock created and nothing wrote into is removed again"
    with pytest.raises(ValueError, match="seeds must be distinct"):
        train(tiny(seeds=(1, 1)), out, progress=False)
    assert not out.exists()


@pytest.mark.slow
def test_two_trains_of_different_agents_started_together_one_is_refused(tmp_path, reference):
    """F7 as the review ran it: apac and spac into one --out at once. One trains, the other is refused
    naming the first's PID; the directory holds the winner's run only."""
    out = tmp_path / "run"
    procs = {agent: subprocess.Popen([sys.executable, "-m", "apac_mj.cli", *train_args(out, agent=agent)], env=ENV,
                                     cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for agent in ("apac", "spac")}
    done = {agent: (p.wait(timeout=600), p.stderr.read()) for agent, p in procs.items()}
    winners = [a for a, (rc, _) in done.items() if rc == 0]
    assert len(winners) == 1, done
    loser = ({"apac", "spac"} - set(winners)).pop()
    rc, err = done[loser]
    assert rc == 2 and f"is in use: PID {procs[winners[0]].pid}" in err, err
    kinds = {checkpoint.load(out / "checkpoints" / f)["config"]["agent"]["kind"] for f in ("latest.pt", "previous.pt")}
    assert kinds == {winners[0]} and RunDir(out).config()["agent"]["kind"] == winners[0]
    if winners[0] == "apac":
        same_run(reference, out)


# -- F1: kill -9 inside a write; the next writer removes the temporary -------------------------

#: Runs the CLI and kills itself (SIGKILL) on entry to its K-th fsync: odd ones sync a file about to be
#: renamed into place, so its temporary is on disk (the review's strace injection, without strace).
KILL_AT_FSYNC = """
import os, signal, sys
count, real = [0], os.fsync
def fsync(fd):
    count[0] += 1
    if count[0] == int(sys.argv[1]):
        os.kill(os.getpid(), signal.SIGKILL)
    real(fd)
os.fsync = fsync
from apac_mj.cli import main
sys.exit(main(sys.argv[2:]))
"""


@pytest.mark.slow  # 11-12 s each on the shared 2-core machine at load 4.5 (a subprocess start, 4 tiny episodes, a resume)
@pytest.mark.parametrize("k", [7, 9])  # the file synced before the rename: 7 metrics.parquet, 9 latest.pt, of episode 2
def test_kill_9_inside_a_write_then_resume_removes_the_temporary_and_equals_uninterrupted(tmp_path, reference, k,
                                                                                        capsys):
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-c", KILL_AT_FSYNC, str(k), *train_args(out)], env=ENV, cwd=ROOT,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    left = sorted(p.name for p in out.rglob(".*.tmp"))
    assert len(left) == 1 and left[0].startswith((".metrics.parquet.", ".latest.pt.")), left
    assert main(train_args(out)) == 0
    err = capsys.readouterr().err
    assert "removed 1 temporary file(s) a killed writer left" in err and left[0] in err
    assert not list(out.rglob(".*.tmp"))
    same_run(reference, out)


def test_a_live_writers_temporary_is_kept(tmp_path):
    mine = tmp_path / f".x.json.{os.getpid()}.abcdefgh.tmp"
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    gone = tmp_path / f".x.json.{dead.pid}.abcdefgh.tmp"
    old = tmp_path / ".x.json.abcdefgh.tmp"  # older releases: no PID
    for p in (mine, gone, old):
        p.write_bytes(b"partial")
    assert sorted(files.remove_stale_temporaries(tmp_path)) == sorted([gone, old])
    assert mine.exists()


# -- F3: SIGTERM is Ctrl-C --------------------------------------------------------------------

@pytest.mark.slow
def test_sigterm_says_what_was_saved_and_resume_equals_uninterrupted(tmp_path, reference):
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "apac_mj.cli", *train_args(out)], env=ENV, cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while not (out / "checkpoints" / "latest.pt").exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    err = proc.communicate(timeout=120)[1]
    if proc.returncode == 0:
        pytest.skip("the run finished before SIGTERM arrived")
    assert proc.returncode == 143, err
    assert "terminated (SIGTERM)" in err and "checkpoints/latest.pt holds the run after" in err, err
    assert "run the same command again to resume" in err
    assert main(train_args(out)) == 0
    same_run(reference, out)


# -- F2, F4: the grid's workers stop with it ------------------------------------------------------

GRID_SETS = ["seeds=2", "episodes=6", "checkpoint_every=1", "conditions=changing_target", "agents=apac,spac,ddpg",
             "tests.generalization=false", "tests.occluded=false", "tests.limit=2",
             "actor_hidden=16,16", "critic_hidden=16,16", "forward_hidden=16,16", "inverse_hidden=16,16",
             "batch_size=8", "replay_size=64", "babbling_episodes=1", "planning_episodes=2"]


def grid_cmd(out: Path, workers: int = 2) -> list[str]:
    return [sys.executable, "-m", "apac_mj.cli", "grid", "--preset", "smoke", "--out", str(out), "--no-progress",
            "--workers", str(workers), *[a for s in GRID_SETS for a in ("--set", s)]]


def children(pid: int) -> list[int]:
    """The live child processes of ``pid`` (Linux /proc)."""
    out = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            out += [int(c) for c in (task / "children").read_text().split()]
        except OSError:
            pass
    return out


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0]
    except OSError:
        return False
    return state != "Z"


def start_grid_until_a_checkpoint(out: Path) -> tuple[subprocess.Popen, list[int]]:
    proc = subprocess.Popen(grid_cmd(out), env=ENV, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)
    deadline = time.monotonic() + 300
    while not list(out.glob("*/checkpoints/latest.pt")) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    assert proc.poll() is None, "the grid ended before its first checkpoint"
    return proc, children(proc.pid)


@pytest.mark.slow
@pytest.mark.parametrize("how", ["kill -9", "SIGTERM", "Ctrl-C"])
def test_a_stopped_parallel_grid_stops_its_workers_and_resumes_to_the_same_numbers(tmp_path, how):
    from apac_mj.experiments.results import load_results, load_tests

    clean, stopped = tmp_path / "clean", tmp_path / "stopped"
    proc, workers = start_grid_until_a_checkpoint(stopped)
    assert len(workers) >= 2, workers
    start = time.monotonic()
    if how == "kill -9":
        proc.kill()
    elif how == "SIGTERM":
        proc.terminate()
    else:
        os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C: the terminal signals the whole process group
    err = proc.communicate(timeout=60)[1]
    while any(alive(w) for w in workers) and time.monotonic() - start < 30:
        time.sleep(0.1)
    stopped_after = time.monotonic() - start
    assert not any(alive(w) for w in workers), f"workers still running {stopped_after:.0f} s after {how}"
    assert stopped_after < 15, stopped_after
    if how != "kill -9":
        assert proc.returncode == (143 if how == "SIGTERM" else 130), err
        assert "interrupted:" in err and "run the same command again to resume" in err, err
    subprocess.run(grid_cmd(clean), check=True, env=ENV, cwd=ROOT, timeout=900, capture_output=True)
    subprocess.run(grid_cmd(stopped), check=True, env=ENV, cwd=ROOT, timeout=900, capture_output=True)
    pd.testing.assert_frame_equal(deterministic(load_results(clean)), deterministic(load_results(stopped)),
                                  check_exact=True)  # all but the measured wall times
    pd.testing.assert_frame_equal(deterministic(load_tests(clean)), deterministic(load_tests(stopped)),
                                  check_exact=True)


def test_grid_refuses_a_results_directory_another_grid_writes(tmp_path, capsys):
    out = tmp_path / "results"
    holder = hold_lock(out)
    try:
        rc = main(["grid", "--preset", "smoke", "--out", str(out), "--no-progress", "--set", "agents=apac",
                   "--set", "conditions=changing_target", "--set", "episodes=1", "--set", "seeds=1"])
    finally:
        holder.kill()
        holder.wait()
    assert rc == 2 and f"is in use: PID {holder.pid}" in capsys.readouterr().err
    assert [p.name for p in out.iterdir()] == [".lock"]


# -- F5: recordings are atomic ----------------------------------------------------------------

def _recording(path: Path, episodes: int, fail: bool = False) -> None:
    from apac_mj.recording.recording import Recording, StepRecord

    with Recording(path, {"task": "changing_target", "episodes": episodes}) as rec:
        for e in range(episodes):
            rec.start_episode(e, (20.0, 20.0), (5.0, 8.0))
            for k in range(3):
                rec.log_step(StepRecord(episode=e, step=k, true_arm=np.array([28.0, 15.0, 20.0, 15.0]),
                                        joint_angles=np.array([0.0, 180.0]), link_lengths=np.array([5.0, 8.0]),
                                        target=np.array([20.0, 20.0]), distance=5.0, vision=True), None)
            if fail and e == 1:
                raise KeyboardInterrupt  # Ctrl-C, or SIGTERM (the CLI raises the same) mid-recording


def test_an_interrupted_recording_keeps_the_previous_file_and_is_marked_partial(tmp_path):
    from apac_mj.recording.recording import read_recording, recording_complete

    out = tmp_path / "rollout.rrd"
    _recording(out, 2)
    before = out.read_bytes()
    with pytest.raises(KeyboardInterrupt):
        _recording(out, 5, fail=True)
    assert out.read_bytes() == before, "the previous recording is untouched"
    partial = tmp_path / "rollout.partial.rrd"
    entities, props, _ = read_recording(partial)
    assert recording_complete(partial) is False and recording_complete(out) is True
    assert np.ravel(props["episodes"])[0] == 5 and "plane/target" in entities, "flushed: config and targets are in it"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rollout.partial.rrd", "rollout.rrd"]


def test_a_killed_recordings_temporary_is_removed_by_the_next(tmp_path):
    """What a recording killed with -9 leaves (its temporary, named by its dead PID) goes with the next recording
    of that file; another file's temporaries and a live process's stay."""
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    left = tmp_path / f".rollout.rrd.{dead.pid}.abcdefgh.tmp"
    other = tmp_path / f".other.rrd.{dead.pid}.abcdefgh.tmp"
    live = tmp_path / f".rollout.rrd.{os.getppid()}.abcdefgh.tmp"
    for p in (left, other, live):
        p.write_bytes(b"RRF2 partial")
    _recording(tmp_path / "rollout.rrd", 1)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([other.name, live.name, "rollout.rrd"])


def test_a_huge_plane_records_a_bounded_distance_field():
    """F16: the field was O(plane^2) pixels (182 TiB for a 1e6 cm plane)."""
    from apac_mj.recording import recording as R

    assert R.distance_field((15.0, 15.0), (30.0, 30.0)).shape == (150, 150, 3), "the paper's plane: as before"
    field = R.distance_field((5e3, 5e3), (1e4, 1e4))
    assert field.shape == (R.FIELD_MAX_PX, R.FIELD_MAX_PX, 3)
    r, c = np.unravel_index(field.astype(float).sum(axis=2).argmin(), field.shape[:2])
    px = R.field_px_per_cm((1e4, 1e4))
    assert abs(c / px - 5e3) < 100 and abs(r / px - 5e3) < 100, "still darkest within 1% of the plane at the target"


# -- F6: disk full and read-only: a message naming the file and the way out -----------------------

def test_disk_full_at_a_checkpoint_names_the_file_keeps_the_last_and_resumes_exactly(tmp_path, reference, capsys,
                                                                                     monkeypatch):
    out = tmp_path / "run"
    real, count = os.fsync, [0]

    def full(fd: int) -> None:  # the 13th fsync: the 3rd checkpoint's file (config.json 1-2, then 4 per episode)
        count[0] += 1
        if count[0] == 13:
            raise OSError(errno.ENOSPC, "No space left on device")
        real(fd)

    monkeypatch.setattr(files.os, "fsync", full)
    assert main(train_args(out)) == 2
    err = capsys.readouterr().err
    assert f"apac-mj train: error: no space left on the device of {out}/checkpoints/latest.pt" in err, err
    assert "run the same command again: what was written is intact, and a run resumes from its last checkpoint" in err
    assert not list(out.rglob(".*.tmp")), "the failed write's temporary is removed"
    assert checkpoint.load(out / "checkpoints" / "latest.pt")["loop"]["episode"].min() == 2
    monkeypatch.setattr(files.os, "fsync", real)
    assert main(train_args(out)) == 0
    same_run(reference, out)


@pytest.mark.parametrize("code, says", [(errno.EROFS, "read-only file system; use an --out on a writable one"),
                                        (errno.EACCES, "permission denied for"), (errno.EDQUOT, "quota")])
def test_os_errors_name_the_file_and_the_way_out(code, says):
    message = os_error_message(OSError(code, os.strerror(code), "runs/x/config.json"))
    assert "runs/x/config.json" in message and says in message


# -- F8, F9: metrics.parquet against the checkpoint's digest ----------------------------------------

@pytest.mark.parametrize("damage", ["random bytes", "truncated", "deleted", "values edited"])
def test_damaged_or_edited_metrics_are_restored_from_the_checkpoint(tmp_path, reference, damage, capsys):
    """F8 (a damaged file blocked the run, naming no file) and F9 (edited rows were kept): extend a 2-episode
    run to 4 with its metrics.parquet damaged; the rows come back from the checkpoint and the run equals
    the uninterrupted 4-episode one."""
    out = tmp_path / "run"
    train(tiny(episodes=2), out, progress=False)
    metrics = out / "metrics.parquet"
    if damage == "random bytes":
        metrics.write_bytes(np.random.default_rng(0).bytes(metrics.stat().st_size))
    elif damage == "truncated":
        metrics.write_bytes(metrics.read_bytes()[:300])
    elif damage == "deleted":
        metrics.unlink()
    else:
        df = pd.read_parquet(metrics)
        df["success"] = ~df["success"]
        df.to_parquet(metrics, index=False)
    train(tiny(episodes=4), out, progress=False)
    err = capsys.readouterr().err
    assert f"warning: {metrics}" in err and "restored its" in err, err
    same_run(reference, out, by_seed=True)


def test_edited_metrics_of_a_finished_run_are_restored(tmp_path, reference, capsys):
    out = finished_copy(reference, tmp_path)
    df = pd.read_parquet(out / "metrics.parquet")
    df.loc[0, "return"] += 1e-9
    df.to_parquet(out / "metrics.parquet", index=False)
    train(tiny(), out, progress=False)
    assert "differ from those checkpoint" in capsys.readouterr().err
    same_run(reference, out)


def test_an_old_run_without_a_digest_still_resumes(tmp_path):
    """Checkpoints of releases before digests (tests/fixtures/run_936695d) load; damage is named, not guessed."""
    import shutil

    run = Path(shutil.copytree(ROOT / "tests" / "fixtures" / "run_936695d", tmp_path / "old"))
    ckpt = RunDir(run).load_checkpoint()
    assert ckpt.metric_digest is None and ckpt.metric_table() is None
    assert len(RunDir(run).read_metric_rows(ckpt)) == ckpt.metric_rows
    (run / "metrics.parquet").write_bytes(b"not parquet")
    with pytest.raises(RunMismatch, match="metrics.parquet cannot be read.*older release.*backup"):
        RunDir(run).read_metric_rows(ckpt)


# -- F10: invalid JSON names the file ----------------------------------------------------------

def test_invalid_json_names_the_file_and_the_way_out(tmp_path, reference, capsys):
    out = finished_copy(reference, tmp_path)
    (out / "config.json").write_text("{")
    assert main(["evaluate", str(out), "--limit", "1", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert f"{out}/config.json is not valid JSON" in err and "put back the file" in err, err
    (out / "config.json").write_text((reference / "config.json").read_text())
    (out / "eval").mkdir(exist_ok=True)
    (out / "eval" / "summary.json").write_text("{")
    assert not RunDir(out).evaluated(), "a damaged summary: the tests run again (the grid re-runs them)"
    evaluate(out, limit=1, protocols=("grid",))
    assert RunDir(out).evaluated() and RunDir(out).eval_summary()["protocols"]["grid"]


def test_a_damaged_cell_json_is_named_with_the_way_out(tmp_path, capsys):
    out = tmp_path / "results"
    (out / "apac__changing_target").mkdir(parents=True)
    (out / "apac__changing_target" / "cell.json").write_bytes(b"\x80{")
    rc = main(["grid", "--preset", "smoke", "--out", str(out), "--no-progress", "--dry-run", "--set", "agents=apac",
               "--set", "conditions=changing_target"])
    err = capsys.readouterr().err
    assert rc == 2 and "apac__changing_target/cell.json is not valid JSON" in err and "delete that one file" in err


# -- F11, F12, F13: the checkpoint is the truth ------------------------------------------------------

def edit_config(run: Path, **agent) -> None:
    cfg = json.loads((run / "config.json").read_text())
    cfg["agent"].update(agent)
    (run / "config.json").write_text(json.dumps(cfg))


def test_evaluate_refuses_a_config_json_that_disagrees_with_the_checkpoint(tmp_path, reference):
    """F11: with the agent edited apac -> ddpg, evaluate reported DDPG's success (0.0) for APAC's networks."""
    out = finished_copy(reference, tmp_path)
    edit_config(out, kind="ddpg")
    with pytest.raises(RunMismatch, match=r"config.json disagrees with the run's checkpoint .*latest.pt "
                                          r"\(agent.kind: 'apac' in the checkpoint, 'ddpg' in config.json\)"):
        evaluate(out, limit=1)
    assert not (out / "eval").exists()


@pytest.mark.parametrize("resumed_as", ["edited", "original"])
def test_an_edited_config_is_named_and_deleting_the_run_is_never_advised(tmp_path, reference, resumed_as):
    """F12: the refusal said 'no intact checkpoint is left: delete the run directory'."""
    out = finished_copy(reference, tmp_path)
    (out / "DONE").unlink()
    edit_config(out, kind="ddpg")
    with pytest.raises(RunMismatch) as e:
        train(tiny(agent="ddpg" if resumed_as == "edited" else "apac"), out, progress=False)
    assert "config.json was edited" in str(e.value) and "intact" in str(e.value) and "delete" not in str(e.value)
    edit_config(out, kind="apac")  # the way out it names
    train(tiny(), out, progress=False)
    same_run(reference, out)


@pytest.mark.parametrize("episodes", [8, 2])
def test_an_edited_episode_count_is_not_taken_for_a_finished_run(tmp_path, reference, episodes):
    """F13: config.json episodes 4 -> 8 with DONE: 'already finished 8 episodes' for a run of 4."""
    out = finished_copy(reference, tmp_path)
    cfg = json.loads((out / "config.json").read_text())
    (out / "config.json").write_text(json.dumps({**cfg, "episodes": episodes}))
    with pytest.raises(RunMismatch, match=rf"says {episodes} episodes but the run's checkpoint .* holds a run of 4"):
        train(tiny(episodes=episodes), out, progress=False)


# -- F14-F21: every input checked before anything is written --------------------------------------

def test_a_binary_task_file_is_named(tmp_path):
    """F14: UnicodeDecodeError without the file's name."""
    bad = tmp_path / "binary.toml"
    bad.write_bytes(bytes(range(256)))
    with pytest.raises(TaskSpecError, match=rf"{bad}: not a task file: not UTF-8"):
        load_task_file(bad)


@pytest.mark.parametrize("name", ["../pyproject", "../../etc/passwd", "/tmp/x", "sub/changing_target", ".hidden",
                                  "changing_target/../changing_target"])
def test_task_names_do_not_leave_the_task_directory(name, tmp_path):
    """F17: --task ../pyproject read the repository's pyproject.toml as a task."""
    with pytest.raises(KeyError, match="is not a task name"):
        load_task(name)
    rc = main(["train", "--task", name, "--episodes", "1", "--out", str(tmp_path / "r"), "--no-progress"])
    assert rc == 2 and not (tmp_path / "r").exists()


@pytest.mark.parametrize("override, message", [
    ("{growth_start_episode=\"x\"}", "growth_start_episode must be an integer"),
    ("{plane_size=[30.0]}", "plane_size must be a list of two numbers"),
    ("{origin=\"ab\"}", "origin must be a list of two numbers"),
    ("{region=\"top\"}", "region must be a finite number"),
    ("{steps_per_episode=1.5}", "steps_per_episode must be an integer"),  # F19: ran episodes of 2 steps
    ("{zone_radius=true}", "zone_radius must be a finite number"),        # F19: ran with a 1 cm zone
    ("{plane_size=[1e6, 1e6]}", "plane_size must be at most"),            # F16
    ("{growth_per_step=1e308}", "growth_per_step x steps_per_episode must be at most"),  # F15
])
def test_task_overrides_are_typed_and_bounded_before_anything_is_written(tmp_path, capsys, override, message):
    """F18 (tracebacks), F19 (silently accepted), F15/F16 (absurd sizes failing late)."""
    out = tmp_path / "r"
    rc = main(["train", "--episodes", "1", "--out", str(out), "--no-progress", "--set", f"task_overrides={override}"])
    assert rc == 2 and message in capsys.readouterr().err and not out.exists()


@pytest.mark.parametrize("setting", ["agent.delta_threshold=nan", "ou_sigma=nan", "babbling_scale=inf",
                                     "action_scale=nan", "feasibility_weight=inf", "ou_sigma=1e308",
                                     "weight_decay=-1"])
def test_non_finite_or_absurd_agent_numbers_are_refused_before_anything_is_written(tmp_path, capsys, setting):
    """F20 (delta_threshold = nan silently changed APAC's arbitration) and F15 (NaN/inf failed mid-run with
    'action must be finite', leaving a config.json that refused the corrected rerun)."""
    out = tmp_path / "r"
    rc = main(["train", "--episodes", "1", "--out", str(out), "--no-progress", "--set", setting])
    name = setting.split("=")[0].split(".")[-1]
    assert rc == 2 and f"{name} must be" in capsys.readouterr().err and not out.exists()


def test_a_noise_std_of_1e308_in_a_task_file_is_refused(tmp_path):
    """F15: [vision] noise_std = 1e308 passed validation and failed mid-run with 'action must be finite'."""
    f = tmp_path / "noisy.toml"
    f.write_text('[vision]\nmode = "noisy"\nnoise_std = 1e308\n')
    with pytest.raises(TaskSpecError, match=r"noise_std.* must be at most"):
        load_task_file(f)


@pytest.mark.parametrize("seeds", ["1000000000", "0-99999999999", "99999999999999999999999", "0,4294967296"])
def test_huge_seed_specs_are_refused_before_they_are_expanded(seeds):
    """F21: the whole tuple was built first (MemoryError after 9-11 s, or OverflowError)."""
    start = time.perf_counter()
    with pytest.raises(OverrideError, match="at most 10000|in \\[1, 10000\\]|in \\[0, 2\\^32\\)"):
        parse_seeds(seeds, "--seeds")
    assert time.perf_counter() - start < 0.5
    assert len(parse_seeds("0-9999")) == 10000


def test_a_run_that_fails_at_its_first_reset_leaves_nothing_to_block_the_fix(tmp_path, capsys):
    """F15's second half: a failed start left a config.json that refused the corrected command."""
    out = tmp_path / "r"
    rc = main(["train", "--episodes", "1", "--out", str(out), "--no-progress", *TINY_SETS,
               "--set", 'task_overrides={target_region="test", region=100.0}'])
    assert rc == 2 and "no reachable target" in capsys.readouterr().err and not out.exists()


@pytest.mark.slow
@pytest.mark.ray
def test_a_killed_ray_driver_leaves_no_ray_process(tmp_path):
    """F2 (Ray): kill -9 of the driver left ray::DashboardAgent and ray::RuntimeEnvAgent running (they wait 60 s
    to report the death to the gone GCS); the grid's watchdog stops them."""
    pytest.importorskip("ray")
    script = ("import os, signal, sys, time\nfrom apac_mj.experiments.executors import RayExecutor\n"
              "def cell(d, progress, threads):\n    os.kill(os.getppid() if False else int(d), signal.SIGKILL)\n"
              "RayExecutor(num_cpus=1).run([str(os.getpid())], cell, print, progress=False)\n")
    before = set(subprocess.run(["pgrep", "-f", "ray::"], capture_output=True, text=True).stdout.split())
    proc = subprocess.run([sys.executable, "-c", script], env=ENV, cwd=ROOT, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == -signal.SIGKILL, proc.stderr[-2000:]
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        left = set(subprocess.run(["pgrep", "-f", "ray::"], capture_output=True, text=True).stdout.split()) - before
        if not left:
            break
        time.sleep(0.5)
    assert not left, f"Ray processes still running 20 s after the driver's kill -9: {left}"
