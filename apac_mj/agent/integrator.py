"""The integrator: the state estimate the agent acts and learns on.

The integrator estimates the positions ``[end_x, end_y, elbow_x, elbow_y, target_x, target_y]`` (cm), the
state's first :data:`~apac_mj.types.POSITION_DIM` columns, read through :mod:`apac_mj.types`' names
(``ARM`` = [end, elbow], ``TARGET``); the covariance ``P`` has the same layout.

:func:`integrate` and :class:`PassThrough` are the paper's integrator: with
vision the observed arm position passes through; without it (occluded or an
unseen intermittent step) the forward model's prediction becomes the position
(chained step to step by feeding the result back as the next prior); the
target is the observed one when seen, else the remembered one.

:class:`KalmanIntegrator` fuses both when the observations are noisy: an
independent scalar Kalman filter per coordinate (diagonal covariance
``P [E, 6]``). Per step, with ``x`` the estimate the agent acted on:

* predict: arm ``x- = f(x, a)`` (the forward model's prediction),
  ``P- = P + q``; target ``x- = x``, ``P- = P`` (the target is still
  within an episode);
* correct, where seen: ``K = P- / (P- + R)`` (``K = 1`` where
  ``P- + R == 0``), ``x = (1 - K) x- + K y``, ``P = (1 - K) P-``;
  where not seen ``x = x-``, ``P = P-``.

``R = obs_std^2`` is the observation noise variance (the task's
``vision_noise_std``); ``q [E, 4]`` is the process noise variance, i.e. the
forward model's own error variance per coordinate. With ``obs_std = 0`` every
seen step has ``K = 1`` and the filter returns the pass-through's numbers
exactly. An episode starts (:meth:`KalmanIntegrator.reset`) from the first,
itself noisy, observation: ``x = y``, ``P = R``.

``q`` is estimated online from the innovations ``nu = y_arm - f(x, a)`` of
the seen steps (R. Mehra 1970, "On the identification of variances and
adaptive Kalman filtering", IEEE Trans. Automatic Control 15(2)): their
variance is ``E[nu^2] = P + q + R`` (``P`` before the prediction), so
``q = max(EMA(nu^2) - EMA(P + R), process_floor)``, with exponential moving
averages of rate ``1/window`` per member and coordinate (a plain running mean
for the first ``window`` innovations). Before a member's first innovation
``q = initial_process_var``. The averages persist across episodes (not reset
by :meth:`~KalmanIntegrator.reset`) and travel in ``state_dict()``. The
estimate's standard deviation is about ``(P + q + R) / sqrt(window)`` per
member and coordinate, so it pins ``q`` down only where ``q`` is not much
smaller than ``R / sqrt(window)``: with ``R = q = 0.05^2`` it is within ~20%
after a few hundred steps; with ``R = 0.5^2, q = 0.05^2`` its spread
(~0.02) is several times ``q`` itself, and the floor catches the negative
draws (tests/test_integrator.py measures both).

Both subclass :class:`apac_mj.types.Integrator` (``reset``, ``update``,
``state_dict``, ``load_state_dict``, ``adapt``) and add ``variance``; the
estimate itself is carried by the caller (``prior_state`` in, next estimate
out). The Kalman filter's parameters are the table ``agent.kalman``
(:class:`apac_mj.rules.KalmanParams`). Both are registered integrators (:mod:`apac_mj.systems`:
``"pass_through"`` and ``"kalman"``), chosen by ``AgentConfig.integrator``.
"""
from __future__ import annotations

import math

import numpy as np
import torch

from apac_mj.types import ARM, POSITION_DIM, TARGET, Integrator


def integrate(observed: torch.Tensor, predicted: torch.Tensor, vision: torch.Tensor) -> torch.Tensor:
    """``[E,4]`` observed [end, elbow], ``[E,4]`` forward-model prediction, ``[E]`` bool -> ``[E,4]``."""
    vision = torch.as_tensor(vision, dtype=torch.bool, device=observed.device)
    if observed.shape != predicted.shape or observed.dim() != 2:
        raise ValueError(f"observed and predicted must both be [E, 4], got {tuple(observed.shape)} "
                         f"and {tuple(predicted.shape)}")
    if vision.shape != observed.shape[:1]:
        raise ValueError(f"vision must be [E]={observed.shape[0]} bools, got {tuple(vision.shape)}")
    return torch.where(vision[:, None], observed, predicted)


