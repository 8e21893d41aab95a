"""The arbitration rules' gaps named by mutation testing (docs/mutation.md, issue 41): the speed-accuracy rule's
pending-transition bookkeeping, its untried drift and its recorded inputs, a loaded state's checks, and the
vision-aware rule's frozen/learning flag, each against an answer computed by hand."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from apac_mj.agent.arbitrators import SpeedAccuracyArbitrator, UncertaintyArbitrator, VisionAwareArbitrator
from apac_mj.config import AgentConfig
from apac_mj.types import HABIT_COST, PLANNING_COST

from test_arbitrators import ctx, step

HABIT, PLAN = 0, 1  # the speed-accuracy table's columns


def _rule(window: int = 1) -> SpeedAccuracyArbitrator:
    return SpeedAccuracyArbitrator(AgentConfig(kind="apac", planning_episodes=0,
                                               params={"speed_accuracy": {"window": window}}))


def test_a_pending_step_in_the_first_bin_learns_from_its_successor():
    """A planned step 0.3 cm from the target (bin 0) waits; the next, a habit step at 0.7 cm (bin 1, untried: its
    own cost 1), teaches bin 0's planning entry 3 + 1 (rate 1). Nothing else of bin 0 moves but the drift."""
    rule, one = _rule(), np.ones(1, bool)
    rule.observe(step([0.0], before=[0.3], habit=[False]), one)
    assert rule.stats["pending_bin"].item() == 0 and rule.stats["pending_controller"].item() == PLAN
    assert torch.isnan(rule.stats["table"][0, 0, PLAN])
    rule.observe(step([0.0], before=[0.7], habit=[True]), one)
    assert rule.stats["table"][0, 0, PLAN].item() == PLANNING_COST + HABIT_COST
    assert rule.stats["pending_bin"].item() == 1 and rule.stats["pending_controller"].item() == HABIT
    assert rule.stats["pending_cost"].item() == HABIT_COST


def test_without_a_pending_step_no_entry_learns_from_the_successor():
    """A fresh rule (nothing pending) sees a habit step at 3 cm: only the drift of bin 3's planning entry towards
    its own cost moves the table; the first bin's and the first column's entries stay untried (NaN)."""
    rule = _rule()
    rule.observe(step([0.0], before=[3.0], habit=[True]), np.ones(1, bool))
    table = rule.stats["table"][0]
    assert table[3, PLAN].item() == PLANNING_COST  # the untried drift of a NaN entry: its own cost
    assert torch.isnan(table[3, HABIT]) and torch.isnan(table[0]).all()
    assert int(torch.isfinite(table).sum()) == 1


def test_a_member_outside_the_mask_keeps_its_pending_step_and_table():
    """Member 1 is not stepped: its pending step (bin 5, planning, cost 3) and its table stay; member 0's episode
    ends, so its pending step is cleared to none (-1, -1, NaN)."""
    rule = _rule()
    rule.observe(step([0.0, 0.0], before=[10.0, 10.0], habit=[False, False]), np.ones(2, bool))
    before = rule.stats["table"].clone()
    rule.observe(step([0.0, 0.0], before=[3.0, 3.0], habit=[True, True], done=[True, True], terminal=[True, True]),
                 np.array([True, False]))
    assert rule.stats["pending_bin"].tolist() == [-1, 5]
    assert rule.stats["pending_controller"].tolist() == [-1, PLAN]
    assert np.isnan(rule.stats["pending_cost"][0].item()) and rule.stats["pending_cost"][1].item() == PLANNING_COST
    torch.testing.assert_close(rule.stats["table"][1], before[1], equal_nan=True)
    assert rule.stats["table"][0, 5, PLAN].item() == PLANNING_COST + HABIT_COST


def test_a_pending_habit_step_teaches_the_habit_column():
    """A habit step at 10 cm waits (controller 0); a planned step at 3 cm follows: bin 5's habit entry learns
    1 + 3 (the untried planning entry's own cost), its planning entry only drifts."""
    rule = _rule()
    one = np.ones(1, bool)
    rule.observe(step([0.0], before=[10.0], habit=[True]), one)
    assert rule.stats["pending_controller"].item() == HABIT
    rule.observe(step([0.0], before=[3.0], habit=[False]), one)
    assert rule.stats["table"][0, 5, HABIT].item() == HABIT_COST + PLANNING_COST
    assert rule.stats["table"][0, 5, PLAN].item() == PLANNING_COST  # drift of a NaN entry: planning's own cost


@pytest.mark.parametrize("habit, other, own", [(False, HABIT, HABIT_COST), (True, PLAN, PLANNING_COST)])
def test_the_untried_controller_drifts_back_to_its_own_cost_at_a_tenth_of_the_rate(habit, other, own):
    """Window 2 (rate 0.5): the entry of the controller not chosen, 9, moves 0.5 * 0.1 of the way to its own cost."""
    rule = _rule(window=2)
    table = rule.stat("table", 1)
    table[0, 3, other] = 9.0
    rule.observe(step([0.0], before=[3.0], habit=[habit]), np.ones(1, bool))
    assert rule.stats["table"][0, 3, other].item() == pytest.approx(9.0 + 0.05 * (own - 9.0))


