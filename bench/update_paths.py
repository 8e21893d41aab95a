"""One training update per seed: the agent's autograd path against a plain nn.Linear + torch.optim one.

The agent (:class:`apac_mj.agent.agent.Agent`) keeps E members' weights as ``[E, in, out]``
tensors, computes the four losses once with batched products and lets autograd
differentiate them; ``torch.optim.Adam`` steps per-member views. The reference
here is what one would write with CleanRL at hand: for each member its own
``nn.Sequential`` actor, critic (Table 2: [s, a] -> 400 -> 600 -> 1), forward and
inverse model and target networks, four ``torch.optim.Adam``, the same losses,
and a Python loop over the members. Both run the paper's sizes (minibatch 500,
replay 1000) on the same replay contents.

The rest of a training step (arbitrated proposals + OU noise, the forward
model's prediction, delta, MuJoCo servo step, replay store: ``rollout.agent_step``
on a real ``VecEnv`` of ``changing_target``) is timed in the same rounds, so the
whole step per seed is ``rest + update`` for either path.

Cases are timed round-robin in several rounds (the machine is shared: load hits
all alike), keeping each case's fastest round. Printed: ms per seed of the
update and of the whole step, and the ratios plain / agent measured in the
same run (> 1: the agent's path is faster).

    .venv/bin/python bench/update_paths.py [--cases fp32:1 bf16:10] [--rounds 5] [--updates 5] [--threads 1]
"""
from __future__ import annotations

import argparse
import contextlib
import time

import torch
from torch import nn

from apac_mj.agent.agent import Agent
from apac_mj.config import AgentConfig


def filled_agent(E: int, precision: str) -> Agent:
    """A paper-sized agent whose replay memories hold 1000 random transitions each."""
    agent = Agent(AgentConfig(kind="ddpg", feasibility_weight=0.0), list(range(E)), precision=precision)
    g = torch.Generator().manual_seed(0)
    for _ in range(agent.cfg.replay_size):
        s, s2 = torch.rand(E, 6, generator=g) * 30, torch.rand(E, 6, generator=g) * 30
        a = (torch.rand(E, 2, generator=g) - 0.5) * 360
        agent.replay.add(s, a, -torch.rand(E, generator=g), s2, torch.zeros(E), [True] * E)
    return agent


class PlainMember:
    """One member as plain modules: the same networks, losses and Adam as the agent, no ensemble."""

    def __init__(self, cfg: AgentConfig) -> None:
        def mlp(sizes, act, out):
            layers = []
            for i in range(len(sizes) - 1):
                layers += [nn.Linear(sizes[i], sizes[i + 1]), act() if i < len(sizes) - 2 else out()]
            return nn.Sequential(*layers)
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
            fwd = self.forward_model(torch.cat([x[:, :4], a], -1)).float() * 30
            inv = self.inverse_model(torch.cat([x[:, :4], x2[:, :2]], -1)).float() * 180
            loss = critic_loss + actor_loss + (fwd - b["next_state"][k][:, :4]).pow(2).mean() \
                + (inv - b["executed_action"][k]).pow(2).mean()
        for opt in self.opts:
            opt.zero_grad(set_to_none=True)
        loss.backward()
        for opt in self.opts:
            opt.step()
        with torch.no_grad():
            for net, tnet in ((self.actor, self.target_actor), (self.critic, self.target_critic)):
                torch._foreach_lerp_(list(tnet.parameters()), list(net.parameters()), cfg.tau)


def rest_of_step(agent: Agent):
    """One training step without the update: arbitrate and act, predict, step the plant, delta, store
    (the trainer's :class:`apac_mj.run.rollout.EpisodeLoop` on a real ``VecEnv``)."""
    import numpy as np

    from apac_mj.kinds import arbitrator_for
    from apac_mj.run.rollout import EpisodeLoop, EpisodeState
    from apac_mj.suite.vec_env import VecEnv

    E = agent.E
    loop = EpisodeLoop(agent, arbitrator_for(agent.cfg), VecEnv("changing_target", list(range(E))))
    active, episode = np.ones(E, dtype=bool), np.full(E, 200)
    st = EpisodeState.fresh(E, agent.device)
    loop.start(st, active)

    def step() -> None:
        if (st.step >= 29).any() or loop.env.obs.last.any():
            loop.start(st, active)
        info = loop.act(st, active, episode, explore=True)
        agent.replay.add(torch.as_tensor(info.state), torch.as_tensor(info.action), torch.as_tensor(info.reward),
                         torch.as_tensor(info.next_state), torch.as_tensor(info.terminal, dtype=torch.float32),
                         torch.as_tensor(active))
        loop.advance(st, info, active)
    return step


def timers(precision: str, E: int):
    """(agent update, plain update, rest of the step) callables for one case."""
    agent = filled_agent(E, precision)
    plain = [PlainMember(agent.cfg) for _ in range(E)]
    autocast = (lambda: torch.autocast("cpu", dtype=torch.bfloat16)) if precision == "bf16" else contextlib.nullcontext
    active = [True] * E

    def agent_update() -> None:
        agent.update(active)

    def plain_update() -> None:
        b = agent.replay.sample(agent.cfg.batch_size, list(range(E)))
        for k, member in enumerate(plain):
            member.update(b, k, autocast)
    return agent_update, plain_update, rest_of_step(filled_agent(E, precision))


def best_ms_per_seed(fn, E: int, updates: int) -> float:
    t = time.perf_counter()
    for _ in range(updates):
        fn()
    return 1e3 * (time.perf_counter() - t) / updates / E


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--cases", nargs="+", default=["fp32:1", "fp32:10", "bf16:10"], help="PRECISION:E")
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--updates", type=int, default=5, help="updates per timing")
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    cases = [(c.split(":")[0], int(c.split(":")[1])) for c in args.cases]
    fns = {c: timers(*c) for c in cases}
    paths = ("agent", "plain", "rest")
    best = {(c, path): float("inf") for c in cases for path in paths}
    for fn_pair in fns.values():  # warm-up
        for fn in fn_pair:
            fn()
    for _ in range(args.rounds):
        for c in cases:
            for path, fn in zip(paths, fns[c]):
                best[(c, path)] = min(best[(c, path)], best_ms_per_seed(fn, c[1], args.updates))
    ref = best[(("fp32", 1), "agent")] if ("fp32", 1) in cases else None
    print(f"torch {torch.__version__}, {args.threads} thread(s); paper sizes, minibatch 500; best of {args.rounds} rounds")
    print(f"{'case':10s} {'update ms/seed: agent':>22s} {'plain':>7s} {'plain/agent':>12s} "
          f"{'step ms/seed: agent':>20s} {'plain':>7s} {'plain/agent':>12s} {'agent step vs fp32 E=1':>23s}")
    for c in cases:
        a, pl, rest = best[(c, "agent")], best[(c, "plain")], best[(c, "rest")]
        sa, sp = a + rest, pl + rest
        rel = f"{sa / (ref + best[(('fp32', 1), 'rest')]):23.2f}" if ref else f"{'-':>23s}"
        print(f"{c[0] + ' E=' + str(c[1]):10s} {a:22.2f} {pl:7.2f} {pl / a:12.2f} {sa:20.2f} {sp:7.2f} {sp / sa:12.2f} {rel}")


if __name__ == "__main__":
    main()
