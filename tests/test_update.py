"""The update, checked against an independent implementation, and the critic's defining property.

* Every loss term's gradient, per tensor and before the optimizer (Adam hides a gradient's
  scale), equals the gradient of a separate single-member implementation of the same losses
  written here with plain matrix products; the actor's loss must not reach the critic.
* The critic is not additively separable: dQ/da differs between states, and it fits a toy
  Q(s, a) = -|a - g(s)|^2 that a separable critic (Q = V(s) + A(a), the old bug, kept as the
  negative control) cannot.
"""
from __future__ import annotations

import pytest
import torch

from apac_mj.agent.agent import NETWORKS, TRAINED, Agent
from apac_mj.config import AgentConfig
from apac_mj.agent.networks import EnsembleCritic

from conftest import UNEVEN as SMALL  # test_agent imports SMALL from here


def _batch(E: int, B: int, seed: int = 0) -> dict[str, torch.Tensor]:
    """A random minibatch of arm poses from the motion function (so the feasible range is meaningful)."""
    from apac_mj.kinematics import motion_function

    g = torch.Generator().manual_seed(seed)
    ang = torch.rand(2, E, B, 2, generator=g) * 180
    out = {}
    for key, a in (("state", ang[0]), ("next_state", ang[1])):
        end, elbow = motion_function(a[..., 0].numpy(), a[..., 1].numpy(), 5.0, 8.0, (15.0, 15.0))
        target = torch.rand(E, B, 2, generator=g) * 20 + 5
        out[key] = torch.cat([torch.as_tensor(end), torch.as_tensor(elbow), target], -1).float()
    out["action"] = (torch.rand(E, B, 2, generator=g) - 0.5) * 360
    out["executed_action"] = out["action"] * 0.5
    out["reward"] = -torch.rand(E, B, generator=g) * 10
    out["done"] = (torch.rand(E, B, generator=g) < 0.3).float()
    return out


def _mlp(ws: list[torch.Tensor], x: torch.Tensor, hidden, out) -> torch.Tensor:
    for i in range(0, len(ws), 2):
        x = x @ ws[i] + ws[i + 1][0]
        x = hidden(x) if i < len(ws) - 2 else out(x)
    return x


