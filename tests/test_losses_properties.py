"""The agent's losses and update against answers computed by hand on networks of known output (issue 41's mutation
testing, docs/mutation.md): the critic's TD loss ``(r + gamma (1 - done) Q'(s', pi'(s')) - Q(s, a))^2``, the actor's
``-Q(s, pi(s))``, the forward model's error (with the velocity part), the inverse model's, the soft target update,
the extra model steps' gradients and counts, and each network's weight decay."""
from __future__ import annotations

import math

import pytest
import torch

from apac_mj.agent.agent import TRAINED, Agent
from apac_mj.config import AgentConfig
from apac_mj.layout import Sizes

from conftest import UNEVEN as SMALL
from test_update import _batch, reference_grads

#: A torque task observing the joint velocities (scale 500): two motion entries beyond the positions.
MOTION = Sizes(state_dim=8, extra_scale=(500.0, 500.0), action_bound=2.0, angle_actions=False)


def _constant(agent: Agent, outputs: dict[str, list[float]]) -> None:
    """Every weight and bias of each named network zero but its output layer's bias: member ``k`` outputs
    ``outputs[name][k]`` before the output activation, whatever the input."""
    with torch.no_grad():
        for name, biases in outputs.items():
            net = getattr(agent, name)
            for p in net.parameters():
                p.zero_()
            last = net.out if hasattr(net, "out") else net.layers[-1]
            last.bias.copy_(torch.tensor(biases).reshape(-1, 1, 1).expand_as(last.bias))


