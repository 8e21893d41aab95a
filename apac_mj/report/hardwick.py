"""Hardwick, Forrence, Krakauer & Haith (2019)'s model of forced-response choices, ported from the authors' MATLAB.

Source: github.com/adrianhaith/HabitTR, branch ``publication``, commit 0e0b08a4c9cc009c9a5646ffe11731995ec1d2f1
(``Publication/getResponseProbs.m``, ``habit_lik.m``, ``fit_model.m``); the repository carries no licence, so
only the equations are re-implemented here (no code or data is copied). The model: a habitual response A and
a goal-directed response B are each prepared at a normally distributed time, Φ((t − μ_A)/σ_A) and
Φ((t − μ_B)/σ_B), independently. A prepared B lapses with probability ρ (the response is then what it would be
without B: the habit where A is prepared, else a guess); otherwise it replaces A. The response emitted at
preparation time t then depends on what is in force: nothing → a guess (correct and habitual with q_I each,
other 1 − 2q_I); A → A with q_A = 0.95 (fixed by the authors), each other key (1 − q_A)/3; B → correct with
q_B, each other key (1 − q_B)/3. The no-habit model has B alone (μ_B, σ_B, q_B, q_I: 4 parameters; the habit
model 7).
Responses: 1 correct, 2 habitual error, 3 other error (the authors' codes). Fits maximize the log-likelihood minus
the authors' penalty 500·((σ_A − 0.1)² + (σ_B − 0.1)²) within their bounds and μ_A ≤ μ_B; AIC = 2k − 2·LL (LL
without the penalty), as ``fit_model.m``. Deviations (each stated where it is made): scipy's SLSQP from the
authors' start and from :data:`STARTS` more starts (best penalized fit kept) instead of one fmincon run; the
no-habit model optimizes its 4 parameters only (the authors' 3 unused ones do not change the likelihood; their
σ_A's penalty is 0 at its optimum 0.1); probabilities are floored at :data:`P_FLOOR` before the log.
Times are in seconds throughout.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from scipy import optimize
from scipy.special import ndtr

if TYPE_CHECKING:
    import pandas as pd

#: The habit model's parameters (``getResponseProbs.m``'s order): the habit's and the goal-directed response's
#: preparation time (mean, s.d.; s), P(correct | goal-directed prepared), P(each of correct/habitual | nothing
#: prepared), P(a prepared goal-directed response lapses: the habit, or a guess, is emitted instead).
HABIT = ("mu_habit", "sigma_habit", "mu_goal", "sigma_goal", "q_goal", "q_init", "rho")
#: The no-habit model's parameters (the goal-directed process alone).
NO_HABIT = ("mu_goal", "sigma_goal", "q_goal", "q_init")
#: Responses in the order of the authors' codes 1, 2, 3.
RESPONSES = ("correct", "habitual", "other")
#: P(the habitual response | habit prepared, goal-directed not), fixed by the authors.
Q_HABIT = 0.95
#: The authors' penalty on the preparation-time spreads (``habit_lik.m``: lambda, sigma0).
PENALTY_WEIGHT, SIGMA_PRIOR = 500.0, 0.1
#: The authors' start and bounds (``fit_model.m``), habit-model order.
INIT = (0.4, 0.1, 0.6, 0.1, 0.95, 0.2, 1.0)
LOWER = (0.0, 0.01, 0.0, 0.01, 0.5, 1e-4, 1e-4)
UPPER = (0.75, 100.0, 0.75, 100.0, 0.9999, 0.5, 0.9999)
#: Extra starts (habit-model order) beside the authors' one: SLSQP from one start can stop in a local optimum.
STARTS = ((0.3, 0.05, 0.5, 0.1, 0.9, 0.25, 0.1), (0.45, 0.08, 0.55, 0.08, 0.95, 0.25, 0.5),
          (0.25, 0.1, 0.45, 0.1, 0.9, 0.25, 0.05))
#: Smallest probability a log is taken of (a zero would stop the optimizer; the authors' soft bounds avoid it).
P_FLOOR = 1e-300
_NO_HABIT_INDEX = [HABIT.index(n) for n in NO_HABIT]


class FitInputError(ValueError):
    """Times or responses a fit cannot use: the message names the problem; nothing was fitted."""


def names(habit: bool) -> tuple[str, ...]:
    """The parameter names of the habit (True) or the no-habit model."""
    return HABIT if habit else NO_HABIT


def response_probs(t: np.ndarray, params: Sequence[float], habit: bool = True) -> np.ndarray:
    """(3, n) P(correct), P(habitual), P(other) at preparation times ``t`` (s): ``getResponseProbs.m``'s
    ``Alpha * R * PhiAll``, rows 1-3."""
    t = np.asarray(t, dtype=float)
    p = np.asarray(params, dtype=float)
    if habit:
        mu_a, s_a, mu_b, s_b, q_b, q_i, rho = p
        phi_a, phi_b = ndtr((t - mu_a) / s_a), ndtr((t - mu_b) / s_b)
        replace = np.array([[1, 0, rho, 0], [0, 1, 0, rho], [0, 0, 1 - rho, 0], [0, 0, 0, 1 - rho]])
    else:
        mu_b, s_b, q_b, q_i = p
        phi_a = phi_b = ndtr((t - mu_b) / s_b)
        replace = np.array([[1, 1, 0, 0], [0, 0, 0, 0], [0, 0, 1, 1], [0, 0, 0, 0]], dtype=float)
    q_a = Q_HABIT
    alpha = np.array([[q_i, (1 - q_a) / 3, q_b, q_b],
                      [q_i, q_a, (1 - q_b) / 3, (1 - q_b) / 3],
                      [1 - 2 * q_i, 2 * (1 - q_a) / 3, 2 * (1 - q_b) / 3, 2 * (1 - q_b) / 3]])
    events = np.stack([(1 - phi_a) * (1 - phi_b), phi_a * (1 - phi_b), (1 - phi_a) * phi_b, phi_a * phi_b])
    return alpha @ replace @ events


def log_likelihood(t: np.ndarray, counts: np.ndarray, params: Sequence[float], habit: bool = True) -> float:
    """Σ counts · log P(response | t): ``counts`` (n, 3) of correct, habitual, other at each time of ``t`` (one
    trial per row with a single 1 is ``habit_lik.m``'s LL; counts per time are the same sum, multinomial)."""
    p = response_probs(t, params, habit).T
    return float(np.sum(np.asarray(counts, dtype=float) * np.log(np.maximum(p, P_FLOOR))))


def penalty(params: Sequence[float], habit: bool = True) -> float:
    """The authors' penalty on the spreads (``habit_lik.m``); the no-habit model's σ_A sits at its prior (0)."""
    p = np.asarray(params, dtype=float)
    spreads = (p[1], p[3]) if habit else (p[1],)
    return PENALTY_WEIGHT * sum((s - SIGMA_PRIOR) ** 2 for s in spreads)


def trial_counts(response: np.ndarray) -> np.ndarray:
    """(n, 3) one-hot counts of response codes 1, 2, 3 (anything else refused)."""
    r = np.asarray(response).ravel()
    if not np.isin(r, (1, 2, 3)).all():
        raise FitInputError(f"responses must be the codes 1 (correct), 2 (habitual), 3 (other); got "
                            f"{sorted(set(r[~np.isin(r, (1, 2, 3))].tolist()))[:5]}")
    return (r[:, None] == np.arange(1, 4)[None, :]).astype(float)


@dataclasses.dataclass(frozen=True)
class Fit:
    """One model fitted to one participant's (or seed's) data."""

    #: True: the habit model; False: the no-habit model.
    habit: bool
    #: Fitted parameters, in :func:`names` order (times in s).
    params: tuple[float, ...]
    #: Log-likelihood at ``params`` (without the penalty).
    ll: float
    #: Trials (sum of the counts) fitted.
    trials: float

    @property
    def k(self) -> int:
        """Free parameters (AIC's k): 7 habit, 4 no-habit, as ``fit_model.m``."""
        return len(names(self.habit))

    @property
    def aic(self) -> float:
        """2k − 2·LL."""
        return 2 * self.k - 2 * self.ll

    def as_dict(self) -> dict[str, float]:
        """The parameters by name."""
        return dict(zip(names(self.habit), self.params))


def _check(t: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t, counts = np.asarray(t, dtype=float).ravel(), np.asarray(counts, dtype=float)
    if counts.shape != (t.size, 3):
        raise FitInputError(f"counts must be (n, 3) for n = {t.size} times; got shape {counts.shape}")
    if not (np.isfinite(t).all() and np.isfinite(counts).all()) or (counts < 0).any():
        raise FitInputError("times and counts must be finite, counts >= 0")
    if counts.sum() <= 0:
        raise FitInputError("no trials to fit")
    return t, counts


def fit(t: np.ndarray, counts: np.ndarray, habit: bool = True) -> Fit:
    """Maximum penalized likelihood fit (``fit_model.m``): SLSQP within the authors' bounds, μ_A ≤ μ_B, from their
    start and :data:`STARTS`; the best penalized fit is kept. ``t`` (s), ``counts`` (n, 3)."""
    t, counts = _check(t, counts)
    idx = slice(None) if habit else _NO_HABIT_INDEX
    lo, hi = np.asarray(LOWER)[idx], np.asarray(UPPER)[idx]

    def objective(p: np.ndarray) -> float:
        return -log_likelihood(t, counts, p, habit) + penalty(p, habit)

    cons = [{"type": "ineq", "fun": lambda p: p[2] - p[0]}] if habit else []
    best = None
    for start in (INIT, *STARTS):
        x0 = np.clip(np.asarray(start)[idx], lo, hi)
        res = optimize.minimize(objective, x0, method="SLSQP", bounds=list(zip(lo, hi)), constraints=cons,
                                options={"maxiter": 500, "ftol": 1e-10})
        x = np.clip(res.x, lo, hi)
        if habit and x[0] > x[2]:  # SLSQP can end outside μ_A ≤ μ_B: project onto it (both at their mean)
            x[0] = x[2] = (x[0] + x[2]) / 2
        if best is None or objective(x) < objective(best):
            best = x
    assert best is not None
    return Fit(habit, tuple(float(v) for v in best), log_likelihood(t, counts, best, habit), float(counts.sum()))


def fit_both(t: np.ndarray, counts: np.ndarray) -> tuple[Fit, Fit]:
    """The habit and the no-habit model on the same data."""
    return fit(t, counts, True), fit(t, counts, False)


def simulate(t: np.ndarray, params: Sequence[float], habit: bool, rng: np.random.Generator) -> np.ndarray:
    """One response code (1, 2, 3) per time of ``t``, drawn from the model."""
    p = response_probs(t, params, habit)
    u = rng.random(p.shape[1])
    return 1 + (u > p[0]).astype(int) + (u > p[0] + p[1]).astype(int)


def sliding_window(t: np.ndarray, counts: np.ndarray, centres: np.ndarray, width: float,
                   min_trials: int = 4) -> np.ndarray:
    """(3, n_centres) P(correct), P(habitual), P(other) in windows (c − width/2, c + width/2] over the trials at
    times ``t`` with ``counts`` (n, 3); NaN where a window holds fewer than ``min_trials`` trials (the human
    script's rule, from the authors' ``sliding_window.m``: <= 3 trials give NaN)."""
    t, counts = np.asarray(t, dtype=float).ravel(), np.asarray(counts, dtype=float)
    c = np.asarray(centres, dtype=float)[:, None]
    inwin = (t[None, :] > c - width / 2) & (t[None, :] <= c + width / 2)
    n = inwin.astype(float) @ counts.sum(axis=1)
    p = (inwin.astype(float) @ counts).T / np.maximum(n, 1)
    p[:, n < min_trials] = np.nan
    return p


def guesses(counts: np.ndarray, timeouts: np.ndarray, keys: int = 4) -> np.ndarray:
    """``counts`` (n, 3) with each time-out replaced by a guess among ``keys`` responses, as people must respond:
    1/keys correct, 1/keys habitual, the rest other (expected counts; a remapped cue's old target is one key)."""
    if keys < 3:
        raise FitInputError(f"a guess needs at least 3 keys (correct, habitual, other); got {keys}")
    to = np.asarray(timeouts, dtype=float).reshape(-1, 1)
    return np.asarray(counts, dtype=float) + to * np.array([1 / keys, 1 / keys, 1 - 2 / keys])


def delta_aic(habit: Fit, no_habit: Fit) -> float:
    """AIC(no-habit) − AIC(habit): > 0 favours the habit model (``make_plots.m``'s ΔAIC)."""
    return no_habit.aic - habit.aic


def fit_row(t: np.ndarray, counts: np.ndarray) -> dict[str, float]:
    """Both models on one data set, flattened: the habit model's parameters (times in ms), both AICs, ΔAIC and
    whether the habit model wins (ΔAIC > 0)."""
    h, n = fit_both(t, counts)
    row = {k: (v * 1000.0 if k.startswith(("mu", "sigma")) else v) for k, v in h.as_dict().items()}
    row.update({f"nohabit_{k}": (v * 1000.0 if k.startswith(("mu", "sigma")) else v)
                for k, v in n.as_dict().items()})
    d = delta_aic(h, n)
    row.update(trials=h.trials, ll_habit=h.ll, ll_nohabit=n.ll, aic_habit=h.aic, aic_nohabit=n.aic,
               delta_aic=d, habit_wins=float(d > 0))
    return row


def nan_row() -> dict[str, float]:
    """A :func:`fit_row` of NaN (no data)."""
    keys = [*HABIT, *(f"nohabit_{k}" for k in NO_HABIT), "trials", "ll_habit", "ll_nohabit", "aic_habit",
            "aic_nohabit", "delta_aic", "habit_wins"]
    return dict.fromkeys(keys, math.nan)


#: The quantities a summary gives a mean and interval for (habit-model parameters, times in ms; ΔAIC).
SUMMARY = (*HABIT, "delta_aic")
#: Each summary quantity's range (the interval is clipped to it).
RANGES = {"mu_habit": (0.0, 750.0), "mu_goal": (0.0, 750.0), "sigma_habit": (10.0, 1e5), "sigma_goal": (10.0, 1e5),
          "q_goal": (0.5, 1.0), "q_init": (0.0, 0.5), "rho": (0.0, 1.0), "delta_aic": None}


def summarize(fits: "pd.DataFrame", by: Sequence[str]) -> "pd.DataFrame":
    """Per group of ``by`` (e.g. condition; practice and variant): how many fits (``n``), in how many the habit
    model wins by AIC, and the mean of each :data:`SUMMARY` quantity over the group's participants or seeds with
    the report's interval (:func:`apac_mj.report.stats.seed_interval`: Student-t at the 97.5% quantile, clipped
    to the quantity's range; NaN with fewer than 3)."""
    import pandas as pd

    from apac_mj.report.stats import seed_interval

    rows = []
    for key, g in fits.groupby(list(by), sort=True):
        key = key if isinstance(key, tuple) else (key,)
        row = dict(zip(by, key), n=len(g), habit_wins=int(np.nansum(g["habit_wins"])))
        for q in SUMMARY:
            v = g[q].to_numpy(dtype=float)
            lo, hi = seed_interval(v, RANGES[q])
            row[q], row[f"{q}_lo"], row[f"{q}_hi"] = float(np.nanmean(v)) if v.size else math.nan, lo, hi
        rows.append(row)
    return pd.DataFrame(rows)


def bootstrap_fit(t: np.ndarray, counts: np.ndarray, resamples: int = 100, seed: int = 0,
                  level: float = 0.95) -> dict[str, tuple[float, float]]:
    """Percentile interval of each habit-model parameter (times in ms) and of ΔAIC over ``resamples``
    parametric resamples of ``counts`` (n, 3): each time's total redrawn multinomially from its observed
    proportions, both models refitted. Trial-level sampling only: it does not contain seed-to-seed variation."""
    t, counts = _check(t, counts)
    rng = np.random.default_rng(seed)
    n = counts.sum(axis=1)
    p = counts / np.maximum(n, 1e-12)[:, None]
    draws = []
    for _ in range(resamples):
        c = np.stack([rng.multinomial(int(round(k)), pk) if k > 0 else np.zeros(3) for k, pk in zip(n, p)])
        row = fit_row(t, c)
        draws.append([row[q] for q in SUMMARY])
    lo, hi = np.nanquantile(np.asarray(draws), [(1 - level) / 2, (1 + level) / 2], axis=0)
    return {q: (float(a), float(b)) for q, a, b in zip(SUMMARY, lo, hi)}


#: The parameters laid side by side with the humans' (times in ms).
COMPARED = ("mu_habit", "sigma_habit", "mu_goal", "sigma_goal", "rho", "q_goal", "q_init")


def verdict(a: tuple[float, float, float], h: tuple[float, float, float]) -> str:
    """How an agent's (mean, lo, hi) stands to a human group's: ``overlaps`` (the 95% intervals share a point:
    no difference shown), ``below`` / ``above`` (disjoint intervals: a difference), or ``no interval``."""
    if not all(np.isfinite([a[1], a[2], h[1], h[2]])):
        return "no interval"
    if a[2] < h[1]:
        return "below"
    if a[1] > h[2]:
        return "above"
    return "overlaps"


def side_by_side(agents: "pd.DataFrame", humans: "pd.DataFrame", keys: Sequence[str] = ("practice", "variant"),
                 params: Sequence[str] = COMPARED) -> "pd.DataFrame":
    """One row per agent row (``keys``), human group (``condition``) and parameter: both means and intervals
    and the :func:`verdict`. Both tables as :func:`summarize` (or the bootstrap table) write them."""
    import pandas as pd

    rows = []
    for _, a in agents.iterrows():
        for _, h in humans.iterrows():
            for q in params:
                av = (a[q], a.get(f"{q}_lo", math.nan), a.get(f"{q}_hi", math.nan))
                hv = (h[q], h[f"{q}_lo"], h[f"{q}_hi"])
                rows.append({**{k: a[k] for k in keys}, "condition": h["condition"], "parameter": q,
                             "agent": av[0], "agent_lo": av[1], "agent_hi": av[2],
                             "human": hv[0], "human_lo": hv[1], "human_hi": hv[2], "verdict": verdict(av, hv)})
    return pd.DataFrame(rows)
