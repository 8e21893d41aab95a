"""The arbitration under dynamics (issue 17): event numbers and one figure from a ``dynamics`` grid.

    apac-mj grid --preset dynamics --out results/dynamics
    python bench/dynamics.py results/dynamics --out docs/results/dynamics

Reads every cell's ``metrics.parquet`` (training episodes) and ``eval/summary.json`` (test on the angle grid)
that exists, so it also reports a grid that is still running (cells not yet trained are listed as missing).
Per episode the *error* is the mean distance from hand to target over the episode's steps (cm; minus the
return over the steps), the *relative error* that error over the target's distance from the start pose (so
near and far targets weigh alike), and the final distance. Writes ``events.csv`` (one row per agent, condition and
window), ``learning.csv`` (per episode) and ``fig_dynamics.png``; prints the tables as markdown.

Windows (training episodes; the task files' schedule):

* curl field (on in 110-129): ``before`` 100-109 (APAC arbitrates from 100), ``field early`` 110-114,
  ``field late`` 125-129, ``after-effect`` 130-134 (the first 5 episodes after switch-off), ``after late``
  145-149. The after-effect is ``after-effect - before``.
* load change (1 kg from 110): ``before`` 100-109, ``right after`` 110-114, ``late`` 140-149; the recovery
  episode is the first after the change whose 5-episode mean error is back within the ``before`` mean plus
  one standard deviation of the ``before`` episodes.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pandas as pd

AGENTS = ("ddpg", "spac", "apac")
CURL = "changing_target_compliant_curl_field"
LOAD = "changing_target_compliant_load_change"
WINDOWS = {
    CURL: {"before": (100, 109), "field early": (110, 114), "field late": (125, 129),
           "after-effect": (130, 134), "after late": (145, 149)},
    LOAD: {"before": (100, 109), "right after": (110, 114), "late": (140, 149)},
}
EVENT = {CURL: (110, 130), LOAD: (110, None)}
COLORS = {"ddpg": "tab:orange", "spac": "tab:green", "apac": "tab:blue"}


def load_cells(grid: Path) -> tuple[pd.DataFrame, dict[tuple[str, str], dict]]:
    """Training rows of every cell that has any (with ``agent``, ``condition``, ``error``, ``habit_share``)
    and the test summaries of the finished ones."""
    frames, tests = [], {}
    for cond in WINDOWS:
        for agent in AGENTS:
            cell = grid / f"{agent}__{cond}"
            if not (cell / "metrics.parquet").is_file():
                continue
            d = pd.read_parquet(cell / "metrics.parquet")
            d = d[d.phase == "train"].copy()
            d["agent"], d["condition"] = agent, cond
            d["error"] = -d["return"] / d["steps"]
            # the start pose (0, 180) puts the hand at origin + (l1 - l2, 0): the initial distance to the target
            start_x, start_y = 15.0 + d.l1 - d.l2, 15.0
            d["relative_error"] = d.error / np.hypot(d.target_x - start_x, d.target_y - start_y)
            acts = d.habit_actions + d.planning_actions
            d["habit_share"] = np.where(acts > 0, d.habit_actions / acts.clip(lower=1), np.nan)
            frames.append(d)
            summary = cell / "eval" / "summary.json"
            if summary.is_file():
                tests[(agent, cond)] = json.loads(summary.read_text())["protocols"]["grid"]
    return (pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()), tests


def events(rows: pd.DataFrame) -> pd.DataFrame:
    """Mean error, final distance, success and habit share per agent, condition and window."""
    out = []
    for (agent, cond), d in rows.groupby(["agent", "condition"]):
        for name, (lo, hi) in WINDOWS[cond].items():
            w = d[(d.episode >= lo) & (d.episode <= hi)]
            complete = len(w) == hi - lo + 1
            out.append({"agent": agent, "condition": cond, "window": name, "episodes": f"{lo}-{hi}",
                        "n": len(w), "complete": complete, "error_cm": w.error.mean() if len(w) else np.nan,
                        "relative_error": w.relative_error.mean() if len(w) else np.nan,
                        "final_distance_cm": w.final_distance.mean() if len(w) else np.nan,
                        "success": w.success.mean() if len(w) else np.nan,
                        "habit_share": w.habit_share.mean() if len(w) else np.nan})
    return pd.DataFrame(out)


def recovery(rows: pd.DataFrame, window: int = 5) -> pd.DataFrame:
    """Load change: the first episode after the change whose ``window``-episode mean error is back within
    the ``before`` mean + 1 sd (None: not within the episodes trained)."""
    out = []
    for agent, d in rows[rows.condition == LOAD].groupby("agent"):
        d = d.set_index("episode").sort_index()
        before = d.loc[100:109, "error"]
        if len(before) < 10:
            continue
        level = before.mean() + before.std(ddof=1)
        after = d.loc[110:, "error"].rolling(window).mean().dropna()
        back = after[after <= level]
        out.append({"agent": agent, "before_error_cm": before.mean(), "threshold_cm": level,
                    "right_after_error_cm": d.loc[110:114, "error"].mean(),
                    "recovered_at_episode": int(back.index[0]) if len(back) else None,
                    "episodes_to_recover": int(back.index[0]) - 110 if len(back) else None,
                    "last_episode": int(d.index.max())})
    return pd.DataFrame(out)


# -- frozen probes: the agent as it was at an episode, on the same 100 targets, field/load on or off ----------
def _frozen_error(cell: Path, checkpoint: Path, plant_changes: dict) -> dict:
    """Test the checkpoint's frozen agent on the 100 angle-grid targets with the task's plant changed by
    ``plant_changes`` (e.g. the field on from the first episode): success, relative error, final distance."""
    import dataclasses

    import torch

    from apac_mj.agent.agent import Agent
    from apac_mj.kinematics import Geometry
    from apac_mj.run.evaluate import evaluation_targets, run_protocol
    from apac_mj.run.run_dir import RunCheckpoint, RunDir, task_sizes
    from apac_mj.suite import spec_for

    cfg = RunDir(cell).train_config()
    plant = dataclasses.replace(spec_for(cfg).plant, **plant_changes)
    cfg = dataclasses.replace(cfg, task_overrides={**cfg.task_overrides, "plant": plant})
    spec = spec_for(cfg)
    ckpt = RunCheckpoint(torch.load(checkpoint, weights_only=True), Path(checkpoint))
    agent = Agent(cfg.agent, list(cfg.seeds), geometry=Geometry.from_spec(spec), sizes=task_sizes(cfg))
    agent.load_state_dict(ckpt.agent)
    lengths = ckpt.member_lengths()
    targets = evaluation_targets(spec, lengths, ckpt.member_targets())
    rows = pd.DataFrame(run_protocol(cfg, agent, spec, lengths, targets, occluded=False,
                                     running=ckpt.running_statistics()))
    start = np.array([15.0 + lengths[0, 0] - lengths[0, 1], 15.0])
    start_distance = np.hypot(rows.target_x - start[0], rows.target_y - start[1])
    path_error = [np.mean(np.hypot(np.asarray(px) - tx, np.asarray(py) - ty))
                  for px, py, tx, ty in zip(rows.path_x, rows.path_y, rows.target_x, rows.target_y)]
    habit = rows.habit_actions.sum() / max(1, (rows.habit_actions + rows.planning_actions).sum())
    return {"episode": ckpt.member_episode(0), "success": rows.success.mean(),
            "relative_error": float(np.mean(np.asarray(path_error) / start_distance)),
            "final_distance_cm": rows.final_distance.mean(), "steps": rows.steps.mean(), "habit_share": habit}


def probes(grid: Path, history: Path) -> pd.DataFrame:
    """Every agent frozen before the event (after training episode 110) and after it (curl: after 130, when
    the field goes off, and at the end, 150; load: at the end, 150), each tested on the 100 grid targets with
    the field / load off and on. The curl after-effect is the ``off`` error after 130 against after 110."""
    import torch

    settings = {CURL: {"off": {"field_b": 0.0, "field_on_episode": -1, "field_off_episode": -1},
                       "on": {"field_on_episode": 0, "field_off_episode": -1}},
                LOAD: {"off": {"load": 0.0, "load_change_episode": -1, "load_after": 0.0},
                       "on": {"load": 1.0, "load_change_episode": -1, "load_after": 0.0}}}
    moments = {CURL: (110, 130, 150), LOAD: (110, 150)}
    out = []
    for cond in WINDOWS:
        for agent in AGENTS:
            cell = grid / f"{agent}__{cond}"
            saved = sorted((history / cell.name).glob("*.pt"))
            if (cell / "DONE").is_file():
                saved.append(cell / "checkpoints" / "latest.pt")
            at = {}
            for path in saved:
                at[int(torch.load(path, weights_only=True)["loop"]["episode"][0])] = path
            for moment in moments[cond]:
                if moment not in at:
                    continue
                for name, changes in settings[cond].items():
                    cache = history / cell.name / f"probe_{moment}_{name}.json"  # a probe costs ~20 s of CPU
                    if cache.is_file():
                        r = json.loads(cache.read_text())
                    else:
                        r = {k: float(v) for k, v in _frozen_error(cell, at[moment], changes).items()}
                        cache.write_text(json.dumps(r))
                    out.append({"agent": agent, "condition": cond, "after_episode": moment, "plant": name, **r})
    return pd.DataFrame(out)


def figure(rows: pd.DataFrame, tests: dict, path: Path, smooth: int = 5) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(15, 7.5), constrained_layout=True)
    for row, cond in enumerate((CURL, LOAD)):
        ax_err, ax_habit, ax_test = axes[row]
        for agent in AGENTS:
            d = rows[(rows.agent == agent) & (rows.condition == cond)].sort_values("episode")
            if d.empty:
                continue
            ax_err.plot(d.episode, d.relative_error.rolling(smooth, min_periods=1).mean(), color=COLORS[agent],
                        label=agent.upper())
            ax_habit.plot(d.episode, d.habit_share.rolling(smooth, min_periods=1).mean(), color=COLORS[agent],
                          label=agent.upper())
        on, off = EVENT[cond]
        for ax in (ax_err, ax_habit):
            if off is None:
                ax.axvline(on, color="k", ls="--", lw=1)
            else:
                ax.axvspan(on, off, color="tab:purple", alpha=0.12, lw=0)
            ax.set_xlabel("training episode")
        what = "curl field on (shaded)" if off else "1 kg load from the dashed line"
        ax_err.set_title(f"{'curl field' if off else 'gravity + load change'}: {what}")
        ax_err.set_ylabel(f"relative error, {smooth}-episode mean")
        ax_err.legend()
        ax_habit.set_title("habit share (actor's actions / all)")
        ax_habit.set_ylim(-0.05, 1.05)
        names = [a for a in AGENTS if (a, cond) in tests]
        if not names:
            ax_test.text(0.5, 0.5, "no cell tested yet", ha="center", transform=ax_test.transAxes)
        ax_test.bar([a.upper() for a in names], [tests[(a, cond)]["success_rate"] for a in names],
                    color=[COLORS[a] for a in names])
        ax_test.set_ylim(0, 1)
        ax_test.set_title("test success (100 grid targets, plant before any change)")
    fig.savefig(path, dpi=110)


def markdown(df: pd.DataFrame) -> str:
    """A markdown table (numbers to 3 significant digits), without pandas' optional tabulate."""
    def cell(v) -> str:
        return f"{v:.3g}" if isinstance(v, (float, np.floating)) else str(v)

    lines = ["| " + " | ".join(df.columns) + " |", "|" + "---|" * len(df.columns)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in df.itertuples(index=False)]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("grid", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--history", type=Path, default=None,
                    help="folder of per-cell checkpoint copies (<cell>/*.pt) for the frozen probes")
    args = ap.parse_args()
    rows, tests = load_cells(args.grid)
    args.out.mkdir(parents=True, exist_ok=True)
    missing = [f"{a}__{c}" for c in WINDOWS for a in AGENTS if rows.empty or rows[(rows.agent == a)
               & (rows.condition == c)].empty]
    ev, rec = events(rows), recovery(rows)
    ev.to_csv(args.out / "events.csv", index=False, float_format="%.4g")
    rows[["agent", "condition", "episode", "success", "steps", "final_distance", "error", "relative_error",
          "habit_share"]].to_csv(
        args.out / "learning.csv", index=False, float_format="%.4g")
    figure(rows, tests, args.out / "fig_dynamics.png")
    print(markdown(ev))
    print()
    print(markdown(rec) if len(rec) else "load change: no cell past episode 109")
    print()
    for (agent, cond), t in sorted(tests.items()):
        print(f"test {agent} {cond}: success {t['success_rate']:.2f}, habit share {t['habit_share']:.2f}, "
              f"final distance {t['final_distance_mean']:.2f} cm")
    last = rows.groupby(["agent", "condition"]).episode.max() if len(rows) else {}
    print("trained up to:", dict(last))
    print("missing cells:", missing)
    if args.history is not None:
        pr = probes(args.grid, args.history)
        pr.to_csv(args.out / "probes.csv", index=False, float_format="%.4g")
        print()
        print(markdown(pr) if len(pr) else "no checkpoint at the probe episodes")


if __name__ == "__main__":
    main()
