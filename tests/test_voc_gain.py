"""The graded rule learns its true gain (issue 42 item 2): the gain table, learned on the steps where every budget
could have been used, converges to the gains of a known model, a negative one included; the releases' learning
(the imagined gain, on the steps the rule chose to plan) does not."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from apac_mj.agent.arbitrators import ValueOfComputationArbitrator
from apac_mj.config import AgentConfig, migrate
from apac_mj.types import ArbitrationContext, HabitProbe, Proposal

#: The known model's true gain of k = 1..4 planning iterations over the habit (cm of return) after the planning
#: phase (the habit has improved: one iteration's plan is worse than the habit), and during it.
TRUE_GAIN = np.array([-0.6, 0.4, 0.9, 1.0])
EARLY_GAIN = np.array([0.5, 1.0, 1.5, 2.0])
PHASE, EPISODES, STEPS = 3, 60, 20


def rule(**voc) -> ValueOfComputationArbitrator:
    """4 iterations, window 50, one iteration priced at 10/100 of a step: 0.3 k cm at 3 cm from the target."""
    table = {"iteration_cost": 10.0, "decisions_per_step": 100.0, "window": 50, **voc}
    return ValueOfComputationArbitrator(AgentConfig(kind="apac_voc", planning_episodes=PHASE,
                                                    params={"voc": table, "mpc": {"iterations": 4}}))


def ctx(episode: int, step: int) -> ArbitrationContext:
    """One member 3 cm from its target whose habit is imagined to end 0.7 cm away (bin 1 at a 0.5 cm zone)."""
    state = torch.zeros(1, 6)
    state[0, 0], state[0, 5] = 3.0, 1.0  # hand (3, 0), target (0, 1): 3.16 cm
    probe = HabitProbe(value=torch.tensor([-10.0]), final_distance=torch.tensor([0.7]))
    return ArbitrationContext(episode=torch.tensor([episode]), step=torch.tensor([step]), last_delta=torch.zeros(1),
                              state=state, habit_probe=lambda: probe)


def measured(true: np.ndarray, budget: int, estimate: str, rng: np.random.Generator) -> np.ndarray:
    """``[1, 4]`` what a plan of ``budget`` iterations reports (NaN past it). ``independent``: the true gain plus
    zero-mean noise (an estimate the selection did not see); ``imagined``: the best of the 2 + 32 k candidates as the
    selecting model sees them (true gain + model noise, sd 0.5), and never below the habit (it is in the pool)."""
    out = np.full((1, 4), np.nan, dtype=np.float32)
    for k in range(budget):
        if estimate == "independent":
            out[0, k] = true[k] + rng.normal(0.0, 0.2)
        else:
            out[0, k] = max(0.0, float((true[k] + rng.normal(0.0, 0.5, 2 + 32 * (k + 1))).max()))
    return out


def train(r: ValueOfComputationArbitrator, estimate: str, seed: int = 0, early: np.ndarray = EARLY_GAIN,
          late: np.ndarray = TRUE_GAIN) -> np.ndarray:
    """The rule decides and learns in the known model (gains ``early`` in the planning phase, ``late`` for
    ``EPISODES`` more); its table."""
    rng = np.random.default_rng(seed)
    for episode in range(PHASE + EPISODES):
        true = early if episode < PHASE else late
        for step in range(STEPS):
            r.exploring = True
            d = r.use_habit(ctx(episode, step))
            budget = 0 if bool(d.habit[0]) else int(d.iterations[0])
            info = SimpleNamespace(
                episode=np.array([episode]), zone_radius=0.5, plan_iterations=np.array([budget]),
                arbitration={k: np.asarray(v, dtype=np.float32) for k, v in d.inputs.items()},
                plan_gains=None if budget == 0 else measured(true, budget, estimate, rng),
                decision_seconds=np.array([0.01]))
            r.observe(info, np.array([True]))
    return r.stats["gain"][0, 1, :4].numpy()


def test_the_table_learned_on_unselected_steps_converges_to_the_true_gains_a_negative_one_included():
    """Re-explored at the full budget with probability 0.25, the independent estimate teaches every k on the same
    steps: each entry ends within 0.1 cm of the known model's gain (EMA noise: 0.2 / sqrt(100) = 0.02)."""
    table = train(rule(learn_on="unselected", explore=0.25), "independent")
    np.testing.assert_allclose(table, TRUE_GAIN, atol=0.1)
    assert table[0] < 0


