"""Ensemble networks: every layer holds E independent members.

A layer's weight is ``[E, in, out]`` and its bias ``[E, 1, out]``; inputs are
``[E, B, in]`` and one ``torch.baddbmm`` computes all members at once. Member
``k`` is initialised from its own ``torch.Generator``, so member ``k`` of an
ensemble built from generators ``g_0..g_{E-1}`` is bit-identical to the single
member built from ``g_k`` alone.

Initialisation is DDPG's (Lillicrap et al. 2015): hidden layers uniform in
``±1/sqrt(fan_in)`` (weights and biases), output layers uniform in ``±3e-3``.
"""
from __future__ import annotations

from typing import Callable, Sequence

import torch
from torch import nn

#: Output-layer init bound (DDPG).
FINAL_INIT = 3e-3

ACTIVATIONS: dict[str, Callable[[torch.Tensor], torch.Tensor]] = {
    "relu": torch.relu,
    "sigmoid": torch.sigmoid,
    "tanh": torch.tanh,
}


def _uniform(shape: Sequence[int], bound: float, generators: Sequence[torch.Generator]) -> torch.Tensor:
    """Stack one ``U(-bound, bound)`` draw of ``shape`` per member generator."""
    return torch.stack([
        torch.empty(*shape).uniform_(-bound, bound, generator=g) for g in generators
    ])


class EnsembleLinear(nn.Module):
    """``y = x @ W + b`` for E members at once: x ``[E,B,in]`` -> ``[E,B,out]``."""

    def __init__(self, in_features: int, out_features: int,
                 generators: Sequence[torch.Generator], final: bool = False) -> None:
        super().__init__()
        if in_features < 1 or out_features < 1:
            raise ValueError(f"layer sizes must be >= 1, got {in_features}->{out_features}")
        if not generators:
            raise ValueError("EnsembleLinear needs one generator per member, got none")
        bound = FINAL_INIT if final else in_features ** -0.5
        self.in_features, self.out_features = in_features, out_features
        self.weight = nn.Parameter(_uniform((in_features, out_features), bound, generators))
        self.bias = nn.Parameter(_uniform((1, out_features), bound, generators))

    @property
    def E(self) -> int:
        return self.weight.shape[0]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.baddbmm(self.bias, x, self.weight)


class EnsembleMLP(nn.Module):
    """Two hidden layers and a squashed, scaled output: ``scale * out_act(...)``."""

    def __init__(self, sizes: Sequence[int], hidden_act: str, out_act: str, scale: float,
                 generators: Sequence[torch.Generator]) -> None:
        super().__init__()
        if len(sizes) < 2:
            raise ValueError(f"an MLP needs at least input and output sizes, got {sizes}")
        for act in (hidden_act, out_act):
            if act not in ACTIVATIONS:
                raise ValueError(f"unknown activation {act!r}; choose from {sorted(ACTIVATIONS)}")
        n = len(sizes) - 1
        self.layers = nn.ModuleList(
            EnsembleLinear(sizes[i], sizes[i + 1], generators, final=(i == n - 1)) for i in range(n))
        self.hidden_act, self.out_act, self.scale = hidden_act, out_act, float(scale)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        act = ACTIVATIONS[self.hidden_act]
        for layer in self.layers[:-1]:
            x = act(layer(x))
        return ACTIVATIONS[self.out_act](self.layers[-1](x)) * self.scale


