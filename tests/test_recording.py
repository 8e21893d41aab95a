"""Recordings read back from .rrd files: entity paths, one frame per step, physics vs motion function."""
from __future__ import annotations

import shutil
import subprocess
import sys
import json
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

import apac_mj  # noqa: F401  (sets MUJOCO_GL before mujoco loads)
from apac_mj.recording import recording as R
from apac_mj.suite import render
from apac_mj import suite


def _record_plain_rollout(path: Path, task: str, episodes: int, seed: int = 0, **task_kwargs) -> dict:
    """Roll out random actions in a suite env, recording every step; return what was logged."""
    env = suite.load("planar_arm", task, task_kwargs={"random": seed, **task_kwargs})
    rng = np.random.default_rng(seed)
    logged = {"habit": [], "steps": 0, "lengths": []}
    with render.Renderer(env.physics) as ren, R.recording_for_env(path, env, {"task": task, "seeds": [seed]}) as rec:
        for ep in range(episodes):
            ts = env.reset()
            first = R.step_record_from_env(env, ep, ts)
            rec.start_episode(ep, first.target, first.link_lengths)
            rec.log_step(first, render.encode_jpeg(ren.render()))
            logged["steps"] += 1
            while not ts.last():
                habit = bool(rng.integers(2))
                ts = env.step(rng.uniform(-40, 40, size=2))
                step = R.step_record_from_env(env, ep, ts, habit=habit, delta=float(rng.normal()),
                                              predicted_arm=first.true_arm + rng.normal(size=4))
                rec.log_step(step, render.encode_jpeg(ren.render()))
                logged["habit"].append(habit)
                logged["lengths"].append(step.link_lengths)
                logged["steps"] += 1
    return logged


@pytest.fixture(scope="module")
def changing_target(tmp_path_factory) -> tuple[Path, dict]:
    path = tmp_path_factory.mktemp("rec") / "rollout.rrd"
    return path, _record_plain_rollout(path, "changing_target", episodes=2)


def test_recording_holds_every_entity_path_and_one_frame_per_step(changing_target):
    path, logged = changing_target
    entities, props, blueprints = R.read_recording(path)
    missing = [p for p in R.ENTITY_PATHS if p not in entities]
    assert not missing, f"missing entity paths {missing}"
    assert len(entities[R.RENDER].times["frame"]) == logged["steps"]
    assert sorted(entities[R.RENDER].times["frame"]) == list(range(logged["steps"]))
    assert blueprints == 1
    assert props["task"] == ["changing_target"] and "git_commit" in props
    blob = entities[R.RENDER].components["EncodedImage:blob"][0]
    frame = iio.imread(bytes(blob[0]), extension=".jpg")
    assert frame.shape == (*render.FRAME_SHAPE, 3)


