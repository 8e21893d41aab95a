"""The two-state model of motor adaptation (Smith, Ghazizadeh & Shadmehr 2006, PLoS Biol 4:e179), simulated and
fitted.

Two processes learn from the same error: a fast one that learns quickly and forgets quickly and a slow one that
learns slowly and retains well (``A_s > A_f``, ``B_f > B_s``)::

    x_f(n+1) = A_f x_f(n) + B_f e(n)        x_s(n+1) = A_s x_s(n) + B_s e(n)        x(n) = x_f(n) + x_s(n)

with the error ``e(n) = f(n) - x(n)`` on a trial where the field ``f(n)`` acts (``f = 0`` in a null field and
on a catch trial) and ``e(n) = 0`` on a force-channel (error-clamp) trial, where the channel removes the
lateral error. ``x`` is the adaptation in units of the field (1: the field fully compensated), what a channel
trial measures as the adaptation index (lateral force over the force the field would exert).

:func:`fit` finds ``(A_f, B_f, A_s, B_s)`` by constrained least squares on the measured trials (NaN elsewhere)
from several starts; the order constraints are built into the parameters (:func:`_unpack`), so every fit
satisfies them. :func:`fit_seeds` fits each seed and summarizes over seeds with
:func:`apac_mj.report.stats.seed_interval`.
"""
from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Sequence

import numpy as np
import pandas as pd
from scipy.optimize import least_squares

from apac_mj.report.stats import seed_interval

#: The parameters, in the paper's names and order.
PARAMETERS = ("A_f", "B_f", "A_s", "B_s")
#: The values Smith et al. 2006 simulate their paradigm with (their Fig. 2; per trial).
SMITH_2006 = {"A_f": 0.92, "B_f": 0.03, "A_s": 0.996, "B_s": 0.004}
#: Starting points per packed coordinate (:func:`_unpack`: A_f, A_s's share of 1 - A_f, B_s, B_f's share of
#: 1 - B_s; each in [0, 1]); their product is the set of starts.
STARTS = ((0.5, 0.9), (0.5, 0.95), (0.005, 0.05), (0.05, 0.5))


@dataclasses.dataclass(frozen=True)
class TwoState:
    """One learner's parameters (per trial)."""

    A_f: float  #: retention of the fast process
    B_f: float  #: learning rate of the fast process
    A_s: float  #: retention of the slow process (> A_f)
    B_s: float  #: learning rate of the slow process (< B_f)

    def __post_init__(self) -> None:
        for name in PARAMETERS:
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {getattr(self, name)}")

    def as_dict(self) -> dict[str, float]:
        return {name: float(getattr(self, name)) for name in PARAMETERS}


def check_schedule(field: Sequence[float], channel: Sequence[bool]) -> tuple[np.ndarray, np.ndarray]:
    """The field per trial and the channel-trial mask as arrays of one length; else ValueError."""
    f, c = np.asarray(field, dtype=float), np.asarray(channel, dtype=bool)
    if f.ndim != 1 or f.shape != c.shape or f.size == 0:
        raise ValueError(f"field and channel must be 1-D and of one length >= 1, got {f.shape} and {c.shape}")
    if not np.all(np.isfinite(f)):
        raise ValueError("the field per trial must be finite")
    return f, c


#: What each block of a paradigm sets per trial: (field in units of the adaptation field, channel trial).
BLOCKS = {"null": (0.0, False), "field": (1.0, False), "reverse": (-1.0, False), "channel": (0.0, True)}


def paradigm(blocks: Sequence[tuple[str, int]]) -> tuple[np.ndarray, np.ndarray]:
    """The field per trial and the channel mask of a block schedule, e.g. Smith et al.'s
    ``[("null", 50), ("field", 200), ("reverse", 20), ("channel", 100)]``; block names in :data:`BLOCKS`."""
    f, c = [], []
    for name, trials in blocks:
        if name not in BLOCKS or int(trials) < 0:
            raise ValueError(f"a block is (one of {sorted(BLOCKS)}, trials >= 0), got ({name!r}, {trials})")
        f += [BLOCKS[name][0]] * int(trials)
        c += [BLOCKS[name][1]] * int(trials)
    return check_schedule(f, c)


