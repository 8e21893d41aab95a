"""The episode loop and one agent-environment step, shared by training, evaluation and recordings.

:class:`EpisodeLoop` is the one place that carries per-member state between
steps (:class:`EpisodeState`: the state estimate, step, TD errors, vision,
forward-model error, counts) and builds the arbitrator's
:class:`~apac_mj.types.ArbitrationContext` from it; the arbitrator's
choice between the actor and the inverse model (plus OU noise) is
:func:`select_action`. :func:`agent_step` is the body of Algorithm 2's inner
loop up to the store: feed the action and the current arm estimate to the forward model, step the plant,
integrate (observed position with vision, the forward model's prediction
without), build ``s_{t+1}`` and compute this transition's TD error ``delta``
on the executable part of the command (:meth:`Agent.executable`, what the
critic and the forward model learn from)
(the arbitrator's reliability signal for the next step). It returns a
:class:`StepInfo`, the per-step record that a :class:`Hook` receives::

    class MyHook(Hook):
        def on_episode_start(self, members: np.ndarray, vec_env: VecEnv) -> None: ...  # [E] bool, just reset
        def on_step(self, info: StepInfo, vec_env: VecEnv) -> None: ...

Hooks are accepted by the loop itself, :func:`apac_mj.run.trainer.train` and
:func:`apac_mj.run.evaluate.evaluate`; the last two also take the two methods as
plain functions (``on_step=``, ``on_episode_start=``).

What the agent perceives: with vision, the environment's reward and
termination; without vision (occluded), the reward and termination of its
own estimate (``-|end_est - target_remembered|`` and "estimate inside the
zone"), so nothing true leaks after step 0.
"""
from __future__ import annotations

import dataclasses
import time
from typing import Any, Callable, Iterator, Sequence

import numpy as np
import torch

from apac_mj.agent.arbitration import HISTORY, push_delta
from apac_mj.run import deliberation
from apac_mj.suite.vec_env import VecEnv
from apac_mj.types import (ARM, END, EXTRA, POSITION_DIM, POSITIONS, TARGET, ArbitrationContext, Arbitrator, Decision,
                           Integrator, Observation, Planner, Policy, StepInfo, StepTensors)


#: A hook's methods as plain functions: ``on_step(info, vec_env)``, ``on_episode_start(members, vec_env)``.
OnStep = Callable[[StepInfo, VecEnv], None]
OnEpisodeStart = Callable[[np.ndarray, VecEnv], None]


class Hook:
    """What the episode loop calls on its way (SB3's ``BaseCallback`` style): override what you need."""

    def on_episode_start(self, members: np.ndarray, vec_env: VecEnv) -> None:
        """After the members in ``members`` (``[E]`` bool) were reset."""

    def on_step(self, info: StepInfo, vec_env: VecEnv) -> None:
        """After every step, once the loop's state is carried past it."""


class FunctionHook(Hook):
    """A hook made of plain functions (either may be None)."""

    def __init__(self, on_step: OnStep | None = None, on_episode_start: OnEpisodeStart | None = None) -> None:
        self.step_fn, self.start_fn = on_step, on_episode_start

    def on_episode_start(self, members: np.ndarray, vec_env: VecEnv) -> None:
        if self.start_fn is not None:
            self.start_fn(members, vec_env)

    def on_step(self, info: StepInfo, vec_env: VecEnv) -> None:
        if self.step_fn is not None:
            self.step_fn(info, vec_env)


def as_hooks(hooks: Sequence[Hook], on_step: OnStep | None = None,
             on_episode_start: OnEpisodeStart | None = None) -> list[Hook]:
    """``hooks``, then the plain functions as one more hook (if any is given)."""
    plain = [FunctionHook(on_step, on_episode_start)] if on_step is not None or on_episode_start is not None else []
    return [*hooks, *plain]


def observed_state(obs: Observation, device: torch.device) -> torch.Tensor:
    """``[E, 6]`` state from an observation that was seen (episode start)."""
    return torch.as_tensor(np.concatenate([obs.arm, obs.target], axis=1), dtype=torch.float32, device=device)


