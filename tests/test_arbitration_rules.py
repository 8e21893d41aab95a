"""The paper's arbitration rules and the helpers every rule shares (apac_mj.agent.arbitration), against answers
computed by hand: APAC's delta rule at each of its boundaries (planning phase, first steps, threshold, NaN),
both delta rules, the step signals the running statistics learn from, and the TD-error history."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from apac_mj.agent.arbitration import AlwaysHabit, AlwaysPlan, DeltaArbitrator, push_delta, step_signals
from apac_mj.config import AgentConfig
from apac_mj.types import HABIT_COST, PLANNING_COST, ArbitrationContext

NAN = float("nan")


def _ctx(episode: list[int], step: list[int], delta: list[float]) -> ArbitrationContext:
    return ArbitrationContext(episode=torch.tensor(episode), step=torch.tensor(step),
                              last_delta=torch.tensor(delta, dtype=torch.float32))


def test_the_exclusive_rules_always_choose_their_controller():
    c = _ctx([0, 9, 300], [0, 1, 7], [NAN, 0.0, 5.0])
    habit, plan = AlwaysHabit().use_habit(c).habit, AlwaysPlan(AgentConfig()).use_habit(c).habit
    assert habit.dtype == plan.dtype == torch.bool
    assert habit.tolist() == [True, True, True] and plan.tolist() == [False, False, False]


def test_apacs_rule_at_each_boundary():
    """Planning phase 2 episodes, the habit on the first 2 steps, then where |delta| < 1 (NaN: unreliable):
    episode 1 plans; episode 2 step 0 and step 1 take the habit whatever delta; from step 2 only |delta| < 1."""
    rule = DeltaArbitrator(AgentConfig(kind="apac", planning_episodes=2, habit_first_steps=2, delta_threshold=1.0))
    c = _ctx([1, 2, 2, 5, 5, 5, 5, 5], [0, 0, 1, 2, 2, 2, 2, 9], [0.0, 5.0, 5.0, 0.5, -1.5, 1.0, NAN, -0.99])
    d = rule.use_habit(c)
    assert d.habit.tolist() == [False, True, True, True, False, False, False, True]
    assert set(d.inputs) == {"abs_delta", "threshold"}
    torch.testing.assert_close(d.inputs["abs_delta"], torch.tensor([0.0, 5.0, 5.0, 0.5, 1.5, 1.0, NAN, 0.99]),
                               equal_nan=True)
    assert d.inputs["threshold"].tolist() == [1.0] * 8


def test_the_signed_rule_compares_delta_itself():
    """Algorithm 2's "RPE < 1": a large negative delta counts as reliable, a positive one at the threshold not."""
    rule = DeltaArbitrator(AgentConfig(kind="apac", planning_episodes=0, habit_first_steps=0, delta_threshold=0.5,
                                       delta_rule="signed"))
    d = rule.use_habit(_ctx([0, 0, 0, 0], [3, 3, 3, 3], [-7.0, 0.5, 0.49, NAN]))
    assert d.habit.tolist() == [True, False, True, False]
    assert set(d.inputs) == {"delta", "threshold"} and d.inputs["threshold"].tolist() == [0.5] * 4


def test_the_step_signals_are_the_steps_distances_errors_and_costs():
    """Hand (3, 5) -> (0, 2), target (0, 1): 5 cm before, 1 after; the forward model predicted the hand 2 cm off
    (seen by member 0 only); the habit's step costs HABIT_COST, the planner's PLANNING_COST."""
    state = np.array([[3.0, 5.0, 0, 0, 0, 1.0]] * 2, np.float32)
    nxt = np.array([[0.0, 2.0, 0, 0, 0, 1.0]] * 2, np.float32)
    predicted = np.array([[2.0, 2.0, 0, 0]] * 2, np.float32)
    info = SimpleNamespace(delta=np.array([0.25, -2.0]), state=state, next_state=nxt, predicted_arm=predicted,
                           vision=np.array([True, False]), habit=np.array([True, False]),
                           done=np.array([False, True]), terminal=np.array([False, True]), episode=np.array([4, 7]),
                           zone_radius=0.75)
    sig = step_signals(info)
    assert sig["delta"].tolist() == [0.25, -2.0] and sig["delta"].dtype == torch.float32
    torch.testing.assert_close(sig["end_error"], torch.tensor([2.0, NAN]), equal_nan=True)
    assert sig["before"].tolist() == [5.0, 5.0] and sig["after"].tolist() == [1.0, 1.0]
    assert sig["cost"].tolist() == [float(HABIT_COST), float(PLANNING_COST)]
    assert sig["habit"].tolist() == [True, False] and sig["done"].tolist() == [False, True]
    assert sig["terminal"].tolist() == [False, True] and sig["episode"].tolist() == [4, 7]
    assert sig["zone_radius"].item() == pytest.approx(0.75) and sig["zone_radius"].dim() == 0


