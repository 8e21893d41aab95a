"""The arbitration under dynamics (issue 17): event numbers, frozen probes and one figure from a ``dynamics`` grid.

    apac-mj grid --preset dynamics --out results/dynamics
    python bench/dynamics.py results/dynamics --out docs/results/dynamics [--history DIR --probe-cache DIR]

Reads every cell's ``metrics.parquet`` (training episodes, one row per seed and episode) and ``eval/grid.parquet``
(test on the 100 angle-grid targets, the plant before any change) that exist, so it also reports a grid that is
still running: cells without metrics are listed as missing, windows not yet trained as incomplete. Any number of
seeds and episodes: the event episodes come from each cell's task (``[plant]``), the episode count from its config.

Per episode the *error* is the mean distance from hand to target over the episode's steps (cm; minus the return
over the steps), the *relative error* that error over the target's distance from the start pose (so near and far
targets weigh alike). Every number is computed per seed first; across seeds the tables give the mean, its 95%
interval (apac_mj.report.stats: a bootstrap over seeds, for rates widened to the pooled count's Wilson interval,
as ``apac-mj report`` does) and the per-seed values.

Windows (training episodes; on/off/change: the task's schedule, N: the episodes trained):

* curl field (on in [on, off)): ``before`` on-10..on-1, ``field early`` on..on+4, ``field late`` off-5..off-1,
  ``after-effect`` off..off+4 (the first 5 episodes after switch-off), ``after late`` N-5..N-1. Per seed:
  immediate cost = field early - before, residual cost = field late - before, after-effect = after-effect - before.
* load change (from episode c): ``before`` c-10..c-1, ``right after`` c..c+4, ``late`` N-10..N-1. The recovery
  episode of a seed is the last episode of the first 5-episode window after the change whose mean error is back
  within that seed's ``before`` mean plus one standard deviation of its ``before`` episodes.
* torque-driven arm (no event): ``late`` N-10..N-1. Every condition: ``last 30`` N-30..N-1.

Frozen probes (``--history``, a folder of per-cell checkpoint copies ``<cell>/*.pt``): every seed of every agent as
it was after 110 (the event), 130 (curl: the field goes off) or 140 (load: 30 episodes with it) and N training episodes, tested on the same 100 grid
targets with the field / load off and on. The seeds train side by side and drift apart by a few episodes, and a
checkpoint is written when the slowest reaches a multiple of checkpoint_every: each seed is probed in the checkpoint
where it had trained the most episodes not past the moment (its episode there is listed as ``seed_episode``).

Writes to ``--out``: ``learning.csv`` (per seed and episode), ``windows.csv`` (per seed and window), ``events.csv``
(per window and quantity: mean, interval, per-seed values), ``effects.csv`` (the differences above, per seed then
summarized), ``recovery.csv``, ``tests.csv``, ``probes.csv`` / ``probe_summary.csv`` / ``probe_effects.csv``
(with --history) and ``fig_dynamics.png``; prints the tables as markdown.
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from apac_mj.report.stats import interval

AGENTS = ("ddpg", "spac", "apac")
CURL = "changing_target_compliant_curl_field"
LOAD = "changing_target_compliant_load_change"
TORQUE = "changing_target_torque"
CONDITIONS = (CURL, LOAD, TORQUE)
TITLES = {CURL: "compliant arm, curl field on (shaded)",
          LOAD: "compliant arm + gravity, 1 kg load from the dashed line",
          TORQUE: "torque-driven arm (no event)"}
COLORS = {"ddpg": "tab:orange", "spac": "tab:green", "apac": "tab:blue"}
#: Per-seed window quantities (column in the training rows -> name in the tables); success is a rate.
QUANTITIES = {"error": "error_cm", "relative_error": "relative_error", "final_distance": "final_distance_cm",
              "success": "success", "habit_share": "habit_share"}
#: Per-seed differences of windows: (name, window, reference window).
EFFECTS = {CURL: (("immediate cost", "field early", "before"), ("residual cost", "field late", "before"),
                  ("after-effect", "after-effect", "before"), ("after late - before", "after late", "before")),
           LOAD: (("right after - before", "right after", "before"), ("late - before", "late", "before"))}
RECOVERY_WINDOW = 5


# -- the schedule and the windows --------------------------------------------------------------------------------
def windows(condition: str, schedule: dict[str, int], episodes: int) -> dict[str, tuple[int, int]]:
    """The named windows (first, last training episode, inclusive) of ``condition`` for a run of ``episodes``
    training episodes; ``schedule``: the plant's ``field_on_episode``, ``field_off_episode``,
    ``load_change_episode`` (-1: none)."""
    n = episodes
    out: dict[str, tuple[int, int]] = {}
    on, off, change = (schedule.get(k, -1) for k in ("field_on_episode", "field_off_episode", "load_change_episode"))
    if on >= 0 and off > on:
        out = {"before": (on - 10, on - 1), "field early": (on, on + 4), "field late": (off - 5, off - 1),
               "after-effect": (off, off + 4), "after late": (n - 5, n - 1)}
    elif change >= 0:
        out = {"before": (change - 10, change - 1), "right after": (change, change + 4), "late": (n - 10, n - 1)}
    else:
        out = {"late": (n - 10, n - 1)}
    return {**out, "last 30": (n - 30, n - 1)}


def cell_schedule(cell: Path) -> tuple[dict[str, int], int]:
    """The cell's plant schedule (training episodes) and its configured episode count."""
    from apac_mj.run.run_dir import RunDir
    from apac_mj.suite import spec_for

    cfg = RunDir(cell).train_config()
    plant = spec_for(cfg).plant
    keys = ("field_on_episode", "field_off_episode", "load_change_episode")
    return {k: int(getattr(plant, k)) for k in keys}, int(cfg.episodes)


