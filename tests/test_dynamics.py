"""The arm's dynamics (``[plant]``): physical properties of the compliant and torque-driven plants, gravity,
the hand load and the curl field; the plant as task data; the agent's sizes from the task's specs."""
import dataclasses

import mujoco
import numpy as np
import pytest

from apac_mj import suite
from apac_mj.layout import Sizes
from apac_mj.suite import planar_arm
from apac_mj.suite.task_spec import PlantSpec, TaskSpecError, load_task, parse_task, task_names

GRAVITY = "changing_target_compliant_gravity"
LOAD = "changing_target_compliant_load_change"
CURL = "changing_target_compliant_curl_field"
TORQUE = "changing_target_torque"
G = 9.81


def make(task, seed=0, **overrides):
    env = suite.load("planar_arm", task, task_kwargs={"random": seed, **overrides})
    env.reset()
    return env


# -- the paper's tasks keep the paper's plant -------------------------------------------------------------------
def test_paper_tasks_keep_the_ideal_plant():
    """Every task without a [plant] table has the ideal plant, and its model is the MJCF's as compiled."""
    ideal = [n for n in task_names() if not load_task(n).plant.dynamic]
    assert len(ideal) == 15
    env = make("changing_target")
    m = env.physics.model
    assert env.physics.plant is None and env._n_sub_steps == planar_arm.N_SUB_STEPS
    assert np.all(m.dof_armature == 1.0) and np.all(m.actuator_gainprm[:, 0] == 1e4)
    assert np.all(m.actuator_biasprm[:, 2] == -200.0) and np.all(m.opt.gravity == 0.0)
    assert env.action_spec().maximum == 180.0 and "joint_velocities" not in env.observation_spec()


@pytest.mark.parametrize("plant, problem", [
    ({"actuation": "muscle"}, "plant.actuation must be one of"),
    ({"gravity": True}, "plant.gravity needs a plant with dynamics"),
    ({"actuation": "compliant", "stiffness": [15, -1]}, "plant.stiffness must be positive"),
    ({"actuation": "compliant", "control_interval": 0.1, "timestep": 0.003}, "whole number of plant.timestep"),
    ({"actuation": "compliant", "field_b": 10.0}, "field_on_episode is -1"),
    ({"actuation": "compliant", "field_b": 10.0, "field_on_episode": 5, "field_off_episode": 5}, "must come after"),
    ({"actuation": "compliant", "load": -1.0}, "plant.load must be a finite number >= 0"),
    ({"actuation": "compliant", "gravity": 1}, "plant.gravity must be true or false"),
    ({"actuation": "compliant", "mass": 1.0}, "unknown key plant.mass"),
])
def test_bad_plant_tables_name_the_key(plant, problem):
    with pytest.raises(TaskSpecError, match=problem) as e:
        parse_task({"plant": plant}, "t", source="tasks/t.toml")
    assert "tasks/t.toml" in str(e.value)


def test_kinematic_actuation_is_refused_for_a_plant_with_dynamics():
    with pytest.raises(ValueError, match="skip its dynamics: use 'servo'"):
        suite.load("planar_arm", GRAVITY, task_kwargs={"actuation": "kinematic"})


def test_tasks_show_prints_every_plant_value_with_its_unit(capsys):
    from apac_mj import cli

    assert cli.main(["tasks", "--show", CURL]) == 0
    out = capsys.readouterr().out
    for line in ("* plant.actuation = 'compliant'", "plant.stiffness = (15.0, 16.0)  [N·m/rad]",
                 "* plant.field_b = 100.0  [N·s/m]", "plant.control_interval = 0.1  [s]", "plant.link_masses"):
        assert line in out


# -- compliant actuation ---------------------------------------------------------------------------------------
def test_compliant_servo_falls_short_within_the_step_and_carries_velocity():
    """A 30 degree command is not reached within the 100 ms step; the arm keeps moving into the next one."""
    env = make(CURL)  # horizontal plane: no gravity
    p = env.physics
    before = p.joint_angles()
    env.step([30.0, -45.0])
    moved = p.joint_angles() - before
    assert 0.2 < moved[0] / 30.0 < 0.9 and 0.2 < moved[1] / -45.0 < 0.9
    assert abs(p.joint_velocities()[0]) > 10.0  # deg/s carried into the next step
    env.step([0.0, 0.0])  # "no change" from where the arm is: the carried velocity still moves it
    assert np.max(np.abs(p.joint_angles() - before - moved)) > 0.1


