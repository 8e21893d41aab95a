"""The forced-response test (Hardwick et al. 2019): a trained agent on a cued task, its cues remapped, made to
respond at a deadline (the allowed preparation time) with whatever its controllers have ready by then.

A trial shows one cue at ``t = 0``; the arm must launch its movement at the deadline ``T`` (ms, simulated time;
docs/forced_response.md). The two systems prepare in parallel from the cue:

* the habit's proposal (one pass of the actor) is ready at ``H ~ N(habit_latency_ms, latency_sd_ms)``;
* the planner starts at ``S ~ N(planning_latency_ms, latency_sd_ms)`` and finishes an iteration every
  ``inverse_pass_ms`` (the paper's inverse model: one iteration) or ``mpc_iteration_ms`` (the anytime planner
  through the learned model: its best plan after each iteration); at ``T`` it has ``k = floor((T - S) / d)``
  iterations (at most its maximum);
* the arbitrator's inputs are ready ``rule_ms`` after the habit: none for the paper's delta rule (it reads the
  last transition's delta, which the first decision of a trial does not have: the habit acts on the first
  steps, ``habit_first_steps``), one forward-model pass for the delta of the habit's imagined transition
  (the kind's name and ``_imagined``, :mod:`apac_mj.run.variants`), the habit's sequence through the model (``horizon`` passes) for the graded rule.

At the deadline the arm acts by what is ready: the arbitrator's choice where its inputs are ready (a plan only
with at least one finished iteration, cut to the iterations done), else the habit where it is ready, else the
plan where one is ready, else the default: **no movement** (a time-out). The controller chosen at the deadline is
committed to: it drives the whole movement (the episode's steps; the planner with the iterations it had), and the
response is classified by where the hand ends: at the cued target (correct), at the remapped cue's old target (a
habitual error), elsewhere (another error), or where it started (a time-out).

What a trial computes is separated from when it is ready: :func:`candidates` runs the frozen agent once per
cue and repeat (the rule's decision at the first step; the movement of the habit and of the plan at each
iteration count, executed in MuJoCo from the start pose); :func:`simulate` then draws the latencies of many trials per
preparation time and picks each trial's candidate. Same seed, same numbers.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any, Sequence

import numpy as np
import torch

from apac_mj import kinds
from apac_mj.agent.arbitration import DeltaArbitrator
from apac_mj.rules import MPCParams
from apac_mj.run.timing import Timing
from apac_mj.run.variants import IMAGINED
from apac_mj.types import END, TARGET, ArbitrationContext, Arbitrator, Decision, Policy

#: Outcomes of a trial, in the order of the count columns.
OUTCOMES = ("correct", "habitual", "other", "timeout")
#: Which candidate a trial executed (the ``acted`` columns).
ACTORS = ("habit", "planner", "default")
#: The hand moved less than this (cm) from its start: no movement (a time-out).
STILL_CM = 1.0


def variants(cfg_agent: Any) -> tuple[str, ...]:
    """The variants a kind is tested as (:mod:`apac_mj.run.variants`): the kind's own rule, and for the paper's
    delta rule also the delta of the habit's imagined transition (what the rule could read at a trial's first
    decision)."""
    delta_rule = isinstance(kinds.arbitrator_for(cfg_agent), DeltaArbitrator)
    return (cfg_agent.kind, cfg_agent.kind + IMAGINED) if delta_rule else (cfg_agent.kind,)


@dataclasses.dataclass
class Candidates:
    """Every trial candidate's outcome, ``[E, cues, repeats]`` (outcome indices into :data:`OUTCOMES`)."""

    habit: np.ndarray          # the habit's action
    plan: np.ndarray           # [E, cues, repeats, K] the plan after k = 1..K iterations
    default: np.ndarray        # no movement
    rule_habit: np.ndarray     # bool: the rule (with its inputs ready) lets the habit act
    rule_iterations: np.ndarray  # the iterations the rule grants a plan (K: the planner's maximum)
    rule_ms: float             # how long after the habit the rule's inputs are ready
    hand: dict[str, np.ndarray]  # "habit" [E, cues, repeats, 2], "plan" [..., K, 2]: the hand after the movement