def test_the_speed_accuracy_rule_records_its_inputs_by_name_with_a_target_off_the_origin():
    """Hand (3, 2), target (0, 2): 3 cm (bin 3), not the 5 cm to (3, 4); a learned table entry gives the gain."""
    rule = _rule()
    table = rule.stat("table", 1)
    table[0, 3, HABIT], table[0, 3, PLAN] = 7.0, 4.0
    state = torch.tensor([[3.0, 2.0, 0.0, 0.0, 0.0, 2.0]])
    d = rule.use_habit(ctx(E=1, state=state))
    assert set(d.inputs) == {"distance", "time_if_habit", "time_if_planning", "planning_gain",
                             "planning_extra_cost"}
    assert d.inputs["distance"].item() == pytest.approx(3.0)
    assert d.inputs["time_if_habit"].item() == 7.0 and d.inputs["time_if_planning"].item() == 4.0
    assert d.inputs["planning_gain"].item() == (7.0 - HABIT_COST) - (4.0 - PLANNING_COST)
    assert d.inputs["planning_extra_cost"].tolist() == [float(PLANNING_COST - HABIT_COST)]
    assert d.habit.tolist() == [False]  # a gain of 5 > the extra cost 2: plan


@pytest.mark.parametrize("state, problem", [
    ({"habit_var": torch.zeros(2, 3), "planning_var": torch.zeros(2)}, "an entry of the wrong shape"),
    ({"habit_var": torch.tensor(1.0), "planning_var": torch.tensor(2.0)}, "0-dim entries"),
    ({"habit_var": torch.zeros(2), "planning_var": torch.zeros(3)}, "two lengths"),
    ({"habit_var": torch.tensor(1.0)}, "one 0-dim entry"),
])
def test_a_loaded_state_that_only_the_shape_checks_refuse_is_refused(state, problem):
    rule = UncertaintyArbitrator(AgentConfig(kind="apac_uncertainty"))
    with pytest.raises(ValueError, match=r"UncertaintyArbitrator: statistics must be \[E, \.\.\.\] tensors of one "
                                         r"length E"):
        rule.load_state_dict(state)
    assert rule.stats == {}, problem


def test_a_well_shaped_state_loads_as_the_statistics_dtype():
    rule = SpeedAccuracyArbitrator(AgentConfig(kind="apac_speed_accuracy"))
    rule.load_state_dict({"table": torch.zeros(2, 6, 2, dtype=torch.float64),
                          "pending_bin": torch.tensor([0.0, 4.0])})
    assert rule.stats["table"].dtype == torch.float32 and rule.stats["pending_bin"].dtype == torch.int64
    assert rule.stats["pending_bin"].tolist() == [0, 4]


def test_a_frozen_vision_aware_rule_does_not_let_its_base_learn():
    """``observe(..., adapt=False)`` over a learning base (the uncertainty rule): nothing learned; with
    ``adapt=True`` the base learns delta^2 = 4."""
    cfg = AgentConfig(kind="apac_vision")
    base = UncertaintyArbitrator(cfg)
    rule = VisionAwareArbitrator(cfg, base)
    rule.observe(step([2.0]), np.ones(1, bool), adapt=False)
    assert base.stats == {}
    rule.observe(step([2.0]), np.ones(1, bool), adapt=True)
    assert base.stats["habit_var"].item() == 4.0


def test_each_members_distance_is_its_own_and_an_untried_entry_is_its_controllers_cost():
    """Two members: hand 3 cm (bin 3) and 10 cm (bin 5) from targets off the origin, each its own distance (not one
    norm over the batch). Member 0's planning entry is untried (NaN): it counts as planning's cost 3, while its
    habit entry, 4, is learned (so a gain of (4 - 1) - (3 - 3) = 3 > 2: plan); member 1's habit entry is untried:
    the habit's cost 1 against a learned 6 for planning: a negative gain, the habit acts."""
    rule = _rule()
    table = rule.stat("table", 2)
    table[0, 3, HABIT], table[1, 5, PLAN] = 4.0, 6.0
    state = torch.tensor([[3.0, 2.0, 0.0, 0.0, 0.0, 2.0], [1.0, 11.0, 0.0, 0.0, 1.0, 1.0]])
    d = rule.use_habit(ctx(E=2, state=state))
    assert d.inputs["distance"].tolist() == pytest.approx([3.0, 10.0])
    assert d.inputs["time_if_habit"].tolist() == [4.0, float(HABIT_COST)]
    assert d.inputs["time_if_planning"].tolist() == [float(PLANNING_COST), 6.0]
    assert d.inputs["planning_gain"].tolist() == [3.0, -3.0]
    assert d.habit.tolist() == [False, True]
