"""The planar_arm dm_control suite: servos, observations, reward, conditions, errors."""
import numpy as np
import pytest
from absl.testing import absltest
from dm_env import test_utils

from apac_mj import suite
from apac_mj.kinematics import motion_function
from apac_mj.suite import planar_arm
from apac_mj.suite.regions import region_stats

TASKS = [task for _, task in suite.ALL_TASKS]


def make(task="changing_target", seed=0, **task_kwargs):
    return suite.load("planar_arm", task, task_kwargs={"random": seed, **task_kwargs})


# -- dm_env conformance, one test class per task ---------------------------------
def _conformance_class(task: str) -> type:
    def make_object_under_test(self):
        return make(task)

    return type(f"TestDmEnv_{task}", (test_utils.EnvironmentTestMixin, absltest.TestCase),
                {"make_object_under_test": make_object_under_test})


for _task in TASKS:
    globals()[f"TestDmEnv_{_task}"] = _conformance_class(_task)


def test_all_tasks_listed():
    """Every file in tasks/ is a task; the paper's conditions are there with their occluded and train-region
    variants (the grid's suffix convention). Properties, not a count: adding a task file keeps this green."""
    from apac_mj.experiments.presets import CONDITIONS
    from apac_mj.suite.task_spec import task_names

    assert sorted(TASKS) == task_names() and len(set(TASKS)) == len(TASKS)
    assert {c + suffix for c in CONDITIONS for suffix in ("", "_occluded", "_train_region")} <= set(TASKS)
    assert {"static_target", "changing_target_changing_kinematics_occluded"} <= set(TASKS)


@pytest.mark.parametrize("task", TASKS)
def test_task_files_state_only_what_differs_from_the_defaults(task):
    """Each key a task file sets (but its description) changes a TaskSpec default; the name tells which."""
    import dataclasses
    import tomllib

    from apac_mj.util import paths
    from apac_mj.suite.task_spec import TaskSpec, load_task

    spec, default = load_task(task), TaskSpec(name=task)
    data = tomllib.loads((paths.tasks_dir() / f"{task}.toml").read_text())
    whole = {"cues", "signals", "deliberation", "trials"}  # tables that are one field each (TaskSpec.cues, ...)
    stated = {f"{sec}.{k}" for sec, table in data.items() if isinstance(table, dict) and sec not in whole for k in table}
    stated |= whole & set(data)  # such a table's keys are one field's
    changed = [f.name for f in dataclasses.fields(spec) if f.name not in ("name", "description", "plant")
               and getattr(spec, f.name) != getattr(default, f.name)]
    changed += [f"plant.{f.name}" for f in dataclasses.fields(spec.plant)  # [plant]: one key per field
                if getattr(spec.plant, f.name) != getattr(default.plant, f.name)]
    assert len(stated) == len(changed), f"{task}.toml restates a default: {sorted(stated)} vs changed {changed}"
    assert spec.description
    assert (spec.target_mode == "static") == task.startswith("static_target")
    assert (spec.kinematics_mode == "changing") == ("changing_kinematics" in task)
    assert spec.occluded == task.endswith("_occluded")
    assert (spec.vision == "noisy") == task.endswith("_noisy")
    assert (spec.vision == "intermittent") == task.endswith("_intermittent")
    assert (spec.target_region == "train") == task.endswith("_train_region")


@pytest.mark.parametrize("task", TASKS)
def test_same_seed_same_numbers(task):
    """Same seed => identical observations and rewards over two full episodes; all finite."""
    actions = np.random.default_rng(1).uniform(-40.0, 40.0, size=(70, 2))
    runs = []
    for _ in range(2):
        env = make(task, seed=7)
        ts, trace = env.reset(), []
        for a in actions:
            trace.append((np.concatenate(list(ts.observation.values())), ts.reward))
            ts = env.step(a) if not ts.last() else env.reset()
        runs.append(trace)
    for (obs_a, r_a), (obs_b, r_b) in zip(*runs):
        assert np.all(np.isfinite(obs_a))
        np.testing.assert_array_equal(obs_a, obs_b)
        assert r_a == r_b


