"""Trial types (``[trials]``, apac_mj.suite.trials): block schedules, channel and catch trials, the go cue, their
per-trial metrics and recordings, the refusals, and every kind training on them (issue 44 items 2 and 6).

Known answers: the schedule of a 3-block table, episode by episode; the channel's force for a hand held at a known
lateral offset and velocity (the spring-damper's, computed here from the geometry); the channel's bound on the
lateral deviation under constant torques (energy: K d^2 / 2 <= the torques' work tau . (q - q0)); a catch trial's
zero force; a table that applies nothing reproduces its task bit for bit.
"""
from __future__ import annotations

import math

import mujoco
import numpy as np
import pandas as pd
import pytest

import apac_mj
from apac_mj import kinds
from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.run import run_dir
from apac_mj.suite import load_spec, planar_arm, trials
from apac_mj.suite.plant import FORCE_UNIT, PlantSpec
from apac_mj.kinematics import motion_function
from apac_mj.suite.task_spec import START_ANGLES, TaskSpec, TaskSpecError, parse_task
from apac_mj.suite.trials import Block, TrialSpec
from apac_mj.suite.vec_env import VecEnv

from conftest import TINY_MPC
from conftest import TINY8 as TINY

TASK = "changing_target_compliant_channel_trials"
COMPLIANT = PlantSpec(actuation="compliant")


def _spec(blocks, plant=COMPLIANT, steps=10, **table) -> TaskSpec:
    return TaskSpec(name="trials_probe", plant=plant, steps_per_episode=steps,
                    trials=TrialSpec(blocks=tuple(blocks), **table))


def _env(spec: TaskSpec, seed: int = 0):
    env = planar_arm.make_environment(spec, random=seed)
    env.reset()
    return env


# -- the schedule ------------------------------------------------------------------------------------------------------

def test_three_block_schedule_gives_each_episode_its_block():
    spec = TrialSpec(blocks=(Block("a", 2), Block("b", 3, field_b=10.0), Block("c", 1, field_b=-10.0)))
    assert [spec.block_at(e) for e in range(9)] == [0, 0, 1, 1, 1, 2, 2, 2, 2]  # after the last: the last
    shifted = spec.shifted(4)  # a run's 4 babbling episodes: the first block's settings
    assert [shifted.block_at(e) for e in range(13)] == [0] * 6 + [1, 1, 1, 2, 2, 2, 2]
    types = [spec.trial_at(7, e).type for e in range(9)]
    assert types == ["null", "null", "field", "field", "field", "field", "field", "field", "field"]
    assert [spec.trial_at(7, e).field_b for e in (0, 2, 5)] == [0.0, 10.0, -10.0]


def test_the_environments_run_the_schedule_after_the_babbling():
    task = _spec([Block("a", 1), Block("b", 2, field_b=50.0), Block("c", 1, channel=True)], steps=2)
    env = VecEnv(task, [0], episode_offset=2)  # 2 babbling episodes, then the schedule from its episode 0
    seen = []
    for _ in range(7):
        env.reset()
        while not env.obs.last[0]:
            env.step(np.zeros((1, 2)))
        seen.append((env.episode(0), env.trial_record(0)["trial_block"], env.physics(0).field_b))
    assert seen == [(-2, "a", 0.0), (-1, "a", 0.0), (0, "a", 0.0), (1, "b", 50.0), (2, "b", 50.0), (3, "c", 0.0),
                    (4, "c", 0.0)]