def _gravity_torque(q, lengths, masses, load):
    """-dV/dq (N·m) of two uniform rods and a point load at the hand, plane vertical, gravity along -y."""
    (l1, l2), (m1, m2) = np.asarray(lengths) / 100.0, masses
    c1, c12 = np.cos(q[0]), np.cos(q[0] + q[1])
    elbow_term = m2 * l2 / 2 * c12 + load * l2 * c12
    return -G * np.array([m1 * l1 / 2 * np.cos(q[0]) + (m2 + load) * l1 * np.cos(q[0]) + elbow_term, elbow_term])


def _settle(env, load, command=(30.0, 60.0)):
    p = env.physics
    p.set_load(load)
    p.set_joint_angles(*command)
    p.step(2000)  # 4 s: the servos' slowest time constant is damping / stiffness ~ 0.15 s
    assert np.max(np.abs(p.joint_velocities())) < 1e-6
    return p.joint_angles(), p.end_effector()


def test_gravity_droop_grows_with_the_load_and_points_down():
    """At rest under gravity the servo torque K (q_cmd - q) balances the rods' and the load's gravity torque
    (computed here from first principles); the droop has gravity's sign and grows with the load."""
    env = make(GRAVITY)
    plant, p = env.task.spec.plant, env.physics
    command = np.array([30.0, 60.0])
    commanded_hand, _ = planar_arm.motion_function(*command, *p.link_lengths(), p.origin())
    drops = []
    for load in (0.0, 0.5, 1.0):
        angles, hand = _settle(env, load, command)
        q = np.deg2rad(angles)
        servo = np.asarray(plant.stiffness) * (np.deg2rad(command) - q)
        tau_g = _gravity_torque(q, p.link_lengths(), plant.link_masses, load)
        np.testing.assert_allclose(servo + tau_g, 0.0, atol=1e-9 * np.max(np.abs(tau_g)))
        assert angles[0] < command[0]  # the shoulder sags
        drops.append(commanded_hand[1] - hand[1])
    assert 0 < drops[0] < drops[1] < drops[2]  # the hand is below the command, more so with more load
    flat = make(CURL)  # horizontal plane: no droop whatever the load
    angles, _ = _settle(flat, 1.0, command)
    np.testing.assert_allclose(angles, command, atol=1e-9)


def test_load_change_happens_at_its_episode():
    env = make(LOAD, plant=dataclasses.replace(load_task(LOAD).plant, load_change_episode=2))
    masses = []
    for _ in range(4):
        masses.append(env.physics.model.body_mass[env.physics.ids.fore_body])
        env.reset()
    np.testing.assert_allclose(masses, [1.52, 1.52, 2.52, 2.52])
    assert env.physics.load == 1.0


# -- the curl field --------------------------------------------------------------------------------------------
def test_curl_force_is_perpendicular_to_the_hand_velocity_with_magnitude_b_v():
    env = make(CURL)
    p, b = env.physics, env.task.spec.plant.field_b
    p.set_field(b)
    env.task.before_step(np.array([40.0, -60.0]), p)
    checked = 0
    for _ in range(50):
        p.step(1)
        v = p.hand_velocity() / 100.0  # m/s
        force = p.field_force()  # N
        if np.linalg.norm(v) < 1e-3:
            continue
        checked += 1
        assert abs(force @ v) <= 1e-12 * np.linalg.norm(force) * np.linalg.norm(v)
        np.testing.assert_allclose(np.linalg.norm(force), b * np.linalg.norm(v), rtol=1e-12)
        assert v[0] * force[1] - v[1] * force[0] < 0  # b > 0: clockwise from the velocity
    assert checked > 30


