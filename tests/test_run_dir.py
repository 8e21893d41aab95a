"""The run directory (apac_mj.run.run_dir): what it reads and writes, the config diff, checkpoints' files
and keys, a run written by an older release, and that no other module opens its files by name."""
from __future__ import annotations

import ast
import dataclasses
import json
import shutil
from pathlib import Path

import pandas as pd
import pytest
import torch

from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.run import run_dir as rd
from apac_mj.run.build import load_run
from apac_mj.run.checkpoint import CheckpointError
from apac_mj.run.run_dir import RunCheckpoint, RunDir

from conftest import TINY

PACKAGE = Path(__file__).resolve().parents[1] / "apac_mj"
#: A run directory written by release 936695d (tests/fixtures/run_936695d/README.md).
OLD_RUN = Path(__file__).resolve().parent / "fixtures" / "run_936695d"


def tiny_config(episodes: int = 4, **kw) -> TrainConfig:
    return TrainConfig(task="changing_target", seeds=(0, 1), episodes=episodes, checkpoint_every=2,
                       actuation="kinematic", agent=AgentConfig(**{**TINY, **kw}))


def written(run: RunDir, cfg: TrainConfig) -> dict:
    config, episodes = run.prepare(cfg)
    run.write_config(config, episodes)
    return config


def fake_checkpoint(metric_rows: int = 0, episode: int = 2) -> dict:
    """A checkpoint with every key a training checkpoint has (contents: small stand-ins)."""
    env = {"members": [{"task": {"lengths": torch.tensor([5.0 + k, 8.0]), "static_target": None}} for k in (0, 1)]}
    loop = {"episode": torch.tensor([episode, episode + 1])}
    return RunCheckpoint.layout({"episodes": 4}, loop, {"w": torch.ones(2)}, env, {"arbitrator": {}, "integrator": {}},
                                [torch.Generator().get_state()], metric_rows)


def test_config_round_trip_keeps_the_commit_out_of_the_config(tmp_path):
    run, cfg = RunDir(tmp_path / "run"), tiny_config()
    assert not run.exists() and run.episodes() is None
    config = written(run, cfg)
    stored = json.loads((run.path / rd.CONFIG).read_text())
    assert stored["git_commit"] and stored["git_commit"] == rd.git_commit()
    assert run.config() == config == rd.config_dict(cfg) and "git_commit" not in run.config()
    assert run.train_config() == cfg and run.episodes() == 4


def test_extending_keeps_the_commit_and_unfinishes(tmp_path):
    run = RunDir(tmp_path / "run")
    written(run, tiny_config())
    stored = json.loads((run.path / rd.CONFIG).read_text())
    stored["git_commit"] = "the commit the run started at"
    (run.path / rd.CONFIG).write_text(json.dumps(stored))
    run.mark_finished()
    assert run.finished()
    config, episodes = run.prepare(tiny_config(episodes=6))
    assert episodes == 4 and run.finished(), "prepare writes nothing"
    run.write_config(config, episodes)
    assert not run.finished() and run.episodes() == 6
    assert json.loads((run.path / rd.CONFIG).read_text())["git_commit"] == "the commit the run started at"


def test_prepare_refuses_another_config_or_fewer_episodes_and_writes_nothing(tmp_path):
    run = RunDir(tmp_path / "run")
    assert run.prepare(tiny_config()) == (rd.config_dict(tiny_config()), None)
    assert not run.path.exists()
    written(run, tiny_config())
    before = (run.path / rd.CONFIG).read_text()
    with pytest.raises(ValueError, match=r"different config \(agent.batch_size: 8 in the run, 4 now\)"):
        run.prepare(tiny_config(batch_size=4))
    with pytest.raises(ValueError, match="cannot be shortened to 3"):
        run.prepare(tiny_config(episodes=3))
    assert (run.path / rd.CONFIG).read_text() == before


def test_diff_names_every_nested_leaf():
    old = {"a": 1, "b": {"c": [1, 2], "d": "x"}, "gone": 0}
    new = {"a": 1, "b": {"c": [1, 3], "d": "x"}, "new": True}
    assert rd.diff(old, new, "there") == ["b.c: [1, 2] there, [1, 3] now", "gone: 0 there, '<missing>' now",
                                          "new: '<missing>' there, True now"]
    assert rd.diff(old, old, "there") == []


def test_not_a_run_directory_says_why(tmp_path):
    assert RunDir(tmp_path / "nope").problem() == f"{tmp_path / 'nope'} does not exist"
    assert "is not a run directory (no config.json)" in RunDir(tmp_path).problem()
    with pytest.raises(FileNotFoundError, match="not a run directory"):
        RunDir(tmp_path).config()
    with pytest.raises(FileNotFoundError, match="not a run directory"):
        load_run(tmp_path)


def test_metrics_rows_and_summary(tmp_path):
    run = RunDir(tmp_path)
    assert run.metric_rows() == 0 and not run.has_metrics()
    rows = [{**{c: 0 for c in rd.METRIC_COLUMNS}, "seed": s, "episode": e, "phase": "train", "success": e == 1,
             "habit_actions": 3, "planning_actions": 1} for s in (0, 1) for e in (0, 1)]
    run.write_metrics(rows)
    assert list(run.metrics().columns) == list(rd.METRIC_COLUMNS) and run.metric_rows() == 4
    back = run.read_metric_rows(rd.RunCheckpoint({"metric_rows": 3}, tmp_path / "old.pt"))
    assert back == rows[:3] and all(type(v) in (int, float, bool, str) for r in back for v in r.values())
    assert rd.metric_digest(back) == rd.metric_digest(rows[:3]), "the digest of rows read back is the one written"
    with pytest.raises(rd.RunMismatch, match="has 4 rows, the checkpoint expects 5.*older release.*backup"):
        run.read_metric_rows(rd.RunCheckpoint({"metric_rows": 5}, tmp_path / "old.pt"))
    assert run.summary(last=1) == {"episodes": 2, "seeds": 2, "success_rate_last_1": 1.0, "habit_share_last_1": 0.75}


