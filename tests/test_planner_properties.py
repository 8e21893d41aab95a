"""The planner's valuation and MPPI refit against answers computed by hand (the fidelity audit, section 2).

A point hand with an exact model (the next hand is the hand plus the action) and a *known, non-zero* critic:
``V(s) = -C |hand - target| + W hand_y``. Each test pins one ingredient the audit found a wrong version of
passing the older tests: the terminal value ``gamma^H V(s_H)`` (not ``gamma^(H-1)``, not the start state's, not
after an arrival, not dropped, not subtracted), the elite weights ``softmax(tau (v - v_max))``, and the habit's
sequence in every refit. ``docs/mutation.md`` lists the mutants these tests kill.
"""
from __future__ import annotations

import dataclasses
import math

import pytest
import torch
from conftest import ExactPointHand

from apac_mj.agent.planner import MPCPlanner
from apac_mj.config import AgentConfig
from apac_mj.layout import Sizes, StateLayout
from apac_mj.rules import MPCParams
from apac_mj.types import END, TARGET, ArbitrationContext

GAMMA, C, W = 0.9, 2.0, 0.0


class CriticHand(ExactPointHand):
    """An exact point-hand model (cm; ``scale`` cm per tanh unit) whose habit repeats ``habit`` (tanh units)
    and whose critic is ``V(s) = -c |hand - target| + w hand_y``."""

    def __init__(self, habit: tuple[float, float] = (0.25, 0.0), c: float = C, w: float = W,
                 scale: float = 2.0) -> None:
        self.cfg = dataclasses.replace(AgentConfig(), gamma=GAMMA)
        self.habit, self.c, self.w, self.scale = torch.tensor(habit), c, w, scale
        self.layout = StateLayout(Sizes(state_dim=8, extra_scale=(1.0, 1.0)))

    def habit_u(self, s: torch.Tensor) -> torch.Tensor:
        return self.habit.expand(*s.shape[:-1], 2).clone()

    def value(self, s: torch.Tensor) -> torch.Tensor:
        return -self.c * torch.linalg.vector_norm(s[..., END] - s[..., TARGET], dim=-1) + self.w * s[..., 1]

    def critic(self, hand: tuple[float, float], target: tuple[float, float]) -> float:
        """``V`` of a hand and target (plain floats: the hand computation's own critic)."""
        dx, dy = hand[0] - target[0], hand[1] - target[1]
        return -self.c * (dx * dx + dy * dy) ** 0.5 + self.w * hand[1]


def _state(hand: tuple[float, float], target: tuple[float, float]) -> torch.Tensor:
    """One member's state ``[1, 8]``: hand, elbow (unused), target, two joint speeds of 0."""
    return torch.tensor([[hand[0], hand[1], 0.0, 0.0, target[0], target[1], 0.0, 0.0]])


def _ctx(state: torch.Tensor) -> ArbitrationContext:
    E = len(state)
    return ArbitrationContext(episode=torch.zeros(E, dtype=torch.long), step=torch.zeros(E, dtype=torch.long),
                              last_delta=torch.zeros(E), state=state, zone_radius=0.5)


def _planner(**kw) -> MPCPlanner:
    return MPCPlanner(MPCParams(**{**dict(horizon=3, candidates=8, elites=2, iterations=1, habit_candidates=1),
                                   **kw}), seeds=[0])


def _by_hand(agent: CriticHand, hand: tuple[float, float], target: tuple[float, float], steps: list,
             zone: float = 0.5) -> float:
    """``sum_t gamma^t r_t + gamma^H V(s_H)``, ``r_t = -|hand_{t+1} - target|``; after an arrival nothing more."""
    total, (x, y) = 0.0, hand
    for t, (ax, ay) in enumerate(steps):
        x, y = x + agent.scale * ax, y + agent.scale * ay
        d = ((x - target[0]) ** 2 + (y - target[1]) ** 2) ** 0.5
        total -= GAMMA ** t * d
        if d <= zone:
            return total
    return total + GAMMA ** len(steps) * agent.critic((x, y), target)


