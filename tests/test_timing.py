"""The forced-response test's time model (apac_mj.run.timing): its checks at each boundary, the planners'
iteration times, the deadlines a test may use, and a test plan's settings."""
from __future__ import annotations

import dataclasses
import math
import types

import numpy as np
import pytest

from apac_mj.rules import MPCParams
from apac_mj.run import timing
from apac_mj.run.timing import Counts, TestPlan, Timing, decision_ms

FIELDS = [f.name for f in dataclasses.fields(Timing)]
NUMBERS = [f for f in FIELDS if f not in timing.OVERRIDES]
POSITIVE = ("actor_pass_ms", "critic_pass_ms", "inverse_pass_ms", "model_pass_ms", "mpc_iteration_ms", "step_ms")


def test_the_calibration_is_the_documented_one():
    """docs/forced_response.md, "Calibration": the numbers the curves are made with, :func:`calibrate`'s fit."""
    assert dataclasses.asdict(Timing()) == {"perception_ms": 400.61, "latency_sd_ms": 60.0, "actor_pass_ms": 1.456,
                                            "critic_pass_ms": 0.917, "inverse_pass_ms": 1.383, "model_pass_ms": 1.660,
                                            "row_ms": 0.0655, "step_ms": 50.0, "habit_latency_ms": None,
                                            "mpc_iteration_ms": None}
    fitted = timing.calibrate()
    assert fitted.habit_latency_ms is None and fitted.mpc_iteration_ms is None and fitted.step_ms == 50.0
    for f in NUMBERS:
        assert getattr(fitted, f) == pytest.approx(getattr(Timing(), f), abs=6e-3 if f == "perception_ms" else 6e-4,
                                                   rel=0), f


@pytest.mark.parametrize("field", FIELDS)
@pytest.mark.parametrize("bad", [-1.0, float("nan"), float("inf"), True, "300"])
def test_every_field_must_be_a_finite_number_of_ms_at_least_0(field, bad):
    with pytest.raises(ValueError, match=rf"^timing: {field} must be a finite number of ms >= 0, got {bad!r}$"):
        Timing(**{field: bad})


@pytest.mark.parametrize("field", FIELDS)
def test_zero_is_allowed_except_for_a_passs_a_iterations_and_a_steps_duration(field):
    assert (field in timing.OVERRIDES) == (field in ("habit_latency_ms", "mpc_iteration_ms"))
    if field in timing.OVERRIDES:
        assert getattr(Timing(**{field: None}), field) is None
    if field in POSITIVE:
        with pytest.raises(ValueError, match=rf"^timing: {field} must be > 0 ms, got 0$"):
            Timing(**{field: 0})
    else:
        assert getattr(Timing(**{field: 0}), field) == 0
    assert getattr(Timing(**{field: 1e-9}), field) == 1e-9


def test_a_planners_iteration_is_the_field_its_kind_names(monkeypatch):
    t = Timing(inverse_pass_ms=123.0, mpc_iteration_ms=45.0)
    assert t.iteration("inverse") == 123.0 and t.iteration("mpc") == 45.0
    assert isinstance(t.iteration("mpc"), float) and isinstance(Timing(inverse_pass_ms=2).iteration("inverse"), float)
    # unset: one iteration's passes at their prices (4 model, 1 actor, 1 critic; 31 extra rows of each)
    p = Timing(actor_pass_ms=1.0, critic_pass_ms=10.0, model_pass_ms=100.0, row_ms=0.5)
    assert p.iteration("mpc") == 4 * 100 + 1 + 10 + 0.5 * 31 * 6
    assert p.iteration("mpc", MPCParams(horizon=2, candidates=3, elites=2)) == 2 * 100 + 1 + 10 + 0.5 * 2 * 4
    from apac_mj import systems

    monkeypatch.setattr(systems, "planner", lambda name: types.SimpleNamespace(iteration_ms="warp_ms"))
    with pytest.raises(ValueError, match=r"^planner 'x': its iteration_ms names 'warp_ms', not a Timing field "
                                         r"\(perception_ms, latency_sd_ms, .*, mpc_iteration_ms\)$"):
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
    assert plan.default == "guess" and plan.told_value is False
    assert TestPlan((100.0,), default="still").default == "still"
    with pytest.raises(ValueError, match=r"^default must be one of \('guess', 'still'\), got 'wait'$"):
        TestPlan((100.0,), default="wait")
    with pytest.raises(ValueError, match=r"^told_value must be true or false, got 1$"):
        TestPlan((100.0,), told_value=1)
    with pytest.raises(ValueError, match="prep_times_ms: every deadline"):
        TestPlan((10.0,))
    for name in ("trials", "repeats"):
        for bad in (0, -2, True, 2.0):
            with pytest.raises(ValueError, match=rf"^{name} must be an integer >= 1, got {bad!r}$"):
                TestPlan((100.0,), **{name: bad})


