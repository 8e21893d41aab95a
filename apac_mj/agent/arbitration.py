"""The arbitrator: which controller acts, the actor (habit) or the inverse model (planning).

An arbitrator implements one method, ``use_habit(ctx) -> [E] bool``, over an
:class:`ArbitrationContext`: everything a rule may look at for each member at
this step (episode, step, the last and the recent TD errors, vision, the
forward model's recent error, the agent's uncertainty estimates where it has
them). The episode loop (:mod:`apac_mj.run.rollout`) builds the context; a new rule
is a new class, registered with an agent kind (:mod:`apac_mj.kinds`).

The built-in rules (the kinds ``ddpg``, ``spac`` and ``apac``):

* :class:`AlwaysHabit`: always the actor (exclusive habits, APAC == DDPG);
* :class:`AlwaysPlan`: always the inverse model (exclusive planning);
* :class:`DeltaArbitrator` (APAC): the inverse model during the first
  ``planning_episodes`` (100) training episodes; after that the actor on the
  first ``habit_first_steps`` (2) steps of each episode, then the actor if
  ``|delta|`` (``delta_rule="abs"``) or ``delta`` (``"signed"``, Algorithm 2's
  "RPE < 1") of the member's last transition is below ``delta_threshold`` (1),
  else the inverse model. A NaN delta (no last transition) counts as unreliable.

Beyond the paper (its "Discussion" names them; docs/arbitrators.md has the
equations and sources), each after the same planning phase:

* :class:`UncertaintyArbitrator` (Daw, Niv & Dayan 2005): the system whose
  one-step prediction is less uncertain acts (habit: running mean of delta^2;
  planning: running mean of the forward model's squared end-effector error);
* :class:`ReliabilityArbitrator` (Lee, Shimojo & O'Doherty 2014): reliabilities
  from the reward and state prediction errors drive a two-state transition
  of the probability of planning control;
* :class:`SpeedAccuracyArbitrator` (Keramati, Dezfouli & Piray 2011; the
  paper's "threshold modulated by the task"): plan only where the time that
  planning saves later (learned, per distance to the target) exceeds its
  extra cost (3 habit steps, :data:`PLANNING_COST`, against 1);
* :class:`VisionAwareArbitrator`: another kind's rule with vision; without
  vision the habit is suppressed, or checked against the forward model.

Optional methods an arbitrator may have (the episode loop calls them where
present): ``observe(info, mask, adapt)`` after every step (``adapt``: update
the running statistics, True in training, False in frozen tests), and
``state_dict()`` / ``load_state_dict(d)`` (saved in training checkpoints and
loaded by the tests). Every rule leaves its decision inputs in
``last_inputs`` (``name -> [E]``), which recordings show per step.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import torch

from apac_mj.types import HABIT_COST, PLANNING_COST, ArbitrationContext

if TYPE_CHECKING:
    from apac_mj.config import AgentConfig

#: TD errors of the member's last transitions kept in :attr:`ArbitrationContext.recent_deltas`.
HISTORY = 8


class Arbitrator(Protocol):
    """Decides per member whether the habit (actor) acts; ``False``: the planner (inverse model)."""

    def use_habit(self, ctx: ArbitrationContext) -> torch.Tensor:
        """``[E]`` bool: True where the actor acts."""
        ...


class AlwaysHabit:
    """Exclusive habits: the actor always acts (DDPG)."""

    def __init__(self, cfg: AgentConfig | None = None) -> None:
        del cfg  # no parameters

    def use_habit(self, ctx: ArbitrationContext) -> torch.Tensor:
        return torch.ones(ctx.E, dtype=torch.bool)


class AlwaysPlan:
    """Exclusive planning: the inverse model always acts (SPAC)."""

    def __init__(self, cfg: AgentConfig | None = None) -> None:
        del cfg  # no parameters

    def use_habit(self, ctx: ArbitrationContext) -> torch.Tensor:
        return torch.zeros(ctx.E, dtype=torch.bool)


class DeltaArbitrator:
    """APAC's rule: planning phase, then the habit on the first steps and where the last delta is small."""

    def __init__(self, cfg: AgentConfig) -> None:
        self.planning_episodes = cfg.planning_episodes
        self.habit_first_steps = cfg.habit_first_steps
        self.delta_threshold = cfg.delta_threshold
        self.delta_rule = cfg.delta_rule
        self.last_inputs: dict[str, torch.Tensor] = {}

    def use_habit(self, ctx: ArbitrationContext) -> torch.Tensor:
        signal = ctx.last_delta.abs() if self.delta_rule == "abs" else ctx.last_delta
        reliable = signal.to(ctx.episode.device) < self.delta_threshold
        habit = (ctx.step < self.habit_first_steps) | reliable
        # what is compared with the threshold, named as it is compared: |delta| (rule "abs") or delta ("signed")
        self.last_inputs = {"abs_delta" if self.delta_rule == "abs" else "delta": signal.float(),
                            "threshold": torch.full((ctx.E,), float(self.delta_threshold))}
        return habit & (ctx.episode >= self.planning_episodes)


