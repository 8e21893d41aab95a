"""The planning system's proposals: the paper's inverse model, and model-predictive control through the learned
forward model (beyond the paper; issue 28, docs/agent.md "Planning through the model"). Both are registered
planners (:mod:`apac_mj.systems`: ``"inverse"`` and ``"mpc"``); an agent kind names its own.

:class:`InversePlanner` is the paper's planner: one query of the inverse model with the target as the hand's
goal, re-asked every step. :class:`MPCPlanner` plans ``horizon`` steps ahead through the forward model
(the agent's learned dynamics: ``[arm, extra, action] -> [arm, extra]``), batched ``[E, candidates, horizon]``:

* each iteration samples ``candidates`` action sequences around a mean (tanh units, the actor's output
  space), adds the habit's sequences (the actor rolled through the model; ``habit_candidates`` 0: none), and
  scores every sequence by the task's reward, ``-|hand - target|`` (cm) per imagined step, discounted, until
  the hand is imagined inside the zone (and, on a task with a stop criterion, slow enough), then the critic's
  ``Q(s_H, pi(s_H))`` at the horizon (TD-MPC2's terminal value);
* the next mean and spread are the temperature-weighted mean and spread of the ``elites`` best (MPPI);
* **anytime**: the best sequence found so far is kept, so cutting the iterations at any count returns a
  plan at least as good (by the model) as any fewer iterations found; each member runs its own budget;
* the mean is warm-started from the last decision's, shifted by one step.

Every member has its own random stream (from its seed), drawn only on the iterations it runs, so a member
plans alike in an ensemble and alone.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

from apac_mj.rules import MPCParams
from apac_mj.types import END, TARGET, ArbitrationContext, HabitProbe, Planner, Proposal, WorldModel

#: The spawn key of the planner's random streams (independent of the agent's init, replay and noise streams).
STREAM = 28


class InversePlanner(Planner):
    """The paper's planning system: the inverse model's proposal, one query per step."""

    def propose(self, agent: WorldModel, ctx: ArbitrationContext, iterations: torch.Tensor) -> Proposal:
        return Proposal(agent.inverse_action(ctx.state), (iterations > 0).long())


class MPCPlanner(Planner):
    """Sampling-based MPC (MPPI with elites) through the forward model; anytime, warm-started."""

    def __init__(self, params: MPCParams, seeds: Sequence[int], action_dim: int = 2,
                 zone_radius: float = 0.5, stop_speed: float | None = None) -> None:
        self.p, self.action_dim = params, action_dim
        self.max_iterations = params.iterations
        #: The success criterion imagined rollouts stop at: inside ``zone_radius`` (cm) and, where the task
        #: has one, every joint slower than ``stop_speed`` (deg/s, the state's extra entries).
        self.zone_radius, self.stop_speed = float(zone_radius), stop_speed
        self.seeds = [int(s) for s in seeds]
        self.generators = [torch.Generator().manual_seed(_stream_seed(s)) for s in self.seeds]
        self.mean = torch.zeros(len(self.seeds), params.horizon, action_dim)
        #: The last decision's best sequences, imagined (recordings): hand ``[E, H + 1, 2]`` and a few
        #: candidates' hands ``[E, C, H + 1, 2]`` (cm); None before the first plan.
        self.last_plan: dict[str, torch.Tensor] | None = None
        #: On a cued task, close the horizon with the critic of the cue that the told target had (issue 42 item 5):
        #: the cue whose habit the model imagines ending nearest the told target (:meth:`told_cue`). False: the
        #: shown cue's critic (the habit's view), which after a remap values the old target. The forced-response
        #: test sets it (``TestPlan.told_value``); training keeps False (under the practised mapping both agree).
        self.told_value = False
        self._habit_cache: tuple[torch.Tensor, ...] | None = None
        self._told_cache: tuple[torch.Tensor, torch.Tensor | None] | None = None

    # -- what a checkpoint keeps ----------------------------------------------------------------
    def reset(self, mask: np.ndarray) -> None:
        self.mean[torch.as_tensor(np.asarray(mask, dtype=bool))] = 0.0

    def state_dict(self) -> dict[str, object]:
        return {"mean": self.mean.clone(), "generators": [g.get_state() for g in self.generators]}

    def load_state_dict(self, d: dict[str, object]) -> None:
        if not d:
            return
        mean = torch.as_tensor(d["mean"])
        if tuple(mean.shape) != tuple(self.mean.shape) or len(d["generators"]) != len(self.generators):
            raise ValueError(f"MPCPlanner state for mean {tuple(mean.shape)}, {len(d['generators'])} streams; "
                             f"this planner has {tuple(self.mean.shape)}, {len(self.generators)}")
        self.mean = mean.float().clone()
        for g, state in zip(self.generators, d["generators"]):
            g.set_state(state)

    # -- imagination --------------------------------------------------------------------------
    def rollout(self, agent: WorldModel, state: torch.Tensor, u: torch.Tensor | None = None,
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Imagine sequences from ``state`` ``[E, S]``: ``u`` ``[E, B, H, A]`` (tanh units), or the habit's
        (None: the actor acts at each imagined state). Returns the values ``[E, B]`` (cm of return), the
        hands ``[E, B, H + 1, 2]`` and the sequences ``[E, B, H, A]``."""
        H, gamma = self.p.horizon, agent.cfg.gamma
        B = 1 if u is None else u.shape[1]
        cue = self.told_cue(agent, state)
        s = state[:, None].expand(state.shape[0], B, state.shape[1])
        value = torch.zeros(s.shape[:2], device=state.device)
        alive = torch.ones_like(value)
        hands, taken = [s[..., END]], []
        for t in range(H):
            u_t = agent.habit_u(s) if u is None else u[:, :, t]
            taken.append(u_t)
            s = agent.imagine(s, agent.executable(agent.to_action(u_t, s), s))
            distance = torch.linalg.vector_norm(s[..., END] - s[..., TARGET], dim=-1)
            value = value - gamma ** t * alive * distance
            alive = alive * (1.0 - self._arrived(s, distance, agent.layout.motion))
            hands.append(s[..., END])
        value = value + gamma ** H * alive * agent.value(s if cue is None else _with_cue(s, cue, agent.layout.cue))
        return value, torch.stack(hands, 2), torch.stack(taken, 2)

    def told_cue(self, agent: WorldModel, state: torch.Tensor) -> torch.Tensor | None:
        """``[E, cues]``: the one-hot cue the told target had, where :attr:`told_value` is set on a cued task (the
        habit of every cue imagined ``horizon`` steps from ``state`` in one batch; the cue whose hand ends nearest
        the state's target), computed once per state; None: the state's own cue."""
        layout = agent.layout
        if not (self.told_value and layout.cue_dim):
            return None
        if self._told_cache is None or self._told_cache[0] is not state:
            n = layout.cue_dim
            s = _with_cue(state[:, None].expand(state.shape[0], n, state.shape[1]),
                          torch.eye(n, dtype=state.dtype, device=state.device)[None], layout.cue)
            for _ in range(self.p.horizon):
                s = agent.imagine(s, agent.executable(agent.to_action(agent.habit_u(s), s), s))
            distance = torch.linalg.vector_norm(s[..., END] - state[:, None, TARGET], dim=-1)
            self._told_cache = (state, torch.nn.functional.one_hot(distance.argmin(1), n).to(state.dtype))
        return self._told_cache[1]

    def _arrived(self, s: torch.Tensor, distance: torch.Tensor, motion: slice) -> torch.Tensor:
        """Where the imagined hand arrived: in the zone and (a stop criterion) every joint speed, the state's
        ``motion`` entries (``StateLayout.motion``), at most ``stop_speed``."""
        arrived = distance <= self.zone_radius
        if self.stop_speed is not None:
            arrived = arrived & (s[..., motion].abs().amax(-1) <= self.stop_speed)
        return arrived.float()

    def _habit(self, agent: WorldModel, state: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """:meth:`rollout` of the habit from ``state``, computed once per state (the probe and the plan share it)."""
        if self._habit_cache is None or self._habit_cache[0] is not state:
            self._habit_cache = (state, *self.rollout(agent, state))
        return self._habit_cache[1:]

    def probe(self, agent: WorldModel, state: torch.Tensor) -> HabitProbe:
        value, hands, _ = self._habit(agent, state)
        final = torch.linalg.vector_norm(hands[:, 0, -1] - state[:, TARGET], dim=-1)
        return HabitProbe(value[:, 0], final)

    # -- the plan -------------------------------------------------------------------------------
    def propose(self, agent: WorldModel, ctx: ArbitrationContext, iterations: torch.Tensor) -> Proposal:
        p, state, E = self.p, ctx.state, ctx.E
        budget = torch.as_tensor(iterations).long().clamp(0, p.iterations)
        best_values = torch.full((E, p.iterations), float("nan"))
        best_sequences = torch.zeros(E, p.iterations, p.horizon, self.action_dim)  # Proposal.best_sequences
        if not bool((budget > 0).any()):
            self._shift(self.mean)
            return Proposal(torch.zeros(E, self.action_dim, device=state.device), budget, best_values, None)
        habit_value, habit_hands, habit_u = self._habit(agent, state)
        pool_u, pool_v, pool_h = self._habit_pool(agent, state, budget, habit_value, habit_hands, habit_u)
        mean = self.mean.to(state.device).clone()
        std = torch.full_like(mean, p.max_std)
        best_u, best_v, best_h = _best(pool_u, pool_v, pool_h)
        for i in range(int(budget.max())):
            running = budget > i
            u = (mean[:, None] + std[:, None] * self._noise(running, state.device)).clamp(-1.0, 1.0)
            v, h, _ = self.rollout(agent, state, u)
            all_u, all_v = torch.cat([u, pool_u], 1), torch.cat([v, pool_v], 1)
            new_mean, new_std = self._refit(all_u, all_v)
            keep = running.to(state.device)[:, None, None]
            mean, std = torch.where(keep, new_mean, mean), torch.where(keep, new_std, std)
            cand_u, cand_v, cand_h = _best(u, v, h)
            better = running.to(state.device) & (cand_v > best_v)
            best_u = torch.where(better[:, None, None], cand_u, best_u)
            best_h = torch.where(better[:, None, None], cand_h, best_h)
            best_v = torch.where(better, cand_v, best_v)
            best_values[:, i] = torch.where(running, best_v.cpu(), float("nan"))
            best_sequences[:, i] = torch.where(running[:, None, None], best_u.cpu(), 0.0)
            last_h = h
        planned = (budget > 0).to(state.device)
        self.mean = torch.where(planned[:, None, None].cpu(), self._shifted(mean).cpu(), self._shifted(self.mean))
        self.last_plan = {"hand": best_h.cpu(), "candidates": last_h[:, :8].cpu()}
        action = agent.to_action(best_u[:, 0], state)
        return Proposal(action, budget, best_values, habit_value[:, 0].cpu(), best_sequences)

    def _habit_pool(self, agent: WorldModel, state: torch.Tensor, budget: torch.Tensor, habit_value: torch.Tensor,
                    habit_hands: torch.Tensor, habit_u: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """The habit's sequences every iteration's refit sees and the best starts from: its own sequence and
        ``habit_candidates - 1`` perturbed copies (values ``[E, n]``, hands, sequences); ``habit_candidates``
        0: none (empty, ``n = 0``: the plan is the samples' alone; the habit's value is still recorded)."""
        if self.p.habit_candidates == 0:
            return habit_u[:, :0], habit_value[:, :0], habit_hands[:, :0]
        extra_u = self._habit_variants(habit_u, budget)
        if extra_u is None:
            return habit_u, habit_value, habit_hands
        v, h, _ = self.rollout(agent, state, extra_u)
        return torch.cat([habit_u, extra_u], 1), torch.cat([habit_value, v], 1), torch.cat([habit_hands, h], 1)

    def _habit_variants(self, habit_u: torch.Tensor, budget: torch.Tensor) -> torch.Tensor | None:
        """``habit_candidates - 1`` perturbed copies of the habit's sequence ``[E, n, H, A]``; None: none."""
        n = self.p.habit_candidates - 1
        if n < 1 or self.p.habit_noise == 0:
            return None
        noise = self._noise(budget > 0, habit_u.device, n) * self.p.habit_noise
        return (habit_u + noise).clamp(-1.0, 1.0)

    def _noise(self, running: torch.Tensor, device: torch.device, n: int | None = None) -> torch.Tensor:
        """Standard normal ``[E, n, H, A]`` (default n: ``candidates``), drawn from the streams of the
        ``running`` members only (zeros for the others)."""
        n = self.p.candidates if n is None else n
        out = torch.zeros(len(self.generators), n, self.p.horizon, self.action_dim)
        for k in np.flatnonzero(running.cpu().numpy()):
            out[k] = torch.randn(n, self.p.horizon, self.action_dim, generator=self.generators[k])
        return out.to(device)

    def _refit(self, u: torch.Tensor, v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """MPPI: the temperature-weighted mean and spread of the ``elites`` best sequences ``[E, H, A]``."""
        p = self.p
        value, idx = v.topk(p.elites, dim=1)
        elite = u.gather(1, idx[..., None, None].expand(-1, -1, *u.shape[2:]))
        w = torch.softmax(p.temperature * (value - value[:, :1]), dim=1)[..., None, None]
        mean = (w * elite).sum(1)
        std = ((w * (elite - mean[:, None]) ** 2).sum(1)).sqrt().clamp(p.min_std, p.max_std)
        return mean, std

    def _shift(self, mean: torch.Tensor) -> None:
        self.mean = self._shifted(mean).cpu()

    @staticmethod
    def _shifted(mean: torch.Tensor) -> torch.Tensor:
        """The warm start: the sequence one step on (the last step repeated as zero)."""
        return torch.cat([mean[:, 1:], torch.zeros_like(mean[:, :1])], 1)


def _best(u: torch.Tensor, v: torch.Tensor, h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Each member's best sequence ``[E, H, A]``, its value ``[E]`` and imagined hand ``[E, H + 1, 2]``; of no
    sequence (``B = 0``): zeros at value ``-inf``, which any sequence beats."""
    if v.shape[1] == 0:
        return u.new_zeros(u.shape[0], *u.shape[2:]), v.new_full(v.shape[:1], -float("inf")), \
            h.new_zeros(h.shape[0], *h.shape[2:])
    k = v.argmax(1)
    rows = torch.arange(len(k), device=k.device)
    return u[rows, k], v[rows, k], h[rows, k]


def _with_cue(s: torch.Tensor, cue: torch.Tensor, where: slice) -> torch.Tensor:
    """States ``s`` ``[E, B, S]`` with the cue entries ``where`` replaced by ``cue`` (``[E, cues]`` or
    broadcastable to ``[E, B, cues]``)."""
    cue = cue[:, None] if cue.dim() == 2 else cue
    return torch.cat([s[..., :where.start], cue.expand(*s.shape[:-1], cue.shape[-1]), s[..., where.stop:]], -1)


def _stream_seed(seed: int) -> int:
    state = np.random.SeedSequence(int(seed), spawn_key=(STREAM,)).generate_state(1, dtype=np.uint64)[0]
    return int(state) & (2**63 - 1)