def test_the_habits_value_is_the_discounted_return_plus_the_discounted_critic_at_the_horizon():
    """Hand (0, 0), target (3, 0), the habit 0.5 cm a step: distances 2.5, 2, 1.5, never inside the zone, so
    ``-(2.5 + 0.9 * 2 + 0.81 * 1.5) + 0.9^3 V(s_3)`` with ``V(s_3) = -2 * 1.5`` (not the start's -6)."""
    agent, state = CriticHand(), _state((0.0, 0.0), (3.0, 0.0))
    expected = -(2.5 + 0.9 * 2.0 + 0.81 * 1.5) + 0.729 * (-3.0)
    assert _by_hand(agent, (0.0, 0.0), (3.0, 0.0), [(0.25, 0.0)] * 3) == pytest.approx(expected, abs=1e-12)
    planner = _planner()
    value, hands, u = planner.rollout(agent, state)
    assert value.item() == pytest.approx(expected, abs=1e-5)
    assert hands[0, 0, -1].tolist() == pytest.approx([1.5, 0.0])
    assert planner.probe(agent, state).value.item() == pytest.approx(expected, abs=1e-5)
    torch.testing.assert_close(u[0, 0], agent.habit.expand(3, 2))


def test_after_an_imagined_arrival_neither_reward_nor_the_critic_counts():
    """Hand (0, 0), target (1, 0), the habit 0.5 cm a step: inside the zone (0.5 cm) after the first step, so the
    value is that step's -0.5 alone; the critic at the horizon (-2 * 0.5 there) is not added."""
    agent, state = CriticHand(), _state((0.0, 0.0), (1.0, 0.0))
    assert _by_hand(agent, (0.0, 0.0), (1.0, 0.0), [(0.25, 0.0)] * 3) == pytest.approx(-0.5)
    value, hands, _ = _planner().rollout(agent, state)
    assert hands[0, 0, -1].tolist() == pytest.approx([1.5, 0.0])  # the hand went on; its value did not
    assert value.item() == pytest.approx(-0.5, abs=1e-6)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_any_sequence_is_valued_by_the_same_sum(seed):
    """Random sequences (some arriving, some not) from random hands: each value is the hand-computed sum."""
    g = torch.Generator().manual_seed(seed)
    agent = CriticHand(c=1.5, w=0.7)
    hand, target = (torch.rand(2, generator=g) * 4).tolist(), (torch.rand(2, generator=g) * 4).tolist()
    u = torch.rand(1, 16, 4, 2, generator=g) * 2 - 1
    value, _, _ = _planner(horizon=4).rollout(agent, _state(hand, target), u)
    expected = [_by_hand(agent, hand, target, u[0, b].tolist()) for b in range(16)]
    assert value[0].tolist() == pytest.approx(expected, abs=1e-4)


def test_of_two_sequences_tied_on_reward_the_one_the_critic_prefers_is_valued_and_chosen_higher():
    """Up (0.25, 0.25) and down (0.25, -0.25) towards a target at (3, 0) are at the same distances every step;
    a critic that likes ``hand_y`` (w = 1) values the upper end 3 cm higher, ``gamma^3 * 3`` more in all. With
    the habit going up and the sampled sequences all (within 1e-4) going down, the plan goes up."""
    agent = CriticHand(habit=(0.25, 0.25), c=0.0, w=1.0)
    state = _state((0.0, 0.0), (3.0, 0.0))
    up, down = torch.tensor([0.25, 0.25]).expand(3, 2), torch.tensor([0.25, -0.25]).expand(3, 2)
    planner = _planner(candidates=16, min_std=1e-4, max_std=1e-4)
    value, _, _ = planner.rollout(agent, state, torch.stack([up, down])[None])
    assert value[0, 0] - value[0, 1] == pytest.approx(GAMMA ** 3 * 3.0, abs=1e-5)
    planner.mean = down[None].clone()
    plan = planner.propose(agent, _ctx(state), torch.ones(1, dtype=torch.long))
    assert plan.action[0].tolist() == pytest.approx([0.5, 0.5])
    assert planner.last_plan["hand"][0, -1].tolist() == pytest.approx([1.5, 1.5])
    assert plan.best_values[0, 0].item() == pytest.approx(value[0, 0].item(), abs=1e-6)