def test_trial_types_are_a_pure_function_of_seed_and_episode():
    spec = TrialSpec(blocks=(Block("mixed", 4000, field_b=10.0, channel_probability=0.2, catch_probability=0.25),))
    a = [spec.trial_at(11, e).type for e in range(4000)]
    assert a == [spec.trial_at(11, e).type for e in range(4000)]       # the same key: the same schedule
    assert a != [spec.trial_at(12, e).type for e in range(4000)]       # another key: another one
    n = len(a)  # channel: p = 0.2; catch: 0.8 x 0.25 = 0.2 of all trials; 5 binomial standard deviations
    for kind, p in (("channel", 0.2), ("catch", 0.2), ("field", 0.6)):
        assert abs(a.count(kind) - p * n) < 5 * math.sqrt(n * p * (1 - p)), kind
    null_block = TrialSpec(blocks=(Block("null", 50, catch_probability=1.0),))  # no field: nothing to catch
    assert {null_block.trial_at(3, e).type for e in range(50)} == {"null"}


def test_the_trial_key_leaves_the_task_stream_alone():
    """The key comes from a copy of the seed's stream: a task with an inert table draws the targets (and every other
    number) of the same task without it, bit for bit; two seeds get two keys."""
    base = load_spec("changing_target_compliant_curl_field")
    plain = base.replace(plant={"field_b": 0.0, "field_on_episode": -1, "field_off_episode": -1})
    inert = plain.replace(trials={"block": [{"name": "baseline", "episodes": 5}]})
    runs = []
    for spec in (plain, inert):
        env, rng, rec = VecEnv(spec, [0, 3]), np.random.default_rng(1), []
        for _ in range(2):
            env.reset()
            rec.append(env.obs.target.copy())
            while not env.obs.last.all():
                env.step(rng.uniform(-30, 30, (2, 2)), ~env.obs.last)
                rec += [env.obs.arm.copy(), env.obs.reward.copy()]
        runs.append(np.concatenate([r.ravel() for r in rec]))
    np.testing.assert_array_equal(runs[0], runs[1])
    keys = [planar_arm.make_environment(inert, random=s).task.trials.key for s in (0, 0, 3)]
    assert keys[0] == keys[1] != keys[2]


# -- the channel -------------------------------------------------------------------------------------------------------

def _hold(physics, angles_deg, qvel=(0.0, 0.0)) -> None:
    """Put the arm at ``angles_deg`` moving at ``qvel`` (rad/s) and compute what a sub-step sees (mj_step1)."""
    d = physics.data.ptr
    d.qpos[:2] = np.deg2rad(angles_deg)
    d.qvel[:2] = qvel
    mujoco.mj_step1(physics.model.ptr, d)


@pytest.mark.parametrize("qvel", [(0.0, 0.0), (1.5, -2.0)])
def test_channel_force_is_the_spring_damper_for_a_known_offset(qvel):
    k, b = 6000.0, 150.0
    env = _env(_spec([Block("clamp", 5, channel=True)], channel_stiffness=k, channel_damping=b))
    physics, runner = env.physics, env.task.trials
    anchor, target = np.array(runner.anchor), np.array(runner.target)
    _hold(physics, (30.0, 100.0), qvel)
    hand = physics.end_effector()
    jac = np.zeros((3, physics.model.nv))  # the hand's velocity, from MuJoCo's Jacobian (cm/s)
    mujoco.mj_jacSite(physics.model.ptr, physics.data.ptr, jac, None, physics.ids.end_site)
    velocity = (jac @ physics.data.qvel)[:2]
    u = (target - anchor) / np.linalg.norm(target - anchor)
    n = np.array([u[1], -u[0]])  # clockwise: where the b > 0 curl field pushes a hand moving along u
    assert np.allclose(planar_arm.curl_force(1.0, u), n)
    offset, rate = (hand - anchor) @ n, velocity @ n  # cm, cm/s
    assert abs(offset) > 1.0  # a real offset, not the line
    expected_n = -(k * offset / 100 + b * rate / 100) * n  # N: K (N/m) x offset (m) + B (N·s/m) x rate (m/s)
    physics.dynamics.apply_field()
    applied = physics.data.xfrc_applied[physics.ids.fore_body, :2] / FORCE_UNIT
    np.testing.assert_allclose(applied, expected_n, rtol=1e-9)
    assert runner.record()["channel_force_peak"] == pytest.approx(-expected_n @ n, rel=1e-9)  # the agent's push


