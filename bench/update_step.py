"""Time one Agent.update() per seed against the update's own matrix products alone.

For each ensemble size E and precision the script
1. builds an Agent at the paper's sizes with a full replay memory (1000),
2. records every matrix product (mm/bmm/baddbmm/addmm, forward and backward)
   that one update dispatches, with its shapes, strides and dtypes,
3. times, round-robin over all cases in several rounds (the machine is shared:
   load hits all cases alike), alternating single timings of the full update and a
   replay of exactly those matrix products on random tensors of the same
   layout ("roofline"), keeping the fastest timing of each (the least disturbed),
and prints ms per update per seed, the ratio update / matmuls-only, and each
per-seed time relative to the fp32 E=1 update.

Goals (issue 3): fp32 E=1 update <= 1.2x its matmuls; bf16 E=50 per seed
<= 0.3x fp32 E=1.

    .venv/bin/python bench/update_step.py [--sizes 1 10 50] [--precisions fp32 bf16] [--threads 1]
"""
from __future__ import annotations

import argparse
import time

import torch
from tqdm import tqdm
from torch.utils._python_dispatch import TorchDispatchMode

from apac_mj.agent import Agent
from apac_mj.config import AgentConfig

MATMULS = {"mm", "bmm", "baddbmm", "addmm"}


class _RecordMatmuls(TorchDispatchMode):
    """Record (op, [(shape, stride, dtype) of tensor args], kwargs) of matrix products."""

    def __init__(self) -> None:
        super().__init__()
        self.calls: list[tuple] = []

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        if func.overloadpacket.__name__ in MATMULS:
            meta = [(tuple(a.shape), tuple(a.stride()), a.dtype) if isinstance(a, torch.Tensor) else a
                    for a in args]
            self.calls.append((func, meta, dict(kwargs or {})))
        return func(*args, **(kwargs or {}))


def make_agent(E: int, precision: str) -> Agent:
    agent = Agent(AgentConfig(), list(range(E)), precision=precision)
    g = torch.Generator().manual_seed(0)
    for _ in range(agent.cfg.replay_size):
        s, s2 = torch.rand(E, 6, generator=g) * 30, torch.rand(E, 6, generator=g) * 30
        a = (torch.rand(E, 2, generator=g) - 0.5) * 360
        agent.replay.add(s, a, -torch.rand(E, generator=g), s2, torch.zeros(E), [True] * E)
    return agent


def matmul_replay(agent: Agent, active: list[bool]):
    """A function that runs exactly the update's matrix products on random data."""
    rec = _RecordMatmuls()
    with rec:
        agent.update(active)
    g = torch.Generator().manual_seed(1)
    calls = []
    for func, meta, kwargs in rec.calls:
        args = [torch.empty_strided(m[0], m[1], dtype=m[2]).copy_(torch.randn(m[0], generator=g).to(m[2]))
                if isinstance(m, tuple) and len(m) == 3 and isinstance(m[2], torch.dtype) else m
                for m in meta]
        calls.append((func, args, kwargs))

    def run() -> None:
        for func, args, kwargs in calls:
            func(*args, **kwargs)
    flops = sum(_flops(func, [m for m in meta if isinstance(m, tuple)]) for func, meta, _ in rec.calls)
    return run, len(rec.calls), flops


def _flops(func, meta) -> float:
    shapes = [m[0] for m in meta]
    name = func.overloadpacket.__name__
    a, b = (shapes[1], shapes[2]) if name in ("baddbmm", "addmm") else (shapes[0], shapes[1])
    batch = a[0] if len(a) == 3 else 1
    return 2.0 * batch * a[-2] * a[-1] * b[-1]


def mean_ms(fn, reps: int) -> float:
    start = time.perf_counter()
    for _ in range(reps):
        fn()
    return (time.perf_counter() - start) / reps * 1e3


class Case:
    """One (E, precision): the agent's update and the replay of its matrix products."""

    def __init__(self, E: int, precision: str, slot_s: float) -> None:
        self.E, self.precision = E, precision
        agent = make_agent(E, precision)
        active = [True] * E
        self.update = lambda: agent.update(active)  # noqa: E731
        for _ in range(3):
            self.update()
        self.matmuls, self.n, self.flops = matmul_replay(agent, active)
        self.matmuls()
        self.reps = max(1, int(slot_s / (mean_ms(self.update, 1) / 1e3)))
        self.up: list[float] = []
        self.mm: list[float] = []

    def round(self) -> None:
        """``reps`` single timings of each, alternating (the minimum is the least disturbed)."""
        for _ in range(self.reps):
            self.up.append(mean_ms(self.update, 1))
            self.mm.append(mean_ms(self.matmuls, 1))

    def row(self) -> dict:
        return {"E": self.E, "precision": self.precision, "update_ms": min(self.up) / self.E,
                "matmul_ms": min(self.mm) / self.E, "n_matmuls": self.n, "gflop_per_seed": self.flops / self.E / 1e9}


def bench(sizes: list[int], precisions: list[str], rounds: int, slot_s: float) -> list[dict]:
    """All cases timed round-robin (so machine load hits them alike); the best round is kept."""
    cases = [Case(E, p, slot_s) for p in precisions for E in sizes]
    for _ in tqdm(range(rounds), desc="rounds"):
        for case in cases:
            case.round()
    return [c.row() for c in cases]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sizes", type=int, nargs="+", default=[1, 10, 50], help="ensemble sizes E")
    p.add_argument("--precisions", nargs="+", default=["fp32", "bf16"], choices=["fp32", "bf16"])
    p.add_argument("--rounds", type=int, default=8, help="round-robin timing rounds (the fastest single timing is kept)")
    p.add_argument("--slot", type=float, default=0.3, help="seconds per timing slot (at least one update)")
    p.add_argument("--threads", type=int, default=1, help="torch threads (0: leave torch's default)")
    args = p.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    print(f"torch {torch.__version__}, threads {torch.get_num_threads()}")
    rows = bench(args.sizes, args.precisions, args.rounds, args.slot)
    ref = next((r["update_ms"] for r in rows if r["E"] == 1 and r["precision"] == "fp32"), None)
    print(f"{'prec':>5} {'E':>4} {'update ms/seed':>15} {'matmul ms/seed':>15} {'update/matmul':>14} "
          f"{'vs fp32 E=1':>12} {'#mm':>5} {'GFLOP/seed':>10}")
    for r in rows:
        rel = f"{r['update_ms'] / ref:12.3f}" if ref else f"{'-':>12}"
        print(f"{r['precision']:>5} {r['E']:>4} {r['update_ms']:15.3f} {r['matmul_ms']:15.3f} "
              f"{r['update_ms'] / r['matmul_ms']:14.3f} {rel} {r['n_matmuls']:>5} {r['gflop_per_seed']:10.3f}")
    print("goals: fp32 E=1 update/matmul <= 1.2; bf16 E=50 'vs fp32 E=1' <= 0.3")
    best = next((r for r in rows if r["E"] == max(args.sizes) and r["precision"] == "bf16"), None)
    if ref and best:
        print(f"bound: bf16 E={best['E']} matmuls alone / fp32 E=1 update = {best['matmul_ms'] / ref:.3f} "
              "(no implementation of these products can beat this ratio on this machine)")


if __name__ == "__main__":
    main()
