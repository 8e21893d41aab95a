"""Where one whole training step goes (act + env step + store + update), per seed.

Runs the real training loop (:func:`apac_mj.run.trainer.train`) for a few
episodes with timers wrapped around its parts, and prints, per ensemble size
and network size, milliseconds per step per seed and each part's share of the
loop's wall time. The environment's share (``VecEnv.step`` + ``reset``) is
the figure to watch (goal: <= 5% at the paper's sizes).

Parts: ``act`` (actor + inverse model proposals, OU noise), ``forward`` (the
forward model's prediction), ``td_error`` (delta for the arbitrator),
``env`` (MuJoCo steps and resets), ``store`` (replay add), ``update`` (one
``Agent.update``) and ``loop`` (everything else: arbitration, integrator,
StepInfo, metrics, Python).

    .venv/bin/python bench/train_step.py [--sizes 1 4] [--nets paper small] [--episodes 3] [--threads 1]
"""
from __future__ import annotations

import argparse
import collections
import contextlib
import shutil
import tempfile
import time
from pathlib import Path
from typing import Callable, Iterator

import torch

import apac_mj  # noqa: F401  (sets MUJOCO_GL)
from apac_mj.config import ACTUATIONS
from apac_mj.agent.agent import Agent
from apac_mj.agent.replay import EnsembleReplay
from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.agent.noise import OUNoise
from apac_mj.run.trainer import train
from apac_mj.suite.vec_env import VecEnv

PARTS = {
    "act": [(Agent, "actor_action"), (Agent, "inverse_action"), (OUNoise, "sample")],
    "forward": [(Agent, "predict_arm")],
    "td_error": [(Agent, "td_error")],
    "env": [(VecEnv, "step"), (VecEnv, "reset")],
    "store": [(EnsembleReplay, "add")],
    "update": [(Agent, "update")],
}
NETS = {"paper": {}, "small": dict(actor_hidden=(64, 64), critic_hidden=(64, 64), forward_hidden=(64, 64),
                                   inverse_hidden=(64, 64), batch_size=64)}


@contextlib.contextmanager
def timed_parts(totals: dict[str, float]) -> Iterator[None]:
    """Wrap every method in PARTS with a timer adding to ``totals[part]``."""
    saved = []

    def wrap(fn: Callable, part: str) -> Callable:
        def timed(*a, **k):
            t = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                totals[part] += time.perf_counter() - t
        return timed

    for part, methods in PARTS.items():
        for cls, name in methods:
            saved.append((cls, name, getattr(cls, name)))
            setattr(cls, name, wrap(getattr(cls, name), part))
    try:
        yield
    finally:
        for cls, name, fn in saved:
            setattr(cls, name, fn)


def measure(E: int, net: str, episodes: int, actuation: str) -> tuple[float, dict[str, float], int]:
    """(wall seconds, per-part seconds, environment steps of all seeds) of a short training run."""
    cfg = TrainConfig(task="changing_target", seeds=tuple(range(E)), episodes=episodes, checkpoint_every=10**6,
                      actuation=actuation, agent=AgentConfig(kind="apac", babbling_episodes=1, **NETS[net]))
    out = Path(tempfile.mkdtemp(prefix="train_step_"))
    totals: dict[str, float] = collections.defaultdict(float)
    steps = [0]

    def count(info, env) -> None:
        steps[0] += int(info.active.sum())

    try:
        with timed_parts(totals):
            t = time.perf_counter()
            train(cfg, out, progress=False, on_step=count, threads=torch.get_num_threads())  # main()'s --threads
            wall = time.perf_counter() - t
    finally:
        shutil.rmtree(out, ignore_errors=True)
    return wall, dict(totals), steps[0]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sizes", type=int, nargs="+", default=[1, 4], help="ensemble sizes E")
    p.add_argument("--nets", nargs="+", default=["paper", "small"], choices=sorted(NETS),
                   help="paper: 400-300 nets, batch 500; small: 64-64 nets, batch 64")
    p.add_argument("--episodes", type=int, default=2, help="training episodes per seed (after 1 babbling)")
    p.add_argument("--actuation", default="servo", choices=ACTUATIONS)
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    print(f"torch threads {args.threads}, actuation {args.actuation}, task changing_target, agent apac")
    print(f"{'nets':6s} {'E':>3s} {'ms/step/seed':>13s} " + " ".join(f"{k:>9s}" for k in [*PARTS, "loop"]))
    for net in args.nets:
        for E in args.sizes:
            wall, parts, steps = measure(E, net, args.episodes, args.actuation)
            shares = {k: parts.get(k, 0.0) / wall for k in PARTS}
            shares["loop"] = 1.0 - sum(shares.values())
            print(f"{net:6s} {E:3d} {1e3 * wall / steps:13.3f} "
                  + " ".join(f"{100 * shares[k]:8.1f}%" for k in [*PARTS, "loop"]))
    print("shares are of the training loop's wall time; env = VecEnv.step + VecEnv.reset (goal <= 5%)")


if __name__ == "__main__":
    main()