# -- reading a grid ----------------------------------------------------------------------------------------------
def derive(d: pd.DataFrame) -> pd.DataFrame:
    """Training rows with ``error`` (cm), ``relative_error`` and ``habit_share`` added."""
    d = d[d.phase == "train"].copy()
    d["error"] = -d["return"] / d["steps"]
    # the start pose (0, 180) puts the hand at origin + (l1 - l2, 0): the initial distance to the target
    start_x, start_y = 15.0 + d.l1 - d.l2, 15.0
    d["relative_error"] = d.error / np.hypot(d.target_x - start_x, d.target_y - start_y)
    acts = d.habit_actions + d.planning_actions
    d["habit_share"] = np.where(acts > 0, d.habit_actions / acts.clip(lower=1), np.nan)
    return d


def cell_dirs(grid: Path) -> dict[tuple[str, str], Path]:
    """Every (agent, condition) cell of the study, whether it exists yet or not."""
    return {(a, c): grid / f"{a}__{c}" for c in CONDITIONS for a in AGENTS}


def load_grid(grid: Path) -> tuple[pd.DataFrame, pd.DataFrame, dict[tuple[str, str], dict[str, Any]]]:
    """Training rows (``agent``, ``condition``, ``seed``, ``episode`` ...), test rows (eval/grid.parquet) and
    per cell its schedule, configured episodes and whether it is done."""
    train, test, info = [], [], {}
    for (agent, cond), cell in cell_dirs(grid).items():
        if not (cell / "metrics.parquet").is_file():
            continue
        schedule, episodes = cell_schedule(cell)
        info[(agent, cond)] = {"schedule": schedule, "episodes": episodes, "done": (cell / "DONE").is_file()}
        d = derive(pd.read_parquet(cell / "metrics.parquet"))
        d["agent"], d["condition"] = agent, cond
        train.append(d)
        if (cell / "eval" / "grid.parquet").is_file():
            t = pd.read_parquet(cell / "eval" / "grid.parquet")
            t["agent"], t["condition"] = agent, cond
            test.append(t)
    cat = lambda fs: pd.concat(fs, ignore_index=True) if fs else pd.DataFrame()  # noqa: E731
    return cat(train), cat(test), info


# -- per seed, then across seeds ---------------------------------------------------------------------------------
def seed_windows(rows: pd.DataFrame, cell_windows: dict[tuple[str, str], dict[str, tuple[int, int]]]) -> pd.DataFrame:
    """One row per agent, condition, window and seed: the window's mean of every quantity (NaN where the seed
    has not trained the window completely), its episode count ``n`` and ``successes``."""
    out = []
    for (agent, cond, seed), d in rows.groupby(["agent", "condition", "seed"]):
        for name, (lo, hi) in cell_windows.get((agent, cond), {}).items():
            w = d[(d.episode >= lo) & (d.episode <= hi)]
            complete = lo >= 0 and len(w) == hi - lo + 1
            row = {"agent": agent, "condition": cond, "window": name, "episodes": f"{lo}-{hi}", "seed": int(seed),
                   "n": len(w), "complete": complete, "successes": int(w.success.sum()) if complete else np.nan}
            row.update({q: (float(w[c].mean()) if complete else np.nan) for c, q in QUANTITIES.items()})
            out.append(row)
    return pd.DataFrame(out)


