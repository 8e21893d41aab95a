"""The integrator: the state estimate the agent acts and learns on.

With vision, the observed arm position passes through; with occluded vision,
the forward model's prediction becomes the position (chained step to step by
feeding the result back as the next "observed" state for occluded members).
"""
from __future__ import annotations

import torch


def integrate(observed: torch.Tensor, predicted: torch.Tensor, vision: torch.Tensor) -> torch.Tensor:
    """``[E,4]`` observed [end, elbow], ``[E,4]`` forward-model prediction, ``[E]`` bool -> ``[E,4]``."""
    vision = torch.as_tensor(vision, dtype=torch.bool, device=observed.device)
    if observed.shape != predicted.shape or observed.dim() != 2:
        raise ValueError(f"observed and predicted must both be [E, 4], got {tuple(observed.shape)} "
                         f"and {tuple(predicted.shape)}")
    if vision.shape != observed.shape[:1]:
        raise ValueError(f"vision must be [E]={observed.shape[0]} bools, got {tuple(vision.shape)}")
    return torch.where(vision[:, None], observed, predicted)