def _one_step(trial: str, stiffness: float, change_deg) -> float:
    """The lateral error (cm) of one control step of the compliant arm from its start pose with the servos' set-point
    moved by ``change_deg``, through a channel or a null trial whose line is perpendicular to the set-point's hand
    displacement (the whole displacement is lateral)."""
    block = Block("clamp", 5, channel=True) if trial == "channel" else Block("null", 5)
    spec = TaskSpec(name="trials_probe", plant=COMPLIANT, at_limit="unbounded", steps_per_episode=3,
                    trials=TrialSpec(blocks=(block,), channel_stiffness=stiffness))
    env = planar_arm.make_environment(spec, random=0)
    start, _ = motion_function(*START_ANGLES, *spec.link_lengths, spec.origin)
    goal, _ = motion_function(*(np.array(START_ANGLES) + change_deg), *spec.link_lengths, spec.origin)
    across = np.array([goal[1] - start[1], start[0] - goal[0]]) / np.linalg.norm(goal - start)
    env.task.set_target_override(start + 4.0 * across)
    env.reset()
    env.step(np.asarray(change_deg, dtype=float))
    return env.task.trials.record()["lateral_error"]


@pytest.mark.parametrize("change_deg", [(10.0, 25.0), (-15.0, -30.0)])
def test_in_a_channel_the_lateral_deviation_stays_below_its_energy_bound(change_deg):
    """The servos start at rest with the set-point moved by dq: their spring holds V0 = dq' Kp dq / 2 (Kp the joint
    stiffness), and nothing adds energy after (no gravity, no field; the dampers take some), so the channel's spring
    K d^2 / 2 <= V0 at every sub-step: |d| <= sqrt(dq' Kp dq / K). A free arm strays past the bound of a 60 kN/m
    channel, which holds it well inside; the 6 kN/m default stays inside its own (looser) bound."""
    dq = np.deg2rad(change_deg)
    kp = np.array(COMPLIANT.stiffness)
    for stiffness in (60000.0, trials.CHANNEL_STIFFNESS):
        bound_cm = math.sqrt(dq @ (kp * dq) / stiffness) * 100
        assert abs(_one_step("channel", stiffness, change_deg)) <= bound_cm
    free = abs(_one_step("null", 60000.0, change_deg))
    assert free > 1.5 * math.sqrt(dq @ (kp * dq) / 60000.0) * 100


# -- catch trials ------------------------------------------------------------------------------------------------------

def test_a_catch_trial_has_no_field_force():
    catch = _env(_spec([Block("field", 5, field_b=100.0, catch_probability=1.0)]))
    field = _env(_spec([Block("field", 5, field_b=100.0)]))
    forces = {}
    for name, env in (("catch", catch), ("field", field)):
        largest = 0.0
        for _ in range(3):
            env.step(np.array([20.0, -30.0]))
            largest = max(largest, float(np.abs(env.physics.data.xfrc_applied).max()))
        forces[name] = (largest, env.task.trials.record(), env.physics.field_b)
    assert forces["catch"][0] == 0.0 and forces["catch"][2] == 0.0
    assert forces["catch"][1]["trial_type"] == "catch" and forces["catch"][1]["trial_field_b"] == 0.0
    assert forces["field"][0] > 0.0 and forces["field"][2] == 100.0 and forces["field"][1]["trial_type"] == "field"


# -- the go cue --------------------------------------------------------------------------------------------------------

