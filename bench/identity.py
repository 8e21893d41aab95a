"""Nothing moves in the numbers: a smoke grid of every agent kind on every task, run at two commits and compared
file by file (metrics.parquet, eval/*.parquet, eval/summary.json, config.json and every checkpoint tensor).

    # at the old commit (a worktree; PYTHONPATH puts its package first):
    git worktree add /tmp/base OLD && PYTHONPATH=/tmp/base python bench/identity.py run OUT/before
    python bench/identity.py run OUT/after
    python bench/identity.py compare OUT/before OUT/after
    python bench/identity.py compare OUT/before OUT/after --ignore-key executed_action --exclude compliant \
        --exclude torque     # issue 27: a new config field; the dynamics tasks are meant to move
    python bench/identity.py compare OUT/before OUT/after --ignore-key mpc --ignore-key voc \
        --ignore-key habit_seconds --ignore-key planning_seconds --ignore-key plan_iterations \
        --ignore-key mean_decision_ms --ignore-key task_spec --ignore-key task_digest
                         # issue 28: two new parameter tables, the measured decision times (new columns and
                         # a summary key); issue 29: the run's task recorded in config.json

Each cell trains 2 seeds for a few tiny episodes (babbling, planning and habit phases), in two calls (half, then
extended to the full length: the resume path), then runs the frozen tests on a few targets (on a cued task: the
forced-response test at three deadlines, ``eval/forced_response.parquet``). A cell that raises
records the error (``error.txt``); the comparison lists cells that failed on one side only. Refactors that claim
"no number changes" are checked with this; it is a bench, not a test (about 10 minutes of one core).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
import traceback
from pathlib import Path
from typing import Any, Sequence

import numpy as np

#: Tiny settings (the smoke preset's networks): the numbers mean nothing, only their equality does.
AGENT = dict(actor_hidden=(32, 32), critic_hidden=(32, 32), forward_hidden=(32, 32), inverse_hidden=(32, 32),
             batch_size=16, replay_size=200, babbling_episodes=1, planning_episodes=2, ou_sigma_anneal_episodes=4)
EPISODES, SEEDS, LIMIT = 4, (0, 1), 3
#: The deadlines (ms) of a cued task's forced-response test (short, intermediate, long).
FORCED_RESPONSE_MS = (100.0, 350.0, 900.0)


def run(out: Path, kinds: list[str] | None, tasks: list[str] | None) -> None:
    import torch

    import apac_mj
    from apac_mj import kinds as kind_registry
    from apac_mj.suite.task_spec import task_names

    torch.set_num_threads(1)
    out.mkdir(parents=True, exist_ok=True)
    for task in tasks or list(task_names()):
        for kind in kinds or list(kind_registry.names()):
            cell = out / f"{kind}__{task}"
            if (cell / "ok").exists() or (cell / "error.txt").exists():
                continue
            t0 = time.time()
            try:
                _cell(apac_mj, kind, task, cell)
                (cell / "ok").write_text("ok\n")
                status = "ok"
            except Exception:  # noqa: BLE001 - the comparison reports it
                cell.mkdir(parents=True, exist_ok=True)
                (cell / "error.txt").write_text(traceback.format_exc())
                status = "error: " + traceback.format_exc().strip().splitlines()[-1]
            print(f"{kind:22s} {task:50s} {time.time() - t0:5.1f} s  {status}", flush=True)


def _cell(apac_mj: Any, kind: str, task: str, cell: Path) -> None:
    cfg = apac_mj.TrainConfig(task=task, seeds=SEEDS, episodes=EPISODES // 2, checkpoint_every=1,
                              agent=apac_mj.AgentConfig(kind=kind, **AGENT))
    run_dir = cell / "run"
    apac_mj.train(cfg, run_dir, progress=False)
    apac_mj.train(dataclasses.replace(cfg, episodes=EPISODES), run_dir, progress=False)
    if apac_mj.suite.load_spec(task).cued:  # a cued task's frozen test is the forced-response test
        from apac_mj.run.forced_response import test_run

        (run_dir / "eval").mkdir(exist_ok=True)
        test_run(run_dir, FORCED_RESPONSE_MS, trials=5, repeats=1).to_parquet(run_dir / "eval" / "forced_response.parquet")
        return
    protocols = ["grid", "occluded"] + (["generalization"] if "train_region" in task else [])
    apac_mj.evaluate(run_dir, protocols, limit=LIMIT)


def compare(a: Path, b: Path, ignore: Sequence[str] = (), exclude: Sequence[str] = ()) -> int:
    """File by file; ``ignore``: keys (at any depth of a JSON file or checkpoint, or columns of a table) left out
    on both sides, e.g. a config field added between the commits; ``exclude``: substrings of cell names not compared (listed)."""
    global _NOT_COMPUTED
    _NOT_COMPUTED = (*_NOT_COMPUTED, *ignore)
    cells = sorted({p.name for p in a.iterdir() if p.is_dir()} | {p.name for p in b.iterdir() if p.is_dir()})
    skipped = [c for c in cells if any(x in c for x in exclude)]
    cells = [c for c in cells if c not in skipped]
    compared = differing = 0
    only = []
    for name in cells:
        ca, cb = a / name, b / name
        ok_a, ok_b = (ca / "ok").exists(), (cb / "ok").exists()
        if not (ok_a and ok_b):
            only.append(f"{name}: {'ok' if ok_a else _error(ca)} before, {'ok' if ok_b else _error(cb)} after")
            continue
        for rel in _files(ca / "run"):
            compared += 1
            problem = _differs(ca / "run" / rel, cb / "run" / rel)
            if problem:
                differing += 1
                print(f"DIFFERS {name}/{rel}: {problem}")
    print(f"{len(cells)} cells, {compared} files compared, {differing} differing"
          + (f"; {len(skipped)} cells excluded ({', '.join(exclude)})" if skipped else "")
          + (f"; keys ignored: {', '.join(ignore)}" if ignore else ""))
    for line in only:
        print("NOT COMPARED", line)
    return 1 if differing else 0


def _error(cell: Path) -> str:
    path = cell / "error.txt"
    return ("error " + path.read_text().strip().splitlines()[-1]) if path.exists() else "missing"


def _files(run_dir: Path) -> list[str]:
    keep = ("config.json", "metrics.parquet", "eval/summary.json", "checkpoints/latest.pt", "checkpoints/previous.pt")
    return [k for k in keep if (run_dir / k).exists()] + sorted(
        str(p.relative_to(run_dir)) for p in (run_dir / "eval").glob("*.parquet"))


def _differs(x: Path, y: Path) -> str | None:
    if not y.exists():
        return "missing after"
    if x.suffix == ".parquet":
        import pandas as pd

        dx, dy = (pd.read_parquet(p).drop(columns=list(_NOT_COMPUTED), errors="ignore") for p in (x, y))
        return None if dx.equals(dy) else f"tables differ ({dx.shape} vs {dy.shape})"
    if x.suffix == ".json":
        jx, jy = (_strip(json.loads(p.read_text())) for p in (x, y))
        return None if jx == jy else "json differs"
    import torch

    tx, ty = (torch.load(p, weights_only=True) for p in (x, y))
    return _tensors_differ(_strip(tx), _strip(ty), "")


#: Keys that name where and when, not what was computed: the commit, the run's own path, and the global torch
#: generator's state (torch 2.13 seeds it at random per process; nothing a run computes draws from it).
_NOT_COMPUTED = ("git_commit", "run_dir", "torch_rng")


def _strip(obj: Any) -> Any:
    """Without the keys of :data:`_NOT_COMPUTED`; a checkpoint's copy of the metric rows (parquet bytes) as its
    table's JSON without those columns."""
    if isinstance(obj, dict):
        return {k: _metric_table(v) if k == "metric_table" else _strip(v)
                for k, v in obj.items() if k not in _NOT_COMPUTED}
    return obj


