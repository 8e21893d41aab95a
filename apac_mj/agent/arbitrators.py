"""The arbitration rules beyond the paper (its "Discussion" names them; docs/arbitrators.md has the
equations and sources), each after APAC's planning phase:

* :class:`UncertaintyArbitrator` (Daw, Niv & Dayan 2005): the system whose
  one-step prediction is less uncertain acts (habit: running mean of delta^2;
  planning: running mean of the forward model's squared end-effector error);
* :class:`ReliabilityArbitrator` (Lee, Shimojo & O'Doherty 2014): reliabilities
  from the reward and state prediction errors drive a two-state transition
  of the probability of planning control;
* :class:`SpeedAccuracyArbitrator` (Keramati, Dezfouli & Piray 2011; the
  paper's "threshold modulated by the task"): plan only where the time that
  planning saves later (learned, per distance to the target) exceeds its
  extra cost (3 habit steps, :data:`~apac_mj.types.PLANNING_COST`, against 1);
* :class:`VisionAwareArbitrator`: another kind's rule with vision; without
  vision the habit is suppressed, or checked against the forward model.

Each reads its own parameter table (:mod:`apac_mj.rules`, ``cfg.params[...]``). The first three keep
per-member running statistics (:class:`RunningArbitrator`): they learn in training (``observe(...,
adapt=True)``), stay frozen in the tests, and travel in checkpoints (any tensors: ``state_dict``).
"""
from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np
import torch

from apac_mj.agent.arbitration import blend, ema, step_signals
from apac_mj.rules import (MPCParams, ReliabilityParams, SpeedAccuracyParams, UncertaintyParams,
                           ValueOfComputationParams, VisionAwareParams)
from apac_mj.types import (END, HABIT_COST, PLANNING_COST, TARGET, ArbitrationContext, Arbitrator, Decision, Planner,
                           Proposal, StepInfo, WorldModel)

if TYPE_CHECKING:
    from apac_mj.config import AgentConfig


@dataclasses.dataclass(frozen=True)
class Stat:
    """One running statistic: per member ``[E, *shape]``, ``initial`` before any evidence."""

    initial: float
    shape: tuple[int, ...] = ()
    dtype: torch.dtype = torch.float32


def _mask(mask: np.ndarray) -> torch.Tensor:
    return torch.as_tensor(np.asarray(mask, dtype=bool))


class RunningArbitrator(Arbitrator):
    """Base of the rules that keep per-member running statistics (``STATS``: name -> :class:`Stat`)."""

    STATS: dict[str, Stat] = {}

    def __init__(self, cfg: AgentConfig, window: int) -> None:
        """``window``: of the running statistics (exponential running means with rate ``1 / window``)."""
        self.planning_episodes = cfg.planning_episodes
        self.rate = 1.0 / window
        self.delta_threshold = cfg.delta_threshold
        self.stats: dict[str, torch.Tensor] = {}

    def stat(self, name: str, E: int) -> torch.Tensor:
        if name not in self.stats or len(self.stats[name]) != E:
            s = self.STATS[name]
            self.stats[name] = torch.full((E, *s.shape), float(s.initial), dtype=s.dtype)
        return self.stats[name]

    def state_dict(self) -> dict[str, torch.Tensor]:
        return {k: v.clone() for k, v in self.stats.items()}

    def load_state_dict(self, d: dict[str, torch.Tensor]) -> None:
        """Restore :meth:`state_dict`; an unknown statistic or a bad shape is an error naming it."""
        unknown = set(d) - set(self.STATS)
        if unknown:
            raise ValueError(f"{type(self).__name__}: unknown statistics {sorted(unknown)}; known: {sorted(self.STATS)}")
        d = {k: torch.as_tensor(v) for k, v in d.items()}
        lengths = {len(v) if v.dim() else None for v in d.values()}
        bad = {k: tuple(v.shape) for k, v in d.items() if tuple(v.shape[1:]) != self.STATS[k].shape}
        if len(lengths) > 1 or None in lengths or bad:
            raise ValueError(f"{type(self).__name__}: statistics must be [E, ...] tensors of one length E, got "
                             f"{ {k: tuple(v.shape) for k, v in d.items()} }")
        self.stats = {k: v.to(self.STATS[k].dtype).clone() for k, v in d.items()}

    def observe(self, info: StepInfo, mask: np.ndarray, adapt: bool = True) -> None:
        """Learn from the step in ``info`` for the members in ``mask`` (only when ``adapt``)."""
        if adapt:
            self.learn(step_signals(info), _mask(mask))

    def learn(self, sig: dict[str, torch.Tensor], mask: torch.Tensor) -> None:
        raise NotImplementedError(f"{type(self).__name__} must implement learn(sig, mask)")

    def planning_phase(self, ctx: ArbitrationContext) -> torch.Tensor:
        return ctx.episode < self.planning_episodes