def summarize(per_seed: pd.DataFrame, keys: list[str], quantities: list[str],
              rates: dict[str, tuple[str, str]] | None = None) -> pd.DataFrame:
    """Across seeds, per ``keys`` group and quantity: the mean, its 95% interval, the seed count and the
    per-seed values. ``rates``: quantity -> (successes column, trials column), for the Wilson widening."""
    rates = rates or {}
    out = []
    for key, d in per_seed.groupby(keys, sort=False):
        d = d.sort_values("seed")
        for q in quantities:
            v = d[q].astype(float)
            ok = ~v.isna()
            if q in rates:
                k, n = rates[q]
                mean, lo, hi = interval(v[ok].tolist(), d[k][ok].astype(float).tolist(),
                                        d[n][ok].astype(float).tolist(), scale=1.0)
            else:
                mean, lo, hi = interval(v[ok].tolist())
            out.append({**dict(zip(keys, key if isinstance(key, tuple) else (key,))), "quantity": q, "mean": mean,
                        "lo": lo, "hi": hi, "seeds": int(ok.sum()),
                        "per_seed": " ".join(f"{s}:{x:.3g}" for s, x in zip(d.seed[ok], v[ok]))})
    return pd.DataFrame(out)


def seed_effects(per_seed: pd.DataFrame) -> pd.DataFrame:
    """Per agent, condition, seed and effect (:data:`EFFECTS`): window minus reference window of every quantity
    (NaN where either window is incomplete for that seed)."""
    out = []
    by = per_seed.set_index(["agent", "condition", "seed", "window"])
    for (agent, cond, seed), _ in per_seed.groupby(["agent", "condition", "seed"]):
        for name, window, ref in EFFECTS.get(cond, ()):
            if (agent, cond, seed, window) not in by.index or (agent, cond, seed, ref) not in by.index:
                continue
            a, b = by.loc[(agent, cond, seed, window)], by.loc[(agent, cond, seed, ref)]
            out.append({"agent": agent, "condition": cond, "effect": name, "seed": int(seed),
                        **{q: float(a[q]) - float(b[q]) for q in QUANTITIES.values()}})
    return pd.DataFrame(out)


def recovery(rows: pd.DataFrame, change: int, window: int = RECOVERY_WINDOW) -> pd.DataFrame:
    """Per agent and seed of the load change: the ``before`` level (mean + 1 sd of episodes change-10..change-1),
    the right-after error (change..change+4) and the recovery episode (the last episode of the first
    ``window``-episode window from the change on whose mean error is within the level; None: not within the
    episodes trained)."""
    out = []
    for (agent, seed), d in rows.groupby(["agent", "seed"]):
        e = d.set_index("episode").sort_index().error
        before = e.loc[change - 10:change - 1]
        if len(before) < 10:
            continue
        level = before.mean() + before.std(ddof=1)
        after = e.loc[change:].rolling(window).mean().dropna()
        back = after[after <= level]
        at = int(back.index[0]) if len(back) else None
        right = e.loc[change:change + 4]
        out.append({"agent": agent, "seed": int(seed), "before_error_cm": before.mean(), "threshold_cm": level,
                    "right_after_error_cm": right.mean() if len(right) == 5 else np.nan,
                    "recovered_at_episode": at, "episodes_to_recover": None if at is None else at - change,
                    "last_episode": int(e.index.max())})
    return pd.DataFrame(out)


def recovery_summary(rec: pd.DataFrame) -> pd.DataFrame:
    """Per agent: seeds, seeds recovered, the recovery episode's mean and range (recovered seeds) and the
    right-after error's mean and interval."""
    out = []
    for agent, d in rec.groupby("agent", sort=False):
        back = d.recovered_at_episode.dropna().astype(int)
        mean, lo, hi = interval(d.right_after_error_cm.dropna().tolist())
        out.append({"agent": agent, "seeds": len(d), "recovered": len(back),
                    "recovered_at_mean": back.mean() if len(back) else np.nan,
                    "recovered_at_range": f"{back.min()}-{back.max()}" if len(back) else "-",
                    "right_after_error_cm": mean, "lo": lo, "hi": hi,
                    "before_error_cm": d.before_error_cm.mean()})
    return pd.DataFrame(out)


