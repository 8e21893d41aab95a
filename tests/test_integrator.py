"""The integrators: the pass-through (the paper's) and the Kalman filter with an adaptive process variance."""
from __future__ import annotations

import io

import numpy as np
import pytest
import torch

from apac_mj.agent.integrator import KalmanIntegrator, PassThrough, integrate
from apac_mj.run.build import make_integrator
from apac_mj.config import AgentConfig
from apac_mj.types import Integrator

ALL = np.ones


def _random_inputs(g: torch.Generator, E: int):
    """A random step: prior [E,6], predicted [E,4], observed [E,6], vision [E], active [E]."""
    prior, predicted, observed = (torch.randn(E, n, generator=g) * 5 for n in (6, 4, 6))
    vision = torch.rand(E, generator=g) < 0.5
    active = torch.rand(E, generator=g) < 0.7
    return prior, predicted, observed, vision, active


def _forward(state: torch.Tensor, t: int) -> torch.Tensor:
    """A deterministic stand-in forward model: the arm moves by a step that depends on the estimate."""
    return state[:, :4] + torch.sin(state[:, :4] + t)


# -- (a) the pass-through is today's integrator ------------------------------------------
def test_pass_through_is_integrate_plus_the_target_rule():
    g = torch.Generator().manual_seed(0)
    E = 16
    f = PassThrough(E)
    for _ in range(20):
        prior, predicted, observed, vision, active = _random_inputs(g, E)
        out = f.update(prior, predicted, observed, vision.numpy(), active)  # numpy masks are accepted
        arm = integrate(observed[:, :4], predicted, vision)
        target = torch.where(vision[:, None], observed[:, 4:], prior[:, 4:])
        expected = torch.where(active[:, None], torch.cat([arm, target], 1), prior)
        assert torch.equal(out, expected)
        assert torch.equal(out[~active], prior[~active])
        seen, blind = active & vision, active & ~vision
        assert torch.equal(out[seen], observed[seen]) and torch.equal(out[blind, :4], predicted[blind])
    assert torch.equal(f.variance(), torch.zeros(E, 6)) and f.state_dict() == {}


# -- (b) Kalman without observation noise is the pass-through, bit for bit ---------------------
def test_kalman_without_noise_equals_pass_through_bit_exact():
    """Chained estimates (each filter's own output feeds its next prediction), random vision, inactive
    members and episode resets: any difference would propagate."""
    g = torch.Generator().manual_seed(1)
    E = 8
    kalman, plain = KalmanIntegrator(E, obs_std=0.0), PassThrough(E)
    start = torch.randn(E, 6, generator=g) * 5
    xk, xp = start.clone(), start.clone()
    kalman.reset(ALL(E, bool), start)
    plain.reset(ALL(E, bool), start)
    seen_any = 0
    for t in range(300):
        if t % 30 == 29:
            mask = torch.rand(E, generator=g) < 0.5
            fresh = torch.randn(E, 6, generator=g) * 5
            xk, xp = torch.where(mask[:, None], fresh, xk), torch.where(mask[:, None], fresh, xp)
            kalman.reset(mask, fresh)
            plain.reset(mask, fresh)
        observed = torch.randn(E, 6, generator=g) * 5
        vision, active = torch.rand(E, generator=g) < 0.4, torch.rand(E, generator=g) < 0.8
        observed[~vision] = torch.nan  # meaningless where unseen: must not leak
        xk = kalman.update(xk, _forward(xk, t), observed, vision, active)
        xp = plain.update(xp, _forward(xp, t), observed, vision, active)
        assert torch.equal(xk, xp), t
        seen_any += int((vision & active).sum())
    assert seen_any > 500 and torch.isfinite(xk).all()
    assert (kalman.q() > 0).all()  # learned something, yet K = 1 whenever seen