class UncertaintyArbitrator(RunningArbitrator):
    """Daw, Niv & Dayan (2005): the system whose prediction is less uncertain acts.

    Habit: ``U_h`` = this episode's delta^2 shrunk towards the running mean of delta^2 (the critic's
    one-step error, reward units = cm); planning: ``U_p`` = running mean of the forward model's squared
    end-effector error (cm^2, the error of its one-step reward prediction, seen steps). Habit iff ``U_h < U_p``.
    """

    STATS = {"habit_var": Stat(float("nan")), "planning_var": Stat(float("nan"))}

    def __init__(self, cfg: AgentConfig) -> None:
        params: UncertaintyParams = cfg.params[UncertaintyParams.table]
        super().__init__(cfg, params.window)
        self.prior_weight = params.prior_weight

    def learn(self, sig: dict[str, torch.Tensor], mask: torch.Tensor) -> None:
        E = len(mask)
        self.stats["habit_var"] = ema(self.stat("habit_var", E), sig["delta"] ** 2, self.rate, mask)
        self.stats["planning_var"] = ema(self.stat("planning_var", E), sig["end_error"] ** 2, self.rate, mask)

    def use_habit(self, ctx: ArbitrationContext) -> Decision:
        habit_u = blend(self.stat("habit_var", ctx.E), ctx.recent_deltas ** 2, self.prior_weight)
        plan_u = self.stat("planning_var", ctx.E)
        inputs = {"habit_uncertainty": habit_u, "planning_uncertainty": plan_u.clone()}
        return Decision((habit_u < plan_u) & ~self.planning_phase(ctx), inputs)