# -- beyond the paper: rules with running statistics ------------------------------------------
def ema(old: torch.Tensor, new: torch.Tensor, rate: float, mask: torch.Tensor) -> torch.Tensor:
    """Running mean per member: ``new`` where ``old`` is NaN (the first sample), else
    ``old + rate (new - old)``; only where ``mask`` and ``new`` is finite."""
    updated = torch.where(torch.isnan(old), new, old + rate * (new - old))
    return torch.where(mask & torch.isfinite(new), updated, old)


def blend(prior: torch.Tensor, samples: torch.Tensor, weight: float) -> torch.Tensor:
    """``(weight * prior + sum(samples)) / (weight + n)`` per member over the finite ``samples`` ``[E, H]``
    (this episode's evidence shrunk towards the running statistic ``prior`` ``[E]``; NaN prior: weight 0)."""
    finite = torch.isfinite(samples)
    n, total = finite.sum(dim=1).float(), torch.where(finite, samples, 0.0).sum(dim=1)
    w = torch.where(torch.isfinite(prior), torch.full_like(prior, weight), 0.0)
    return (w * torch.nan_to_num(prior) + total) / (w + n)  # 0/0 = NaN: no evidence at all


def step_signals(info: Any) -> dict[str, torch.Tensor]:
    """What the running statistics learn from one :class:`~apac_mj.types.StepInfo` (``[E]`` each):
    the TD error, the forward model's end-effector error where the arm was seen (NaN elsewhere), the
    estimated distance to the target before and after the step, the step's time cost, the controller."""
    state, nxt = torch.as_tensor(info.state), torch.as_tensor(info.next_state)
    vision = torch.as_tensor(info.vision)
    end_error = torch.linalg.vector_norm(torch.as_tensor(info.predicted_arm)[:, :2] - nxt[:, :2], dim=1)
    habit = torch.as_tensor(info.habit)
    return {"delta": torch.as_tensor(info.delta, dtype=torch.float32),
            "end_error": torch.where(vision, end_error, float("nan")).float(),
            "before": torch.linalg.vector_norm(state[:, :2] - state[:, 4:], dim=1).float(),
            "after": torch.linalg.vector_norm(nxt[:, :2] - nxt[:, 4:], dim=1).float(),
            "cost": torch.where(habit, float(HABIT_COST), float(PLANNING_COST)), "habit": habit,
            "done": torch.as_tensor(info.done), "terminal": torch.as_tensor(info.terminal),
            "episode": torch.as_tensor(info.episode)}