# -- (c) against an independent scalar Kalman filter --------------------------------------------
def _reference(z0, predicted, observed, seen, R, q_fixed, floor=1e-4, window=200, q0=0.25):
    """Plain-float scalar filters, one per coordinate (one member); Mehra's q when ``q_fixed`` is None."""
    x, P = list(z0), [R] * 6
    a_nu, a_pv, n = [0.0] * 4, [0.0] * 4, 0
    out, qs = [], []
    for pred, obs, s in zip(predicted, observed, seen):
        q = [q_fixed if q_fixed is not None else (max(a_nu[i] - a_pv[i], floor) if n else q0) for i in range(4)]
        qs.append(q)
        if s and q_fixed is None:
            n += 1
            rate = 1.0 / min(n, window)
            for i in range(4):
                a_nu[i] += rate * ((obs[i] - pred[i]) ** 2 - a_nu[i])
                a_pv[i] += rate * (P[i] + R - a_pv[i])
        for i in range(6):
            xm, pm = (pred[i], P[i] + q[i]) if i < 4 else (x[i], P[i])
            if s:
                k = 1.0 if pm + R == 0 else pm / (pm + R)
                x[i], P[i] = xm + k * (obs[i] - xm), (1 - k) * pm
            else:
                x[i], P[i] = xm, pm
        out.append(list(x))
    return np.array(out), np.array(qs)


@pytest.mark.parametrize("q_fixed", [0.01, None])
def test_kalman_matches_a_hand_written_scalar_filter(q_fixed):
    rng = np.random.default_rng(2)
    T, R = 120, 0.3 ** 2
    z0 = rng.normal(size=6) * 3
    predicted = rng.normal(size=(T, 4)) * 3
    observed = rng.normal(size=(T, 6)) * 3
    seen = rng.uniform(size=T) < 0.6
    f = KalmanIntegrator(1, obs_std=0.3, process_var=q_fixed, window=20)  # 120 steps: past the running mean
    x = torch.tensor(z0[None], dtype=torch.float64)
    f.reset(ALL(1, bool), x)
    got, qs = [], []
    for t in range(T):
        qs.append(f.q()[0].numpy().copy())
        x = f.update(x, torch.tensor(predicted[t:t + 1]), torch.tensor(observed[t:t + 1]),
                     np.array([seen[t]]), ALL(1, bool))
        got.append(x[0].numpy())
    want, want_q = _reference(z0, predicted, observed, seen, R, q_fixed, window=20)
    np.testing.assert_allclose(np.array(got), want, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.array(qs), want_q, rtol=1e-4, atol=1e-7)
    assert np.ptp(want_q) > 0 if q_fixed is None else np.all(want_q == q_fixed)
    assert not np.allclose(np.array(got)[seen, :4], observed[seen, :4], atol=1e-3)  # a real blend, not a copy


# -- (d) a synthetic problem: noisy vision, a good forward model ------------------------------------
def _synthetic(filt, E, obs_std, model_std, T=600, episode=30, seed=0):
    """True arm moves by known random steps; the forward model predicts from the filter's own estimate
    with N(0, model_std^2) error; observations are the truth plus N(0, obs_std^2). Returns the mean
    end-effector error (cm) over all steps after the first of each episode."""
    g = torch.Generator().manual_seed(seed)
    true, errors, est = torch.zeros(E, 6), [], None
    for t in range(T):
        if t % episode == 0:
            true = torch.randn(E, 6, generator=g) * 3
            est = true + obs_std * torch.randn(E, 6, generator=g)
            filt.reset(ALL(E, bool), est)
            continue
        step = torch.randn(E, 4, generator=g)
        predicted = est[:, :4] + step + model_std * torch.randn(E, 4, generator=g)
        true[:, :4] += step
        observed = true + obs_std * torch.randn(E, 6, generator=g)
        est = filt.update(est, predicted, observed, ALL(E, bool), ALL(E, bool))
        errors.append(torch.linalg.vector_norm(est[:, :2] - true[:, :2], dim=1).mean().item())
    return float(np.mean(errors))


def test_kalman_halves_the_pass_through_error_under_noisy_vision():
    """obs std 0.5 cm (the zone radius), model error 0.05 cm: measured ratio ~0.40 (adaptive q; ~0.36
    with the true q fixed); pass-through's error is the noise's, 0.5 sqrt(pi/2) ~ 0.63 cm."""
    E = 4
    kalman = KalmanIntegrator(E, obs_std=0.5)
    err_k, err_p = _synthetic(kalman, E, 0.5, 0.05), _synthetic(PassThrough(E), E, 0.5, 0.05)
    assert abs(err_p - 0.5 * np.sqrt(np.pi / 2)) < 0.03
    assert err_k < 0.5 * err_p
    q = kalman.q()
    assert (q >= kalman.process_floor).all() and q.median() < 0.02  # learned away from initial 0.25


