"""Torch's CPU threads are decided in one place (apac_mj.util.threads) and the library, the CLI and the grid use it
(issue 29 item 1: the README's ``apac_mj.train`` ran at torch's default of 2 threads, ~14x slower than
``apac-mj train`` at 1 on a busy 2-core machine; item 6: ``evaluate`` likewise). The speed itself is measured by
``bench/threads.py``, not here; these tests check the setting."""
from __future__ import annotations

import pytest
import torch

import apac_mj
from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.util import threads as th

from conftest import TINY


def _cfg(episodes: int = 2) -> TrainConfig:
    return TrainConfig(task="changing_target", seeds=(0, 1), episodes=episodes, checkpoint_every=episodes,
                       actuation="kinematic", agent=AgentConfig(kind="apac", **TINY))


@pytest.fixture
def caller_threads():
    """The caller (a notebook, say) runs torch at 2 threads; restored after the test (conftest pins 1)."""
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    yield 2
    torch.set_num_threads(before)


def _seen(counts: list[int]):
    """An on_step hook noting the torch thread count at every training or test step."""
    def on_step(info, env) -> None:
        counts.append(torch.get_num_threads())
    return on_step


def test_the_default_is_one_thread() -> None:
    assert th.DEFAULT_THREADS == 1
    assert th.resolve(None) == 1 and th.resolve(3) == 3
    for bad in (0, -1, True, 1.5, "2"):
        with pytest.raises(ValueError, match="threads must be an int >= 1"):
            th.resolve(bad)


def test_library_train_runs_at_the_default_and_restores_the_callers(tmp_path, caller_threads) -> None:
    """The README's ``apac_mj.train(cfg, out)``, asking for nothing, trains at DEFAULT_THREADS (on the landed code:
    at the caller's 2) and leaves the caller's count as it was."""
    counts: list[int] = []
    apac_mj.train(_cfg(), tmp_path / "run", progress=False, on_step=_seen(counts))
    assert counts and set(counts) == {th.DEFAULT_THREADS}
    assert torch.get_num_threads() == caller_threads


@pytest.fixture
def counted_threads(monkeypatch) -> dict[str, int]:
    """``torch.set_num_threads`` and ``get_num_threads`` on a count kept here, the caller's 1 to begin with: what the
    library sets is seen and restored as on torch, while torch itself stays at 1 (at a real 2, a run on a busy
    2-core machine is the slowdown apac_mj.util.threads documents)."""
    count = {"n": 1}
    monkeypatch.setattr(torch, "set_num_threads", lambda n: count.update(n=n))
    monkeypatch.setattr(torch, "get_num_threads", lambda: count["n"])
    return count


def test_library_train_runs_at_the_count_asked_for(tmp_path, counted_threads) -> None:
    """Every step of a one-episode run sees the count asked for (2); the caller's (1) is back after it."""
    counts: list[int] = []
    apac_mj.train(_cfg(episodes=1), tmp_path / "run", progress=False, on_step=_seen(counts), threads=2)
    assert counts and set(counts) == {2}
    assert counted_threads["n"] == 1
    with pytest.raises(ValueError, match="threads must be an int >= 1"):
        apac_mj.train(_cfg(), tmp_path / "refused", progress=False, threads=0)
    assert not (tmp_path / "refused").exists()


def test_library_evaluate_runs_at_the_default_or_the_count_asked_for(tmp_path, caller_threads) -> None:
    run = apac_mj.train(_cfg(), tmp_path / "run", progress=False)
    counts: list[int] = []
    apac_mj.evaluate(run, protocols=("grid",), limit=2, on_step=_seen(counts))
    assert counts and set(counts) == {th.DEFAULT_THREADS}
    assert torch.get_num_threads() == caller_threads
    counts.clear()
    torch.set_num_threads(1)
    apac_mj.evaluate(run, protocols=("grid",), limit=2, on_step=_seen(counts), threads=2)
    assert counts and set(counts) == {2} and torch.get_num_threads() == 1


def test_the_cli_takes_its_default_from_the_same_place(monkeypatch, tmp_path) -> None:
    """``apac-mj train`` and ``apac-mj evaluate``: ``--threads`` defaults to DEFAULT_THREADS and reaches the library
    call; a changed default changes both."""
    import argparse

    from apac_mj.commands import evaluate as evaluate_cmd, train as train_cmd

    monkeypatch.setattr(th, "DEFAULT_THREADS", 3)
    for command in (train_cmd, evaluate_cmd):
        parser = argparse.ArgumentParser()
        command.register(parser.add_subparsers())
        name = command.__name__.rsplit(".", 1)[1]
        required = {"train": ["--out", "x"], "evaluate": ["x"]}[name]
        assert parser.parse_args([name, *required]).threads == 3

    seen = {}

    def fake_evaluate(run_dir, **kw):
        seen.update(kw)
        return {"run_dir": str(run_dir), "agent": "apac", "task": "t", "protocols": {}}

    monkeypatch.setattr("apac_mj.run.evaluate.evaluate", fake_evaluate)
    monkeypatch.setattr("apac_mj.commands.hints.results_dir_hint", lambda *a: None)
    from apac_mj.cli import main

    assert main(["evaluate", str(tmp_path), "--threads", "2"]) == 0
    assert seen["threads"] == 2


def test_a_grid_cell_trains_and_tests_at_its_presets_threads(monkeypatch, tmp_path) -> None:
    """run_cell hands the preset's ``threads`` to train and evaluate (which would otherwise apply the default)."""
    from apac_mj.experiments import grid

    calls = {}
    monkeypatch.setattr(grid, "_cell_file", lambda d: {"train_config": {}, "protocols": ["grid"], "test_limit": 2})
    monkeypatch.setattr(grid, "cell_done", lambda d: False)
    monkeypatch.setattr(grid, "train_config_from_dict", lambda d: None)
    monkeypatch.setattr("apac_mj.run.trainer.train",
                        lambda cfg, d, progress, threads: calls.setdefault("train", threads))
    monkeypatch.setattr("apac_mj.run.evaluate.evaluate",
                        lambda d, protocols, limit, threads: calls.setdefault("evaluate", threads))
    before = torch.get_num_threads()
    try:
        grid.run_cell(tmp_path, progress=False, threads=2)
    finally:
        torch.set_num_threads(before)
    assert calls == {"train": 2, "evaluate": 2}


def test_evaluate_labels_each_progress_bar_with_its_protocol(tmp_path, capsys) -> None:
    """Issue 29 item 6: both bars read only 'evaluate:'; each names its protocol now."""
    run = apac_mj.train(_cfg(), tmp_path / "run", progress=False)
    capsys.readouterr()
    apac_mj.evaluate(run, protocols=("grid", "occluded"), limit=2, progress=True)
    err = capsys.readouterr().err
    assert "evaluate grid:" in err and "evaluate occluded:" in err