def test_the_go_cue_holds_then_shows_the_target_and_counts_early_movements():
    spec = _spec([Block("null", 5)], go_cue_step=3, early_movement_cm=0.5)
    env = planar_arm.make_environment(spec, random=0)
    ts = env.reset()
    runner = env.task.trials
    start, target = np.array(runner.start), np.array(runner.target)
    assert np.linalg.norm(target - start) > 1.0
    np.testing.assert_allclose(ts.observation["target"], start)  # the hold: the hand's start is shown
    rewards = []
    for step in range(1, 5):
        ts = env.step(np.zeros(2))  # the hand at the shown target: only the hold keeps the episode going
        rewards.append(ts.reward)
        assert not ts.last()
        np.testing.assert_allclose(ts.observation["target"], start if step < 3 else target)
    assert rewards[:3] == pytest.approx([0.0] * 3, abs=1e-9)  # held still: no cost
    assert rewards[3] == pytest.approx(-np.linalg.norm(target - start), rel=1e-6)  # then the task's reward
    assert runner.record()["early_movement"] is False
    env.reset()
    ts = env.step(np.array([40.0, -40.0]))  # a move before the cue
    moved = np.linalg.norm(env.physics.end_effector() - np.array(env.task.trials.start))
    assert moved > 0.5 and ts.reward == pytest.approx(-moved, rel=1e-9)
    assert env.task.trials.record()["early_movement"] is True


# -- resume, metrics, recordings ---------------------------------------------------------------------------------------

def test_a_restored_environment_continues_the_trial_exactly():
    task = _spec([Block("clamp", 1, channel=True), Block("field", 3, field_b=80.0, catch_probability=0.5)],
                 go_cue_step=2)
    a, b = VecEnv(task, [0, 1]), VecEnv(task, [0, 1])
    rng = np.random.default_rng(0)
    actions = rng.uniform(-30, 30, (40, 2, 2))
    for env in (a,):
        env.reset()
        for t in range(4):
            env.step(actions[t])
    b.set_state(a.get_state())
    records = []
    for env in (a, b):
        for t in range(4, 10):
            env.step(actions[t], ~env.obs.last)
        records.append([env.trial_record(k) for k in range(2)])
    assert records[0] == records[1] and records[0][0]["trial_type"] == "channel"


def test_metrics_carry_the_trial_columns_and_other_tasks_none(tmp_path):
    assert set(trials.TRIAL_COLUMNS) == set(run_dir.TRIAL_COLUMNS)
    centre_out_only = {"trial_direction"}
    overrides = {"steps_per_episode": 6, "trials": {"go_cue_step": 1, "block": [
        {"name": "clamp", "episodes": 1, "channel": True},
        {"name": "adapt", "episodes": 1, "field_b": 100.0, "catch_probability": 1.0},
        {"name": "after", "episodes": 1, "field_b": -100.0}]}}
    agent = AgentConfig(kind="apac", **TINY)
    run = apac_mj.train(TrainConfig(task=TASK, seeds=(0,), episodes=3, task_overrides=overrides, agent=agent),
                        tmp_path / "trials", progress=False)
    df = pd.read_parquet(run / "metrics.parquet")
    assert list(df.columns[:len(run_dir.METRIC_COLUMNS)]) == list(run_dir.METRIC_COLUMNS)
    assert set(run_dir.TRIAL_COLUMNS) - set(df.columns) == centre_out_only  # no centre-out targets here
    assert df[["episode", "trial_block", "trial_type"]].values.tolist() == [
        [-1, "clamp", "channel"], [0, "clamp", "channel"], [1, "adapt", "catch"], [2, "after", "field"]]
    assert df.trial_field_b.tolist() == [0.0, 0.0, 0.0, -100.0]
    assert df.channel_force_peak[:2].notna().all() and df.channel_force_peak[2:].isna().all()
    rows = run_dir.RunDir(run).metrics().to_dict("records")
    edited = [dict(r) for r in rows]
    edited[1]["lateral_error"] += 1.0  # a trial column is in the rows' digest
    assert run_dir.metric_digest(rows) != run_dir.metric_digest(edited)
    plain = apac_mj.train(TrainConfig(task="changing_target_compliant_curl_field", seeds=(0,), episodes=1,
                                      task_overrides={"steps_per_episode": 4}, agent=agent),
                          tmp_path / "plain", progress=False)
    assert not set(run_dir.TRIAL_COLUMNS) & set(pd.read_parquet(plain / "metrics.parquet").columns)


