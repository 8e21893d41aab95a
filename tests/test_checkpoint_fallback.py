"""Which checkpoint a run is read from when latest.pt is damaged or stale (issue 45, faults F7 and F10):
a damaged latest.pt after an extension falls back to previous.pt and the extension re-runs, and an older
checkpoint put in place of a finished run's latest.pt is a named error, not the final networks."""
from __future__ import annotations

import shutil

import pandas as pd
import pytest

from apac_mj.commands.train import _progress_mark
from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.run import run_dir as rd
from apac_mj.run.build import load_run
from apac_mj.run.evaluate import evaluate
from apac_mj.run.run_dir import RunDir, RunMismatch, StaleCheckpoint
from apac_mj.run.trainer import train
from apac_mj.types import TIMING_COLUMNS

from conftest import TINY


def tiny(episodes: int, checkpoint_every: int = 50) -> TrainConfig:
    return TrainConfig(task="changing_target", seeds=(0, 1), episodes=episodes, checkpoint_every=checkpoint_every,
                       actuation="kinematic", agent=AgentConfig(**TINY))


def by_seed_and_episode(run: RunDir) -> pd.DataFrame:
    """metrics.parquet without the measured wall times, in (seed, episode) order."""
    df = run.metrics().drop(columns=[c for c in TIMING_COLUMNS if c in run.metrics().columns])
    return df.sort_values(["seed", "episode", "phase"]).reset_index(drop=True)


def test_a_damaged_latest_after_an_extension_falls_back_to_previous_and_the_extension_reruns(tmp_path, capsys):
    out = tmp_path / "ext"
    train(tiny(4), out, progress=False)
    train(tiny(6), out, progress=False)  # latest.pt: the 6-episode run; previous.pt: the 4-episode one
    run = RunDir(out)
    extended = by_seed_and_episode(run)
    latest = run.checkpoints / rd.LATEST
    latest.write_bytes(latest.read_bytes()[: latest.stat().st_size // 2])
    capsys.readouterr()

    loaded = load_run(out, device="cpu")  # was: RunMismatch "config.json was edited"
    assert loaded.ckpt.path.name == rd.PREVIOUS and loaded.ckpt.member_episode(0) == 4
    assert "using the newest intact checkpoint" in capsys.readouterr().err
    assert run.prepare(tiny(6)) == (rd.config_dict(tiny(6)), 6)

    summary = evaluate(out, protocols=("grid",), limit=1)  # the older networks are not the finished run's
    assert summary["finished"] is False and summary["network_episodes"] == [4, 4]
    capsys.readouterr()
    mark = _progress_mark(run)  # what `apac-mj train` compares to say "trained" or "nothing trained"
    train(tiny(6), out, progress=False)
    assert "is marked finished but" in capsys.readouterr().err
    assert _progress_mark(run) != mark, "the re-run extension gives the same rows, yet it was trained"
    assert run.finished() and run.load_checkpoint().path.name == rd.LATEST
    assert [run.load_checkpoint().member_episode(k) for k in (0, 1)] == [6, 6]
    pd.testing.assert_frame_equal(by_seed_and_episode(run), extended)


def test_an_edited_episode_count_of_a_finished_run_is_still_refused(tmp_path):
    out = tmp_path / "run"
    train(tiny(4), out, progress=False)
    config = (out / rd.CONFIG).read_text()
    (out / rd.CONFIG).write_text(config.replace('"episodes": 4', '"episodes": 6'))
    with pytest.raises(RunMismatch, match=r"says 6 episodes but .*latest.pt holds a run of 4 \(finished\)"):
        load_run(out, device="cpu")


def test_an_older_checkpoint_over_a_finished_runs_latest_is_refused_by_name(tmp_path):
    out = tmp_path / "fin"
    train(tiny(4, checkpoint_every=1), out, progress=False)
    run = RunDir(out)
    final = by_seed_and_episode(run)
    shutil.copyfile(run.checkpoints / rd.PREVIOUS, run.checkpoints / rd.LATEST)
    stale = r"latest.pt is older than the run: it holds seed index \d at episode 3, but .* finished 4 episodes"
    with pytest.raises(StaleCheckpoint, match=stale):
        load_run(out, device="cpu")
    with pytest.raises(StaleCheckpoint, match=stale):
        train(tiny(4, checkpoint_every=1), out, progress=False)
    assert run.finished(), "nothing was written"

    (out / rd.DONE).unlink()  # the way out the error gives: train the missing episodes again from it
    train(tiny(4, checkpoint_every=1), out, progress=False)
    assert [run.load_checkpoint().member_episode(k) for k in (0, 1)] == [4, 4]
    pd.testing.assert_frame_equal(by_seed_and_episode(run), final)
