"""Where APAC fails the frozen angle-grid test, and what the paper's rule does there (issue 19).

    python bench/apac_failures.py RUN [RUN ...] [--json out.json]

RUN: an APAC run directory (``apac-mj train`` or a grid cell). The frozen test of ``apac-mj evaluate``
(the 100 angle-grid targets per seed, networks and arbitrator frozen, arbitrated as after the planning
phase) is run again with every step kept, and the failed episodes are described:

* how they end: a 30-step time-out, and how far from the target (the zone radius is 0.5 cm);
* who acted: the habit's share of the actions, and of the last 10;
* the paper's rule there: the habit acts in the first two steps, then whenever the last TD error
  ``|delta| < 1`` (``AgentConfig.delta_threshold``): the share of the rule's decisions (step >= 2) with
  ``|delta|`` below the threshold, the largest ``|delta|`` the rule saw, and how far the hand moved over
  the last 10 steps (a habit re-proposing the same pose moves it ~0);
* what else would have reached those targets, with the same frozen networks and running statistics on
  the same targets (the rule is not changed; these are counterfactual tests): the inverse model alone
  (arbitrated as SPAC) and the actor alone (as DDPG).

The failed targets come from the run's ``eval/grid.parquet`` (``apac-mj evaluate`` or the grid wrote it);
only those are re-run (the frozen episodes are deterministic: a re-run target that is reached is an
error). Without it every target is run.

Prints one table per run (per seed and over all seeds) and, with ``--json``, writes the numbers.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from apac_mj.run.evaluate import evaluation_targets, run_protocol
from apac_mj.run.rollout import Hook
from apac_mj.run.build import load_run
from apac_mj.run.run_dir import RunDir

LAST = 10  # steps at the end of a failed episode that "who acted" and "how far it moved" look at


class StepLog(Hook):
    """Every member's steps of every frozen episode: (target index, seed index) -> list of step dicts."""

    def __init__(self) -> None:
        self.episode = -1
        self.steps: dict[tuple[int, int], list[dict[str, float]]] = {}

    def on_episode_start(self, members: np.ndarray, vec_env: Any) -> None:
        self.episode += 1

    def on_step(self, info: Any, vec_env: Any) -> None:
        for k in np.flatnonzero(info.active):
            self.steps.setdefault((self.episode, int(k)), []).append(
                {"step": int(info.step[k]), "habit": bool(info.habit[k]), "delta": float(info.delta[k]),
                 "distance": float(info.distance[k]), "x": float(info.true_arm[k, 0]),
                 "y": float(info.true_arm[k, 1])})


def frozen_test(run: Path, kind: str | None = None, log: StepLog | None = None,
                only: list[np.ndarray] | None = None) -> pd.DataFrame:
    """The run's frozen angle-grid test (as ``apac-mj evaluate``), arbitrated as ``kind`` (default: the run's);
    ``only``: per member, the indices of the targets to run (the episodes are deterministic, so a subset
    runs exactly as in the full test). ``target_index`` is the index in the member's full target list."""
    loaded = load_run(run, device="cpu")
    cfg, agent, ckpt, spec = loaded.cfg, loaded.agent, loaded.ckpt, loaded.spec
    if kind is not None:
        cfg = dataclasses.replace(cfg, agent=dataclasses.replace(cfg.agent, kind=kind))
    lengths = ckpt.member_lengths()
    targets = evaluation_targets(spec, lengths, ckpt.member_targets())
    only = [np.arange(len(t)) for t in targets] if only is None else only
    running = ckpt.running_statistics()
    if kind is not None:
        running.pop("arbitrator", None)
    rows = pd.DataFrame(run_protocol(cfg, agent, spec, lengths, [t[i] for t, i in zip(targets, only)],
                                     occluded=False, hooks=[log] if log else [], running=running))
    if rows.empty:
        return rows
    seeds = list(cfg.seeds)
    if log is not None:  # the log's episode counter is the position in the subset: key it by target index
        log.steps = {(int(only[k][i]), k): v for (i, k), v in log.steps.items()}
    rows["target_index"] = [int(only[seeds.index(int(r.seed))][int(r.target_index)]) for r in rows.itertuples()]
    return rows.drop(columns=["path_x", "path_y"])


def failed_targets(run: Path, seeds: list[int]) -> list[np.ndarray] | None:
    """Per member, the target indices its frozen test (``eval/grid.parquet``) failed; None without one."""
    path = run / "eval" / "grid.parquet"
    if not path.is_file():
        return None
    g = pd.read_parquet(path)
    return [np.sort(g[(g.seed == s) & ~g.success].target_index.to_numpy()) for s in seeds]