def test_a_recording_shows_the_channel_the_catch_trial_and_the_go_cue(tmp_path):
    from apac_mj.recording import recording as R

    views = {}
    for kind, block in (("channel", Block("clamp", 5, channel=True)),
                        ("catch", Block("f", 5, field_b=50.0, catch_probability=1.0))):
        env = VecEnv(_spec([block], go_cue_step=1, steps=3), [0])
        rec = R.Recording(tmp_path / f"{kind}.rrd", plane_size=env.spec.plane_size)
        env.reset()
        rec.start_episode(0, env.physics(0).target(), env.physics(0).link_lengths())
        rec.log_trial(0, 0, env.trial_view(0))
        for step in (1, 2):
            env.step(np.full((1, 2), 10.0))
            rec.log_trial(0, step, env.trial_view(0))
        rec.close()
        entities, _, _ = R.read_recording(tmp_path / f"{kind}.rrd")
        views[kind] = (entities, [t[0] for t in entities[R.EVENTS].components["TextLog:text"]])
    (channel, channel_events), (catch, catch_events) = views["channel"], views["catch"]
    def drawn(entities, path):  # rows that draw strips (a trial's start also clears the last trial's)
        return len(entities[path].components.get("LineStrips2D:strips", []))

    assert drawn(channel, R.CHANNEL) == 3 and drawn(catch, R.CHANNEL) == 0  # the walls at every channel step
    assert drawn(catch, R.TRIAL_MARKER) == 2  # the catch cross at the start, the go cue's at step 1
    assert drawn(channel, R.TRIAL_MARKER) == 1   # the go cue's only
    assert any(t.startswith("catch trial in block 'f'") for t in catch_events)
    assert any(t.startswith("channel trial in block 'clamp'") for t in channel_events)
    assert sum(t.startswith("go cue: the target shown") for t in catch_events + channel_events) == 2


# -- centre-out targets ------------------------------------------------------------------------------------------------

def test_each_direction_comes_once_per_cycle_in_an_order_drawn_per_cycle():
    spec = TrialSpec(blocks=(Block("a", 40),), directions=8, start_episode=3)  # 3 babbling episodes before
    ks = [spec.direction_at(5, e) for e in range(3, 3 + 40)]
    for c in range(5):
        assert sorted(ks[8 * c:8 * c + 8]) == list(range(8))
    assert len({tuple(ks[8 * c:8 * c + 8]) for c in range(5)}) > 1  # not one order repeated
    assert ks == [spec.direction_at(5, e) for e in range(3, 43)]  # a pure function of (key, episode)
    assert ks != [spec.direction_at(6, e) for e in range(3, 43)]
    assert sorted(spec.direction_at(5, e) for e in range(-5, 3)) == list(range(8))  # babbling: a cycle of its own
    assert spec.trial_at(5, 10).direction == ks[7]
    assert TrialSpec(blocks=(Block("a", 4),)).direction_at(5, 2) == -1  # no centre-out: -1


def test_centre_out_targets_lie_at_the_distance_and_angle_from_the_start_posture():
    spec = _spec([Block("a", 20)], directions=4, distance_cm=2.5, first_direction_deg=90.0, start_angles=(45.0, 90.0))
    start, _ = motion_function(45.0, 90.0, *spec.link_lengths, spec.origin)
    env = planar_arm.make_environment(spec, random=3)
    seen = {}
    for _ in range(8):
        env.reset()
        np.testing.assert_allclose(env.physics.joint_angles(), (45.0, 90.0))
        np.testing.assert_allclose(env.physics.end_effector(), start, atol=1e-9)
        k = env.task.trials.trial.direction
        seen[k] = env.physics.target() - start
        assert env.task.trials.record()["trial_direction"] == k
    by_hand = {0: (0.0, 2.5), 1: (-2.5, 0.0), 2: (0.0, -2.5), 3: (2.5, 0.0)}  # 90, 180, 270, 360 degrees
    assert sorted(seen) == [0, 1, 2, 3]
    for k, offset in seen.items():
        np.testing.assert_allclose(offset, by_hand[k], atol=1e-12)


