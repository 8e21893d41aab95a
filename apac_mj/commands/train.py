"""``apac-mj train``: train an ensemble of seeds on one task into a (resumable) run directory."""
from __future__ import annotations

import argparse
import dataclasses
import json
from typing import Any

EPILOG = """\
examples:
  apac-mj train --task changing_target --agent apac --seeds 0-9 --episodes 1000 --out runs/apac_ct
  apac-mj train --task static_target --agent spac --seeds 0,3,5 --episodes 200 --out runs/spac_st \\
                --set batch_size=128 --set ou_sigma=5
  apac-mj evaluate runs/apac_ct

The run directory gets config.json (the resolved config and git commit), metrics.parquet (one row
per seed and episode: success, steps, return, final distance, habit and planning action counts,
link lengths, target, mean losses of the four networks), checkpoints/ (periodic and final) and
DONE when finished. Files get the usual permissions (0666 minus the umask). Re-running the same
command resumes from the last checkpoint with the same numbers as an uninterrupted run, and says so;
on a finished run it does nothing and says so. A larger --episodes (everything else the same)
extends a finished run, again with the numbers of an uninterrupted run of that length; any other
difference for an existing directory is an error. A damaged checkpoints/latest.pt falls back, with a
warning, to checkpoints/previous.pt. Everything is checked before the directory is created."""