def test_the_delta_history_drops_the_oldest_for_the_members_that_stepped():
    history = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], np.float32)
    out = push_delta(history, np.array([7.0, 8.0]), np.array([True, False]))
    assert out.tolist() == [[2.0, 3.0, 7.0], [4.0, 5.0, 6.0]] and out.dtype == np.float32


# -- the graded rule (value of computation), by hand ---------------------------------------------------------
from apac_mj.agent.arbitrators import (VOC_EDGES, ValueOfComputationArbitrator,  # noqa: E402
                                       VisionAwareArbitrator)
from apac_mj.types import HabitProbe  # noqa: E402


def _voc(**voc) -> ValueOfComputationArbitrator:
    """A graded rule with 4 iterations, window 2 (rate 1/2), one iteration priced at 10/100 of a step, learning on
    every planned step (``learn_on = "planned"``; the re-explored learning: tests/test_voc_gain.py)."""
    table = {"iteration_cost": 10.0, "decisions_per_step": 100.0, "window": 2, "learn_on": "planned",
             "explore": 0.0, **voc}
    return ValueOfComputationArbitrator(AgentConfig(kind="apac_voc", planning_episodes=3,
                                                    params={"voc": table, "mpc": {"iterations": 4}}))


def _voc_ctx(final: list[float], distance: list[float], episode: int = 5, zone: float = 0.5) -> ArbitrationContext:
    E = len(final)
    state = torch.zeros(E, 6)
    state[:, 0], state[:, 1], state[:, 5] = torch.tensor(distance), 1.0, 1.0  # the hand on x of the target (0, 1)
    probe = HabitProbe(value=-torch.arange(1.0, E + 1), final_distance=torch.tensor(final))
    return ArbitrationContext(episode=torch.full((E,), episode), step=torch.zeros(E, dtype=torch.long),
                              last_delta=torch.zeros(E), state=state, zone_radius=zone,
                              habit_probe=lambda: probe)


def test_the_graded_rule_plans_for_the_iterations_with_the_largest_net_gain():
    """Costs: distance x k x 10 / 100 cm. Member 0 (3 cm away: 0.3 cm an iteration) in bin 1 measured
    0.2, 1.0, 1.05, 1.3 -> nets -0.1, 0.4, 0.15, 0.1: 2 iterations. Member 1 (bin 0) measured less than its cost:
    the habit. Member 2 (bin 3) never measured k = 3: optimistic, all 4. Member 3 in the planning phase: all 4."""
    rule = _voc()
    rule.stat("gain", 4)
    rule.stats["gain"][0, 1, :4] = torch.tensor([0.2, 1.0, 1.05, 1.3])
    rule.stats["gain"][1, 0, :4] = torch.tensor([0.05, 0.1, 0.1, 0.1])
    rule.stats["gain"][2, 3, :4] = torch.tensor([0.1, 0.1, float("nan"), 0.1])
    ctx = _voc_ctx([0.7, 0.3, 3.0, 0.3], [3.0, 1.0, 1.0, 1.0])
    ctx.episode = torch.tensor([5, 3, 5, 2])  # planning_episodes 3: episode 3 is past the phase
    d = rule.use_habit(ctx)
    assert rule.bins(torch.tensor([0.7, 0.3, 3.0, 0.5, 0.2]), 0.5).tolist() == [1, 0, 3, 0, 0]
    assert d.habit.tolist() == [False, True, False, False]
    assert d.iterations.tolist() == [2, 0, 4, 4]
    assert d.inputs["expected_gain"][0].item() == pytest.approx(1.0)
    assert d.inputs["planning_cost"][0].item() == pytest.approx(0.6)
    assert d.inputs["planning_cost"][1].item() == pytest.approx(0.1)
    assert d.inputs["distance"].tolist() == pytest.approx([3.0, 1.0, 1.0, 1.0])
    assert d.inputs["habit_final_distance"].tolist() == pytest.approx([0.7, 0.3, 3.0, 0.3])
    assert d.inputs["habit_value"].tolist() == [-1.0, -2.0, -3.0, -4.0]
    assert d.inputs["iterations"].tolist() == [2.0, 0.0, 4.0, 4.0]