def test_the_critic_and_actor_losses_by_hand_on_constant_networks():
    """Q = c = (2, -1), Q' = c' = (5, 4): the critic's loss is the mean of ``(r + gamma (1 - d) c' - c)^2`` over the
    batch, the actor's ``-c``."""
    agent = Agent(AgentConfig(**SMALL, gamma=0.9, feasibility_weight=0.0), [0, 1])
    _constant(agent, {"critic": [2.0, -1.0], "target_critic": [5.0, 4.0]})
    b = _batch(2, 8)
    b["done"][:, :3] = 1.0
    b["done"][:, 3:] = 0.0
    losses = agent.losses(b)
    c, c2 = torch.tensor([[2.0], [-1.0]]), torch.tensor([[5.0], [4.0]])
    want = (b["reward"] + 0.9 * (1 - b["done"]) * c2 - c).pow(2).mean(1)
    torch.testing.assert_close(losses["critic"], want, rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(losses["actor"], torch.tensor([-2.0, 1.0]))


@pytest.mark.parametrize("kw", [dict(kind="apac", habit_distillation_weight=0.5),
                                dict(feasibility_weight=0.5, action_squash="tanh")])
def test_a_penalty_weight_below_one_still_adds_its_term(kw):
    """The distillation and feasibility terms at weight 0.5: every gradient equals the independent implementation's
    (tests/test_update.py), which adds them."""
    agent = Agent(AgentConfig(**{**SMALL, **kw}), [3, 4])
    with torch.no_grad():
        agent.actor.layers[-1].weight.mul_(300)  # a saturating actor: the feasibility term is not 0
    batch = _batch(2, 8)
    agent.gradients(batch, [1])
    ref = reference_grads(agent, 1, batch)
    for net in TRAINED:  # member 0 is not updated: a weight of 0 on its losses, its gradient zero
        assert all(torch.equal(p.grad[0], torch.zeros_like(p.grad[0])) for p in getattr(agent, net).parameters())
    for p, want in zip(agent.actor.parameters(), ref["actor"]):
        torch.testing.assert_close(p.grad[1], want, rtol=1e-4, atol=1e-6)


def test_the_forward_models_error_by_hand_with_the_velocities():
    """A forward model of zero weights and output bias ln 3 outputs 30 sigmoid(ln 3) = 22.5 cm on every entry: its
    velocity outputs read as 2 (2 * 22.5 / 30 - 1) = 1 (500 deg/s); the error is ``22.5 - arm'`` in cm and
    ``(1 - v' / 500) * 15`` (half the 30 cm plane) per velocity."""
    agent = Agent(AgentConfig(kind="spac", **{k: (8, 8) for k in ("actor_hidden", "critic_hidden", "forward_hidden",
                                                                   "inverse_hidden")}, batch_size=4), [0],
                  sizes=MOTION)
    _constant(agent, {"forward_model": [math.log(3.0)]})
    g = torch.Generator().manual_seed(5)
    s = torch.cat([torch.rand(1, 4, 6, generator=g) * 30, torch.randn(1, 4, 2, generator=g) * 300], -1)
    s2 = torch.cat([torch.rand(1, 4, 6, generator=g) * 30, torch.randn(1, 4, 2, generator=g) * 300], -1)
    b = {"state": s, "next_state": s2, "action": torch.rand(1, 4, 2, generator=g) * 4 - 2,
         "executed_action": torch.rand(1, 4, 2, generator=g) * 4 - 2, "reward": torch.zeros(1, 4),
         "done": torch.zeros(1, 4)}
    err = torch.cat([22.5 - s2[..., :4], (1.0 - s2[..., 6:] / 500.0) * 15.0], -1)
    torch.testing.assert_close(agent.losses(b)["forward"], err.pow(2).mean((1, 2)), rtol=1e-5, atol=1e-5)


def test_the_inverse_models_error_by_hand():
    """An inverse model of zero weights proposes tanh(0) = 0 degrees (the paper's squash): its loss is the mean
    square of the executed action."""
    agent = Agent(AgentConfig(**SMALL, action_squash="tanh"), [0, 1])
    _constant(agent, {"inverse_model": [0.0, 0.0]})
    b = _batch(2, 8)
    torch.testing.assert_close(agent.losses(b)["inverse"], b["executed_action"].pow(2).mean((1, 2)))


def _filled(agent: Agent, n: int = 6) -> None:
    g = torch.Generator().manual_seed(1)
    E = agent.E
    for _ in range(n):
        s, s2 = torch.rand(E, 6, generator=g) * 30, torch.rand(E, 6, generator=g) * 30
        agent.replay.add(s, (torch.rand(E, 2, generator=g) - 0.5) * 360, -torch.rand(E, generator=g), s2,
                         torch.zeros(E), torch.ones(E, dtype=torch.bool))


def test_the_soft_update_of_every_member_is_tau_theta_plus_one_minus_tau_theta_prime():
    agent = Agent(AgentConfig(**SMALL, tau=0.25), [0, 1])
    _filled(agent)
    old = {n: [p.detach().clone() for p in getattr(agent, n).parameters()] for n in ("target_actor", "target_critic")}
    agent.update([True, True])
    for target, online in (("target_actor", "actor"), ("target_critic", "critic")):
        for o, t, p in zip(old[target], getattr(agent, target).parameters(), getattr(agent, online).parameters()):
            torch.testing.assert_close(t, 0.75 * o + 0.25 * p.detach(), rtol=1e-6, atol=1e-7)
            assert not torch.equal(t, o)


def test_an_extra_inverse_step_has_the_inverse_losss_gradient_for_its_members_only():
    """``_model_step`` on the inverse model for member 0: its gradient is the independent implementation's, member
    1's is zero (a weight of 0, not a division by it)."""
    agent = Agent(AgentConfig(**SMALL), [3, 4])
    batch = _batch(2, 8)
    want = reference_grads(agent, 0, batch)["inverse_model"]
    agent._model_step(batch, [0], "inverse_model")
    for p, w in zip(agent.inverse_model.parameters(), want):
        torch.testing.assert_close(p.grad[0], w, rtol=1e-4, atol=1e-6)
        assert torch.equal(p.grad[1], torch.zeros_like(p.grad[1]))


@pytest.mark.parametrize("inverse_updates", [0, 2])
def test_each_update_takes_one_adam_step_per_network_and_the_extra_inverse_steps(inverse_updates):
    """Adam's step count per member view after two updates of member 0: 2 for every network, plus
    ``2 * inverse_updates`` for the inverse model; member 1 (inactive) none."""
    agent = Agent(AgentConfig(**SMALL, inverse_updates=inverse_updates), [0, 1])
    _filled(agent)
    for _ in range(2):
        agent.update([True, False])
    for net, views in agent._views.items():
        steps = {int(agent.optimizer.state[vs[0]]["step"]) for vs in views}
        assert steps == {2 + (2 * inverse_updates if net == "inverse_model" else 0)}, net
        assert all(vs[1] not in agent.optimizer.state for vs in views), net


def test_each_network_is_decayed_by_its_own_weight_decay():
    """The paper's decay on the critic, actor and forward model, the inverse model's own where set."""
    agent = Agent(AgentConfig(**SMALL, weight_decay=0.003, inverse_weight_decay=0.25), [0])
    decay = [group["weight_decay"] for group in agent.optimizer.param_groups]
    assert decay == [0.25 if n == "inverse_model" else 0.003 for n in TRAINED]
    assert [group["lr"] for group in agent.optimizer.param_groups] == [getattr(agent.cfg, lr) for lr in TRAINED.values()]


@pytest.mark.parametrize("heads", [1, 2])
def test_the_dynamics_models_loss_by_hand_on_constant_heads(heads):
    """Heads of zero weights output their output bias ``c_i``: the loss is the mean over the heads of
    ``mean((c_i - target)^2)``, the target the motion's change in network units ``(s' - s) / 15`` (arm, cm)."""
    from apac_mj.rules import MPCParams

    mpc = MPCParams(model_hidden=(8, 8), model_heads=heads, model_updates=0)
    agent = Agent(AgentConfig(**SMALL), [0, 1], dynamics=mpc)
    models = agent.dynamics_model.heads if heads > 1 else [agent.dynamics_model]
    with torch.no_grad():
        for i, head in enumerate(models):
            for p in head.parameters():
                p.zero_()
            head.layers[-1].bias.fill_(0.5 * (i + 1))
    b = _batch(2, 8)
    target = (b["next_state"][..., :4] - b["state"][..., :4]) / 15.0
    want = torch.stack([(0.5 * (i + 1) - target).pow(2).mean((1, 2)) for i in range(heads)]).mean(0)
    losses = agent.losses(b)
    assert set(losses) == {"critic", "actor", "forward", "inverse", "dynamics"}
    torch.testing.assert_close(losses["dynamics"], want, rtol=1e-5, atol=1e-6)
    if heads > 1:
        each = agent.dynamics_model.each(torch.zeros(2, 3, 6))
        assert each.shape == (2, 2, 3, 4) and each[1].unique().tolist() == [1.0]
        mean = agent.dynamics_model(torch.zeros(2, 3, 6))
        assert mean.shape == (2, 3, 4) and mean.unique().tolist() == [0.75]


def test_the_dynamics_model_takes_its_extra_steps_with_its_own_rate_and_decay():
    """``model_updates = 3``: after one update of member 0 its dynamics model's views took 1 + 3 Adam steps, the
    other networks 1; its parameter group has ``model_lr`` and ``model_weight_decay``."""
    from apac_mj.rules import MPCParams

    mpc = MPCParams(model_hidden=(8, 8), model_updates=3, model_lr=0.002, model_weight_decay=0.125)
    agent = Agent(AgentConfig(**SMALL), [0, 1], dynamics=mpc)
    _filled(agent)
    agent.update([True, False])
    for net, views in agent._views.items():
        assert {int(agent.optimizer.state[vs[0]]["step"]) for vs in views} == {4 if net == "dynamics_model" else 1}
    group = agent.optimizer.param_groups[-1]
    assert (group["lr"], group["weight_decay"]) == (0.002, 0.125)
    assert agent.loss_names[-1] == "dynamics" and agent.networks[-1] == "dynamics_model"


def test_the_dynamics_model_builder_refuses_no_heads_and_a_single_head_ensemble():
    from apac_mj.agent.networks import DynamicsHeads, EnsembleMLP, build_dynamics_model

    gens = [torch.Generator().manual_seed(0)]
    one = build_dynamics_model((8, 8), gens, action_dim=2, extra_dim=2)
    assert isinstance(one, EnsembleMLP) and [(l.in_features, l.out_features) for l in one.layers] == [
        (8, 8), (8, 8), (8, 6)]
    assert one.hidden_act == "relu" and one.out_act == "linear" and one.scale == 1.0
    three = build_dynamics_model((8, 8), gens, heads=3)
    assert isinstance(three, DynamicsHeads) and len(three.heads) == 3
    assert not torch.equal(three.heads[0].layers[0].weight, three.heads[1].layers[0].weight)
    with pytest.raises(ValueError, match=r"^heads must be >= 1, got 0$"):
        build_dynamics_model((8, 8), gens, heads=0)
    with pytest.raises(ValueError, match=r"^DynamicsHeads needs two heads or more, got 1 \(one: the plain model\)$"):
        DynamicsHeads([one])


# -- the agent's construction: what a torque task, a plane and the networks' shapes make of the settings ----------
def test_a_torque_task_keeps_the_noises_and_babblings_fraction_of_the_action_range():
    """Action bound 2 N·m against the 180-degree scale: r = 2 / 180; the action scale becomes 2, the babbling
    range, the exploration noise and its initial value keep their fraction; the feasible range is (-2, 2)."""
    from apac_mj.agent.agent import in_action_units

    cfg = AgentConfig(**SMALL, babbling_scale=90.0, ou_sigma=9.0, ou_sigma_initial=18.0, ou_theta=0.3)
    out = in_action_units(cfg, MOTION)
    r = 2.0 / 180.0
    assert out.action_scale == 2.0
    assert (out.babbling_scale, out.ou_sigma, out.ou_sigma_initial) == pytest.approx((90.0 * r, 9.0 * r, 18.0 * r))
    assert in_action_units(AgentConfig(**SMALL, ou_sigma_initial=None), MOTION).ou_sigma_initial is None
    assert in_action_units(cfg, Sizes()) is cfg  # joint-angle actions: unchanged
    agent = Agent(cfg, [0], sizes=MOTION)
    lo, hi = agent.feasible_range(torch.zeros(1, 3, 8))
    assert lo.tolist() == [[[-2.0, -2.0]] * 3] and hi.tolist() == [[[2.0, 2.0]] * 3]
    assert (agent.noise.theta, agent.noise.sigma) == pytest.approx((0.3, 9.0 * r))


def test_the_agent_refuses_a_plane_scale_other_than_the_tasks():
    with pytest.raises(ValueError, match=r"^AgentConfig.plane_scale = 40.0 but the task's plane is 30.0 x 30.0 cm: "
                                         r"set plane_scale = 30 or None \(None: the task's plane\)$"):
        Agent(AgentConfig(**SMALL, plane_scale=40.0), [0])
    assert Agent(AgentConfig(**SMALL, plane_scale=30.0), [0]).plane_scale == 30.0


def test_the_agents_state_names_its_precision_and_its_targets_take_no_gradient():
    agent = Agent(AgentConfig(**SMALL), [0])
    assert agent.state_dict()["precision"] == "fp32"
    assert not any(p.requires_grad for n in ("target_actor", "target_critic") for p in getattr(agent, n).parameters())
    with pytest.raises(ValueError, match=r"^actor.layers.0.weight: shape \(1, 6, 3\) != \(1, 6, 24\)$"):
        state = agent.state_dict()
        state["networks"]["actor"]["layers.0.weight"] = torch.zeros(1, 6, 3)
        agent.load_state_dict(state)


def test_the_networks_shapes_and_their_last_layers_small_initialization():
    """A one-input layer and an MLP without a hidden layer are allowed; only the last layer starts within
    +-3e-3 (DDPG's); a bad activation or no generator is refused by name."""
    from apac_mj.agent.networks import EnsembleLinear, EnsembleMLP

    gens = [torch.Generator().manual_seed(0)]
    assert EnsembleLinear(1, 3, gens).weight.shape == (1, 1, 3)
    mlp = EnsembleMLP([5, 400, 400, 2], "relu", "tanh", 1.0, gens)
    assert [l.weight.abs().max().item() <= 3e-3 for l in mlp.layers] == [False, False, True]
    assert len(EnsembleMLP([5, 2], "relu", "tanh", 1.0, gens).layers) == 1
    with pytest.raises(ValueError, match=r"^unknown activation 'gelu'; choose from \["):
        EnsembleMLP([5, 2], "gelu", "tanh", 1.0, gens)
    with pytest.raises(ValueError, match=r"^an MLP needs at least input and output sizes, got \[5\]$"):
        EnsembleMLP([5], "relu", "tanh", 1.0, gens)
    with pytest.raises(ValueError, match=r"^EnsembleLinear needs one generator per member, got none$"):
        EnsembleLinear(2, 2, [])


def test_the_agent_refuses_no_seeds_a_missing_cuda_and_a_plane_that_is_not_square():
    from apac_mj.kinematics import Geometry

    with pytest.raises(ValueError, match=r"^Agent needs at least one seed$"):
        Agent(AgentConfig(**SMALL), [])
    with pytest.raises(ValueError, match=r"^the agent needs a square plane \(one output scale for the forward model\); "
                                         r"the task's plane is 30.0 x 40.0 cm$"):
        Agent(AgentConfig(**SMALL), [0], geometry=Geometry(plane_size=(30.0, 40.0)))
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match=r"^device 'cuda' requested but CUDA is not available$"):
            Agent(AgentConfig(**SMALL), [0], device="cuda")
