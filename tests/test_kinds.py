"""The agent-kind registry: every kind, a dummy one defined here included, trains, evaluates and reports."""
from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from apac_mj.experiments import grid
from apac_mj.experiments.presets import load_preset
from apac_mj import kinds, report
from apac_mj.agent.arbitration import HISTORY
from apac_mj.types import ArbitrationContext, Arbitrator, Decision
from apac_mj.config import AgentConfig

PACKAGE = Path(__file__).resolve().parents[1] / "apac_mj"


class EveryOtherStep(Arbitrator):
    """A rule the built-ins cannot express, implementing only ``use_habit`` (the base class's no-op
    ``observe``, ``state_dict`` and ``load_state_dict`` do the rest): the habit on even steps; it also keeps
    every context it saw."""

    seen: list[ArbitrationContext] = []

    def __init__(self, cfg: AgentConfig) -> None:
        self.cfg = cfg

    def use_habit(self, ctx: ArbitrationContext) -> Decision:
        EveryOtherStep.seen.append(ctx)
        return Decision(ctx.step % 2 == 0)


DUMMY = kinds.AgentKind("every_other", "Every other step", "tab:pink", EveryOtherStep)
KINDS = [*kinds.names(), DUMMY.name]


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    """A tiny grid of every registered kind plus the dummy: trained, tested, reported."""
    kinds.register(DUMMY)
    try:
        preset = load_preset("smoke", [f"agents={','.join(KINDS)}", "conditions=changing_target",
                                            "episodes=3", "tests.generalization=false", "tests.limit=3"])
        out = tmp_path_factory.mktemp("kinds")
        grid.run_grid(preset, out, progress=False)
        report_dir = report.write_report(out)
        yield out, report_dir
    finally:
        kinds.unregister(DUMMY.name)


@pytest.mark.parametrize("name", KINDS)
def test_every_kind_trains_evaluates_and_reports(results, name):
    out, report_dir = results
    kind = DUMMY if name == DUMMY.name else kinds.get(name)
    cell = out / f"{name}__changing_target"
    metrics = pd.read_parquet(cell / "metrics.parquet")
    assert (metrics.phase == "train").sum() == 2 * 3
    summary = pd.read_json(cell / "eval" / "summary.json", typ="series")["protocols"]
    assert summary["grid"]["episodes"] == 2 * 3
    assert ("occluded" in summary) == kind.acts_occluded
    table = pd.read_csv(report_dir / "key_numbers.csv")
    assert (table.agent == name).any()
    text = (report_dir / "report.md").read_text()
    assert kind.label in text
    if kind.arbitrates:
        assert (table[table.quantity == "habit_fraction_late"].agent == name).any()
    for fig in ("fig3_training_success.png", "fig4_test.png", "fig6_steps_time.png"):
        assert (report_dir / fig).stat().st_size > 0


def test_the_dummy_arbitrator_decides_and_sees_the_context(results):
    out, _ = results
    metrics = pd.read_parquet(out / f"{DUMMY.name}__changing_target" / "metrics.parquet")
    train = metrics[metrics.phase == "train"]
    np.testing.assert_array_equal(train.habit_actions, (train.steps + 1) // 2)  # steps 0, 2, 4, ...
    late = [c for c in EveryOtherStep.seen if (c.step > 0).all()]
    assert late and all(c.recent_deltas.shape == (c.E, HISTORY) and c.state.shape == (c.E, 6) for c in late)
    assert any(torch.isfinite(c.forward_error).all() and c.vision.all() for c in late)
    assert all(torch.isfinite(c.recent_deltas[:, -1]).all() for c in late)  # the last delta is pushed
    first = [c for c in EveryOtherStep.seen if (c.step == 0).all()]
    assert first and all(torch.isnan(c.last_delta).all() and torch.isnan(c.forward_error).all() for c in first)


def test_an_unregistered_kind_in_results_is_a_clear_error(results):
    out, _ = results
    kinds.unregister(DUMMY.name)
    try:
        with pytest.raises(kinds.UnknownKindError, match="every_other.*not registered"):
            report.write_report(out, out / "report_again")
        assert not (out / "report_again").exists()
    finally:
        kinds.register(DUMMY)


def test_registry_refuses_bad_kinds():
    with pytest.raises(ValueError, match="already registered"):
        kinds.register(kinds.AgentKind("apac", "APAC", "tab:blue", EveryOtherStep))
    with pytest.raises(ValueError, match="habit, the planner or both"):
        kinds.AgentKind("none", "None", "k", EveryOtherStep, uses_habit=False, uses_planner=False)
    with pytest.raises(ValueError, match="built-in"):
        kinds.unregister("ddpg")
    with pytest.raises(ValueError, match="unknown agent kind 'nope'; registered kinds: ddpg, spac, apac"):
        kinds.check(AgentConfig(kind="nope"))


def test_a_factory_must_build_an_arbitrator():
    class Duck:  # the old duck-typed contract: a bare tensor, no base class
        def use_habit(self, ctx):
            return torch.ones(ctx.E, dtype=torch.bool)

    kinds.register(kinds.AgentKind("duck", "Duck", "k", lambda cfg: Duck()))
    try:
        with pytest.raises(TypeError, match="agent kind 'duck' built a Duck, not an apac_mj.types.Arbitrator"):
            kinds.arbitrator_for(AgentConfig(kind="duck"))
    finally:
        kinds.unregister("duck")


def test_the_base_class_keeps_no_statistics():
    rule = EveryOtherStep(AgentConfig())
    rule.observe(None, np.ones(2, dtype=bool), adapt=True)  # a no-op: nothing to learn
    assert rule.state_dict() == {}
    rule.load_state_dict({})
    with pytest.raises(ValueError, match=r"EveryOtherStep rule keeps no statistics, but the checkpoint has \['x'\]"):
        rule.load_state_dict({"x": torch.zeros(2)})


@pytest.mark.parametrize("kind", ["ddpg", "spac"])
def test_habit_formation_is_refused_for_kinds_that_do_not_arbitrate(kind):
    kinds.check(AgentConfig(kind="apac", habit_distillation_weight=50.0))
    with pytest.raises(ValueError, match=f"habit_distillation_weight = 50.0 needs a kind that arbitrates.*'{kind}'"):
        kinds.check(AgentConfig(kind=kind, habit_distillation_weight=50.0))


def test_use_habit_must_return_one_bool_per_member():
    from apac_mj.agent.planner import InversePlanner
    from apac_mj.run.rollout import select_action

    class Wrong(Arbitrator):
        def use_habit(self, ctx):
            return Decision(torch.ones(ctx.E + 1, dtype=torch.bool))

    class Bare(Arbitrator):
        def use_habit(self, ctx):
            return torch.ones(ctx.E, dtype=torch.bool)

    ctx = ArbitrationContext(torch.zeros(2, dtype=torch.long), torch.zeros(2, dtype=torch.long), torch.zeros(2),
                             state=torch.zeros(2, 6))
    with pytest.raises(ValueError, match=r"Wrong.use_habit must return \[E\] = \(2,\) bools"):
        select_action(None, Wrong(), ctx, np.ones(2, dtype=bool), explore=False, planner=InversePlanner())
    with pytest.raises(ValueError, match=r"Bare.use_habit must return a Decision\(habit \[E\] bools, inputs\), got"):
        select_action(None, Bare(), ctx, np.ones(2, dtype=bool), explore=False, planner=InversePlanner())


def test_kind_names_appear_only_in_the_registry_and_the_papers_table():
    """No module tests a kind's name: string constants equal to a built-in name live only in kinds.py,
    in the report's table of the paper's values (PAPER, apac_mj/report/quantities.py) and in rules.py's
    DEFAULT_KIND and a study's default list (the forced-response protocol's STUDY_KINDS, data as a preset's list)."""
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.name == "kinds.py":
            continue
        tree = ast.parse(path.read_text())
        allowed = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Assign) and any(getattr(t, "id", None) in ("PAPER", "DEFAULT_KIND", "STUDY_KINDS")
                                                    for t in node.targets):
                allowed |= {id(n) for n in ast.walk(node)}
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and node.value in kinds.BUILTIN and id(node) not in allowed:
                found.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno} {node.value!r}")
    assert not found, "agent kind names outside the registry: " + ", ".join(found)