def test_the_field_acts_at_the_hand():
    """The force and torque applied at the forearm's centre of mass are, in joint space, J_hand^T F: the force
    acts at the hand."""
    env = make(CURL)
    p = env.physics
    p.set_field(40.0)
    env.task.before_step(np.array([40.0, -60.0]), p)
    p.step(10)
    m, d = p.model.ptr, p.data.ptr
    p._apply_field()
    applied = np.zeros(m.nv)
    mujoco.mj_applyFT(m, d, d.xfrc_applied[p.ids.fore_body, :3].copy(), d.xfrc_applied[p.ids.fore_body, 3:].copy(),
                      d.xipos[p.ids.fore_body].copy(), p.ids.fore_body, applied)
    jac = np.zeros((3, m.nv))
    mujoco.mj_jacSite(m, d, jac, None, p.ids.end_site)
    force = np.append(p.field_force() * planar_arm.FORCE_UNIT, 0.0)
    np.testing.assert_allclose(applied, jac.T @ force, rtol=1e-10, atol=1e-9)
    assert np.linalg.norm(force) > 1.0


def test_the_field_switches_on_and_off_at_its_episodes():
    plant = dataclasses.replace(load_task(CURL).plant, field_on_episode=1, field_off_episode=3)
    env = make(CURL, plant=plant)
    fields = []
    for _ in range(4):
        fields.append(env.physics.field_b)
        env.step([20.0, 20.0])
        fields[-1] = (fields[-1], bool(np.any(env.physics.data.xfrc_applied != 0)))
        env.reset()
    assert fields == [(0.0, False), (100.0, True), (100.0, True), (0.0, False)]


# -- energy and determinism ------------------------------------------------------------------------------------
def _swing(integrator, timestep=0.002, seconds=1.0):
    plant = dataclasses.replace(load_task(TORQUE).plant, joint_damping=(0.0, 0.0), gravity=True, load=0.5,
                                timestep=timestep, control_interval=timestep)
    env = make(TORQUE, plant=plant, at_limit="unbounded")
    p = env.physics
    p.model.opt.integrator = integrator
    p.set_joint_angles(30.0, 60.0)  # at rest, no torque: a free double pendulum under gravity
    energy = []
    for _ in range(int(round(seconds / timestep))):
        p.step(1)
        energy.append(sum(p.energy()))
    kinetic = p.energy()[1]
    return np.asarray(energy), kinetic


def test_energy_is_conserved_without_actuation_and_damping():
    """A free, undamped swing under gravity (torque plant, zero torque, 0.5 kg in the hand): with RK4 the total
    energy holds to 1e-6 of the energy the swing exchanges, and its drift falls as dt^4 (> 8x per halving);
    the plant's own implicitfast is first order (drift falls ~dt: measured 1.6 J at 2 ms, 0.31 J at 0.5 ms,
    of 4.2 J exchanged; docs/environment.md)."""
    exchanged = _potential_range()
    rk4 = mujoco.mjtIntegrator.mjINT_RK4
    half, quarter = np.ptp(_swing(rk4, 0.001)[0]), np.ptp(_swing(rk4, 0.0005)[0])
    assert quarter < 1e-6 * exchanged and half / quarter > 8
    fast = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    assert np.ptp(_swing(fast, 0.0005)[0]) < np.ptp(_swing(fast, 0.002)[0]) / 3


def _potential_range():
    """How much potential energy the swing exchanges (J): the test's scale."""
    plant = dataclasses.replace(load_task(TORQUE).plant, joint_damping=(0.0, 0.0), gravity=True, load=0.5)
    env = make(TORQUE, plant=plant, at_limit="unbounded")
    p = env.physics
    p.model.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    p.set_joint_angles(30.0, 60.0)
    pot = []
    for _ in range(500):
        p.step(1)
        pot.append(p.energy()[0])
    return float(np.ptp(pot))


def _trajectory(task, seed, plant=None, steps=70):
    env = make(task, seed, **({} if plant is None else {"plant": plant}))
    rng = np.random.default_rng(seed)
    bound = planar_arm.action_bound(env.task.spec)
    out = []
    for _ in range(steps):
        ts = env.step(rng.uniform(-bound, bound, 2) / 4)
        out.append(np.concatenate([env.physics.data.qpos, env.physics.data.qvel, env.physics.target()]))
        if ts.last():
            env.reset()
    return np.array(out)