def test_the_tables_columns_are_the_outcomes_and_who_acted():
    assert timing.OUTCOMES == ("correct", "habitual", "other", "timeout")
    assert timing.COLUMNS[:7] == ("seed", "episode", "variant", "prep_ms", "cue", "remapped", "trials")
    assert timing.COLUMNS[7:] == (*timing.OUTCOMES, "habit_acted", "planner_acted", "default_acted", "guessed")


# -- the time model: counts and prices --------------------------------------------------------------------------
PRICES = Timing(actor_pass_ms=1.0, critic_pass_ms=10.0, inverse_pass_ms=1000.0, model_pass_ms=100.0, row_ms=0.5,
                perception_ms=7.0)


def test_known_counts_cost_known_milliseconds():
    assert decision_ms(Counts(), PRICES) == 0.0
    assert decision_ms(Counts(actor=2, critic=3, inverse=4, model=5, rows=6), PRICES) == 2 + 30 + 4000 + 500 + 3
    assert decision_ms(timing.HABIT, PRICES) == 1.0 and decision_ms(timing.INVERSE, PRICES) == 1000.0
    assert decision_ms(timing.IMAGINED_DELTA, PRICES) == 1 + 2 * 10 + 100  # pi'(s'), Q'(s', .), Q(s, a), model


def test_counts_add_subtract_scale_and_refuse_what_is_not_counts():
    a, b = Counts(1, 2, 3, 4, 5), Counts(1, 1, 0, 2, 5)
    assert a + b == Counts(2, 3, 3, 6, 10) and a - b == Counts(0, 1, 3, 2, 0) and a * 3 == Counts(3, 6, 9, 12, 15)
    assert a * 0 == Counts() and a.passes == 10 and Counts(rows=9).passes == 0
    with pytest.raises(ValueError, match=r"^counts: Counts\(actor=1, critic=1, inverse=0, model=2, rows=6\) is not "
                                         r"part of Counts\(actor=1, critic=2, inverse=3, model=4, rows=5\)$"):
        a - Counts(1, 1, 0, 2, 6)
    for bad in (-1, 1.0, True, "1"):
        with pytest.raises(ValueError, match=rf"^counts: model must be an integer >= 0, got {bad!r}$"):
            Counts(model=bad)
    assert Counts(actor=np.int64(2)).actor == 2


def test_a_rollout_is_a_model_pass_a_step_then_the_critic_the_habits_with_an_actor_pass_a_step():
    assert timing.rollout_counts(4, 1, habit=True) == Counts(actor=5, critic=1, model=4)
    assert timing.rollout_counts(4, 1, habit=False) == Counts(actor=1, critic=1, model=4)
    assert timing.rollout_counts(3, 32, habit=False) == Counts(actor=1, critic=1, model=3, rows=31 * 5)
    assert timing.rollout_counts(2, 3, habit=True) == Counts(actor=3, critic=1, model=2, rows=2 * 6)
    assert timing.rollout_counts(1, 1, habit=False) == Counts(actor=1, critic=1, model=1)
    for h, b in ((0, 1), (1, 0)):
        with pytest.raises(ValueError, match=rf"^a rollout needs horizon >= 1 and sequences >= 1, got {h}, {b}$"):
            timing.rollout_counts(h, b, habit=True)
    with pytest.raises(ValueError, match=r"^habit must be True or False, got None$"):
        timing.rollout_counts(1, 1, habit=None)