def classify(hand: np.ndarray, start: np.ndarray, targets_now: np.ndarray, targets_before: np.ndarray,
             cue: int, radius: float) -> np.ndarray:
    """Outcome indices of hands ``[..., 2]`` (cm) after one movement from ``start``: correct (within ``radius`` of
    the cue's target now, nearest of all targets), habitual (nearest its target before the remap, where that
    differs), other (elsewhere), timeout (moved less than :data:`STILL_CM`)."""
    d = np.linalg.norm(hand[..., None, :] - targets_now, axis=-1)
    nearest, near = d.argmin(-1), d.min(-1) <= radius
    now = np.all(np.isclose(targets_now, targets_now[cue]), axis=-1)
    before = np.all(np.isclose(targets_now, targets_before[cue]), axis=-1)
    out = np.full(hand.shape[:-1], OUTCOMES.index("other"))
    out[near & now[nearest]] = OUTCOMES.index("correct")
    if not np.allclose(targets_now[cue], targets_before[cue]):
        out[near & before[nearest]] = OUTCOMES.index("habitual")
    out[np.linalg.norm(hand - start, axis=-1) < STILL_CM] = OUTCOMES.index("timeout")
    return out


def imagined_delta(agent: Policy, state: torch.Tensor, action: torch.Tensor, zone_radius: float) -> torch.Tensor:
    """``[E]`` the TD error of the habit's imagined transition: the forward model's next arm after ``action``
    from ``state``, rewarded by minus its distance to the target the planner is told, terminal inside the zone."""
    executable = agent.executable(action, state)
    nxt = agent.imagine(state[:, None], executable[:, None])[:, 0]
    distance = torch.linalg.vector_norm(nxt[:, END] - nxt[:, TARGET], dim=1)
    return agent.td_error(state, executable, -distance, nxt, (distance <= zone_radius).float())


def rule_ms(variant: str, cfg_agent: Any, timing: Timing) -> float:
    """How long after the habit's proposal the rule of ``variant`` has its inputs: the imagined transition's
    delta one forward-model pass, a rule reading the habit's probe ``agent.mpc.horizon`` of them; the other
    rules none."""
    if variant != cfg_agent.kind and variant.endswith(IMAGINED):
        return timing.model_pass_ms
    if kinds.arbitrator_for(cfg_agent).needs_habit_probe:
        return timing.model_pass_ms * cfg_agent.params[MPCParams.table].horizon
    return 0.0


def iteration_ms(cfg_agent: Any, timing: Timing) -> float:
    """One planning iteration's duration for the kind's planner."""
    return timing.mpc_iteration_ms if kinds.get(cfg_agent.kind).planner == "mpc" else timing.inverse_pass_ms


class Committed(Arbitrator):
    """The controller a trial committed to at its deadline, for the whole movement: the habit, or the planner
    with ``iterations`` per step."""

    def __init__(self, habit: bool, iterations: int = 1) -> None:
        self.habit, self.iterations = habit, iterations

    def use_habit(self, ctx: ArbitrationContext) -> Decision:
        return Decision(torch.full((ctx.E,), self.habit), {}, torch.full((ctx.E,), self.iterations))


def candidates(loop: Any, cfg: Any, variant: str, repeats: int, timing: Timing) -> Candidates:
    """Run the frozen agent of ``loop`` (an :class:`~apac_mj.run.rollout.EpisodeLoop` on a cued task's
    environments) ``repeats`` times per cue under the remapped mapping: the rule's decision at the trial's first
    step, and the movement each candidate makes when committed to (the habit; the plan with k = 1..K iterations
    per step), executed in MuJoCo to the episode's end; each classified by where the hand ended."""
    env, agent, spec = loop.env, loop.agent, loop.env.spec
    cues, E, K = spec.cues, env.E, loop.planner.max_iterations
    everyone = np.ones(E, dtype=bool)
    now, before = cues.mapping(True), cues.mapping(False)
    radius = _response_radius(now)
    shape = (E, cues.n, repeats)
    out = {"habit": np.zeros(shape, int), "plan": np.zeros((*shape, K), int), "rule_habit": np.zeros(shape, bool),
           "rule_iterations": np.zeros(shape, int), "hand_habit": np.zeros((*shape, 2)),
           "hand_plan": np.zeros((*shape, K, 2))}
    env.set_mapping_override(True)
    try:
        for c in range(cues.n):
            env.set_cue_override(np.full(E, c))
            for r in range(repeats):
                st = loop.begin(everyone)
                start = st.state[:, END].cpu().numpy()
                ctx = st.context(np.full(E, cfg.episodes), agent, loop.zone_radius, loop.planner, habit_action=True)
                out["rule_habit"][:, c, r], out["rule_iterations"][:, c, r] = _rule(loop, ctx, variant, cfg)
                hands = [movement(loop, Committed(True))] + [movement(loop, Committed(False, k)) for k in range(1, K + 1)]
                out["hand_habit"][:, c, r], out["hand_plan"][:, c, r] = hands[0], np.stack(hands[1:], 1)
                out["habit"][:, c, r] = classify(hands[0], start, now, before, c, radius)
                out["plan"][:, c, r] = classify(np.stack(hands[1:], 1), start[:, None], now, before, c, radius)
    finally:
        env.set_cue_override(None)
        env.set_mapping_override(None)
    return Candidates(out["habit"], out["plan"], np.full(shape, OUTCOMES.index("timeout")), out["rule_habit"],
                      out["rule_iterations"], rule_ms(variant, cfg.agent, timing),
                      {"habit": out["hand_habit"], "plan": out["hand_plan"]})