@pytest.mark.parametrize("task", [LOAD, CURL, TORQUE])
def test_same_seed_same_trajectory(task):
    plant = load_task(task).plant
    plant = dataclasses.replace(plant, **({"field_on_episode": 1, "field_off_episode": -1} if plant.field_b
                                          else {"load_change_episode": 1} if plant.load_change_episode >= 0 else {}))
    a, b = _trajectory(task, 3, plant), _trajectory(task, 3, plant)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, _trajectory(task, 4, plant))


def test_resume_restores_the_plant_of_the_episode():
    """VecEnv.get_state/set_state in a fresh process-like VecEnv: the load of the episode is back."""
    from apac_mj.suite.vec_env import VecEnv

    plant = dataclasses.replace(load_task(LOAD).plant, load_change_episode=1)
    env = VecEnv(LOAD, [0], overrides={"plant": plant})
    env.reset()
    for _ in range(35):  # into the second episode: the load is on
        if env.obs.last[0]:
            env.reset()
        env.step(np.array([[5.0, -5.0]]))
    state = env.get_state()
    after = [env.step(np.array([[3.0, 2.0]])).arm.copy() for _ in range(5)]
    again = VecEnv(LOAD, [0], overrides={"plant": plant})
    again.set_state(state)
    assert again.physics(0).load == 1.0
    assert all(np.array_equal(x, again.step(np.array([[3.0, 2.0]])).arm) for x in after)


# -- torque actuation and the agent's sizes --------------------------------------------------------------------
def test_torque_actuation_observes_velocities_and_is_bounded():
    env = make(TORQUE)
    spec = env.action_spec()
    assert spec.name == "joint_torque_Nm" and spec.maximum == 0.5 and spec.minimum == -0.5
    assert list(env.observation_spec())[-1] == "joint_velocities"
    p = env.physics
    env.step([10.0, 0.0])  # clipped to the bound
    np.testing.assert_array_equal(p.data.ctrl, [0.5, 0.0])
    ts = env.step([0.0, 0.0])
    np.testing.assert_allclose(ts.observation["joint_velocities"], p.joint_velocities())
    assert abs(ts.observation["joint_velocities"][0]) > 1.0


def test_sizes_come_from_the_specs():
    def sizes(task):
        env = make(task)
        return Sizes.from_specs(env.observation_spec(), env.action_spec())

    assert sizes("changing_target") == Sizes() == Sizes(6, 2, 180.0, True)
    assert sizes(CURL) == Sizes()
    assert sizes(TORQUE) == Sizes(8, 2, 0.5, False, (500.0, 500.0))  # the velocities read by their scale (deg/s)


def test_the_paper_agent_trains_on_the_torque_arm(tmp_path):
    """No agent edit: the sizes come from the task; the actions stay within the torque bound."""
    import pandas as pd
    import torch

    from apac_mj.config import AgentConfig, TrainConfig
    from apac_mj.run.trainer import train

    small = dict(actor_hidden=(16, 16), critic_hidden=(16, 16), forward_hidden=(16, 16), inverse_hidden=(16, 16),
                 batch_size=8, babbling_episodes=1, planning_episodes=1)
    cfg = TrainConfig(task=TORQUE, seeds=(0,), episodes=2, agent=AgentConfig(kind="apac", **small),
                      task_overrides={"steps_per_episode": 6})
    seen = []
    run = train(cfg, tmp_path / "run", on_step=lambda info, env: seen.append((info.action, info.state)),
                progress=False)
    rows = pd.read_parquet(run / "metrics.parquet")
    assert len(rows) == 3 and np.isfinite(rows.critic_loss.iloc[-1])
    assert all(np.all(np.abs(a) <= 0.5) for a, _ in seen) and all(s.shape == (1, 8) for _, s in seen)
    ckpt = torch.load(run / "checkpoints" / "latest.pt", weights_only=True)
    assert ckpt["agent"]["networks"]["actor"]["layers.0.weight"].shape == (1, 8, 16)


