"""Ornstein-Uhlenbeck exploration noise, one independent process per member.

``x <- x + theta * (mu - x) + sigma * N(0, 1)`` per step (dt = 1 step), in
degrees, added to both proposals (actor and inverse model) as in DDPG.
This discretisation is the AR(1) process ``x_{t+1} = (1 - theta) x_t + sigma eps``, whose
stationary standard deviation is ``sigma / sqrt(1 - (1 - theta)^2) = sigma / sqrt(theta * (2 - theta))``:
``1.898 * sigma`` for theta = 0.15 (the continuous-time ``sigma / sqrt(2 theta)`` = 1.83 sigma
does not apply at dt = 1). From a reset to mu the standard deviation after t steps is
``sigma * sqrt((1 - (1 - theta)^(2 t)) / (theta * (2 - theta)))``: 96% of the stationary value
after 8 steps, 99.6% after 15 (an episode has 30).
"""
from __future__ import annotations

from typing import Sequence

import torch


class OUNoise:
    """E independent OU processes of dimension ``dim``, each with its own generator."""

    def __init__(self, generators: Sequence[torch.Generator], dim: int = 2, theta: float = 0.15,
                 sigma: float = 2.0, mu: float = 0.0, device: str | torch.device = "cpu") -> None:
        if not 0 < theta <= 1:
            raise ValueError(f"OU theta must be in (0, 1], got {theta}")
        if sigma < 0:
            raise ValueError(f"OU sigma must be >= 0 (degrees), got {sigma}")
        self.generators = list(generators)
        self.E, self.dim = len(self.generators), dim
        self.theta, self.sigma, self.mu = theta, sigma, mu
        self.device = torch.device(device)
        self.x = torch.full((self.E, dim), float(mu))

    def reset(self, mask: torch.Tensor | Sequence[bool] | None = None) -> None:
        """Reset the processes of members with ``mask`` (all if None) to ``mu``."""
        m = torch.ones(self.E, dtype=torch.bool) if mask is None else torch.as_tensor(mask).cpu().bool()
        if m.shape != (self.E,):
            raise ValueError(f"mask must have shape ({self.E},), got {tuple(m.shape)}")
        self.x[m] = self.mu

    def sample(self, mask: torch.Tensor | Sequence[bool] | None = None,
               sigma: Sequence[float] | None = None) -> torch.Tensor:
        """Advance members with ``mask`` (all if None) one step; return the state ``[E, dim]``.

        ``sigma`` (``[E]``, degrees) replaces the constant ``self.sigma`` for this step (annealing)."""
        m = [True] * self.E if mask is None else torch.as_tensor(mask).cpu().bool().tolist()
        if len(m) != self.E:
            raise ValueError(f"mask must have {self.E} entries, got {len(m)}")
        sig = [self.sigma] * self.E if sigma is None else [float(v) for v in sigma]
        for k, on in enumerate(m):
            if on:
                eps = torch.randn(self.dim, generator=self.generators[k])
                self.x[k] += self.theta * (self.mu - self.x[k]) + sig[k] * eps
        return self.x.to(self.device, copy=True)

    def state_dict(self) -> dict:
        return {"x": self.x.clone(), "generators": [g.get_state() for g in self.generators]}

    def load_state_dict(self, d: dict) -> None:
        if len(d["generators"]) != self.E:
            raise ValueError(f"noise state has {len(d['generators'])} members, expected {self.E}")
        self.x.copy_(d["x"])
        for g, s in zip(self.generators, d["generators"]):
            g.set_state(s)
