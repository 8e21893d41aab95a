"""Frozen-network tests: output files, time-cost arithmetic, targets, and the occluded protocol's blindness."""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.run.evaluate import COLUMNS, MEASURED_COLUMNS, evaluate, evaluation_targets, time_cost
from apac_mj.kinematics import angle_grid, motion_function
from apac_mj.suite import load_spec
from apac_mj.run.trainer import train

from conftest import TINY, deterministic


def _train(tmp_path_factory, agent: str, task: str = "changing_target"):
    cfg = TrainConfig(task=task, seeds=(0, 1), episodes=3, checkpoint_every=3, actuation="kinematic",
                      agent=AgentConfig(kind=agent, **TINY))
    return train(cfg, tmp_path_factory.mktemp(f"{agent}_{task}"), progress=False)


@pytest.fixture(scope="module")
def apac_run(tmp_path_factory):
    return _train(tmp_path_factory, "apac")


def test_time_cost_arithmetic():
    assert time_cost(0, 0) == 0
    assert time_cost(2, 0) == 2
    assert time_cost(2, 3) == 11  # planning costs 3, habit 1


def test_grid_outputs_and_summary(apac_run):
    summary = evaluate(apac_run, protocols=("grid",), limit=10)
    df = pd.read_parquet(apac_run / "eval" / "grid.parquet")
    assert list(df.columns) == list(COLUMNS) + ["path_x", "path_y"] + list(MEASURED_COLUMNS)
    assert len(df) == 20 and sorted(df.seed.unique()) == [0, 1]
    assert (df.time_cost == df.habit_actions + 3 * df.planning_actions).all()
    assert (df.steps == df.habit_actions + df.planning_actions).all()
    assert (df.success == (df.final_distance <= 0.5)).all()
    assert ((df.steps >= 1) & (df.steps <= 30)).all()
    assert all(len(x) == s + 1 for x, s in zip(df.path_x, df.steps))
    # Grid targets: angle grid through the motion function at the (static) lengths (5, 8).
    g = angle_grid()[:10]
    end, _ = motion_function(g[:, 0], g[:, 1], 5.0, 8.0)
    np.testing.assert_allclose(df[df.seed == 0][["target_x", "target_y"]].to_numpy(), end, atol=1e-9)
    s = summary["protocols"]["grid"]
    assert s["success_rate"] == pytest.approx(df.success.mean())
    assert s["mean_time_cost"] == pytest.approx(df.time_cost.mean())
    on_disk = json.loads((apac_run / "eval" / "summary.json").read_text())
    assert on_disk["protocols"]["grid"]["episodes"] == 20
    assert list(s)[-1] == "mean_decision_ms"  # after the keys written before it, in their order


def test_grid_rows_measure_each_episodes_decision_time(apac_run):
    """Each test episode's measured decision time where the habit and where the planner acted, and its planning
    iterations (APAC plans with the paper's inverse model: one iteration per planning action); the summary's
    mean decision time per episode is theirs."""
    summary = evaluate(apac_run, protocols=("grid",), limit=10)
    df = pd.read_parquet(apac_run / "eval" / "grid.parquet")
    assert df.habit_seconds.dtype == df.planning_seconds.dtype == np.float64
    assert (df.habit_seconds >= 0).all() and (df.planning_seconds >= 0).all()
    assert ((df.habit_seconds > 0) == (df.habit_actions > 0)).all()
    assert ((df.planning_seconds > 0) == (df.planning_actions > 0)).all()
    assert (df.plan_iterations == df.planning_actions).all()
    assert (df.habit_actions > 0).any() and (df.planning_actions > 0).any()  # both kinds were timed
    assert summary["protocols"]["grid"]["mean_decision_ms"] == pytest.approx(
        1e3 * (df.habit_seconds + df.planning_seconds).mean())


def test_frozen_evaluation_is_deterministic_and_changes_nothing(apac_run):
    before = (apac_run / "checkpoints" / "latest.pt").read_bytes()
    evaluate(apac_run, protocols=("grid",), limit=5)
    a = pd.read_parquet(apac_run / "eval" / "grid.parquet")
    evaluate(apac_run, protocols=("grid",), limit=5)
    b = pd.read_parquet(apac_run / "eval" / "grid.parquet")
    assert "plan_iterations" in deterministic(a) and "habit_seconds" not in deterministic(a)
    pd.testing.assert_frame_equal(deterministic(a), deterministic(b), check_exact=True)
    assert (apac_run / "checkpoints" / "latest.pt").read_bytes() == before