def test_the_same_work_has_the_same_price_the_probe_and_an_iteration():
    """The audit: the probe (4 model passes) cost 100 ms while an MPC iteration that needs that rollout cost 50.
    Now the probe is an iteration over one sequence plus the habit's actor pass at each imagined step."""
    p = MPCParams()
    probe, iteration = timing.probe_counts(4), timing.iteration_counts(p)
    assert probe - timing.rollout_counts(4, 1, habit=False) == Counts(actor=4)
    assert decision_ms(iteration, PRICES) == decision_ms(timing.rollout_counts(4, 1, False), PRICES) + 0.5 * 31 * 6
    assert decision_ms(probe, PRICES) == 5 + 10 + 400


def test_the_told_values_cue_search_is_the_habit_of_every_cue_in_one_batch():
    assert timing.told_counts(4, 0) == Counts() and timing.probe_counts(4, 0) == timing.probe_counts(4)
    assert timing.told_counts(4, 1) == Counts(actor=4, model=4)
    assert timing.told_counts(3, 4) == Counts(actor=3, model=3, rows=3 * 6)
    assert timing.probe_counts(3, 4) == Counts(actor=4, critic=1, model=3) + Counts(actor=3, model=3, rows=18)
    with pytest.raises(ValueError, match=r"^cues must be >= 0, got -1$"):
        timing.told_counts(4, -1)


def test_a_plan_is_the_habits_rollout_its_variants_and_its_iterations():
    p = MPCParams(horizon=2, candidates=3, elites=2, habit_candidates=3, habit_noise=0.1)
    habit, variants = Counts(actor=3, critic=1, model=2), Counts(actor=1, critic=1, model=2, rows=4)
    iteration = Counts(actor=1, critic=1, model=2, rows=8)
    assert timing.mpc_setup_counts(p) == habit + variants
    assert timing.mpc_counts(p, 0) == Counts() and timing.mpc_counts(p, 1) == habit + variants + iteration
    assert timing.mpc_counts(p, 3) == habit + variants + iteration * 3
    assert timing.mpc_counts(p, 2, cues=2) == timing.mpc_counts(p, 2) + timing.told_counts(2, 2)
    for quiet in (dict(habit_noise=0.0), dict(habit_candidates=1), dict(habit_candidates=0)):
        assert timing.mpc_setup_counts(dataclasses.replace(p, **quiet)) == habit, quiet
    assert timing.mpc_setup_counts(dataclasses.replace(p, habit_candidates=2)) == habit + Counts(1, 1, 0, 2, 0)
    with pytest.raises(ValueError, match=r"^iterations must be >= 0, got -1$"):
        timing.mpc_counts(p, -1)


def test_the_habit_is_ready_after_perception_and_one_actor_pass_unless_set():
    assert PRICES.habit_ms() == 8.0 and Timing(habit_latency_ms=250).habit_ms() == 250.0
    assert isinstance(Timing(habit_latency_ms=250).habit_ms(), float)
    assert Timing().habit_ms() == pytest.approx(400.61 + 1.456)


