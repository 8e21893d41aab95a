"""bench/ceiling.py: its model steps the true plant (a rollout from the saved state is ``env.step`` to the bit, with
the curl field on too, and planning leaves the environment as it was), the MPC through it reaches the torque
arm's targets while the zero action reaches none, and the CLI's checks."""
from __future__ import annotations

import csv

import numpy as np
import pytest
from conftest import bench_module

from apac_mj.kinematics import motion_function



@pytest.fixture(scope="module")
def ceil():
    return bench_module("ceiling")


def _state(env) -> tuple[np.ndarray, ...]:
    ph = env.physics
    return ph.end_effector(), ph.joint_angles(), ph.joint_velocities()


@pytest.mark.parametrize("condition", ["torque", "curl_field", "gravity_1kg"])
def test_model_step_is_env_step(ceil, condition):
    """From the saved state (after an unrelated rollout has run on the physics), one model step of an action
    gives bit for bit the hand, angles and velocities that ``env.step`` of that action gives, step after step."""
    env = ceil.make_env(condition, 0)
    env.reset()
    model = ceil.Model(env)
    rng = np.random.default_rng(1)
    for _ in range(4):
        u = rng.uniform(model.low, model.high)
        model.save()
        model.cost(rng.uniform(model.low, model.high, size=(3, 2)))  # disturb the physics
        model.restore()
        model.step(u)
        predicted = _state(env)
        model.restore()
        env.step(model.action(u))
        for p, t in zip(predicted, _state(env)):
            np.testing.assert_array_equal(p, t)


def test_conditions_have_their_plant(ceil):
    """The curl field is on at the task's b (and moves the hand), the load is 1 kg, the half torque bound 0.25."""
    ends = []
    for b in (None, 0.0):
        env = ceil.make_env("curl_field", 0)
        env.reset()
        if b is None:
            assert env.physics.field_b == env.task.spec.plant.field_b == 100.0
        else:
            env.physics.set_field(b)
        env.step(np.array([60.0, -60.0]))
        ends.append(env.physics.end_effector())
    assert np.linalg.norm(ends[0] - ends[1]) > 0.1
    load = ceil.make_env("gravity_1kg", 0)
    load.reset()
    assert load.physics.load == 1.0
    half = ceil.make_env("torque_half", 0)
    assert float(half.action_spec().maximum) == 0.25


def test_planning_leaves_the_environment_alone(ceil):
    """An episode with the MPC planning between steps follows, bit for bit, a twin environment that only
    replays the executed actions."""
    env, twin = ceil.make_env("curl_field", 3), ceil.make_env("curl_field", 3)
    mpc = ceil.MPC(samples=8, horizon=2, iterations=1)
    env.reset()
    twin.reset()
    mpc.reset(ceil.Model(env), np.random.default_rng(0))
    for _ in range(3):
        a = mpc.act()
        env.step(a)
        twin.step(a)
        for p, t in zip(_state(env), _state(twin)):
            np.testing.assert_array_equal(p, t)


def test_inverse_kinematics(ceil):
    rng = np.random.default_rng(0)
    for alpha, beta in rng.uniform(1.0, 179.0, size=(20, 2)):
        end, _ = motion_function(alpha, beta, 5.0, 8.0, (15.0, 15.0))
        np.testing.assert_allclose(ceil.inverse_kinematics(end, 5.0, 8.0, (15.0, 15.0)), [alpha, beta], atol=1e-9)


def test_mpc_reaches_torque_targets_zero_does_not(ceil):
    """The MPC through the true model reaches >= 4 of 5 targets of the torque arm in the step limit; the zero
    action (no torque: the arm stays at rest) reaches none."""
    mpc = ceil.run_row("torque", "mpc", episodes=5, samples=48, horizon=3, iterations=2, seed=0)
    zero = ceil.run_row("torque", "zero", episodes=5, seed=0)
    assert mpc["successes"] >= 4, mpc
    assert mpc["mean_steps"] <= 10, mpc
    assert zero["successes"] == 0, zero
    assert zero["final_distance_cm"] > 1.0


def test_same_seed_same_numbers(ceil):
    rows = [ceil.run_row("gravity", "mpc", episodes=2, samples=8, horizon=2, iterations=1, seed=5)
            for _ in range(2)]
    for r in rows:
        r.pop("seconds")
    assert rows[0] == rows[1]


def test_cli_errors(ceil, capsys):
    with pytest.raises(SystemExit):
        ceil.parse_args(["--tasks", "nope"])
    assert "unknown task 'nope'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        ceil.parse_args(["--controllers", "mpc", "lqr"])
    assert "unknown controller 'lqr'" in capsys.readouterr().err
    with pytest.raises(ValueError, match="unknown controller"):
        ceil.make_controller("lqr", 8, 2, 1)


def test_main_writes_csv(ceil, tmp_path):
    """Rows only where the controller applies (pd: torque; target_angles: compliant), written as CSV."""
    out = tmp_path / "sub" / "ceiling.csv"
    ceil.main(["--tasks", "torque", "gravity", "--controllers", "pd", "target_angles", "--episodes", "2",
               "--no-progress", "--out", str(out)])
    rows = list(csv.DictReader(out.open()))
    assert [(r["condition"], r["controller"]) for r in rows] == [("torque", "pd"), ("gravity", "target_angles")]
    assert all(r["episodes"] == "2" for r in rows)


def test_stop_task_rollouts_end_only_when_stopped(ceil):
    """On the stop task a model rollout ends where the episode would: a step that leaves the hand inside the zone
    but faster than stop_speed does not end it (the next step's distance counts too), one at rest does; on the
    torque task (no stop criterion) the same fast step ends it."""
    costs = {}
    for condition in ("torque_stop", "torque"):
        env = ceil.make_env(condition, 0)
        env.task.set_target_override((12.0, 15.0))  # the start pose's hand
        env.reset()
        model = ceil.Model(env)
        model.save()
        fast, rest = np.array([[0.03, 0.0], [0.0, 0.0]]), np.zeros((2, 2))
        model.restore()
        d1 = model.step(fast[0])
        assert d1 <= model.zone and np.abs(env.physics.joint_velocities()).max() > 10.0
        assert model.reached(d1) is (condition == "torque")
        d2 = model.step(fast[1])
        costs[condition] = model.cost(fast), d1, d2
        model.restore()
        r1 = model.step(rest[0])
        assert model.reached(r1) and model.cost(rest) == r1
    cost, d1, d2 = costs["torque_stop"]
    assert cost == d1 + d2
    cost, d1, _ = costs["torque"]
    assert cost == d1


def test_mpc_stops_in_the_zone(ceil):
    """The MPC honours the stop criterion: on grid targets of the stop task it ends episodes at rest in the
    zone (the environment judges success: inside and both joints <= stop_speed)."""
    row = ceil.run_row("torque_stop", "mpc", episodes=3, samples=48, horizon=3, iterations=2, seed=0,
                       targets="grid")
    assert row["task"] == "changing_target_torque_stop"
    assert row["successes"] >= 2, row