class RunningArbitrator:
    """Base of the rules that keep per-member running statistics (``STATS``: name -> initial value).

    The statistics learn in training (``observe(..., adapt=True)``) and stay frozen in the tests; they
    are saved in checkpoints (:meth:`state_dict`) and loaded for the tests.
    """

    STATS: dict[str, float] = {}

    def __init__(self, cfg: AgentConfig) -> None:
        self.planning_episodes = cfg.planning_episodes
        self.rate = 1.0 / cfg.arbitration_window
        self.prior_weight = cfg.arbitration_prior_weight
        self.delta_threshold = cfg.delta_threshold
        self.stats: dict[str, torch.Tensor] = {}
        self.last_inputs: dict[str, torch.Tensor] = {}

    def stat(self, name: str, E: int) -> torch.Tensor:
        if name not in self.stats or len(self.stats[name]) != E:
            self.stats[name] = torch.full((E,), float(self.STATS[name]))
        return self.stats[name]

    def state_dict(self) -> dict[str, torch.Tensor]:
        return {k: v.clone() for k, v in self.stats.items()}

    def load_state_dict(self, d: dict[str, torch.Tensor]) -> None:
        unknown = set(d) - set(self.STATS)
        if unknown:
            raise ValueError(f"{type(self).__name__}: unknown statistics {sorted(unknown)}; known: {sorted(self.STATS)}")
        lengths = {tuple(torch.as_tensor(v).shape) for v in d.values()}
        if len(lengths) > 1 or any(len(shape) != 1 for shape in lengths):
            raise ValueError(f"{type(self).__name__}: statistics must be [E] tensors of one length, got {lengths}")
        self.stats = {k: torch.as_tensor(v, dtype=torch.float32).clone() for k, v in d.items()}

    def observe(self, info: Any, mask: np.ndarray, adapt: bool = True) -> None:
        """Learn from the step in ``info`` for the members in ``mask`` (only when ``adapt``)."""
        if adapt:
            self.learn(step_signals(info), torch.as_tensor(np.asarray(mask, dtype=bool)))

    def learn(self, sig: dict[str, torch.Tensor], mask: torch.Tensor) -> None:
        raise NotImplementedError

    def planning_phase(self, ctx: ArbitrationContext) -> torch.Tensor:
        return ctx.episode < self.planning_episodes


class UncertaintyArbitrator(RunningArbitrator):
    """Daw, Niv & Dayan (2005): the system whose prediction is less uncertain acts.

    Habit: ``U_h`` = this episode's delta^2 shrunk towards the running mean of delta^2 (the critic's
    one-step error, reward units = cm); planning: ``U_p`` = running mean of the forward model's squared
    end-effector error (cm^2, the error of its one-step reward prediction, seen steps). Habit iff ``U_h < U_p``.
    """

    STATS = {"habit_var": float("nan"), "planning_var": float("nan")}

    def learn(self, sig: dict[str, torch.Tensor], mask: torch.Tensor) -> None:
        E = len(mask)
        self.stats["habit_var"] = ema(self.stat("habit_var", E), sig["delta"] ** 2, self.rate, mask)
        self.stats["planning_var"] = ema(self.stat("planning_var", E), sig["end_error"] ** 2, self.rate, mask)

    def use_habit(self, ctx: ArbitrationContext) -> torch.Tensor:
        habit_u = blend(self.stat("habit_var", ctx.E), ctx.recent_deltas ** 2, self.prior_weight)
        plan_u = self.stat("planning_var", ctx.E)
        self.last_inputs = {"habit_uncertainty": habit_u, "planning_uncertainty": plan_u.clone()}
        return (habit_u < plan_u) & ~self.planning_phase(ctx)


