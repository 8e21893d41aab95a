"""One training update per seed: the agent's ensemble path against a plain per-member loop, in fp32 and bf16.

The agent (:class:`apac_mj.agent.agent.Agent`) keeps E members' weights as ``[E, in, out]``
tensors, computes the four losses once with batched products and lets autograd
differentiate them; ``torch.optim.Adam`` steps per-member views. The reference
("plain") is what one would write with CleanRL at hand: for each member its own
``nn.Sequential`` actor, critic (Table 2: [s, a] -> 400 -> 600 -> 1), forward and
inverse model and target networks, four ``torch.optim.Adam``, the same losses,
and a Python loop over the members. Both run the paper's sizes (minibatch 500,
replay 1000) on the same replay contents.

The rest of a training step (arbitrated proposals + OU noise, the forward
model's prediction, delta, MuJoCo servo step, replay store: the trainer's
``EpisodeLoop`` on a real ``VecEnv`` of ``changing_target``) is timed in the same
rounds, so the whole step per seed is ``rest + update`` for either path.

What it prints:

* the machine: CPU model and the flags bf16 depends on (AVX512-BF16, AMX), whether
  PyTorch sends bf16 matrix products to oneDNN here, and the oneDNN kernels one bf16
  update used (a child process run with ``ONEDNN_VERBOSE=1``; the implementation names,
  e.g. ``brg_matmul:avx512_core_amx`` = AMX, ``brg_matmul:avx512_core_bf16`` = AVX512-BF16,
  ``brg_matmul:avx512_core`` = bf16 emulated on fp32 FMA; none = ATen's own bf16 kernels),
  and what ``--precision auto`` picks here and why;
* per case (PRECISION:E), the update's and the whole step's ms per seed for both paths;
* per-round ratios measured side by side (each round times every case once, so load on a
  shared machine hits a round's cases alike), as the median and the range over rounds:
  plain/agent per case (> 1: the ensemble is faster than the loop), and every case's
  agent update against the agent's fp32 E = 1 (bf16 E = 10 / fp32 E = 1 is the issue's figure).

Times are the process's CPU time on the CPU (robust to other jobs on a shared machine: a
descheduled process accrues none) and synchronized wall time on CUDA.

    python bench/update_paths.py [--cases fp32:1 fp32:10 bf16:10] [--rounds 7] [--updates 2] [--threads 1]
                                 [--device cpu|cuda] [--json results.json] [--no-plain] [--no-rest]
                                 [--plain-precisions fp32]
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import statistics
import subprocess
import sys
import time
from collections import Counter
from typing import Callable

import torch
from torch import nn

from apac_mj.agent.agent import Agent
from apac_mj.agent.precision import cpu_info, resolve
from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.layout import Sizes
from apac_mj.run.build import make_agent
from apac_mj.suite import spec_for
from apac_mj.types import ARM, END


def filled_agent(E: int, precision: str, device: str = "cpu") -> Agent:
    """A paper-sized agent whose replay memories hold 1000 random transitions each."""
    cfg = TrainConfig(seeds=tuple(range(E)), precision=precision, device=device,
                      agent=AgentConfig(kind="ddpg", feasibility_weight=0.0))
    agent = make_agent(cfg, spec_for(cfg), Sizes())  # the paper's sizes (changing_target's)
    g = torch.Generator().manual_seed(0)
    for _ in range(agent.cfg.replay_size):
        s, s2 = torch.rand(E, 6, generator=g) * 30, torch.rand(E, 6, generator=g) * 30
        a = (torch.rand(E, 2, generator=g) - 0.5) * 360
        agent.replay.add(s, a, -torch.rand(E, generator=g), s2, torch.zeros(E), [True] * E)
    return agent


class PlainMember:
    """One member as plain modules: the same networks, losses and Adam as the agent, no ensemble."""

    def __init__(self, cfg: AgentConfig, device: str = "cpu") -> None:
        def mlp(sizes, act, out):
            layers = []
            for i in range(len(sizes) - 1):
                layers += [nn.Linear(sizes[i], sizes[i + 1]), act() if i < len(sizes) - 2 else out()]
            return nn.Sequential(*layers).to(device)
        self.cfg = cfg
        self.actor = mlp([6, *cfg.actor_hidden, 2], nn.ReLU, nn.Tanh)
        self.critic = mlp([8, *cfg.critic_hidden, 1], nn.ReLU, nn.Identity)
        self.forward_model = mlp([6, *cfg.forward_hidden, 4], nn.Sigmoid, nn.Sigmoid)
        self.inverse_model = mlp([6, *cfg.inverse_hidden, 2], nn.ReLU, nn.Tanh)
        self.target_actor, self.target_critic = mlp([6, *cfg.actor_hidden, 2], nn.ReLU, nn.Tanh), \
            mlp([8, *cfg.critic_hidden, 1], nn.ReLU, nn.Identity)
        self.target_actor.load_state_dict(self.actor.state_dict())
        self.target_critic.load_state_dict(self.critic.state_dict())
        self.opts = [torch.optim.Adam(net.parameters(), lr=lr, weight_decay=cfg.weight_decay, fused=True)
                     for net, lr in ((self.critic, cfg.critic_lr), (self.actor, cfg.actor_lr),
                                     (self.forward_model, cfg.forward_lr), (self.inverse_model, cfg.inverse_lr))]

    def update(self, b: dict[str, torch.Tensor], k: int, autocast) -> None:
        cfg = self.cfg
        x, a, x2 = (b["state"][k] - 15) / 15, b["action"][k] / 180, (b["next_state"][k] - 15) / 15
        with autocast():
            with torch.no_grad():
                q2 = self.target_critic(torch.cat([x2, self.target_actor(x2)], -1))[:, 0].float()
                y = b["reward"][k] + cfg.gamma * (1 - b["done"][k]) * q2
            critic_loss = (y - self.critic(torch.cat([x, a], -1))[:, 0].float()).pow(2).mean()
            for p in self.critic.parameters():
                p.requires_grad_(False)
            actor_loss = -self.critic(torch.cat([x, self.actor(x)], -1)).float().mean()
            for p in self.critic.parameters():
                p.requires_grad_(True)
            fwd = self.forward_model(torch.cat([x[:, ARM], a], -1)).float() * 30
            inv = self.inverse_model(torch.cat([x[:, ARM], x2[:, END]], -1)).float() * 180
            loss = critic_loss + actor_loss + (fwd - b["next_state"][k][:, ARM]).pow(2).mean() \
                + (inv - b["executed_action"][k]).pow(2).mean()
        for opt in self.opts:
            opt.zero_grad(set_to_none=True)
        loss.backward()
        for opt in self.opts:
            opt.step()
        with torch.no_grad():
            for net, tnet in ((self.actor, self.target_actor), (self.critic, self.target_critic)):
                torch._foreach_lerp_(list(tnet.parameters()), list(net.parameters()), cfg.tau)


def rest_of_step(agent: Agent) -> Callable[[], None]:
    """One training step without the update: arbitrate and act, predict, step the plant, delta, store
    (the trainer's :class:`apac_mj.run.rollout.EpisodeLoop` on a real ``VecEnv``)."""
    import numpy as np

    from apac_mj.run.build import episode_loop
    from apac_mj.run.rollout import EpisodeState
    from apac_mj.suite.vec_env import VecEnv

    E = agent.E
    loop = episode_loop(agent, VecEnv("changing_target", list(range(E))))
    active, episode = np.ones(E, dtype=bool), np.full(E, 200)
    st = EpisodeState.fresh(E, agent.device)
    loop.start(st, active)

    def step() -> None:
        if (st.step >= 29).any() or loop.env.obs.last.any():
            loop.start(st, active)
        info = loop.act(st, active, episode, explore=True)
        dev = agent.device
        agent.replay.add(torch.as_tensor(info.state, device=dev), torch.as_tensor(info.action, device=dev),
                         torch.as_tensor(info.reward, device=dev), torch.as_tensor(info.next_state, device=dev),
                         torch.as_tensor(info.terminal, dtype=torch.float32, device=dev), torch.as_tensor(active))
        loop.advance(st, info, active)
    return step


def timers(precision: str, E: int, device: str, plain: bool, rest: bool) -> dict[str, Callable[[], None]]:
    """The callables of one case: ``agent`` (one ``Agent.update``), ``plain`` (the loop), ``rest``."""
    agent = filled_agent(E, precision, device)
    out = {"agent": lambda: agent.update([True] * E)}
    if plain:
        members = [PlainMember(agent.cfg, device) for _ in range(E)]
        dev = torch.device(device).type
        autocast = (lambda: torch.autocast(dev, dtype=torch.bfloat16)) if precision == "bf16" \
            else contextlib.nullcontext

        def plain_update() -> None:
            b = agent.replay.sample(agent.cfg.batch_size, list(range(E)))
            for k, member in enumerate(members):
                member.update(b, k, autocast)
        out["plain"] = plain_update
    if rest:
        out["rest"] = rest_of_step(filled_agent(E, precision, device))
    return out


def ms_per_seed(fn: Callable[[], None], E: int, updates: int, device: str) -> float:
    """CPU time (process) per call and seed on the CPU; synchronized wall time on CUDA."""
    cuda = device.startswith("cuda")
    if cuda:
        torch.cuda.synchronize()
    clock = time.perf_counter if cuda else time.process_time
    t = clock()
    for _ in range(updates):
        fn()
    if cuda:
        torch.cuda.synchronize()
    return 1e3 * (clock() - t) / updates / E


# -- the machine --------------------------------------------------------------------------------
def onednn_kernels(E: int = 2) -> tuple[Counter, str]:
    """The oneDNN primitives one bf16 update executes here: ``Counter((kind, implementation))``, from a
    child process run with ``ONEDNN_VERBOSE=1`` (oneDNN prints one line per executed primitive to stdout)."""
    code = ("import sys, torch; torch.set_num_threads(1); sys.path.insert(0, %r); "
            "from update_paths import filled_agent; a = filled_agent(%d, 'bf16'); a.update([True] * %d)"
            % (os.path.dirname(os.path.abspath(__file__)), E, E))
    env = {**os.environ, "ONEDNN_VERBOSE": "1", "DNNL_VERBOSE": "1"}
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600)
    if proc.returncode != 0:
        return Counter(), f"the child process failed: {proc.stderr.strip().splitlines()[-1:]}"
    found = Counter()
    for line in proc.stdout.splitlines():
        parts = line.split(",")
        if not parts[0].startswith(("onednn_verbose", "dnnl_verbose")) or "exec" not in parts:
            continue
        i = parts.index("exec")
        if len(parts) > i + 3:
            found[(parts[i + 2], parts[i + 3])] += 1
    return found, ""


