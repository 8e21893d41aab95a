"""The Kalman integrator's gaps named by mutation testing (docs/mutation.md, issue 41), against answers computed by
hand: the settings' boundaries and types, the default window, a fixed process variance (no innovation statistics),
the zero-variance gain, and the wording that names a bad mask."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from apac_mj.agent.integrator import KalmanIntegrator, PassThrough

ALL = np.ones


@pytest.mark.parametrize("kwargs", [dict(window=1), dict(process_var=0.0), dict(process_floor=0.0),
                                    dict(initial_process_var=0.0), dict(obs_std=0), dict(process_var=2)])
def test_the_lowest_allowed_settings_are_accepted(kwargs):
    f = KalmanIntegrator(2, **{"obs_std": 0.1, **kwargs})
    for key, value in kwargs.items():
        assert getattr(f, key) == value and type(getattr(f, key)) is (int if key == "window" else float)


@pytest.mark.parametrize("kwargs, problem", [
    (dict(obs_std=True), r"^obs_std must be a finite number >= 0.0, got True$"),
    (dict(obs_std="0.1"), r"^obs_std must be a finite number >= 0.0, got '0.1'$"),
    (dict(obs_std=float("inf")), r"^obs_std must be a finite number >= 0.0, got inf$"),
    (dict(obs_std=0.1, initial_process_var=-0.5), r"^initial_process_var must be a finite number >= 0.0"),
    (dict(obs_std=0.1, process_floor=float("nan")), r"^process_floor must be a finite number >= 0.0, got nan$"),
    (dict(obs_std=0.1, process_var=float("inf")), r"^process_var must be None \(adaptive\) or a finite number"),
    (dict(obs_std=0.1, window=2.0), r"^window must be an int >= 1, got 2.0$"),
    (dict(obs_std=0.1, window=True), r"^window must be an int >= 1, got True$"),
    (dict(obs_std=0.1, window=-3), r"^window must be an int >= 1, got -3$"),
])
def test_each_bad_setting_is_refused_by_name(kwargs, problem):
    with pytest.raises(ValueError, match=problem):
        KalmanIntegrator(2, **kwargs)


def _seen_step(f: KalmanIntegrator, innovation: float) -> None:
    """One seen step of member 0 whose arm innovation is ``innovation`` on every coordinate."""
    E = f.E
    f.update(torch.zeros(E, 6), torch.zeros(E, 4), torch.full((E, 6), innovation), ALL(E, bool), ALL(E, bool))


def test_the_default_window_is_200_innovations():
    """A plain mean for the first 200 innovations, then a running mean of rate 1/200: after 200 innovations of
    0 the 201st, of 2, moves the average of nu^2 from 0 to 4/200 (window 199 would give 4/199)."""
    f = KalmanIntegrator(1, obs_std=0.0, process_floor=0.0)
    assert f.window == 200
    for _ in range(200):
        _seen_step(f, 0.0)
    _seen_step(f, 2.0)
    assert f.ema_innovation_sq[0].tolist() == pytest.approx([4.0 / 200] * 4)
    assert f.count.tolist() == [201]


def test_a_fixed_process_variance_learns_no_innovation_statistics():
    """``process_var`` given: ``q`` is it, the averages and counts stay at zero, and ``P- = P + q``."""
    f = KalmanIntegrator(2, obs_std=0.5, process_var=0.75)
    f.reset(ALL(2, bool), torch.zeros(2, 6))
    for _ in range(3):
        _seen_step(f, 1.0)
    assert f.count.tolist() == [0, 0]
    assert torch.equal(f.ema_innovation_sq, torch.zeros(2, 4)) and torch.equal(f.ema_prior_var, torch.zeros(2, 4))
    assert torch.equal(f.q(), torch.full((2, 4), 0.75))


def test_a_zero_variance_prediction_under_noiseless_vision_takes_the_observation():
    """``R = 0`` and ``q = 0``: ``P- + R == 0``, so ``K = 1``: the estimate is the observation and ``P`` stays 0."""
    f = KalmanIntegrator(1, obs_std=0.0, process_var=0.0)
    f.reset(ALL(1, bool), torch.zeros(1, 6))
    obs = torch.tensor([[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]])
    x = f.update(torch.zeros(1, 6), torch.full((1, 4), 9.0), obs, ALL(1, bool), ALL(1, bool))
    assert torch.equal(x, obs) and torch.equal(f.variance(), torch.zeros(1, 6))
    unseen = f.update(x, torch.full((1, 4), 9.0), torch.zeros(1, 6), np.zeros(1, bool), ALL(1, bool))
    assert unseen.tolist() == [[9.0, 9.0, 9.0, 9.0, 5.0, 6.0]]


@pytest.mark.parametrize("make", [lambda: PassThrough(3), lambda: KalmanIntegrator(3, obs_std=0.1)])
def test_a_bad_reset_mask_is_refused_naming_the_mask(make):
    with pytest.raises(ValueError, match=r"^mask must be \[E\] = \(3,\) bools, got dtype torch.int64 and shape "
                                         r"\(3,\)$"):
        make().reset(np.ones(3, int), torch.zeros(3, 6))
    with pytest.raises(ValueError, match=r"^seen_state must be a tensor of shape \(3, 6\), got list$"):
        make().reset(ALL(3, bool), [0.0] * 6)


def test_a_bad_state_entry_is_refused_naming_it_and_its_type():
    f = KalmanIntegrator(2, obs_std=0.5)
    with pytest.raises(ValueError, match=r"^KalmanIntegrator state 'count' must have shape \(2,\), got list$"):
        f.load_state_dict({**f.state_dict(), "count": [0, 0]})
    loaded = {**f.state_dict(), "count": torch.tensor([3.0, 4.0])}
    f.load_state_dict(loaded)
    assert f.count.dtype == torch.int64 and f.count.tolist() == [3, 4]


def test_integrate_refuses_inputs_that_are_not_e_by_4_naming_the_shapes():
    """Equal shapes are not enough: two ``[4]`` vectors are refused; a vision mask of the wrong length names E."""
    from apac_mj.agent.integrator import integrate

    with pytest.raises(ValueError, match=r"^observed and predicted must both be \[E, 4\], got \(4,\) and \(4,\)$"):
        integrate(torch.zeros(4), torch.zeros(4), torch.ones(1, dtype=torch.bool))
    with pytest.raises(ValueError, match=r"^vision must be \[E\]=3 bools, got \(2,\)$"):
        integrate(torch.zeros(3, 4), torch.zeros(3, 4), torch.ones(2, dtype=torch.bool))


def test_a_bad_tensor_input_is_refused_with_its_shape():
    f = KalmanIntegrator(3, obs_std=0.1)
    with pytest.raises(ValueError, match=r"^prior_state must be a tensor of shape \(3, 6\), got \(3, 5\)$"):
        f.update(torch.zeros(3, 5), torch.zeros(3, 4), torch.zeros(3, 6), ALL(3, bool), ALL(3, bool))