class ReliabilityArbitrator(RunningArbitrator):
    """Lee, Shimojo & O'Doherty (2014): reliabilities drive a two-state transition between the systems.

    Reliability of the habit ``chi_h``: the running rate of ``|delta| < delta_threshold`` (the reward
    prediction error is small), with this episode's own rate shrunk towards it; of the planner
    ``chi_p``: the running rate of a forward-model end-effector error below the zone radius (the state
    prediction error is small).
    The probability of planning control moves as ``P <- P + alpha (1 - P) - beta P`` with
    ``alpha = A / (1 + exp(B chi_h))`` (habit -> planning) and ``beta = A / (1 + exp(B chi_p))``
    (planning -> habit); the habit acts where ``P < 0.5``.
    """

    STATS = {"habit_reliability": float("nan"), "planning_reliability": float("nan"), "p_planning": 1.0}

    def __init__(self, cfg: AgentConfig) -> None:
        super().__init__(cfg)
        self.A, self.B = cfg.reliability_rate, cfg.reliability_slope
        self.zone_radius = 0.5  # the task's, read from the context at every decision
        self._chi: tuple[torch.Tensor, torch.Tensor] | None = None

    def learn(self, sig: dict[str, torch.Tensor], mask: torch.Tensor) -> None:
        E = len(mask)
        small_rpe = torch.where(torch.isfinite(sig["delta"]), (sig["delta"].abs() < self.delta_threshold).float(),
                                float("nan"))
        small_spe = torch.where(torch.isfinite(sig["end_error"]), (sig["end_error"] < self.zone_radius).float(),
                                float("nan"))
        self.stats["habit_reliability"] = ema(self.stat("habit_reliability", E), small_rpe, self.rate, mask)
        self.stats["planning_reliability"] = ema(self.stat("planning_reliability", E), small_spe, self.rate, mask)

    def observe(self, info: Any, mask: np.ndarray, adapt: bool = True) -> None:
        """The statistics learn (``adapt``); the probability of planning control moves at every step."""
        super().observe(info, mask, adapt)
        if self._chi is None:
            return
        chi_h, chi_p = (torch.nan_to_num(c, nan=0.0) for c in self._chi)
        p = self.stat("p_planning", len(mask))
        alpha, beta = self.A / (1 + torch.exp(self.B * chi_h)), self.A / (1 + torch.exp(self.B * chi_p))
        moved = (p + alpha * (1 - p) - beta * p).clamp(0.0, 1.0)
        self.stats["p_planning"] = torch.where(torch.as_tensor(np.asarray(mask, dtype=bool)), moved, p)

    def use_habit(self, ctx: ArbitrationContext) -> torch.Tensor:
        self.zone_radius = ctx.zone_radius
        small = torch.where(torch.isfinite(ctx.recent_deltas), (ctx.recent_deltas.abs() < self.delta_threshold).float(),
                            float("nan"))
        chi_h = blend(self.stat("habit_reliability", ctx.E), small, self.prior_weight)
        chi_p = self.stat("planning_reliability", ctx.E).clone()
        self._chi = (chi_h, chi_p)
        p = self.stat("p_planning", ctx.E)
        self.last_inputs = {"habit_reliability": chi_h, "planning_reliability": chi_p, "p_planning": p.clone()}
        return (p < 0.5) & ~self.planning_phase(ctx)


#: Bin edges (cm) of the estimated distance to the target in the speed-accuracy rule's time-cost table.
DISTANCE_EDGES = (0.5, 1.0, 2.0, 4.0, 8.0)
#: In training, the entry of the controller not chosen moves towards that controller's own cost (its
#: optimistic value) at this fraction of the learning rate: a controller abandoned in a bin is tried again.
UNTRIED_DRIFT = 0.1


