"""The forced-response test (Hardwick et al. 2019): a trained agent on a cued task, its cues remapped, made to
respond at a deadline (the allowed preparation time) with whatever its controllers have ready by then.

A trial shows one cue at ``t = 0``; the arm must launch its movement at the deadline ``T`` (ms, simulated time;
docs/forced_response.md). When each computation is ready follows from what it computes (:mod:`apac_mj.run.timing`:
network passes at measured prices after the cue's perception; :class:`Schedule`):

* the habit's proposal (one actor pass) is ready at ``H = perception + actor pass + e_h``;
* the arbitrator's inputs ``rule_ms`` after the habit: none for the paper's delta rule (it reads the last
  transition's delta, which the first decision of a trial does not have: the habit acts on the first steps,
  ``habit_first_steps``), :data:`~apac_mj.run.timing.IMAGINED_DELTA`'s passes for the delta of the habit's
  imagined transition, the rest of the habit's rollout (the probe) for the graded rule;
* a plan of ``k`` iterations: the MPC planner's after the habit (its pool holds the habit's sequence: the
  rollout the probe is, then ``k`` iterations of ``candidates`` sequences); the paper's inverse model ``k``
  passes after ``S = perception + e_s``. ``e_h``, ``e_s`` ~ N(0, ``latency_sd_ms``), drawn per trial.

At the deadline the arm acts by what is ready: the arbitrator's choice where its inputs are ready (a plan only
with at least one finished iteration, cut to the iterations done), else the habit where it is ready, else the
plan where one is ready, else the default: **a guess**, a uniformly drawn one of the cued targets (as people
are forced to; ``TestPlan.default = "still"``: no movement, a time-out). The controller chosen at the deadline is
committed to: it drives the whole movement (the episode's steps; the planner with the iterations it had), and the
response is classified by where the hand ends: at the cued target (correct), at the remapped cue's old target (a
habitual error), elsewhere (another error), or where it started (a time-out). A guess is classified by the target
it aims at.

What a trial computes is separated from when it is ready: :func:`candidates` runs the frozen agent once per
cue and repeat (the rule's decision at the first step; the movement of the habit and of the plan at each
iteration count, executed in MuJoCo from the start pose); :func:`simulate` then draws the latencies (and
guesses) of many trials per preparation time and picks each trial's candidate. Same seed, same numbers.
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
from apac_mj.run.timing import (ACTORS, COLUMNS, HABIT, IMAGINED_DELTA, OUTCOMES, TestPlan, Timing, decision_ms,
                                probe_counts)
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
    hand: dict[str, np.ndarray]  # "habit" [E, cues, repeats, 2], "plan" [..., K, 2]: the hand after the movement
    guess: np.ndarray          # [cues, targets]: the outcome of a guess of each cued target


@dataclasses.dataclass(frozen=True)
class Schedule:
    """When a variant's computations are ready in a trial (ms; :func:`schedule`)."""

    #: Mean time from the cue until the habit's proposal is ready.
    habit_ms: float
    #: Mean time from the cue until a planner that does not wait for the habit starts (the cue's perception).
    start_ms: float
    #: After the habit, when the rule's inputs are ready.
    rule_ms: float
    #: ``[K]``: when a plan of 1..K iterations is done, from the habit (``after_habit``) or from the start.
    plan_ms: np.ndarray
    #: The plan needs the habit's rollout (the MPC planner's pool holds the habit's sequence).
    after_habit: bool
    #: The kind has a habit / a planner.
    uses_habit: bool = True
    uses_planner: bool = True


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


def rule_ms(variant: str, cfg_agent: AgentConfig, timing: Timing, arbitrator: Arbitrator | None = None,
            cues: int = 0) -> float:
    """How long after the habit's proposal the rule of ``variant`` has its inputs (:func:`decision_ms`): the
    imagined transition's delta :data:`IMAGINED_DELTA`'s passes, a rule reading the habit's probe the rest of
    the habit's rollout (:func:`probe_counts` less the habit's pass; ``cues``: with the told value's cue
    search); the other rules none. ``arbitrator``: the kind's, if built already."""
    if variant != cfg_agent.kind and variant.endswith(IMAGINED):
        return decision_ms(IMAGINED_DELTA, timing)
    arbitrator = kinds.arbitrator_for(cfg_agent) if arbitrator is None else arbitrator
    if arbitrator.needs_habit_probe:
        return decision_ms(probe_counts(cfg_agent.params[MPCParams.table].horizon, cues) - HABIT, timing)
    return 0.0


