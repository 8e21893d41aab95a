"""Time in a decision, derived from what the agent computed, and the forced-response test's table columns;
torch-free (the command line lists its fields, the report checks its tables, without loading torch).

**The time model** (issue 42 item 1; docs/forced_response.md, "Time in a decision"). A decision's duration is a
price list applied to deterministic counts of the network passes it computed:

* :class:`Counts`: sequential passes of the actor, the critic, the inverse model and the forward (or dynamics)
  model, and ``rows``, the extra rows of batched passes (a pass over ``B`` sequences adds ``B - 1``);
* :func:`decision_ms` ``(counts, timing) -> float``: ``sum(count x price)``, the prices being :class:`Timing`'s
  ``*_pass_ms`` and ``row_ms`` (pure; the same work has the same price wherever it is done);
* the counts of every computation a decision can make: :data:`HABIT` (one actor pass), :data:`INVERSE` (one
  inverse-model query), :data:`IMAGINED_DELTA` (the delta of the habit's imagined transition),
  :func:`rollout_counts` (sequences imagined ``horizon`` steps through the model, closed by ``Q(s_H, pi(s_H))``),
  :func:`probe_counts` (the graded rule's probe: the habit's rollout), :func:`iteration_counts` (one MPPI
  iteration), :func:`mpc_counts` (a plan of ``k`` iterations, the habit's rollout, which its pool needs, first)
  and :func:`told_counts` (a cued task's told value: which cue the told target had).

The prices' ratios are measured by ``bench/planning.py`` (it prints them: :data:`PASS_RATIOS`); their scale and
the cue's perception time are fitted (:func:`calibrate`) on two human numbers that are not the remapped cues'
habitual errors: the 4-day group's t50 of P(correct) for the unchanged cues (the habit's latency) and for the
remapped cues (a full-budget MPC plan). Use: ``decision_ms(mpc_counts(params, 4), Timing())``.
"""
from __future__ import annotations

import dataclasses
import math
from statistics import NormalDist
from typing import TYPE_CHECKING, Sequence

import numpy as np

if TYPE_CHECKING:
    from apac_mj.rules import MPCParams

#: Outcomes of a trial, in the order of the count columns.
OUTCOMES = ("correct", "habitual", "other", "timeout")
#: Which candidate a trial executed (the ``acted`` columns); ``default``: neither controller was ready (the
#: test's default response: a guess, or no movement).
ACTORS = ("habit", "planner", "default")
#: The columns of a test's table (one row per seed, variant, preparation time and cue; ``episode``: the training
#: episodes of the tested networks, absent from tables written before it; ``guessed``: the trials whose response
#: was a guess, absent from tables written before guesses).
COLUMNS = ("seed", "episode", "variant", "prep_ms", "cue", "remapped", "trials", *OUTCOMES,
           *(f"{a}_acted" for a in ACTORS), "guessed")

#: The prices of the networks' passes relative to the actor's, and of one extra row of a batched pass: measured
#: by ``bench/planning.py --passes-only --rounds 400 --task cued_targets`` (one agent, one torch thread, the
#: paper's sizes, a 2-core AMD EPYC, busy: actor 0.086, critic 0.054, inverse 0.081, model 0.098 ms a pass at one
#: row, 0.17-0.25 ms at 34 rows: an extra row 0.045 of an actor pass).
PASS_RATIOS: dict[str, float] = {"actor": 1.0, "critic": 0.63, "inverse": 0.95, "model": 1.14, "row": 0.045}
#: The humans' t50 of P(correct) (ms) the time scale is fitted on (:func:`calibrate`): Hardwick et al.'s 4-day
#: group, unchanged and remapped cues (docs/results/forced_response/human/human_summary.csv).
HUMAN_T50_UNCHANGED_MS, HUMAN_T50_REMAPPED_MS = 376.220, 507.766
#: The targets a guess chooses among (the cued task's 4 and the 4 responses of Hardwick et al.).
GUESS_TARGETS = 4


