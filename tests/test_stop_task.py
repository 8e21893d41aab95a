"""The stop criterion (``[target] stop_speed``, ``TaskSpec.stop_speed``) and the task built on it,
``changing_target_torque_stop``: reached only inside the zone *and* slower than the stated joint speed; light
joint damping (``[plant] joint_damping``, MuJoCo's ``dof_damping``); the paper's criterion (None) unchanged."""
from __future__ import annotations

import math

import numpy as np
import pytest

from apac_mj import suite
from apac_mj.suite.plant import TORQUE_UNIT
from apac_mj.suite.task_spec import TaskSpec, TaskSpecError, load_task, load_task_file, task_names

STOP = "changing_target_torque_stop"
#: A task file that is the stop task's plant with ``stop_speed`` = the value to check.
TORQUE_PLANT = """
[plant]
actuation = "torque"
max_torque = 0.5
observe_velocities = true
"""


def make(task: str = STOP, seed: int = 0, **overrides):
    return suite.load("planar_arm", task, task_kwargs={"random": seed, **overrides})


def test_stop_task_loads():
    """The task file: a stop criterion of 10 deg/s, the torque arm with 1/5 of changing_target_torque's joint
    damping, its velocities observed (the criterion is on what the agent sees)."""
    spec, torque = load_task(STOP), load_task("changing_target_torque")
    assert STOP in task_names() and spec.name == STOP
    assert spec.stop_speed == 10.0 and torque.stop_speed is None
    assert spec.plant.joint_damping == (0.01, 0.01) and torque.plant.joint_damping == (0.05, 0.05)
    assert spec.plant.observe_velocities and spec.plant.actuation == "torque"
    assert spec.plant.max_torque == torque.plant.max_torque
    ts = make().reset()
    assert "joint_velocities" in ts.observation


def test_joint_damping_sets_dof_damping():
    """``[plant] joint_damping`` (N·m·s/rad) becomes MuJoCo's dof_damping (kg·cm²/s per rad/s) on both hinges."""
    for task, damping in ((STOP, 0.01), ("changing_target_torque", 0.05)):
        env = make(task)
        env.reset()
        qvel = env.physics.ids.qvel
        np.testing.assert_allclose(env.physics.model.dof_damping[qvel], [damping * TORQUE_UNIT] * 2)
    light = make("changing_target_torque", plant={"joint_damping": [0.002, 0.003]})
    np.testing.assert_allclose(light.physics.model.dof_damping[light.physics.ids.qvel], [20.0, 30.0])


def test_inside_but_fast_is_not_reached():
    """A hand inside the zone but moving faster than stop_speed does not end the episode (the episode goes on,
    reward the same -distance); the same state on the paper's criterion (stop_speed None) is reached."""
    env, paper = make(), make(stop_speed=None)
    for e in (env, paper):
        e.task.set_target_override((12.0, 15.0))  # the start pose's hand: (15 + 5 - 8, 15)
        e.reset()
        np.testing.assert_allclose(e.physics.end_effector(), (12.0, 15.0), atol=1e-9)
    ts, pts = env.step(np.array([0.01, 0.0])), paper.step(np.array([0.01, 0.0]))
    d, speed = env.physics.distance_to_target(), float(np.abs(env.physics.joint_velocities()).max())
    assert d <= env.task.spec.zone_radius and speed > env.task.spec.stop_speed, (d, speed)
    assert ts.mid() and not env.task.reached(env.physics) and env.task.get_termination(env.physics) is None
    assert ts.reward == pytest.approx(-d)
    assert pts.last() and pts.discount == 0.0  # the paper's criterion: inside the zone is enough
    np.testing.assert_array_equal(paper.physics.end_effector(), env.physics.end_effector())


def test_inside_and_slow_is_reached():
    """Inside the zone and every joint at most stop_speed deg/s: reached, terminal (discount 0); a joint just
    over the speed (either one) is not; the bound is the observed deg/s value, inclusive."""
    env = make()
    env.task.set_target_override((12.0, 15.0))
    env.reset()
    ts = env.step(np.zeros(2))  # no torque: the arm stays at rest where it started, on the target
    assert ts.last() and ts.discount == 0.0 and env.task.reached(env.physics)
    ph, stop = env.physics, env.task.spec.stop_speed
    for v in ((stop, -stop), (0.5 * stop, 0.0), (stop * 1.001, 0.0), (0.0, -stop * 1.001)):
        ph.data.qvel[ph.ids.qvel] = np.radians(v)
        fast = max(abs(x) for x in ph.joint_velocities()) > stop
        assert env.task.reached(ph) is (not fast), v
        assert env.task.get_termination(ph) == (None if fast else 0.0), v