class EnsembleCritic(nn.Module):
    """Q(s, a): state -> h1 relu; [h1 -> h/2, action -> h/2] concatenated -> relu -> 1.

    This is the text's reading (Appendix 2): the second hidden layer of
    ``hidden[1]`` units is the concatenation of a ``hidden[1]/2`` projection of
    the first layer and a ``hidden[1]/2`` projection of the action.
    """

    def __init__(self, state_dim: int, action_dim: int, hidden: Sequence[int],
                 generators: Sequence[torch.Generator]) -> None:
        super().__init__()
        h1, h2 = hidden
        if h2 % 2:
            raise ValueError(f"critic second layer must be even (two halves), got {h2}")
        self.l1 = EnsembleLinear(state_dim, h1, generators)
        self.l2_state = EnsembleLinear(h1, h2 // 2, generators)
        self.l2_action = EnsembleLinear(action_dim, h2 // 2, generators)
        self.out = EnsembleLinear(h2, 1, generators, final=True)

    def features(self, state: torch.Tensor) -> torch.Tensor:
        """The state half of the second layer before its relu: ``[E,B,S] -> [E,B,h2/2]``."""
        return self.l2_state(torch.relu(self.l1(state)))

    def head(self, features: torch.Tensor, action: torch.Tensor, detach: bool = False) -> torch.Tensor:
        """Q from state features and an action; ``detach`` keeps gradients out of the critic's weights."""
        la, lo = self.l2_action, self.out
        wa, ba, wo, bo = la.weight, la.bias, lo.weight, lo.bias
        if detach:
            wa, ba, wo, bo = wa.detach(), ba.detach(), wo.detach(), bo.detach()
        h = torch.relu(torch.cat([features, torch.baddbmm(ba, action, wa)], dim=-1))
        return torch.baddbmm(bo, h, wo).squeeze(-1)

    def forward(self, state: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """``[E,B,S], [E,B,A] -> [E,B]``."""
        return self.head(self.features(state), action)


def build_actor(hidden: Sequence[int], scale: float, gens: Sequence[torch.Generator]) -> EnsembleMLP:
    """Actor pi(s): state (6) -> relu -> relu -> 2 x tanh x scale (degrees)."""
    return EnsembleMLP([6, *hidden, 2], "relu", "tanh", scale, gens)


def build_critic(hidden: Sequence[int], gens: Sequence[torch.Generator]) -> EnsembleCritic:
    """Critic Q(s, a): state (6), action (2) -> scalar."""
    return EnsembleCritic(6, 2, hidden, gens)


def build_forward_model(hidden: Sequence[int], scale: float, gens: Sequence[torch.Generator]) -> EnsembleMLP:
    """Forward model: [end, elbow] (4) + action (2) -> sigmoid -> sigmoid -> 4 x sigmoid x scale (cm)."""
    return EnsembleMLP([6, *hidden, 4], "sigmoid", "sigmoid", scale, gens)


def build_inverse_model(hidden: Sequence[int], scale: float, gens: Sequence[torch.Generator]) -> EnsembleMLP:
    """Inverse model: [end_t, elbow_t, end_{t+1}] (6) -> relu -> relu -> 2 x tanh x scale (degrees)."""
    return EnsembleMLP([6, *hidden, 2], "relu", "tanh", scale, gens)


# -- allocation-free forward/backward for the update's hot path ---------------------
#
# Agent.update() computes all gradients by hand with out= ops on preallocated
# buffers: no autograd graph, no allocations, no page faults. These helpers take
# the weights explicitly ([(W, b), ...], possibly bf16 copies) and are checked
# against autograd in tests/test_agent.py.

#: Layers with at most this many outputs are computed in transposed form.
NARROW = 8

_ACT_INPLACE: dict[str, Callable[[torch.Tensor], torch.Tensor]] = {
    "relu": torch.relu_, "sigmoid": torch.sigmoid_, "tanh": torch.tanh_}


def act_backward_(name: str, grad: torch.Tensor, out: torch.Tensor) -> torch.Tensor:
    """In place ``grad <- grad * act'(.)`` given the activation's output ``out``."""
    if name == "relu":
        return torch.ops.aten.threshold_backward.grad_input(grad, out, 0, grad_input=grad)
    if name == "sigmoid":
        return torch.ops.aten.sigmoid_backward.grad_input(grad, out, grad_input=grad)
    if name == "tanh":
        return torch.ops.aten.tanh_backward.grad_input(grad, out, grad_input=grad)
    raise ValueError(f"unknown activation {name!r}")


class Workspace:
    """Preallocated tensors reused across updates, keyed by name."""

    def __init__(self, device: torch.device) -> None:
        self.device, self.buffers = device, {}

    def get(self, name: str, shape: Sequence[int], dtype: torch.dtype) -> torch.Tensor:
        t = self.buffers.get(name)
        if t is None or tuple(t.shape) != tuple(shape) or t.dtype != dtype:
            t = self.buffers[name] = torch.empty(tuple(shape), dtype=dtype, device=self.device)
        return t


def mlp_forward(ws: Workspace, key: str, weights: Sequence[tuple[torch.Tensor, torch.Tensor]],
                hidden_act: str, out_act: str, x: torch.Tensor) -> list[torch.Tensor]:
    """Layer inputs and the squashed (unscaled) output: ``[x, h1, ..., out_act(z_n)]``."""
    xs = [x]
    n = len(weights)
    for i, (w, b) in enumerate(weights):
        E, B, out = x.shape[0], x.shape[1], w.shape[-1]
        if out <= NARROW:
            # narrow outputs as W^T x^T ([E,out,B], viewed back as [E,B,out]): several times faster
            zt = ws.get(f"{key}.h{i}t", (E, out, B), x.dtype)
            z = torch.baddbmm(b.transpose(1, 2), w.transpose(1, 2), xs[-1].transpose(1, 2), out=zt).transpose(1, 2)
        else:
            z = torch.baddbmm(b, xs[-1], w, out=ws.get(f"{key}.h{i}", (E, B, out), x.dtype))
        _ACT_INPLACE[hidden_act if i < n - 1 else out_act](z)
        xs.append(z)
    return xs


def mlp_backward(ws: Workspace, key: str, weights: Sequence[tuple[torch.Tensor, torch.Tensor]],
                 hidden_act: str, out_act: str, xs: Sequence[torch.Tensor], grad: torch.Tensor,
                 grads: Sequence[tuple[torch.Tensor, torch.Tensor]], input_grad: bool = False) -> torch.Tensor | None:
    """Backpropagate ``grad`` (w.r.t. the squashed output, overwritten) into ``grads`` [(gW, gb)]."""
    n = len(weights)
    for i in reversed(range(n)):
        act_backward_(hidden_act if i < n - 1 else out_act, grad, xs[i + 1])
        torch.bmm(xs[i].transpose(1, 2), grad, out=grads[i][0])
        torch.sum(grad, dim=1, keepdim=True, out=grads[i][1])
        if i == 0 and not input_grad:
            return None
        w = weights[i][0]
        grad = torch.bmm(grad, w.transpose(1, 2), out=ws.get(f"{key}.d{i}", xs[i].shape, grad.dtype))
    return grad
