"""The arbitrator: which controller acts, the actor (habit) or the inverse model (planning).

Modes (``AgentConfig.agent``):

* ``ddpg``: always the actor (exclusive habits, APAC == DDPG);
* ``spac``: always the inverse model (exclusive planning);
* ``apac``: the inverse model during the first ``planning_episodes`` (100)
  training episodes; after that the actor on the first ``habit_first_steps``
  (2) steps of each episode, then the actor if ``|delta|`` (``delta_rule="abs"``)
  or ``delta`` (``"signed"``, Algorithm 2's "RPE < 1") of the member's last
  transition is below ``delta_threshold`` (1), else the inverse model.
  A NaN delta (no last transition) counts as unreliable.
"""
from __future__ import annotations

import torch

from apac_mj.config import AGENTS, AgentConfig


class Arbitrator:
    """Decides per member whether the habit (actor) acts."""

    def __init__(self, cfg: AgentConfig) -> None:
        if cfg.agent not in AGENTS:
            raise ValueError(f"arbitrator mode must be one of {AGENTS}, got {cfg.agent!r}")
        self.mode = cfg.agent
        self.planning_episodes = cfg.planning_episodes
        self.habit_first_steps = cfg.habit_first_steps
        self.delta_threshold = cfg.delta_threshold
        self.delta_rule = cfg.delta_rule

    def use_habit(self, episode: torch.Tensor, step: torch.Tensor, last_delta: torch.Tensor) -> torch.Tensor:
        """``[E]`` training episode (0-based), step in episode (0-based), last |delta| -> ``[E]`` bool."""
        episode, step = torch.as_tensor(episode), torch.as_tensor(step)
        last_delta = torch.as_tensor(last_delta, dtype=torch.float32)
        if not (episode.shape == step.shape == last_delta.shape) or episode.dim() != 1:
            raise ValueError("episode, step and last_delta must be 1-D tensors of equal length [E], got "
                             f"{tuple(episode.shape)}, {tuple(step.shape)}, {tuple(last_delta.shape)}")
        if self.mode == "ddpg":
            return torch.ones(episode.shape, dtype=torch.bool, device=episode.device)
        if self.mode == "spac":
            return torch.zeros(episode.shape, dtype=torch.bool, device=episode.device)
        signal = last_delta.abs() if self.delta_rule == "abs" else last_delta
        reliable = signal.to(episode.device) < self.delta_threshold
        habit = (step < self.habit_first_steps) | reliable
        return habit & (episode >= self.planning_episodes)
