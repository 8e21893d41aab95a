"""The world that does not wait (issue 42 item 1): a ``[deliberation]`` table makes a decision's time, priced from
what it computed, run on the plant under the last command before the new one starts, against a deadline."""
from __future__ import annotations

import mujoco
import numpy as np
import pandas as pd
import pytest
import torch

from apac_mj import kinds
from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.agent.planner import InversePlanner, MPCPlanner
from apac_mj.rules import MPCParams
from apac_mj.run import deliberation, rollout
from apac_mj.run.deliberation import Meter
from apac_mj.run.timing import Counts, Timing, decision_ms
from apac_mj.run.trainer import train
from apac_mj.suite import deliberation as plant_clock
from apac_mj.suite import load_spec
from apac_mj.suite.task_spec import TaskSpecError
from apac_mj.suite.vec_env import VecEnv
from apac_mj.types import ArbitrationContext, Decision

from conftest import TINY8, TINY_MPC

TASK = "changing_target_torque_no_wait"
#: Horizon 2 by hand: the habit's own sequence (the actor at the 2 imagined states and at s_H, 2 model passes,
#: the critic's Q(s_H, pi(s_H))); one sampled sequence (the actor only at s_H); 8 sampled sequences in one batch
#: (the passes of one, and 7 extra rows of each of its 4 passes).
HABIT_ROLLOUT = Counts(actor=3, critic=1, model=2)
SEQUENCE = Counts(actor=1, critic=1, model=2)
EIGHT = Counts(actor=1, critic=1, model=2, rows=28)


def ms_of(counts: Counts) -> float:
    return decision_ms(counts, Timing())


def step_ms(counts: Counts) -> float:
    """A step's plant time (ms): the decision's time rounded to 2 ms sub-steps, then the 100 ms command."""
    return 100.0 + 2.0 * int(np.floor(ms_of(counts) / 2.0 + 0.5))


# -- the table --------------------------------------------------------------------------------------------

def test_the_table_is_read_with_its_defaults():
    spec = load_spec(TASK)
    assert (spec.deliberation.deadline_ms, spec.deliberation.time_scale) == (3000.0, 1.0)
    half = spec.replace(deliberation={"time_scale": 0.5})  # an override keeps the keys it does not set
    assert (half.deliberation.deadline_ms, half.deliberation.time_scale) == (3000.0, 0.5)
    plain = load_spec("changing_target_torque").replace(deliberation={"time_scale": 0.5})
    assert plain.deliberation.deadline_ms is None and plant_clock.deadline_ms(plain) == 30 * 100.0
    assert spec.replace(deliberation=None).deliberation is None
    assert plant_clock.deadline_ms(load_spec("changing_target_torque").replace(steps_per_episode=20,
                                                                             deliberation={})) == 2000.0
    assert load_spec("changing_target_torque").deliberation is None


@pytest.mark.parametrize("table, problem", [
    ({"deadline_ms": -5.0}, "deadline_ms must be a finite number > 0"),
    ({"deadline_ms": 0}, "deadline_ms must be a finite number > 0"),
    ({"deadline_ms": float("nan")}, "deadline_ms must be a finite number > 0"),
    ({"deadline_ms": True}, "deadline_ms must be a finite number > 0"),
    ({"time_scale": -0.5}, "time_scale must be a finite number >= 0"),
    ({"time_scale": "1"}, "time_scale must be a finite number >= 0"),
    ({"speed": 2.0}, r"unknown key\(s\) \['speed'\]"),
    ({"deadline_ms": 99.0}, "deadline_ms must be at least one control interval \\(100 ms"),
])
def test_bad_tables_are_refused_before_anything_is_written(tmp_path, table, problem):
    with pytest.raises(TaskSpecError, match=problem):
        load_spec(TASK).replace(deliberation=table)
    out = tmp_path / "run"
    cfg = TrainConfig(task=TASK, seeds=(0,), episodes=1, task_overrides={"deliberation": table},
                      agent=AgentConfig(**TINY8))
    with pytest.raises(TaskSpecError, match=problem):
        train(cfg, out, progress=False)
    assert not out.exists()


