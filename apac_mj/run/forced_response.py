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

import copy
import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Sequence

import numpy as np
import torch

from apac_mj import kinds
from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.rules import MPCParams
from apac_mj.run.build import LoadedRun, episode_loop, load_run
from apac_mj.run.rollout import EpisodeLoop, Hook
from apac_mj.run.run_dir import RunDir, say
from apac_mj.run.timing import ACTORS, COLUMNS, OUTCOMES, TestPlan, Timing
from apac_mj.run.variants import IMAGINED
from apac_mj.suite.task_spec import Cues
from apac_mj.types import END, TARGET, ArbitrationContext, Arbitrator, Decision, WorldModel

if TYPE_CHECKING:
    import pandas as pd

#: The hand moved less than this (cm) from its start: no movement (a time-out).
STILL_CM = 1.0


def variants(cfg_agent: AgentConfig, arbitrator: Arbitrator | None = None) -> tuple[str, ...]:
    """The variants a kind is tested as (:mod:`apac_mj.run.variants`): the kind's own rule, and for a rule that
    reads the last transition's delta (:attr:`Arbitrator.reads_last_delta`: the paper's delta rule) also the delta
    of the habit's imagined transition (what the rule could read at a trial's first decision). ``arbitrator``:
    the kind's, if built already."""
    arbitrator = kinds.arbitrator_for(cfg_agent) if arbitrator is None else arbitrator
    return (cfg_agent.kind, cfg_agent.kind + IMAGINED) if arbitrator.reads_last_delta else (cfg_agent.kind,)


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


def imagined_delta(agent: WorldModel, state: torch.Tensor, action: torch.Tensor, zone_radius: float) -> torch.Tensor:
    """``[E]`` the TD error of the habit's imagined transition: the forward model's next arm after ``action``
    from ``state``, rewarded by minus its distance to the target the planner is told, terminal inside the zone."""
    executable = agent.executable(action, state)
    nxt = agent.imagine(state[:, None], executable[:, None])[:, 0]
    distance = torch.linalg.vector_norm(nxt[:, END] - nxt[:, TARGET], dim=1)
    return agent.td_error(state, executable, -distance, nxt, (distance <= zone_radius).float())


def rule_ms(variant: str, cfg_agent: AgentConfig, timing: Timing, arbitrator: Arbitrator | None = None) -> float:
    """How long after the habit's proposal the rule of ``variant`` has its inputs: the imagined transition's
    delta one forward-model pass, a rule reading the habit's probe ``agent.mpc.horizon`` of them; the other
    rules none. ``arbitrator``: the kind's, if built already."""
    if variant != cfg_agent.kind and variant.endswith(IMAGINED):
        return timing.model_pass_ms
    arbitrator = kinds.arbitrator_for(cfg_agent) if arbitrator is None else arbitrator
    if arbitrator.needs_habit_probe:
        return timing.model_pass_ms * cfg_agent.params[MPCParams.table].horizon
    return 0.0


def iteration_ms(cfg_agent: AgentConfig, timing: Timing) -> float:
    """One planning iteration's duration for the kind's planner (:meth:`Timing.iteration`)."""
    return timing.iteration(kinds.get(cfg_agent.kind).planner)


def ready_iterations(t: float, S: np.ndarray, iteration: float, K: int, uses_planner: bool) -> np.ndarray:
    """The planning iterations finished by the deadline ``t`` (ms) by planners that started at ``S``, each
    ``iteration`` ms long (at most ``K``; none for a kind without a planner)."""
    if not uses_planner:
        return np.zeros(np.shape(S), int)
    return np.clip(np.floor((t - S) / iteration), 0, K).astype(int)


class Committed(Arbitrator):
    """The controller a trial committed to at its deadline, for the whole movement: the habit, or the planner
    with ``iterations`` per step."""

    def __init__(self, habit: bool, iterations: int = 1) -> None:
        self.habit, self.iterations = habit, iterations

    def use_habit(self, ctx: ArbitrationContext) -> Decision:
        return Decision(torch.full((ctx.E,), self.habit), {}, torch.full((ctx.E,), self.iterations))


