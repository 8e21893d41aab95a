"""Time in a forced-response decision (:mod:`apac_mj.run.forced_response`) and the columns of its test's table,
torch-free so that the command line can list its fields, and the report check its tables, without loading torch."""
from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import numpy as np

#: Outcomes of a trial, in the order of the count columns.
OUTCOMES = ("correct", "habitual", "other", "timeout")
#: Which candidate a trial executed (the ``acted`` columns).
ACTORS = ("habit", "planner", "default")
#: The columns of a test's table (one row per seed, variant, preparation time and cue; ``episode``: the training
#: episodes of the tested networks, absent from tables written before it).
COLUMNS = ("seed", "episode", "variant", "prep_ms", "cue", "remapped", "trials", *OUTCOMES,
           *(f"{a}_acted" for a in ACTORS))


@dataclasses.dataclass(frozen=True)
class Timing:
    """Time in a decision, simulated (ms from the cue). Calibrated so that the model's time axis can be laid
    on the human curves (docs/forced_response.md, "Calibration"): the habit's latency puts the unchanged cues'
    rise of P(correct) where the 4-day group's is, the planner's where the remapped cues' rise is."""

    #: Mean time from the cue until the habit's proposal (the actor's pass) is ready.
    habit_latency_ms: float = 300.0
    #: Mean time from the cue until the planner starts its first iteration (reading the cue, told the mapping).
    planning_latency_ms: float = 300.0
    #: Trial-to-trial standard deviation of both latencies (Gaussian, cut at 0): the spread of the human curves.
    latency_sd_ms: float = 60.0
    #: Duration of the paper's planner's one iteration (the inverse model's query, with what it needs).
    inverse_pass_ms: float = 200.0
    #: Duration of one iteration of the planner through the learned model (MPPI; ``agent.mpc.iterations`` of
    #: them, default 4: 200 ms in all, as the inverse model's one).
    mpc_iteration_ms: float = 50.0
    #: Duration of one forward-model pass (the imagined transition's delta; the graded rule's probe is
    #: ``horizon`` of them).
    model_pass_ms: float = 25.0
    #: The shortest deadline allowed: one control step of the arm's decision clock. A deadline shorter than a
    #: step leaves the arm no step to launch a movement in.
    step_ms: float = 50.0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ValueError(f"timing: {f.name} must be a finite number of ms >= 0, got {v!r}")
        for name in ("inverse_pass_ms", "mpc_iteration_ms", "step_ms"):
            if getattr(self, name) <= 0:
                raise ValueError(f"timing: {name} must be > 0 ms, got {getattr(self, name)!r}")

    def iteration(self, planner: str) -> float:
        """One iteration of the registered planner ``planner`` (ms): the field its kind names
        (:attr:`apac_mj.systems.PlannerKind.iteration_ms`)."""
        from apac_mj import systems

        field = systems.planner(planner).iteration_ms
        if field not in {f.name for f in dataclasses.fields(self)}:
            raise ValueError(f"planner {planner!r}: its iteration_ms names {field!r}, not a Timing field "
                             f"({', '.join(f.name for f in dataclasses.fields(self))})")
        return float(getattr(self, field))

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


@dataclasses.dataclass(frozen=True)
class TestPlan:
    """What one forced-response test runs, checked once when made: the deadlines, the trials, the repeats of the
    frozen agent, the seed of the latency draws and the timing."""

    __test__ = False  # not a pytest class

    #: Allowed preparation times (ms), each at least one step (:meth:`Timing.check_deadlines`).
    prep_times_ms: tuple[float, ...]
    #: Trials per seed, cue and preparation time.
    trials: int = 100
    #: Runs of the frozen agent per seed and cue.
    repeats: int = 3
    #: The seed of the trials' latency draws.
    seed: int = 0
    timing: Timing = Timing()

    def __post_init__(self) -> None:
        self.timing.check_deadlines(self.prep_times_ms)
        for name in ("trials", "repeats"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