def test_reaching_angles_invert_the_motion_function():
    for alpha, beta in ((45.0, 90.0), (10.0, 150.0), (120.0, 30.0)):
        end, _ = motion_function(alpha, beta, 5.0, 8.0, (15.0, 15.0))
        pairs = trials.reaching_angles(end, (5.0, 8.0), (15.0, 15.0))
        assert any(abs(a - alpha) < 1e-9 and abs(b - beta) < 1e-9 for a, b in pairs)
        for a, b in pairs:
            np.testing.assert_allclose(motion_function(a, b, 5.0, 8.0, (15.0, 15.0))[0], end, atol=1e-9)
    assert trials.reaching_angles((15.0 + 13.5, 15.0), (5.0, 8.0), (15.0, 15.0)) == []  # beyond l1 + l2


@pytest.mark.parametrize("table, names", [
    ({"directions": 8, "distance_cm": 9.0}, "trials.directions: direction"),  # off the reachable annulus
    ({"directions": 8, "start_angles": [0.0, 180.0]}, "trials.directions: direction"),  # folded: some out of range
    ({"directions": -1}, "trials.directions"),
    ({"directions": 8, "distance_cm": 0.0}, "trials.distance_cm"),
    ({"start_angles": [45.0]}, "trials.start_angles"),
    ({"start_angles": [45.0, 200.0]}, "start pose"),
])
def test_bad_centre_out_tables_are_refused(table, names):
    data = _task({**table, "block": [{"name": "a", "episodes": 5}]})
    with pytest.raises(TaskSpecError, match=names.replace("[", r"\[").replace(".", r"\.")):
        parse_task(data, "bad", "bad.toml")


def test_centre_out_targets_refuse_a_task_that_sets_its_own():
    with pytest.raises(TaskSpecError, match="centre-out targets need a task of changing targets"):
        parse_task(_task({"directions": 4, "block": [{"name": "a", "episodes": 5}]}, target={"mode": "static"}),
                   "bad", "bad.toml")


# -- refusals ----------------------------------------------------------------------------------------------------------

def _task(trials_table, plant=None, **top) -> dict:
    return {**top, "plant": plant or {"actuation": "compliant"}, "trials": trials_table}


@pytest.mark.parametrize("data, names", [
    (_task({"block": [{"name": "a", "episodes": -3}]}), "trials.block[0].episodes"),
    (_task({"block": [{"name": "a", "episodes": 0}]}), "trials.block[0].episodes"),
    (_task({"block": [{"name": "a", "episodes": 5, "channel": True}]}, plant={"actuation": "ideal"}), "trials.block[0].channel"),
    (_task({"block": [{"name": "a", "episodes": 5, "field_b": 10.0}]}, plant={"actuation": "ideal"}), "trials.block[0].field_b"),
    (_task({"block": [{"name": "a", "episodes": 5, "channel_probability": 0.2}]}, plant={"actuation": "ideal"}),
     "trials.block[0].channel_probability"),
    (_task({"block": [{"name": "a", "episodes": 5, "field_b": 1.0, "catch_probability": 1.5}]}),
     "trials.block[0].catch_probability"),
    (_task({"channel_probability": -0.1, "block": [{"name": "a", "episodes": 5}]}), "trials.channel_probability"),
    (_task({"block": [{"name": "a", "episodes": 5, "catch_probability": 0.5}]}), "trials.block[0].catch_probability"),
    (_task({"go_cue_step": 30, "block": [{"name": "a", "episodes": 5}]}), "trials.go_cue_step"),
    (_task({"go_cue_step": 2, "block": [{"name": "a", "episodes": 5}]}, vision={"mode": "occluded"}),
     "trials.go_cue_step"),
    (_task({"channel_stiffness": 0.0, "block": [{"name": "a", "episodes": 5}]}), "trials.channel_stiffness"),
    (_task({"block": []}), "trials.block"),
    (_task({"block": [{"name": "a", "episodes": 5, "b": 1}]}), "unknown key"),
    (_task({"block": [{"name": "a", "episodes": 5}]}, plant={"actuation": "compliant", "field_b": 5.0,
                                                             "field_on_episode": 1}), "plant.field_b"),
])
def test_bad_values_are_refused_naming_the_field(data, names):
    with pytest.raises(TaskSpecError, match=names.replace("[", r"\[").replace("]", r"\]").replace(".", r"\.")):
        parse_task(data, "bad", "bad.toml")