def test_the_releases_learning_fails_the_known_model():
    """The imagined gain on the steps the rule chose: never negative (k = 1 stays >= 0 against -0.6), and biased
    upwards at every k by the maximum over the candidates; with the independent estimate but only the rule's steps,
    the entries the rule stops granting stay where they were."""
    old = train(rule(learn_on="planned", explore=0.0), "imagined")
    assert old[0] >= 0 and np.abs(old - TRUE_GAIN).max() > 0.5
    assert np.all(old > TRUE_GAIN)
    selected = train(rule(learn_on="planned", explore=0.0), "independent")
    assert np.abs(selected - TRUE_GAIN).max() > 0.1


def test_learned_where_the_rule_planned_the_table_inverts_k_4_and_k_3_from_selection_alone():
    """The gains grow after the planning phase (0.5, 1.0, 1.6, 1.7 -> 0.6, 1.5, 2.4, 3.0; cost 0.3 k): the rule
    first buys 3 iterations (net 0.7 against 0.5 for 4) and, learning only k <= 3, never measures k = 4 again:
    G[4] stays 1.7 below G[3]'s 2.4, an unbiased estimate notwithstanding. Learned on the unselected steps, the
    table follows every k."""
    early, late = np.array([0.5, 1.0, 1.6, 1.7]), np.array([0.6, 1.5, 2.4, 3.0])
    old = train(rule(learn_on="planned", explore=0.0), "independent", early=early, late=late)
    assert old[3] < old[2] - 0.5
    new = train(rule(learn_on="unselected", explore=0.25), "independent", early=early, late=late)
    np.testing.assert_allclose(new, late, atol=0.1)


def test_re_exploration_is_a_stated_rate_only_in_training_and_the_same_in_an_ensemble_and_alone():
    r = rule(explore=0.25)
    draws = []
    for episode in range(PHASE, PHASE + 40):
        for step in range(20):
            r.exploring = True
            draws.append(bool(r.explores(ctx(episode, step))[0]))
    assert 0.2 < np.mean(draws) < 0.3  # 800 draws: sd 0.015
    r.exploring = False
    assert not r.explores(ctx(PHASE, 0)).any()
    pair = ArbitrationContext(episode=torch.tensor([7, 7]), step=torch.tensor([3, 4]), last_delta=torch.zeros(2))
    r.exploring = True
    alone = [bool(r.explores(ctx(7, s))[0]) for s in (3, 4)]
    assert r.explores(pair).tolist() == alone


def test_the_imagined_gain_is_the_plans_best_minus_the_habits():
    r = rule(gain="imagined")
    plan = Proposal(torch.zeros(1, 2), torch.tensor([2]), torch.tensor([[-4.0, -3.0, float("nan"), float("nan")]]),
                    torch.tensor([-5.0]), torch.zeros(1, 4, 4, 2))
    gains = r.plan_gains(None, ctx(PHASE, 0), plan, None)
    np.testing.assert_allclose(gains, [[1.0, 2.0, np.nan, np.nan]])
    unheld = SimpleNamespace(dynamics_model=None)  # an apac run re-arbitrated by the graded rule (record --agent)
    np.testing.assert_allclose(rule().plan_gains(unheld, ctx(PHASE, 0), plan, None), gains)


def test_old_runs_load_with_the_releases_estimator_and_new_runs_get_the_new_one():
    old = migrate({"agent": {"kind": "apac_voc", "voc": {"window": 50, "cost": "fixed", "iteration_cost": 7.0,
                                                          "decisions_per_step": 14.0}}})["agent"]["voc"]
    assert (old["gain"], old["learn_on"], old["explore"]) == ("imagined", "planned", 0.0)
    new = AgentConfig(kind="apac_voc").params["voc"]
    assert (new.gain, new.learn_on, new.explore) == ("heldout", "unselected", 0.1)


@pytest.mark.parametrize("voc, message", [
    ({"gain": "best"}, r"agent.voc.gain must be one of \('heldout', 'imagined', 'advantage'\), got 'best'"),
    ({"learn_on": "all"}, r"agent.voc.learn_on must be 'unselected' or 'planned', got 'all'"),
    ({"explore": 1.5}, r"agent.voc.explore must be in \[0, 1\], got 1.5"),
    ({"explore": 0.0}, r"agent.voc.learn_on = 'unselected' needs explore > 0")])
def test_bad_settings_are_refused_naming_the_field(voc, message):
    with pytest.raises(ValueError, match=message):
        AgentConfig(kind="apac_voc", params={"voc": voc})


# -- the held-out dynamics heads ------------------------------------------------------------------------------
from apac_mj.agent.agent import Agent  # noqa: E402
from apac_mj.agent.arbitrators import HeldOutView, held_out_dynamics, heldout_gains  # noqa: E402
from apac_mj.agent.networks import DynamicsHeads  # noqa: E402
from apac_mj.agent.planner import MPCPlanner  # noqa: E402

TINY = dict(actor_hidden=(16, 16), critic_hidden=(16, 16), forward_hidden=(16, 16), inverse_hidden=(16, 16))