def candidates(loop: EpisodeLoop, cfg: TrainConfig, variant: str, repeats: int, timing: Timing) -> Candidates:
    """Run the frozen agent of ``loop`` (:func:`frozen_loop`: a cued task's environments) ``repeats`` times per
    cue under the remapped mapping: the rule's decision at the trial's first step, and the movement each
    candidate makes when committed to (the habit; the plan with k = 1..K iterations per step), executed in MuJoCo
    to the episode's end; each classified by where the hand ended."""
    cues, E, K = loop.env.spec.cues, loop.env.E, loop.planner.max_iterations
    targets = cues.mapping(True), cues.mapping(False)  # now (remapped) and before: fixed for the whole test
    shape = (E, cues.n, repeats)
    out = {"habit": np.zeros(shape, int), "plan": np.zeros((*shape, K), int), "rule_habit": np.zeros(shape, bool),
           "rule_iterations": np.zeros(shape, int), "hand_habit": np.zeros((*shape, 2)),
           "hand_plan": np.zeros((*shape, K, 2))}
    for c in range(cues.n):
        with loop.env.overridden(cue=c, remapped=True):
            for r in range(repeats):
                for name, value in _trial(loop, cfg, variant, c, targets).items():
                    out[name][:, c, r] = value
    return Candidates(out["habit"], out["plan"], np.full(shape, OUTCOMES.index("timeout")), out["rule_habit"],
                      out["rule_iterations"], rule_ms(variant, cfg.agent, timing, loop.arbitrator),
                      {"habit": out["hand_habit"], "plan": out["hand_plan"]})


def _trial(loop: EpisodeLoop, cfg: TrainConfig, variant: str, cue: int,
           targets: tuple[np.ndarray, np.ndarray]) -> dict[str, np.ndarray]:
    """One trial of every member with ``cue`` shown (the overrides set): the rule's decision at its first step,
    each candidate's movement (where the hand ends) and its outcome; ``targets``: the cues' targets now and
    before the remap."""
    E, K = loop.env.E, loop.planner.max_iterations
    (now, before), radius = targets, _response_radius(targets[0])
    st = loop.begin(np.ones(E, dtype=bool))
    start = st.state[:, END].cpu().numpy()
    ctx = st.context(np.full(E, cfg.episodes), loop.agent, loop.zone_radius, loop.planner, habit_action=True)
    rule_habit, rule_iterations = _rule(loop, ctx, variant, cfg)
    hands = [movement(loop, Committed(True))] + [movement(loop, Committed(False, k)) for k in range(1, K + 1)]
    plan_hands = np.stack(hands[1:], 1)
    return {"rule_habit": rule_habit, "rule_iterations": rule_iterations, "hand_habit": hands[0],
            "hand_plan": plan_hands, "habit": classify(hands[0], start, now, before, cue, radius),
            "plan": classify(plan_hands, start[:, None], now, before, cue, radius)}


def _rule(loop: EpisodeLoop, ctx: ArbitrationContext, variant: str, cfg: TrainConfig) -> tuple[np.ndarray, np.ndarray]:
    """The rule's decision at a trial's first step: ``[E]`` habit, ``[E]`` iterations granted to a plan."""
    K = loop.planner.max_iterations
    if variant != cfg.agent.kind:  # the delta rule on the imagined transition's delta
        delta = imagined_delta(loop.agent, ctx.state, ctx.habit_action, loop.zone_radius).abs().cpu().numpy()
        return delta < cfg.agent.delta_threshold, np.full(ctx.E, K)
    decision = loop.arbitrator.use_habit(ctx)
    habit = torch.as_tensor(decision.habit).cpu().numpy().astype(bool)
    k = np.full(ctx.E, K) if decision.iterations is None else torch.as_tensor(decision.iterations).cpu().numpy()
    return habit, np.clip(k, 1, K)


def movement(loop: EpisodeLoop, committed: Arbitrator, hooks: Sequence[Hook] = (), episode: int = 0) -> np.ndarray:
    """``[E, 2]`` where the hand ends (MuJoCo's site) after a frozen episode from the start pose in which every
    step is ``committed``'s controller (the loop's agent, planner and environments; ``hooks`` see it as
    ``episode``)."""
    loop.with_arbitrator(committed, hooks).run_episode(np.ones(loop.env.E, dtype=bool), episode=episode)
    return loop.env.true_arm()[:, END].copy()