def test_specs_describe_observations_and_actions():
    env = make()
    obs_spec = env.observation_spec()
    assert list(obs_spec) == ["end_effector", "elbow", "target", "vision"]
    assert [s.shape for s in obs_spec.values()] == [(2,), (2,), (2,), (1,)]
    spec = env.action_spec()
    assert spec.shape == (2,)
    np.testing.assert_array_equal(spec.minimum, -180.0)
    np.testing.assert_array_equal(spec.maximum, 180.0)
    ts = env.reset()
    for name, value in ts.observation.items():
        obs_spec[name].validate(value)


# -- servos and kinematic actuation --------------------------------------------------
@pytest.mark.parametrize("lengths", [(5.0, 8.0), (2.0, 3.0), (9.0, 14.0)])
@pytest.mark.parametrize("start, action", [((0.0, 0.0), (180.0, 180.0)), ((180.0, 180.0), (-180.0, -180.0)),
                                           ((0.0, 180.0), (180.0, -180.0))])
def test_servo_settles_a_full_move_in_one_step(lengths, start, action):
    env = make(link_lengths=lengths)
    env.reset()
    env.physics.set_joint_angles(*start)
    env.step(np.array(action))
    target = np.clip(np.add(start, action), 0.0, 180.0)
    assert np.max(np.abs(env.physics.joint_angles() - target)) < 0.01
    assert np.max(np.abs(env.physics.data.qvel)) < 1e-3


def test_action_is_a_change_clipped_to_the_joint_range():
    env = make(actuation="kinematic")
    env.reset()  # start pose (0, 180)
    env.step(np.array([30.0, 40.0]))  # elbow clipped at 180
    np.testing.assert_allclose(env.physics.joint_angles(), [30.0, 180.0], atol=1e-12)
    env.step(np.array([-50.0, -100.0]))  # shoulder clipped at 0
    np.testing.assert_allclose(env.physics.joint_angles(), [0.0, 80.0], atol=1e-12)