def _critic(ws: list[torch.Tensor], form: str, x: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
    if form == "concat":
        w1, b1, w2, b2, wo, bo = ws
        h = torch.relu(torch.relu(torch.cat([x, a], -1) @ w1 + b1[0]) @ w2 + b2[0])
    else:
        w1, b1, w2, b2, wa, ba, wo, bo = ws
        h = torch.relu(torch.relu(x @ w1 + b1[0]) @ w2 + b2[0] + a @ wa + ba[0])
    return (h @ wo + bo[0])[..., 0]


def reference_grads(agent: Agent, k: int, b: dict[str, torch.Tensor]) -> dict[str, list[torch.Tensor]]:
    """Gradients of member k's four losses, each w.r.t. its own network, written independently."""
    cfg = agent.cfg
    W = {n: [p.detach()[k].clone().requires_grad_(n in TRAINED) for p in getattr(agent, n).parameters()]
         for n in NETWORKS}
    s, a, s2 = b["state"][k], b["action"][k], b["next_state"][k]
    pos = (lambda v: (v - 15.0) / 15.0) if cfg.normalize_inputs else (lambda v: v)
    act = (lambda v: v / 180.0) if cfg.normalize_inputs else (lambda v: v)
    lo, hi = agent.feasible_range(s)
    lo2, hi2 = agent.feasible_range(s2)

    def squash(u, low, high):
        return 180.0 * u if cfg.action_squash == "tanh" else low + (high - low) * (u + 1) / 2

    with torch.no_grad():
        a2 = squash(_mlp(W["target_actor"], pos(s2), torch.relu, torch.tanh), lo2, hi2)
        y = b["reward"][k] + cfg.gamma * (1 - b["done"][k]) * _critic(W["target_critic"], cfg.critic_form, pos(s2), act(a2))
    critic_loss = ((y - _critic(W["critic"], cfg.critic_form, pos(s), act(a))) ** 2).mean()
    pi = squash(_mlp(W["actor"], pos(s), torch.relu, torch.tanh), lo, hi)
    frozen = [w.detach() for w in W["critic"]]
    actor_loss = -_critic(frozen, cfg.critic_form, pos(s), act(pi)).mean()
    if cfg.habit_distillation_weight:
        plan = squash(_mlp([w.detach() for w in W["inverse_model"]], pos(s), torch.relu, torch.tanh), lo, hi)
        actor_loss = actor_loss + cfg.habit_distillation_weight * (((pi - plan) / 180) ** 2).sum(-1).mean()
    if cfg.feasibility_weight:
        excess = (pi - torch.minimum(torch.maximum(pi, lo), hi)) / 180
        actor_loss = actor_loss + cfg.feasibility_weight * (excess ** 2).sum(-1).mean()
    fwd = _mlp(W["forward_model"], torch.cat([pos(s[:, :4]), act(a)], -1), torch.sigmoid, torch.sigmoid) * 30
    inv = _mlp(W["inverse_model"], torch.cat([pos(s[:, :4]), pos(s2[:, :2])], -1), torch.relu, torch.tanh)
    losses = {"critic": critic_loss, "actor": actor_loss, "forward_model": ((fwd - s2[:, :4]) ** 2).mean(),
              "inverse_model": ((squash(inv, lo, hi) - b["executed_action"][k]) ** 2).mean()}
    return {n: list(torch.autograd.grad(losses[n], W[n])) for n in TRAINED}


CONFIGS = {
    "default": dict(),
    "paper_tanh": dict(action_squash="tanh"),
    "raw_inputs": dict(normalize_inputs=False, action_squash="tanh"),
    "summed_critic": dict(critic_form="summed"),
    "feasibility_penalty": dict(feasibility_weight=1000.0, action_squash="tanh"),
    "distillation": dict(kind="apac", habit_distillation_weight=10.0),
    "summed_penalty": dict(critic_form="summed", feasibility_weight=3.0, action_squash="tanh"),
}


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_every_gradient_equals_an_independent_implementation(name):
    agent = Agent(AgentConfig(**{**SMALL, **CONFIGS[name]}), [3, 4, 5])
    with torch.no_grad():  # targets differ from the online networks, as after some soft updates
        for p in list(agent.target_actor.parameters()) + list(agent.target_critic.parameters()):
            p.add_(0.05 * torch.randn_like(p))
        agent.actor.layers[-1].weight.mul_(300)  # a saturating actor exercises the penalty and the squash
    batch, members = _batch(3, 8), [0, 2]
    agent.gradients(batch, members)
    for k in members:
        ref = reference_grads(agent, k, batch)
        for net in TRAINED:
            for p, want in zip(getattr(agent, net).parameters(), ref[net]):
                torch.testing.assert_close(p.grad[k], want, rtol=1e-4, atol=1e-6, msg=f"{name}: {net}")
    views = agent._views["critic"][0]
    assert views[1].grad is None and views[0].grad is not None  # member 1 is not updated


def test_actor_loss_does_not_reach_the_critic():
    """The critic's gradient is the TD loss's alone, whatever the actor's loss."""
    a, b = (Agent(AgentConfig(**SMALL, feasibility_weight=0.0), [0]) for _ in range(2))
    with torch.no_grad():
        b.actor.layers[-1].bias.add_(2.0)  # a different policy changes the actor's loss only
    batch = _batch(1, 8)
    a.gradients(batch, [0])
    b.gradients(batch, [0])
    for p, q in zip(a.critic.parameters(), b.critic.parameters()):
        assert torch.equal(p.grad, q.grad)
    assert not all(torch.equal(p.grad, q.grad) for p, q in zip(a.actor.parameters(), b.actor.parameters()))


def _critic_net(form: str, hidden=(64, 64), E: int = 1) -> EnsembleCritic:
    return EnsembleCritic(6, 2, hidden, [torch.Generator().manual_seed(s) for s in range(E)], form)


def _dq_da(critic: EnsembleCritic, states: torch.Tensor) -> torch.Tensor:
    """dQ/da at a = 0 for each state ``[B, 6]`` -> ``[B, 2]``."""
    a = torch.zeros(1, states.shape[0], 2, requires_grad=True)
    critic(states[None], a).sum().backward()
    return a.grad[0]


@pytest.mark.parametrize("form", ["concat", "summed", "separable"])
def test_dq_da_depends_on_the_state_unless_separable(form):
    states = torch.rand(8, 6) * 2 - 1
    g = _dq_da(_critic_net(form, (400, 600)), states)
    spread = (g - g.mean(0)).abs().max() / g.abs().max()
    if form == "separable":
        assert spread < 1e-5  # the bug: the same action gradient in every state
    else:
        assert spread > 1e-2


def _fit_toy(form: str, steps: int = 600) -> float:
    """R^2 of a critic trained on Q(s, a) = -|a - g(s)|^2, g linear, on held-out points."""
    torch.manual_seed(0)
    G = torch.randn(6, 2) * 0.5
    def sample(n):
        s, a = torch.rand(n, 6) * 2 - 1, torch.rand(n, 2) * 2 - 1
        return s, a, -((a - s @ G) ** 2).sum(-1)
    critic = _critic_net(form)
    opt = torch.optim.Adam(critic.parameters(), lr=3e-3)
    for _ in range(steps):
        s, a, q = sample(256)
        loss = ((critic(s[None], a[None])[0] - q) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    s, a, q = sample(2000)
    with torch.no_grad():
        err = ((critic(s[None], a[None])[0] - q) ** 2).mean()
    return float(1 - err / q.var())


def test_critic_fits_a_state_action_interaction_that_a_separable_one_cannot():
    r2 = {form: _fit_toy(form) for form in ("concat", "summed", "separable")}
    assert r2["concat"] > 0.9 and r2["summed"] > 0.9, r2
    assert r2["separable"] < 0.75, r2  # the interaction term 2 a.g(s) is out of its reach