def test_the_graded_rule_refuses_a_planner_without_a_probe_and_more_iterations_than_its_table():
    c = _voc_ctx([1.0], [1.0])
    c.habit_probe = None
    with pytest.raises(ValueError, match=r"^the graded rule \(apac_voc\) needs a model planner's habit probe: its "
                                         r"kind's planner must be 'mpc'$"):
        _voc().use_habit(c)
    with pytest.raises(ValueError, match="at most 64 iterations; agent.mpc.iterations = 65"):
        ValueOfComputationArbitrator(AgentConfig(kind="apac_voc", params={"mpc": {"iterations": 65,
                                                                                    "candidates": 65}}))
    assert ValueOfComputationArbitrator(AgentConfig(kind="apac_voc", params={"mpc": {"iterations": 64,
                                                                                      "candidates": 64}})).K == 64


def test_a_measured_iteration_cost_is_the_ratio_of_the_measured_times_fixed_until_both_are_known():
    rule = _voc(cost="measured")
    assert rule.iteration_cost(2).tolist() == [10.0, 10.0]
    rule.stats["habit_seconds"] = torch.tensor([0.002, float("nan")])
    rule.stats["iteration_seconds"] = torch.tensor([0.03, 0.05])
    assert rule.iteration_cost(2).tolist() == pytest.approx([15.0, 10.0])
    fixed = _voc()
    fixed.stats.update(habit_seconds=torch.tensor([0.002]), iteration_seconds=torch.tensor([0.03]))
    assert fixed.iteration_cost(1).tolist() == [10.0]


def _planned(rule, final: list[float], gains, iterations: list[int], seconds: list[float],
             mask: list[bool], adapt: bool = True) -> None:
    E = len(final)
    info = SimpleNamespace(arbitration={"habit_final_distance": np.array(final)}, zone_radius=0.5,
                           plan_gains=None if gains is None else np.asarray(gains, np.float32),
                           plan_iterations=np.array(iterations), decision_seconds=np.array(seconds))
    if adapt:
        rule.observe(info, np.array(mask))  # learning is the default
    else:
        rule.observe(info, np.array(mask), adapt=False)
    del E


def test_planned_steps_teach_the_gain_table_a_running_mean_in_the_steps_bin():
    """Rate 1/2: the first measurement is the entry, the next moves it half way; NaN measurements (iterations
    not run) and masked members leave it; a frozen rule (adapt False) and a habit step (no gains) learn nothing."""
    rule = _voc()
    nan = float("nan")
    _planned(rule, [0.7, 0.7], [[1.0, 2.0, nan, nan], [5.0, 5.0, 5.0, 5.0]], [2, 4], [0.1, 0.1], [True, False])
    g = rule.stats["gain"]
    assert g[0, 1, :4].tolist()[:2] == [1.0, 2.0] and torch.isnan(g[0, 1, 2:]).all()
    assert torch.isnan(g[1]).all() and torch.isnan(g[0, 0]).all()
    _planned(rule, [0.7, 0.7], [[3.0, 0.0, 4.0, nan], [5.0] * 4], [3, 4], [0.1, 0.1], [True, False])
    assert rule.stats["gain"][0, 1, :3].tolist() == [2.0, 1.0, 4.0]
    before = rule.stats["gain"].clone()
    _planned(rule, [0.7, 0.7], [[9.0] * 4] * 2, [4, 4], [0.1, 0.1], [True, True], adapt=False)
    _planned(rule, [0.7, 0.7], None, [0, 0], [0.1, 0.1], [True, True])
    torch.testing.assert_close(rule.stats["gain"], before, equal_nan=True)