def machine_lines(device: str) -> list[str]:
    cpu = cpu_info()
    lines = [f"torch {torch.__version__}, {torch.get_num_threads()} thread(s), device {device}",
             f"CPU: {cpu.model}",
             "CPU flags: " + ", ".join(f"{f} {'yes' if on else 'no'}" for f, on in cpu.flags.items()),
             f"ATen CPU capability: {torch.backends.cpu.get_cpu_capability()}"]
    mkldnn_bf16 = torch.ops.mkldnn._is_mkldnn_bf16_supported()
    lines.append(f"bf16 matrix products sent to oneDNN (torch.ops.mkldnn._is_mkldnn_bf16_supported): {mkldnn_bf16}")
    kernels, problem = onednn_kernels()
    if problem:
        lines.append(f"oneDNN kernels of one bf16 update: not measured ({problem})")
    elif not kernels:
        lines.append("oneDNN kernels of one bf16 update: none (oneDNN ran no primitive; the bf16 products ran in "
                     "ATen's own kernels, bf16 emulated on fp32 arithmetic)")
    else:
        lines.append("oneDNN kernels of one bf16 update (kind: implementation x calls): "
                     + "; ".join(f"{k}: {impl} x{n}" for (k, impl), n in kernels.most_common()))
    choice = resolve("auto", device)
    lines.append(f"--precision auto here: {choice.precision} ({choice.reason})")
    if device.startswith("cuda"):
        lines.append(f"GPU: {torch.cuda.get_device_name(torch.device(device))}")
    return lines