def test_the_ideal_arm_is_refused():
    with pytest.raises(TaskSpecError, match="needs a plant with dynamics"):
        load_spec("changing_target").replace(deliberation={})


def test_times_round_to_the_nearest_sub_step():
    assert [plant_clock.substeps(ms, 0.002) for ms in (0.0, 0.9, 1.0, 129.0, 130.0, 130.9, 131.0)] == \
        [0, 0, 1, 65, 65, 65, 66]
    with pytest.raises(ValueError, match="finite number of ms >= 0"):
        plant_clock.substeps(-1.0, 0.002)


# -- the plant --------------------------------------------------------------------------------------------

def test_a_decision_delays_the_command_by_exactly_its_time():
    """130 ms of deliberation: 65 sub-steps under the last torques, then 50 under the new ones (MuJoCo by hand)."""
    env = VecEnv(TASK, [0])
    env.reset()
    old, new = np.array([[0.3, -0.2]]), np.array([[-0.4, 0.1]])
    env.step(old)
    p = env.physics(0)
    m, ref = p.model.ptr, mujoco.MjData(p.model.ptr)
    full = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)
    state = np.empty(mujoco.mj_stateSize(m, full))
    mujoco.mj_getState(m, p.data.ptr, state, full)
    mujoco.mj_setState(m, ref, state, full)
    ref.ctrl[:] = p.data.ctrl
    assert deliberation.elapse(env, np.array([130.0]), np.array([True])).tolist() == [65]
    env.step(new)
    mujoco.mj_step(m, ref, 65)
    ref.ctrl[:] = new[0]
    mujoco.mj_step(m, ref, 50)
    np.testing.assert_allclose(p.data.qpos, ref.qpos, rtol=0, atol=1e-12)
    np.testing.assert_allclose(p.data.qvel, ref.qvel, rtol=0, atol=1e-9)
    assert plant_clock.elapsed_ms(p) == pytest.approx(100.0 + 130.0 + 100.0, abs=1e-9)


def _at_the_start_hand(spec):
    """Environments of ``spec`` whose next episode's target is the hand's start position (a zero torque reaches it)."""
    env = VecEnv(spec, [0])
    env.reset()
    env.set_target_override(env.true_arm()[:, :2])
    env.reset()
    return env


@pytest.mark.parametrize("decision_ms, reached", [(0.0, True), (2.0, False)])
def test_a_reach_counts_only_by_the_deadline(decision_ms, reached):
    env = _at_the_start_hand(load_spec(TASK).replace(deliberation={"deadline_ms": 100.0}))
    deliberation.elapse(env, np.array([decision_ms]), np.array([True]))
    obs = env.step(np.zeros((1, 2)))
    assert obs.last[0] and obs.reached[0] == reached  # ended either way: the deadline came


@pytest.mark.parametrize("decision_ms, reached", [(0.0, True), (2.0, False)])
def test_the_frozen_tests_count_a_reach_only_by_the_deadline(decision_ms, reached):
    """``evaluate.reached`` (the frozen tests' success) reads the deadline as the task does: a hand inside the zone
    after the deadline is a failure."""
    from apac_mj.run.evaluate import reached as test_reached

    env = _at_the_start_hand(load_spec(TASK).replace(deliberation={"deadline_ms": 100.0}))
    deliberation.elapse(env, np.array([decision_ms]), np.array([True]))
    env.step(np.zeros((1, 2)))
    distance = float(env.distances()[0])
    assert distance <= env.spec.zone_radius
    assert test_reached(env, 0, distance, env.spec.zone_radius, None) == reached