def describe_failures(tests: pd.DataFrame, log: StepLog, threshold: float, seeds: list[int]) -> pd.DataFrame:
    """One row per failed episode: how it ended, who acted, what the rule saw. The rule decides at every
    step from the third on, from the TD error of the step before (``ruled``: those previous deltas)."""
    out = []
    if tests.empty:
        return pd.DataFrame(out)
    for r in tests[~tests.success].itertuples():
        steps = log.steps[(int(r.target_index), seeds.index(int(r.seed)))]
        ruled = [(abs(prev["delta"]), s["habit"]) for prev, s in zip(steps, steps[1:]) if s["step"] >= 2]
        last = steps[-LAST:]
        out.append({
            "seed": int(r.seed), "target_index": int(r.target_index), "steps": len(steps),
            "final_distance": float(r.final_distance),
            "habit_share": float(np.mean([s["habit"] for s in steps])),
            "habit_share_last": float(np.mean([s["habit"] for s in last])),
            "rule_below_threshold": float(np.mean([d < threshold for d, _ in ruled])) if ruled else float("nan"),
            "rule_followed": float(np.mean([(d < threshold) == h for d, h in ruled])) if ruled else float("nan"),
            "max_abs_delta_ruled": float(max((d for d, _ in ruled), default=float("nan"))),
            "moved_last_cm": float(np.hypot(last[-1]["x"] - last[0]["x"], last[-1]["y"] - last[0]["y"])),
        })
    return pd.DataFrame(out)


def analyse(run: Path) -> dict[str, Any]:
    """The failed episodes of the run's frozen test, re-run step by step, and the counterfactual controllers
    on exactly those targets. Uses the run's ``eval/grid.parquet`` to find them (else runs every target)."""
    cfg = RunDir(run).train_config()
    seeds = list(cfg.seeds)
    only = failed_targets(run, seeds)
    log = StepLog()
    apac = frozen_test(run, log=log, only=only)
    if only is not None and len(apac) and apac.success.any():
        raise RuntimeError(f"{run}: a target that eval/grid.parquet records as failed was reached on re-running; "
                           "the test is not deterministic or the checkpoint changed since it was evaluated")
    fails = describe_failures(apac, log, cfg.agent.delta_threshold, seeds)
    key = ["seed", "target_index"]
    failed_only = [np.sort(fails[fails.seed == s].target_index.to_numpy()) for s in seeds] if len(fails) else None
    if failed_only is not None:
        for name in ("spac", "ddpg"):
            other = frozen_test(run, name, only=failed_only).set_index(key)["success"]
            fails[f"{name}_reaches"] = other.reindex(pd.MultiIndex.from_frame(fails[key])).to_numpy()
    full = pd.read_parquet(run / "eval" / "grid.parquet") if only is not None else apac
    per_seed = full.groupby("seed").agg(apac_success=("success", "mean"), targets=("success", "size"))
    per_seed["failures"] = fails.groupby("seed").size() if len(fails) else 0
    per_seed = per_seed.fillna({"failures": 0})
    # the run as OUT/<results>/<cell>: a published file names no folder of the machine that wrote it
    return {"run": f"OUT/{run.parent.name}/{run.name}", "kind": cfg.agent.kind, "task": cfg.task, "precision": cfg.precision,
            "episodes": cfg.episodes, "delta_threshold": cfg.agent.delta_threshold,
            "test_success": per_seed.reset_index().to_dict(orient="records"),
            "failures": fails.to_dict(orient="records"), "summary": summarize(fails)}


def summarize(fails: pd.DataFrame) -> dict[str, float]:
    if fails.empty:
        return {"failures": 0}
    return {"failures": int(len(fails)), "time_outs": int((fails.steps >= 30).sum()),
            "final_distance_median": float(fails.final_distance.median()),
            "final_distance_q25": float(fails.final_distance.quantile(0.25)),
            "final_distance_q75": float(fails.final_distance.quantile(0.75)),
            "habit_share_mean": float(fails.habit_share.mean()),
            "habit_share_last_mean": float(fails.habit_share_last.mean()),
            "rule_below_threshold_mean": float(fails.rule_below_threshold.mean()),
            "rule_followed_mean": float(fails.rule_followed.mean()),
            "max_abs_delta_ruled_median": float(fails.max_abs_delta_ruled.median()),
            "moved_last_cm_median": float(fails.moved_last_cm.median()),
            "spac_reaches": float(fails.spac_reaches.mean()), "ddpg_reaches": float(fails.ddpg_reaches.mean())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("runs", nargs="+", type=Path, help="APAC run directories (apac-mj train or grid cells)")
    ap.add_argument("--json", type=Path, default=None, help="write every number here")
    args = ap.parse_args()
    results = []
    for run in args.runs:
        r = analyse(run)
        results.append(r)
        print(f"\n{run} ({r['kind']}, {r['task']}, {r['episodes']} episodes, {r['precision']}; "
              f"rule: habit iff |delta| < {r['delta_threshold']} from the third step)")
        print(pd.DataFrame(r["test_success"]).to_string(index=False, float_format="%.2f"))
        for k, v in r["summary"].items():
            print(f"  {k}: {v:.3g}" if isinstance(v, float) else f"  {k}: {v}")
    if args.json is not None:
        args.json.write_text(json.dumps(results, indent=1, default=float))


if __name__ == "__main__":
    main()
