"""The inverse model trained like the dynamics model (issue 41, item 5): ``inverse_updates`` extra Adam steps of
the inverse model alone after every update, and its own ``inverse_weight_decay``; the defaults keep the paper's
one step and 1e-3."""
from __future__ import annotations

import pytest
import torch

from apac_mj.agent.agent import Agent
from apac_mj.config import AgentConfig, TrainConfig, migrate, to_dict, train_config_from_dict
from apac_mj.layout import Sizes
from conftest import fill_and_update

TINY = dict(actor_hidden=(16, 16), critic_hidden=(16, 16), forward_hidden=(16, 16), inverse_hidden=(16, 16))
SIZES = Sizes(state_dim=8, extra_scale=(500.0, 500.0), action_bound=2.0, angle_actions=False)


def _updated(**kw) -> Agent:
    return fill_and_update(Agent(AgentConfig(kind="spac", **TINY, batch_size=4, **kw), [0, 1], sizes=SIZES))


def _same(a: torch.nn.Module, b: torch.nn.Module, member: int) -> list[bool]:
    return [torch.equal(p[member], q[member]) for p, q in zip(a.parameters(), b.parameters())]


def test_the_extra_inverse_steps_move_only_the_inverse_model_of_the_active_member():
    plain, more = _updated(), _updated(inverse_updates=3)
    for name in ("actor", "critic", "forward_model"):
        assert all(_same(getattr(plain, name), getattr(more, name), 0)), name
    assert not any(_same(plain.inverse_model, more.inverse_model, 0)), "every inverse-model weight moves"
    assert all(_same(plain.inverse_model, more.inverse_model, 1)), "the inactive member is left alone"


def test_an_extra_inverse_step_lowers_the_inverse_models_loss_on_its_batch():
    agent = _updated()
    batch = agent.replay.sample(4, [0])
    x = agent.inputs.state(batch["state"])
    before = agent._inverse_loss(x, batch)[0].item()
    for _ in range(20):
        agent._model_step(batch, [0], "inverse_model")
    assert agent._inverse_loss(x, batch)[0].item() < before


@pytest.mark.parametrize("kw, expected", [({}, 1e-3), ({"weight_decay": 2e-3}, 2e-3),
                                          ({"inverse_weight_decay": 0.0}, 0.0),
                                          ({"inverse_weight_decay": 5e-4, "weight_decay": 2e-3}, 5e-4)])
def test_the_inverse_model_has_its_own_weight_decay_defaulting_to_the_papers(kw, expected):
    agent = Agent(AgentConfig(kind="spac", **TINY, **kw), [0, 1], sizes=SIZES)
    decay = {name: g["weight_decay"] for name, g in zip(agent.trained, agent.optimizer.param_groups)}
    assert decay["inverse_model"] == expected
    assert decay["actor"] == decay["critic"] == decay["forward_model"] == kw.get("weight_decay", 1e-3)


@pytest.mark.parametrize("field, value", [("inverse_updates", -1), ("inverse_weight_decay", -0.1),
                                          ("inverse_weight_decay", 2.0), ("inverse_updates", True)])
def test_bad_inverse_budgets_are_refused(field, value):
    with pytest.raises(ValueError, match=field):
        AgentConfig(**{field: value})


def test_a_config_written_before_the_fields_keeps_the_papers_inverse_training():
    old = to_dict(TrainConfig(agent=AgentConfig(kind="spac")))
    del old["agent"]["inverse_updates"], old["agent"]["inverse_weight_decay"]
    agent = train_config_from_dict(migrate(old)).agent
    assert (agent.inverse_updates, agent.inverse_weight_decay) == (0, None)
