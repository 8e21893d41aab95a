"""``mpc.habit_candidates = 0``: the plan is the samples' alone (issue 41, item 4).

A point hand whose model is exact and whose habit is perfect (one step into the zone, value 0): any planner
that keeps the habit's sequence in its pool, its starting best or its refit returns the habit's action. With
``habit_candidates = 0`` the plan must be what the samples alone give, recomputed here from the member's own
random stream.
"""
from __future__ import annotations

import dataclasses

import pytest
import torch
from conftest import ExactPointHand

from apac_mj.agent.planner import MPCPlanner, _stream_seed
from apac_mj.config import AgentConfig
from apac_mj.layout import Sizes, StateLayout
from apac_mj.rules import MPCParams
from apac_mj.types import END, TARGET, ArbitrationContext

SCALE = 2.0  # cm the hand moves per unit of action (tanh units), per axis


class PerfectHabitHand(ExactPointHand):
    scale = SCALE

    """An exact model (the hand moves by ``SCALE * u``) whose habit steps straight to the target."""

    def __init__(self) -> None:
        self.cfg = dataclasses.replace(AgentConfig(), gamma=0.99)
        self.sizes = Sizes(state_dim=8, extra_scale=(1.0, 1.0))
        self.layout = StateLayout(self.sizes)

    def habit_u(self, s: torch.Tensor) -> torch.Tensor:
        return ((s[..., TARGET] - s[..., END]) / SCALE).clamp(-1.0, 1.0)

    def value(self, s: torch.Tensor) -> torch.Tensor:
        return torch.zeros(s.shape[:-1])


STATE = torch.tensor([[0.0, 0.0, 0.0, 0.0, 1.3, -0.7], [0.0, 0.0, 0.0, 0.0, -0.9, 1.1]])


def _plan(habit_candidates: int, seeds: tuple[int, ...] = (3, 4)):
    params = MPCParams(horizon=3, candidates=16, elites=1, iterations=1, habit_candidates=habit_candidates)
    planner = MPCPlanner(params, seeds=list(seeds))
    ctx = ArbitrationContext(episode=torch.zeros(2, dtype=torch.long), step=torch.zeros(2, dtype=torch.long),
                             last_delta=torch.zeros(2), state=STATE, zone_radius=0.5)
    return planner, planner.propose(PerfectHabitHand(), ctx, torch.full((2,), 1))


def _samples_alone(planner: MPCPlanner, seeds: tuple[int, ...] = (3, 4)) -> tuple[torch.Tensor, torch.Tensor]:
    """The first iteration's samples, drawn again from each member's stream, and their best by the exact model."""
    p = planner.p
    u = torch.stack([(p.max_std * torch.randn(p.candidates, p.horizon, 2,
                                              generator=torch.Generator().manual_seed(_stream_seed(s))))
                     for s in seeds]).clamp(-1.0, 1.0)
    v, _, _ = planner.rollout(PerfectHabitHand(), STATE, u)
    best = u[torch.arange(2), v.argmax(1)]
    return best, v.max(1).values


def test_the_perfect_habit_is_the_plan_when_it_is_in_the_pool():
    _, plan = _plan(habit_candidates=1)
    torch.testing.assert_close(plan.action, (STATE[:, TARGET] - STATE[:, END]))
    torch.testing.assert_close(plan.best_values[:, 0], torch.zeros(2))


def test_no_habit_candidates_plans_with_the_samples_alone():
    """Pool, starting best and refit without the habit: the action, best value and warm start are the samples'."""
    planner, plan = _plan(habit_candidates=0)
    best_u, best_v = _samples_alone(planner)
    torch.testing.assert_close(plan.best_values[:, 0], best_v)
    assert bool((plan.best_values[:, 0] < 0).all()), "no random sample lands exactly on the target"
    torch.testing.assert_close(plan.action, best_u[:, 0] * SCALE)
    # elites = 1: the refit's mean is the best sample (not the better habit), shifted one step for the warm start
    torch.testing.assert_close(planner.mean[:, :-1], best_u[:, 1:])
    torch.testing.assert_close(plan.habit_value, torch.zeros(2))  # the habit's value is still recorded


@pytest.mark.parametrize("habit_candidates", [0, 1, 3])
def test_a_member_that_does_not_plan_draws_nothing(habit_candidates):
    params = MPCParams(horizon=3, candidates=8, elites=2, iterations=2, habit_candidates=habit_candidates)
    planner = MPCPlanner(params, seeds=[3, 4])
    ctx = ArbitrationContext(episode=torch.zeros(2, dtype=torch.long), step=torch.zeros(2, dtype=torch.long),
                             last_delta=torch.zeros(2), state=STATE, zone_radius=0.5)
    before = planner.generators[1].get_state()
    plan = planner.propose(PerfectHabitHand(), ctx, torch.tensor([2, 0]))
    assert torch.equal(planner.generators[1].get_state(), before)
    assert bool(torch.isfinite(plan.best_values[0]).all()) and bool(torch.isnan(plan.best_values[1]).all())