def seed_tests(test: pd.DataFrame) -> pd.DataFrame:
    """Per agent, condition and seed: test success, its counts, habit share and final distance (grid targets)."""
    if test.empty:
        return pd.DataFrame()
    g = test.groupby(["agent", "condition", "seed"])
    out = g.agg(targets=("success", "size"), successes=("success", "sum"), success=("success", "mean"),
                final_distance_cm=("final_distance", "mean"), steps=("steps", "mean"),
                habit=("habit_actions", "sum"), planning=("planning_actions", "sum")).reset_index()
    out["habit_share"] = out.habit / (out.habit + out.planning).clip(lower=1)
    return out.drop(columns=["habit", "planning"])


# -- frozen probes -----------------------------------------------------------------------------------------------
PROBE_SETTINGS = {CURL: {"off": {"field_b": 0.0, "field_on_episode": -1, "field_off_episode": -1},
                         "on": {"field_on_episode": 0, "field_off_episode": -1}},
                  LOAD: {"off": {"load": 0.0, "load_change_episode": -1, "load_after": 0.0},
                         "on": {"load": 1.0, "load_change_episode": -1, "load_after": 0.0}}}


#: Training episodes after the load change at which the agent is probed for its recovery (issue 27: back within 10
#: points of its pre-load test success within 30 episodes?).
RECOVERY_EPISODES = 30


def probe_moments(cond: str, schedule: dict[str, int], episodes: int) -> list[int]:
    """The slowest seed's training episodes at which the agent is probed: the event, the field's switch-off (curl)
    or :data:`RECOVERY_EPISODES` after the load change (load), the end."""
    change = schedule.get("load_change_episode", -1)
    events = [schedule["field_on_episode"], schedule["field_off_episode"]] if cond == CURL \
        else [change, change + RECOVERY_EPISODES if change >= 0 else -1]
    return sorted({e for e in events if 0 <= e <= episodes} | {episodes})


def frozen_test(cell: Path, checkpoint: Path, plant_changes: dict[str, Any], limit: int | None = None,
                members: list[int] | None = None) -> list[dict[str, Any]]:
    """Every member (or those listed, by index) of the checkpoint's frozen agent on the 100 angle-grid targets
    (its own link lengths; the first ``limit`` only if given), with the
    task's plant changed by ``plant_changes``: per seed its episode at the checkpoint, success, relative error
    (mean hand-target distance over the path / the target's distance from the start pose), final distance,
    steps, habit share and the first step's signed lateral deviation (:func:`lateral_deviation`)."""
    import dataclasses

    import torch

    from apac_mj.run.build import loaded_agent
    from apac_mj.run.evaluate import eval_env, evaluation_targets, run_protocol
    from apac_mj.run.run_dir import RunCheckpoint, RunDir
    from apac_mj.suite import spec_for

    cfg = RunDir(cell).train_config()
    spec = spec_for(cfg)
    spec = spec.replace(plant=dataclasses.replace(spec.plant, **plant_changes))
    cfg = dataclasses.replace(cfg, task_overrides={**cfg.task_overrides, "plant": spec.plant})
    ckpt = RunCheckpoint(torch.load(checkpoint, weights_only=True), Path(checkpoint))
    env = eval_env(cfg, spec, None, occluded=False)
    agent = loaded_agent(cfg, spec, env.sizes, ckpt.agent)
    lengths = ckpt.member_lengths()
    members = list(range(len(cfg.seeds))) if members is None else members
    targets = [t[:limit] if k in members else t[:0]
               for k, t in enumerate(evaluation_targets(spec, lengths, ckpt.member_targets()))]
    rows = pd.DataFrame(run_protocol(cfg, agent, spec, lengths, targets, occluded=False,
                                     running=ckpt.running_statistics(), env=env))
    out = []
    for k in members:
        seed = cfg.seeds[k]
        r = rows[rows.seed == seed]
        start = np.array([15.0 + lengths[k, 0] - lengths[k, 1], 15.0])
        start_distance = np.hypot(r.target_x - start[0], r.target_y - start[1])
        path_error = [np.mean(np.hypot(np.asarray(px) - tx, np.asarray(py) - ty))
                      for px, py, tx, ty in zip(r.path_x, r.path_y, r.target_x, r.target_y)]
        acts = (r.habit_actions + r.planning_actions).sum()
        out.append({"seed": int(seed), "seed_episode": ckpt.member_episode(k), "targets": len(r),
                    "successes": int(r.success.sum()), "success": float(r.success.mean()),
                    "relative_error": float(np.mean(np.asarray(path_error) / start_distance)),
                    "final_distance_cm": float(r.final_distance.mean()), "steps": float(r.steps.mean()),
                    "habit_share": float(r.habit_actions.sum() / max(1, acts)),
                    "lateral_cm": float(np.mean([lateral_deviation(px, py, tx, ty) for px, py, tx, ty in
                                                 zip(r.path_x, r.path_y, r.target_x, r.target_y)]))})
    return out