def test_rerun_rrd_verify_accepts_the_file(changing_target):
    rerun_cli = Path(sys.executable).parent / "rerun"
    if not rerun_cli.is_file():
        rerun_cli = Path(shutil.which("rerun") or "rerun")
    out = subprocess.run([str(rerun_cli), "rrd", "verify", str(changing_target[0])], capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr


def test_kinematics_error_is_below_1e9_throughout(changing_target):
    path, logged = changing_target
    entities, _, _ = R.read_recording(path)
    _, err = R.scalar_series(entities[R.KINEMATICS_ERROR])
    assert len(err) == logged["steps"]
    assert np.max(err) <= 1e-9


def test_controller_series_matches_what_was_reported(changing_target):
    path, logged = changing_target
    entities, _, _ = R.read_recording(path)
    _, controller = R.scalar_series(entities[R.CONTROLLER])
    assert controller.tolist() == [R.HABIT if h else R.PLANNING for h in logged["habit"]]


def test_episode_and_step_timelines(changing_target):
    path, logged = changing_target
    entities, _, _ = R.read_recording(path)
    rows = entities[R.DISTANCE]
    episodes = np.asarray(rows.times["episode"])
    steps = np.asarray(rows.times["step"])
    assert set(episodes.tolist()) == {0, 1}
    assert steps[episodes == 0].min() == 0 and steps[episodes == 0].max() == 30
    texts = [t[0] for t in entities[R.EVENTS].components["TextLog:text"]]
    assert sum("starts: target" in t for t in texts) == 2
    assert any(("time limit" in t) or ("target reached" in t) for t in texts)


def test_occlusion_and_growing_arm_are_recorded(tmp_path):
    path = tmp_path / "occluded.rrd"
    logged = _record_plain_rollout(path, "changing_target_changing_kinematics_occluded", episodes=1,
                                   growth_start_episode=0)
    entities, _, _ = R.read_recording(path)
    _, vision = R.scalar_series(entities[R.VISION])
    assert vision[0] == 1.0 and np.all(vision[1:] == 0.0)
    texts = [t[0] for t in entities[R.EVENTS].components["TextLog:text"]]
    assert sum(t.startswith("occluded") for t in texts) == logged["steps"] - 1
    _, l1 = R.scalar_series(entities[R.L1])
    assert np.all(np.diff(l1) > 0), "the arm grows every step"
    _, err = R.scalar_series(entities[R.KINEMATICS_ERROR])
    assert np.max(err) <= 1e-9


def test_distance_field_is_smallest_at_the_target():
    field = R.distance_field((8.0, 20.0), (30.0, 30.0)).astype(float).sum(axis=2)
    assert field.shape == (30 * R.FIELD_PX_PER_CM, 30 * R.FIELD_PX_PER_CM)
    # viridis is darkest at 0 and the first contour band darkens it further: the darkest pixel is at the
    # target (row = y, col = x).
    r, c = np.unravel_index(np.argmin(field), field.shape)
    assert abs(c / R.FIELD_PX_PER_CM - 8.0) < 1.0 and abs(r / R.FIELD_PX_PER_CM - 20.0) < 1.0


def test_recording_rejects_a_wrong_suffix(tmp_path):
    with pytest.raises(ValueError, match=r"\.rrd"):
        R.Recording(tmp_path / "x.mp4")


def test_renderer_failure_names_mujoco_gl(monkeypatch):
    env = suite.load("planar_arm", "changing_target", task_kwargs={"random": 0})

    def broken(*args, **kwargs):
        raise render.mujoco.FatalError("gladLoadGL error")

    monkeypatch.setattr(render.mujoco, "Renderer", broken)
    with pytest.raises(RuntimeError, match="MUJOCO_GL"):
        render.Renderer(env.physics)


def test_encode_jpeg_rejects_non_rgb():
    with pytest.raises(ValueError, match="uint8 RGB"):
        render.encode_jpeg(np.zeros((4, 4), dtype=np.uint8))
    with pytest.raises(ValueError, match="uint8 RGB"):
        render.encode_jpeg(np.zeros((4, 4, 3), dtype=np.float32))


@pytest.mark.parametrize("suffix", [".gif", ".mp4"])
def test_write_video_writes_every_frame(tmp_path, suffix):
    frames = [np.full((48, 64, 3), 40 * i, dtype=np.uint8) for i in range(4)]
    out = tmp_path / f"v{suffix}"
    render.write_video(out, frames, fps=5)
    assert len(list(iio.imiter(out))) == 4
    with pytest.raises(ValueError, match="mp4 or .gif"):
        render.write_video(tmp_path / "v.avi", frames)


def _tiny_train_config(seeds=(0,), kind: str = "apac", **agent_fields):
    from apac_mj.config import AgentConfig, TrainConfig

    agent = AgentConfig(kind=kind, babbling_episodes=1, planning_episodes=1, batch_size=16, replay_size=64,
                        actor_hidden=(32, 32), critic_hidden=(32, 32), forward_hidden=(32, 32),
                        inverse_hidden=(32, 32), **agent_fields)
    return TrainConfig(task="changing_target", seeds=seeds, episodes=3, agent=agent)


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory) -> tuple[Path, dict[int, list[bool]]]:
    """A 2-seed APAC run with small networks, recording every 2nd episode; what seed 0's agent reported."""
    import torch

    from apac_mj.run.run_dir import RunDir, config_dict
    from apac_mj.run.trainer import train

    torch.set_num_threads(1)
    reported: dict[int, list[bool]] = {}

    def hook(info, vec_env):
        if info.active[0]:
            reported.setdefault(int(info.episode[0]), []).append(bool(info.habit[0]))

    run_dir = tmp_path_factory.mktemp("train") / "run"
    cfg = _tiny_train_config(seeds=(0, 1))
    with R.EpisodeRecorder(RunDir(run_dir).recordings, record_every=2, config=config_dict(cfg)) as recorder:
        train(cfg, run_dir, progress=False, hooks=[recorder], on_step=hook)
    return run_dir, reported