def test_a_plan_counts_from_the_habits_rollout_or_from_the_planners_start():
    """The MPC plan's pool holds the habit's sequence: its times run from the habit, beyond the habit's pass."""
    p = MPCParams(horizon=2, candidates=3, elites=2, habit_candidates=1, iterations=3)
    ms, after = PRICES.plan_ms("mpc", p, 3)
    setup = 2 + 10 + 200  # the rest of the habit's rollout: 2 actor passes, the critic, 2 model passes
    assert after and ms.tolist() == [setup + k * (1 + 10 + 200 + 0.5 * 2 * 4) for k in (1, 2, 3)]
    told, _ = PRICES.plan_ms("mpc", p, 2, cues=4)
    assert told.tolist() == (ms[:2] + decision_ms(timing.told_counts(2, 4), PRICES)).tolist()
    fixed, _ = dataclasses.replace(PRICES, mpc_iteration_ms=30.0).plan_ms("mpc", p, 2)
    assert fixed.tolist() == [setup + 30, setup + 60]
    ms, after = PRICES.plan_ms("inverse", None, 2)
    assert not after and ms.tolist() == [1000.0, 2000.0] and ms.dtype == np.float64
    assert Timing().plan_ms("mpc", None, 4)[0].tolist() == pytest.approx(
        [decision_ms(timing.mpc_counts(MPCParams(), k) - timing.HABIT, Timing()) for k in (1, 2, 3, 4)])


def test_the_fit_puts_the_agents_t50s_on_the_humans():
    """An agent whose habit is ready at A and a full plan at B, guessing among 4 before either: P(correct) is
    1/2 at the humans' unchanged and remapped t50s (closed forms of docs/forced_response.md)."""
    from scipy.stats import norm

    t = timing.calibrate()
    plan = timing.mpc_counts(MPCParams(), 4)
    A, B = t.habit_ms(), t.perception_ms + decision_ms(plan, t)
    u, r = timing.HUMAN_T50_UNCHANGED_MS, timing.HUMAN_T50_REMAPPED_MS
    assert 0.25 + 0.75 * norm.cdf((u - A) / 60) == pytest.approx(0.5, abs=1e-9)
    assert norm.cdf((r - B) / 60) + (1 - norm.cdf((r - A) / 60)) / 4 == pytest.approx(0.5, abs=1e-9)
    ratios = [getattr(t, f"{k}_pass_ms") / t.actor_pass_ms for k in ("critic", "inverse", "model")]
    assert ratios == pytest.approx([0.63, 0.95, 1.14]) and t.row_ms / t.actor_pass_ms == pytest.approx(0.045)
    other = timing.calibrate(300.0, 600.0, Counts(actor=1, model=10), sd=30.0, targets=3,
                             ratios={"actor": 2.0, "critic": 2.0, "inverse": 1.0, "model": 8.0, "row": 0.5})
    A2 = other.habit_ms()  # a guess among 3: P(correct) 1/2 where the habit is ready in a quarter of the trials
    assert A2 == pytest.approx(300 - 30 * norm.ppf(0.25))
    assert other.model_pass_ms == pytest.approx(4 * other.actor_pass_ms)
    B2 = other.perception_ms + 41 * other.actor_pass_ms  # the actor pass and 10 model passes, each 4 of it
    assert norm.cdf((600 - B2) / 30) + (1 - norm.cdf((600 - A2) / 30)) / 3 == pytest.approx(0.5, abs=1e-9)
    assert other.latency_sd_ms == 30.0 and other.row_ms == pytest.approx(other.actor_pass_ms / 4)
    assert other.critic_pass_ms == other.actor_pass_ms == pytest.approx(2 * other.inverse_pass_ms)
    with pytest.raises(ValueError, match=r"^calibrate: the remapped t50 \(300 ms\) puts the plan at 339\.6 ms, not "
                                         r"after the habit \(425\.8 ms\)$"):
        timing.calibrate(400.0, 300.0)
    assert timing.calibrate(400.0, 430.0).habit_ms() == pytest.approx(400 - 60 * norm.ppf(1 / 3))  # B 448 ms: a fit
    with pytest.raises(ValueError, match=r"^calibrate: a guess among 2 targets is correct half the time or more"):
        timing.calibrate(targets=2)