def lateral_deviation(path_x: Any, path_y: Any, target_x: float, target_y: float) -> float:
    """The hand's signed deviation (cm) from the straight line to the target after the first step: positive to the
    left of the line (counter-clockwise), negative to the right. The curl field (b > 0) turns its force clockwise
    from the hand's velocity, so it pushes the first movement to the right (negative); an internal model adapted
    to it pushes left, and with the field off again the after-effect shows as a deviation to the left (positive)
    of the one before the field. NaN for a path of less than two points."""
    px, py = np.asarray(path_x, dtype=float), np.asarray(path_y, dtype=float)
    if len(px) < 2:
        return float("nan")
    u = np.array([target_x - px[0], target_y - py[0]])
    u /= max(np.linalg.norm(u), 1e-12)
    return float((px[1] - px[0]) * -u[1] + (py[1] - py[0]) * u[0])


def saved_checkpoints(cell: Path, history: Path) -> dict[Path, list[int]]:
    """The cell's saved checkpoints (history copies, then a finished cell's latest.pt) with every seed's
    training episode in each; a checkpoint equal in episodes to an earlier one is left out."""
    import torch

    saved = sorted((history / cell.name).glob("*.pt"))
    if (cell / "DONE").is_file():
        saved.append(cell / "checkpoints" / "latest.pt")
    out: dict[Path, list[int]] = {}
    for path in saved:
        loop = torch.load(path, weights_only=True, mmap=True, map_location="cpu")["loop"]
        episodes = [int(e) for e in loop["episode"]]
        if episodes not in out.values():
            out[path] = episodes
    return out


def member_checkpoints(saved: dict[Path, list[int]], moment: int) -> dict[int, Path]:
    """Per member (index) the checkpoint with the agent as it was after the most training episodes of that
    member not past ``moment`` (the seeds run side by side and drift apart by a few episodes, a checkpoint is
    written when the slowest reaches a multiple of checkpoint_every). A member that has no checkpoint at or past
    ``moment`` yet (a cell still training) or none before it is left out."""
    out: dict[int, Path] = {}
    best: dict[int, int] = {}
    for path, episodes in saved.items():
        for k, e in enumerate(episodes):
            if e <= moment and e > best.get(k, -1):
                best[k], out[k] = e, path
    reached = {k for episodes in saved.values() for k, e in enumerate(episodes) if e >= moment}
    return {k: p for k, p in out.items() if k in reached}


def probes(grid: Path, history: Path, cache: Path, info: dict[tuple[str, str], dict[str, Any]],
           limit: int | None = None, agents: list[str] | None = None, cached_only: bool = False) -> pd.DataFrame:
    """Per agent, condition, probe moment, plant setting (field / load off, on) and seed: :func:`frozen_test` of
    the seed's checkpoint at the moment (:func:`member_checkpoints`; ``limit``: the first targets only). Results
    are cached per checkpoint, setting and seed in ``cache/<cell>/<checkpoint>_<setting>[_<limit>targets].json``
    (a probe of 3 seeds x 100 targets costs ~30 s of CPU)."""
    out = []
    for (agent, cond), cell in cell_dirs(grid).items():
        if cond not in PROBE_SETTINGS or (agent, cond) not in info or (agents and agent not in agents):
            continue
        saved = saved_checkpoints(cell, history)
        for moment in probe_moments(cond, info[(agent, cond)]["schedule"], info[(agent, cond)]["episodes"]):
            chosen = member_checkpoints(saved, moment)
            by_checkpoint: dict[Path, list[int]] = {}
            for k, path in sorted(chosen.items()):
                by_checkpoint.setdefault(path, []).append(k)
            for path, members in by_checkpoint.items():
                for setting, changes in PROBE_SETTINGS[cond].items():
                    result = _cached_probe(cell, path, members, setting, changes, cache, limit, cached_only)
                    out += [{"agent": agent, "condition": cond, "after_episode": moment, "plant": setting, **r}
                            for r in result]
    return pd.DataFrame(out).sort_values(["agent", "condition", "after_episode", "plant", "seed"]) if out \
        else pd.DataFrame()


