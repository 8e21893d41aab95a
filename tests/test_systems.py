"""The open extension points beside the kinds (apac_mj.systems): planners and integrators chosen by name and built
by the builder; the forced-response wing on the same rules (the override grammar, one rule capability, overrides
undone on error); one per-episode record with the dynamics model's loss."""
from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest
import torch

from apac_mj import kinds, systems
from apac_mj.agent.planner import InversePlanner, MPCPlanner
from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.run import build
from apac_mj.run.timing import TestPlan, Timing
from apac_mj.types import Planner, PlanningTask, Proposal

from conftest import TINY, TINY_MPC


class Still(Planner):
    """Proposes no movement; counts its calls."""

    def __init__(self, task: PlanningTask) -> None:
        self.task, self.calls = task, 0

    def propose(self, agent, ctx, iterations) -> Proposal:
        self.calls += 1
        return Proposal(torch.zeros(ctx.E, self.task.action_dim), (iterations > 0).long())


@pytest.fixture
def still_kind():
    """A planner (``model`` as asked) and a kind that always plans with it, registered for one test."""
    made = []

    def register(model: bool = False) -> str:
        systems.register_planner(systems.PlannerKind("still", lambda cfg, task: Still(task), model=model),
                                 replace=True)
        kinds.register(kinds.AgentKind("spac_still", "SPAC-still", "k", kinds.get("spac").arbitrator,
                                       uses_habit=False, planner="still"), replace=True)
        made.append(True)
        return "spac_still"

    yield register
    if made:
        kinds.unregister("spac_still")
        systems.unregister("still")


def test_the_builder_builds_the_planner_the_kind_names(still_kind):
    """The loop's planner is the registered one, built for the members and the task's zone; it is the one that
    proposes while training."""
    kind = still_kind()
    cfg = TrainConfig(task="changing_target", seeds=(3, 4), episodes=1, agent=AgentConfig(kind=kind, **TINY))
    run = build.build(cfg, build.check(cfg))
    planner = run.loop.planner
    assert isinstance(planner, Still)
    assert planner.task == PlanningTask((3, 4), 2, run.spec.zone_radius, run.spec.stop_speed)
    assert run.agent.dynamics_model is None and run.agent.loss_names == ("critic", "actor", "forward", "inverse")
    st = run.loop.begin(np.ones(2, dtype=bool))
    run.loop.act(st, np.ones(2, dtype=bool), np.full(2, 5), explore=False)
    assert planner.calls == 1


def test_a_planner_that_plans_through_a_model_gives_the_agent_one(still_kind):
    """``PlannerKind.model``: the agent learns a dynamics model (set by ``agent.mpc``) and reports its loss."""
    kind = still_kind(model=True)
    cfg = TrainConfig(task="changing_target", seeds=(0,), episodes=1,
                      agent=AgentConfig(kind=kind, **TINY, params=TINY_MPC))
    agent = build.make_agent(cfg, build.check(cfg), build.environments(cfg, build.check(cfg)).sizes)
    assert agent.dynamics_model is not None and agent.loss_names[-1] == "dynamics"
    assert "dynamics_model" in agent.networks and agent.model_updates == cfg.agent.params["mpc"].model_updates


def test_the_built_in_planners_and_integrators_are_registered_and_stay():
    assert systems.PLANNERS.names() == ("inverse", "mpc") and systems.integrator_names() == ("pass_through", "kalman")
    assert systems.planner("mpc").model and not systems.planner("inverse").model
    for name in ("mpc", "kalman"):
        with pytest.raises(ValueError, match="built-in"):
            systems.unregister(name)
    task = PlanningTask((0, 1), 2, 0.5)
    assert isinstance(systems.planner("inverse").build(AgentConfig(), task), InversePlanner)
    mpc = systems.planner("mpc").build(AgentConfig(kind="spac_mpc"), task)
    assert isinstance(mpc, MPCPlanner) and mpc.seeds == [0, 1] and mpc.zone_radius == 0.5


def test_an_unregistered_planner_or_integrator_is_refused_by_name():
    with pytest.raises(ValueError, match=r"planner must be a registered planner, one of \('inverse', 'mpc'\)"):
        kinds.AgentKind("x", "X", "k", kinds.get("spac").arbitrator, planner="ilqr")
    with pytest.raises(KeyError, match="unknown planner 'ilqr'"):
        systems.planner("ilqr")
    with pytest.raises(ValueError, match="name must be a non-empty identifier"):
        systems.PlannerKind("a b", lambda cfg, task: None)
    with pytest.raises(ValueError, match="integrator must be one of"):
        build.check(TrainConfig(agent=AgentConfig(integrator="ukf")))


def test_a_factory_that_builds_no_planner_is_refused(still_kind):
    kind = still_kind()
    systems.register_planner(systems.PlannerKind("still", lambda cfg, task: object()), replace=True)
    cfg = TrainConfig(task="changing_target", seeds=(0,), episodes=1, agent=AgentConfig(kind=kind, **TINY))
    with pytest.raises(TypeError, match="planner 'still' built a object, not an apac_mj.types.Planner"):
        build.build(cfg, build.check(cfg))


