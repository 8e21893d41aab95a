"""The clock of a world that does not wait (a task's ``[deliberation]`` table, :mod:`apac_mj.suite.deliberation`).

Each step the episode loop's :class:`Meter` counts what the decision computed, member by member, in the counts
of :mod:`apac_mj.run.timing` (sequential passes of each network, and the extra rows of batched passes):

* the actor's proposal (:data:`~apac_mj.run.timing.HABIT`) where the rule read it before deciding
  (``needs_habit_action``) or the habit acted;
* the rule's own look-ahead, counted where it was called: the habit's probe
  (:func:`~apac_mj.run.timing.probe_counts`, once a step: the planner caches it; its first pass is the habit's
  proposal) and the forward model as a checker (``predict_end``, one model pass);
* the plan: the paper's inverse model, one query an iteration (:data:`~apac_mj.run.timing.INVERSE`); MPC,
  :func:`~apac_mj.run.timing.mpc_counts` (the habit's rollout, unless the probe imagined it already, its
  perturbed copies, then the iterations).

The counts become milliseconds by :func:`apac_mj.run.timing.decision_ms` at :class:`~apac_mj.run.timing.Timing`'s
prices (one price for the same work), times the table's ``time_scale``; the plant then runs that long under the
last command before the new one starts (:func:`elapse`). A command that is not the decision's (motor babbling
replaces it) took no deliberation.
"""
from __future__ import annotations

from typing import Any, Callable

import numpy as np

from apac_mj.run import timing
from apac_mj.suite import deliberation as plant_clock
from apac_mj.types import ArbitrationContext


class Meter:
    """What one decision computed, per member: wraps the context's look-ahead so that calls are counted."""

    def __init__(self, ctx: ArbitrationContext, spec: Any, timing_: timing.Timing | None = None) -> None:
        #: The task's ``[deliberation]`` table.
        self.spec = spec
        self.timing = timing.Timing() if timing_ is None else timing_
        E = ctx.E
        self.probes = 0          # calls of the habit's probe (every member each)
        self.checks = 0          # calls of the forward model as a checker (every member each)
        self.needs_action = ctx.habit_action is not None
        ctx.habit_probe = self._counted(ctx.habit_probe, "probes")
        ctx.predict_end = self._counted(ctx.predict_end, "checks")
        self.E = E

    def _counted(self, fn: Callable | None, name: str) -> Callable | None:
        if fn is None:
            return None

        def wrapped(*args: Any) -> Any:
            setattr(self, name, getattr(self, name) + 1)
            return fn(*args)

        return wrapped

    def counts(self, planner: Any, choice: Any) -> list[timing.Counts]:
        """Each member's counts of this decision (``planner``: the loop's; ``choice``: what was chosen, a
        :class:`apac_mj.run.rollout.Choice`, which imports this module)."""
        habit = np.asarray(choice.decision.habit.cpu().numpy(), dtype=bool)
        iterations = np.asarray(choice.iterations, dtype=np.int64)
        probed = self.probes > 0 and _horizon(planner) > 0
        rule = timing.probe_counts(_horizon(planner)) if probed else timing.Counts()  # the planner caches it
        rule = rule + timing.Counts(model=self.checks)
        return [rule + (timing.HABIT if (self.needs_action or habit[k]) and not probed else timing.Counts())
                + _plan_counts(planner, int(iterations[k]), probed) for k in range(self.E)]

    def decision_ms(self, planner: Any, choice: Any, action: Any) -> np.ndarray:
        """``[E]`` each member's decision time (ms): its counts priced, times ``time_scale``; 0 where the
        executed command is not the decision's (``action`` differs from ``choice.action``: babbling)."""
        ms = np.array([timing.decision_ms(c, self.timing) for c in self.counts(planner, choice)])
        own = (action == choice.action).all(1).cpu().numpy()
        return np.where(own, ms * self.spec.time_scale, 0.0)


def meter(env: Any, ctx: ArbitrationContext) -> Meter | None:
    """A :class:`Meter` on ``ctx`` where ``env``'s task does not wait (its ``[deliberation]`` table); else None."""
    spec = env.spec.deliberation
    return None if spec is None else Meter(ctx, spec)


def _horizon(planner: Any) -> int:
    """The imagined steps of ``planner``'s look-ahead (0: it has none)."""
    p = getattr(planner, "p", None)
    return int(getattr(p, "horizon", 0))


def _plan_counts(planner: Any, iterations: int, probed: bool) -> timing.Counts:
    """What ``iterations`` of ``planner`` computed for one member (0: nothing); ``probed``: the rule's probe
    imagined the habit's sequence already (the plan's pool reuses it)."""
    from apac_mj.agent.planner import InversePlanner, MPCPlanner

    if iterations == 0:
        return timing.Counts()
    if isinstance(planner, InversePlanner):
        return timing.INVERSE * iterations
    if not isinstance(planner, MPCPlanner):
        raise ValueError(f"a world that does not wait prices the registered planners' work ('inverse', 'mpc'); "
                         f"{type(planner).__name__} has no count of its passes")
    plan = timing.mpc_counts(planner.p, iterations)
    return plan - timing.probe_counts(planner.p.horizon) if probed else plan


def elapse(vec_env: Any, ms: np.ndarray, active: np.ndarray) -> np.ndarray:
    """Run each ``active`` member's plant on for its ``ms`` under its last command; returns the sub-steps run."""
    steps = np.zeros(len(ms), dtype=np.int64)
    for k in np.flatnonzero(active):
        steps[k] = plant_clock.elapse(vec_env.physics(k), float(ms[k]))
    return steps