def _mask(m: np.ndarray | torch.Tensor, E: int, device: torch.device, name: str) -> torch.Tensor:
    """``m`` (numpy or torch) as an ``[E]`` bool tensor on ``device``; ValueError naming ``name`` otherwise."""
    t = torch.as_tensor(np.asarray(m) if not isinstance(m, torch.Tensor) else m, device=device)
    if t.dtype != torch.bool or tuple(t.shape) != (E,):
        raise ValueError(f"{name} must be [E] = ({E},) bools, got dtype {t.dtype} and shape {tuple(t.shape)}")
    return t


def _check(t: torch.Tensor, shape: tuple[int, ...], name: str) -> None:
    if not isinstance(t, torch.Tensor) or tuple(t.shape) != shape:
        got = tuple(t.shape) if isinstance(t, torch.Tensor) else type(t).__name__
        raise ValueError(f"{name} must be a tensor of shape {shape}, got {got}")


def _inputs(E: int, prior_state: torch.Tensor, predicted_arm: torch.Tensor, observed_state: torch.Tensor,
            vision: np.ndarray | torch.Tensor, active: np.ndarray | torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The shapes of an update's inputs checked; ``vision`` and ``active`` as ``[E]`` bool tensors."""
    _check(prior_state, (E, POSITION_DIM), "prior_state")
    _check(predicted_arm, (E, 4), "predicted_arm")
    _check(observed_state, (E, POSITION_DIM), "observed_state")
    return _mask(vision, E, prior_state.device, "vision"), _mask(active, E, prior_state.device, "active")


class PassThrough(Integrator):
    """The paper's integrator: the seen position if seen, else the forward model's prediction."""

    name = "pass_through"

    def reset(self, mask: np.ndarray | torch.Tensor, seen_state: torch.Tensor) -> None:
        """Start new episodes for the members in ``mask`` ``[E]`` from ``seen_state`` ``[E, 6]`` (checks only)."""
        _mask(mask, self.E, self.device, "mask")
        _check(seen_state, (self.E, POSITION_DIM), "seen_state")

    def update(self, prior_state: torch.Tensor, predicted_arm: torch.Tensor, observed_state: torch.Tensor,
               vision: np.ndarray | torch.Tensor, active: np.ndarray | torch.Tensor) -> torch.Tensor:
        """The next estimate ``[E, 6]``: arm observed if seen else predicted, target observed if seen else
        the prior's; rows of inactive members are ``prior_state``'s."""
        vision, active = _inputs(self.E, prior_state, predicted_arm, observed_state, vision, active)
        arm = integrate(observed_state[:, ARM], predicted_arm, vision)
        target = torch.where(vision[:, None], observed_state[:, TARGET], prior_state[:, TARGET])
        return torch.where(active[:, None], torch.cat([arm, target], dim=1), prior_state)

    def variance(self) -> torch.Tensor:
        """``[E, 6]`` per-coordinate variance of the estimate: none is modelled, zeros."""
        return torch.zeros(self.E, POSITION_DIM, device=self.device)


class KalmanIntegrator(Integrator):
    """Per-coordinate scalar Kalman filters with an adaptive (Mehra) process variance; module doc."""

    name = "kalman"
    _KEYS = {"P": POSITION_DIM, "ema_innovation_sq": 4, "ema_prior_var": 4, "count": 0}

    def __init__(self, E: int, obs_std: float, process_floor: float = 1e-4, window: int = 200,
                 initial_process_var: float = 0.25, device: torch.device | str = "cpu",
                 process_var: float | None = None) -> None:
        """``obs_std``: std (cm) of the observation noise; ``process_var``: a fixed ``q`` (None: adaptive)."""
        super().__init__(E, device)
        for key, value, lowest in (("obs_std", obs_std, 0.0), ("process_floor", process_floor, 0.0),
                                   ("initial_process_var", initial_process_var, 0.0)):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                    or value < lowest:
                raise ValueError(f"{key} must be a finite number >= {lowest}, got {value!r}")
        if process_var is not None and (not math.isfinite(process_var) or process_var < 0):
            raise ValueError(f"process_var must be None (adaptive) or a finite number >= 0, got {process_var!r}")
        if not isinstance(window, int) or isinstance(window, bool) or window < 1:
            raise ValueError(f"window must be an int >= 1, got {window!r}")
        self.obs_std, self.R = float(obs_std), float(obs_std) ** 2
        self.process_floor, self.window, self.initial_process_var = float(process_floor), window, \
            float(initial_process_var)
        self.process_var = None if process_var is None else float(process_var)
        dev = self.device
        self.P = torch.full((E, POSITION_DIM), self.R, device=dev)
        self.ema_innovation_sq = torch.zeros(E, 4, device=dev)
        self.ema_prior_var = torch.zeros(E, 4, device=dev)
        self.count = torch.zeros(E, dtype=torch.int64, device=dev)

    def reset(self, mask: np.ndarray | torch.Tensor, seen_state: torch.Tensor) -> None:
        """``P = R`` for the members in ``mask`` (their estimate is ``seen_state``, the caller's); the
        innovation averages are kept."""
        rows = _mask(mask, self.E, self.device, "mask")
        _check(seen_state, (self.E, POSITION_DIM), "seen_state")
        self.P = torch.where(rows[:, None], torch.full_like(self.P, self.R), self.P)

    def q(self) -> torch.Tensor:
        """``[E, 4]`` the process variance the next prediction adds."""
        if self.process_var is not None:
            return torch.full_like(self.ema_innovation_sq, self.process_var)
        adaptive = (self.ema_innovation_sq - self.ema_prior_var).clamp_min(self.process_floor)
        return torch.where(self.count[:, None] > 0, adaptive, torch.full_like(adaptive, self.initial_process_var))

    def update(self, prior_state: torch.Tensor, predicted_arm: torch.Tensor, observed_state: torch.Tensor,
               vision: np.ndarray | torch.Tensor, active: np.ndarray | torch.Tensor) -> torch.Tensor:
        """Predict and correct (module doc); returns the next estimate ``[E, 6]``, inactive rows unchanged."""
        vision, active = _inputs(self.E, prior_state, predicted_arm, observed_state, vision, active)
        dev = self.device
        vision, active = vision.to(dev), active.to(dev)
        seen = vision & active
        prior, predicted, obs = (t.to(dev) for t in (prior_state, predicted_arm, observed_state))
        x_minus = torch.cat([predicted, prior[:, TARGET]], dim=1)
        q = self.q()
        p_minus = torch.cat([self.P[:, ARM] + q, self.P[:, TARGET]], dim=1)
        self._learn_q(seen, obs[:, ARM] - predicted)
        denom = p_minus + self.R
        gain = torch.where(denom == 0, torch.ones_like(denom), p_minus / torch.where(denom == 0, 1.0, denom))
        gain = torch.where(seen[:, None], gain, torch.zeros_like(gain))
        k = gain.to(x_minus.dtype)  # the convex form is exact at K = 1: (1 - 1) x- + 1 y = y
        x = torch.where(seen[:, None], (1 - k) * x_minus + k * obs.to(x_minus.dtype), x_minus)
        self.P = torch.where(active[:, None], (1 - gain) * p_minus, self.P)
        return torch.where(active[:, None].to(prior_state.device), x.to(prior_state.device), prior_state)

    def _learn_q(self, seen: torch.Tensor, innovation: torch.Tensor) -> None:
        """Fold this step's innovations of the ``seen`` members into the averages (``P`` is the pre-prediction one;
        not when frozen: ``adapt`` False)."""
        if self.process_var is not None or not self.adapt:
            return
        self.count = self.count + seen.long()
        rate = (1.0 / self.count.clamp(min=1, max=self.window).to(self.P.dtype))[:, None]
        rows = seen[:, None]
        nu2 = innovation.to(self.P.dtype) ** 2
        self.ema_innovation_sq = torch.where(rows, self.ema_innovation_sq + rate * (nu2 - self.ema_innovation_sq),
                                             self.ema_innovation_sq)
        prior_var = self.P[:, ARM] + self.R
        self.ema_prior_var = torch.where(rows, self.ema_prior_var + rate * (prior_var - self.ema_prior_var),
                                         self.ema_prior_var)

    def variance(self) -> torch.Tensor:
        """``[E, 6]`` the current per-coordinate variance ``P`` of the estimate."""
        return self.P.clone()

    def state_dict(self) -> dict[str, torch.Tensor]:
        """``P``, the innovation averages and counts: plain CPU tensors (``torch.load(weights_only=True)``)."""
        return {key: getattr(self, key).detach().cpu().clone() for key in self._KEYS}

    def load_state_dict(self, d: dict[str, torch.Tensor]) -> None:
        """Restore :meth:`state_dict`'s output; ValueError naming a missing/unknown key or a bad shape."""
        if set(d) != set(self._KEYS):
            raise ValueError(f"KalmanIntegrator state needs keys {sorted(self._KEYS)}, got {sorted(d)}")
        loaded = {}
        for key, width in self._KEYS.items():
            want = (self.E, width) if width else (self.E,)
            t = d[key]
            if not isinstance(t, torch.Tensor) or tuple(t.shape) != want:
                got = tuple(t.shape) if isinstance(t, torch.Tensor) else type(t).__name__
                raise ValueError(f"KalmanIntegrator state {key!r} must have shape {want}, got {got}")
            loaded[key] = t.to(self.device, getattr(self, key).dtype).clone()
        for key, t in loaded.items():
            setattr(self, key, t)
