"""Training loop: ensemble members equal single-seed runs, exact resume, checkpoint errors, run dir contents."""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from apac_mj.run import checkpoint
from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.run.run_dir import METRIC_COLUMNS, TIMING_COLUMNS
from apac_mj.run.trainer import train
from apac_mj.util import files

from conftest import TINY, deterministic, through_a_checkpoint


def tiny_config(seeds=(0, 1), episodes=4, agent="apac", task="changing_target", **kw) -> TrainConfig:
    return TrainConfig(task=task, seeds=tuple(seeds), episodes=episodes, checkpoint_every=2, actuation="kinematic",
                       agent=AgentConfig(kind=agent, **{**TINY, **kw}))


def final_weights(run: Path) -> dict[str, torch.Tensor]:
    ckpt = checkpoint.load(run / "checkpoints" / "latest.pt")
    return ckpt["agent"]["networks"]["actor"] | {f"fwd.{k}": v for k, v in ckpt["agent"]["networks"]["forward_model"].items()}


def test_run_directory_contents(tmp_path):
    run = train(tiny_config(), tmp_path / "run", progress=False)
    df = pd.read_parquet(run / "metrics.parquet")
    assert list(df.columns) == [*METRIC_COLUMNS, *TIMING_COLUMNS]
    # the measured decision times: where each controller acted, and the inverse model's one iteration per action
    train_rows = df[df.phase == "train"]
    assert ((train_rows.planning_seconds > 0) == (train_rows.planning_actions > 0)).all()
    assert ((train_rows.habit_seconds > 0) == (train_rows.habit_actions > 0)).all()
    assert (train_rows.plan_iterations == train_rows.planning_actions).all()
    for seed in (0, 1):
        d = df[df.seed == seed]
        assert d[d.phase == "train"].episode.tolist() == [0, 1, 2, 3]
        assert d[d.phase == "babbling"].episode.tolist() == [-1]
        train_rows = d[d.phase == "train"]
        assert (train_rows.habit_actions + train_rows.planning_actions == train_rows.steps).all()
        assert (d[d.phase == "babbling"].habit_actions == 0).all()
    # APAC plans exclusively during the first planning_episodes (2) training episodes.
    assert (df[(df.phase == "train") & (df.episode < 2)].habit_actions == 0).all()
    assert ((df.success & (df.final_distance <= 0.5)) == df.success).all()
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["seeds"] == [0, 1] and "git_commit" in cfg
    assert (run / "DONE").is_file()
    # What resume needs: the final checkpoint and the one before it (a fallback), nothing more.
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == ["latest.pt", "previous.pt"]
    assert checkpoint.load(run / "checkpoints" / "previous.pt")["loop"]["episode"].tolist() == [2, 2]


def test_ensemble_member_equals_single_seed(tmp_path):
    seeds = (3, 5, 7, 11)
    ens = pd.read_parquet(train(tiny_config(seeds, episodes=3), tmp_path / "ens", progress=False) / "metrics.parquet")
    alone = pd.read_parquet(train(tiny_config((7,), episodes=3), tmp_path / "one", progress=False) / "metrics.parquet")
    member = ens[ens.seed == 7].reset_index(drop=True)
    pd.testing.assert_frame_equal(deterministic(member), deterministic(alone.reset_index(drop=True)), check_exact=True)
    w_ens, w_one = final_weights(tmp_path / "ens"), final_weights(tmp_path / "one")
    for k in w_one:
        assert torch.equal(w_ens[k][2], w_one[k][0]), k


class Crash(Exception):
    pass


def train_killed_and_resumed(cfg: TrainConfig, run: Path, steps_after_checkpoint: int) -> Path:
    """Train ``cfg`` into ``run``, kill it ``steps_after_checkpoint`` steps after its first checkpoint
    (mid-episode for some member), then run the same command again to resume; returns ``run``."""
    calls = {"n": 0}

    def crash_after_checkpoint(info, env):
        if (run / "checkpoints" / "latest.pt").is_file():
            calls["n"] += 1
            if calls["n"] == steps_after_checkpoint:
                raise Crash()

    with pytest.raises(Crash):
        train(cfg, run, progress=False, on_step=crash_after_checkpoint)
    assert not (run / "DONE").exists()
    return train(cfg, run, progress=False)