@pytest.mark.parametrize("temperature", [0.5, 2.0])
def test_the_refit_weights_two_known_elites_by_the_softmax_of_their_value_gap(temperature):
    """Elites A (value -1) and B (value -2): weights ``softmax(tau (v - v_max))`` = (1, e^-tau) / (1 + e^-tau);
    the mean is their weighted mean, the spread their weighted deviation (clamped to [min_std, max_std])."""
    planner = _planner(candidates=2, elites=2, temperature=temperature, min_std=1e-3, max_std=5.0)
    a, b = torch.full((3, 2), 0.8), torch.full((3, 2), -0.4)
    u = torch.stack([b, a, torch.zeros(3, 2)])[None]
    v = torch.tensor([[-2.0, -1.0, -9.0]])
    mean, std = planner._refit(u, v)
    wa = 1.0 / (1.0 + torch.exp(torch.tensor(-temperature))).item()
    expected = wa * 0.8 + (1 - wa) * -0.4
    torch.testing.assert_close(mean, torch.full((1, 3, 2), expected))
    spread = (wa * (0.8 - expected) ** 2 + (1 - wa) * (-0.4 - expected) ** 2) ** 0.5
    torch.testing.assert_close(std, torch.full((1, 3, 2), spread))


def test_a_habit_better_than_every_sample_pulls_the_next_mean_to_itself():
    """The habit heads straight for the target (0.4, 0: 0.8 cm a step); the sampled sequences stay within 1e-3 of
    a mean of 0 (the hand stays put). With one elite the refit's mean is the habit's sequence: the warm start
    (shifted one step) is 0.4, 0 then the appended zero. Left out of the refit, the mean would stay near 0."""
    agent = CriticHand(habit=(0.4, 0.0))
    planner = _planner(candidates=4, elites=1, min_std=1e-3, max_std=1e-3)
    state = _state((0.0, 0.0), (3.0, 0.0))
    planner.propose(agent, _ctx(state), torch.ones(1, dtype=torch.long))
    expected = torch.tensor([[[0.4, 0.0], [0.4, 0.0], [0.0, 0.0]]])
    torch.testing.assert_close(planner.mean, expected)


def test_the_probe_reads_the_habits_value_and_its_distance_at_the_horizon_once_per_state():
    """The probe: the habit's value and its imagined hand's distance from the target at the horizon (1.5 cm); the
    plan from the same state object reuses that rollout, a new state object gets its own."""
    agent, state = CriticHand(), _state((0.0, 0.0), (3.0, 0.0))
    planner, calls = _planner(), []
    rollout = planner.rollout
    planner.rollout = lambda a, s, u=None: calls.append(u is None) or rollout(a, s, u)
    probe = planner.probe(agent, state)
    assert probe.final_distance.tolist() == pytest.approx([1.5]) and probe.value.shape == (1,)
    plan = planner.propose(agent, _ctx(state), torch.ones(1, dtype=torch.long))
    assert calls.count(True) == 1 and plan.habit_value.item() == pytest.approx(probe.value.item())
    other = planner.probe(agent, _state((1.0, 0.0), (3.0, 0.0)))
    assert calls.count(True) == 2 and other.final_distance.tolist() == pytest.approx([0.5])