@dataclasses.dataclass(frozen=True)
class Counts:
    """The network passes one computation makes (deterministic for its settings)."""

    #: Sequential passes of the actor (the habit's policy; the target actor's too).
    actor: int = 0
    #: Of the critic (and target critic).
    critic: int = 0
    #: Of the inverse model (the paper's planner).
    inverse: int = 0
    #: Of the forward or dynamics model (one imagined step of a batch of sequences).
    model: int = 0
    #: Rows beyond the first of every batched pass (a pass over ``B`` sequences adds ``B - 1``).
    rows: int = 0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
                raise ValueError(f"counts: {f.name} must be an integer >= 0, got {v!r}")

    def __add__(self, other: Counts) -> Counts:
        return Counts(*(a + b for a, b in zip(dataclasses.astuple(self), dataclasses.astuple(other))))

    def __sub__(self, other: Counts) -> Counts:
        """What ``self`` computes beyond ``other`` (which it must contain)."""
        left = [a - b for a, b in zip(dataclasses.astuple(self), dataclasses.astuple(other))]
        if min(left) < 0:
            raise ValueError(f"counts: {other} is not part of {self}")
        return Counts(*left)

    def __mul__(self, k: int) -> Counts:
        return Counts(*(k * a for a in dataclasses.astuple(self)))

    @property
    def passes(self) -> int:
        """Sequential network passes of every kind."""
        return self.actor + self.critic + self.inverse + self.model


#: The habit's proposal: one actor pass.
HABIT = Counts(actor=1)
#: The paper's planner's one iteration: one inverse-model query.
INVERSE = Counts(inverse=1)
#: The delta of the habit's imagined transition: the model's next state, ``Q'(s', pi'(s'))`` and ``Q(s, a_h)``
#: (:func:`apac_mj.run.forced_response.imagined_delta`).
IMAGINED_DELTA = Counts(actor=1, critic=2, model=1)


def rollout_counts(horizon: int, sequences: int, habit: bool) -> Counts:
    """``sequences`` imagined ``horizon`` steps in one batch (:meth:`MPCPlanner.rollout`): a model pass a step
    (and, for the habit's sequence, an actor pass a step), then the terminal value ``Q(s_H, pi(s_H))``."""
    if horizon < 1 or sequences < 1:
        raise ValueError(f"a rollout needs horizon >= 1 and sequences >= 1, got {horizon}, {sequences}")
    if not isinstance(habit, bool):
        raise ValueError(f"habit must be True or False, got {habit!r}")
    one = Counts(actor=horizon + 1 if habit else 1, critic=1, model=horizon)
    return one + Counts(rows=(sequences - 1) * one.passes)


def told_counts(horizon: int, cues: int) -> Counts:
    """Finding the cue the told target had (:meth:`MPCPlanner.told_cue`, a cued task's told value): the habit of
    each of ``cues`` cues imagined ``horizon`` steps in one batch, no terminal value; none where ``cues`` is 0."""
    if cues < 0:
        raise ValueError(f"cues must be >= 0, got {cues}")
    one = Counts(actor=horizon, model=horizon) if cues else Counts()
    return one + Counts(rows=max(cues - 1, 0) * one.passes)


def probe_counts(horizon: int, cues: int = 0) -> Counts:
    """The graded rule's probe: the habit's sequence imagined ``horizon`` steps (its first pass is the habit's
    proposal: the probe is ready ``probe_counts(h) - HABIT`` after the habit), closed by the told cue's critic
    on a cued task with the told value (``cues``: its cues; 0: the shown cue's)."""
    return rollout_counts(horizon, 1, habit=True) + told_counts(horizon, cues)


def iteration_counts(p: MPCParams) -> Counts:
    """One MPPI iteration: ``candidates`` sampled sequences through the model (the refit computes no pass)."""
    return rollout_counts(p.horizon, p.candidates, habit=False)


def mpc_setup_counts(p: MPCParams, cues: int = 0) -> Counts:
    """What a plan computes before its first iteration: the habit's rollout (the probe, shared; ``cues``: as
    :func:`probe_counts`) and its ``habit_candidates - 1`` perturbed copies (none where ``habit_noise`` is 0)."""
    n = p.habit_candidates - 1
    variants = rollout_counts(p.horizon, n, habit=False) if n >= 1 and p.habit_noise > 0 else Counts()
    return probe_counts(p.horizon, cues) + variants


def mpc_counts(p: MPCParams, iterations: int, cues: int = 0) -> Counts:
    """A plan of ``iterations`` MPPI iterations (none: no plan, nothing computed; ``cues``: as
    :func:`probe_counts`)."""
    if iterations < 0:
        raise ValueError(f"iterations must be >= 0, got {iterations}")
    return mpc_setup_counts(p, cues) + iteration_counts(p) * iterations if iterations else Counts()


def decision_ms(counts: Counts, timing: Timing) -> float:
    """The time ``counts`` take (ms): each pass at its network's price, each extra row at ``row_ms``."""
    return (counts.actor * timing.actor_pass_ms + counts.critic * timing.critic_pass_ms
            + counts.inverse * timing.inverse_pass_ms + counts.model * timing.model_pass_ms
            + counts.rows * timing.row_ms)