def test_train_records_every_nth_episode_of_the_first_seed(tiny_run):
    run_dir, reported = tiny_run
    files = sorted((run_dir / "recordings").glob("*.rrd"))
    assert [f.name for f in files] == ["episode_000000.rrd", "episode_000002.rrd"]
    for f in files:
        entities, props, _ = R.read_recording(f)
        episode = int(f.stem.split("_")[1])
        steps = len(reported[episode])
        assert len(entities[R.RENDER].times["frame"]) == steps + 1, "one frame per step plus the start pose"
        _, controller = R.scalar_series(entities[R.CONTROLLER])
        assert controller.tolist() == [R.HABIT if h else R.PLANNING for h in reported[episode]]
        _, err = R.scalar_series(entities[R.KINEMATICS_ERROR])
        assert np.max(err) <= 1e-9
        assert set(entities[R.DISTANCE].times["episode"]) == {episode}
        # a predicted arm after every step, and a clear at the start pose
        assert len(entities[R.ARM_FORWARD_MODEL].times["frame"]) == steps + 1
        assert props["task"] == ["changing_target"]


def test_record_command_writes_rrd_and_video(tmp_path, capsys):
    from apac_mj.cli import main

    # mp4 keeps every frame; a GIF merges identical consecutive frames (adding their durations).
    out, gif = tmp_path / "rollout.rrd", tmp_path / "rollout.mp4"
    assert main(["record", "--task", "changing_target_occluded", "--agent", "apac", "--episodes", "2",
                 "--out", str(out), "--video", str(gif)]) == 0
    entities, props, blueprints = R.read_recording(out)
    frames = len(entities[R.RENDER].times["frame"])
    assert frames == len(list(iio.imiter(gif))) and frames >= 4
    assert blueprints == 1 and props["agent.kind"] == ["apac"]
    texts = [t[0] for t in entities[R.EVENTS].components["TextLog:text"]]
    assert sum("starts: target" in t for t in texts) == 2 and any(t.startswith("occluded") for t in texts)
    assert "KB per step" in capsys.readouterr().out


def test_record_command_rejects_bad_arguments(tmp_path, capsys):
    from apac_mj.cli import main

    assert main(["record", "--episodes", "0", "--out", str(tmp_path / "x.rrd")]) == 2
    assert "--episodes" in capsys.readouterr().err
    assert main(["record", "--out", str(tmp_path / "x.mp4")]) == 2
    assert main(["record", "--video", str(tmp_path / "x.avi"), "--out", str(tmp_path / "x.rrd")]) == 2
    assert main(["record", "--run", str(tmp_path / "missing"), "--out", str(tmp_path / "x.rrd")]) == 2


def test_record_command_loads_a_run(tiny_run, tmp_path):
    from apac_mj.cli import main

    run_dir, _ = tiny_run
    out = tmp_path / "from_run.rrd"
    assert main(["record", "--run", str(run_dir), "--member", "1", "--episodes", "1", "--out", str(out)]) == 0
    entities, props, _ = R.read_recording(out)
    assert props["seeds"] == [0.0, 1.0] and props["agent.actor_hidden"] == [32.0, 32.0]
    frames = len(entities[R.RENDER].times["frame"])
    _, controller = R.scalar_series(entities[R.CONTROLLER])
    assert len(controller) == frames - 1 >= 1
    # the run finished 3 training episodes: the arbitrator sees episode 3 (past planning_episodes=1)
    assert set(entities[R.DISTANCE].times["episode"]) == {3}
    assert main(["record", "--run", str(run_dir), "--member", "2", "--out", str(tmp_path / "x.rrd")]) == 2


