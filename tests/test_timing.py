"""The forced-response test's time model (apac_mj.run.timing): its checks at each boundary, the planners'
iteration times, the deadlines a test may use, and a test plan's settings."""
from __future__ import annotations

import dataclasses
import math
import types

import numpy as np
import pytest

from apac_mj.run import timing
from apac_mj.run.timing import TestPlan, Timing

FIELDS = [f.name for f in dataclasses.fields(Timing)]
POSITIVE = ("inverse_pass_ms", "mpc_iteration_ms", "step_ms")


def test_the_calibration_is_the_documented_one():
    """docs/forced_response.md, "Calibration": the numbers the published curves were made with."""
    assert dataclasses.asdict(Timing()) == {"habit_latency_ms": 300.0, "planning_latency_ms": 300.0,
                                            "latency_sd_ms": 60.0, "inverse_pass_ms": 200.0,
                                            "mpc_iteration_ms": 50.0, "model_pass_ms": 25.0, "step_ms": 50.0}


@pytest.mark.parametrize("field", FIELDS)
@pytest.mark.parametrize("bad", [-1.0, float("nan"), float("inf"), True, "300"])
def test_every_field_must_be_a_finite_number_of_ms_at_least_0(field, bad):
    with pytest.raises(ValueError, match=rf"^timing: {field} must be a finite number of ms >= 0, got {bad!r}$"):
        Timing(**{field: bad})


@pytest.mark.parametrize("field", FIELDS)
def test_zero_is_allowed_except_for_a_passs_a_iterations_and_a_steps_duration(field):
    if field in POSITIVE:
        with pytest.raises(ValueError, match=rf"^timing: {field} must be > 0 ms, got 0$"):
            Timing(**{field: 0})
    else:
        assert getattr(Timing(**{field: 0}), field) == 0
    assert getattr(Timing(**{field: 1e-9}), field) == 1e-9


def test_a_planners_iteration_is_the_field_its_kind_names(monkeypatch):
    t = Timing(inverse_pass_ms=123.0, mpc_iteration_ms=45.0)
    assert t.iteration("inverse") == 123.0 and t.iteration("mpc") == 45.0
    assert isinstance(t.iteration("mpc"), float)
    from apac_mj import systems

    monkeypatch.setattr(systems, "planner", lambda name: types.SimpleNamespace(iteration_ms="warp_ms"))
    with pytest.raises(ValueError, match=r"^planner 'x': its iteration_ms names 'warp_ms', not a Timing field "
                                         r"\(habit_latency_ms, planning_latency_ms, .*, step_ms\)$"):
        t.iteration("x")


def test_deadlines_are_finite_and_at_least_one_step():
    t = Timing(step_ms=40.0)
    out = t.check_deadlines([[40, 100.5], [1000, 40.0]])
    assert out.dtype == np.float64 and out.tolist() == [40.0, 100.5, 1000.0, 40.0]
    assert t.check_deadlines([40, 100]).dtype == np.float64  # whole milliseconds too
    with pytest.raises(ValueError, match=r"^prep_times_ms: give at least one preparation time \(ms\)$"):
        t.check_deadlines([])
    with pytest.raises(ValueError, match=r"^prep_times_ms: every deadline must be a finite number of ms >= one "
                                         r"step \(step_ms = 40\): a deadline shorter than a step launches no "
                                         r"movement; got \[39.5, nan, inf\]$"):
        t.check_deadlines([100, 39.5, math.nan, math.inf])


def test_a_test_plan_checks_its_deadlines_trials_and_repeats():
    plan = TestPlan((100.0, 400.0), trials=1, repeats=1)
    assert plan.timing == Timing() and plan.seed == 0 and (TestPlan((100.0,)).trials, TestPlan((100.0,)).repeats) \
        == (100, 3)
    with pytest.raises(ValueError, match="prep_times_ms: every deadline"):
        TestPlan((10.0,))
    for name in ("trials", "repeats"):
        for bad in (0, -2, True, 2.0):
            with pytest.raises(ValueError, match=rf"^{name} must be an integer >= 1, got {bad!r}$"):
                TestPlan((100.0,), **{name: bad})


def test_the_tables_columns_are_the_outcomes_and_who_acted():
    assert timing.OUTCOMES == ("correct", "habitual", "other", "timeout")
    assert timing.COLUMNS[:7] == ("seed", "episode", "variant", "prep_ms", "cue", "remapped", "trials")
    assert timing.COLUMNS[7:] == (*timing.OUTCOMES, "habit_acted", "planner_acted", "default_acted")