def _cached_probe(cell: Path, checkpoint: Path, members: list[int], setting: str, changes: dict[str, Any],
                  cache: Path, limit: int | None, cached_only: bool = False) -> list[dict[str, Any]]:
    """:func:`frozen_test` of ``members`` of ``checkpoint``, from the cache where it has them."""
    stem = "final" if checkpoint.parent.name == "checkpoints" else checkpoint.stem
    path = cache / cell.name / f"{stem}_{setting}{f'_{limit}targets' if limit else ''}.json"
    have = {int(k): v for k, v in json.loads(path.read_text()).items()} if path.is_file() else {}
    todo = [k for k in members if k not in have]
    if todo and cached_only:
        return [have[k] for k in members if k in have]
    if todo:
        print(f"probe {cell.name} {checkpoint.name} members {todo}, {setting}", flush=True)
        for k, r in zip(todo, frozen_test(cell, checkpoint, changes, limit, todo)):
            have[k] = r
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({str(k): v for k, v in sorted(have.items())}))
    return [have[k] for k in members]


def probe_effects(pr: pd.DataFrame, moments: dict[str, list[int]]) -> pd.DataFrame:
    """Per agent, condition and seed, from the frozen probes (``moments``: per condition the probe episodes,
    :func:`probe_moments`; 110/130/N below; off/on: the field or load). Curl: immediate cost = on - off at 110,
    cost after the field = on - off at 130, after-effect = off at 130 - off at 110. Load: cost at the change =
    on - off at 110, cost at the end = on - off at N, loaded: on at N - on at 110, unloaded: off at N - off at
    110 (the load's after-effect and the learning in between)."""
    quantities = [q for q in ("success", "relative_error", "final_distance_cm", "steps", "lateral_cm")
                  if q in pr.columns]
    out = []
    for (agent, cond, seed), d in pr.groupby(["agent", "condition", "seed"]):
        v = {(int(r.after_episode), r.plant): r for r in d.itertuples()}
        first, last = moments[cond][0], moments[cond][-1]
        if cond == CURL:
            mid = moments[cond][1]
            pairs = {"immediate cost (on - off)": ((first, "on"), (first, "off")),
                     "cost after the field (on - off)": ((mid, "on"), (mid, "off")),
                     "after-effect (off: switch-off - event)": ((mid, "off"), (first, "off"))}
        else:
            recovery = first + RECOVERY_EPISODES
            pairs = {"cost at the change (on - off)": ((first, "on"), (first, "off")),
                     f"recovery: loaded {RECOVERY_EPISODES} episodes later - unloaded at the change":
                         ((recovery, "on"), (first, "off")),
                     "cost at the end (on - off)": ((last, "on"), (last, "off")),
                     "loaded: end - change": ((last, "on"), (first, "on")),
                     "unloaded: end - change": ((last, "off"), (first, "off"))}
        for name, (a, b) in pairs.items():
            if a not in v or b not in v or a == b:
                continue
            out.append({"agent": agent, "condition": cond, "effect": name, "between": f"{a[0]}{a[1]}-{b[0]}{b[1]}",
                        "seed": int(seed), **{q: getattr(v[a], q) - getattr(v[b], q) for q in quantities}})
    return pd.DataFrame(out)


# -- the figure --------------------------------------------------------------------------------------------------
def _band(ax: Any, rows: pd.DataFrame, column: str, color: str, label: str, smooth: int) -> None:
    """Mean over seeds of each seed's ``smooth``-episode trailing mean of ``column``; shaded: min-max over seeds."""
    per = rows.pivot_table(index="episode", columns="seed", values=column)
    per = per.rolling(smooth, min_periods=1).mean()
    ax.plot(per.index, per.mean(axis=1), color=color, label=f"{label} ({per.shape[1]} seeds)")
    ax.fill_between(per.index, per.min(axis=1), per.max(axis=1), color=color, alpha=0.15, lw=0)


def _mark_event(ax: Any, schedule: dict[str, int]) -> None:
    if schedule.get("field_on_episode", -1) >= 0:
        ax.axvspan(schedule["field_on_episode"], schedule["field_off_episode"], color="tab:purple", alpha=0.12, lw=0)
    elif schedule.get("load_change_episode", -1) >= 0:
        ax.axvline(schedule["load_change_episode"], color="k", ls="--", lw=1)