def test_a_bad_table_is_refused_before_anything_is_written(tmp_path):
    out = tmp_path / "run"
    cfg = TrainConfig(task="changing_target", seeds=(0,), episodes=1, agent=AgentConfig(kind="apac", **TINY),
                      task_overrides={"trials": {"block": [{"name": "clamp", "episodes": 2, "channel": True}]}})
    with pytest.raises(TaskSpecError, match=r"trials\.block\[0\]\.channel.*ideal plant"):
        apac_mj.train(cfg, out, progress=False)
    assert not out.exists()
    kinematic = TrainConfig(task=TASK, seeds=(0,), episodes=1, actuation="kinematic",
                            agent=AgentConfig(kind="apac", **TINY))
    with pytest.raises(ValueError, match="kinematic"):
        apac_mj.train(kinematic, out, progress=False)
    assert not out.exists()


# -- every kind runs on the trial types --------------------------------------------------------------------------------

#: Babbling in a channel trial, then a catch trial and a field trial, a go cue after one step of hold: 8-step episodes.
KIND_TRIALS = {"steps_per_episode": 8, "trials": {"go_cue_step": 1, "block": [
    {"name": "clamp", "episodes": 1, "channel": True},
    {"name": "catch", "episodes": 1, "field_b": 100.0, "catch_probability": 1.0},
    {"name": "field", "episodes": 1, "field_b": 100.0}]}}


@pytest.mark.parametrize("kind", kinds.names())
def test_every_kind_trains_on_the_trial_types(tmp_path, kind):
    cfg = TrainConfig(task=TASK, seeds=(0,), episodes=3, task_overrides=KIND_TRIALS,
                      agent=AgentConfig(kind=kind, **{**TINY, "planning_episodes": 0}, params=TINY_MPC))
    df = pd.read_parquet(apac_mj.train(cfg, tmp_path, progress=False) / "metrics.parquet")
    assert df.trial_type.tolist() == ["channel", "channel", "catch", "field"]
    assert np.isfinite(df["return"]).all() and np.isfinite(df.lateral_error).all()


def test_an_extended_run_has_the_trials_of_an_uninterrupted_one(tmp_path):
    """Trial types are a pure function of (seed, episode): a run trained for 2 episodes and then extended to 4 has the
    metrics, trial columns included, of one trained for 4 at once."""
    overrides = {"steps_per_episode": 5, "trials": {"directions": 3, "start_angles": [45.0, 90.0], "block": [
        {"name": "mixed", "episodes": 4, "field_b": 80.0, "channel_probability": 0.4, "catch_probability": 0.5}]}}

    def cfg(episodes: int) -> TrainConfig:
        return TrainConfig(task=TASK, seeds=(0, 1), episodes=episodes, checkpoint_every=1, task_overrides=overrides,
                           agent=AgentConfig(kind="apac", **TINY))

    whole = pd.read_parquet(apac_mj.train(cfg(4), tmp_path / "whole", progress=False) / "metrics.parquet")
    apac_mj.train(cfg(2), tmp_path / "parts", progress=False)
    parts = pd.read_parquet(apac_mj.train(cfg(4), tmp_path / "parts", progress=False) / "metrics.parquet")
    columns = [*run_dir.METRIC_COLUMNS, *run_dir.TRIAL_COLUMNS]
    pd.testing.assert_frame_equal(whole[columns], parts[columns])  # centre-out directions included
    assert len(set(whole.trial_type)) >= 2 and set(whole.trial_direction) == {0, 1, 2}