# -- main ---------------------------------------------------------------------------------------
def spread(values: list[float]) -> str:
    return f"{statistics.median(values):6.2f} [{min(values):.2f}-{max(values):.2f}]"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--cases", nargs="+", default=["fp32:1", "fp32:10", "bf16:10"], help="PRECISION:E")
    p.add_argument("--rounds", type=int, default=7)
    p.add_argument("--updates", type=int, default=2, help="updates per timing")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--device", default="cpu")
    p.add_argument("--no-plain", action="store_true", help="skip the per-member loop (large E)")
    p.add_argument("--plain-precisions", nargs="+", default=["fp32", "bf16"],
                   help="the precisions whose cases also time the per-member loop (default both)")
    p.add_argument("--no-rest", action="store_true", help="skip the rest of the step")
    p.add_argument("--json", default=None, help="also write every round's numbers here")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    cases = [(c.split(":")[0], int(c.split(":")[1])) for c in args.cases]
    lines = machine_lines(args.device)
    print("\n".join(lines), flush=True)
    fns = {c: timers(*c, args.device, not args.no_plain and c[0] in args.plain_precisions, not args.no_rest)
           for c in cases}
    for case in fns.values():  # warm-up: the allocator and the kernels settle
        for fn in case.values():
            fn()
            fn()
    times: dict[str, list[float]] = {f"{c[0]}:{c[1]}:{path}": [] for c in cases for path in fns[c]}
    for _ in range(args.rounds):
        for c in cases:
            for path, fn in fns[c].items():
                times[f"{c[0]}:{c[1]}:{path}"].append(ms_per_seed(fn, c[1], args.updates, args.device))
    clock = "synchronized wall time" if args.device.startswith("cuda") else "process CPU time"
    print(f"\npaper sizes, minibatch 500; {args.rounds} rounds x {args.updates} updates; ms per seed ({clock}); "
          "median [min-max] over rounds")
    print(f"{'case':10s} {'update: agent':>22s} {'plain':>22s} {'rest of step':>22s}")
    for c in cases:
        key = f"{c[0]}:{c[1]}"
        cols = [spread(times[f"{key}:{path}"]) if f"{key}:{path}" in times else "-" for path in ("agent", "plain", "rest")]
        print(f"{c[0] + ' E=' + str(c[1]):10s} {cols[0]:>22s} {cols[1]:>22s} {cols[2]:>22s}")
    ratios: dict[str, list[float]] = {}
    for c in cases:
        key = f"{c[0]}:{c[1]}"
        if f"{key}:plain" in times:
            ratios[f"{c[0]} E={c[1]}: plain loop / ensemble (update)"] = [
                pl / a for pl, a in zip(times[f"{key}:plain"], times[f"{key}:agent"])]
            if f"{key}:rest" in times:
                ratios[f"{c[0]} E={c[1]}: plain loop / ensemble (whole step)"] = [
                    (pl + r) / (a + r) for pl, a, r in zip(times[f"{key}:plain"], times[f"{key}:agent"],
                                                           times[f"{key}:rest"])]
        if ("fp32", 1) in cases and c != ("fp32", 1):
            ratios[f"{c[0]} E={c[1]} / fp32 E=1 (agent update per seed)"] = [
                a / ref for a, ref in zip(times[f"{key}:agent"], times["fp32:1:agent"])]
    print("\nratios per round, median [min-max]:")
    for name, values in ratios.items():
        print(f"  {name:55s} {spread(values)}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"machine": lines, "rounds": args.rounds, "updates": args.updates, "threads": args.threads,
                       "device": args.device, "ms_per_seed": times, "ratios": ratios}, f, indent=1)


if __name__ == "__main__":
    main()