def test_the_step_limit_ends_an_episode_that_comes_to_it_before_the_deadline():
    env = VecEnv(load_spec(TASK).replace(steps_per_episode=3), [0])  # the 3 s deadline: after 3 steps of 100 ms
    env.reset()
    assert [env.step(np.zeros((1, 2))).last[0] for _ in range(3)] == [False, False, True]


def test_the_deadline_cuts_the_episode_at_the_first_step_that_ends_at_or_after_it():
    env = VecEnv(load_spec(TASK).replace(deliberation={"deadline_ms": 1000.0}), [0])
    env.reset()
    ends = []
    for _ in range(10):
        deliberation.elapse(env, np.array([150.0]), np.array([True]))
        ends.append(env.step(np.zeros((1, 2))).last[0])
        if ends[-1]:
            break
    assert ends == [False, False, False, True]  # 4 steps of 250 ms: 1000 ms


# -- what a decision computed ---------------------------------------------------------------------------------

def _context(E: int, habit_action: bool = False) -> tuple[ArbitrationContext, list[int]]:
    calls = [0]

    def probe():
        calls[0] += 1

    ctx = ArbitrationContext(episode=torch.zeros(E, dtype=torch.long), step=torch.zeros(E, dtype=torch.long),
                             last_delta=torch.zeros(E), habit_action=torch.zeros(E, 2) if habit_action else None,
                             predict_end=lambda a: a, habit_probe=probe)
    return ctx, calls


def _choice(habit, iterations, E):
    return rollout.Choice(torch.zeros(E, 2), Decision(torch.tensor(habit)), np.array(iterations), np.zeros(E), None)


def test_an_mpc_decision_counts_its_sequences():
    """Horizon 2, 8 candidates, 2 habit sequences (the habit's own and one perturbed copy), k iterations:
    the habit's rollout, its copy, then k batches of 8 sequences."""
    spec = load_spec(TASK)
    planner = MPCPlanner(MPCParams(horizon=2, candidates=8, elites=2, iterations=3), seeds=[0, 1, 2])
    ctx, _ = _context(3)
    meter = Meter(ctx, spec.deliberation)
    counts = meter.counts(planner, _choice([True, False, False], [0, 1, 3], 3))
    assert counts == [Counts(actor=1), HABIT_ROLLOUT + SEQUENCE + EIGHT, HABIT_ROLLOUT + SEQUENCE + EIGHT * 3]
    assert counts[2] == Counts(actor=7, critic=5, model=10, rows=84)


def test_the_rules_probe_is_counted_once_and_the_plan_reuses_it():
    spec = load_spec(TASK)
    planner = MPCPlanner(MPCParams(horizon=2, candidates=8, elites=2, iterations=2, habit_candidates=1), seeds=[0, 1])
    ctx, calls = _context(2, habit_action=True)
    meter = Meter(ctx, spec.deliberation)
    ctx.habit_probe()
    ctx.predict_end(torch.zeros(2, 2))
    assert calls == [1] and (meter.probes, meter.checks) == (1, 1)
    counts = meter.counts(planner, _choice([True, False], [0, 2], 2))
    probe_and_check = HABIT_ROLLOUT + Counts(model=1)  # the probe's first pass is the habit's proposal
    assert counts == [probe_and_check, probe_and_check + EIGHT * 2]
    assert counts[1] == Counts(actor=5, critic=3, model=7, rows=56)


def test_the_inverse_model_is_one_pass_per_iteration():
    ctx, _ = _context(2)
    counts = Meter(ctx, load_spec(TASK).deliberation).counts(InversePlanner(), _choice([False, True], [1, 0], 2))
    assert counts == [Counts(inverse=1), Counts(actor=1)]


def test_time_scale_multiplies_and_a_babbled_command_took_no_time():
    spec = load_spec(TASK).replace(deliberation={"time_scale": 0.5})
    ctx, _ = _context(2)
    meter = Meter(ctx, spec.deliberation)
    choice = _choice([False, False], [1, 1], 2)
    babbled = choice.action.clone()
    babbled[1] += 1.0
    ms = meter.decision_ms(InversePlanner(), choice, babbled)
    assert ms.tolist() == [0.5 * ms_of(Counts(inverse=1)), 0.0]


