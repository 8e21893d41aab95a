"""Ensemble building blocks: layers, optimizer, noise, replay, arbitrator, integrator."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from apac_mj.agent.agent import _member_adam, member_generators
from apac_mj.types import ArbitrationContext
from apac_mj.kinds import arbitrator_for
from apac_mj.agent.replay import EnsembleReplay
from apac_mj.config import AgentConfig
from apac_mj.agent.integrator import integrate
from apac_mj.agent.networks import EnsembleLinear, build_actor, build_critic
from apac_mj.agent.noise import OUNoise


def gens(seeds, which=0):
    return [member_generators(s)[which] for s in seeds]


def test_ensemble_linear_member_equals_single_seed():
    big = EnsembleLinear(6, 5, gens([3, 4, 5, 6]))
    for k, seed in enumerate([3, 4, 5, 6]):
        one = EnsembleLinear(6, 5, gens([seed]))
        assert torch.equal(big.weight[k], one.weight[0]) and torch.equal(big.bias[k], one.bias[0])
    assert not torch.equal(big.weight[0], big.weight[1])


def test_init_bounds_ddpg():
    hidden = EnsembleLinear(400, 300, gens([0]))
    final = EnsembleLinear(300, 2, gens([0]), final=True)
    assert hidden.weight.abs().max() <= 400 ** -0.5 and hidden.weight.abs().max() > 0.9 * 400 ** -0.5
    assert final.weight.abs().max() <= 3e-3


def test_networks_member_outputs_match_single():
    x, a = torch.randn(4, 7, 6), torch.randn(4, 7, 2)
    g4 = gens(range(4))
    actor, critic = build_actor((16, 12), g4), build_critic((16, 12), g4)
    for k in range(4):
        g = gens([k])
        one_actor, one_critic = build_actor((16, 12), g), build_critic((16, 12), g)
        torch.testing.assert_close(actor(x)[k], one_actor(x[k:k + 1])[0], rtol=0, atol=1e-5)
        torch.testing.assert_close(critic(x, a)[k], one_critic(x[k:k + 1], a[k:k + 1])[0], rtol=0, atol=1e-6)
    out = actor(x * 100)
    assert out.shape == (4, 7, 2) and out.abs().max() <= 1.0


def test_bad_sizes_raise():
    with pytest.raises(ValueError, match="layer sizes"):
        EnsembleLinear(0, 3, gens([0]))
    with pytest.raises(ValueError, match="even"):
        build_critic((4, 5), gens([0]), form="separable")
    with pytest.raises(ValueError, match="critic form"):
        build_critic((4, 4), gens([0]), form="additive")


def _member_opt(E=3, wd=1e-3):
    torch.manual_seed(0)
    net = torch.nn.Module()
    net.p = torch.nn.Parameter(torch.randn(E, 5, 3))
    opt, views = _member_adam({"net": (net, 0.01, wd)}, E)
    return net.p, opt, views["net"][0]


def test_member_adam_matches_torch_adam_per_member():
    p, opt, views = _member_opt(E=1)
    ref = p.detach()[0].clone().requires_grad_()
    ref_opt = torch.optim.Adam([ref], lr=0.01, weight_decay=1e-3)
    for i in range(5):
        g = torch.randn(5, 3) * (i + 1)
        views[0].grad = g.clone()
        opt.step()
        ref.grad = g.clone()
        ref_opt.step()
        torch.testing.assert_close(p.detach()[0], ref.detach(), rtol=1e-6, atol=1e-7)


def test_member_adam_decays_each_network_by_its_own_weight_decay():
    """One param group per network with its own L2 decay (the dynamics model's ``mpc.model_weight_decay``
    beside the paper's 1e-3): each equals torch's Adam with that decay alone."""
    torch.manual_seed(0)
    a, b = torch.nn.Module(), torch.nn.Module()
    a.p, b.p = torch.nn.Parameter(torch.randn(1, 4, 2)), torch.nn.Parameter(torch.randn(1, 4, 2))
    opt, views = _member_adam({"a": (a, 0.01, 1e-3), "b": (b, 0.02, 0.0)}, 1)
    refs = [(a.p.detach()[0].clone().requires_grad_(), 0.01, 1e-3), (b.p.detach()[0].clone().requires_grad_(), 0.02, 0.0)]
    ref_opts = [torch.optim.Adam([r], lr=lr, weight_decay=wd) for r, lr, wd in refs]
    for i in range(4):
        grads = [torch.randn(4, 2) * 1e-4 for _ in refs]  # small gradients: the decay dominates where it acts
        views["a"][0][0].grad, views["b"][0][0].grad = grads[0].clone(), grads[1].clone()
        opt.step()
        for (r, _, _), o, g in zip(refs, ref_opts, grads):
            r.grad = g.clone()
            o.step()
    torch.testing.assert_close(a.p.detach()[0], refs[0][0].detach(), rtol=1e-6, atol=1e-7)
    torch.testing.assert_close(b.p.detach()[0], refs[1][0].detach(), rtol=1e-6, atol=1e-7)
    assert [g["weight_decay"] for g in opt.param_groups] == [1e-3, 0.0]


def test_member_adam_inactive_members_untouched():
    """A member whose view has no gradient keeps its weights, moments and step count."""
    p, opt, views = _member_opt()
    for v in views:
        v.grad = torch.randn(4 + 1, 3)
    opt.step()
    before = (p.detach()[1].clone(), {k: t.clone() for k, t in opt.state[views[1]].items()})
    others = p.detach()[0].clone()
    views[0].grad, views[1].grad, views[2].grad = torch.randn(5, 3), None, torch.randn(5, 3)
    opt.step()
    assert torch.equal(p.detach()[1], before[0])
    assert all(torch.equal(opt.state[views[1]][k], t) for k, t in before[1].items())
    assert not torch.equal(p.detach()[0], others)
    assert [float(opt.state[v]["step"]) for v in views] == [2.0, 1.0, 2.0]


def test_ou_statistics_and_reset():
    theta, sigma = 0.15, 2.0
    noise = OUNoise(gens([0, 1], which=2), theta=theta, sigma=sigma)
    xs = torch.stack([noise.sample() for _ in range(8000)])[500:]
    expected_std = sigma / math.sqrt(theta * (2 - theta))
    assert xs.mean().abs() < 0.5
    assert abs(xs.std().item() - expected_std) / expected_std < 0.1
    lag1 = torch.corrcoef(torch.stack([xs[:-1, 0, 0], xs[1:, 0, 0]]))[0, 1]
    assert abs(lag1 - (1 - theta)) < 0.05
    noise.reset(torch.tensor([True, False]))
    assert torch.equal(noise.x[0], torch.zeros(2)) and not torch.equal(noise.x[1], torch.zeros(2))
    frozen = noise.x[1].clone()
    noise.sample(torch.tensor([True, False]))
    assert torch.equal(noise.x[1], frozen)


def test_ou_member_matches_single():
    four, one = OUNoise(gens(range(4), 2)), OUNoise(gens([2], 2))
    for _ in range(10):
        assert torch.equal(four.sample()[2], one.sample()[0])


def _add(rep, E, value, mask):
    v = torch.full((E,), float(value))
    rep.add(v[:, None].expand(E, 6), v[:, None].expand(E, 2), v, v[:, None].expand(E, 6), v * 0, mask)


def test_replay_ring_wraparound_and_mask():
    rep = EnsembleReplay(gens([0, 1], 1), capacity=3)
    for i in range(5):
        _add(rep, 2, i, [True, i < 2])
    assert rep.count == [3, 2] and rep.ptr == [2, 2]
    assert rep.data["reward"][0].tolist() == [3.0, 4.0, 2.0]
    assert rep.data["reward"][1].tolist() == [0.0, 1.0, 0.0]
    batch = rep.sample(200, [0, 1])
    assert set(batch["reward"][0].tolist()) == {2.0, 3.0, 4.0}
    assert set(batch["reward"][1].tolist()) == {0.0, 1.0}
    assert batch["state"].shape == (2, 200, 6)


def test_replay_bad_shape_and_empty():
    rep = EnsembleReplay(gens([0], 1), capacity=3)
    with pytest.raises(ValueError, match="empty"):
        rep.sample(4, [0])
    with pytest.raises(ValueError, match="state must have shape"):
        rep.add(torch.zeros(1, 5), torch.zeros(1, 2), torch.zeros(1), torch.zeros(1, 6), torch.zeros(1), [True])


@pytest.mark.parametrize("mode,expected", [
    ("ddpg", [True] * 6),
    ("spac", [False] * 6),
    #           ep<100,step0  ep>=100,s0  s1 small-d  s1 big-d  s2 small-d  s2 big-d
    ("apac", [False, True, True, True, True, False]),
])
def test_arbitrator_decision_table(mode, expected):
    arb = arbitrator_for(AgentConfig(kind=mode))
    episode = torch.tensor([50, 100, 100, 150, 100, 150])
    step = torch.tensor([0, 0, 1, 1, 2, 5])
    delta = torch.tensor([0.1, 5.0, 0.5, -3.0, -0.99, 1.0])
    assert arb.use_habit(ArbitrationContext(episode, step, delta)).habit.tolist() == expected


def test_arbitrator_apac_planning_phase_and_nan():
    arb = arbitrator_for(AgentConfig(kind="apac"))
    ctx = ArbitrationContext
    assert arb.use_habit(ctx(torch.tensor([99, 99]), torch.tensor([0, 5]), torch.tensor([0.0, 0.0]))).habit.tolist() == [False, False]
    assert arb.use_habit(ctx(torch.tensor([200]), torch.tensor([3]), torch.tensor([float("nan")]))).habit.tolist() == [False]
    with pytest.raises(ValueError, match="equal length"):
        arb.use_habit(ctx(torch.tensor([1, 2]), torch.tensor([1]), torch.tensor([0.0])))


def test_integrator():
    obs, pred = torch.zeros(3, 4), torch.ones(3, 4)
    out = integrate(obs, pred, torch.tensor([True, False, True]))
    assert out[:, 0].tolist() == [0.0, 1.0, 0.0]
    with pytest.raises(ValueError, match="vision"):
        integrate(obs, pred, torch.tensor([True]))


def test_ou_sigma_annealing():
    """ou_sigma_initial -> ou_sigma linearly over ou_sigma_anneal_episodes; the noise scales with it."""
    cfg = AgentConfig(ou_sigma=2.0, ou_sigma_initial=60.0, ou_sigma_anneal_episodes=100)
    np.testing.assert_allclose(cfg.ou_sigma_at(np.array([-5, 0, 50, 100, 400])), [60.0, 60.0, 31.0, 2.0, 2.0])
    np.testing.assert_allclose(AgentConfig(ou_sigma=2.0, ou_sigma_initial=None).ou_sigma_at(np.array([0, 500])),
                               [2.0, 2.0])
    small, big = (OUNoise([torch.Generator().manual_seed(7)], sigma=2.0) for _ in range(2))
    torch.testing.assert_close(big.sample(sigma=[6.0]), 3 * small.sample())