def test_stop_task_steps_end_only_when_stopped():
    """Along random-torque episodes the episode ends (terminal) exactly where the hand is inside the zone and
    both observed joint speeds are <= stop_speed, and nowhere else."""
    env = make(seed=3)
    rng = np.random.default_rng(0)
    spec = env.task.spec
    for _ in range(3):
        env.task.set_target_override(None)
        ts = env.reset()
        while not ts.last():
            ts = env.step(rng.uniform(-0.05, 0.05, size=2))
            inside = env.physics.distance_to_target() <= spec.zone_radius
            slow = np.abs(ts.observation["joint_velocities"]).max() <= spec.stop_speed
            assert (ts.last() and ts.discount == 0.0) == (inside and slow)


@pytest.mark.parametrize("value, problem", [
    ("-1.0", "must be a positive finite number"), ("0.0", "must be a positive finite number"),
    ("nan", "must be a finite number"), ("inf", "must be a finite number"), ("true", "must be a finite number"),
    ('"fast"', "must be a finite number")])
def test_bad_stop_speed_refused(tmp_path, value, problem):
    """A bad ``[target] stop_speed`` is refused naming the file and the key."""
    path = tmp_path / "stop_bad.toml"
    path.write_text(f"[target]\nstop_speed = {value}\n{TORQUE_PLANT}")
    with pytest.raises(TaskSpecError, match=problem) as e:
        load_task_file(path)
    assert str(path) in str(e.value) and "stop_speed" in str(e.value)


def test_stop_speed_needs_observed_velocities(tmp_path):
    """The criterion is on the joint velocities: a plant that does not observe them (or the ideal arm) refuses
    it, naming the key that is missing."""
    for plant in ("", '[plant]\nactuation = "torque"\n'):
        path = tmp_path / "stop_unseen.toml"
        path.write_text(f"[target]\nstop_speed = 10.0\n{plant}")
        with pytest.raises(TaskSpecError, match=r"stop_speed.*observe_velocities") as e:
            load_task_file(path)
        assert str(path) in str(e.value)
    good = tmp_path / "stop_good.toml"
    good.write_text(f"[target]\nstop_speed = 25\n{TORQUE_PLANT}")
    assert load_task_file(good).stop_speed == 25.0


def test_stop_speed_overrides():
    """As a run's override: a number is checked as in a file, None is the paper's criterion."""
    spec = load_task(STOP)
    assert spec.replace(stop_speed=None).stop_speed is None
    assert spec.replace(stop_speed=30).stop_speed == 30.0
    for bad in (-5.0, math.nan, "10"):
        with pytest.raises(TaskSpecError, match="stop_speed"):
            spec.replace(stop_speed=bad)
    with pytest.raises(TaskSpecError, match="stop_speed"):
        load_task("changing_target").replace(stop_speed=10.0)  # the ideal arm observes no velocities
    with pytest.raises(TaskSpecError, match="stop_speed"):
        TaskSpec(name="x", stop_speed=float("nan"))


def test_paper_tasks_keep_the_zone_criterion():
    """Every shipped task but the stop task has no stop criterion (None: the paper's), and on them the episode
    ends exactly where the hand is inside the zone, however fast it moves (the torque arm included)."""
    assert [n for n in task_names() if load_task(n).stop_speed is not None] == [STOP]
    assert TaskSpec(name="x").stop_speed is None
    for task, actions in (("changing_target", np.random.default_rng(1).uniform(-40, 40, size=(60, 2))),
                          ("changing_target_torque", np.random.default_rng(2).uniform(-0.5, 0.5, size=(60, 2)))):
        env = make(task, seed=5)
        ts = env.reset()
        for a in actions:
            ts = env.step(a) if not ts.last() else env.reset()
            if ts.first():
                continue
            inside = env.physics.distance_to_target() <= env.task.spec.zone_radius
            assert (ts.last() and ts.discount == 0.0) == inside
            assert env.task.reached(env.physics) == inside


def test_the_frozen_test_counts_a_stop_task_success_only_when_stopped():
    """The test's ``success`` is the task's criterion: a hand inside the zone but still moving faster than
    stop_speed at the end is a failure on the stop task (issue 41: it was counted as a success), and a success on
    the paper's criterion; the occluded protocol's unreachable zone is not what it reads."""
    from apac_mj.run.evaluate import reached
    from apac_mj.suite.task_spec import load_task
    from apac_mj.suite.vec_env import VecEnv

    env = VecEnv(load_task(STOP), [0], "servo")  # the task file's plant says torque
    member = env.envs[0]
    member.task.set_target_override((12.0, 15.0))
    member.reset()
    member.step(np.array([0.01, 0.0]))  # inside the zone, moving
    d, zone, stop = float(env.distances()[0]), load_task(STOP).zone_radius, load_task(STOP).stop_speed
    assert d <= zone and not env.stopped(stop)[0]
    assert reached(env, 0, d, zone, stop) is False
    assert reached(env, 0, d, zone, None) is True  # the paper's criterion: inside the zone is enough
    ph = member.physics
    ph.data.qvel[ph.ids.qvel] = 0.0
    assert env.stopped(stop)[0] and reached(env, 0, d, zone, stop) is True
    assert reached(env, 0, zone + 0.1, zone, stop) is False
