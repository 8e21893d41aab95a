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

from apac_mj.layout import POSITION_DIM

#: Output-layer init bound (DDPG).
FINAL_INIT = 3e-3

#: In place: each is applied to a layer's fresh output (which the layer's backward does not need; the
#: activation's backward reads its own result), so no second ``[E, B, h]`` tensor is allocated per layer.
#: Same values as ``torch.relu`` etc. (docs/agent.md, "Speed").
ACTIVATIONS: dict[str, Callable[[torch.Tensor], torch.Tensor]] = {
    "relu": torch.relu_,
    "sigmoid": torch.sigmoid_,
    "tanh": torch.tanh_,
    "linear": lambda x: x,
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

    def forward(self, x: torch.Tensor, detach: bool = False) -> torch.Tensor:
        """``detach``: the weights as constants (gradients reach ``x`` but not this layer)."""
        if detach:
            return torch.baddbmm(self.bias.detach(), x, self.weight.detach())
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


#: The critic's forms (``AgentConfig.critic_form``); see :class:`EnsembleCritic`.
CRITIC_FORMS = ("concat", "summed", "separable")


class EnsembleCritic(nn.Module):
    """Q(s, a) in one of three forms (``hidden = (h1, h2)``, relu throughout, linear output):

    * ``"concat"``: Table 2 read literally: ``[s, a]`` (8) -> h1 -> h2 -> 1.
    * ``"summed"``: the DDPG code the paper's hyperparameters come from:
      ``s -> h1``; ``relu(W_h h1 + W_a a + b)`` (h2) -> 1: state and action meet inside one relu.
    * ``"separable"``: the old reading, ``relu([W_h h1, W_a a])`` -> 1, i.e. ``Q = V(s) + A(a)``:
      dQ/da is the same in every state. Kept only as the negative control of the tests; never train it.
    """

    def __init__(self, state_dim: int, action_dim: int, hidden: Sequence[int],
                 generators: Sequence[torch.Generator], form: str = "concat") -> None:
        super().__init__()
        if form not in CRITIC_FORMS:
            raise ValueError(f"critic form must be one of {CRITIC_FORMS}, got {form!r}")
        h1, h2 = hidden
        self.form = form
        if form == "concat":
            self.l1 = EnsembleLinear(state_dim + action_dim, h1, generators)
            self.l2 = EnsembleLinear(h1, h2, generators)
        else:
            if form == "separable" and h2 % 2:
                raise ValueError(f"the separable critic's second layer must be even (two halves), got {h2}")
            width = h2 // 2 if form == "separable" else h2
            self.l1 = EnsembleLinear(state_dim, h1, generators)
            self.l2 = EnsembleLinear(h1, width, generators)
            self.l2_action = EnsembleLinear(action_dim, width, generators)
        self.out = EnsembleLinear(h2, 1, generators, final=True)

    def forward(self, state: torch.Tensor, action: torch.Tensor, detach: bool = False) -> torch.Tensor:
        """``[E,B,S], [E,B,A] -> [E,B]``; ``detach`` keeps gradients out of the critic's weights
        (the actor's loss differentiates Q with respect to the action only)."""
        if self.form == "concat":
            h = torch.relu_(self.l1(torch.cat([state, action], -1), detach))
            h = torch.relu_(self.l2(h, detach))
        else:
            zs = self.l2(torch.relu_(self.l1(state, detach)), detach)
            za = self.l2_action(action, detach)
            h = torch.relu_(zs + za) if self.form == "summed" else torch.relu_(torch.cat([zs, za], -1))
        return self.out(h, detach).squeeze(-1)


def build_actor(hidden: Sequence[int], gens: Sequence[torch.Generator], state_dim: int = POSITION_DIM,
                action_dim: int = 2) -> EnsembleMLP:
    """Actor pi(s): state (6, the paper's; more if the task observes more) -> relu -> relu -> action (2) x tanh,
    in [-1, 1] (the agent maps it to the action's units)."""
    return EnsembleMLP([state_dim, *hidden, action_dim], "relu", "tanh", 1.0, gens)


def build_critic(hidden: Sequence[int], gens: Sequence[torch.Generator], form: str = "concat",
                 state_dim: int = POSITION_DIM,
                 action_dim: int = 2) -> EnsembleCritic:
    """Critic Q(s, a): state (6), action (2) -> scalar."""
    return EnsembleCritic(state_dim, action_dim, hidden, gens, form)


def build_forward_model(hidden: Sequence[int], scale: float, gens: Sequence[torch.Generator],
                        action_dim: int = 2, extra_dim: int = 0) -> EnsembleMLP:
    """Forward model: [end, elbow] (4) + extra (the task's extra observations, e.g. joint velocities; none on
    the paper's tasks) + action (2) -> sigmoid -> sigmoid -> (4 + extra) x sigmoid x scale: the next arm (cm)
    and, where observed, the next extra entries (the agent maps them back, ``Agent._forward_extra``)."""
    return EnsembleMLP([4 + extra_dim + action_dim, *hidden, 4 + extra_dim], "sigmoid", "sigmoid", scale, gens)


class DynamicsHeads(nn.Module):
    """``K`` dynamics models per member (each an :class:`EnsembleMLP` over the members), trained side by side
    on the same minibatches from their own initializations; the prediction is their mean (a model ensemble,
    PETS's, propagated by its expectation). :meth:`each` gives every head's, ``[K, ...]``. The last ``held_out``
    heads are trained as the others but left out of the prediction: :meth:`held_out_mean` is theirs, a model the
    plans were not selected by (``mpc.held_out_heads``, the graded rule's ``voc.gain = "heldout"``)."""

    def __init__(self, heads: Sequence[EnsembleMLP], held_out: int = 0) -> None:
        super().__init__()
        if len(heads) < 2:
            raise ValueError(f"DynamicsHeads needs two heads or more, got {len(heads)} (one: the plain model)")
        if not 0 <= held_out < len(heads):
            raise ValueError(f"held_out must be in [0, {len(heads) - 1}] (a head must be planned through), "
                             f"got {held_out}")
        self.heads = nn.ModuleList(heads)
        self.held_out = held_out

    def each(self, x: torch.Tensor) -> torch.Tensor:
        return torch.stack([h(x) for h in self.heads])

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        used = len(self.heads) - self.held_out
        return torch.stack([h(x) for h in self.heads[:used]]).mean(0)

    def held_out_mean(self, x: torch.Tensor) -> torch.Tensor:
        """The held-out heads' mean prediction (an error where none is held out)."""
        if self.held_out == 0:
            raise ValueError("no dynamics head is held out (mpc.held_out_heads = 0)")
        return torch.stack([h(x) for h in self.heads[len(self.heads) - self.held_out:]]).mean(0)


def build_dynamics_model(hidden: Sequence[int], gens: Sequence[torch.Generator], action_dim: int = 2,
                         extra_dim: int = 0, heads: int = 1, held_out: int = 0) -> nn.Module:
    """The planning system's dynamics model (beyond the paper; kinds that plan through a model): the motion
    [end, elbow, extra] and the action, normalized (6 + extra) -> relu -> relu -> the motion's change over the
    step (4 + extra), normalized, linear: a residual model, as model-based RL's dynamics models are. ``heads``
    > 1: that many, initialized one after another from the members' generators, averaged
    (:class:`DynamicsHeads`; the last ``held_out`` of them left out of the mean); 1: the single model (its parameters
    as before the heads existed)."""
    sizes = [4 + extra_dim + action_dim, *hidden, 4 + extra_dim]
    if heads < 1:
        raise ValueError(f"heads must be >= 1, got {heads}")
    if heads == 1:
        return EnsembleMLP(sizes, "relu", "linear", 1.0, gens)
    return DynamicsHeads([EnsembleMLP(sizes, "relu", "linear", 1.0, gens) for _ in range(heads)], held_out)


def build_inverse_model(hidden: Sequence[int], gens: Sequence[torch.Generator], action_dim: int = 2,
                        extra_dim: int = 0) -> EnsembleMLP:
    """Inverse model: [end_t, elbow_t, extra_t, end_{t+1}] (6 + extra; the paper's 6) -> relu -> relu ->
    action (2) x tanh, in [-1, 1]."""
    return EnsembleMLP([POSITION_DIM + extra_dim, *hidden, action_dim], "relu", "tanh", 1.0, gens)


def dynamics_loss(model: nn.Module, inputs: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """The dynamics model's error ``[E]`` on the motion's change ``target`` (normalized: every entry of order 1)
    from its ``inputs``; with several heads (:class:`DynamicsHeads`), the mean of each head's own error (each
    head learns to predict, not only their mean)."""
    if isinstance(model, DynamicsHeads):
        return (model.each(inputs).float() - target).pow(2).mean((2, 3)).mean(0)
    return (model(inputs).float() - target).pow(2).mean((1, 2))