def test_occluded_protocol_acts_on_forward_model_only(apac_run):
    infos = []
    evaluate(apac_run, protocols=("occluded",), limit=4, on_step=lambda info, env: infos.append(info))
    df = pd.read_parquet(apac_run / "eval" / "occluded.parquet")
    assert len(df) == 8 and "path_x" not in df.columns
    assert list(df.columns) == list(COLUMNS) + list(MEASURED_COLUMNS)
    prev = None
    for info in infos:
        act = info.active
        assert not info.vision[act].any(), "the agent saw something after step 0"
        if prev is not None and (info.step[act] > 0).all():
            # The state acted on is the previous step's integrated estimate = the forward model's prediction,
            # and the target is the one remembered from step 0.
            np.testing.assert_array_equal(info.state[act, :4], prev.predicted_arm[act, :4])
            np.testing.assert_array_equal(info.state[act, 4:], prev.state[act, 4:])
        prev = info
    first = [i for i in infos if (i.step[i.active] == 0).all()]
    assert first and all(np.allclose(i.state[i.active, 4:], i.target[i.active], atol=1e-5) for i in first)
    # The arm stops when its estimate is inside the zone (or at 30 steps); the true distance is recorded.
    last_est = {}
    for info in infos:
        for k in np.flatnonzero(info.active):
            last_est[(int(info.episode[k]), k)] = (info.terminal[k], int(info.step[k]) + 1)
    for (ep, k), (terminal, steps) in last_est.items():
        assert terminal or steps == 30
    assert (df.success == (df.final_distance <= 0.5)).all()


def test_generalization_targets_lie_in_test_region(apac_run):
    evaluate(apac_run, protocols=("generalization",))
    df = pd.read_parquet(apac_run / "eval" / "generalization.parquet")
    y_min = load_spec("changing_target").region.test_y_min
    assert len(df) > 0 and (df.target_y >= y_min).all()
    assert len(df[df.seed == 0]) < 100


def test_static_target_runs_test_their_own_target(tmp_path_factory):
    run = _train(tmp_path_factory, "spac", "static_target")
    spec = load_spec("static_target")
    targets = evaluation_targets(spec, np.array([[5.0, 8.0]]), [np.array([20.0, 21.0])])
    assert targets[0].shape == (100, 2) and (targets[0] == [20.0, 21.0]).all()
    evaluate(run, protocols=("grid",), limit=3)
    df = pd.read_parquet(run / "eval" / "grid.parquet")
    metrics = pd.read_parquet(run / "metrics.parquet")
    for seed in (0, 1):
        own = metrics[(metrics.seed == seed) & (metrics.phase == "train")][["target_x", "target_y"]].iloc[0]
        np.testing.assert_allclose(df[df.seed == seed][["target_x", "target_y"]].to_numpy(),
                                   np.repeat(own.to_numpy()[None], 3, 0))


def test_ddpg_occluded_not_applicable(tmp_path_factory):
    run = _train(tmp_path_factory, "ddpg")
    s = evaluate(run, protocols=("occluded",))
    assert s["protocols"]["occluded"]["applicable"] is False
    assert not (run / "eval" / "occluded.parquet").exists()


def test_bad_arguments(apac_run, tmp_path):
    with pytest.raises(ValueError, match="unknown protocol"):
        evaluate(apac_run, protocols=("nope",))
    with pytest.raises(FileNotFoundError, match="not a run directory"):
        evaluate(tmp_path, protocols=("grid",))


@pytest.mark.parametrize("task, overrides, grid_vision", [
    ("changing_target", {}, ("perfect", 0.0, 1.0)),
    ("changing_target_occluded", {}, ("perfect", 0.0, 1.0)),
    ("changing_target_noisy", {}, ("noisy", 0.5, 1.0)),
    ("changing_target_intermittent", {"vision_noise_std": 0.2}, ("intermittent", 0.2, 0.5)),
])
def test_protocol_environments_keep_the_vision_under_test(task, overrides, grid_vision):
    """grid/generalization test the task's noisy or intermittent vision (occluded tasks: perfect); the
    occluded protocol is clean occlusion whatever the task's vision."""
    from apac_mj.suite import spec_for
    from apac_mj.run.evaluate import eval_env

    cfg = TrainConfig(task=task, seeds=(0,), task_overrides=overrides)
    spec, lengths = spec_for(cfg), np.array([[5.0, 8.0]])
    vision = lambda env: (env.spec.vision, env.spec.vision_noise_std, env.spec.vision_seen_probability)
    assert vision(eval_env(cfg, spec, lengths, occluded=False)) == grid_vision
    assert vision(eval_env(cfg, spec, lengths, occluded=True)) == ("occluded", 0.0, 1.0)
