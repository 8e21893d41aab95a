"""The README's Python example against ``apac-mj train``, side by side: the library must train as fast as the CLI.

Each round trains the same config twice, each in a fresh Python process as a user would start it (no
``OMP_NUM_THREADS`` or ``MKL_NUM_THREADS`` in its environment, so torch starts at its own default of one thread
per core): once through the CLI (``apac-mj train --task ... --seeds ... --episodes ... --set batch_size=...``)
and once through the library as the README shows it (``apac_mj.train(apac_mj.TrainConfig(...), out)``), the
two alternating so that both see the same load. It prints each process's wall time, the median of each and the
ratio library/CLI, and checks that the two runs' metrics are the same (every column but the measured seconds).
Issue 29 item 1: on the landed code the ratio was ~14 (329.6 s against 23.9 s at 30 episodes; this bench's
defaults: 100.7 s against 17.9 s, ratio 5.6, imports included) because the CLI pinned torch to one thread and
the library did not; ``apac_mj.util.threads`` now decides for both (ratio 0.95 over 2 rounds, 1.00 at 30 episodes).

    .venv/bin/python bench/threads.py [--seeds 2] [--episodes 10] [--batch 64] [--rounds 1] [--threads N]
    PYTHONPATH=/tmp/old .venv/bin/python bench/threads.py     # another commit: git archive HEAD apac_mj tasks assets
                                                              # pyproject.toml | tar -x -C /tmp/old

``--threads N`` passes ``--threads N`` to the CLI and ``threads=N`` to the library (both sides the same).
The ratio is a measurement of this machine under its load at the time; it is printed with both.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: Environment variables that would fix torch's thread count from outside: removed, as a new user has none.
THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")
#: The measured columns of metrics.parquet, which differ from run to run.
MEASURED = ("habit_seconds", "planning_seconds")

LIBRARY = """\
import sys, apac_mj
cfg = apac_mj.TrainConfig(task={task!r}, seeds={seeds!r}, episodes={episodes},
                          agent=apac_mj.AgentConfig(kind={agent!r}, batch_size={batch}))
apac_mj.train(cfg, sys.argv[1], progress=False{threads})
"""
CLI = "import sys; from apac_mj.cli import main; sys.exit(main(sys.argv[1:]))"


def environment() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in THREAD_VARIABLES}
    env.setdefault("MUJOCO_GL", "egl")
    return env


def timed(argv: list[str], cwd: Path) -> float:
    """Wall seconds of one fresh process in ``cwd`` (its imports included, as a user waits for them)."""
    t = time.perf_counter()
    done = subprocess.run(argv, env=environment(), cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                          text=True)
    wall = time.perf_counter() - t
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(argv[:3])} ... failed ({done.returncode}):\n{done.stderr[-3000:]}")
    return wall


def same_metrics(a: Path, b: Path) -> bool:
    import pandas as pd

    x, y = (pd.read_parquet(p / "metrics.parquet") for p in (a, b))
    x, y = (d.drop(columns=[c for c in MEASURED if c in d.columns]) for d in (x, y))
    return list(x.columns) == list(y.columns) and x.equals(y)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", default="changing_target")
    p.add_argument("--agent", default="apac")
    p.add_argument("--seeds", type=int, default=2, help="seeds 0..N-1 (default 2)")
    p.add_argument("--episodes", type=int, default=10, help="training episodes per seed (default 10)")
    p.add_argument("--batch", type=int, default=64, help="minibatch (default 64, the README's quick look)")
    p.add_argument("--rounds", type=int, default=1, help="CLI/library pairs, alternating (default 1)")
    p.add_argument("--threads", type=int, default=None, help="ask both for this many torch threads "
                   "(default: ask for nothing, as the README does)")
    args = p.parse_args()

    seeds = tuple(range(args.seeds))
    root = Path(tempfile.mkdtemp(prefix="bench_threads_"))
    cli_args = ["train", "--task", args.task, "--agent", args.agent, "--seeds", f"0-{args.seeds - 1}",
                "--episodes", str(args.episodes), "--set", f"batch_size={args.batch}", "--no-progress"]
    if args.threads is not None:
        cli_args += ["--threads", str(args.threads)]
    library = LIBRARY.format(task=args.task, seeds=seeds, episodes=args.episodes, agent=args.agent,
                             batch=args.batch, threads="" if args.threads is None else f", threads={args.threads}")
    probe = subprocess.run([sys.executable, "-c", "import torch, apac_mj; print(torch.get_num_threads(), "
                            "apac_mj.__file__)"], env=environment(), cwd=root, capture_output=True,
                           text=True).stdout.split()
    print(f"{args.agent} on {args.task}, {args.seeds} seeds x {args.episodes} episodes, batch {args.batch}; "
          f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f} at the start; torch's default in a fresh "
          f"process: {probe[0]} thread(s); package {Path(probe[1]).parent}")
    cli_s, lib_s, same = [], [], []
    try:
        for r in range(args.rounds):
            a, b = root / f"cli{r}", root / f"lib{r}"
            cli_s.append(timed([sys.executable, "-c", CLI, *cli_args, "--out", str(a)], root))
            lib_s.append(timed([sys.executable, "-c", library, str(b)], root))
            same.append(same_metrics(a, b))
            print(f"round {r + 1}: apac-mj train {cli_s[-1]:.1f} s, apac_mj.train {lib_s[-1]:.1f} s, "
                  f"ratio {lib_s[-1] / cli_s[-1]:.2f}; metrics {'identical' if same[-1] else 'DIFFER'}")
    finally:
        shutil.rmtree(root, ignore_errors=True)
    cli, lib = statistics.median(cli_s), statistics.median(lib_s)
    print(f"median: apac-mj train {cli:.1f} s, apac_mj.train {lib:.1f} s; ratio library/CLI {lib / cli:.2f}; "
          f"load average {os.getloadavg()[0]:.1f} at the end")
    print(json.dumps({"cli_s": cli_s, "library_s": lib_s, "ratio": lib / cli, "metrics_identical": all(same)}))


if __name__ == "__main__":
    main()
