"""The arbitrator: which controller acts, the actor (habit) or the inverse model (planning).

An arbitrator (:class:`apac_mj.types.Arbitrator`) implements one method,
``use_habit(ctx) -> Decision``, over an :class:`~apac_mj.types.ArbitrationContext`:
everything a rule may look at for each member at this step (episode, step, the
last and the recent TD errors, vision, the forward model's recent error, the
state and the proposals). The :class:`~apac_mj.types.Decision` holds where the
habit acts and the inputs it was decided on (recordings show them per step).
The episode loop (:mod:`apac_mj.run.rollout`) builds the context; a new rule
is a new subclass, registered with an agent kind (:mod:`apac_mj.kinds`).

The paper's rules (the kinds ``ddpg``, ``spac`` and ``apac``), here with the
helpers the rules share:

* :class:`AlwaysHabit`: always the actor (exclusive habits, APAC == DDPG);
* :class:`AlwaysPlan`: always the inverse model (exclusive planning);
* :class:`DeltaArbitrator` (APAC): the inverse model during the first
  ``planning_episodes`` (100) training episodes; after that the actor on the
  first ``habit_first_steps`` (2) steps of each episode, then the actor if
  ``|delta|`` (``delta_rule="abs"``) or ``delta`` (``"signed"``, Algorithm 2's
  "RPE < 1") of the member's last transition is below ``delta_threshold`` (1),
  else the inverse model. A NaN delta (no last transition) counts as unreliable.

The four rules beyond the paper are in :mod:`apac_mj.agent.arbitrators`.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch

from apac_mj.types import END, HABIT_COST, PLANNING_COST, TARGET, ArbitrationContext, Arbitrator, Decision, StepInfo

if TYPE_CHECKING:
    from apac_mj.config import AgentConfig

#: TD errors of the member's last transitions kept in :attr:`ArbitrationContext.recent_deltas`.
HISTORY = 8


class AlwaysHabit(Arbitrator):
    """Exclusive habits: the actor always acts (DDPG)."""

    def __init__(self, cfg: AgentConfig | None = None) -> None:
        del cfg  # no parameters

    def use_habit(self, ctx: ArbitrationContext) -> Decision:
        return Decision(torch.ones(ctx.E, dtype=torch.bool))


class AlwaysPlan(Arbitrator):
    """Exclusive planning: the inverse model always acts (SPAC)."""

    def __init__(self, cfg: AgentConfig | None = None) -> None:
        del cfg  # no parameters

    def use_habit(self, ctx: ArbitrationContext) -> Decision:
        return Decision(torch.zeros(ctx.E, dtype=torch.bool))


class DeltaArbitrator(Arbitrator):
    """APAC's rule: planning phase, then the habit on the first steps and where the last delta is small."""

    reads_last_delta = True

    def __init__(self, cfg: AgentConfig) -> None:
        self.planning_episodes = cfg.planning_episodes
        self.habit_first_steps = cfg.habit_first_steps
        self.delta_threshold = cfg.delta_threshold
        self.delta_rule = cfg.delta_rule

    def use_habit(self, ctx: ArbitrationContext) -> Decision:
        signal = ctx.last_delta.abs() if self.delta_rule == "abs" else ctx.last_delta
        reliable = signal.to(ctx.episode.device) < self.delta_threshold
        habit = (ctx.step < self.habit_first_steps) | reliable
        # what is compared with the threshold, named as it is compared: |delta| (rule "abs") or delta ("signed")
        inputs = {"abs_delta" if self.delta_rule == "abs" else "delta": signal.float(),
                  "threshold": torch.full((ctx.E,), float(self.delta_threshold))}
        return Decision(habit & (ctx.episode >= self.planning_episodes), inputs)


# -- shared by the rules with running statistics ------------------------------------------------
def ema(old: torch.Tensor, new: torch.Tensor, rate: float, mask: torch.Tensor) -> torch.Tensor:
    """Running mean per member: ``new`` where ``old`` is NaN (the first sample), else
    ``old + rate (new - old)``; only where ``mask`` and ``new`` is finite."""
    updated = torch.where(torch.isnan(old), new, old + rate * (new - old))
    return torch.where(mask & torch.isfinite(new), updated, old)


def blend(prior: torch.Tensor, samples: torch.Tensor, weight: float) -> torch.Tensor:
    """``(weight * prior + sum(samples)) / (weight + n)`` per member over the finite ``samples`` ``[E, H]``
    (this episode's evidence shrunk towards the running statistic ``prior`` ``[E]``; NaN prior: weight 0)."""
    finite = torch.isfinite(samples)
    n, total = finite.sum(dim=1).float(), torch.where(finite, samples, 0.0).sum(dim=1)
    w = torch.where(torch.isfinite(prior), torch.full_like(prior, weight), 0.0)
    return (w * torch.nan_to_num(prior) + total) / (w + n)  # 0/0 = NaN: no evidence at all


def step_signals(info: StepInfo) -> dict[str, torch.Tensor]:
    """What the running statistics learn from one :class:`~apac_mj.types.StepInfo` (``[E]`` each):
    the TD error, the forward model's end-effector error where the arm was seen (NaN elsewhere), the
    estimated distance to the target before and after the step, the step's time cost, the controller,
    the zone radius the step was judged by (0-dim)."""
    state, nxt = torch.as_tensor(info.state), torch.as_tensor(info.next_state)
    vision = torch.as_tensor(info.vision)
    end_error = torch.linalg.vector_norm(torch.as_tensor(info.predicted_arm)[:, END] - nxt[:, END], dim=1)
    habit = torch.as_tensor(info.habit)
    return {"delta": torch.as_tensor(info.delta, dtype=torch.float32),
            "end_error": torch.where(vision, end_error, float("nan")).float(),
            "before": torch.linalg.vector_norm(state[:, END] - state[:, TARGET], dim=1).float(),
            "after": torch.linalg.vector_norm(nxt[:, END] - nxt[:, TARGET], dim=1).float(),
            "cost": torch.where(habit, float(HABIT_COST), float(PLANNING_COST)), "habit": habit,
            "done": torch.as_tensor(info.done), "terminal": torch.as_tensor(info.terminal),
            "episode": torch.as_tensor(info.episode), "zone_radius": torch.tensor(float(info.zone_radius))}


def push_delta(history: np.ndarray, delta: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``history`` ``[E, H]`` with ``delta`` appended (oldest dropped) for the members in ``mask``."""
    shifted = np.concatenate([history[:, 1:], np.asarray(delta, dtype=history.dtype)[:, None]], axis=1)
    return np.where(np.asarray(mask)[:, None], shifted, history)