class SpeedAccuracyArbitrator(RunningArbitrator):
    """Plan only where the time planning saves later is worth its extra cost (Keramati et al. 2011).

    The rule learns, per member, the time cost to the episode's end ``T(b, c)`` (this step's cost
    included) after choosing controller ``c`` (habit, planning) at estimated distance ``b`` to the target
    (bins :data:`DISTANCE_EDGES`, cm), by SARSA(0) on the time cost: ``T(b, c) <- T(b, c) + rate
    (cost + T(b', c') - T(b, c))``, with ``T = 0`` after a perceived reach and :data:`PLANNING_COST`
    more after a time limit (the episode was not finished). With ``T = cost + R`` (``R``: what remains
    after the step), planning's expected gain is the time it saves later, ``R_h - R_p``; planning is worth
    it only where that gain exceeds its extra cost ``PLANNING_COST - HABIT_COST`` (2 habit steps). So
    the threshold follows from the cost and from what the task and the controllers make of it, not a
    fixed 1. The table learns only once the rule arbitrates (after the planning phase): both controllers
    are then measured under the same, annealed exploration noise, not planning under the noisy early
    episodes and the habit under the quiet late ones. An entry never tried is optimistic (the action's
    own cost), so each controller is tried;
    in training the entry of the controller not chosen drifts back towards that value
    (:data:`UNTRIED_DRIFT`), so a controller abandoned in a bin is tried again as the other one improves.
    """

    DISTANCE_EDGES = DISTANCE_EDGES
    CONTROLLERS = ("habit", "planning")
    STATS = {**{f"time_{c}_{b}": float("nan") for c in ("habit", "planning") for b in range(len(DISTANCE_EDGES) + 1)},
             "pending_bin": float("nan"), "pending_habit": float("nan"), "pending_cost": float("nan")}

    def __init__(self, cfg: AgentConfig) -> None:
        super().__init__(cfg)
        self.rate = 1.0 / cfg.speed_accuracy_window  # per visit of a table entry

    def bins(self, distance: torch.Tensor) -> torch.Tensor:
        return torch.bucketize(distance.float(), torch.tensor(self.DISTANCE_EDGES))

    def table(self, E: int) -> torch.Tensor:
        """``[E, bins, 2]`` the learned time cost (NaN: never tried)."""
        return torch.stack([torch.stack([self.stat(f"time_{c}_{b}", E) for c in self.CONTROLLERS], dim=1)
                            for b in range(len(self.DISTANCE_EDGES) + 1)], dim=1)

    def _set_table(self, table: torch.Tensor) -> None:
        for b in range(table.shape[1]):
            for i, c in enumerate(self.CONTROLLERS):
                self.stats[f"time_{c}_{b}"] = table[:, b, i].clone()

    def learn(self, sig: dict[str, torch.Tensor], mask: torch.Tensor) -> None:
        E = len(mask)
        mask = mask & (sig["episode"] >= self.planning_episodes)  # it learns what it chooses: after the planning phase
        table = self.table(E)
        rows = torch.arange(E)
        b, c = self.bins(sig["before"]), (~sig["habit"]).long()  # column 0 habit, 1 planning
        # the previous step's entry learns from this step's: cost_prev + T(b, c)
        pb, pc, pcost = (self.stat(k, E) for k in ("pending_bin", "pending_habit", "pending_cost"))
        has_prev = mask & torch.isfinite(pb)
        here = torch.where(torch.isnan(table[rows, b, c]), sig["cost"], table[rows, b, c])  # optimistic: own cost
        pbi, pci = torch.nan_to_num(pb).long(), torch.nan_to_num(pc).long()
        table[rows, pbi, pci] = ema(table[rows, pbi, pci], pcost + here, self.rate, has_prev)
        # this step's entry: finished now (perceived reach: nothing remains; time limit: a planning step more)
        end = torch.where(sig["terminal"], 0.0, float(PLANNING_COST))
        done = mask & sig["done"]
        table[rows, b, c] = ema(table[rows, b, c], sig["cost"] + end, self.rate, done)
        # the controller not chosen drifts back towards its own cost (optimism), so it is tried again
        other, own = 1 - c, torch.where(c == 1, float(HABIT_COST), float(PLANNING_COST))
        table[rows, b, other] = ema(table[rows, b, other], own, self.rate * UNTRIED_DRIFT, mask)
        self._set_table(table)
        going = mask & ~sig["done"]
        nan = torch.full((E,), float("nan"))
        for key, value in (("pending_bin", b.float()), ("pending_habit", c.float()), ("pending_cost", sig["cost"])):
            self.stats[key] = torch.where(going, value, torch.where(mask, nan, self.stat(key, E)))

    def use_habit(self, ctx: ArbitrationContext) -> torch.Tensor:
        distance = torch.linalg.vector_norm(ctx.state[:, :2] - ctx.state[:, 4:6], dim=1).cpu()
        table = self.table(ctx.E)[torch.arange(ctx.E), self.bins(distance)]
        time_habit = torch.where(torch.isnan(table[:, 0]), float(HABIT_COST), table[:, 0])
        time_plan = torch.where(torch.isnan(table[:, 1]), float(PLANNING_COST), table[:, 1])
        gain = (time_habit - HABIT_COST) - (time_plan - PLANNING_COST)  # remaining time planning saves
        self.last_inputs = {"distance": distance, "time_if_habit": time_habit, "time_if_planning": time_plan,
                            "planning_gain": gain,
                            "planning_extra_cost": torch.full((ctx.E,), float(PLANNING_COST - HABIT_COST))}
        return (gain <= PLANNING_COST - HABIT_COST) & ~self.planning_phase(ctx)