# -- the episode loop -------------------------------------------------------------------------------------------

def _steps(tmp_path, kind: str, overrides: dict | None = None, episodes: int = 1) -> pd.DataFrame:
    """Every step of a tiny training on the no-wait task: the plant time it took, and what the decision was."""
    rows = []
    last = {}

    def on_step(info, env):
        for k in np.flatnonzero(info.active):
            now = plant_clock.elapsed_ms(env.physics(k))
            rows.append({"member": k, "episode": int(info.episode[k]), "step": int(info.step[k]),
                         "ms": now - (0.0 if info.step[k] == 0 else last[k]), "end": now,
                         "habit": bool(info.habit[k]), "iterations": int(info.plan_iterations[k]),
                         "done": bool(info.done[k]), "reached": bool(info.reached[k])})
            last[k] = now

    cfg = TrainConfig(task=TASK, seeds=(0, 1), episodes=episodes, checkpoint_every=episodes,
                      task_overrides=overrides or {}, agent=AgentConfig(kind=kind, **TINY8, params=TINY_MPC))
    train(cfg, tmp_path / kind, progress=False, on_step=on_step)
    return pd.DataFrame(rows)


def test_time_to_target_includes_every_decisions_time(tmp_path):
    """SPAC-MPC plans every step (tiny planner, 2 iterations): each trained step lasts the priced plan plus the
    command; babbling steps only the command; episodes end at the first step at or after the 3 s deadline."""
    df = _steps(tmp_path, "spac_mpc")
    plan = HABIT_ROLLOUT + SEQUENCE + EIGHT * 2
    trained = df[df.episode >= 0]
    assert (trained.iterations == 2).all()
    np.testing.assert_allclose(trained.ms, step_ms(plan), atol=1e-6)
    np.testing.assert_allclose(df[df.episode < 0].ms, 100.0, atol=1e-6)
    ends = trained[trained.done]
    expected = np.ceil(3000.0 / step_ms(plan) - 1e-9) * step_ms(plan)
    assert ((ends.end - expected).abs() < 1e-6).all() or ends.reached.any()


def test_a_habit_only_agent_pays_only_its_actors_pass(tmp_path):
    df = _steps(tmp_path, "ddpg")
    trained = df[df.episode >= 0]
    np.testing.assert_allclose(trained.ms, step_ms(Counts(actor=1)), atol=1e-6)


def test_with_no_decision_time_the_table_changes_nothing_before_the_deadline(tmp_path):
    """time_scale 0 and the default deadline (the step limit's time): the same numbers as the plain torque arm."""
    def metrics(task, overrides):
        cfg = TrainConfig(task=task, seeds=(0, 1), episodes=2, checkpoint_every=2, task_overrides=overrides,
                          agent=AgentConfig(kind="apac", **TINY8))
        out = train(cfg, tmp_path / f"{task}{len(overrides)}", progress=False)
        return pd.read_parquet(out / "metrics.parquet").drop(columns=["habit_seconds", "planning_seconds"],
                                                             errors="ignore")

    plain = metrics("changing_target_torque", {})
    waiting = metrics("changing_target_torque", {"deliberation": {"time_scale": 0.0}})
    pd.testing.assert_frame_equal(plain, waiting)


@pytest.mark.parametrize("kind", kinds.names())
def test_every_kind_runs_where_the_world_does_not_wait(tmp_path, kind):
    df = _steps(tmp_path, kind)
    trained = df[df.episode >= 0]
    assert len(trained) and (trained.ms >= 100.0 - 1e-6).all()
    planned, habitual = trained[trained.iterations > 0].ms, trained[trained.iterations == 0].ms
    if len(planned) and len(habitual):
        assert planned.min() > habitual.max()
    assert (trained[trained.done].end <= 3000.0 + trained.ms.max()).all()