def _rule(loop: Any, ctx: ArbitrationContext, variant: str, cfg: Any) -> tuple[np.ndarray, np.ndarray]:
    """The rule's decision at a trial's first step: ``[E]`` habit, ``[E]`` iterations granted to a plan."""
    K = loop.planner.max_iterations
    if variant != cfg.agent.kind:  # the delta rule on the imagined transition's delta
        delta = imagined_delta(loop.agent, ctx.state, ctx.habit_action, loop.zone_radius).abs().cpu().numpy()
        return delta < cfg.agent.delta_threshold, np.full(ctx.E, K)
    decision = loop.arbitrator.use_habit(ctx)
    habit = torch.as_tensor(decision.habit).cpu().numpy().astype(bool)
    k = np.full(ctx.E, K) if decision.iterations is None else torch.as_tensor(decision.iterations).cpu().numpy()
    return habit, np.clip(k, 1, K)


def movement(loop: Any, committed: Arbitrator, hooks: Sequence[Any] = (), episode: int = 0) -> np.ndarray:
    """``[E, 2]`` where the hand ends (MuJoCo's site) after a frozen episode from the start pose in which every
    step is ``committed``'s controller (the loop's agent, planner and environments; ``hooks`` see it as
    ``episode``)."""
    from apac_mj.run.rollout import EpisodeLoop

    run = EpisodeLoop(loop.agent, committed, loop.env, zone_radius=loop.zone_radius, hooks=hooks, adapt=False,
                      integrator=loop.integrator, planner=loop.planner)
    run.run_episode(np.ones(loop.env.E, dtype=bool), episode=episode)
    return loop.env.true_arm()[:, END].copy()


def _response_radius(targets: np.ndarray) -> float:
    """How near (cm) a hand must come to a target for the response to count as aimed at it: half the smallest
    distance between two targets (so no hand counts for two)."""
    gaps = np.linalg.norm(targets[:, None] - targets[None], axis=-1)
    return float(gaps[np.triu_indices(len(targets), 1)].min() / 2)