def test_resume_equals_uninterrupted(tmp_path):
    cfg = tiny_config((0, 1), episodes=6)
    full = train(cfg, tmp_path / "full", progress=False)
    # The first checkpoint (slowest member at 2 episodes) is written after some step; crash a few steps later.
    resumed = train_killed_and_resumed(cfg, tmp_path / "cut", 7)
    a, b = pd.read_parquet(full / "metrics.parquet"), pd.read_parquet(resumed / "metrics.parquet")
    pd.testing.assert_frame_equal(deterministic(a), deterministic(b), check_exact=True)
    wa, wb = final_weights(full), final_weights(resumed)
    assert all(torch.equal(wa[k], wb[k]) for k in wa)


def test_config_mismatch_is_a_clear_error(tmp_path):
    train(tiny_config(episodes=2), tmp_path / "run", progress=False)
    with pytest.raises(ValueError, match="different config.*seeds"):
        train(tiny_config(seeds=(0, 2), episodes=2), tmp_path / "run", progress=False)


@pytest.mark.parametrize("damage", ["truncate", "garbage"])
def test_corrupt_checkpoint_is_a_clear_error(tmp_path, damage):
    cfg = tiny_config(episodes=4)
    run = tmp_path / "run"
    train(cfg, run, progress=False)
    (run / "checkpoints" / "previous.pt").unlink()  # no intact checkpoint left to fall back to
    latest = run / "checkpoints" / "latest.pt"
    data = latest.read_bytes()
    latest.write_bytes(data[: len(data) // 2] if damage == "truncate"
                       else np.random.default_rng(0).bytes(len(data)))
    (run / "DONE").unlink()
    with pytest.raises(checkpoint.CheckpointError, match=r"checkpoint .*latest.pt is corrupt or incompatible"):
        train(cfg, run, progress=False)


def test_checkpoint_missing_keys_and_roundtrip(tmp_path):
    path = checkpoint.save({"a": torch.arange(3), "b": [1, "x"]}, tmp_path / "c.pt")
    assert torch.equal(checkpoint.load(path)["a"], torch.arange(3))
    with pytest.raises(checkpoint.CheckpointError, match="missing key"):
        checkpoint.load(path, required=("a", "agent"))
    with pytest.raises(checkpoint.CheckpointError, match="does not exist"):
        checkpoint.load(tmp_path / "nope.pt")


def test_bad_config_values(tmp_path):
    with pytest.raises(ValueError, match="seeds must be distinct"):
        train(tiny_config(seeds=(1, 1)), tmp_path / "a", progress=False)
    with pytest.raises(KeyError, match="unknown task"):
        train(tiny_config(task="no_such_task"), tmp_path / "b", progress=False)


def test_cli_train_then_evaluate(tmp_path, capsys):
    from apac_mj.cli import main

    run = tmp_path / "cli_run"
    args = ["train", "--task", "static_target", "--agent", "spac", "--seeds", "2-3", "--episodes", "2",
            "--out", str(run), "--actuation", "kinematic", "--checkpoint-every", "1", "--no-progress"]
    tiny = [f"--set={k}={','.join(map(str, v)) if isinstance(v, tuple) else v}" for k, v in TINY.items()]
    assert main(args + tiny) == 0
    assert json.loads((run / "config.json").read_text())["seeds"] == [2, 3]
    assert '"status": "trained"' in capsys.readouterr().out
    assert main(args + tiny) == 0  # finished run: returns at once, and says so
    assert '"status": "already finished; nothing trained"' in capsys.readouterr().out
    assert main(["evaluate", str(run), "--limit", "2", "--no-progress", "--json"]) == 0
    out = capsys.readouterr().out
    assert '"success_rate"' in out and (run / "eval" / "grid.parquet").is_file()
    assert main(["train", "--seeds", "3-1", "--out", str(tmp_path / "x")]) == 2
    assert "--seeds must be" in capsys.readouterr().err
    assert main(args[:-1] + ["--set", "no_such=1"]) == 2


def test_parse_seeds():
    from apac_mj.commands.train import parse_seeds

    assert parse_seeds("0-3") == (0, 1, 2, 3)
    assert parse_seeds("0,3,5") == (0, 3, 5)
    assert parse_seeds("7") == tuple(range(7))  # one seed grammar with grid --set seeds=7 (issue 10)
    assert parse_seeds("7-7") == (7,)
    for bad in ("a", "3-1", "1,1", "-2"):
        with pytest.raises(ValueError, match="--seeds"):
            parse_seeds(bad)


def test_bf16_run_is_finite_and_reproducible(tmp_path):
    cfg = dataclasses.replace(tiny_config((0,), episodes=2), precision="bf16")
    a = pd.read_parquet(train(cfg, tmp_path / "a", progress=False) / "metrics.parquet")
    b = pd.read_parquet(train(cfg, tmp_path / "b", progress=False) / "metrics.parquet")
    pd.testing.assert_frame_equal(deterministic(a), deterministic(b), check_exact=True)
    assert np.isfinite(a[["return", "final_distance"]].to_numpy()).all()


class _Evil:
    def __reduce__(self):
        return (print, ("code ran",))


def test_checkpoint_with_code_is_refused(tmp_path, capsys):
    path = tmp_path / "evil.pt"
    torch.save({"format_version": checkpoint.FORMAT_VERSION, "x": _Evil()}, path)
    with pytest.raises(checkpoint.CheckpointError, match="corrupt or incompatible"):
        checkpoint.load(path)
    assert "code ran" not in capsys.readouterr().out


@pytest.mark.parametrize("task,actuation", [("changing_target", "servo"), ("changing_target_noisy", "kinematic"),
                                            ("changing_target_intermittent", "kinematic"),
                                            ("static_target_changing_kinematics", "kinematic")])
def test_vec_env_state_roundtrip_mid_episode(task, actuation):
    from apac_mj.suite.vec_env import VecEnv

    def make():
        return VecEnv(task, [0, 1], actuation, overrides={"growth_start_episode": 0})

    def play(env, actions):
        out = []
        for a in actions:
            o = env.step(a)
            out.append(np.concatenate([o.arm.ravel(), o.reward, env.link_lengths().ravel(), env.targets().ravel()]))
            env.reset(o.last)
        return np.array(out)

    actions = np.random.default_rng(0).uniform(-60, 60, size=(40, 2, 2))
    env = make()
    env.reset()
    play(env, actions[:7])
    state = through_a_checkpoint(env.get_state())
    reference = play(env, actions[7:])
    restored = make()
    restored.set_state(state)
    np.testing.assert_array_equal(play(restored, actions[7:]), reference)
    with pytest.raises(ValueError, match="seeds"):
        VecEnv(task, [5, 6], actuation).set_state(state)


def test_episode_losses_are_the_mean_of_the_updates(tmp_path, monkeypatch):
    """The *_loss columns hold the mean of the losses Agent.update returned during that episode."""
    from apac_mj.agent import agent as agent_mod

    seen: list[dict[str, np.ndarray]] = []
    original = agent_mod.Agent.update

    def spy(self, active):
        out = original(self, active)
        seen.append({k: v.clone().numpy() for k, v in out.items()})
        return out

    monkeypatch.setattr(agent_mod.Agent, "update", spy)
    run = train(tiny_config(seeds=(0,), episodes=3, agent="spac"), tmp_path / "run", progress=False)
    df = pd.read_parquet(run / "metrics.parquet")
    assert len(seen) == int(df.steps.sum())  # one update per step, babbling included
    start = 0
    for _, row in df.iterrows():
        chunk = seen[start:start + int(row.steps)]
        start += int(row.steps)
        for name in ("critic", "actor", "forward", "inverse"):
            assert row[f"{name}_loss"] == pytest.approx(np.mean([c[name][0] for c in chunk], dtype=np.float64),
                                                        rel=1e-9)
    assert (df[["critic_loss", "forward_loss", "inverse_loss"]] >= 0).all().all()


@pytest.mark.parametrize("critic_action", ["executed", "commanded"])
def test_replay_action_for_the_critic(tmp_path, critic_action):
    """The inverse model's label is always the executed change; the critic's action is the command
    (clipped by the joint limits only in the executed version) when critic_action="commanded"."""
    run = train(tiny_config(seeds=(0,), episodes=2, critic_action=critic_action), tmp_path / "run", progress=False)
    replay = checkpoint.load(run / "checkpoints" / "latest.pt")["agent"]["replay"]
    n = replay["count"][0]
    learned, executed = replay["data"]["action"][0, :n], replay["data"]["executed_action"][0, :n]
    clipped = (learned - executed).abs().amax(-1) > 1e-3
    if critic_action == "executed":
        assert torch.equal(learned, executed)
    else:  # some commands left the joint range (measured: 5 of the 64 transitions kept)
        assert clipped.any()


# -- issue 11: run directories --------------------------------------------------------------

def _modes(run: Path) -> dict[str, int]:
    return {str(p.relative_to(run)): p.stat().st_mode & 0o777 for p in run.rglob("*") if p.is_file()}


def test_result_files_honour_the_umask(tmp_path):
    import os

    old = os.umask(0o022)
    try:
        run = train(tiny_config(seeds=(0,), episodes=4), tmp_path / "run", progress=False)
    finally:
        os.umask(old)
    modes = _modes(run)
    assert {"config.json", "metrics.parquet", "DONE", "checkpoints/latest.pt", "checkpoints/previous.pt"} <= set(modes)
    assert set(modes.values()) == {0o644}, modes
    old = os.umask(0o077)
    try:
        files.atomic_write_bytes(tmp_path / "private", lambda f: f.write(b"x"))
    finally:
        os.umask(old)
    assert (tmp_path / "private").stat().st_mode & 0o777 == 0o600


@pytest.mark.skipif(torch.cuda.is_available(), reason="needs a machine without CUDA")
def test_failed_start_leaves_nothing_behind(tmp_path):
    cfg = dataclasses.replace(tiny_config(seeds=(0,), episodes=2), device="cuda")
    with pytest.raises(ValueError, match="CUDA is not available.*--device cpu"):
        train(cfg, tmp_path / "run", progress=False)
    assert not (tmp_path / "run").exists()
    cfg = dataclasses.replace(cfg, device="cpu")
    assert (train(cfg, tmp_path / "run", progress=False) / "DONE").is_file()


def test_bad_agent_config_writes_no_config(tmp_path, monkeypatch):
    from apac_mj.run import build

    def broken(*a, **k):
        raise RuntimeError("agent construction failed")

    monkeypatch.setattr(build, "Agent", broken)
    with pytest.raises(RuntimeError, match="construction failed"):
        train(tiny_config(seeds=(0,), episodes=2), tmp_path / "run", progress=False)
    assert not (tmp_path / "run" / "config.json").exists()


def _sorted_metrics(run: Path) -> pd.DataFrame:
    df = pd.read_parquet(run / "metrics.parquet")
    return df.sort_values(["seed", "episode"], kind="stable").reset_index(drop=True)


def test_extending_a_finished_run_equals_a_longer_run(tmp_path, capsys):
    full = train(tiny_config((0, 1), episodes=6), tmp_path / "full", progress=False)
    short = train(tiny_config((0, 1), episodes=3), tmp_path / "ext", progress=False)
    assert (short / "DONE").is_file()
    capsys.readouterr()
    extended = train(tiny_config((0, 1), episodes=6), tmp_path / "ext", progress=False)
    assert f"extending {tmp_path / 'ext'} from 3 to 6 episodes: resuming at episode 3" in capsys.readouterr().err
    pd.testing.assert_frame_equal(deterministic(_sorted_metrics(full)), deterministic(_sorted_metrics(extended)),
                                  check_exact=True)
    wa, wb = final_weights(full), final_weights(extended)
    assert all(torch.equal(wa[k], wb[k]) for k in wa)
    assert json.loads((extended / "config.json").read_text())["episodes"] == 6
    with pytest.raises(ValueError, match="cannot be shortened to 4"):
        train(tiny_config((0, 1), episodes=4), tmp_path / "ext", progress=False)
    with pytest.raises(ValueError, match="different config.*batch_size"):
        train(tiny_config((0, 1), episodes=8, batch_size=4), tmp_path / "ext", progress=False)


def test_damaged_latest_falls_back_to_previous(tmp_path, capsys):
    """A truncated latest.pt of a finished run: train warns, resumes from previous.pt and ends where it
    ended; evaluate warns and uses previous.pt."""
    from apac_mj.run.evaluate import evaluate

    cfg = tiny_config((0, 1), episodes=4)
    run = train(cfg, tmp_path / "run", progress=False)
    before = _sorted_metrics(run)
    weights = final_weights(run)
    latest = run / "checkpoints" / "latest.pt"
    with open(latest, "r+b") as f:
        f.truncate(1000)
    capsys.readouterr()
    evaluate(run, protocols=("grid",), limit=1)
    assert "using the newest intact checkpoint" in capsys.readouterr().err
    with open(latest, "r+b") as f:
        f.truncate(1000)
    train(cfg, run, progress=False)
    err = capsys.readouterr().err
    assert "marked finished but checkpoint" in err and "corrupt" in err
    assert f"using the newest intact checkpoint, {run / 'checkpoints' / 'previous.pt'}" in err
    assert "2 of 4 episodes done" in err
    pd.testing.assert_frame_equal(deterministic(before), deterministic(_sorted_metrics(run)), check_exact=True)
    assert all(torch.equal(weights[k], final_weights(run)[k]) for k in weights)
    assert (run / "DONE").is_file()


def test_resume_finish_and_interrupt_are_said(tmp_path, capsys):
    cfg = tiny_config((0,), episodes=4)
    run = tmp_path / "run"

    def interrupt_after_checkpoint(info, env):
        if (run / "checkpoints" / "latest.pt").is_file():
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train(cfg, run, progress=False, on_step=interrupt_after_checkpoint)
    err = capsys.readouterr().err
    assert f"interrupted: {run}/checkpoints/latest.pt holds the run after 2 of 4 episodes" in err
    assert "run the same command again to resume" in err
    train(cfg, run, progress=False)
    assert f"resuming {run} from its checkpoint: 2 of 4 episodes done" in capsys.readouterr().err
    train(cfg, run, progress=False)
    assert f"{run} already finished 4 episodes; nothing to train" in capsys.readouterr().err

    def interrupt_at_once(info, env):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train(cfg, tmp_path / "other", progress=False, on_step=interrupt_at_once)
    assert "nothing saved yet" in capsys.readouterr().err


def test_cli_without_arguments_prints_help(capsys):
    from apac_mj.cli import main

    assert main([]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: apac-mj") and "train" in out and "evaluate" in out


def test_cli_device_without_cuda_leaves_no_run_dir(tmp_path, capsys):
    from apac_mj.cli import main

    if torch.cuda.is_available():
        pytest.skip("needs a machine without CUDA")
    assert main(["train", "--episodes", "1", "--device", "cuda", "--out", str(tmp_path / "x"), "--no-progress"]) == 2
    assert "CUDA is not available" in capsys.readouterr().err and not (tmp_path / "x").exists()


def test_progress_bar_labels_motor_babbling(tmp_path, capsys):
    """The bar does not sit at 0/N unlabelled while the agent babbles: it says so, then drops the label."""
    train(tiny_config(seeds=(0,), episodes=1, agent="ddpg", babbling_episodes=2), tmp_path / "run", progress=True)
    lines = [ln for ln in capsys.readouterr().err.replace("\r", "\n").splitlines() if "ddpg" in ln]
    babbling = [ln for ln in lines if "motor babbling" in ln]
    assert any("episode 1 of 2" in ln for ln in babbling) and any("episode 2 of 2" in ln for ln in babbling)
    assert all("0/1" in ln for ln in babbling) and "motor babbling" not in lines[-1] and "1/1" in lines[-1]
