"""Frozen-network tests of a finished run (the paper's "Results" protocols).

``evaluate(run_dir, protocols)`` loads the run's last checkpoint, freezes the
networks (no noise, no updates) and runs, batched over all members at once:

* ``grid``: the 100 angle-grid targets (:func:`apac_mj.kinematics.angle_grid`
  through the motion function at each member's end-of-training lengths);
  static-target runs: the member's own target, 100 episodes. The task's own
  vision when it is the condition under test ("perfect", "noisy",
  "intermittent"); a task trained "occluded" is tested with perfect vision
  here (occlusion is the next protocol's test).
* ``occluded`` (agent kinds that act in the dark, ``AgentKind.acts_occluded``: SPAC and
  APAC; not applicable to DDPG): the same targets with
  the target and arm seen at step 0 only (without noise, whatever the task's
  vision). The arm moves on the forward model's chained estimate and stops when that estimate is inside the target
  zone (or after the episode's 30 steps); the real final distance is recorded.
  The environment's own reach test is disabled (zone radius ~0) so that its
  termination cannot tell the agent anything true.
* ``generalization``: the grid targets inside the task's test region
  (``y >= region.test_y_min``), with the vision of ``grid``.

Arbitration is the trained one after the planning phase (APAC: the actor on
the first two steps, then ``|delta| < 1``). Lengths are frozen at their
end-of-training values during the tests. Time cost: a planning action costs
3, a habitual one 1; beside it each episode's measured decision time where the habit and where the
planner acted (s) and its planning iterations (the trailing columns :data:`MEASURED_COLUMNS`, as in the
training's metrics). Writes ``eval/<protocol>.parquet`` (one row per seed and target) and
``eval/summary.json``; returns the summary.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

from apac_mj.agent.agent import Agent
from apac_mj.config import TrainConfig
from apac_mj.kinematics import angle_grid, motion_function
from apac_mj.kinds import get as get_kind
from apac_mj.run.build import environments, episode_loop, load_run
from apac_mj.run.rollout import EpisodeLoop, EpisodeState, Hook, OnEpisodeStart, OnStep, as_hooks
from apac_mj.run.run_dir import TIMING_COLUMNS, RunDir
from apac_mj.suite import spec_for
from apac_mj.suite.task_spec import TaskSpec
from apac_mj.suite.vec_env import VecEnv
from apac_mj.types import HABIT_COST, PLANNING_COST
from apac_mj.util.threads import torch_threads
from apac_mj.util.progress import progress_iter

PROTOCOLS = ("grid", "occluded", "generalization")
#: Environment zone radius in the occluded protocol: its reach test never fires.
_NO_REACH_RADIUS = 1e-9
COLUMNS = ("seed", "target_index", "target_x", "target_y", "success", "steps", "final_distance", "habit_actions",
           "planning_actions", "time_cost", "judged_reached", "estimate_error")
#: The measured columns after them (and after ``path_x``, ``path_y`` where the protocol keeps the paths): the
#: episode's decision wall time where the habit acted and where the planner acted (s), and its planning
#: iterations (:data:`apac_mj.run.run_dir.TIMING_COLUMNS`). The seconds differ from run to run; the iterations do not.
MEASURED_COLUMNS = TIMING_COLUMNS


def evaluate(run_dir: str | Path, protocols: Sequence[str] = ("grid", "occluded"), region: str | None = None,
             device: str | None = None, progress: bool = False, on_step: OnStep | None = None,
             on_episode_start: OnEpisodeStart | None = None, limit: int | None = None,
             hooks: Sequence[Hook] = (), threads: int | None = None) -> dict[str, Any]:
    """Run the frozen-network ``protocols``; write eval/*.parquet and eval/summary.json; return the summary.

    ``region`` ("test" or "train") restricts the targets of every protocol to
    that part of the task's region split (``generalization`` implies "test").
    ``limit`` keeps only the first ``limit`` targets per member (quick checks).
    ``hooks`` (then the plain ``on_step`` and ``on_episode_start`` functions) see every frozen episode.
    ``threads``: torch CPU threads while it runs (None: 1, as ``apac-mj evaluate``; :mod:`apac_mj.util.threads`
    says why), the caller's count restored after. ``progress``: one bar per protocol, labelled with its name.
    """
    unknown = [p for p in protocols if p not in PROTOCOLS]
    if unknown or not protocols:
        raise ValueError(f"unknown protocol(s) {unknown}; choose from {PROTOCOLS}")
    if limit is not None and limit < 1:
        raise ValueError(f"limit must be >= 1, got {limit}")
    if region not in (None, "test", "train"):
        raise ValueError(f"region must be 'test' or 'train', got {region!r}")
    run = RunDir(run_dir)
    if (problem := run.problem()) is not None:
        raise FileNotFoundError(problem)
    with torch_threads(threads), run.lock():  # the run's one writer while it is tested (a training is refused)
        return _evaluate(run, protocols, region, device, progress, as_hooks(hooks, on_step, on_episode_start), limit)


def _evaluate(run: RunDir, protocols: Sequence[str], region: str | None, device: str | None, progress: bool,
              hooks: Sequence[Hook], limit: int | None) -> dict[str, Any]:
    """:func:`evaluate` as the run's one writer."""
    cfg = run.train_config()
    spec = spec_for(cfg)  # the task, read once for every protocol
    if spec.cued:
        raise ValueError(f"task {cfg.task!r} is a cued task: its targets are its cues', not the angle grid's; test it "
                         f"with apac-mj forced-response test {run.path} --out FILE.parquet (docs/forced_response.md)")
    kind = get_kind(cfg.agent.kind)
    tested = [p for p in protocols if p != "occluded" or kind.acts_occluded]
    first = None if not tested else eval_env(cfg, spec, None, tested[0] == "occluded")
    loaded = load_run(run.path, device, env=first, spec=spec)
    agent, ckpt = loaded.agent, loaded.ckpt
    lengths, own = ckpt.member_lengths(), ckpt.member_targets()
    try:
        summary = run.eval_summary()
    except ValueError:  # a damaged eval/summary.json: written anew
        summary = {}
    summary.update(run_dir=str(run.path), agent=cfg.agent.kind, task=cfg.task, seeds=list(cfg.seeds),
                   finished=run.is_final(ckpt),  # not networks read from previous.pt past a damaged latest.pt
                   network_episodes=[ckpt.member_episode(k) for k in range(len(cfg.seeds))])
    for protocol in protocols:
        if protocol not in tested:
            reason = kind.occluded_reason or f"{kind.label} does not act without vision"
            summary.setdefault("protocols", {})[protocol] = {"applicable": False, "reason": reason}
            continue
        reg = "test" if protocol == "generalization" else region
        targets = evaluation_targets(spec, lengths, own, grid_only=protocol == "generalization", region=reg)
        targets = [t[:limit] for t in targets] if limit is not None else targets
        env = loaded.env if protocol == tested[0] else eval_env(cfg, spec, None, protocol == "occluded")
        rows = run_protocol(cfg, agent, spec, lengths, targets, occluded=protocol == "occluded",
                            progress=progress, label=f"evaluate {protocol}", hooks=hooks,
                            running=ckpt.running_statistics(), env=env)
        df = pd.DataFrame(rows)
        if protocol == "occluded":
            df = df.drop(columns=["path_x", "path_y"])
        run.write_eval(protocol, df)
        summary.setdefault("protocols", {})[protocol] = summarize(df, spec.zone_radius)
    run.write_eval_summary(summary)
    return summary


def evaluation_targets(spec: TaskSpec, lengths: np.ndarray, own: list[Any], grid_only: bool = False,
                 region: str | None = None) -> list[np.ndarray]:
    """Per member ``[n_k, 2]`` targets: the angle grid at its lengths (or its own static target x100).

    Grid targets off the plane are dropped; ``region`` keeps only the "test"
    (``y >= test_y_min``) or "train" part.
    """
    out = []
    for k, (l1, l2) in enumerate(lengths):
        if spec.target_mode == "static" and not grid_only:
            if own[k] is None:
                raise ValueError(f"member {k} has no static target in the checkpoint")
            t = np.repeat(np.asarray(own[k], dtype=np.float64)[None], 100, axis=0)
        else:
            g = angle_grid()
            t, _ = motion_function(g[:, 0], g[:, 1], l1, l2, spec.origin)
            w, h = spec.plane_size
            t = t[(t[:, 0] >= 0) & (t[:, 0] <= w) & (t[:, 1] >= 0) & (t[:, 1] <= h)]
        if region is not None:
            in_test = spec.region.contains_test(t)
            t = t[in_test if region == "test" else ~in_test]
        out.append(t)
    return out


#: The vision parameters of a condition without noise or dropped frames (perfect, occluded).
_CLEAN_VISION = {"vision_noise_std": 0.0, "vision_seen_probability": 1.0}


def eval_env(cfg: TrainConfig, spec: TaskSpec, lengths: np.ndarray | None, occluded: bool) -> VecEnv:
    """The environments of a frozen test: the run's task with its vision for the protocol, no change of the
    kinematics; the members' link lengths set to ``lengths`` (None: set later, by :func:`run_protocol`)."""
    overrides: dict[str, Any] = {"growth_start_episode": 2**31 - 1}
    if occluded:
        overrides.update(vision="occluded", zone_radius=_NO_REACH_RADIUS, **_CLEAN_VISION)
    elif spec.vision == "occluded":
        overrides.update(vision="perfect", **_CLEAN_VISION)
    if spec.kinematics_mode == "static":
        overrides["kinematics_mode"] = "changing"  # keep the lengths set below across resets
    env = environments(cfg, spec.replace(**overrides), training=False)
    if lengths is not None:
        env.set_link_lengths(lengths)
    return env


def run_protocol(cfg: TrainConfig, agent: Agent, spec: TaskSpec, lengths: np.ndarray, targets: list[np.ndarray],
                 occluded: bool, progress: bool = False, hooks: Sequence[Hook] = (),
                 running: dict[str, Any] | None = None, env: VecEnv | None = None,
                 label: str = "evaluate") -> list[dict[str, Any]]:
    """Episode ``i`` of every member goes to its ``targets[k][i]``; all members side by side.

    The arbitrator and the integrator start from ``running`` (the checkpoint's running statistics,
    :meth:`apac_mj.run.run_dir.RunCheckpoint.running_statistics`) and keep them frozen, like the networks.
    ``env``: the protocol's environments (default: built here); their link lengths are set to ``lengths``.
    ``label``: the progress bar's (:func:`evaluate`: "evaluate <protocol>")."""
    env = eval_env(cfg, spec, None, occluded) if env is None else env
    env.set_link_lengths(lengths)
    episodes = episode_loop(agent, env, zone_radius=spec.zone_radius, hooks=hooks, adapt=False)
    episodes.load_state_dict(running or {})
    counts = np.array([len(t) for t in targets])
    rows = []
    n = int(counts.max(initial=0))
    for i in progress_iter(range(n), n, label, "target", enabled=progress):  # plain lines off a terminal
        members = counts > i
        padded = np.stack([t[i] if len(t) > i else np.zeros(2) for t in targets])
        env.set_target_override(padded, members)
        rows += _episode(cfg, episodes, spec, members, i, occluded)
    return rows


def _episode(cfg: TrainConfig, episodes: EpisodeLoop, spec: TaskSpec, members: np.ndarray, index: int,
             occluded: bool) -> list[dict[str, Any]]:
    """One frozen episode for ``members`` (arbitrated as after the planning phase); their result rows."""
    env = episodes.env
    st = episodes.begin(members)
    path = [[env.true_arm()[k, :2].copy()] for k in range(env.E)]
    judged = np.zeros(env.E, dtype=bool)
    for info, stepped in episodes.steps(st, members, index, arbitration_episode=cfg.agent.planning_episodes,
                                        stop_on_terminal=occluded):
        for k in np.flatnonzero(stepped):
            path[k].append(info.true_arm[k, :2].copy())
        judged |= stepped & info.terminal & (info.done | occluded)
    return [_row(env, k, index, st, path, spec.zone_radius, bool(judged[k]), spec.stop_speed)
            for k in np.flatnonzero(members)]


def _row(env: VecEnv, k: int, index: int, st: EpisodeState, path: list[list[np.ndarray]], zone_radius: float,
         judged: bool, stop_speed: float | None = None) -> dict[str, Any]:
    """One result row; ``success``: the hand ended where the task counts the target reached (inside the zone and,
    on a stop task, stopped: a hand still moving through the zone at the time limit is a failure);
    ``judged_reached``: the episode ended because the agent judged the target reached (with vision: it was;
    occluded: the forward model's estimate was inside the zone)."""
    target, distance, p, measures = env.targets()[k], float(env.distances()[k]), np.array(path[k]), st.summary(k)
    row = {"seed": env.seeds[k], "target_index": index, "target_x": float(target[0]), "target_y": float(target[1]),
           "success": reached(env, k, distance, zone_radius, stop_speed), "final_distance": distance,
           "judged_reached": judged,
           "time_cost": time_cost(measures["habit_actions"], measures["planning_actions"]),
           "path_x": p[:, 0].tolist(), "path_y": p[:, 1].tolist(), **measures}
    order = [*COLUMNS, "path_x", "path_y", *MEASURED_COLUMNS]
    return {**{c: row[c] for c in order}, **{c: v for c, v in row.items() if c not in order}}


def reached(env: VecEnv, k: int, distance: float, zone_radius: float, stop_speed: float | None) -> bool:
    """Member ``k`` ended where its task counts the target reached: within ``zone_radius`` of it, on a stop
    task (``stop_speed`` deg/s) with every joint at most that fast, and where the world does not wait
    (``[deliberation]``) by the deadline. The task's own zone is not read: the occluded protocol runs the
    environment with an unreachable one."""
    return bool(distance <= zone_radius and (stop_speed is None or env.stopped(stop_speed)[k])
                and env.in_time()[k])


def time_cost(habit_actions: int, planning_actions: int) -> int:
    """The paper's time cost: a planning action costs 3, a habitual one 1."""
    return HABIT_COST * habit_actions + PLANNING_COST * planning_actions


def summarize(df: pd.DataFrame, zone_radius: float) -> dict[str, Any]:
    """Success rate, mean steps to reach (successes), time cost, distances, the measured decision time per
    episode (ms, habit + planning; rows with the measured columns); overall and per seed."""
    if df.empty:
        return {"applicable": True, "episodes": 0}
    reached = df[df.success]
    per_seed = df.groupby("seed").success.mean()
    return {"applicable": True, "episodes": int(len(df)), "success_rate": float(df.success.mean()),
            "mean_steps_to_reach": float(reached.steps.mean()) if len(reached) else None,
            "mean_steps": float(df.steps.mean()), "mean_time_cost": float(df.time_cost.mean()),
            "mean_time_cost_to_reach": float(reached.time_cost.mean()) if len(reached) else None,
            "habit_share": float(df.habit_actions.sum() / max(1, (df.habit_actions + df.planning_actions).sum())),
            "final_distance_mean": float(df.final_distance.mean()),
            "final_distance_min": float(df.final_distance.min()),
            "final_distance_max": float(df.final_distance.max()), "zone_radius": zone_radius,
            **({"estimate_error_mean": float(df.estimate_error.mean())} if "estimate_error" in df else {}),
            **_judged_summary(df),
            "success_rate_per_seed": {str(int(s)): float(v) for s, v in per_seed.items()},
            "targets_per_seed": {str(int(s)): int(v) for s, v in df.groupby("seed").size().items()},
            **_decision_summary(df)}


def _judged_summary(df: pd.DataFrame) -> dict[str, Any]:
    """Share of episodes the agent ended judging the target reached, and their real final distance."""
    if "judged_reached" not in df:
        return {}
    judged = df[df.judged_reached]
    return {"judged_reached_rate": float(df.judged_reached.mean()),
            "final_distance_judged_mean": float(judged.final_distance.mean()) if len(judged) else None}


def _decision_summary(df: pd.DataFrame) -> dict[str, Any]:
    """The mean measured decision time per episode (ms; where the habit and where the planner acted
    together); nothing for rows without the measured columns."""
    if not all(c in df for c in MEASURED_COLUMNS):
        return {}
    return {"mean_decision_ms": float(1e3 * (df.habit_seconds + df.planning_seconds).mean())}