@dataclasses.dataclass(frozen=True)
class Timing:
    """Time in a decision, simulated (ms from the cue): the perception of the cue, then the passes the agent
    computes at their prices (:func:`decision_ms`). The defaults are :func:`calibrate`'s fit (docs/forced_response.md,
    "Calibration")."""

    #: From the cue until the first pass can start (seeing and reading the cue), both systems alike.
    perception_ms: float = 400.61
    #: Trial-to-trial standard deviation of the latencies (Gaussian, cut at 0): the spread of the human curves.
    latency_sd_ms: float = 60.0
    #: One actor pass (the habit's proposal is one).
    actor_pass_ms: float = 1.456
    #: One critic pass.
    critic_pass_ms: float = 0.917
    #: One inverse-model pass (the paper's planner's one iteration).
    inverse_pass_ms: float = 1.383
    #: One forward/dynamics-model pass (one imagined step of a batch of sequences).
    model_pass_ms: float = 1.660
    #: One extra row of a batched pass (a sequence beyond the first).
    row_ms: float = 0.0655
    #: The shortest deadline allowed: one control step of the arm's decision clock. A deadline shorter than a
    #: step leaves the arm no step to launch a movement in.
    step_ms: float = 50.0
    #: None: the habit is ready ``perception_ms`` + one actor pass after the cue (the default); a number: its mean
    #: latency set directly (a sensitivity check; what follows the habit keeps its computed times).
    habit_latency_ms: float | None = None
    #: None: one MPPI iteration costs its passes (:func:`iteration_counts`, the default); a number: its price set
    #: directly (a sensitivity check).
    mpc_iteration_ms: float | None = None

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if v is None and f.name in OVERRIDES:
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ValueError(f"timing: {f.name} must be a finite number of ms >= 0, got {v!r}")
        for name in POSITIVE:
            if getattr(self, name) is not None and getattr(self, name) <= 0:
                raise ValueError(f"timing: {name} must be > 0 ms, got {getattr(self, name)!r}")

    def habit_ms(self) -> float:
        """Mean time from the cue until the habit's proposal is ready."""
        return self.perception_ms + decision_ms(HABIT, self) if self.habit_latency_ms is None \
            else float(self.habit_latency_ms)

    def iteration(self, planner: str, params: MPCParams | None = None) -> float:
        """One iteration of the registered planner ``planner`` (ms): the field its kind names
        (:attr:`apac_mj.systems.PlannerKind.iteration_ms`); ``mpc_iteration_ms`` unset: the passes of
        :func:`iteration_counts` at ``params`` (default: the MPC defaults)."""
        from apac_mj import systems

        field = systems.planner(planner).iteration_ms
        if field not in {f.name for f in dataclasses.fields(self)}:
            raise ValueError(f"planner {planner!r}: its iteration_ms names {field!r}, not a Timing field "
                             f"({', '.join(f.name for f in dataclasses.fields(self))})")
        if field == "mpc_iteration_ms" and self.mpc_iteration_ms is None:
            from apac_mj.rules import MPCParams

            return decision_ms(iteration_counts(params or MPCParams()), self)
        return float(getattr(self, field))

    def plan_ms(self, planner: str, params: MPCParams | None, K: int, cues: int = 0) -> tuple[np.ndarray, bool]:
        """``[K]``: when a plan of 1..K iterations is done (ms), and whether from the habit's readiness (True: the
        MPC plan's pool needs the habit's rollout, the probe, shared) or from the planner's start (the cue's
        perception: the inverse model). ``cues``: as :func:`probe_counts`."""
        if planner == "mpc":
            from apac_mj.rules import MPCParams

            p = params or MPCParams()
            setup = decision_ms(mpc_setup_counts(p, cues) - HABIT, self)
            return setup + self.iteration(planner, p) * np.arange(1, K + 1), True
        return self.iteration(planner) * np.arange(1, K + 1), False

    def check_deadlines(self, prep_times_ms: Sequence[float]) -> np.ndarray:
        """The preparation times as an array, each finite and at least one step (:attr:`step_ms`)."""
        t = np.asarray(prep_times_ms, dtype=np.float64).ravel()
        if t.size == 0:
            raise ValueError("prep_times_ms: give at least one preparation time (ms)")
        bad = [float(v) for v in t if not math.isfinite(v) or v < self.step_ms]
        if bad:
            raise ValueError(f"prep_times_ms: every deadline must be a finite number of ms >= one step "
                             f"(step_ms = {self.step_ms:g}): a deadline shorter than a step launches no movement; "
                             f"got {bad}")
        return t