def test_record_says_when_agent_or_task_differ_from_the_run(tiny_run, tmp_path, capsys):
    from apac_mj.cli import main

    run_dir, _ = tiny_run
    trained = json.loads((run_dir / "config.json").read_text())
    other = "spac" if trained["agent"]["kind"] != "spac" else "apac"
    args = ["record", "--run", str(run_dir), "--episodes", "1", "--out", str(tmp_path / "o.rrd")]
    assert main(args) == 0
    assert "note:" not in capsys.readouterr().err
    assert main(args + ["--agent", other, "--task", "static_target", "--force"]) == 0
    err = capsys.readouterr().err
    assert f"trained {trained['agent']['kind']}; recording its networks arbitrated as {other}" in err
    assert f"trained on {trained['task']}; recording on static_target" in err


def test_record_refuses_a_task_with_another_plane_or_shoulder(tiny_run, tmp_path, capsys):
    """A run's networks read positions and command angles in the frame they were trained in: recording them on
    a task whose shoulder (or plane) lies elsewhere is an error naming both geometries, and writes nothing."""
    import dataclasses

    from apac_mj.cli import main
    from apac_mj.suite.task_spec import load_task, register_task, unregister_task

    run_dir, _ = tiny_run
    trained = json.loads((run_dir / "config.json").read_text())["task"]
    for name, change in (("moved_shoulder", {"origin": (10.0, 12.0)}), ("wider_plane", {"plane_size": (40.0, 30.0)})):
        register_task(dataclasses.replace(load_task(trained), name=name, **change))
        try:
            out = tmp_path / f"{name}.rrd"
            assert main(["record", "--run", str(run_dir), "--episodes", "1", "--task", name, "--out", str(out)]) != 0
            err = capsys.readouterr().err
            assert f"apac-mj record: error: --task {name}: its arm geometry" in err and "(15.0, 15.0)" in err
            assert not out.exists()
        finally:
            unregister_task(name)


def test_dashed_forward_model_arm_geometry():
    """The predicted arm is drawn as dashes: every other piece of length ``dash`` along each segment."""
    strip = np.array([[15.0, 15.0], [21.0, 15.0], [21.0, 18.0]])  # segments of 6 and 3 cm
    dashes = R._dashed(strip, dash=0.6)
    assert dashes.shape == (5 + 3, 2, 2)  # 10 pieces -> 5 dashes; 5 pieces -> 3 dashes
    np.testing.assert_allclose(dashes[:5, 0, 0], 15.0 + np.arange(5) * 1.2)
    np.testing.assert_allclose(np.linalg.norm(dashes[:, 1] - dashes[:, 0], axis=1), 0.6)
    np.testing.assert_allclose(dashes[5:, :, 0], 21.0)


def test_a_task_with_dynamics_records_its_physics(tmp_path):
    """The commanded arm beside the reached one, the field's force at the hand, the load and the joint
    velocities; the paper's ideal arm records none of them."""
    import dataclasses

    from apac_mj.suite.task_spec import load_task

    task = "changing_target_compliant_curl_field"
    plant = dataclasses.replace(load_task(task).plant, field_on_episode=0)
    path = tmp_path / "curl.rrd"
    _record_plain_rollout(path, task, episodes=1, plant=plant)
    entities, _, _ = R.read_recording(path)
    assert all(p in entities for p in R.PLANT_PATHS), [p for p in R.PLANT_PATHS if p not in entities]
    _, speed = R.scalar_series(entities[f"{R.JOINT_VELOCITY}/shoulder"])
    _, force = R.scalar_series(entities[R.HAND_FORCE_SIZE])
    assert np.max(np.abs(speed)) > 10.0 and np.max(force) > 0.1  # the arm moved and the field pushed
    _, load = R.scalar_series(entities[R.LOAD])
    assert np.all(load == 0.0)
    ideal, _, _ = R.read_recording(_paper_rollout(tmp_path))
    assert not any(p in ideal for p in R.PLANT_PATHS)


def _paper_rollout(tmp_path: Path) -> Path:
    path = tmp_path / "ideal.rrd"
    _record_plain_rollout(path, "changing_target", episodes=1)
    return path