def _metric_table(t: Any) -> Any:
    import io

    import pandas as pd

    if not hasattr(t, "numel") or not t.numel():
        return t
    df = pd.read_parquet(io.BytesIO(t.numpy().tobytes()))
    return df.drop(columns=list(_NOT_COMPUTED), errors="ignore").to_json()


def _tensors_differ(x: Any, y: Any, where: str) -> str | None:
    import torch

    if isinstance(x, dict) and isinstance(y, dict):
        if set(x) != set(y):
            return f"{where or '/'}: keys {sorted(set(x) ^ set(y))} on one side only"
        for k in x:
            if (p := _tensors_differ(x[k], y[k], f"{where}/{k}")) is not None:
                return p
        return None
    if isinstance(x, (list, tuple)) and isinstance(y, (list, tuple)):
        if len(x) != len(y):
            return f"{where}: lengths {len(x)} vs {len(y)}"
        for i, (u, v) in enumerate(zip(x, y)):
            if (p := _tensors_differ(u, v, f"{where}[{i}]")) is not None:
                return p
        return None
    if isinstance(x, torch.Tensor) and isinstance(y, torch.Tensor):
        same = x.shape == y.shape and x.dtype == y.dtype and torch.equal(torch.nan_to_num(x), torch.nan_to_num(y)) \
            and torch.equal(x.isnan() if x.is_floating_point() else x, y.isnan() if y.is_floating_point() else y)
        return None if same else f"{where}: tensors differ"
    if isinstance(x, float) and isinstance(y, float) and np.isnan(x) and np.isnan(y):
        return None
    return None if x == y else f"{where}: {x!r} vs {y!r}"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="run the smoke grid into OUT (resumes: finished cells are skipped)")
    r.add_argument("out", type=Path)
    r.add_argument("--kinds", nargs="*", help="agent kinds (default: every registered kind)")
    r.add_argument("--tasks", nargs="*", help="tasks (default: every task in tasks/)")
    c = sub.add_parser("compare", help="compare two smoke grids file by file; exit 1 if any file differs")
    c.add_argument("before", type=Path)
    c.add_argument("after", type=Path)
    c.add_argument("--ignore-key", action="append", default=[], metavar="KEY",
                   help="leave this key out of every JSON file and checkpoint, and this column out of every table, "
                        "on both sides (a config field or column added between the commits); repeatable")
    c.add_argument("--exclude", action="append", default=[], metavar="TEXT",
                   help="do not compare cells whose name contains TEXT (e.g. the tasks a change is meant to move); "
                        "repeatable")
    args = p.parse_args()
    if args.command == "run":
        run(args.out, args.kinds, args.tasks)
        return 0
    return compare(args.before, args.after, args.ignore_key, args.exclude)


if __name__ == "__main__":
    sys.exit(main())