def test_the_plant_schedule_counts_training_episodes():
    """As changing kinematics: a run's environment counts its babbling resets, so the schedule moves by them."""
    from apac_mj.config import AgentConfig, TrainConfig
    from apac_mj.run.build import check, environments

    def training_env(cfg: TrainConfig):
        return environments(cfg, check(cfg))

    env = training_env(TrainConfig(task=CURL, seeds=(0,), agent=AgentConfig(babbling_episodes=10)))
    plant = env.spec.plant
    assert (plant.field_on_episode, plant.field_off_episode) == (120, 140) and plant.field_b == 100.0
    env.reset()
    assert env.episode(0) == -10  # the first of the 10 babbling episodes, before training episode 0
    assert training_env(TrainConfig(task=LOAD, seeds=(0,))).spec.plant.load_change_episode == 120


def test_record_an_agent_on_the_torque_arm(tmp_path):
    """apac-mj record rolls the (untrained) paper agent out on a task with an 8-D state and logs the plant."""
    from apac_mj import cli
    from apac_mj.recording import recording as R

    path = tmp_path / "torque.rrd"
    assert cli.main(["record", "--task", TORQUE, "--episodes", "1", "--out", str(path)]) == 0
    entities, _, _ = R.read_recording(path)
    assert f"{R.JOINT_VELOCITY}/shoulder" in entities and R.LOAD in entities
    assert R.ARM_COMMANDED not in entities  # torques command no angles


@pytest.mark.parametrize("task", [GRAVITY, LOAD, CURL, TORQUE])
def test_kinematics_hold_while_moving_under_load_and_field(task):
    """MuJoCo's sites equal the motion function at the actual angles after every sub-step, with the task's
    heaviest load and its field on, on random link lengths, while the arm moves."""
    from apac_mj.suite.kinematics_check import check_kinematics

    report = check_kinematics(samples=20, seed=2, task=task)
    assert report.passed and max(report.worst_end_effector, report.worst_elbow) < 1e-12
    assert report.max_joint_speed > 100.0 and report.task == task


def test_a_kinematic_run_of_a_task_with_dynamics_is_refused_before_anything_is_written(tmp_path):
    from apac_mj.config import TrainConfig
    from apac_mj.run.trainer import train

    with pytest.raises(ValueError, match="use 'servo'"):
        train(TrainConfig(task=CURL, seeds=(0,), episodes=1, actuation="kinematic"), tmp_path / "run",
              progress=False)
    assert not (tmp_path / "run").exists()


def test_plant_overrides_are_checked_like_the_file():
    spec = suite.load_spec(CURL, plant={"actuation": "compliant", "gravity": True})
    assert spec.plant.gravity and spec.plant.field_b == 100.0  # merged into the task's [plant]: the field stays
    with pytest.raises(TaskSpecError, match="plant.gravity must be true or false"):
        suite.load_spec(CURL, plant={"actuation": "compliant", "gravity": "yes"})
    with pytest.raises(TaskSpecError, match="must be a PlantSpec or a table"):
        suite.load_spec(CURL, plant="compliant")


def test_one_plant_key_overrides_merge_into_the_tasks_plant():
    """Issue 29 item 5: overriding one key of a dynamics task's [plant] keeps the rest of its table (it used to
    replace the table and fail with "needs a plant with dynamics")."""
    from apac_mj.config import TrainConfig
    from apac_mj.run.build import check

    spec = suite.load_spec(CURL, plant={"field_on_episode": 10})
    task = load_task(CURL).plant
    assert spec.plant == dataclasses.replace(task, field_on_episode=10)
    cfg = TrainConfig(task=CURL, task_overrides={"plant": {"field_on_episode": 10, "field_off_episode": 20}})
    assert check(cfg).plant == dataclasses.replace(task, field_on_episode=10, field_off_episode=20)
    whole = PlantSpec(actuation="compliant")  # a PlantSpec is the whole plant
    assert suite.load_spec(CURL, plant=whole).plant == whole
    with pytest.raises(TaskSpecError, match="field_off_episode"):
        suite.load_spec(CURL, plant={"field_off_episode": 5})  # before the task's field_on_episode (110)