def test_the_time_statistics_learn_the_habits_time_and_each_iterations_share():
    """Habit steps (0 iterations) teach the habit's seconds; a planned step's time less the habit's, per
    iteration, teaches the iteration's (the habit's unknown counts 0)."""
    rule = _voc()
    nan = float("nan")
    _planned(rule, [0.7, 0.7], [[nan] * 4] * 2, [4, 0], [0.41, 0.01], [True, True])
    assert rule.stats["iteration_seconds"][0].item() == pytest.approx(0.41 / 4)
    assert torch.isnan(rule.stats["habit_seconds"][0]) and torch.isnan(rule.stats["iteration_seconds"][1])
    assert rule.stats["habit_seconds"][1].item() == pytest.approx(0.01)
    _planned(rule, [0.7, 0.7], [[nan] * 4] * 2, [0, 2], [0.03, 0.21], [True, True])
    assert rule.stats["habit_seconds"][0].item() == pytest.approx(0.03)
    assert rule.stats["iteration_seconds"][1].item() == pytest.approx(0.1)
    _planned(rule, [0.7, 0.7], [[nan] * 4] * 2, [0, 2], [0.05, 0.41], [False, True])
    assert rule.stats["habit_seconds"][0].item() == pytest.approx(0.03)
    assert rule.stats["iteration_seconds"][1].item() == pytest.approx(0.1 + 0.5 * (0.2 - 0.1))
    _planned(rule, [0.7, 0.7], [[nan] * 4] * 2, [1, 0], [0.23, 0.01], [True, False])  # one iteration: 0.2 s
    assert rule.stats["iteration_seconds"][0].item() == pytest.approx(0.41 / 4 + 0.5 * (0.2 - 0.41 / 4))


# -- the vision-aware rule -------------------------------------------------------------------------------------
def _vision(dark: str, ratio: float = 0.5) -> VisionAwareArbitrator:
    return VisionAwareArbitrator(AgentConfig(kind="apac_vision", params={"vision_aware": {"dark": dark,
                                                                                         "check_ratio": ratio}}),
                                 AlwaysHabit())


def test_in_the_dark_the_habit_is_suppressed():
    c = _ctx([5, 5], [3, 3], [0.0, 0.0])
    c.vision = torch.tensor([True, False])
    d = _vision("suppress").use_habit(c)
    assert d.habit.tolist() == [True, False] and d.inputs["vision"].tolist() == [1.0, 0.0]


def test_in_the_dark_the_checked_habit_acts_where_its_predicted_end_is_close_enough():
    """Hand 4 cm from the target on x, ratio 0.5: allowed in the dark where the predicted end is at most 2 cm
    away (member 1: 2 cm, at the bound), or inside the zone when that is larger (member 3: 0.6 cm from a
    0.8 cm hand, zone 0.75); member 2's 2.5 cm is not; member 0 sees and keeps the base rule's habit."""
    state = torch.zeros(4, 6)
    state[:, 0], state[:, 1], state[:, 5] = torch.tensor([4.0, 4.0, 4.0, 0.8]), 2.0, 2.0  # target (0, 2)
    predicted = torch.tensor([[9.0, 2.0], [2.0, 2.0], [2.5, 2.0], [0.6, 2.0]])
    c = ArbitrationContext(episode=torch.full((4,), 5), step=torch.full((4,), 3), last_delta=torch.zeros(4),
                           vision=torch.tensor([True, False, False, False]), state=state,
                           habit_action=predicted - state[:, :2], predict_end=lambda a: state[:, :2] + a,
                           zone_radius=0.75)
    rule = _vision("check")
    assert rule.needs_habit_action and not rule.needs_habit_probe
    d = rule.use_habit(c)
    assert d.habit.tolist() == [True, True, False, True]
    assert d.inputs["predicted_habit_distance"].tolist() == pytest.approx([9.0, 2.0, 2.5, 0.6])
    c.predict_end = None
    with pytest.raises(ValueError, match=r"^vision_aware.dark='check' needs the context's habit_action and "
                                         r"predict_end$"):
        rule.use_habit(c)
    assert not _vision("suppress").needs_habit_action


def test_the_vision_aware_rule_passes_learning_and_state_to_its_base():
    cfg = AgentConfig(kind="apac_vision", params={"voc": {"window": 2, "learn_on": "planned", "explore": 0.0},
                                                  "mpc": {"iterations": 4}})
    base = ValueOfComputationArbitrator(cfg)
    rule = VisionAwareArbitrator(cfg, base)
    assert rule.needs_habit_probe
    _planned(rule, [0.7], [[1.0, 2.0, 3.0, 4.0]], [4], [0.1], [True])
    assert base.stats["gain"][0, 1, :4].tolist() == [1.0, 2.0, 3.0, 4.0]
    saved = rule.state_dict()
    again = VisionAwareArbitrator(cfg, ValueOfComputationArbitrator(cfg))
    again.load_state_dict(saved)
    torch.testing.assert_close(again.base.stats["gain"], base.stats["gain"], equal_nan=True)
    with pytest.raises(ValueError, match=r"is itself vision-aware; name a kind with another rule \(e.g. apac\)$"):
        VisionAwareArbitrator(cfg, rule)


