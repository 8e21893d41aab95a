"""EnsembleAdam: Adam over ``[E, ...]`` parameters, one independent optimizer per member.

Semantics per member are exactly ``torch.optim.Adam(lr, betas, eps,
weight_decay)`` (L2 added to the gradient, not decoupled): each member keeps
its own step count (bias correction) and moments. ``step(grads, active)``
touches only members with ``active[k]``: the params, moments and step counts
of the others stay bit-identical.

The work is done by PyTorch's fused multi-tensor Adam kernel on per-member
views (``tensor[k]``), so no Python loop runs over elements and inactive
members are simply left out of the call.
"""
from __future__ import annotations

from typing import Sequence

import torch


class EnsembleAdam:
    """Adam with L2 for E independent members; ``groups`` = [(params, lr), ...]."""

    def __init__(self, groups: Sequence[tuple[Sequence[torch.Tensor], float]],
                 betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8,
                 weight_decay: float = 0.0) -> None:
        if not groups or not all(params for params, _ in groups):
            raise ValueError("EnsembleAdam needs at least one non-empty parameter group")
        self.params = [[p for p in params] for params, _ in groups]
        self.lrs = [float(lr) for _, lr in groups]
        if any(lr <= 0 for lr in self.lrs):
            raise ValueError(f"learning rates must be > 0, got {self.lrs}")
        E = self.params[0][0].shape[0]
        if any(p.shape[0] != E for ps in self.params for p in ps):
            raise ValueError("all parameters must share the leading ensemble dimension E")
        self.E, self.betas, self.eps, self.weight_decay = E, betas, eps, weight_decay
        device = self.params[0][0].device
        self.exp_avg = [[torch.zeros_like(p) for p in ps] for ps in self.params]
        self.exp_avg_sq = [[torch.zeros_like(p) for p in ps] for ps in self.params]
        #: Per-member step counts (float, as torch.optim.Adam keeps them).
        self.steps = torch.zeros(E, dtype=torch.float32, device=device)
        self._views()

    def _views(self) -> None:
        """Cache per-member views of params, moments and step counts."""
        def unbind(ts: list[torch.Tensor]) -> list[tuple[torch.Tensor, ...]]:
            return [t.detach().unbind(0) for t in ts]
        self._p = [unbind(ps) for ps in self.params]
        self._m = [unbind(ms) for ms in self.exp_avg]
        self._v = [unbind(vs) for vs in self.exp_avg_sq]
        self._s = self.steps.unbind(0)

    @torch.no_grad()
    def step(self, grads: Sequence[Sequence[torch.Tensor]], members: Sequence[int]) -> None:
        """One Adam step for ``members`` (indices) with ``grads`` shaped like ``params``."""
        if len(grads) != len(self.params):
            raise ValueError(f"expected grads for {len(self.params)} groups, got {len(grads)}")
        members = list(members)
        if not members:
            return
        idx = torch.as_tensor(members, device=self.steps.device)
        self.steps.index_add_(0, idx, torch.ones(len(members), device=self.steps.device))
        b1, b2 = self.betas
        for gi, group_grads in enumerate(grads):
            g = [t.detach().unbind(0) for t in group_grads]
            n = len(g)
            torch._fused_adam_(
                [self._p[gi][j][k] for k in members for j in range(n)],
                [g[j][k] for k in members for j in range(n)],
                [self._m[gi][j][k] for k in members for j in range(n)],
                [self._v[gi][j][k] for k in members for j in range(n)],
                [],
                [self._s[k] for k in members for _ in range(n)],
                lr=self.lrs[gi], beta1=b1, beta2=b2, weight_decay=self.weight_decay,
                eps=self.eps, amsgrad=False, maximize=False)

    def state_dict(self) -> dict:
        return {"exp_avg": [[t.clone() for t in ts] for ts in self.exp_avg],
                "exp_avg_sq": [[t.clone() for t in ts] for ts in self.exp_avg_sq],
                "steps": self.steps.clone()}

    def load_state_dict(self, d: dict) -> None:
        for name in ("exp_avg", "exp_avg_sq"):
            for dst, src in zip(getattr(self, name), d[name], strict=True):
                for t, s in zip(dst, src, strict=True):
                    if t.shape != s.shape:
                        raise ValueError(f"optimizer {name} shape {tuple(s.shape)} != {tuple(t.shape)}")
                    t.copy_(s)
        self.steps.copy_(d["steps"])