def register(sub: argparse._SubParsersAction) -> None:
    from apac_mj import kinds

    p = sub.add_parser("train", help="train an ensemble of seeds on a task (resumable run directory)",
                       description="Train DDPG, SPAC or APAC on one task, every seed as an independent member of "
                                   "one batched ensemble: motor babbling first, then the training episodes. "
                                   "Shows a progress bar (episodes of the slowest seed, success rate and habit "
                                   "share over the last 20 episodes of all seeds).",
                       epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", default="changing_target", help="task name (a file in tasks/; see apac-mj tasks)")
    p.add_argument("--agent", choices=kinds.names(), default=kinds.DEFAULT,
                   help="agent kind (apac_mj.kinds): ddpg: always the actor; spac: always the inverse model; "
                        "apac: the arbitrator decides (default); or a registered one")
    p.add_argument("--seeds", default="0", help="seeds: a range '0-9' (inclusive), a list '0,3,5' or one seed")
    p.add_argument("--episodes", type=int, default=1000, help="training episodes per seed (default 1000)")
    p.add_argument("--out", required=True, help="run directory (created; an existing one is resumed)")
    p.add_argument("--device", default="cpu", help="cpu or cuda (default cpu)")
    p.add_argument("--precision", choices=("fp32", "bf16"), default="fp32",
                   help="fp32 (reference, bit-reproducible on CPU) or bf16 autocast of the matrix products")
    p.add_argument("--checkpoint-every", type=int, default=50,
                   help="checkpoint every N episodes of the slowest seed (default 50)")
    p.add_argument("--actuation", choices=("servo", "kinematic"), default="servo",
                   help="servo: MuJoCo position servos (default); kinematic: joint angles written exactly")
    p.add_argument("--record-every", type=int, default=None, metavar="N",
                   help="record every N-th episode to RUN_DIR/recordings/*.rrd (Rerun; apac_mj.recording)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override an AgentConfig field (apac_mj/config.py), repeatable: batch_size=128, "
                        "ou_sigma=5, babbling_episodes=20, actor_hidden=64,64")
    p.add_argument("--threads", type=int, default=1,
                   help="torch CPU threads (default 1: these networks are small, and on a busy 2-core machine "
                        "2 threads measured 10-25x slower; raise it for E >= 10 on free cores)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def parse_seeds(text: str) -> tuple[int, ...]:
    """'0-9' -> 0..9, '0,3,5' -> (0, 3, 5), '4' -> (4,); raises ValueError naming the problem."""
    text = str(text).strip()
    try:
        if "-" in text and "," not in text:
            a, b = (int(x) for x in text.split("-", 1))
            if b < a:
                raise ValueError
            seeds = tuple(range(a, b + 1))
        else:
            seeds = tuple(int(x) for x in text.split(","))
    except ValueError:
        raise ValueError(f"--seeds must be a range 'a-b' (a <= b), a list '0,3,5' or one seed, got {text!r}") from None
    if any(s < 0 for s in seeds) or len(set(seeds)) != len(seeds):
        raise ValueError(f"--seeds must be distinct non-negative integers, got {text!r}")
    return seeds


def agent_overrides(items: list[str]) -> dict[str, Any]:
    """``KEY=VALUE`` strings -> AgentConfig keyword arguments (values typed like the field's default)."""
    from apac_mj.config import AgentConfig

    fields = {f.name: f for f in dataclasses.fields(AgentConfig)}
    defaults = AgentConfig()
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        key = key.strip().removeprefix("agent.")
        if not sep:
            raise ValueError(f"--set expects KEY=VALUE, got {item!r}")
        if key not in fields or key == "agent":
            raise ValueError(f"--set: unknown AgentConfig field {key!r}; known: {', '.join(sorted(set(fields) - {'agent'}))}")
        out[key] = _typed(value.strip(), getattr(defaults, key), key)
    return out


def _typed(value: str, default: Any, key: str) -> Any:
    try:
        if default is None:  # optional float fields (e.g. ou_sigma_initial)
            return None if value.lower() == "none" else float(value)
        if isinstance(default, bool):
            if value.lower() not in ("true", "false", "1", "0"):
                raise ValueError
            return value.lower() in ("true", "1")
        if isinstance(default, tuple):
            return tuple(type(default[0])(v) for v in value.strip("()[]").split(","))
        return type(default)(value)
    except ValueError:
        raise ValueError(f"--set {key}: cannot read {value!r} as {type(default).__name__}") from None


def run(args: argparse.Namespace) -> int:
    import torch

    from apac_mj.config import AgentConfig, TrainConfig
    from apac_mj.trainer import train

    if args.threads < 1:
        raise ValueError(f"--threads must be >= 1, got {args.threads}")
    torch.set_num_threads(args.threads)
    agent = AgentConfig(agent=args.agent, **agent_overrides(args.overrides))
    cfg = TrainConfig(task=args.task, seeds=parse_seeds(args.seeds), episodes=args.episodes, device=args.device,
                      precision=args.precision, checkpoint_every=args.checkpoint_every, actuation=args.actuation,
                      agent=agent)
    before = _metric_rows(args.out)
    run_dir = train(cfg, args.out, progress=not args.no_progress, record_every=args.record_every)
    _print_summary(run_dir, trained=_metric_rows(run_dir) != before)
    return 0


def _metric_rows(run_dir) -> int:
    """Rows in RUN_DIR/metrics.parquet (0 if none yet), read from the file's footer."""
    from pathlib import Path

    import pyarrow.parquet as pq

    path = Path(run_dir) / "metrics.parquet"
    return pq.ParquetFile(path).metadata.num_rows if path.is_file() else 0


def _print_summary(run_dir, trained: bool) -> None:
    import pandas as pd

    df = pd.read_parquet(run_dir / "metrics.parquet")
    tr = df[df.phase == "train"]
    last = tr[tr.episode >= tr.episode.max() - 99]
    acts = last.habit_actions.sum() + last.planning_actions.sum()
    print(json.dumps({"run_dir": str(run_dir), "status": "trained" if trained else "already finished; nothing trained",
                      "episodes": int(tr.episode.max()) + 1, "seeds": int(df.seed.nunique()),
                      "success_rate_last_100": round(float(last.success.mean()), 4),
                      "habit_share_last_100": round(float(last.habit_actions.sum() / max(1, acts)), 4)}))
    print(f"next: apac-mj evaluate {run_dir}")