# -- the running-statistics rules at their strict boundaries ----------------------------------------------------
from apac_mj.agent.arbitrators import ReliabilityArbitrator, UncertaintyArbitrator  # noqa: E402


def test_the_uncertainty_rule_takes_the_habit_only_when_strictly_less_uncertain():
    """No running delta^2 yet: U_h is this episode's mean delta^2, (3^2 + 1^2) / 2 = 5; U_p = 5.5 takes the
    habit, U_p = 5 (a tie) the planner."""
    rule = UncertaintyArbitrator(AgentConfig(kind="apac_uncertainty", planning_episodes=0))
    rule.stats = {"habit_var": torch.tensor([NAN, NAN]), "planning_var": torch.tensor([5.5, 5.0])}
    c = _ctx([9, 9], [4, 4], [1.0, 1.0])
    c.recent_deltas = torch.tensor([[NAN, 3.0, -1.0], [NAN, 3.0, -1.0]])
    d = rule.use_habit(c)
    assert d.inputs["habit_uncertainty"].tolist() == [5.0, 5.0] and d.habit.tolist() == [True, False]


def _reliability() -> ReliabilityArbitrator:
    return ReliabilityArbitrator(AgentConfig(kind="apac_reliability", planning_episodes=0, delta_threshold=1.0,
                                             params={"reliability": {"window": 1}}))


def test_the_reliability_rule_counts_only_errors_strictly_below_their_bounds():
    """|delta| = 1 (the threshold) and an end error of 0.5 cm (the zone radius) are not small: window 1, so the
    reliabilities are the last step's 0 and 0; a recent delta at the threshold is not small either; P = 0.5
    plans."""
    rule = _reliability()
    rule.learn({"delta": torch.tensor([1.0, 0.5]), "end_error": torch.tensor([0.5, 0.25]),
                "zone_radius": torch.tensor(0.5)}, torch.tensor([True, True]))
    assert rule.stats["habit_reliability"].tolist() == [0.0, 1.0]
    assert rule.stats["planning_reliability"].tolist() == [0.0, 1.0]
    rule.stats["p_planning"] = torch.tensor([0.5, 0.49])
    c = _ctx([9, 9], [4, 4], [0.0, 0.0])
    c.recent_deltas = torch.tensor([[1.0], [1.0]])
    d = rule.use_habit(c)
    assert d.habit.tolist() == [False, True]
    assert d.inputs["habit_reliability"].tolist() == pytest.approx([0.0, 0.8])  # (4 x prior 1 + a 0) / 5


def test_a_frozen_reliability_rule_learns_no_reliability_but_still_moves_p():
    rule = _reliability()
    rule.stats = {"habit_reliability": torch.tensor([0.5]), "planning_reliability": torch.tensor([0.5]),
                  "p_planning": torch.tensor([1.0])}
    info = SimpleNamespace(delta=np.array([0.1]), state=np.zeros((1, 6), np.float32),
                           next_state=np.zeros((1, 6), np.float32), predicted_arm=np.zeros((1, 4), np.float32),
                           vision=np.array([True]), habit=np.array([True]), done=np.array([False]),
                           terminal=np.array([False]), episode=np.array([9]), zone_radius=0.5,
                           arbitration={"habit_reliability": np.array([1.0]), "planning_reliability": np.array([0.0])})
    rule.observe(info, np.array([True]), adapt=False)
    assert rule.stats["habit_reliability"].tolist() == [0.5] and rule.stats["planning_reliability"].tolist() == [0.5]
    assert rule.stats["p_planning"].item() < 1.0


def test_the_probability_of_planning_stays_a_probability_at_a_fast_rate():
    """Rate A = 4 with both reliabilities 0: alpha = beta = 2, so P = 1 would move to -1 and P = 0 to 2; both
    are held in [0, 1]."""
    rule = ReliabilityArbitrator(AgentConfig(kind="apac_reliability", params={"reliability": {"rate": 4.0}}))
    rule.stats = {"habit_reliability": torch.tensor([NAN, NAN]), "planning_reliability": torch.tensor([NAN, NAN]),
                  "p_planning": torch.tensor([1.0, 0.0])}
    info = SimpleNamespace(arbitration={"habit_reliability": np.zeros(2), "planning_reliability": np.zeros(2)})
    rule.observe(info, np.array([True, True]), adapt=False)
    assert rule.stats["p_planning"].tolist() == [0.0, 1.0]