class ReliabilityArbitrator(RunningArbitrator):
    """Lee, Shimojo & O'Doherty (2014): reliabilities drive a two-state transition between the systems.

    Reliability of the habit ``chi_h``: the running rate of ``|delta| < delta_threshold`` (the reward
    prediction error is small), with this episode's own rate shrunk towards it; of the planner
    ``chi_p``: the running rate of a forward-model end-effector error below the zone radius (the state
    prediction error is small).
    The probability of planning control moves as ``P <- P + alpha (1 - P) - beta P`` with
    ``alpha = A / (1 + exp(B chi_h))`` (habit -> planning) and ``beta = A / (1 + exp(B chi_p))``
    (planning -> habit), at every step with the reliabilities the step was decided on (its
    :attr:`~apac_mj.types.StepInfo.arbitration` inputs); the habit acts where ``P < 0.5``.
    """

    STATS = {"habit_reliability": Stat(float("nan")), "planning_reliability": Stat(float("nan")),
             "p_planning": Stat(1.0)}

    def __init__(self, cfg: AgentConfig) -> None:
        params: ReliabilityParams = cfg.params[ReliabilityParams.table]
        super().__init__(cfg, params.window)
        self.prior_weight, self.A, self.B = params.prior_weight, params.rate, params.slope

    def learn(self, sig: dict[str, torch.Tensor], mask: torch.Tensor) -> None:
        E = len(mask)
        small_rpe = torch.where(torch.isfinite(sig["delta"]), (sig["delta"].abs() < self.delta_threshold).float(),
                                float("nan"))
        small_spe = torch.where(torch.isfinite(sig["end_error"]), (sig["end_error"] < sig["zone_radius"]).float(),
                                float("nan"))
        self.stats["habit_reliability"] = ema(self.stat("habit_reliability", E), small_rpe, self.rate, mask)
        self.stats["planning_reliability"] = ema(self.stat("planning_reliability", E), small_spe, self.rate, mask)

    def observe(self, info: StepInfo, mask: np.ndarray, adapt: bool = True) -> None:
        """The statistics learn (``adapt``); the probability of planning control moves at every step."""
        super().observe(info, mask, adapt)
        chi_h, chi_p = (torch.nan_to_num(torch.as_tensor(info.arbitration[k]), nan=0.0)
                        for k in ("habit_reliability", "planning_reliability"))
        p = self.stat("p_planning", len(mask))
        alpha, beta = self.A / (1 + torch.exp(self.B * chi_h)), self.A / (1 + torch.exp(self.B * chi_p))
        moved = (p + alpha * (1 - p) - beta * p).clamp(0.0, 1.0)
        self.stats["p_planning"] = torch.where(_mask(mask), moved, p)

    def use_habit(self, ctx: ArbitrationContext) -> Decision:
        small = torch.where(torch.isfinite(ctx.recent_deltas), (ctx.recent_deltas.abs() < self.delta_threshold).float(),
                            float("nan"))
        chi_h = blend(self.stat("habit_reliability", ctx.E), small, self.prior_weight)
        chi_p = self.stat("planning_reliability", ctx.E).clone()
        p = self.stat("p_planning", ctx.E)
        inputs = {"habit_reliability": chi_h, "planning_reliability": chi_p, "p_planning": p.clone()}
        return Decision((p < 0.5) & ~self.planning_phase(ctx), inputs)


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

    Statistics: ``table`` ``[E, bins, 2]`` (column 0 habit, 1 planning; NaN: never tried) and the step
    waiting for its successor's entry: ``pending_bin``, ``pending_controller`` (-1: none) and ``pending_cost``.
    """

    DISTANCE_EDGES = DISTANCE_EDGES
    CONTROLLERS = ("habit", "planning")
    STATS = {"table": Stat(float("nan"), (len(DISTANCE_EDGES) + 1, len(CONTROLLERS))),
             "pending_bin": Stat(-1, dtype=torch.int64), "pending_controller": Stat(-1, dtype=torch.int64),
             "pending_cost": Stat(float("nan"))}

    def __init__(self, cfg: AgentConfig) -> None:
        super().__init__(cfg, cfg.params[SpeedAccuracyParams.table].window)  # rate: per visit of a table entry

    def bins(self, distance: torch.Tensor) -> torch.Tensor:
        return torch.bucketize(distance.float(), torch.tensor(self.DISTANCE_EDGES))

    def load_state_dict(self, d: dict[str, torch.Tensor]) -> None:
        """Also the format of the releases up to 936695d: flat ``time_{c}_{b}`` ``[E]`` entries and NaN-encoded
        ``pending_bin`` / ``pending_habit`` (converted)."""
        super().load_state_dict(self._from_flat(d) if "pending_habit" in d else d)

    def _from_flat(self, d: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        d = dict(d)
        table = torch.stack([torch.stack([torch.as_tensor(d.pop(f"time_{c}_{b}")) for c in self.CONTROLLERS], dim=1)
                             for b in range(len(self.DISTANCE_EDGES) + 1)], dim=1)
        pending = {k: torch.as_tensor(d.pop(old)) for k, old in (("pending_bin", "pending_bin"),
                                                               ("pending_controller", "pending_habit"))}
        return {**d, "table": table, **{k: torch.where(torch.isnan(v), -1, torch.nan_to_num(v)).long()
                                        for k, v in pending.items()}}

    def learn(self, sig: dict[str, torch.Tensor], mask: torch.Tensor) -> None:
        E = len(mask)
        mask = mask & (sig["episode"] >= self.planning_episodes)  # it learns what it chooses: after the planning phase
        table = self.stat("table", E).clone()
        rows = torch.arange(E)
        b, c = self.bins(sig["before"]), (~sig["habit"]).long()  # column 0 habit, 1 planning
        # the previous step's entry learns from this step's: cost_prev + T(b, c)
        pb, pc, pcost = (self.stat(k, E) for k in ("pending_bin", "pending_controller", "pending_cost"))
        has_prev = mask & (pb >= 0)
        here = torch.where(torch.isnan(table[rows, b, c]), sig["cost"], table[rows, b, c])  # optimistic: own cost
        pbi, pci = pb.clamp(min=0), pc.clamp(min=0)
        table[rows, pbi, pci] = ema(table[rows, pbi, pci], pcost + here, self.rate, has_prev)
        # this step's entry: finished now (perceived reach: nothing remains; time limit: a planning step more)
        end = torch.where(sig["terminal"], 0.0, float(PLANNING_COST))
        done = mask & sig["done"]
        table[rows, b, c] = ema(table[rows, b, c], sig["cost"] + end, self.rate, done)
        # the controller not chosen drifts back towards its own cost (optimism), so it is tried again
        other, own = 1 - c, torch.where(c == 1, float(HABIT_COST), float(PLANNING_COST))
        table[rows, b, other] = ema(table[rows, b, other], own, self.rate * UNTRIED_DRIFT, mask)
        self.stats["table"] = table
        going = mask & ~sig["done"]
        for key, value, none in (("pending_bin", b, -1), ("pending_controller", c, -1),
                                 ("pending_cost", sig["cost"], float("nan"))):
            old = self.stat(key, E)
            self.stats[key] = torch.where(going, value.to(old.dtype), torch.where(mask, none, old))

    def use_habit(self, ctx: ArbitrationContext) -> Decision:
        distance = torch.linalg.vector_norm(ctx.state[:, END] - ctx.state[:, TARGET], dim=1).cpu()
        table = self.stat("table", ctx.E)[torch.arange(ctx.E), self.bins(distance)]
        time_habit = torch.where(torch.isnan(table[:, 0]), float(HABIT_COST), table[:, 0])
        time_plan = torch.where(torch.isnan(table[:, 1]), float(PLANNING_COST), table[:, 1])
        gain = (time_habit - HABIT_COST) - (time_plan - PLANNING_COST)  # remaining time planning saves
        inputs = {"distance": distance, "time_if_habit": time_habit, "time_if_planning": time_plan,
                  "planning_gain": gain,
                  "planning_extra_cost": torch.full((ctx.E,), float(PLANNING_COST - HABIT_COST))}
        return Decision((gain <= PLANNING_COST - HABIT_COST) & ~self.planning_phase(ctx), inputs)


#: Bin edges of the habit's imagined final distance, in zone radii, in the graded rule's gain table: inside
#: the zone, just outside it (where the habit traps lie: the hand stalls 0.64 cm from a 0.5 cm zone), further.
VOC_EDGES = (1.0, 2.0, 4.0, 8.0, 16.0)


class ValueOfComputationArbitrator(RunningArbitrator):
    """A graded arbitration: whether and how long to plan, by the value of computation (Keramati et al.
    2011, 2016; Hamrick et al. 2017; Lu et al. 2019's adaptive online planning).

    Every step the habit's sequence is imagined through the forward model (the planner's probe:
    :class:`~apac_mj.types.HabitProbe`, one candidate, the cheapest look ahead). Its imagined final distance
    to the target (in zone radii, bins :data:`VOC_EDGES`) indexes a per-member table ``G[b, k]``: the running
    mean of what ``k`` planning iterations gained over the habit's value (cm of return), measured on every
    planned step (the anytime planner reports its best value after each iteration). Their cost is the time
    they take, priced as the reward rate of a reach: the current distance to the target per movement step
    (Keramati et al.'s opportunity cost of time), ``d * k * c / voc.decisions_per_step`` with ``c`` one
    iteration's time in habit decisions (``voc.iteration_cost``, or this run's measured ratio). The rule
    plans for the ``k`` with the largest positive net value ``G[b, k] - cost(k)``, else the habit acts.
    An entry never measured is optimistic (full planning). In the planning phase (``planning_episodes``)
    every step plans at the full budget.

    What a plan gained (``voc.gain``, :meth:`plan_gains`) and which steps teach the table (``voc.learn_on``):
    by default each iteration's best sequence minus the habit's valued through a held-out dynamics head, a model
    the plan was not selected by (:func:`heldout_gains`; it can be negative), learned for every ``k`` on the steps
    that planned the full budget whatever the rule chose: the planning phase and, in training, a re-exploration
    with probability ``voc.explore``. The releases before issue 42 (``gain = "imagined"``, ``learn_on =
    "planned"``): the imagined best minus the habit's imagined value, learned where the rule chose to plan.
    """

    needs_habit_probe = True
    STATS = {"gain": Stat(float("nan"), (len(VOC_EDGES) + 1, 64)),
             "habit_seconds": Stat(float("nan")), "iteration_seconds": Stat(float("nan"))}

    def __init__(self, cfg: AgentConfig) -> None:
        params: ValueOfComputationParams = cfg.params[ValueOfComputationParams.table]
        super().__init__(cfg, params.window)
        self.params, self.K = params, cfg.params[MPCParams.table].iterations
        #: Whether the actor explores this step (training; the episode loop sets it before every decision): only
        #: then does the rule re-explore (``voc.explore``).
        self.exploring = False
        if self.K > self.STATS["gain"].shape[1]:
            raise ValueError(f"the graded rule keeps gains for at most {self.STATS['gain'].shape[1]} iterations; "
                             f"agent.mpc.iterations = {self.K}")

    def bins(self, final_distance: torch.Tensor, zone_radius: float) -> torch.Tensor:
        return torch.bucketize(final_distance.float().cpu() / zone_radius, torch.tensor(VOC_EDGES))

    def iteration_cost(self, E: int) -> torch.Tensor:
        """``[E]`` one iteration's time in habit decisions: fixed, or this run's measured ratio (fixed until
        both times were measured)."""
        fixed = torch.full((E,), float(self.params.iteration_cost))
        if self.params.cost == "fixed":
            return fixed
        ratio = self.stat("iteration_seconds", E) / self.stat("habit_seconds", E)
        return torch.where(torch.isfinite(ratio), ratio, fixed)

    def use_habit(self, ctx: ArbitrationContext) -> Decision:
        if ctx.habit_probe is None:
            raise ValueError("the graded rule (apac_voc) needs a model planner's habit probe: its kind's planner "
                             "must be 'mpc'")
        probe = ctx.habit_probe()
        b = self.bins(probe.final_distance, ctx.zone_radius)
        gain = self.stat("gain", ctx.E)[torch.arange(ctx.E), b, :self.K]
        k = torch.arange(1, self.K + 1, dtype=torch.float32)
        distance = torch.linalg.vector_norm(ctx.state[:, END] - ctx.state[:, TARGET], dim=1).float().cpu()
        steps = self.iteration_cost(ctx.E)[:, None] * k / self.params.decisions_per_step  # movement steps of time
        cost = distance[:, None] * steps
        net = torch.where(torch.isnan(gain), float("inf"), gain - cost)
        best_net, best = net.max(1)
        planning = self.planning_phase(ctx)
        plan = planning | (best_net > 0)
        iterations = torch.where(planning | torch.isinf(best_net), self.K, best + 1) * plan
        rows = torch.arange(ctx.E)
        inputs = {"habit_final_distance": probe.final_distance.float().cpu(), "habit_value": probe.value.float().cpu(),
                  "distance": distance, "expected_gain": gain[rows, best], "planning_cost": cost[rows, best],
                  "iterations": iterations.float()}
        if self.params.learn_on == "unselected":
            explored = self.explores(ctx) & ~planning
            plan, iterations = plan | explored, torch.where(explored, self.K, iterations)
            inputs.update(iterations=iterations.float(), explored=explored.float())
        return Decision(~plan, inputs, iterations)

    def explores(self, ctx: ArbitrationContext) -> torch.Tensor:
        """``[E]`` bools: the steps re-explored at the full budget (training only; a uniform draw of each member's
        (episode, step) below ``voc.explore``, so the same in an ensemble and alone)."""
        if not self.exploring or self.params.explore == 0:
            return torch.zeros(ctx.E, dtype=torch.bool)
        p = self.params.explore
        draws = [e >= self.planning_episodes and np.random.default_rng([EXPLORE_STREAM, e, t]).random() < p
                 for e, t in zip(ctx.episode.tolist(), ctx.step.tolist())]
        return torch.as_tensor(draws, dtype=torch.bool)

    def plan_gains(self, agent: WorldModel, ctx: ArbitrationContext, plan: Proposal, planner: Planner) -> np.ndarray:
        """``[E, K]`` what the plan gained over the habit after each iteration (NaN past a member's budget), as
        ``voc.gain`` measures it: the iteration's best sequence minus the habit's valued through the held-out
        dynamics heads (``heldout``), the critic's advantage of its first action (``advantage``), or
        (``imagined``) through the model that selected it."""
        imagined = (plan.best_values - plan.habit_value[:, None]).numpy()
        # an agent built without a held-out head (another kind's run re-arbitrated by this rule): the imagined gain
        unheld = self.params.gain == "heldout" and getattr(getattr(agent, "dynamics_model", None), "held_out", 0) < 1
        if self.params.gain == "imagined" or plan.best_sequences is None or unheld:
            return imagined
        state, best = ctx.state, plan.best_sequences.to(ctx.state.device)
        if self.params.gain == "advantage":
            gains = critic_advantage(agent, state, best[:, :, 0])
        else:
            gains = heldout_gains(agent, planner, state, best)
        return np.where(np.isfinite(imagined), gains.float().cpu().numpy(), np.nan)

    def observe(self, info: StepInfo, mask: np.ndarray, adapt: bool = True) -> None:
        """Planned steps teach the gain table (``adapt``): each iteration's measured gain over the habit, in the
        bin the step was decided in (``learn_on = "unselected"``: only the full-budget steps of the planning phase
        and of a re-exploration); the time statistics learn from every step's measured shares."""
        if not adapt or info.plan_gains is None:
            return
        E, m = len(mask), _mask(mask)
        if self.params.learn_on == "unselected":  # only full-budget steps the rule did not choose teach the gains
            explored = info.arbitration.get("explored", np.zeros(E))  # none: a step the rule did not decide (babbling)
            unselected = (torch.as_tensor(info.episode) < self.planning_episodes) | torch.as_tensor(explored > 0)
            full = torch.as_tensor(np.asarray(info.plan_iterations) >= self.K)
            self._learn_gains(info, m & unselected & full)
            self._learn_times(info, m)
            return
        self._learn_gains(info, m)
        self._learn_times(info, m)

    def _learn_gains(self, info: StepInfo, m: torch.Tensor) -> None:
        """Each iteration's measured gain (finite entries of ``info.plan_gains``) moves its entry, in the bin the
        step was decided in, for the members in ``m``."""
        E = len(m)
        b = self.bins(torch.as_tensor(info.arbitration["habit_final_distance"]), info.zone_radius)
        table, rows = self.stat("gain", E).clone(), torch.arange(E)
        measured = torch.as_tensor(info.plan_gains, dtype=torch.float32)
        entry = table[rows, b, :measured.shape[1]]
        table[rows, b, :measured.shape[1]] = torch.where(
            m[:, None] & torch.isfinite(measured),
            torch.where(torch.isnan(entry), measured, entry + self.rate * (measured - entry)), entry)
        self.stats["gain"] = table

    def _learn_times(self, info: StepInfo, m: torch.Tensor) -> None:
        E = len(m)
        seconds = torch.as_tensor(info.decision_seconds, dtype=torch.float32)
        iters = torch.as_tensor(info.plan_iterations, dtype=torch.float32)
        habit_s = self.stat("habit_seconds", E)
        self.stats["habit_seconds"] = ema(habit_s, seconds, self.rate, m & (iters == 0))
        per_iteration = (seconds - torch.nan_to_num(habit_s)) / iters.clamp(min=1)
        self.stats["iteration_seconds"] = ema(self.stat("iteration_seconds", E), per_iteration, self.rate,
                                              m & (iters > 0))


#: The spawn key of the graded rule's re-exploration draws (:meth:`ValueOfComputationArbitrator.explores`).
EXPLORE_STREAM = 42


@torch.no_grad()
def critic_advantage(agent: WorldModel, state: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """``[E, B]`` the critic's advantage ``Q(s, a) - Q(s, pi(s))`` (cm of return) of the first actions ``u``
    ``[E, B, A]`` (tanh units, as the planner's sequences) in ``state`` ``[E, S]``; both actions as the plant
    executes them (``executable``), as the critic learned them."""
    B = u.shape[1]
    s = state[:, None].expand(state.shape[0], B + 1, state.shape[1])
    habit = agent.habit_u(s[:, :1])
    actions = agent.executable(agent.to_action(torch.cat([habit, u], 1), s), s)
    q = agent.critic(agent.inputs.habit(agent.inputs.state(s)), agent.inputs.act(actions))
    return q[:, 1:] - q[:, :1]


def held_out_dynamics(rule: Arbitrator, mpc: MPCParams) -> MPCParams:
    """The dynamics model an agent trains for its planner (``mpc``): under a graded rule that values its plans by a
    held-out head (``voc.gain = "heldout"``), one head more, held out, unless ``mpc`` holds some out itself
    (``mpc.held_out_heads``); the planner still plans through ``mpc.model_heads`` heads."""
    base = getattr(rule, "base", rule)
    if not isinstance(base, ValueOfComputationArbitrator) or base.params.gain != "heldout" or mpc.held_out_heads:
        return mpc
    return dataclasses.replace(mpc, model_heads=mpc.model_heads + 1, held_out_heads=1)


class AgentView:
    """An agent with another imagination (a subclass's ``imagine``); everything else is the agent's."""

    def __init__(self, agent: WorldModel) -> None:
        self.agent = agent

    def __getattr__(self, name: str) -> object:
        return getattr(self.agent, name)


class HeldOutView(AgentView):
    """An agent whose imagination is its held-out dynamics heads (``mpc.held_out_heads``: trained beside the others
    on the same transitions from their own initializations, but not planned through): a model the plans were not
    selected by."""

    def __init__(self, agent: WorldModel) -> None:
        if getattr(getattr(agent, "dynamics_model", None), "held_out", 0) < 1:
            raise ValueError("voc.gain = 'heldout' needs a held-out dynamics head (an agent built for the graded "
                             "rule has one: apac_mj.run.build.make_agent; or set agent.mpc.held_out_heads >= 1)")
        super().__init__(agent)

    @torch.no_grad()
    def imagine(self, state: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """The next state ``[E, B, S]`` the held-out heads predict (as ``Agent.imagine`` through the planned ones)."""
        a = self.agent
        x = a.inputs.state(state)
        change = a.dynamics_model.held_out_mean(a.inputs.model_input(x, action))
        return a.inputs.from_motion(a.inputs.motion_x(x) + change, state)


@torch.no_grad()
def heldout_gains(agent: WorldModel, planner: Planner, state: torch.Tensor, best: torch.Tensor) -> torch.Tensor:
    """``[E, K]`` the best sequences ``best`` ``[E, K, H, A]`` minus the habit's imagined sequence, both valued as
    the planner values them (``planner.rollout``) through the held-out heads (:class:`HeldOutView`)."""
    _, _, habit = planner._habit(agent, state)  # the habit's sequence the plan was compared with (cached)
    value, _, _ = planner.rollout(HeldOutView(agent), state, torch.cat([habit, best], 1))
    return value[:, 1:] - value[:, :1]


class VisionAwareArbitrator(Arbitrator):
    """Another kind's rule (``vision_aware.base``, default the paper's) while the arm is seen; in the dark
    the habit is suppressed (``vision_aware.dark = "suppress"``, the paper's conclusion) or acts only where
    the forward model predicts its proposal lands in the zone or at least ``vision_aware.check_ratio``
    closer (``"check"``)."""

    def __init__(self, cfg: AgentConfig, base: Arbitrator) -> None:
        """``base``: the rule that decides with vision (the registry builds ``vision_aware.base``'s)."""
        params: VisionAwareParams = cfg.params[VisionAwareParams.table]
        if isinstance(base, VisionAwareArbitrator):
            raise ValueError(f"agent.vision_aware.base {params.base!r} is itself vision-aware; name a kind "
                             "with another rule (e.g. apac)")
        self.base, self.dark, self.ratio = base, params.dark, params.check_ratio

    @property
    def needs_habit_action(self) -> bool:  # type: ignore[override]
        """The dark check reads the habit's proposal before deciding; the base rule may too."""
        return self.dark == "check" or self.base.needs_habit_action

    @property
    def needs_habit_probe(self) -> bool:  # type: ignore[override]
        """Whether the base rule reads the habit's probe (this rule adds none)."""
        return self.base.needs_habit_probe

    def plan_gains(self, agent: WorldModel, ctx: ArbitrationContext, plan: Proposal, planner: Planner
                   ) -> np.ndarray | None:
        """The base rule's own estimate of a plan's gain (None: the planner's imagined one)."""
        return self.base.plan_gains(agent, ctx, plan, planner)

    @property
    def exploring(self) -> bool:
        """Whether the actor explores this step, passed on to the base rule."""
        return self.base.exploring

    @exploring.setter
    def exploring(self, value: bool) -> None:
        self.base.exploring = value

    def use_habit(self, ctx: ArbitrationContext) -> Decision:
        decision = self.base.use_habit(ctx)
        habit = torch.as_tensor(decision.habit, dtype=torch.bool)
        dark = ~ctx.vision.to(habit.device)
        inputs = dict(decision.inputs, vision=ctx.vision.float())
        if self.dark == "suppress":
            allowed = ~dark
        else:
            if ctx.habit_action is None or ctx.predict_end is None:
                raise ValueError("vision_aware.dark='check' needs the context's habit_action and predict_end")
            target = ctx.state[:, TARGET]
            now = torch.linalg.vector_norm(ctx.state[:, END] - target, dim=1)
            after = torch.linalg.vector_norm(ctx.predict_end(ctx.habit_action) - target, dim=1)
            allowed = (~dark | (after <= torch.clamp(self.ratio * now, min=ctx.zone_radius))).cpu()
            inputs["predicted_habit_distance"] = after.cpu()
        return Decision(habit & allowed, inputs)

    def observe(self, info: StepInfo, mask: np.ndarray, adapt: bool = True) -> None:
        self.base.observe(info, mask, adapt)

    def state_dict(self) -> dict[str, torch.Tensor]:
        return self.base.state_dict()

    def load_state_dict(self, d: dict[str, torch.Tensor]) -> None:
        self.base.load_state_dict(d)