class Constant(torch.nn.Module):
    def __init__(self, c: float) -> None:
        super().__init__()
        self.c = c

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.full_like(x, self.c)


def test_held_out_heads_are_left_out_of_the_prediction_and_are_their_own():
    """Heads predicting 1, 2 and 6: the plain mean 3; with the last held out, 1.5 planned through and 6 held out."""
    x = torch.zeros(1, 2)
    assert DynamicsHeads([Constant(1.0), Constant(2.0), Constant(6.0)])(x).tolist() == [[3.0, 3.0]]
    heads = DynamicsHeads([Constant(1.0), Constant(2.0), Constant(6.0)], held_out=1)
    assert heads(x).tolist() == [[1.5, 1.5]] and heads.held_out_mean(x).tolist() == [[6.0, 6.0]]
    assert heads.each(x).shape == (3, 1, 2)  # every head is trained
    with pytest.raises(ValueError, match=r"held_out must be in \[0, 2\]"):
        DynamicsHeads([Constant(1.0), Constant(2.0), Constant(6.0)], held_out=3)
    with pytest.raises(ValueError, match=r"agent.mpc.held_out_heads must be an integer in \[0, model_heads - 1 = 1\]"):
        AgentConfig(kind="apac_voc", params={"mpc": {"model_heads": 2, "held_out_heads": 2}})
    with pytest.raises(ValueError, match=r"^voc.gain = 'heldout' needs a held-out dynamics head"):
        HeldOutView(SimpleNamespace(dynamics_model=Constant(1.0)))


def test_the_graded_rule_valuing_by_a_held_out_head_gets_one_head_more_and_no_other_rule_does():
    from apac_mj.agent.arbitrators import VisionAwareArbitrator
    from apac_mj.kinds import arbitrator_for
    from apac_mj.rules import MPCParams

    mpc = MPCParams()
    assert (held_out_dynamics(rule(), mpc).model_heads, held_out_dynamics(rule(), mpc).held_out_heads) == (2, 1)
    assert held_out_dynamics(rule(gain="imagined"), mpc) == mpc
    own = MPCParams(model_heads=3, held_out_heads=1)
    assert held_out_dynamics(rule(), own) == own
    assert held_out_dynamics(arbitrator_for(AgentConfig(kind="apac_mpc")), mpc) == mpc
    seeing = VisionAwareArbitrator(AgentConfig(kind="apac_vision"), rule())
    assert held_out_dynamics(seeing, mpc).held_out_heads == 1


def _held_out_agent() -> tuple[Agent, AgentConfig]:
    cfg = AgentConfig(kind="apac_voc", **TINY, params={"mpc": {"model_heads": 2, "held_out_heads": 1, "horizon": 3,
                                                               "candidates": 16, "elites": 4, "iterations": 3},
                                                       "voc": {"gain": "heldout"}})
    return Agent(cfg, [0, 1], dynamics=cfg.params["mpc"]), cfg


def test_the_held_out_gain_values_the_plan_through_the_head_it_was_not_selected_by():
    """With the held-out head a copy of the planned one, the held-out gain is the imagined gain exactly; with its
    own initialization, it differs (and the view imagines through that head alone)."""
    agent, cfg = _held_out_agent()
    g = torch.Generator().manual_seed(0)
    state = torch.rand(2, 6, generator=g) * 20  # hand, elbow, target (cm)
    c = ArbitrationContext(episode=torch.zeros(2, dtype=torch.long), step=torch.zeros(2, dtype=torch.long),
                           last_delta=torch.zeros(2), state=state)
    planner = MPCPlanner(cfg.params["mpc"], [0, 1], 2)
    plan = planner.propose(agent, c, torch.tensor([3, 2]))
    r = ValueOfComputationArbitrator(cfg)
    own = r.plan_gains(agent, c, plan, planner)
    assert np.isnan(own[1, 2]) and np.isfinite(own[:, :2]).all()
    heads = agent.dynamics_model.heads
    action = torch.zeros(2, 1, 2)
    x = agent.inputs.state(state[:, None])
    expected = agent.inputs.from_motion(agent.inputs.motion_x(x) + heads[1](agent.inputs.model_input(x, action)),
                                        state[:, None])
    torch.testing.assert_close(HeldOutView(agent).imagine(state[:, None], action), expected)
    heads[1].load_state_dict(heads[0].state_dict())
    same = heldout_gains(agent, planner, state, plan.best_sequences).numpy()
    imagined = (plan.best_values - plan.habit_value[:, None]).numpy()
    np.testing.assert_allclose(same[0], imagined[0], rtol=1e-5, atol=1e-4)
    assert np.abs(own[0] - imagined[0]).max() > 1e-3