def schedule(variant: str, cfg_agent: AgentConfig, timing: Timing, K: int, arbitrator: Arbitrator | None = None,
             cues: int = 0) -> Schedule:
    """When ``variant``'s habit, rule and plans of 1..``K`` iterations are ready (:class:`Schedule`), from the
    counts of what each computes at ``timing``'s prices. ``arbitrator``: the kind's, if built already; ``cues``:
    the cued task's cues where the MPC planner finds the told target's cue (0: it does not)."""
    kind = kinds.get(cfg_agent.kind)
    mpc = kind.planner == "mpc"
    params = cfg_agent.params.get(MPCParams.table) if mpc else None
    plan_ms, after_habit = timing.plan_ms(kind.planner, params, K, cues if mpc else 0)
    return Schedule(timing.habit_ms(), timing.perception_ms,
                    rule_ms(variant, cfg_agent, timing, arbitrator, cues if mpc else 0), plan_ms, after_habit,
                    kind.uses_habit, kind.uses_planner)


def ready_iterations(t: float, H: np.ndarray, S: np.ndarray, sched: Schedule) -> np.ndarray:
    """The planning iterations finished by the deadline ``t`` (ms) in trials whose habit is ready at ``H`` and
    planner starts at ``S`` (at most ``K``; none for a kind without a planner)."""
    if not sched.uses_planner:
        return np.zeros(np.shape(S), int)
    since = t - (H if sched.after_habit else S)
    return np.searchsorted(sched.plan_ms, since, side="right").astype(int)


class Committed(Arbitrator):
    """The controller a trial committed to at its deadline, for the whole movement: the habit, or the planner
    with ``iterations`` per step."""

    def __init__(self, habit: bool, iterations: int = 1) -> None:
        self.habit, self.iterations = habit, iterations

    def use_habit(self, ctx: ArbitrationContext) -> Decision:
        return Decision(torch.full((ctx.E,), self.habit), {}, torch.full((ctx.E,), self.iterations))


def candidates(loop: EpisodeLoop, cfg: TrainConfig, variant: str, repeats: int) -> Candidates:
    """Run the frozen agent of ``loop`` (:func:`frozen_loop`: a cued task's environments) ``repeats`` times per
    cue under the remapped mapping: the rule's decision at the trial's first step, and the movement each
    candidate makes when committed to (the habit; the plan with k = 1..K iterations per step), executed in MuJoCo
    to the episode's end; each classified by where the hand ended; and a guess's outcome for every cue and target."""
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
                      out["rule_iterations"], {"habit": out["hand_habit"], "plan": out["hand_plan"]},
                      guesses(cues.mapping(True), cues.mapping(False)))


def guesses(targets_now: np.ndarray, targets_before: np.ndarray) -> np.ndarray:
    """``[cues, targets]``: the outcome of guessing each cued target (:data:`OUTCOMES`) for each cue: correct at
    the cue's target now, habitual at a remapped cue's target before, else other."""
    n = len(targets_now)
    out = np.full((n, n), OUTCOMES.index("other"))
    for c in range(n):
        if not np.allclose(targets_now[c], targets_before[c]):
            out[c, np.all(np.isclose(targets_now, targets_before[c]), axis=-1)] = OUTCOMES.index("habitual")
        out[c, np.all(np.isclose(targets_now, targets_now[c]), axis=-1)] = OUTCOMES.index("correct")
    return out


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
           sched: Schedule) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What acts at deadline ``t`` (ms) in trials whose habit is ready at ``H`` and planner starts at ``S``:
    masks ``plan`` and ``habit`` (neither: the default) and the plan's iterations ``k``."""
    K = len(sched.plan_ms)
    habit_ready = (H <= t) & sched.uses_habit
    k_ready = ready_iterations(t, H, S, sched)
    rule_ready = habit_ready & (H + sched.rule_ms <= t)
    plan = (k_ready >= 1) & ((rule_ready & ~rule_habit) | ~habit_ready)
    habit = ~plan & habit_ready
    return plan, habit, np.clip(np.minimum(k_ready, rule_iterations), 1, K)