def _observed_step(obs: Observation, active: np.ndarray,
                   device: torch.device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """A step's observation on the agent's device through one host-to-device copy: the observed positions
    ``[E, 6]`` (float32, :func:`observed_state`'s), ``vision``, the reward (float32), ``reached`` and ``active``
    (``[E]`` each; the flags as bools). Every value is the one converting each array alone gives (float32 of the
    same numbers; 0/1 back to bools)."""
    packed = torch.as_tensor(np.concatenate([obs.arm, obs.target, obs.reward[:, None], obs.vision[:, None],
                                             obs.reached[:, None], np.asarray(active)[:, None]], axis=1),
                             dtype=torch.float32, device=device)
    # columns: the 6 positions (the state's layout), then the reward, vision, reached, active
    seen = packed[:, POSITIONS].contiguous()
    vision, reached, active_t = packed[:, 7] != 0, packed[:, 8] != 0, packed[:, 9] != 0
    return seen, vision, packed[:, 6], reached, active_t


def with_extra(positions: torch.Tensor, vec_env: VecEnv) -> torch.Tensor:
    """``[E, 6]`` positions followed by the task's extra observations (``vec_env.extra``, e.g. joint
    velocities): the agent's state; the positions alone for the paper's tasks."""
    if not vec_env.extra.shape[1]:
        return positions
    extra = torch.as_tensor(vec_env.extra, dtype=positions.dtype, device=positions.device)
    return torch.cat([positions, extra], 1)


@dataclasses.dataclass(kw_only=True)
class EpisodeState:
    """What every member carries from step to step within its episode (the one copy of this bookkeeping)."""

    state: torch.Tensor          # [E, 6 + extra] the state the agent acts on (apac_mj.types: END, TARGET, ...)
    step: np.ndarray             # [E] steps taken in the current episode
    last_delta: np.ndarray       # [E] TD error of the member's last transition (NaN: none this episode)
    ret: np.ndarray              # [E] return so far in the episode
    habit_n: np.ndarray          # [E] habitual actions counted this episode
    plan_n: np.ndarray           # [E] planning actions counted this episode
    recent_deltas: np.ndarray | None = None  # [E, HISTORY] this episode's last TD errors, oldest first (NaN pad)
    vision: np.ndarray | None = None         # [E] bool: the current state was seen
    forward_error: np.ndarray | None = None  # [E] forward model's error at the last seen step (cm; NaN: none)
    estimate_error_sum: np.ndarray | None = None  # [E] this episode's sum over steps of the integrator's error (cm)
    habit_seconds: np.ndarray | None = None     # [E] this episode's measured decision time where the habit acted (s)
    planning_seconds: np.ndarray | None = None  # [E] ... where the planner acted (s)
    plan_iterations: np.ndarray | None = None   # [E] this episode's planning iterations
    trials: list | None = None  # [E] each member's last finished trial (a [trials] task: suite.trials.TRIAL_COLUMNS)

    def __post_init__(self) -> None:
        E = len(self.step)
        for name in ("habit_seconds", "planning_seconds"):
            setattr(self, name, np.zeros(E) if getattr(self, name) is None else getattr(self, name))
        self.plan_iterations = np.zeros(E, dtype=np.int64) if self.plan_iterations is None else self.plan_iterations
        self.recent_deltas = np.full((E, HISTORY), np.nan) if self.recent_deltas is None else self.recent_deltas
        self.vision = np.ones(E, dtype=bool) if self.vision is None else self.vision
        self.forward_error = np.full(E, np.nan) if self.forward_error is None else self.forward_error
        self.estimate_error_sum = np.zeros(E) if self.estimate_error_sum is None else self.estimate_error_sum

    @staticmethod
    def fresh_fields(E: int, device: torch.device, state_dim: int = POSITION_DIM) -> dict[str, Any]:
        """Keyword arguments of a carry at the start of nothing (every member to be reset); ``state_dim``:
        the agent's (6, the paper's, plus the task's extra observations)."""
        return dict(state=torch.zeros(E, state_dim, device=device), step=np.zeros(E, dtype=np.int64),
                    last_delta=np.full(E, np.nan), ret=np.zeros(E), habit_n=np.zeros(E, dtype=np.int64),
                    plan_n=np.zeros(E, dtype=np.int64))

    @classmethod
    def fresh(cls, E: int, device: torch.device, state_dim: int = POSITION_DIM) -> "EpisodeState":
        return cls(**cls.fresh_fields(E, device, state_dim))

    def reset(self, mask: np.ndarray, seen: torch.Tensor) -> None:
        """Start a new episode for the members in ``mask`` from the ``seen`` state ``[E, 6 + extra]``."""
        rows = torch.as_tensor(mask, device=self.state.device)
        self.state = torch.where(rows[:, None], seen, self.state)
        self.step[mask], self.last_delta[mask], self.ret[mask] = 0, np.nan, 0.0
        self.habit_n[mask], self.plan_n[mask] = 0, 0
        self.recent_deltas[mask], self.vision[mask], self.forward_error[mask] = np.nan, True, np.nan
        self.estimate_error_sum[mask] = 0.0
        self.habit_seconds[mask], self.planning_seconds[mask], self.plan_iterations[mask] = 0.0, 0.0, 0

    def advance(self, info: StepInfo, mask: np.ndarray, counted: np.ndarray | None = None,
                next_state: torch.Tensor | np.ndarray | None = None) -> None:
        """Carry the members in ``mask`` past the step in ``info``: state (``next_state``, default the
        integrator's), TD errors, vision, forward error, return, step; habit/planning counts for ``counted``."""
        counted = mask if counted is None else counted
        if next_state is None:  # the integrator's, on the device already (or from the numpy of a hand-made record)
            next_state = info.next_state if info.tensors is None else info.tensors.next_state
        nxt = torch.as_tensor(next_state, device=self.state.device)
        self.state = torch.where(torch.as_tensor(mask, device=self.state.device)[:, None], nxt, self.state)
        self.last_delta = np.where(mask, info.delta, self.last_delta)
        self.recent_deltas = push_delta(self.recent_deltas, info.delta, mask)
        error = np.linalg.norm((info.predicted_arm - info.next_state[:, ARM]).reshape(-1, 2, 2), axis=-1).mean(-1)
        self.forward_error = np.where(mask & info.vision, error, self.forward_error)
        self.vision = np.where(mask, info.vision, self.vision)
        self.ret += np.where(mask, info.reward, 0.0)
        self.estimate_error_sum += np.where(mask, estimate_error(info), 0.0)
        self.habit_n += counted & info.habit
        self.plan_n += counted & ~info.habit
        if info.decision_seconds is not None:
            self.habit_seconds += np.where(counted & info.habit, info.decision_seconds, 0.0)
            self.planning_seconds += np.where(counted & ~info.habit, info.decision_seconds, 0.0)
            self.plan_iterations += np.where(counted, info.plan_iterations, 0)
        self.step += mask

    def summary(self, k: int) -> dict[str, Any]:
        """Member ``k``'s episode so far as the per-episode columns every table carries (the training's metrics and
        the frozen tests'): a new per-episode measure is one field above and one line here."""
        return {"steps": int(self.step[k]), "habit_actions": int(self.habit_n[k]),
                "planning_actions": int(self.plan_n[k]),
                "estimate_error": float(self.estimate_error_sum[k] / max(1, self.step[k])),
                "habit_seconds": float(self.habit_seconds[k]), "planning_seconds": float(self.planning_seconds[k]),
                "plan_iterations": int(self.plan_iterations[k]), **(self.trials[k] if self.trials else {})}

    def context(self, episode: np.ndarray, agent: Policy, zone_radius: float,
                planner: Planner | None = None, habit_action: bool = True) -> ArbitrationContext:
        """The arbitrator's view of every member at this step (``episode`` as the arbitrator reads it;
        ``zone_radius``: the target zone's, cm, :attr:`EpisodeLoop.zone_radius`; ``planner``: the one whose
        model imagines the habit's sequence, :attr:`ArbitrationContext.habit_probe`; ``habit_action``: compute
        the actor's proposal before the decision (:attr:`Arbitrator.needs_habit_action`; else None, and
        :func:`select_action` computes it after the decision, only where the habit acts))."""
        state = self.state
        probe = None if planner is None else (lambda: planner.probe(agent, state))

        def predict_end(action: torch.Tensor) -> torch.Tensor:
            return agent.predict_arm(state, agent.executable(action, state))[:, END]

        # copies (torch.tensor), not views of the carried arrays: a context kept by a rule stays as it was
        return ArbitrationContext(episode=torch.tensor(episode), step=torch.tensor(self.step),
                                  last_delta=torch.tensor(self.last_delta, dtype=torch.float32),
                                  recent_deltas=torch.tensor(self.recent_deltas, dtype=torch.float32),
                                  vision=torch.tensor(self.vision), state=state,
                                  forward_error=torch.tensor(self.forward_error, dtype=torch.float32),
                                  habit_action=agent.actor_action(state) if habit_action else None,
                                  predict_end=predict_end,
                                  habit_probe=probe, zone_radius=float(zone_radius))


def estimate_error(info: StepInfo) -> np.ndarray:
    """``[E]`` the integrator's error after the step: mean over hand, elbow and target of the distance
    between the estimate and the truth (MuJoCo's sites) (cm)."""
    truth = np.concatenate([info.true_arm, info.target], axis=1)
    return np.linalg.norm((info.next_state[:, POSITIONS] - truth).reshape(-1, 3, 2), axis=-1).mean(-1)


@dataclasses.dataclass
class Choice:
    """What :func:`select_action` chose for every member, and what the choice cost."""

    action: torch.Tensor       # [E, 2] the command (noise added when exploring, bounded)
    decision: Decision         # the arbitrator's (``habit`` on the agent's device)
    iterations: np.ndarray     # [E] planning iterations run (0 where the habit acted)
    seconds: np.ndarray        # [E] each member's share of the decision's measured wall time (StepInfo.decision_seconds)
    gains: np.ndarray | None   # [E, K] the plan's best value after each iteration minus the habit's (None: no model)


def select_action(agent: Policy, arbitrator: Arbitrator, ctx: ArbitrationContext, active: np.ndarray,
                  explore: bool, planner: Planner, habit_seconds: float = 0.0) -> Choice:
    """The arbitrator's choice between the actor's and the ``planner``'s proposals (+ OU noise);
    ``habit_seconds``: the measured time of building ``ctx`` (with the actor's pass where it carries
    ``habit_action``). Without ``ctx.habit_action`` the actor's pass runs (and is timed)
    only when some member's habit acts: a kind that always plans is not charged for a habit it never uses."""
    state = ctx.state
    t0 = time.perf_counter()
    arbitrator.exploring = bool(explore)  # a rule that re-explores does so only where the actor explores
    decision = arbitrator.use_habit(ctx)
    if not isinstance(decision, tuple) or len(decision) not in (2, 3):
        raise ValueError(f"{type(arbitrator).__name__}.use_habit must return a Decision(habit [E] bools, inputs), "
                         f"got {type(decision).__name__}")
    decision = Decision(*decision)
    habit = torch.as_tensor(decision.habit, dtype=torch.bool).to(state.device)
    if tuple(habit.shape) != (ctx.E,):
        raise ValueError(f"{type(arbitrator).__name__}.use_habit must return [E] = ({ctx.E},) bools, "
                         f"got shape {tuple(habit.shape)}")
    common_seconds = habit_seconds + time.perf_counter() - t0  # the context, the rule (every member)
    budget = _budget(decision, habit, planner)
    t0 = time.perf_counter()
    habit_action = ctx.habit_action
    if habit_action is None and bool(habit.any()):
        habit_action = agent.actor_action(state)
    common_seconds += time.perf_counter() - t0  # the actor's pass, where a habit acts
    t0 = time.perf_counter()
    plan = planner.propose(agent, ctx, budget)
    plan_seconds = time.perf_counter() - t0
    proposal = plan.action if habit_action is None else torch.where(habit[:, None], habit_action, plan.action)
    if explore:
        sigma = agent.cfg.ou_sigma_at(ctx.episode.numpy())
        proposal = proposal + agent.noise.sample(torch.as_tensor(active), sigma).to(state.device)
    bound = agent.sizes.action_bound
    iterations = plan.iterations.cpu().numpy() * ~habit.cpu().numpy()
    seconds = _shares(common_seconds, plan_seconds, iterations)
    gains = None if plan.habit_value is None else arbitrator.plan_gains(agent, ctx, plan, planner)
    if plan.habit_value is not None and gains is None:  # the planner's imagined gain
        gains = (plan.best_values - plan.habit_value[:, None]).numpy()
    return Choice(proposal.clamp(-bound, bound), Decision(habit, dict(decision.inputs), decision.iterations),
                  iterations, seconds, gains)


def _budget(decision: Decision, habit: torch.Tensor, planner: Planner) -> torch.Tensor:
    """``[E]`` planning iterations per member: the decision's (where it grants them), else the planner's
    maximum; 0 where the habit acts."""
    planning = ~habit.cpu()
    if decision.iterations is None:
        return planning.long() * planner.max_iterations
    return torch.as_tensor(decision.iterations).long().cpu().clamp(0, planner.max_iterations) * planning


def _shares(common: float, plan_seconds: float, iterations: np.ndarray) -> np.ndarray:
    """Each member's share of a decision's time: ``common`` (the actor's pass and the arbitration, every
    member) split evenly, ``plan_seconds`` split in proportion to the iterations run."""
    total = iterations.sum()
    plan = plan_seconds * iterations / total if total else np.zeros(len(iterations))
    return common / len(iterations) + plan


def decision_inputs(decision: Decision) -> dict[str, np.ndarray]:
    """A decision's inputs (``name -> [E]``) as float numpy arrays (one device-to-host transfer for all)."""
    names = list(decision.inputs)
    return dict(zip(names, to_host([torch.as_tensor(decision.inputs[k]) for k in names])))


def to_host(tensors: Sequence[torch.Tensor]) -> list[np.ndarray]:
    """Tensors ``[E, ...]`` as float32 numpy arrays (bools as 0/1) through one device-to-host transfer: those on a
    device (a GPU) are packed into one ``[E, n]`` tensor there and copied once; those on the CPU are only
    converted. The values are exactly the tensors' (float32 of float32, 0/1 of bools)."""
    out: list[np.ndarray | None] = [None] * len(tensors)
    on_device = [i for i, t in enumerate(tensors) if t.device.type != "cpu"]
    for i, t in enumerate(tensors):
        if t.device.type == "cpu":
            out[i] = t.detach().float().numpy().copy()
    if on_device:
        parts = [tensors[i].detach().float() for i in on_device]
        packed = torch.cat([p.reshape(p.shape[0], -1) for p in parts], 1).cpu().numpy()
        start = 0
        for i, p in zip(on_device, parts):
            width = int(np.prod(p.shape[1:], dtype=np.int64))
            out[i] = packed[:, start:start + width].reshape(p.shape).copy()
            start += width
    return out  # type: ignore[return-value]


Override = Callable[[torch.Tensor, torch.Tensor], tuple[torch.Tensor, torch.Tensor]]


class EpisodeLoop:
    """The one per-member episode loop shared by training, evaluation and recordings.

    :meth:`start` resets members (environment, carried state, noise, the hooks' episode start),
    :meth:`act` arbitrates and steps (:func:`agent_step`), :meth:`advance` carries the state past
    the step and calls the hooks' step; :meth:`begin` and :meth:`steps` (together :meth:`run_episode`)
    are the frozen episode that evaluation and recordings run.
    """

    def __init__(self, agent: Policy, arbitrator: Arbitrator, env: VecEnv, zone_radius: float | None = None,
                 hooks: Sequence[Hook] = (), adapt: bool = True, *, integrator: Integrator,
                 planner: Planner) -> None:
        self.agent, self.arbitrator, self.env = agent, arbitrator, env
        #: Radius (cm) of the target zone the agent judges its estimate by: ``zone_radius``, default the
        #: task's (``env.spec.zone_radius``), resolved here once for every step.
        self.zone_radius = env.spec.zone_radius if zone_radius is None else zone_radius
        self.hooks = _checked(hooks)
        #: The arbitrator's and the integrator's running statistics learn from the steps (training);
        #: False: frozen (tests).
        self.adapt = adapt
        #: The state estimate (the run's integrator, :mod:`apac_mj.systems`; built by ``apac_mj.run.build``).
        self.integrator = integrator
        self.integrator.adapt = adapt
        #: The planning system (the kind's planner, :mod:`apac_mj.systems`; built by ``apac_mj.run.build``).
        self.planner = planner

    def with_arbitrator(self, arbitrator: Arbitrator, hooks: Sequence[Hook] = ()) -> "EpisodeLoop":
        """A loop like this one (its agent, environments, zone, integrator and planner, frozen or not) in which
        ``arbitrator`` decides, seen by ``hooks``."""
        return EpisodeLoop(self.agent, arbitrator, self.env, zone_radius=self.zone_radius, hooks=hooks,
                           adapt=self.adapt, integrator=self.integrator, planner=self.planner)

    def state_dict(self) -> dict[str, Any]:
        """What a checkpoint keeps: the arbitrator's and the integrator's running statistics; the planner's
        warm start and random streams where it has them."""
        d = {"arbitrator": self.arbitrator.state_dict(), "integrator": self.integrator.state_dict()}
        planner = self.planner.state_dict()
        return {**d, "planner": planner} if planner else d

    def load_state_dict(self, d: dict[str, Any]) -> None:
        """Restore :meth:`state_dict` (missing parts: kept as built; a checkpoint from before them)."""
        self.arbitrator.load_state_dict(d.get("arbitrator") or {})
        if "integrator" in d:
            self.integrator.load_state_dict(d["integrator"])
        self.planner.load_state_dict(d.get("planner") or {})

    def start(self, st: EpisodeState, mask: np.ndarray, reset_noise: bool = True) -> None:
        """New episodes for the members in ``mask``: reset their environment and carried state."""
        obs = self.env.reset(mask)
        seen = observed_state(obs, st.state.device)
        self.integrator.reset(np.asarray(mask, dtype=bool), seen)
        st.reset(mask, with_extra(seen, self.env))
        self.planner.reset(mask)
        if reset_noise:
            self.agent.noise.reset(torch.as_tensor(mask))
        for hook in self.hooks:
            hook.on_episode_start(mask.copy(), self.env)

    def act(self, st: EpisodeState, active: np.ndarray, episode: np.ndarray, explore: bool,
            arbitration_episode: np.ndarray | None = None, override: Override | None = None) -> StepInfo:
        """Arbitrate (the arbitrator reads ``arbitration_episode``, default ``episode``), let ``override``
        replace the action (the trainer's babbling), step the ``active`` members."""
        t0 = time.perf_counter()
        ctx = st.context(episode if arbitration_episode is None else arbitration_episode, self.agent,
                         self.zone_radius, self.planner, habit_action=self.arbitrator.needs_habit_action)
        meter = deliberation.meter(self.env, ctx)  # None: the world waits (no [deliberation] table)
        choice = select_action(self.agent, self.arbitrator, ctx, active, explore, self.planner,
                               habit_seconds=time.perf_counter() - t0)
        action, habit, inputs = choice.action, choice.decision.habit, decision_inputs(choice.decision)
        if override is not None:
            action, habit = override(action, habit)
        info = agent_step(self.agent, self.env, self.integrator, st.state, episode, st.step, active, action, habit,
                          zone_radius=self.zone_radius,
                          deliberation_ms=None if meter is None else meter.decision_ms(self.planner, choice, action))
        info.arbitration, info.decision_seconds = inputs, choice.seconds
        info.plan_iterations = np.where(habit.cpu().numpy(), 0, choice.iterations)
        info.plan_gains = choice.gains
        if choice.iterations.any() and self.planner.last_plan is not None:
            info.plan = {k: v.numpy() for k, v in self.planner.last_plan.items()}
        return info

    def advance(self, st: EpisodeState, info: StepInfo, active: np.ndarray, counted: np.ndarray | None = None,
                next_state: torch.Tensor | np.ndarray | None = None) -> None:
        """Carry ``st`` past ``info`` (see :meth:`EpisodeState.advance`), then the step hook."""
        st.advance(info, active, counted, next_state)
        if self.env.spec.trials is not None:  # the finished trials' measures, before their members are reset
            st.trials = st.trials or [{} for _ in range(self.env.E)]
            for k in np.flatnonzero(active & info.done):
                st.trials[k] = self.env.trial_record(k)
        self.arbitrator.observe(info, active if counted is None else counted, self.adapt)
        for hook in self.hooks:
            hook.on_step(info, self.env)

    def begin(self, members: np.ndarray) -> EpisodeState:
        """A frozen episode's start for ``members``: a fresh carry, their environments reset (noise untouched)."""
        st = EpisodeState.fresh(self.env.E, self.agent.device, POSITION_DIM + self.env.extra.shape[1])
        self.start(st, members, reset_noise=False)
        return st

    def steps(self, st: EpisodeState, members: np.ndarray, episode: int, arbitration_episode: int | None = None,
              stop_on_terminal: bool = False) -> Iterator[tuple[StepInfo, np.ndarray]]:
        """Step a begun frozen episode (no noise, no learning) to its end; yields ``(info, stepped)``.

        A member stops when its episode ends, or also (``stop_on_terminal``) when it judges the target
        reached (the occluded protocol)."""
        E = self.env.E
        running = members.copy()
        ep = np.full(E, episode)
        arb = None if arbitration_episode is None else np.full(E, arbitration_episode, dtype=np.int64)
        while running.any():
            info = self.act(st, running, ep, explore=False, arbitration_episode=arb)
            stepped = running.copy()
            self.advance(st, info, stepped)
            yield info, stepped
            running &= ~(info.done | (info.terminal if stop_on_terminal else np.zeros(E, dtype=bool)))

    def run_episode(self, members: np.ndarray, episode: int, arbitration_episode: int | None = None,
                    stop_on_terminal: bool = False) -> EpisodeState:
        """:meth:`begin` and every one of :meth:`steps`; returns the carry at the episode's end."""
        st = self.begin(members)
        for _ in self.steps(st, members, episode, arbitration_episode, stop_on_terminal):
            pass
        return st


def _checked(hooks: Sequence[Hook]) -> list[Hook]:
    wrong = [type(h).__name__ for h in hooks if not isinstance(h, Hook)]
    if wrong:
        raise TypeError(f"hooks must be apac_mj.run.rollout.Hook instances, got {', '.join(wrong)}; "
                        "pass plain functions as on_step= or on_episode_start=")
    return list(hooks)


def agent_step(agent: Policy, vec_env: VecEnv, integrator: Integrator, state: torch.Tensor, episode: np.ndarray,
               step: np.ndarray, active: np.ndarray, action: torch.Tensor, habit: torch.Tensor,
               zone_radius: float | None = None, deliberation_ms: np.ndarray | None = None) -> StepInfo:
    """One step of the ``active`` members with ``action`` ``[E,2]`` (``habit`` ``[E]``: the actor chose it).

    ``integrator`` makes ``s_{t+1}`` from the prediction and the observation; ``zone_radius`` is the
    radius the agent uses to judge its own estimate under occlusion (default: the task's);
    ``deliberation_ms`` ``[E]``: the decision's time, which the plant runs on for under the last command before
    ``action`` starts (a world that does not wait, :mod:`apac_mj.run.deliberation`; None: the world waits).
    """
    device = state.device
    executable = agent.executable(action, state)  # what the plant will do: every network sees this action
    predicted = agent.predict_arm(state, executable)
    if deliberation_ms is not None:
        deliberation.elapse(vec_env, deliberation_ms, active)
    obs = vec_env.step(action.detach().cpu().double().numpy(), active)
    seen, vision, seen_reward, reached, active_t = _observed_step(obs, active, device)
    if vec_env.extra.shape[1]:  # the integrator estimates the positions; the extra observations (proprioception)
        # are read as they are, every step
        positions = integrator.update(state[:, POSITIONS], predicted, seen, vision, active_t)
        kept = torch.cat([positions, state[:, EXTRA]], 1)
        next_state = torch.where(active_t[:, None], with_extra(positions, vec_env), kept)
    else:
        next_state = integrator.update(state, predicted, seen, vision, active_t)
    radius = vec_env.spec.zone_radius if zone_radius is None else zone_radius
    est_distance = torch.linalg.vector_norm(next_state[:, END] - next_state[:, TARGET], dim=1)
    reward = torch.where(vision, seen_reward, -est_distance)
    terminal = torch.where(vision, reached, est_distance <= radius)
    delta = agent.td_error(state, executable, reward, next_state, terminal.float())
    info = _info(vec_env, obs, episode, step, active, state, action, habit, delta, predicted, reward,
                 next_state, terminal, radius)
    info.tensors = StepTensors(state, action, reward, next_state, terminal)
    return info


def _info(vec_env: VecEnv, obs: Observation, episode, step, active, state, action, habit, delta, predicted,
          reward, next_state, terminal, zone_radius: float) -> StepInfo:
    """The step's record; the agent's tensors reach the host in one transfer (:func:`to_host`)."""
    state, action, habit, delta, predicted, reward, next_state, terminal = to_host(
        [state, action, habit, delta, predicted, reward, next_state, terminal])
    return StepInfo(
        episode=np.asarray(episode, dtype=np.int64).copy(), step=np.asarray(step, dtype=np.int64).copy(),
        active=np.asarray(active, dtype=bool).copy(), state=state, action=action,
        habit=habit.astype(bool), delta=delta, predicted_arm=predicted, reward=reward,
        done=obs.last.copy(), reached=obs.reached.copy(), vision=obs.vision.copy(), next_state=next_state,
        terminal=terminal.astype(bool), zone_radius=float(zone_radius), **vec_env.snapshot())