class _CountingAgent:
    """What select_action asks of an agent: the actor's and the inverse model's proposals, counted."""

    def __init__(self, E: int) -> None:
        import types

        self.E, self.actor_calls = E, 0
        self.sizes = types.SimpleNamespace(action_bound=1e9)

    def actor_action(self, state):
        self.actor_calls += 1
        return torch.full((self.E, 2), 1.0)

    def inverse_action(self, state):
        return torch.full((self.E, 2), 2.0)


@pytest.mark.parametrize("rule, habit, calls", [
    ("spac", [False, False, False], 0), ("ddpg", [True, True, True], 1), ("mixed", [True, False, False], 1)])
def test_the_actors_pass_runs_only_where_a_habit_acts(rule, habit, calls):
    """A kind that always plans (SPAC) is not charged a habit pass it never uses: the measured decision time of
    the paper's planner holds the inverse model's pass alone. The actions are those of the old code (the
    actor's where the habit acts, else the planner's)."""
    from apac_mj.agent.planner import InversePlanner
    from apac_mj.run.rollout import select_action

    class Mixed(Arbitrator):
        def use_habit(self, ctx):
            return Decision(torch.tensor([True, False, False]))

    arbitrator = Mixed() if rule == "mixed" else kinds.arbitrator_for(AgentConfig(kind=rule))
    assert arbitrator.needs_habit_action is False
    agent = _CountingAgent(3)
    ctx = ArbitrationContext(torch.full((3,), 200), torch.full((3,), 5), torch.zeros(3), state=torch.zeros(3, 6))
    choice = select_action(agent, arbitrator, ctx, np.ones(3, dtype=bool), explore=False, planner=InversePlanner())
    assert agent.actor_calls == calls
    assert choice.decision.habit.tolist() == habit
    assert choice.action[:, 0].tolist() == [1.0 if h else 2.0 for h in habit]


def test_a_rule_that_reads_the_habits_proposal_gets_it_before_deciding():
    """vision_aware's dark check reads the habit's proposal (the context carries it); its suppressing form and
    the paper's rules do not ask for it, and the episode loop then builds the context without the actor's pass."""
    from apac_mj.run.rollout import EpisodeState

    def rule(dark):
        return kinds.arbitrator_for(AgentConfig(kind="apac_vision", params={"vision_aware": {"dark": dark}}))

    assert rule("check").needs_habit_action is True
    assert rule("suppress").needs_habit_action is False
    assert kinds.arbitrator_for(AgentConfig(kind="apac")).needs_habit_action is False
    agent = _CountingAgent(2)
    st = EpisodeState.fresh(2, torch.device("cpu"))
    assert st.context(np.zeros(2, dtype=np.int64), agent, 0.5, habit_action=False).habit_action is None
    assert agent.actor_calls == 0
    assert st.context(np.zeros(2, dtype=np.int64), agent, 0.5).habit_action.tolist() == [[1.0, 1.0]] * 2
    assert agent.actor_calls == 1