def no_movement(loop: EpisodeLoop, hooks: Sequence[Hook] = (), episode: int = 0) -> None:
    """A time-out as ``hooks`` see it (as ``episode``): one step of every member with a zero command."""
    run, everyone = loop.with_arbitrator(Committed(True), hooks), np.ones(loop.env.E, dtype=bool)
    st = run.begin(everyone)
    info = run.act(st, everyone, np.full(loop.env.E, episode, dtype=np.int64), explore=False,
                   override=lambda a, h: (torch.zeros_like(a), h))
    run.advance(st, info, everyone)


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
    k_ready = ready_iterations(t, S, iteration, K, uses_planner)
    rule_ready = habit_ready & (H + rule_ms <= t)
    plan = (k_ready >= 1) & ((rule_ready & ~rule_habit) | ~habit_ready)
    habit = ~plan & habit_ready
    return plan, habit, np.clip(np.minimum(k_ready, rule_iterations), 1, K)


def latencies(timing: Timing, rng: np.random.Generator, shape: tuple[int, ...] = ()) -> tuple[np.ndarray, np.ndarray]:
    """Draws of when the habit is ready (``H``) and the planner starts (``S``), ms, cut at 0."""
    H = np.maximum(rng.normal(timing.habit_latency_ms, timing.latency_sd_ms, shape), 0.0)
    S = np.maximum(rng.normal(timing.planning_latency_ms, timing.latency_sd_ms, shape), 0.0)
    return H, S


def simulate(c: Candidates, timing: Timing, prep_times_ms: Sequence[float], trials: int, seed: int,
             uses_habit: bool, uses_planner: bool, iteration: float) -> dict[str, np.ndarray]:
    """``trials`` trials per member, cue and preparation time (checked by the caller: :class:`TestPlan`): each
    draws its latencies and a repeat of the candidates, and acts by what is ready at the deadline. Returns counts
    ``outcomes`` ``[E, cues, T, 4]`` (:data:`OUTCOMES`) and ``acted`` ``[E, cues, T, 3]`` (:data:`ACTORS`)."""
    T = np.asarray(prep_times_ms, dtype=np.float64).ravel()
    rng = np.random.default_rng(seed)
    E, n, R = c.habit.shape
    K = c.plan.shape[-1]
    outcomes, acted = np.zeros((E, n, len(T), len(OUTCOMES)), int), np.zeros((E, n, len(T), len(ACTORS)), int)
    for i, t in enumerate(T):
        shape = (E, n, trials)
        H, S = latencies(timing, rng, shape)
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


def frozen_loop(run_dir: str | Path, device: str | None = None,
                warn: Callable[[str], None] = say) -> tuple[LoadedRun, EpisodeLoop]:
    """A trained run on a cued task, frozen: its agent with the checkpoint's weights in the test's environments
    (the task read once, E environments, each member at its end-of-training lengths) and the episode loop with
    the kind's arbitrator and planner and the checkpoint's running statistics. A task without remapped cues is
    refused before the networks are loaded. Loaded as the run's one user (its lock: a run being trained is
    refused, naming the training's PID); a run not finished (stopped or killed) is ``warn``-ed about, naming the
    episode its networks are from (:func:`networks_episode`)."""
    from apac_mj.run.evaluate import eval_env
    from apac_mj.suite import spec_for

    run = RunDir(run_dir)
    if (problem := run.problem()) is not None:
        raise FileNotFoundError(problem)
    cfg = run.train_config()
    spec = spec_for(cfg)
    if not spec.cued:
        raise ValueError(f"the forced-response test needs a cued task ([cues] in its file); run {run_dir} trained on "
                         f"{cfg.task!r}, which has none")
    if not spec.cues.swap:
        raise ValueError(f"task {cfg.task!r}: [cues] swap names no cues to remap")
    env = eval_env(cfg, spec, None, occluded=False)
    with run.lock():  # not while it trains: a training holds the lock (refused, naming its PID)
        loaded = load_run(run_dir, device, env=env, spec=spec)
        finished = run.finished()
    if not finished:
        warn(f"warning: {run_dir} is not finished (no DONE: training was stopped or killed); its newest checkpoint's "
             f"networks are from episode {networks_episode(loaded)} of {cfg.episodes} (the table's episode column). "
             "Run the same apac-mj train command again to finish it")
    env.set_link_lengths(loaded.ckpt.member_lengths())
    loop = episode_loop(loaded.agent, env, zone_radius=spec.zone_radius, adapt=False)
    loop.load_state_dict(loaded.ckpt.running_statistics())
    return loaded, loop