def test_adaptive_q_converges_where_it_is_identifiable():
    """obs std = model error = 0.05 cm: after 600 steps every member's and coordinate's q is within a
    factor 2 of the true 0.0025 (measured 0.0017-0.0032), their mean within 20% (measured ~0.00245)."""
    E = 4
    kalman = KalmanIntegrator(E, obs_std=0.05)
    _synthetic(kalman, E, 0.05, 0.05)
    q = kalman.q()
    assert ((q > 0.0025 / 2) & (q < 0.0025 * 2)).all(), q
    assert abs(q.mean().item() / 0.0025 - 1) < 0.2


def test_q_starts_at_the_initial_value_and_persists_across_episodes():
    E = 2
    f = KalmanIntegrator(E, obs_std=0.5, initial_process_var=0.3)
    assert torch.equal(f.q(), torch.full((E, 4), 0.3))
    x = torch.zeros(E, 6)
    f.reset(ALL(E, bool), x)
    f.update(x, torch.ones(E, 4), torch.zeros(E, 6), np.array([True, False]), ALL(E, bool))
    q = f.q()
    assert q[0, 0] == pytest.approx(1.0 - (0.25 + 0.25))  # nu^2 - (P + R), P = R after the reset
    assert torch.equal(q[1], torch.full((4,), 0.3))  # no innovation seen yet
    f.reset(ALL(E, bool), x)
    assert torch.equal(f.q(), q) and torch.equal(f.variance(), torch.full((E, 6), 0.25))


# -- (e) inactive members ------------------------------------------------------------------------------
@pytest.mark.parametrize("make", [lambda E: PassThrough(E), lambda E: KalmanIntegrator(E, obs_std=0.5)])
def test_inactive_members_are_unchanged(make):
    g = torch.Generator().manual_seed(3)
    E = 6
    f = make(E)
    f.reset(ALL(E, bool), torch.zeros(E, 6))
    for _ in range(5):
        prior, predicted, observed, vision, active = _random_inputs(g, E)
        vision[:] = True
        before = f.state_dict(), f.variance()
        out = f.update(prior, predicted, observed, vision, active)
        after = f.state_dict(), f.variance()
        assert torch.equal(out[~active], prior[~active]) and not torch.equal(out[active], prior[active])
        assert torch.equal(before[1][~active], after[1][~active])
        for key in before[0]:
            assert torch.equal(before[0][key][~active], after[0][key][~active]), key
        if isinstance(f, KalmanIntegrator):
            assert not torch.equal(before[1][active], after[1][active])


# -- (f) state_dict ---------------------------------------------------------------------------------------
def test_state_dict_round_trip_reproduces_the_next_outputs():
    g = torch.Generator().manual_seed(4)
    E = 5
    f = KalmanIntegrator(E, obs_std=0.5)
    x = torch.randn(E, 6, generator=g)
    f.reset(ALL(E, bool), x)
    steps = [_random_inputs(g, E) for _ in range(30)]
    for prior, predicted, observed, vision, active in steps[:20]:
        x = f.update(x, predicted, observed, vision, active)
    buf = io.BytesIO()
    torch.save(f.state_dict(), buf)
    buf.seek(0)
    restored = KalmanIntegrator(E, obs_std=0.5)
    restored.load_state_dict(torch.load(buf, weights_only=True))
    xa, xb = x.clone(), x.clone()
    for prior, predicted, observed, vision, active in steps[20:]:
        xa = f.update(xa, predicted, observed, vision, active)
        xb = restored.update(xb, predicted, observed, vision, active)
        assert torch.equal(xa, xb)
    fresh = KalmanIntegrator(E, obs_std=0.5)
    assert not torch.equal(fresh.q(), f.q())  # the round trip carried something