def test_reached_targets_predicts_what_each_members_recording_shows(tiny_run, tmp_path):
    """The demo picks the seed to record from a dry rollout: it must be the rollout record() then writes."""
    from apac_mj.recording.record import reached_targets, record

    run_dir, _ = tiny_run
    reached = reached_targets(run_dir, 2)
    assert reached.shape == (2, 2)
    for member in range(2):
        out = record(tmp_path / f"m{member}.rrd", run=run_dir, member=member, episodes=2, progress=False).rrd
        entities, _, _ = R.read_recording(out)
        texts = [t[0] for t in entities[R.EVENTS].components["TextLog:text"]]
        ends = [t.startswith("target reached") for t in texts if t.startswith(("target reached", "time limit"))]
        assert ends == reached[member].tolist()


def test_showcase_member_prefers_most_reached_then_a_reached_first_episode():
    from apac_mj.recording.record import showcase_member

    assert showcase_member(np.array([[False, True, True], [True, True, False], [True, True, True]])) == 2
    assert showcase_member(np.array([[False, True, True], [True, True, False]])) == 1
    assert showcase_member(np.array([[False, False], [False, False]])) == 0


def test_a_planning_agents_recording_draws_its_plan_and_iterations(tmp_path):
    """Training an MPC kind with a recorder: every planned step draws the chosen plan (horizon + 1 points, from
    the hand as it was) and its candidates, and the iterations and the decision time are series."""
    from conftest import TINY_MPC

    from apac_mj.run.run_dir import RunDir, config_dict
    from apac_mj.run.trainer import train

    cfg = _tiny_train_config(seeds=(0,), kind="spac_mpc", params=TINY_MPC)
    run_dir = tmp_path / "run"
    steps = []
    with R.EpisodeRecorder(RunDir(run_dir).recordings, record_every=1, config=config_dict(cfg)) as recorder:
        train(cfg, run_dir, progress=False, hooks=[recorder], on_step=lambda info, env: steps.append(info))
    entities, _, _ = R.read_recording(sorted((run_dir / "recordings").glob("*.rrd"))[-1])
    assert R.PLAN in entities and R.PLAN_CANDIDATES in entities
    strips = entities[R.PLAN].components["LineStrips2D:strips"]
    assert all(len(row) == 1 and len(row[0]) == TINY_MPC["mpc"]["horizon"] + 1 for row in strips)
    _, iterations = R.scalar_series(entities[R.PLAN_ITERATIONS])
    assert set(iterations.tolist()) == {float(TINY_MPC["mpc"]["iterations"])}
    _, ms = R.scalar_series(entities[R.DECISION_MS])
    assert (ms > 0).all()
    planned = [s for s in steps if s.plan is not None and s.episode[0] >= 0]
    assert planned and all(np.allclose(s.plan["hand"][0, 0], s.state[0, :2]) for s in planned)


def test_preview_counts_the_steps_each_members_recording_shows(tiny_run, tmp_path):
    """The demo sizes its recording from a dry rollout's steps: a recording has one frame per step and one
    per episode start, so the preview's steps must equal the frames it then writes, member by member."""
    from apac_mj.recording.record import preview, record

    run_dir, _ = tiny_run
    seen = preview(run_dir, 2)
    assert seen.steps.shape == (2, 2) and (seen.steps >= 1).all()
    for member in range(2):
        r = record(tmp_path / f"m{member}.rrd", run=run_dir, member=member, episodes=2, progress=False)
        assert r.frames == int(seen.steps[member].sum()) + 2
    early = preview(run_dir, 5, until_steps=1)  # every member has a step after its first episode
    assert early.steps.shape == (2, 1) and (early.steps == seen.steps[:, :1]).all()


def test_episodes_for_steps_takes_the_fewest_leading_episodes():
    from apac_mj.recording.record import episodes_for_steps

    assert episodes_for_steps(np.array([3, 1, 1, 30, 2]), 5) == 3
    assert episodes_for_steps(np.array([3, 1, 1, 30, 2]), 6) == 4
    assert episodes_for_steps(np.array([3, 1, 1, 30, 2]), 3) == 1
    assert episodes_for_steps(np.array([3, 1, 1]), 60) == 3  # fewer steps than asked: all of them
    with pytest.raises(ValueError, match="min_steps"):
        episodes_for_steps(np.array([3]), 0)
