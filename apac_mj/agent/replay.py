"""EnsembleReplay: the replay memory R, one ring buffer per member.

Storage is ``[E, capacity, dim]``; member ``k`` writes only when its mask is
set and samples ``batch_size`` indices *with replacement* from its own
``[0, count_k)`` using its own generator (the paper's minibatch of N = 500
from a memory of 1000, and valid from the first stored transition on).
Counts and write positions live on the CPU so that masking needs no device sync.
"""
from __future__ import annotations

from typing import Sequence

import torch

from apac_mj.layout import POSITION_DIM

FIELDS = ("state", "action", "reward", "next_state", "done", "executed_action")


class EnsembleReplay:
    """E ring buffers of transitions ``(s, a, r, s2, done)``."""

    def __init__(self, generators: Sequence[torch.Generator], capacity: int, state_dim: int = POSITION_DIM,
                 action_dim: int = 2, device: str | torch.device = "cpu") -> None:
        if capacity < 1:
            raise ValueError(f"replay capacity must be >= 1, got {capacity}")
        self.generators = list(generators)
        self.E, self.capacity = len(self.generators), capacity
        self.device = torch.device(device)
        dims = {"state": state_dim, "action": action_dim, "reward": 0, "next_state": state_dim, "done": 0,
                "executed_action": action_dim}
        self.data = {k: torch.zeros((self.E, capacity, d) if d else (self.E, capacity), device=self.device)
                     for k, d in dims.items()}
        self.count = [0] * self.E
        self.ptr = [0] * self.E
        self._rows = torch.arange(self.E, device=self.device)[:, None]

    def add(self, state: torch.Tensor, action: torch.Tensor, reward: torch.Tensor,
            next_state: torch.Tensor, done: torch.Tensor, mask: torch.Tensor | Sequence[bool],
            executed_action: torch.Tensor | None = None) -> None:
        """Store one transition for each member with ``mask`` (``[E]`` bool).

        ``action`` is what the critic and the forward model learn from; ``executed_action`` (default:
        ``action``) the joint-angle change the plant made, the inverse model's hindsight label."""
        executed_action = action if executed_action is None else executed_action
        values = dict(zip(FIELDS, (state, action, reward, next_state, done, executed_action)))
        m = torch.as_tensor(mask).cpu().bool().tolist()
        if len(m) != self.E:
            raise ValueError(f"mask must have {self.E} entries, got {len(m)}")
        for name, v in values.items():
            v = torch.as_tensor(v, dtype=torch.float32, device=self.device)
            want = (self.E, *self.data[name].shape[2:])
            if tuple(v.shape) != want:
                raise ValueError(f"replay.add: {name} must have shape {want}, got {tuple(v.shape)}")
            values[name] = v
        ks = [k for k in range(self.E) if m[k]]
        if not ks:
            return
        rows = torch.tensor(ks, device=self.device)
        cols = torch.tensor([self.ptr[k] for k in ks], device=self.device)
        for name, v in values.items():
            self.data[name][rows, cols] = v[rows]
        for k in ks:
            self.ptr[k] = (self.ptr[k] + 1) % self.capacity
            self.count[k] = min(self.count[k] + 1, self.capacity)

    def sample(self, batch_size: int, members: Sequence[int]) -> dict[str, torch.Tensor]:
        """``batch_size`` transitions per member in ``members`` (others get row 0): ``[E, B, ...]``."""
        idx = torch.zeros(self.E, batch_size, dtype=torch.long)
        for k in members:
            if self.count[k] < 1:
                raise ValueError(f"member {k} has an empty replay memory")
            idx[k] = torch.randint(self.count[k], (batch_size,), generator=self.generators[k])
        idx = idx.to(self.device)
        return {name: t[self._rows, idx] for name, t in self.data.items()}

    def state_dict(self) -> dict:
        return {"data": {k: v.clone() for k, v in self.data.items()}, "count": list(self.count),
                "ptr": list(self.ptr), "generators": [g.get_state() for g in self.generators]}

    def load_state_dict(self, d: dict) -> None:
        if len(d["count"]) != self.E:
            raise ValueError(f"replay state has {len(d['count'])} members, expected {self.E}")
        missing = sorted(set(self.data) - set(d["data"]))
        if missing:
            raise ValueError(f"replay state lacks the fields {missing} (written by an older apac_mj)")
        for k, v in d["data"].items():
            if v.shape != self.data[k].shape:
                raise ValueError(f"replay {k} shape {tuple(v.shape)} != {tuple(self.data[k].shape)}")
            self.data[k].copy_(v)
        self.count, self.ptr = [int(c) for c in d["count"]], [int(p) for p in d["ptr"]]
        for g, s in zip(self.generators, d["generators"]):
            g.set_state(s)