def _states(p: TwoState, f: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fast and slow states before each trial and the error each trial."""
    xf, xs, e = np.zeros(f.size), np.zeros(f.size), np.zeros(f.size)
    for n in range(f.size):
        e[n] = 0.0 if c[n] else f[n] - xf[n] - xs[n]
        if n + 1 < f.size:
            xf[n + 1] = p.A_f * xf[n] + p.B_f * e[n]
            xs[n + 1] = p.A_s * xs[n] + p.B_s * e[n]
    return xf, xs, e


def simulate(params: TwoState, field: Sequence[float], channel: Sequence[bool]) -> pd.DataFrame:
    """The noise-free states before each trial (``x_f``, ``x_s``, ``x``) and the error each trial (``e``)."""
    f, c = check_schedule(field, channel)
    xf, xs, e = _states(params, f, c)
    return pd.DataFrame({"x_f": xf, "x_s": xs, "x": xf + xs, "e": e})


def _unpack(z: np.ndarray) -> TwoState:
    """Packed coordinates in [0, 1]^4 to parameters that satisfy the order constraints by construction:
    ``A_s = A_f + (1 - A_f) z1``, ``B_f = B_s + (1 - B_s) z3``."""
    a_f, u, b_s, v = (float(min(max(t, 0.0), 1.0)) for t in z)
    return TwoState(A_f=a_f, B_f=b_s + (1.0 - b_s) * v, A_s=a_f + (1.0 - a_f) * u, B_s=b_s)


def _residuals(z: np.ndarray, f: np.ndarray, c: np.ndarray, y: np.ndarray, seen: np.ndarray) -> np.ndarray:
    xf, xs, _ = _states(_unpack(z), f, c)
    return (xf + xs)[seen] - y[seen]


@dataclasses.dataclass(frozen=True)
class Fit:
    """A fitted learner: its parameters, the root-mean-square residual and the trials it was fitted on."""

    params: TwoState  #: the best of the starts
    rmse: float  #: root-mean-square residual over the measured trials (units of x)
    trials: int  #: measured trials fitted


def fit(field: Sequence[float], channel: Sequence[bool], measured: Sequence[float],
        starts: Sequence[Sequence[float]] = STARTS) -> Fit:
    """Least-squares fit of the two-state model to ``measured`` (the adaptation per trial, NaN where not
    measured), from every combination of ``starts``; the best fit. At least 4 measured trials are needed."""
    f, c = check_schedule(field, channel)
    y = np.asarray(measured, dtype=float)
    if y.shape != f.shape:
        raise ValueError(f"measured must have one value per trial ({f.size}), got {y.shape}")
    seen = np.isfinite(y)
    if seen.sum() < len(PARAMETERS):
        raise ValueError(f"need at least {len(PARAMETERS)} measured trials to fit, got {int(seen.sum())}")
    best = None
    for z0 in itertools.product(*starts):
        r = least_squares(_residuals, np.asarray(z0, float), bounds=(0.0, 1.0), args=(f, c, y, seen),
                          xtol=1e-12, ftol=1e-12, gtol=1e-12)
        if best is None or r.cost < best.cost:
            best = r
    rmse = math.sqrt(2.0 * best.cost / seen.sum())
    return Fit(_unpack(best.x), rmse, int(seen.sum()))


def fit_seeds(table: pd.DataFrame, value: str = "adaptation") -> pd.DataFrame:
    """Fit each seed of a per-trial table (columns ``seed``, ``trial``, ``field``, ``channel`` and ``value``,
    NaN where not measured); one row per seed with the parameters and ``rmse``."""
    missing = {"seed", "trial", "field", "channel", value} - set(table.columns)
    if missing:
        raise ValueError(f"the per-trial table lacks columns {sorted(missing)}")
    rows = []
    for seed, g in table.sort_values(["seed", "trial"]).groupby("seed"):
        r = fit(g["field"].to_numpy(), g["channel"].to_numpy(bool), g[value].to_numpy(float))
        rows.append({"seed": seed, **r.params.as_dict(), "rmse": r.rmse, "trials": r.trials})
    return pd.DataFrame(rows)


def summarize(per_seed: pd.DataFrame) -> pd.DataFrame:
    """Mean and 95% interval over seeds (:func:`seed_interval`, clipped to [0, 1]) of each parameter."""
    rows = []
    for name in PARAMETERS:
        v = per_seed[name].to_numpy(float)
        lo, hi = seed_interval(v, (0.0, 1.0))
        rows.append({"parameter": name, "mean": float(np.mean(v)), "lo": lo, "hi": hi, "seeds": int(v.size)})
    return pd.DataFrame(rows)


def spontaneous_recovery(x: Sequence[float], channel_block: slice, sign: float = 1.0) -> float:
    """How far the adaptation rebounds in a channel block towards the first field (of sign ``sign``): its largest
    value there minus where it started (or 0, if it started on the other side), never below 0. Smith et al.'s
    signature: after de-adaptation to ~0 the two-state model's x rises again; a one-state learner only decays."""
    v = math.copysign(1.0, sign) * np.asarray(x, float)[channel_block]
    if v.size == 0:
        raise ValueError("the channel block is empty")
    return float(max(np.max(v) - max(v[0], 0.0), 0.0))


def lateral_error(path: np.ndarray, start: Sequence[float], target: Sequence[float]) -> float:
    """The hand's signed largest deviation from the straight line ``start`` -> ``target`` (units of ``path``):
    positive to the right of the movement (clockwise from its direction), where a curl field with b > 0 pushes
    (F = B v, B = [[0, b], [-b, 0]]); ``path`` is [T, 2]."""
    s, t = np.asarray(start, float), np.asarray(target, float)
    u = (t - s) / np.linalg.norm(t - s)
    d = (np.asarray(path, float) - s) @ np.array([u[1], -u[0]])
    return float(d[np.argmax(np.abs(d))])