def test_checkpoints_rotate_and_fall_back(tmp_path, capsys):
    run = RunDir(tmp_path)
    with pytest.raises(CheckpointError, match="has no checkpoint yet"):
        run.load_checkpoint()
    (run.checkpoints / "ckpt_000002.pt").parent.mkdir(parents=True)
    (run.checkpoints / "ckpt_000002.pt").write_bytes(b"an older version's numbered checkpoint")
    run.save_checkpoint(fake_checkpoint(episode=1))
    run.save_checkpoint(fake_checkpoint(episode=2))
    assert [p.name for p in run.checkpoint_files()] == [rd.LATEST, rd.PREVIOUS]
    assert run.load_checkpoint().member_episode(0) == 2
    (run.checkpoints / rd.LATEST).write_bytes(b"garbage")
    ckpt = run.load_checkpoint()
    assert ckpt.member_episode(1) == 2 and ckpt.path.name == rd.PREVIOUS
    assert "using the newest intact checkpoint" in capsys.readouterr().err


def test_a_damaged_final_checkpoint_unfinishes_the_run(tmp_path, capsys):
    run = RunDir(tmp_path)
    run.write_config({"episodes": 4}, None)
    run.save_checkpoint(fake_checkpoint(episode=4))  # every member at the run's episode count: final
    run.mark_finished()
    assert run.check_finished() and run.finished()
    latest = run.checkpoints / rd.LATEST
    latest.write_bytes(latest.read_bytes()[:100])
    assert not run.check_finished() and not run.finished()
    assert "is marked finished but checkpoint" in capsys.readouterr().err


def test_eval_files(tmp_path):
    run = RunDir(tmp_path)
    assert run.eval_summary() == {} and not run.evaluated() and run.eval_paths() == []
    run.write_eval("grid", pd.DataFrame({"seed": [0]}))
    run.write_eval_summary({"protocols": {"grid": {"episodes": 1}}})
    assert run.evaluated() and run.eval_summary() == {"protocols": {"grid": {"episodes": 1}}}
    assert run.eval_paths() == [run.eval_path("grid")] and run.eval_path("grid").name == "grid.parquet"


def test_a_run_written_by_an_older_release_reads(tmp_path):
    run = RunDir(OLD_RUN)
    assert run.exists() and run.finished() and run.evaluated() and run.episodes() == 6
    assert run.metric_rows() == len(run.metrics()) == 2 * (6 + 1)
    loaded = load_run(OLD_RUN)
    cfg, agent, ckpt = loaded.cfg, loaded.agent, loaded.ckpt
    assert cfg.agent.kind == "apac_speed_accuracy" and agent.E == 2 == len(cfg.seeds)
    assert ckpt.config == run.config() and ckpt.metric_rows == run.metric_rows()
    assert ckpt.member_lengths().shape == (2, 2) and [ckpt.member_episode(k) for k in (0, 1)] == [6, 6]
    assert ckpt.member_targets() == [None, None] and set(ckpt.running_statistics()) == {"arbitrator", "integrator"}


def test_an_older_release_s_run_resumes_to_the_same_numbers(tmp_path):
    """The 936695d run extended by two episodes gives the rows 936695d gave."""
    from apac_mj.run.trainer import train

    run = Path(shutil.copytree(OLD_RUN, tmp_path / "run"))
    cfg = dataclasses.replace(RunDir(run).train_config(), episodes=8)
    train(cfg, run, progress=False)
    expected = pd.read_parquet(OLD_RUN / "expected_metrics_8_episodes.parquet")
    from tests.test_old_runs import FLOAT_TOLERANCE  # exact off the CPU class that wrote it: float32 rounding

    pd.testing.assert_frame_equal(RunDir(run).metrics()[expected.columns], expected, **FLOAT_TOLERANCE)


def _string_constants(tree: ast.AST) -> list[ast.Constant]:
    """String constants that are not docstrings."""
    docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                  if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
                  and node.body and isinstance(node.body[0], ast.Expr) and isinstance(node.body[0].value, ast.Constant)}
    return [n for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)
            and id(n) not in docstrings]


def test_only_the_run_directory_names_its_files():
    """No module but run_dir.py has config.json, DONE or metrics.parquet as a string (a path part)."""
    names = {rd.CONFIG, rd.DONE, rd.METRICS, rd.LATEST, rd.PREVIOUS}
    owner = PACKAGE / "run" / "run_dir.py"
    assert {c.value for c in _string_constants(ast.parse(owner.read_text()))} >= names, "the check reads strings"
    found = [f"{p.relative_to(PACKAGE)}:{c.lineno} {c.value!r}" for p in sorted(PACKAGE.rglob("*.py")) if p != owner
             for c in _string_constants(ast.parse(p.read_text())) if c.value in names]
    assert not found, found


def test_the_run_layer_does_not_import_the_layers_above_it():
    """Recordings come in as hooks and the grid-directory hint lives in the commands: run/ imports neither."""
    from test_imports import MODULES, imports

    run_modules = [m for m in MODULES if m.startswith("apac_mj.run.")]
    assert "apac_mj.run.run_dir" in run_modules
    upward = [f"{m} -> {i}" for m in run_modules for i in imports(m)
              if i.startswith(("apac_mj.recording", "apac_mj.experiments", "apac_mj.report", "apac_mj.commands"))]
    assert not upward, upward