def latencies(sched: Schedule, sd: float, rng: np.random.Generator,
              shape: tuple[int, ...] = ()) -> tuple[np.ndarray, np.ndarray]:
    """Draws of when the habit is ready (``H``) and a planner that does not wait for it starts (``S``), ms, each
    with its own N(0, ``sd``) noise, cut at 0."""
    H = np.maximum(sched.habit_ms + rng.normal(0.0, sd, shape), 0.0)
    S = np.maximum(sched.start_ms + rng.normal(0.0, sd, shape), 0.0)
    return H, S


def simulate(c: Candidates, sched: Schedule, sd: float, prep_times_ms: Sequence[float], trials: int, seed: int,
             default: str = "guess") -> dict[str, np.ndarray]:
    """``trials`` trials per member, cue and preparation time (checked by the caller: :class:`TestPlan`): each
    draws its latencies, a repeat of the candidates and a guessed target, and acts by what is ready at the
    deadline (neither: the ``default``, "guess" or "still"). Returns counts ``outcomes`` ``[E, cues, T, 4]``
    (:data:`OUTCOMES`), ``acted`` ``[E, cues, T, 3]`` (:data:`ACTORS`) and ``guessed`` ``[E, cues, T]``."""
    T = np.asarray(prep_times_ms, dtype=np.float64).ravel()
    rng = np.random.default_rng(seed)
    E, n, R = c.habit.shape
    outcomes, acted = np.zeros((E, n, len(T), len(OUTCOMES)), int), np.zeros((E, n, len(T), len(ACTORS)), int)
    guessed = np.zeros((E, n, len(T)), int)
    cue = np.arange(n)[None, :, None]
    for i, t in enumerate(T):
        shape = (E, n, trials)
        H, S = latencies(sched, sd, rng, shape)
        r = rng.integers(0, R, shape)
        g = rng.integers(0, c.guess.shape[1], shape)
        pick = lambda a: np.take_along_axis(a, r, axis=2)  # noqa: E731
        plan, habit, k = choose(t, H, S, pick(c.rule_habit), pick(c.rule_iterations), sched)
        plan_out = np.take_along_axis(np.take_along_axis(c.plan, r[..., None], axis=2), (k - 1)[..., None], 3)[..., 0]
        neither = c.guess[cue, g] if default == "guess" else OUTCOMES.index("timeout")
        outcome = np.where(plan, plan_out, np.where(habit, pick(c.habit), neither))
        for j in range(len(OUTCOMES)):
            outcomes[:, :, i, j] = (outcome == j).sum(-1)
        for j, who in enumerate((habit, plan, ~(habit | plan))):
            acted[:, :, i, j] = who.sum(-1)
        guessed[:, :, i] = acted[:, :, i, 2] if default == "guess" else 0
    return {"outcomes": outcomes, "acted": acted, "guessed": guessed}


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
             expect_episodes: int | None = None, default: str = "guess", told: bool = False) -> pd.DataFrame:
    """The forced-response test of a trained run on a cued task (frozen, the remapped mapping): a table of
    outcome counts (:data:`COLUMNS`; ``episode``: each seed's networks' training episodes) for each of the kind's
    :func:`variants`. Settings are checked before the run is loaded. ``expect_episodes``: the networks must be
    from that episode (a study's practice length), else a RuntimeError (nothing written). ``default``: the
    response when nothing is ready (:attr:`TestPlan.default`); ``told``: :attr:`TestPlan.told_value`."""
    plan = TestPlan(tuple(float(t) for t in np.asarray(prep_times_ms, dtype=float).ravel()), trials, repeats,
                    seed, timing, default, told)
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
    told = told_value(loop, plan.told_value)
    c = candidates(loop, cfg, variant, plan.repeats)
    sched = schedule(variant, cfg.agent, plan.timing, loop.planner.max_iterations, loop.arbitrator,
                     loop.env.spec.cues.n if told else 0)
    return simulate(c, sched, plan.timing.latency_sd_ms, plan.prep_times_ms, plan.trials, plan.seed, plan.default)


def told_value(loop: EpisodeLoop, on: bool) -> bool:
    """Set whether the loop's MPC planner closes its horizon with the told target's cue
    (:attr:`MPCPlanner.told_value`); returns whether it does (never for another planner)."""
    from apac_mj.agent.planner import MPCPlanner

    if not isinstance(loop.planner, MPCPlanner):
        return False
    loop.planner.told_value = bool(on)
    return bool(on)


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
                             **dict(zip((f"{a}_acted" for a in ACTORS), counts["acted"][k, cue, i].tolist())),
                             "guessed": int(counts["guessed"][k, cue, i])})
    return rows