def test_kinematic_actuation_writes_angles_exactly():
    env = make(actuation="kinematic")
    env.reset()
    angles = np.array([0.0, 180.0])
    for action in np.random.default_rng(0).uniform(-60.0, 60.0, size=(25, 2)):
        angles = np.clip(angles + action, 0.0, 180.0)
        env.step(action)
        np.testing.assert_allclose(env.physics.joint_angles(), angles, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(env.physics.data.qvel, 0.0)


def test_unknown_actuation_is_rejected():
    with pytest.raises(ValueError, match="actuation"):
        make(actuation="teleport")


@pytest.mark.parametrize("task, words", [("changing_target", "(shoulder, elbow change in degrees)"),
                                         ("changing_target_torque", "(shoulder, elbow torque in N·m)")])
def test_wrong_action_shape_names_the_tasks_units(task, words):
    """An action of the wrong shape is refused in the task's own units: the torque task's are N·m torques,
    not the joint-angle changes in degrees it was once said to take."""
    env = make(task)
    env.reset()
    with pytest.raises(ValueError) as e:
        env.step(np.zeros(3))
    assert str(e.value) == f"action must have shape (2,) {words}, got shape (3,)"


# -- observation, reward, termination ----------------------------------------------
def test_start_pose_and_perfect_vision():
    env = make()
    ts = env.reset()
    np.testing.assert_allclose(env.physics.joint_angles(), planar_arm.START_ANGLES)
    end, elbow = motion_function(0.0, 180.0, 5.0, 8.0)
    np.testing.assert_allclose(ts.observation["end_effector"], end, atol=1e-9)
    np.testing.assert_allclose(ts.observation["elbow"], elbow, atol=1e-9)
    ts = env.step(np.array([20.0, -20.0]))
    np.testing.assert_array_equal(ts.observation["end_effector"], env.physics.end_effector())
    np.testing.assert_array_equal(ts.observation["target"], env.physics.target())
    assert ts.observation["vision"][0] == 1.0


@pytest.mark.parametrize("task", [t for t in TASKS if t.endswith("occluded")])
def test_occluded_vision_withholds_positions_after_first_step(task):
    env = make(task)
    ts = env.reset()
    assert ts.observation["vision"][0] == 1.0
    np.testing.assert_array_equal(ts.observation["target"], env.physics.target())
    for action in np.random.default_rng(0).uniform(-30.0, 30.0, size=(5, 2)):
        ts = env.step(action)
        truth = {"end_effector": env.physics.end_effector(), "elbow": env.physics.elbow(),
                 "target": env.physics.target()}
        assert ts.observation["vision"][0] == 0.0
        for name, value in truth.items():
            assert not np.any(np.isclose(ts.observation[name], value)), name
        if ts.last():
            break


# -- noisy and intermittent vision ------------------------------------------------------
def _truth(env) -> dict[str, np.ndarray]:
    p = env.physics
    return {"end_effector": p.end_effector(), "elbow": p.elbow(), "target": p.target()}


def _play(env, n: int, seed: int = 3):
    """``n`` observations (the reset ones included) with the truth beside each: [(obs, truth, first)]."""
    actions = np.random.default_rng(seed).uniform(-40.0, 40.0, size=(n, 2))
    ts, out = env.reset(), []
    for a in actions:
        out.append((ts.observation, _truth(env), ts.first()))
        ts = env.reset() if ts.last() else env.step(a)
    return out


def test_noisy_vision_adds_independent_gaussian_noise_of_the_tasks_std():
    """Observed minus true positions over 2000 observations (12000 coordinates): mean ~0, std = 0.5 within
    10%, coordinates uncorrelated; the reset observations are noisy too; vision always reads 1."""
    env = make("changing_target_noisy", actuation="kinematic")
    std = env.task.spec.observation_noise_std
    assert std == 0.5
    trace = _play(env, 2000)
    errors = np.array([np.concatenate([o[k] - t[k] for k in t]) for o, t, _ in trace])  # [2000, 6]
    assert all(o["vision"][0] == 1.0 for o, _, _ in trace)
    assert abs(errors.mean()) < 0.03 and np.all(np.abs(errors.mean(axis=0)) < 0.06)
    assert abs(errors.std() / std - 1.0) < 0.1 and np.all(np.abs(errors.std(axis=0) / std - 1.0) < 0.1)
    corr = np.corrcoef(errors.T) - np.eye(6)
    assert np.max(np.abs(corr)) < 0.1
    first = np.array([e for e, (_, _, f) in zip(errors, trace) if f])
    assert len(first) > 30 and abs(first.std() / std - 1.0) < 0.25


def test_noisy_observation_is_drawn_once_per_step():
    """Reading the observation again within a step gives the same numbers (no redraw)."""
    env = make("changing_target_noisy")
    for i in range(4):
        obs = env.reset().observation if i == 0 else env.step(np.array([10.0, -5.0])).observation
        again = env.task.get_observation(env.physics)
        for k in ("end_effector", "elbow", "target"):
            np.testing.assert_array_equal(again[k], obs[k])
            assert not np.array_equal(obs[k], _truth(env)[k])


def test_noisy_vision_depends_on_the_seed():
    a, b = (make("changing_target_noisy", seed=s).reset().observation["end_effector"] for s in (0, 1))
    assert not np.array_equal(a, b)


def test_noisy_vision_keeps_the_true_reward_and_termination():
    env = make("changing_target_noisy", vision_noise_std=3.0)
    target, _ = motion_function(90.0, 90.0, 5.0, 8.0)
    env.task.set_target_override(target)
    env.reset()
    for action in np.random.default_rng(2).uniform(-30.0, 30.0, size=(5, 2)):
        ts = env.step(action)
        assert ts.reward == pytest.approx(-np.linalg.norm(env.physics.end_effector() - env.physics.target()))
        assert abs(ts.reward) > 0.5 and not ts.last()
    env.reset()
    ts = env.step(np.array([90.0, -90.0]))  # (0, 180) -> (90, 90): on the target whatever is observed
    assert ts.last() and ts.discount == 0.0 and -ts.reward <= 0.5
    assert np.linalg.norm(ts.observation["end_effector"] - target) > 0.5  # the std-3 noise moved it off


def test_intermittent_vision_sees_step_zero_then_with_the_tasks_probability():
    """Every reset observation is seen; later steps are seen at rate p (3000 steps: within 0.04 of 0.5);
    a seen step reads the exact truth (no noise), an unseen one zeros and vision 0."""
    env = make("changing_target_intermittent", actuation="kinematic")
    p = env.task.spec.vision_seen_probability
    assert p == 0.5
    trace = _play(env, 3000)
    firsts = [o for o, _, f in trace if f]
    later = [(o, t) for o, t, f in trace if not f]
    assert len(firsts) >= 100 and all(o["vision"][0] == 1.0 for o in firsts)
    seen = np.array([o["vision"][0] == 1.0 for o, _ in later])
    assert abs(seen.mean() - p) < 0.04
    for o, t in later:
        for k in t:
            np.testing.assert_array_equal(o[k], t[k] if o["vision"][0] == 1.0 else np.zeros(2))
    runs = np.flatnonzero(np.diff(seen.astype(int)))  # both seen and unseen stretches, not a fixed pattern
    assert len(runs) > 500


def test_intermittent_vision_with_noise_is_noisy_when_seen_and_zero_when_not():
    env = make("changing_target_intermittent", vision_noise_std=0.5, actuation="kinematic")
    trace = _play(env, 400)
    seen = [(o, t) for o, t, _ in trace if o["vision"][0] == 1.0]
    unseen = [o for o, _, _ in trace if o["vision"][0] == 0.0]
    errors = np.array([np.concatenate([o[k] - t[k] for k in t]) for o, t in seen])
    assert len(unseen) > 100 and all(not np.any(np.concatenate([o[k] for k in _truth(env)])) for o in unseen)
    assert abs(errors.std() / 0.5 - 1.0) < 0.15


@pytest.mark.parametrize("task", ["changing_target", "changing_target_occluded", "static_target"])
def test_perfect_and_occluded_vision_draw_nothing_per_step(task):
    """Only the target draw uses the task's RandomState: stepping, and resetting onto a fixed target,
    leave it untouched (so these conditions' target sequences are those of the code before noisy vision)."""
    env = make(task)
    env.reset()

    def random_state():
        kind, keys, pos, has_gauss, gauss = env.task.random.get_state()
        return kind, keys.copy(), pos, has_gauss, gauss

    before = random_state()
    for action in np.random.default_rng(0).uniform(-30.0, 30.0, size=(10, 2)):
        if env.step(action).last():
            break
    env.task.set_target_override((20.0, 21.0))
    env.reset()
    after = random_state()
    assert before[0] == after[0] and before[2:] == after[2:]
    np.testing.assert_array_equal(before[1], after[1])


def test_noisy_vision_draws_every_step():
    """The counterpart of the test above: it would fail if the draw check could not see draws."""
    env = make("changing_target_noisy")
    env.reset()
    pos = env.task.random.get_state()[2]
    env.step(np.zeros(2))
    assert env.task.random.get_state()[2] != pos


@pytest.mark.parametrize("task", ["changing_target_noisy", "changing_target_intermittent"])
def test_resume_mid_episode_reproduces_the_corrupted_observations(task):
    """Reach.get_state/set_state (with the physics state) mid-episode: the same observation now and
    the same noisy / dropped observations afterwards, as an uninterrupted environment."""
    actions = np.random.default_rng(4).uniform(-30.0, 30.0, size=(12, 2))
    env = make(task, seed=5, vision_noise_std=0.5, actuation="kinematic")
    env.task.set_target_override((20.0, 21.0))  # no episode ends early
    env.reset()
    for a in actions[:4]:
        env.step(a)
    task_state, physics_state = env.task.get_state(), env.physics.get_state().copy()
    steps, at_checkpoint = env.task.step_count, env.task.get_observation(env.physics)
    expected = [np.concatenate(list(env.step(a).observation.values())) for a in actions[4:]]
    other = make(task, seed=11, vision_noise_std=0.5, actuation="kinematic")
    other.task.set_target_override((20.0, 21.0))
    other.reset()
    other.task.set_state(task_state)
    other.task.step_count = steps
    other.physics.set_state(physics_state)
    other.physics.forward()
    restored = other.task.get_observation(other.physics)
    for k, v in at_checkpoint.items():
        np.testing.assert_array_equal(restored[k], v)
    got = [np.concatenate(list(other.step(a).observation.values())) for a in actions[4:]]
    np.testing.assert_array_equal(np.array(got), np.array(expected))


def test_reward_is_minus_distance():
    env = make()
    env.reset()
    for action in np.random.default_rng(2).uniform(-30.0, 30.0, size=(5, 2)):
        ts = env.step(action)
        assert ts.reward == pytest.approx(-np.linalg.norm(env.physics.end_effector() - env.physics.target()))


def test_reaching_the_zone_terminates_with_discount_zero():
    env = make()
    target, _ = motion_function(90.0, 90.0, 5.0, 8.0)
    env.task.set_target_override(target)
    env.reset()
    ts = env.step(np.array([90.0, -90.0]))  # (0, 180) -> (90, 90)
    assert ts.last() and ts.discount == 0.0
    assert -ts.reward <= 0.5


def test_time_limit_after_30_steps_with_discount_one():
    env = make()
    env.task.set_target_override((25.0, 25.0))  # unreachable from a resting arm
    env.reset()
    for i in range(30):
        ts = env.step(np.zeros(2))
        assert ts.last() == (i == 29)
    assert ts.discount == 1.0
    assert env.reset().first()


# -- target and kinematics conditions --------------------------------------------------
def _episode_targets(env, n):
    out = []
    for _ in range(n):
        env.reset()
        out.append(env.physics.target())
    return np.array(out)


def test_static_target_is_kept_for_the_run_and_depends_on_seed():
    targets = _episode_targets(make("static_target", seed=0), 4)
    assert np.all(targets == targets[0])
    other = _episode_targets(make("static_target", seed=1), 1)
    assert not np.allclose(other[0], targets[0])


def test_changing_target_is_new_each_episode_and_reachable():
    env = make("changing_target")
    targets = _episode_targets(env, 20)
    assert len(np.unique(targets, axis=0)) == 20
    dist = np.linalg.norm(targets - np.array([15.0, 15.0]), axis=1)
    assert np.all(dist <= 13.0 + 1e-9)
    assert np.all((targets >= 0) & (targets <= 30))


def test_target_override_and_release():
    env = make()
    env.task.set_target_override((20.0, 21.0))
    np.testing.assert_array_equal(_episode_targets(env, 2), [[20.0, 21.0]] * 2)
    env.task.set_target_override(None)
    assert not np.allclose(_episode_targets(env, 1)[0], [20.0, 21.0])


def test_changing_kinematics_grows_each_step_after_the_start_episode():
    env = make("changing_target_changing_kinematics", growth_start_episode=2)
    for _ in range(2):  # episodes 0, 1: no growth
        env.reset()
        for _ in range(3):
            env.step(np.zeros(2))
        np.testing.assert_allclose(env.physics.link_lengths(), [5.0, 8.0])
    env.reset()  # episode 2
    for k in range(1, 6):
        env.step(np.array([3.0, -3.0]))
        np.testing.assert_allclose(env.physics.link_lengths(), [5.0 + 0.001 * k, 8.0 + 0.001 * k], atol=1e-12)
        alpha, beta = env.physics.joint_angles()
        end, _ = motion_function(alpha, beta, *env.physics.link_lengths())
        np.testing.assert_allclose(env.physics.end_effector(), end, atol=1e-9)
    env.reset()  # growth is kept across episodes
    np.testing.assert_allclose(env.physics.link_lengths(), [5.005, 8.005], atol=1e-12)


def test_static_kinematics_never_grow():
    env = make("changing_target", growth_start_episode=0)
    env.reset()
    for _ in range(5):
        env.step(np.ones(2))
    np.testing.assert_allclose(env.physics.link_lengths(), [5.0, 8.0])


def test_task_state_round_trip_reproduces_following_episodes():
    env = make("changing_target_changing_kinematics", growth_start_episode=1)
    for _ in range(2):
        env.reset()
        env.step(np.ones(2))
    state = env.task.get_state()
    expected = _episode_targets(env, 3)
    fresh = make("changing_target_changing_kinematics", seed=99, growth_start_episode=1)
    fresh.task.set_state(state)
    np.testing.assert_array_equal(_episode_targets(fresh, 3), expected)
    np.testing.assert_allclose(fresh.physics.link_lengths(), env.physics.link_lengths())


# -- the generalization split -------------------------------------------------------------
def test_test_region_is_one_third_of_the_reachable_area():
    stats = region_stats(suite.load_spec("changing_target"))
    assert stats.link_lengths == (5.0, 8.0)
    assert abs(stats.test_area_fraction - 1 / 3) <= 0.02
    assert 25 <= stats.grid_targets_in_test <= 45  # paper: "about 39"


def test_all_task_files_share_the_split():
    assert len({suite.load_spec(t).region.test_y_min for t in TASKS}) == 1


@pytest.mark.parametrize("task", [t for t in TASKS if t.endswith("train_region")])
def test_train_region_tasks_never_draw_test_targets(task):
    env = make(task)
    y_min = env.task.spec.region.test_y_min
    ys = np.array([env.task.sample_target()[1] for _ in range(500)])
    assert np.all(ys < y_min)


def test_test_region_draws_only_test_targets():
    env = make("changing_target", target_region="test")
    y_min = env.task.spec.region.test_y_min
    targets = _episode_targets(env, 50)
    assert np.all(targets[:, 1] >= y_min)


# -- bad input ------------------------------------------------------------------------------
def test_unknown_task_lists_known_ones():
    with pytest.raises(KeyError, match="unknown task 'reach_moon'.*static_target"):
        suite.load("planar_arm", "reach_moon")


def test_unknown_domain():
    with pytest.raises(KeyError, match="unknown domain"):
        suite.load("cartpole", "static_target")


@pytest.mark.parametrize("lengths", [(0.0, 8.0), (5.0, -1.0), (float("nan"), 8.0), (5.0, float("inf"))])
def test_bad_link_lengths_are_rejected(lengths):
    with pytest.raises(suite.TaskSpecError, match="link_lengths"):
        make(link_lengths=lengths)
    env = make()
    with pytest.raises(ValueError, match="link length"):
        env.task.set_link_lengths(*lengths)


@pytest.mark.parametrize("target", [(31.0, 10.0), (-0.1, 5.0), (5.0, float("nan")), (1.0, 2.0, 3.0)])
def test_target_outside_the_plane_is_rejected(target):
    env = make()
    env.reset()
    with pytest.raises(ValueError, match="target"):
        env.task.set_target_override(target)
    with pytest.raises(ValueError, match="target"):
        env.physics.set_target(target)


@pytest.mark.parametrize("action, problem", [([np.nan, 0.0], "finite"), ([0.0, np.inf], "finite"),
                                             ([1.0, 2.0, 3.0], "shape"), ([[1.0, 2.0]], "shape")])
def test_bad_actions_are_rejected(action, problem):
    env = make()
    env.reset()
    with pytest.raises(ValueError, match=problem):
        env.step(np.array(action))


def test_unknown_override_is_rejected():
    with pytest.raises(suite.TaskSpecError, match="unknown override"):
        make(gravity=9.81)