class VisionAwareArbitrator:
    """Another kind's rule (``vision_aware_base``, default the paper's) while the arm is seen; in the dark
    the habit is suppressed (``vision_aware_dark = "suppress"``, the paper's conclusion) or acts only where
    the forward model predicts its proposal lands in the zone or at least ``vision_check_ratio`` closer
    (``"check"``)."""

    def __init__(self, cfg: AgentConfig, base: Arbitrator) -> None:
        """``base``: the rule that decides with vision (the registry builds ``cfg.vision_aware_base``'s)."""
        self.base = base
        if isinstance(self.base, VisionAwareArbitrator):
            raise ValueError(f"vision_aware_base {cfg.vision_aware_base!r} is itself vision-aware; name a kind "
                             "with another rule (e.g. apac)")
        self.dark, self.ratio = cfg.vision_aware_dark, cfg.vision_check_ratio
        self.last_inputs: dict[str, torch.Tensor] = {}

    def use_habit(self, ctx: ArbitrationContext) -> torch.Tensor:
        habit = torch.as_tensor(self.base.use_habit(ctx), dtype=torch.bool)
        dark = ~ctx.vision.to(habit.device)
        inputs = dict(getattr(self.base, "last_inputs", {}), vision=ctx.vision.float())
        if self.dark == "suppress":
            allowed = ~dark
        else:
            if ctx.habit_action is None or ctx.predict_end is None:
                raise ValueError("vision_aware_dark='check' needs the context's habit_action and predict_end")
            target = ctx.state[:, 4:6]
            now = torch.linalg.vector_norm(ctx.state[:, :2] - target, dim=1)
            after = torch.linalg.vector_norm(ctx.predict_end(ctx.habit_action) - target, dim=1)
            allowed = (~dark | (after <= torch.clamp(self.ratio * now, min=ctx.zone_radius))).cpu()
            inputs["predicted_habit_distance"] = after.cpu()
        self.last_inputs = inputs
        return habit & allowed

    def observe(self, info: Any, mask: np.ndarray, adapt: bool = True) -> None:
        if hasattr(self.base, "observe"):
            self.base.observe(info, mask, adapt)

    def state_dict(self) -> dict[str, torch.Tensor]:
        return self.base.state_dict() if hasattr(self.base, "state_dict") else {}

    def load_state_dict(self, d: dict[str, torch.Tensor]) -> None:
        if hasattr(self.base, "load_state_dict"):
            self.base.load_state_dict(d)
        elif d:
            raise ValueError(f"{type(self.base).__name__} keeps no statistics, got {sorted(d)}")


def restore(arbitrator: Arbitrator, state: dict[str, torch.Tensor] | None) -> None:
    """Load a checkpoint's running statistics into ``arbitrator`` (nothing to load: nothing done; a rule
    that keeps none refuses a non-empty ``state``)."""
    if not state:
        return
    if not hasattr(arbitrator, "load_state_dict"):
        raise ValueError(f"the {type(arbitrator).__name__} rule keeps no statistics, but the checkpoint has "
                         f"{sorted(state)}")
    arbitrator.load_state_dict(state)


def push_delta(history: np.ndarray, delta: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``history`` ``[E, H]`` with ``delta`` appended (oldest dropped) for the members in ``mask``."""
    shifted = np.concatenate([history[:, 1:], np.asarray(delta, dtype=history.dtype)[:, None]], axis=1)
    return np.where(np.asarray(mask)[:, None], shifted, history)