def test_a_planners_iteration_time_is_looked_up_by_its_name(still_kind):
    t = Timing(inverse_pass_ms=210.0, mpc_iteration_ms=40.0)
    assert t.iteration("inverse") == 210.0 and t.iteration("mpc") == 40.0
    still_kind()
    assert t.iteration("still") == 210.0  # the default: the inverse model's pass
    systems.register_planner(systems.PlannerKind("still", lambda cfg, task: None, iteration_ms="model_pass_ms"),
                             replace=True)
    assert t.iteration("still") == t.model_pass_ms
    systems.register_planner(systems.PlannerKind("still", lambda cfg, task: None, iteration_ms="nope"),
                             replace=True)
    with pytest.raises(ValueError, match="'nope', not a Timing field"):
        t.iteration("still")


def test_a_test_plan_checks_its_deadlines_trials_and_repeats_once():
    assert TestPlan((100.0, 900.0)).trials == 100
    with pytest.raises(ValueError, match="every deadline must be"):
        TestPlan((10.0,))
    for field in ("trials", "repeats"):
        with pytest.raises(ValueError, match=f"{field} must be an integer >= 1"):
            TestPlan((100.0,), **{field: 0})


def test_the_forced_response_command_sets_any_run_or_agent_field():
    """``--set`` in the grammar of ``train``: protocol, timing, run and agent fields; episodes are the practice's."""
    from apac_mj.commands.forced_response import protocol
    from apac_mj.util.overrides import OverrideError

    p = protocol(["seeds=0-2", "practice=5,10", "agents=ddpg,apac_voc", "timing.habit_latency_ms=250",
                  "batch_size=128", "agent.planning_episodes=7", "mpc.horizon=3", "task=cued_targets"])
    assert p.run.seeds == (0, 1, 2) and p.practice == (5, 10) and p.timing.habit_latency_ms == 250.0
    cfg = p.train_config("apac_voc", 10)
    assert (cfg.episodes, cfg.agent.kind, cfg.agent.batch_size, cfg.agent.planning_episodes) == (10, "apac_voc", 128, 7)
    assert cfg.agent.params["mpc"].horizon == 3
    assert protocol(["practice=1000", "prep_times_ms=350"]).practice == (1000,)  # one value of a list
    default = protocol([]).train_config("apac", 100)  # the published study's run, as before
    assert default == TrainConfig(task="cued_targets", seeds=tuple(range(10)), episodes=100,
                                  agent=AgentConfig(kind="apac", batch_size=64))
    for bad, match in (["episodes=5"], "unknown key"), (["batch_sise=3"], "did you mean 'batch_size'"), \
                      (["prep_times_ms=10"], "every deadline"), (["agents=nope"], "unknown agent kind"):
        with pytest.raises((OverrideError, ValueError, KeyError), match=match):
            protocol(bad)


def test_the_overrides_are_undone_on_leaving_also_on_an_error():
    from apac_mj.suite.vec_env import VecEnv

    env = VecEnv("cued_targets", [0, 1])

    def overrides() -> list[tuple]:
        return [(e.task.get_state()["cue_override"], e.task.get_state()["mapping_override"]) for e in env.envs]

    with pytest.raises(RuntimeError, match="a failed trial"):
        with env.overridden(cue=3, remapped=True):
            assert overrides() == [(3, True)] * 2
            env.reset()
            assert (env.cues() == 3).all()
            raise RuntimeError("a failed trial")
    assert overrides() == [(None, None)] * 2


def test_only_a_rule_that_reads_the_last_delta_is_also_tested_on_the_imagined_one():
    from apac_mj.agent.arbitration import DeltaArbitrator
    from apac_mj.run.forced_response import variants

    class Delta(DeltaArbitrator):
        pass

    class NotDelta(DeltaArbitrator):
        reads_last_delta = False

    cfg = AgentConfig(kind="apac")
    assert variants(cfg, Delta(cfg)) == ("apac", "apac_imagined")
    assert variants(cfg, NotDelta(cfg)) == ("apac",)


def test_the_dynamics_models_loss_reaches_the_metrics(tmp_path):
    """One per-episode record: a model kind's metrics carry ``dynamics_loss`` after the other columns; the paper's
    kinds' carry none; both carry the summary's columns."""
    from apac_mj.run.run_dir import METRIC_COLUMNS
    from apac_mj.run.trainer import train
    from apac_mj.types import TIMING_COLUMNS

    for kind in ("spac", "spac_mpc"):
        cfg = TrainConfig(task="changing_target", seeds=(0, 1), episodes=2, checkpoint_every=2,
                          agent=AgentConfig(kind=kind, **TINY, params=TINY_MPC))
        df = pd.read_parquet(train(cfg, tmp_path / kind, progress=False) / "metrics.parquet")
        extra = ["dynamics_loss"] if kind == "spac_mpc" else []
        assert list(df.columns) == [*METRIC_COLUMNS, *TIMING_COLUMNS, *extra]
        if extra:
            learned = df[df.phase == "train"].dynamics_loss
            assert learned.notna().all() and (learned > 0).all()


def test_a_checkpoint_from_before_the_dynamics_loss_resumes_with_nan_for_it():
    from apac_mj.run.trainer import LoopState

    old = LoopState.fresh(2, 1, torch.device("cpu")).state_dict()
    assert tuple(old["loss_sum"].shape) == (2, 4)
    state = LoopState.from_state_dict(old, torch.device("cpu"), losses=5)
    assert state.loss_sum.shape == (2, 5) and np.isnan(state.loss_sum[:, 4]).all()
    assert (state.loss_sum[:, :4] == 0).all()
    same = LoopState.from_state_dict(dataclasses.replace(state).state_dict(), torch.device("cpu"), losses=5)
    assert same.loss_sum.shape == (2, 5)