def test_bad_state_is_refused_naming_the_problem():
    f = KalmanIntegrator(3, obs_std=0.5)
    good = f.state_dict()
    with pytest.raises(ValueError, match=r"'P' must have shape \(3, 6\), got \(2, 6\)"):
        f.load_state_dict({**good, "P": torch.zeros(2, 6)})
    with pytest.raises(ValueError, match="'count' must have shape"):
        f.load_state_dict({**good, "count": [0, 0, 0]})
    with pytest.raises(ValueError, match="needs keys"):
        f.load_state_dict({k: v for k, v in good.items() if k != "P"})
    with pytest.raises(ValueError, match="has no state"):
        PassThrough(3).load_state_dict(good)
    assert torch.equal(f.state_dict()["P"], good["P"])  # a refused load changes nothing


@pytest.mark.parametrize("args, problem", [
    (dict(prior_state=torch.zeros(3, 5)), r"prior_state must be a tensor of shape \(3, 6\)"),
    (dict(predicted_arm=torch.zeros(3, 6)), r"predicted_arm must be a tensor of shape \(3, 4\)"),
    (dict(observed_state=torch.zeros(6)), r"observed_state must be a tensor of shape \(3, 6\)"),
    (dict(vision=np.ones(2, bool)), r"vision must be \[E\] = \(3,\) bools"),
    (dict(active=np.ones(3)), r"active must be \[E\] = \(3,\) bools, got dtype torch.float64"),
])
def test_bad_inputs_are_refused(args, problem):
    kw = dict(prior_state=torch.zeros(3, 6), predicted_arm=torch.zeros(3, 4), observed_state=torch.zeros(3, 6),
              vision=np.ones(3, bool), active=np.ones(3, bool))
    for f in (PassThrough(3), KalmanIntegrator(3, obs_std=0.1)):
        with pytest.raises(ValueError, match=problem):
            f.update(**{**kw, **args})


@pytest.mark.parametrize("kwargs, problem", [(dict(obs_std=-1.0), "obs_std"), (dict(obs_std=float("nan")), "obs_std"),
                                             (dict(obs_std=0.1, window=0), "window"),
                                             (dict(obs_std=0.1, process_var=-1.0), "process_var"),
                                             (dict(obs_std=0.1, process_floor=-1e-3), "process_floor")])
def test_bad_settings_are_refused(kwargs, problem):
    with pytest.raises(ValueError, match=problem):
        KalmanIntegrator(2, **kwargs)


# -- (g) the base class and the registry --------------------------------------------------------------
def test_the_base_class_gives_an_integrator_its_defaults():
    """An integrator implementing only reset and update: nothing kept, learning switchable (``adapt``)."""
    class Hold(Integrator):
        def reset(self, mask, seen_state):
            pass

        def update(self, prior_state, predicted_arm, observed_state, vision, active):
            return prior_state

    f = Hold(2)
    assert f.adapt and f.state_dict() == {} and f.E == 2
    f.load_state_dict({})
    with pytest.raises(ValueError, match=r"Hold has no state; got keys \['P'\]"):
        f.load_state_dict({"P": torch.zeros(2, 6)})
    with pytest.raises(ValueError, match="E must be an int >= 1, got 0"):
        Hold(0)
    assert isinstance(PassThrough(1), Integrator) and not isinstance(KalmanIntegrator(1, 0.0), PassThrough)


def test_the_kalman_table_reaches_the_filter():
    cfg = AgentConfig(integrator="kalman", params={"kalman": {"window": 7, "process_floor": 0.5,
                                                             "initial_process_var": 0.125}})
    f = make_integrator(cfg, 2, obs_std=0.25, device="cpu")
    assert isinstance(f, KalmanIntegrator) and (f.window, f.process_floor, f.initial_process_var, f.R) == (
        7, 0.5, 0.125, 0.0625)
    assert isinstance(make_integrator(AgentConfig(), 2, obs_std=0.25, device="cpu"), PassThrough)
    with pytest.raises(ValueError, match=r"agent.kalman.window must be >= 1, got 0"):
        AgentConfig(params={"kalman": {"window": 0}})
    from apac_mj import kinds

    with pytest.raises(ValueError, match=r"integrator must be one of \('pass_through', 'kalman'\), got 'ukf'"):
        kinds.check(AgentConfig(integrator="ukf"))