def test_an_imagined_arrival_is_inclusive_at_the_zones_edge_and_at_the_stop_speed():
    """The environment's criterion, ``<=``: a hand exactly 0.5 cm away (zone 0.5) has arrived, and so has one whose
    fastest joint moves exactly ``stop_speed``; each member's own fastest joint counts."""
    agent = CriticHand(habit=(0.25, 0.0), c=0.0)
    edge, _, _ = _planner().rollout(agent, _state((0.0, 0.0), (0.5, 0.5)))
    assert edge.item() == pytest.approx(-0.5)  # then 0.707 cm away: not counted
    planner = MPCPlanner(MPCParams(horizon=2, candidates=8, elites=2, iterations=1), seeds=[0, 1], stop_speed=10.0)
    state = torch.tensor([[0.0, 0.0, 0.0, 0.0, 0.5, 0.5, 10.0, -3.0], [0.0, 0.0, 0.0, 0.0, 0.5, 0.5, 2.0, 10.5]])
    value, _, _ = planner.rollout(agent, state)
    assert value[0, 0].item() == pytest.approx(-0.5)
    assert value[1, 0].item() == pytest.approx(-0.5 - GAMMA * 0.5 ** 0.5)


class WalledHand(CriticHand):
    """The point hand inside a box ``|x|, |y| <= wall``: an action maps onto the moves the pose allows (the real
    agent's "feasible" squash) and is clipped to them, both in the pose it is taken from."""

    wall = 1.5

    def _range(self, s: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return -self.wall - s[..., END], self.wall - s[..., END]

    def to_action(self, u: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
        lo, hi = self._range(s)
        return lo + (hi - lo) * (u + 1.0) / 2.0

    def executable(self, a: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
        lo, hi = self._range(s)
        return torch.minimum(torch.maximum(a, lo), hi)


def test_actions_are_mapped_in_the_imagined_pose_and_the_proposal_in_the_current_one():
    """In the box of half-width 1.5, u = (1, 0) moves the hand to the wall from wherever it is: 1.5 cm away from
    a target at (3, 0) every step; the proposal for u = (1, 0) from (0.5, 0) is the 1 cm left to the wall."""
    agent = WalledHand(habit=(1.0, 0.0), c=0.0)
    value, hands, _ = _planner().rollout(agent, _state((0.0, 0.0), (3.0, 0.0)))
    assert hands[0, 0, 1:, 0].tolist() == pytest.approx([1.5, 1.5, 1.5])
    assert value.item() == pytest.approx(-1.5 * (1 + GAMMA + GAMMA ** 2))
    plan = _planner(min_std=1e-3, max_std=1e-3).propose(agent, _ctx(_state((0.5, 0.0), (3.0, 0.0))),
                                                        torch.ones(1, dtype=torch.long))
    assert plan.action[0, 0].item() == pytest.approx(1.0)


def test_on_a_tie_the_plan_keeps_the_sequence_found_first():
    """Up (1, 1) (the habit) and down (1, -1) (every sample: the mean is far outside the box, so each sample is
    clipped to it exactly) tie on every step's reward with a critic of 0: the habit's sequence is kept."""
    agent = CriticHand(habit=(1.0, 1.0), c=0.0)
    planner = _planner(min_std=1e-3, max_std=1e-3)
    planner.mean = torch.tensor([5.0, -5.0]).expand(1, 3, 2).clone()
    plan = planner.propose(agent, _ctx(_state((0.0, 0.0), (3.0, 0.0))), torch.ones(1, dtype=torch.long))
    assert plan.action[0].tolist() == pytest.approx([2.0, 2.0])


def test_a_budget_is_cut_to_zero_and_to_the_planners_iterations():
    agent, state = CriticHand(), _state((0.0, 0.0), (3.0, 0.0))
    planner = _planner(iterations=2)
    assert planner.max_iterations == 2 and planner.last_plan is None
    plan = planner.propose(agent, _ctx(state), torch.tensor([7]))
    assert plan.iterations.tolist() == [2] and torch.isfinite(plan.best_values).all()
    plan = planner.propose(agent, _ctx(state), torch.tensor([-3]))
    assert plan.iterations.tolist() == [0]


def test_no_budget_no_plan_and_the_warm_start_moves_on():
    """Every member granted 0 iterations: a zero action, no values, no habit value, no recorded plan; the warm
    start still moves one step on (the next decision is one step later)."""
    agent, planner = CriticHand(), _planner(iterations=2)
    planner.mean = torch.tensor([[[0.1, 0.2], [0.3, 0.4], [0.5, 0.6]]])
    plan = planner.propose(agent, _ctx(_state((0.0, 0.0), (3.0, 0.0))), torch.zeros(1, dtype=torch.long))
    assert plan.action.tolist() == [[0.0, 0.0]] and plan.iterations.tolist() == [0]
    assert plan.best_values.shape == (1, 2) and torch.isnan(plan.best_values).all()
    assert plan.habit_value is None and planner.last_plan is None
    torch.testing.assert_close(planner.mean, torch.tensor([[[0.3, 0.4], [0.5, 0.6], [0.0, 0.0]]]))


def test_the_recorded_plan_is_the_best_hand_and_eight_candidates():
    agent = CriticHand()
    planner = _planner(candidates=16, iterations=2)
    planner.propose(agent, _ctx(_state((0.0, 0.0), (3.0, 0.0))), torch.full((1,), 2))
    assert set(planner.last_plan) == {"hand", "candidates"}
    assert planner.last_plan["hand"].shape == (1, 4, 2) and planner.last_plan["candidates"].shape == (1, 8, 4, 2)


@pytest.mark.parametrize("habit_candidates, habit_noise, budget, copies", [
    (3, 0.1, 1, 2), (2, 0.1, 2, 1), (1, 0.1, 1, 0), (3, 0.0, 1, 0)])
def test_the_habits_copies_are_perturbed_by_habit_noise_inside_the_box(habit_candidates, habit_noise, budget,
                                                                         copies):
    """``habit_candidates - 1`` copies of the habit's sequence (0.95, -0.95), each step moved by about
    ``habit_noise`` (within 5 sigma) and clipped to [-1, 1]; none with one candidate or no noise."""
    agent = CriticHand(habit=(0.95, -0.95))
    planner = _planner(habit_candidates=habit_candidates, habit_noise=habit_noise, iterations=2, candidates=64)
    seen = []
    rollout = planner.rollout
    planner.rollout = lambda a, s, u=None: seen.append(u) or rollout(a, s, u)
    planner.propose(agent, _ctx(_state((0.0, 0.0), (3.0, 0.0))), torch.full((1,), budget))
    extra = [u for u in seen if u is not None and u.shape[1] != 64]
    assert len(extra) == (1 if copies else 0)
    if copies:
        u = extra[0]
        assert u.shape == (1, copies, 3, 2) and u.abs().max() <= 1.0
        assert 0 < (u - agent.habit).abs().max() <= 5 * habit_noise
        assert (u == 1.0).any() or (u == -1.0).any(), "clipped at the box"


def test_the_refits_spread_is_clamped_between_min_std_and_max_std():
    planner = _planner(candidates=2, elites=2, min_std=0.05, max_std=0.3)
    same = torch.full((1, 2, 3, 2), 0.2)
    _, std = planner._refit(same, torch.tensor([[-1.0, -1.0]]))
    torch.testing.assert_close(std, torch.full((1, 3, 2), 0.05))
    far = torch.stack([torch.full((3, 2), 1.0), torch.full((3, 2), -1.0)])[None]
    _, std = planner._refit(far, torch.tensor([[-1.0, -1.0]]))
    torch.testing.assert_close(std, torch.full((1, 3, 2), 0.3))


def test_a_saved_plan_state_of_another_shape_is_refused_naming_both():
    planner = _planner()
    with pytest.raises(ValueError, match=r"mean \(1, 4, 2\), 1 streams; this planner has \(1, 3, 2\), 1"):
        planner.load_state_dict({"mean": torch.zeros(1, 4, 2), "generators": [g.get_state()
                                                                               for g in planner.generators]})
    with pytest.raises(ValueError, match=r"mean \(1, 3, 2\), 2 streams; this planner has \(1, 3, 2\), 1"):
        planner.load_state_dict({"mean": torch.zeros(1, 3, 2), "generators": [planner.generators[0].get_state()] * 2})


def test_the_papers_planner_asks_the_inverse_model_once_when_granted_any_iteration():
    class Inverse:
        def inverse_action(self, s: torch.Tensor) -> torch.Tensor:
            return s[:, TARGET] - s[:, END]

    from apac_mj.agent.planner import InversePlanner

    state = torch.cat([_state((0.0, 1.0), (3.0, 0.0)), _state((1.0, 1.0), (0.0, 0.0))])
    plan = InversePlanner().propose(Inverse(), _ctx(state), torch.tensor([0, 1]))
    assert plan.action.tolist() == [[3.0, -1.0], [-1.0, -1.0]] and plan.iterations.tolist() == [0, 1]
    assert InversePlanner().propose(Inverse(), _ctx(state), torch.tensor([2, 5])).iterations.tolist() == [1, 1]


def test_every_member_has_its_own_planning_stream_apart_from_its_seeds_plain_stream():
    """Ten members' first draws all differ, and none is the first draw of the member's other streams (the agent's
    init, replay and noise generators) or of a generator seeded with the seed itself."""
    from apac_mj.agent.agent import member_generators

    planner = MPCPlanner(MPCParams(), seeds=list(range(10)))
    first = [torch.randn(4, generator=g) for g in planner.generators]
    assert len({tuple(x.tolist()) for x in first}) == 10
    for seed, x in enumerate(first):
        others = [*member_generators(seed), torch.Generator().manual_seed(seed)]
        assert not any(torch.equal(x, torch.randn(4, generator=g)) for g in others)


# -- the cued task's terminal value (issue 42 item 5) -----------------------------------------------------------
# After a remap the habit's critic, which reads the cue, values the old target; with ``told_value`` the planner
# closes its horizon with the critic of the cue the told target had, found by imagining every cue's habit. A point
# hand whose habit heads for its cue's practised target and whose critic is ``-C |hand - practised target|``.
#: The practised targets of cues 0 and 1 (cm).
PRACTISED = torch.tensor([[4.0, 0.0], [0.0, 4.0]])


class CuedHand(ExactPointHand):
    """State ``[hand, elbow, target, cue (2, one-hot)]``; the habit moves 2 cm a step towards its cue's practised
    target (stopping there), the critic reads the cue, not the target."""

    def __init__(self) -> None:
        self.cfg = dataclasses.replace(AgentConfig(), gamma=GAMMA)
        self.layout = StateLayout(Sizes(state_dim=8, extra_scale=(1.0, 1.0), cue_dim=2))
        self.calls = 0

    def _practised(self, s: torch.Tensor) -> torch.Tensor:
        return s[..., 6:8] @ PRACTISED

    def habit_u(self, s: torch.Tensor) -> torch.Tensor:
        self.calls += 1
        return ((self._practised(s) - s[..., END]) / self.scale).clamp(-1.0, 1.0)

    def value(self, s: torch.Tensor) -> torch.Tensor:
        return -C * torch.linalg.vector_norm(s[..., END] - self._practised(s), dim=-1)


def _cued_state(hand, target, cue: int) -> torch.Tensor:
    onehot = [1.0, 0.0] if cue == 0 else [0.0, 1.0]
    return torch.tensor([[*hand, 0.0, 0.0, *target, *onehot]])


def _told_planner(told: bool) -> MPCPlanner:
    planner = MPCPlanner(MPCParams(horizon=3, candidates=4, elites=2, iterations=1, habit_candidates=1), seeds=[0],
                         zone_radius=0.5)
    planner.told_value = told
    return planner


def test_the_told_cue_is_the_one_whose_habit_ends_nearest_the_told_target():
    agent = CuedHand()
    remapped = _cued_state((1.0, 0.0), (0.0, 4.0), cue=0)  # cue 0 shown, told cue 1's practised target
    assert _told_planner(True).told_cue(agent, remapped).tolist() == [[0.0, 1.0]]
    unchanged = _cued_state((1.0, 0.0), (4.0, 0.0), cue=0)
    assert _told_planner(True).told_cue(agent, unchanged).tolist() == [[1.0, 0.0]]
    assert _told_planner(False).told_cue(agent, remapped) is None  # off: the shown cue's critic
    no_cue = ExactPointHand()
    no_cue.layout = StateLayout(Sizes(state_dim=8, extra_scale=(1.0, 1.0)))
    assert _told_planner(True).told_cue(no_cue, remapped) is None  # a task without cues: nothing to find


def test_the_cue_search_runs_once_per_cued_state():
    agent, planner = CuedHand(), _told_planner(True)
    state = _cued_state((1.0, 0.0), (0.0, 4.0), cue=0)
    planner.told_cue(agent, state)
    calls = agent.calls
    assert calls == 3  # the horizon's 3 habit passes, every cue in one batch
    planner.told_cue(agent, state)
    assert agent.calls == calls
    planner.told_cue(agent, state.clone())
    assert agent.calls == 2 * calls


@pytest.mark.parametrize("told, terminal_distance", [(False, 3.0), (True, math.sqrt(17.0))])
def test_a_sequence_is_closed_by_the_critic_of_the_told_cue(told, terminal_distance):
    """Standing still at (1, 0), told (0, 4) with cue 0 shown: 3 steps at sqrt(17) cm, then V of the hand
    against cue 0's practised target (4, 0): 3 cm (the old target), or cue 1's, the told one: sqrt(17) cm."""
    agent = CuedHand()
    state = _cued_state((1.0, 0.0), (0.0, 4.0), cue=0)
    value, hands, _ = _told_planner(told).rollout(agent, state, torch.zeros(1, 1, 3, 2))
    reward = -math.sqrt(17.0) * (1 + GAMMA + GAMMA ** 2)
    assert value.item() == pytest.approx(reward - GAMMA ** 3 * C * terminal_distance, rel=1e-6)
    assert hands[0, 0, -1].tolist() == [1.0, 0.0]


def test_with_the_told_value_the_plan_prefers_ending_towards_the_told_target():
    """Two sequences tied on reward (each ends 3 steps at the same distances from the told target (0, 4)), one
    ending nearer the old target (4, 0): the shown cue's critic prefers it, the told cue's does not."""
    agent = CuedHand()
    state = _cued_state((0.0, 0.0), (0.0, 4.0), cue=0)
    right = torch.tensor([[0.5, 0.0], [0.0, 0.0], [0.0, 0.0]])   # to (1, 0): |(1,0)-(0,4)| = sqrt(17)
    left = torch.tensor([[-0.5, 0.0], [0.0, 0.0], [0.0, 0.0]])   # to (-1, 0): the same distance to (0, 4)
    u = torch.stack([right, left])[None]
    shown, _, _ = _told_planner(False).rollout(agent, state, u)
    told, _, _ = _told_planner(True).rollout(agent, state, u)
    assert shown[0, 0] > shown[0, 1]  # the old target (4, 0) is nearer (1, 0)
    assert told[0, 0] == pytest.approx(told[0, 1].item())  # the told critic sees the tie the reward sees


def test_each_member_is_closed_by_its_own_told_cue():
    """Two members, one rollout each: member 0 shown cue 0 and told cue 1's target, member 1 shown cue 1 and told
    cue 0's; standing still at (1, 0), each is valued by the critic of the cue it was told."""
    agent = CuedHand()
    state = torch.cat([_cued_state((1.0, 0.0), (0.0, 4.0), cue=0), _cued_state((1.0, 0.0), (4.0, 0.0), cue=1)])
    planner = MPCPlanner(MPCParams(horizon=3, candidates=4, elites=2, iterations=1, habit_candidates=1), seeds=[0, 1],
                         zone_radius=0.5)
    planner.told_value = True
    assert planner.told_cue(agent, state).tolist() == [[0.0, 1.0], [1.0, 0.0]]
    value, _, _ = planner.rollout(agent, state, torch.zeros(2, 1, 3, 2))
    steps = 1 + GAMMA + GAMMA ** 2
    expected = [-math.sqrt(17.0) * steps - GAMMA ** 3 * C * math.sqrt(17.0), -3.0 * steps - GAMMA ** 3 * C * 3.0]
    assert value[:, 0].tolist() == pytest.approx(expected, rel=1e-6)