def test_the_ideal_plant_measures_once_per_step():
    """The ideal arm (kinematic actuation: the hand jumps to each command) has no forces, so only a go cue and null
    blocks; its lateral error is the largest deviation of the hand's positions after each step since the cue."""
    spec = TaskSpec(name="trials_probe", steps_per_episode=4, trials=TrialSpec(blocks=(Block("null", 3),),
                                                                              go_cue_step=1))
    env = planar_arm.make_environment(spec, actuation="kinematic", random=0)
    env.reset()
    runner, deviations = env.task.trials, []
    for step, action in enumerate(([0.0, 0.0], [30.0, -20.0], [-10.0, 15.0], [5.0, 5.0]), 1):
        env.step(np.array(action))
        if step > 1:  # after the cue, across the line from the hand's position then to the target
            deviations.append((env.physics.end_effector() - np.array(runner.anchor)) @ np.array(runner.normal))
    record = runner.record()
    assert record["trial_type"] == "null" and record["early_movement"] is False
    assert record["lateral_error"] == pytest.approx(max(deviations, key=abs), rel=1e-12)
    assert math.isnan(record["channel_force_peak"])


def test_every_trial_type_carries_its_block_and_direction_and_the_schedule_shifts_whole():
    spec = TrialSpec(blocks=(Block("a", 8), Block("b", 24, field_b=10.0, channel_probability=0.3,
                                                    catch_probability=0.4)), directions=4)
    seen = set()
    for e in range(32):
        t = spec.trial_at(3, e)
        assert (t.block, t.direction) == (int(e >= 8), spec.direction_at(3, e))
        seen.add(t.type)
    assert seen == {"null", "channel", "catch", "field"}
    shifted = spec.shifted(5)  # 5 babbling episodes before: episode e + 5 is the unshifted e
    assert [shifted.trial_at(3, e + 5) for e in range(32)] == [spec.trial_at(3, e) for e in range(32)]
    assert TrialSpec(blocks=(Block("a", 3),), directions=1).direction_at(3, 2) == 0  # one direction: always 0


def test_reaching_angles_give_both_elbows_and_the_edge_of_the_workspace():
    origin = (15.0, 12.0)  # not symmetric in x and y
    end, _ = motion_function(30.0, 70.0, 5.0, 8.0, origin)
    pairs = trials.reaching_angles(end, (5.0, 8.0), origin)
    assert len(pairs) == 2 and {round(b, 9) for _, b in pairs} == {70.0, -70.0}
    for a, b in pairs:
        np.testing.assert_allclose(motion_function(a, b, 5.0, 8.0, origin)[0], end, atol=1e-9)
    stretched = trials.reaching_angles((15.0 + 13.0, 12.0), (5.0, 8.0), origin)  # full extension: c = 1 exactly
    assert [tuple(round(v, 9) for v in p) for p in stretched] == [(0.0, 0.0)]


def test_a_centre_out_target_off_the_plane_is_refused():
    table = {"directions": 4, "distance_cm": 3.0, "first_direction_deg": 180.0, "start_angles": [45.0, 90.0],
             "block": [{"name": "a", "episodes": 5}]}
    near_edge = _task(table, plane={"origin": [4.0, 15.0]})  # the hand starts at x = 1.88 cm: 3 cm left is off the plane
    with pytest.raises(TaskSpecError, match=r"direction 0's target \(-1\.12, 24\.19\) cm.*off the plane"):
        parse_task(near_edge, "bad", "bad.toml")
    parse_task(_task({**table, "first_direction_deg": 0.0, "distance_cm": 1.0}, plane={"origin": [4.0, 15.0]}),
               "ok", "ok.toml")