def choose(t: float, H: np.ndarray, S: np.ndarray, rule_habit: np.ndarray, rule_iterations: np.ndarray,
           rule_ms: float, uses_habit: bool, uses_planner: bool, iteration: float,
           K: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What acts at deadline ``t`` (ms) in trials whose habit is ready at ``H`` and planner starts at ``S``:
    masks ``plan`` and ``habit`` (neither: the default, no movement) and the plan's iterations ``k``."""
    habit_ready = (H <= t) & uses_habit
    k_ready = np.clip(np.floor((t - S) / iteration), 0, K).astype(int) if uses_planner else np.zeros(H.shape, int)
    rule_ready = habit_ready & (H + rule_ms <= t)
    plan = (k_ready >= 1) & ((rule_ready & ~rule_habit) | ~habit_ready)
    habit = ~plan & habit_ready
    return plan, habit, np.clip(np.minimum(k_ready, rule_iterations), 1, K)


def simulate(c: Candidates, timing: Timing, prep_times_ms: Sequence[float], trials: int, seed: int,
             uses_habit: bool, uses_planner: bool, iteration: float) -> dict[str, np.ndarray]:
    """``trials`` trials per member, cue and preparation time: each draws its latencies and a repeat of the
    candidates, and acts by what is ready at the deadline. Returns counts ``outcomes`` ``[E, cues, T, 4]``
    (:data:`OUTCOMES`) and ``acted`` ``[E, cues, T, 3]`` (:data:`ACTORS`)."""
    T = timing.check_deadlines(prep_times_ms)
    if isinstance(trials, bool) or not isinstance(trials, int) or trials < 1:
        raise ValueError(f"trials must be an integer >= 1, got {trials!r}")
    rng = np.random.default_rng(seed)
    E, n, R = c.habit.shape
    K = c.plan.shape[-1]
    outcomes, acted = np.zeros((E, n, len(T), len(OUTCOMES)), int), np.zeros((E, n, len(T), len(ACTORS)), int)
    for i, t in enumerate(T):
        shape = (E, n, trials)
        H = np.maximum(rng.normal(timing.habit_latency_ms, timing.latency_sd_ms, shape), 0.0)
        S = np.maximum(rng.normal(timing.planning_latency_ms, timing.latency_sd_ms, shape), 0.0)
        r = rng.integers(0, R, shape)
        pick = lambda a: np.take_along_axis(a, r, axis=2)  # noqa: E731
        plan, habit, k = choose(t, H, S, pick(c.rule_habit), pick(c.rule_iterations), c.rule_ms, uses_habit,
                                uses_planner, iteration, K)
        plan_out = np.take_along_axis(np.take_along_axis(c.plan, r[..., None], axis=2), (k - 1)[..., None], 3)[..., 0]
        outcome = np.where(plan, plan_out, np.where(habit, pick(c.habit), OUTCOMES.index("timeout")))
        for j in range(len(OUTCOMES)):
            outcomes[:, :, i, j] = (outcome == j).sum(-1)
        for j, who in enumerate((habit, plan, ~(habit | plan))):
            acted[:, :, i, j] = who.sum(-1)
    return {"outcomes": outcomes, "acted": acted}


#: The columns of a test's table (one row per seed, variant, preparation time and cue).
COLUMNS = ("seed", "variant", "prep_ms", "cue", "remapped", "trials", *OUTCOMES, *(f"{a}_acted" for a in ACTORS))


def test_run(run_dir: Any, prep_times_ms: Sequence[float], timing: Timing = Timing(), trials: int = 100,
             repeats: int = 3, seed: int = 0, device: str | None = None) -> "pd.DataFrame":
    """The forced-response test of a trained run on a cued task (frozen, the remapped mapping): a table of
    outcome counts (:data:`COLUMNS`) for each of the kind's :func:`variants`. Settings are checked before the
    run is loaded."""
    import pandas as pd

    from apac_mj.kinds import arbitrator_for
    from apac_mj.run.build import load_run
    from apac_mj.run.evaluate import eval_env
    from apac_mj.run.rollout import EpisodeLoop
    from apac_mj.suite import spec_for

    T = timing.check_deadlines(prep_times_ms)
    for name, v in (("trials", trials), ("repeats", repeats)):
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
    loaded = load_run(run_dir, device)
    cfg, spec = loaded.cfg, spec_for(loaded.cfg)
    if not spec.cued:
        raise ValueError(f"the forced-response test needs a cued task ([cues] in its file); run {run_dir} trained on "
                         f"{cfg.task!r}, which has none")
    if not spec.cues.swap:
        raise ValueError(f"task {cfg.task!r}: [cues] swap names no cues to remap")
    kind = kinds.get(cfg.agent.kind)
    env = eval_env(cfg, spec, loaded.ckpt.member_lengths(), occluded=False)
    rows = []
    for variant in variants(cfg.agent):
        loop = EpisodeLoop(loaded.agent, arbitrator_for(cfg.agent), env, zone_radius=spec.zone_radius, adapt=False)
        loop.load_state_dict(loaded.ckpt.running_statistics())
        c = candidates(loop, cfg, variant, repeats, timing)
        counts = simulate(c, timing, T, trials, seed, kind.uses_habit, kind.uses_planner,
                          iteration_ms(cfg.agent, timing))
        for k, s in enumerate(cfg.seeds):
            for cue in range(spec.cues.n):
                for i, t in enumerate(T):
                    rows.append({"seed": int(s), "variant": variant, "prep_ms": float(t), "cue": cue,
                                 "remapped": cue in spec.cues.remapped, "trials": trials,
                                 **dict(zip(OUTCOMES, counts["outcomes"][k, cue, i].tolist())),
                                 **dict(zip((f"{a}_acted" for a in ACTORS), counts["acted"][k, cue, i].tolist()))})
    return pd.DataFrame(rows, columns=list(COLUMNS))
