"""The arbitrator: which controller acts, the actor (habit) or the inverse model (planning).

An arbitrator implements one method, ``use_habit(ctx) -> [E] bool``, over an
:class:`ArbitrationContext`: everything a rule may look at for each member at
this step (episode, step, the last and the recent TD errors, vision, the
forward model's recent error, the agent's uncertainty estimates where it has
them). The episode loop (:mod:`apac_mj.rollout`) builds the context; a new rule
is a new class, registered with an agent kind (:mod:`apac_mj.kinds`).

The built-in rules (the kinds ``ddpg``, ``spac`` and ``apac``):

* :class:`AlwaysHabit`: always the actor (exclusive habits, APAC == DDPG);
* :class:`AlwaysPlan`: always the inverse model (exclusive planning);
* :class:`DeltaArbitrator` (APAC): the inverse model during the first
  ``planning_episodes`` (100) training episodes; after that the actor on the
  first ``habit_first_steps`` (2) steps of each episode, then the actor if
  ``|delta|`` (``delta_rule="abs"``) or ``delta`` (``"signed"``, Algorithm 2's
  "RPE < 1") of the member's last transition is below ``delta_threshold`` (1),
  else the inverse model. A NaN delta (no last transition) counts as unreliable.
"""
from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Protocol

import numpy as np
import torch

if TYPE_CHECKING:
    from apac_mj.config import AgentConfig

#: TD errors of the member's last transitions kept in :attr:`ArbitrationContext.recent_deltas`.
HISTORY = 8


@dataclasses.dataclass
class ArbitrationContext:
    """What an arbitrator sees at one step, member-batched ``[E]`` (CPU tensors except ``state``).

    Members that do not step this time have stale rows; their decision is ignored.
    """

    #: Training episode (0-based; babbling negative) as the arbitrator is to read it.
    episode: torch.Tensor
    #: Step within the episode (0-based).
    step: torch.Tensor
    #: TD error of the member's last transition (float32; NaN: none yet this episode).
    last_delta: torch.Tensor
    #: ``[E, HISTORY]`` TD errors of this episode's last transitions, oldest first, NaN-padded on the left.
    recent_deltas: torch.Tensor | None = None
    #: True where the state the agent acts on was seen (always at an episode's start).
    vision: torch.Tensor | None = None
    #: Forward model's error (cm, Euclidean over end and elbow) at the member's last seen step; NaN: none yet.
    forward_error: torch.Tensor | None = None
    #: The integrator's state the agent acts on ``[E, 6]`` (on the agent's device); None if not given.
    state: torch.Tensor | None = None
    #: The agent's per-member uncertainty estimates ``name -> [E]`` (empty when the agent has none).
    uncertainty: dict[str, torch.Tensor] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        self.episode, self.step = torch.as_tensor(self.episode), torch.as_tensor(self.step)
        self.last_delta = torch.as_tensor(self.last_delta, dtype=torch.float32)
        if not (self.episode.shape == self.step.shape == self.last_delta.shape) or self.episode.dim() != 1:
            raise ValueError("episode, step and last_delta must be 1-D tensors of equal length [E], got "
                             f"{tuple(self.episode.shape)}, {tuple(self.step.shape)}, {tuple(self.last_delta.shape)}")
        E = len(self.episode)
        nan = torch.full((E,), float("nan"))
        self.recent_deltas = (self.last_delta[:, None] if self.recent_deltas is None
                              else torch.as_tensor(self.recent_deltas, dtype=torch.float32))
        self.vision = torch.ones(E, dtype=torch.bool) if self.vision is None else torch.as_tensor(self.vision)
        self.forward_error = nan if self.forward_error is None else torch.as_tensor(self.forward_error,
                                                                                   dtype=torch.float32)
        for name in ("vision", "forward_error"):
            if tuple(getattr(self, name).shape) != (E,):
                raise ValueError(f"{name} must have shape ({E},), got {tuple(getattr(self, name).shape)}")
        if self.recent_deltas.dim() != 2 or len(self.recent_deltas) != E:
            raise ValueError(f"recent_deltas must have shape ({E}, H), got {tuple(self.recent_deltas.shape)}")

    @property
    def E(self) -> int:
        return len(self.episode)


class Arbitrator(Protocol):
    """Decides per member whether the habit (actor) acts; ``False``: the planner (inverse model)."""

    def use_habit(self, ctx: ArbitrationContext) -> torch.Tensor:
        """``[E]`` bool: True where the actor acts."""
        ...


class AlwaysHabit:
    """Exclusive habits: the actor always acts (DDPG)."""

    def __init__(self, cfg: AgentConfig | None = None) -> None:
        del cfg  # no parameters

    def use_habit(self, ctx: ArbitrationContext) -> torch.Tensor:
        return torch.ones(ctx.E, dtype=torch.bool)


class AlwaysPlan:
    """Exclusive planning: the inverse model always acts (SPAC)."""

    def __init__(self, cfg: AgentConfig | None = None) -> None:
        del cfg  # no parameters

    def use_habit(self, ctx: ArbitrationContext) -> torch.Tensor:
        return torch.zeros(ctx.E, dtype=torch.bool)


class DeltaArbitrator:
    """APAC's rule: planning phase, then the habit on the first steps and where the last delta is small."""

    def __init__(self, cfg: AgentConfig) -> None:
        self.planning_episodes = cfg.planning_episodes
        self.habit_first_steps = cfg.habit_first_steps
        self.delta_threshold = cfg.delta_threshold
        self.delta_rule = cfg.delta_rule

    def use_habit(self, ctx: ArbitrationContext) -> torch.Tensor:
        signal = ctx.last_delta.abs() if self.delta_rule == "abs" else ctx.last_delta
        reliable = signal.to(ctx.episode.device) < self.delta_threshold
        habit = (ctx.step < self.habit_first_steps) | reliable
        return habit & (ctx.episode >= self.planning_episodes)


def push_delta(history: np.ndarray, delta: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``history`` ``[E, H]`` with ``delta`` appended (oldest dropped) for the members in ``mask``."""
    shifted = np.concatenate([history[:, 1:], np.asarray(delta, dtype=history.dtype)[:, None]], axis=1)
    return np.where(np.asarray(mask)[:, None], shifted, history)