def member_episodes(loaded: LoadedRun) -> list[int]:
    """How many training episodes each member's loaded networks had (babbling not counted)."""
    return [max(0, loaded.ckpt.member_episode(k)) for k in range(len(loaded.cfg.seeds))]


def networks_episode(loaded: LoadedRun) -> int:
    """How many training episodes the loaded networks had: the slowest member's (:func:`member_episodes`)."""
    return min(member_episodes(loaded))


def test_run(run_dir: str | Path, prep_times_ms: Sequence[float], timing: Timing = Timing(), trials: int = 100,
             repeats: int = 3, seed: int = 0, device: str | None = None,
             expect_episodes: int | None = None) -> pd.DataFrame:
    """The forced-response test of a trained run on a cued task (frozen, the remapped mapping): a table of
    outcome counts (:data:`COLUMNS`; ``episode``: each seed's networks' training episodes) for each of the kind's
    :func:`variants`. Settings are checked before the run is loaded. ``expect_episodes``: the networks must be
    from that episode (a study's practice length), else a RuntimeError (nothing written)."""
    plan = TestPlan(tuple(float(t) for t in np.asarray(prep_times_ms, dtype=float).ravel()), trials, repeats,
                    seed, timing)
    loaded, loop = frozen_loop(run_dir, device)
    episode = networks_episode(loaded)
    if expect_episodes is not None and episode != expect_episodes:
        raise RuntimeError(f"{run_dir}: the networks are from episode {episode}, not {expect_episodes} (another "
                           "process changed the run); nothing was written")
    fresh = copy.deepcopy(loop.state_dict())  # every variant starts from the checkpoint's statistics and plan
    rows: list[dict] = []
    for variant in variants(loaded.cfg.agent, loop.arbitrator):
        loop.load_state_dict(copy.deepcopy(fresh))
        rows += _rows(loaded.cfg, loaded.spec.cues, variant, plan, _counts(loop, loaded.cfg, variant, plan),
                      member_episodes(loaded))
    import pandas as pd

    return pd.DataFrame(rows, columns=list(COLUMNS))


def _counts(loop: EpisodeLoop, cfg: TrainConfig, variant: str, plan: TestPlan) -> dict[str, np.ndarray]:
    """:func:`simulate` over the candidates of ``variant``."""
    kind = kinds.get(cfg.agent.kind)
    c = candidates(loop, cfg, variant, plan.repeats, plan.timing)
    return simulate(c, plan.timing, plan.prep_times_ms, plan.trials, plan.seed, kind.uses_habit, kind.uses_planner,
                    iteration_ms(cfg.agent, plan.timing))


def _rows(cfg: TrainConfig, cues: Cues, variant: str, plan: TestPlan, counts: dict[str, np.ndarray],
          episodes: list[int]) -> list[dict]:
    """The table's rows of one variant (:data:`COLUMNS`), member k's networks from training episode
    ``episodes[k]``."""
    rows = []
    for k, s in enumerate(cfg.seeds):
        for cue in range(cues.n):
            for i, t in enumerate(plan.prep_times_ms):
                rows.append({"seed": int(s), "episode": episodes[k], "variant": variant, "prep_ms": float(t), "cue": cue,
                             "remapped": cue in cues.remapped, "trials": plan.trials,
                             **dict(zip(OUTCOMES, counts["outcomes"][k, cue, i].tolist())),
                             **dict(zip((f"{a}_acted" for a in ACTORS), counts["acted"][k, cue, i].tolist()))})
    return rows