#: The responses a test may give when nothing is ready (:attr:`TestPlan.default`).
DEFAULTS = ("guess", "still")
#: Timing fields that may be None (computed from the passes).
OVERRIDES = ("habit_latency_ms", "mpc_iteration_ms")
#: Timing fields that must be > 0 (a pass, a step; an iteration where set).
POSITIVE = ("actor_pass_ms", "critic_pass_ms", "inverse_pass_ms", "model_pass_ms", "step_ms", "mpc_iteration_ms")


def calibrate(t50_unchanged: float = HUMAN_T50_UNCHANGED_MS, t50_remapped: float = HUMAN_T50_REMAPPED_MS,
              plan: Counts | None = None, sd: float = 60.0, ratios: dict[str, float] = PASS_RATIOS,
              targets: int = GUESS_TARGETS) -> Timing:
    """The perception time and the price scale that put an agent's t50s of P(correct) on the humans': unchanged
    cues ``1/n + (1 - 1/n) Phi((t - A)/sd)`` (the habit, ready at ``A``; before it a guess among ``targets``),
    remapped cues ``Phi((t - B)/sd) + (1 - Phi((t - A)/sd))/n`` (a plan of ``plan``'s passes, default the MPC
    defaults' full budget, ready at ``B``; the habit, wrong, between); the prices keep ``ratios``."""
    from apac_mj.rules import MPCParams

    if targets < 3:
        raise ValueError(f"calibrate: a guess among {targets} targets is correct half the time or more: give >= 3")
    plan = mpc_counts(MPCParams(), MPCParams().iterations) if plan is None else plan
    n, normal = float(targets), NormalDist()
    A = t50_unchanged - sd * normal.inv_cdf((0.5 - 1 / n) / (1 - 1 / n))
    ready = 0.5 - (1 - normal.cdf((t50_remapped - A) / sd)) / n  # P(the plan is ready) at the remapped t50
    B = t50_remapped - sd * normal.inv_cdf(ready)  # (ready > 1/6 for 3 targets or more)
    unit = Timing(**{f"{k}_pass_ms": v for k, v in ratios.items() if k != "row"}, row_ms=ratios["row"])
    scale = (B - A) / (decision_ms(plan, unit) - decision_ms(HABIT, unit))
    try:  # a plan at or before the habit gives prices <= 0, which Timing refuses
        return Timing(perception_ms=A - scale * decision_ms(HABIT, unit), latency_sd_ms=sd,
                      **{f"{k}_pass_ms": scale * v for k, v in ratios.items() if k != "row"},
                      row_ms=scale * ratios["row"])
    except ValueError:
        raise ValueError(f"calibrate: the remapped t50 ({t50_remapped:g} ms) puts the plan at {B:.1f} ms, not after "
                         f"the habit ({A:.1f} ms)") from None


@dataclasses.dataclass(frozen=True)
class TestPlan:
    """What one forced-response test runs, checked once when made: the deadlines, the trials, the repeats of the
    frozen agent, the seed of the latency draws, the timing and the response when nothing is ready."""

    __test__ = False  # not a pytest class

    #: Allowed preparation times (ms), each at least one step (:meth:`Timing.check_deadlines`).
    prep_times_ms: tuple[float, ...]
    #: Trials per seed, cue and preparation time.
    trials: int = 100
    #: Runs of the frozen agent per seed and cue.
    repeats: int = 3
    #: The seed of the trials' latency draws and guesses.
    seed: int = 0
    timing: Timing = Timing()
    #: The response when neither controller is ready by the deadline: "guess" (a uniformly drawn cued target,
    #: as people are forced to) or "still" (no movement: a time-out).
    default: str = "guess"
    #: The MPC planner closes its horizon with the critic of the cue the told target had
    #: (:attr:`MPCPlanner.told_value`); False (the default, docs/forced_response.md: it measured no better): the
    #: shown cue's, which after a remap values the old target.
    told_value: bool = False

    def __post_init__(self) -> None:
        self.timing.check_deadlines(self.prep_times_ms)
        if not isinstance(self.told_value, bool):
            raise ValueError(f"told_value must be true or false, got {self.told_value!r}")
        for name in ("trials", "repeats"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
        if self.default not in DEFAULTS:
            raise ValueError(f"default must be one of {DEFAULTS}, got {self.default!r}")