def figure(rows: pd.DataFrame, tests: pd.DataFrame, info: dict[tuple[str, str], dict[str, Any]], path: Path,
           smooth: int = 5) -> None:
    """Per condition (rows): relative error and habit share over training, test success per agent."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker  # noqa: F401  (matplotlib.ticker below)

    fig, axes = plt.subplots(len(CONDITIONS), 3, figsize=(16, 4.2 * len(CONDITIONS)), constrained_layout=True,
                             gridspec_kw={"width_ratios": [1.4, 1.4, 0.8]})
    for row, cond in enumerate(CONDITIONS):
        ax_err, ax_habit, ax_test = axes[row]
        for agent in AGENTS:
            d = rows[(rows.agent == agent) & (rows.condition == cond)] if len(rows) else rows
            if d.empty:
                continue
            _band(ax_err, d, "relative_error", COLORS[agent], agent.upper(), smooth)
            _band(ax_habit, d, "habit_share", COLORS[agent], agent.upper(), smooth)
        schedule = next((v["schedule"] for (a, c), v in info.items() if c == cond), {})
        for ax in (ax_err, ax_habit):
            _mark_event(ax, schedule)
            ax.set_xlabel("training episode")
        ax_err.set_title(TITLES[cond])
        ax_err.set_ylabel(f"relative error ({smooth}-episode mean, log scale)")
        ax_err.set_yscale("log")
        ax_err.yaxis.set_major_locator(matplotlib.ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
        ax_err.yaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
        ax_err.yaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        if ax_err.lines:
            ax_err.legend(loc="upper right")
        ax_habit.set_title("habit share (actor's actions / all)")
        ax_habit.set_ylim(-0.05, 1.05)
        _test_panel(ax_test, tests, cond)
    fig.suptitle("Lines: mean over seeds; shaded: min-max over seeds", fontsize=10)
    fig.savefig(path, dpi=100)


def _test_panel(ax: Any, tests: pd.DataFrame, cond: str) -> None:
    """Test success per agent: mean over seeds with its 95% interval, dots: the seeds."""
    ax.set_title("test success, 100 grid targets, no load/field\nbar: mean, 95% interval; dots: seeds", fontsize=9)
    ax.set_ylim(0, 1)
    d = tests[tests.condition == cond] if len(tests) else tests
    if d.empty:
        ax.text(0.5, 0.5, "no cell tested yet", ha="center", transform=ax.transAxes)
        return
    for x, agent in enumerate(AGENTS):
        a = d[d.agent == agent]
        if a.empty:
            continue
        mean, lo, hi = interval(a.success.tolist(), a.successes.tolist(), a.targets.tolist(), scale=1.0)
        ax.bar(x, mean, color=COLORS[agent], alpha=0.7)
        ax.errorbar(x, mean, yerr=[[mean - lo], [hi - mean]], color="k", capsize=4)
        ax.plot(np.full(len(a), x) + np.linspace(-0.15, 0.15, len(a)), a.success, "ko", ms=3)
    ax.set_xticks(range(len(AGENTS)), [a.upper() for a in AGENTS])


# -- output ------------------------------------------------------------------------------------------------------
def markdown(df: pd.DataFrame) -> str:
    """A markdown table (numbers to 3 significant digits), without pandas' optional tabulate."""
    def cell(v: Any) -> str:
        if isinstance(v, (float, np.floating)):
            return "-" if math.isnan(v) else f"{v:.3g}"
        return str(v)

    lines = ["| " + " | ".join(df.columns) + " |", "|" + "---|" * len(df.columns)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in df.itertuples(index=False)]
    return "\n".join(lines)


def ordered(df: pd.DataFrame) -> pd.DataFrame:
    """Rows in the study's order: condition, then agent (DDPG, SPAC, APAC), then as they were."""
    if df.empty or "agent" not in df:
        return df
    key = {"agent": AGENTS.index, "condition": lambda c: CONDITIONS.index(c) if c in CONDITIONS else len(CONDITIONS)}
    cols = [c for c in ("condition", "agent") if c in df]
    return df.sort_values(cols, key=lambda s: s.map(key[s.name]), kind="stable").reset_index(drop=True)


def section(title: str, df: pd.DataFrame, path: Path | None = None) -> None:
    """Print ``df`` under ``title`` (and write it to ``path`` as CSV), in the study's order."""
    df = ordered(df)
    if path is not None and len(df):
        df.to_csv(path, index=False, float_format="%.4g")
    print(f"\n## {title}\n")
    print(markdown(df) if len(df) else "(nothing yet)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__.split("\n\n", 2)[2],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("grid", type=Path, help="the grid's results folder (cells <agent>__<condition>)")
    ap.add_argument("--out", type=Path, required=True, help="folder for the CSVs and fig_dynamics.png")
    ap.add_argument("--history", type=Path, default=None,
                    help="folder of per-cell checkpoint copies (<cell>/*.pt) for the frozen probes")
    ap.add_argument("--probe-cache", type=Path, default=None,
                    help="folder for the probes' results (default: <history>_probes next to --history)")
    ap.add_argument("--probe-targets", type=int, default=None,
                    help="probe on the first N of the 100 grid targets only (a quick look; default: all)")
    ap.add_argument("--probe-agents", type=lambda s: s.split(","), default=None,
                    help="probe only these agent kinds (comma-separated; default: every one)")
    ap.add_argument("--cached-probes-only", action="store_true",
                    help="report the probes already in --probe-cache, run none (a probe of 5 seeds costs minutes)")
    args = ap.parse_args()
    rows, test, info = load_grid(args.grid)
    args.out.mkdir(parents=True, exist_ok=True)
    missing = [f"{a}__{c}" for (a, c) in cell_dirs(args.grid) if (a, c) not in info]
    cell_windows = {key: windows(key[1], v["schedule"], v["episodes"]) for key, v in info.items()}
    per_seed = seed_windows(rows, cell_windows) if len(rows) else pd.DataFrame()
    if len(rows):
        rows[["agent", "condition", "seed", "episode", "success", "steps", "final_distance", "error",
              "relative_error", "habit_share"]].to_csv(args.out / "learning.csv", index=False, float_format="%.4g")
        per_seed.to_csv(args.out / "windows.csv", index=False, float_format="%.4g")
        section("windows: mean over seeds, 95% interval, per seed",
                summarize(per_seed, ["agent", "condition", "window", "episodes"], list(QUANTITIES.values()),
                          {"success": ("successes", "n")}), args.out / "events.csv")
        eff = seed_effects(per_seed)
        section("effects (window - reference, per seed, then over seeds)",
                summarize(eff, ["agent", "condition", "effect"], list(QUANTITIES.values()))
                if len(eff) else eff, args.out / "effects.csv")
        load_rows = rows[rows.condition == LOAD]
        change = next((v["schedule"]["load_change_episode"] for (a, c), v in info.items() if c == LOAD), -1)
        rec = recovery(load_rows, change) if len(load_rows) and change >= 0 else pd.DataFrame()
        section("load change: recovery per seed", rec, args.out / "recovery.csv")
        section("load change: recovery over seeds", recovery_summary(rec) if len(rec) else rec)
    tests = seed_tests(test)
    section("test per seed (100 grid targets, plant before any change)", tests, args.out / "tests.csv")
    if len(tests):
        section("test over seeds", summarize(tests, ["agent", "condition"],
                                             ["success", "habit_share", "final_distance_cm", "steps"],
                                             {"success": ("successes", "targets")}))
    figure(rows, tests, info, args.out / "fig_dynamics.png")
    if args.history is not None:
        cache = args.probe_cache or args.history.parent / f"{args.history.name}_probes"
        pr = probes(args.grid, args.history, cache, info, args.probe_targets, args.probe_agents,
                    args.cached_probes_only)
        section("frozen probes per seed", pr, args.out / "probes.csv")
        if len(pr):
            quantities = [q for q in ("success", "relative_error", "final_distance_cm", "steps", "habit_share",
                                      "lateral_cm") if q in pr.columns]
            section("frozen probes over seeds", summarize(pr, ["agent", "condition", "after_episode", "plant"],
                                                          quantities, {"success": ("successes", "targets")}),
                    args.out / "probe_summary.csv")
            pe = probe_effects(pr, {c: probe_moments(c, v["schedule"], v["episodes"]) for (a, c), v in info.items()
                                    if c in PROBE_SETTINGS})
            section("frozen-probe effects (per seed, then over seeds)",
                    summarize(pe, ["agent", "condition", "effect", "between"],
                              [q for q in quantities if q != "habit_share"])
                    if len(pe) else pe, args.out / "probe_effects.csv")
    print("\ntrained up to (slowest seed):",
          {f"{a}__{c}": int(d.groupby("seed").episode.max().min())
           for (a, c), d in rows.groupby(["agent", "condition"])}
          if len(rows) else {})
    print("cells done:", sorted(f"{a}__{c}" for (a, c), v in info.items() if v["done"]))
    print("missing cells:", missing)


if __name__ == "__main__":
    main()
