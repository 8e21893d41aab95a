"""What a planning decision costs, side by side in one run: the habit's decision (the actor's forward pass), the
paper's planner (one inverse-model query), the habit probe (the actor imagined through the forward model), one
MPC decision at each iteration count, and one training update (``Agent.update``), all at the paper's network
sizes for E members, on the agent's device, interleaved round by round so that machine load hits all alike.

It prints the median milliseconds of each and the ratios the project's claims rest on: a planning decision at
the defaults against one training update (issue 28: at most 1), the inverse model against the habit (the paper
assumes 3, ``apac_mj.types.PLANNING_COST``), and one MPC iteration against the habit (the graded rule's
``agent.voc.iteration_cost``).

It then measures the prices of the time model (:mod:`apac_mj.run.timing`, issue 42): one pass of each network
(actor, critic, inverse model, dynamics model) for one agent (``--pass-seeds``, default 1) at one row and at
``candidates + 2`` rows, prints each price relative to the actor's and the price of an extra row (the
``PASS_RATIOS`` the timing uses), and the timing's constants fitted with the measured ratios
(:func:`apac_mj.run.timing.calibrate`).

    .venv/bin/python bench/planning.py [--task changing_target] [--seeds 10] [--rounds 30] [--threads 1]
    .venv/bin/python bench/planning.py --passes-only --rounds 300     # the time model's prices only
"""
from __future__ import annotations

import argparse
import dataclasses
import statistics
import time
from typing import Callable

import numpy as np
import torch

import apac_mj  # noqa: F401  (sets MUJOCO_GL)
from apac_mj.agent.agent import Agent
from apac_mj.agent.planner import MPCPlanner
from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.rules import MPCParams
from apac_mj.run.build import environments, make_agent
from apac_mj.suite import spec_for
from apac_mj.types import ArbitrationContext


def setup(task: str, E: int, kind: str = "spac_mpc") -> tuple[Agent, MPCPlanner, ArbitrationContext]:
    """An agent at the paper's sizes with a full replay memory of random transitions, its planner and a context."""
    run_cfg = TrainConfig(task=task, seeds=tuple(range(E)), agent=AgentConfig(kind=kind))
    spec = spec_for(run_cfg)
    env = environments(run_cfg, spec, training=False)
    agent, cfg = make_agent(run_cfg, spec, env.sizes), run_cfg.agent
    S, A = agent.state_dim, agent.action_dim
    g = torch.Generator().manual_seed(0)
    for _ in range(cfg.batch_size // 50 + 1):
        s = torch.rand(E, S, generator=g) * 30
        a = (torch.rand(E, A, generator=g) * 2 - 1) * agent.cfg.action_scale
        agent.replay.add(s, a, -torch.rand(E, generator=g), s, torch.zeros(E), torch.ones(E, dtype=torch.bool),
                         executed_action=a)
    planner = MPCPlanner(cfg.params[MPCParams.table], agent.seeds, A, env.spec.zone_radius, env.spec.stop_speed)
    state = torch.cat([torch.rand(E, 6, generator=g) * 20 + 5, torch.zeros(E, S - 6)], 1)
    ctx = ArbitrationContext(episode=torch.full((E,), 500), step=torch.zeros(E, dtype=torch.long),
                             last_delta=torch.zeros(E), state=state, zone_radius=env.spec.zone_radius)
    return agent, planner, ctx


def fresh(ctx: ArbitrationContext) -> ArbitrationContext:
    """The context with a new state object (the same numbers), as every step of a run has: the planner's
    per-state cache of the habit's rollout does not serve it, so a timed plan pays for the habit probe."""
    return dataclasses.replace(ctx, state=ctx.state.clone())


def timings(agent: Agent, planner: MPCPlanner, ctx: ArbitrationContext, rounds: int) -> dict[str, list[float]]:
    """Seconds of each operation per round (interleaved); every planning call starts from a fresh state."""
    E, K = ctx.E, planner.max_iterations
    ops: dict[str, Callable[[ArbitrationContext], object]] = {
        "habit (actor)": lambda c: agent.actor_action(c.state),
        "inverse model": lambda c: agent.inverse_action(c.state),
        "habit probe": lambda c: planner.probe(agent, c.state),
        **{f"MPC {k} iteration{'s' if k > 1 else ''}": (lambda c, k=k: planner.propose(agent, c, torch.full((E,), k)))
           for k in range(1, K + 1)},
        "training update": lambda c: agent.update(torch.ones(E, dtype=torch.bool)),
    }
    out: dict[str, list[float]] = {name: [] for name in ops}
    for _ in range(rounds):
        for name, op in ops.items():
            c = fresh(ctx)
            t = time.perf_counter()
            op(c)
            out[name].append(time.perf_counter() - t)
    return out


def pass_timings(agent: Agent, state: torch.Tensor, rows: int, rounds: int) -> dict[str, float]:
    """Median ms of one pass of each network over ``rows`` rows per member, as the planner calls them (the model
    through ``imagine``, its inputs and outputs included), interleaved round by round."""
    E = state.shape[0]
    x = state[:, None].expand(E, rows, state.shape[1]).contiguous()
    a = torch.zeros(E, rows, agent.action_dim)
    h = agent.inputs.habit(agent.inputs.state(x))
    ops: dict[str, Callable[[], object]] = {
        "actor": lambda: agent.habit_u(x),
        "critic": lambda: agent.critic(h, agent.inputs.act(a)),
        "inverse": lambda: agent.inverse_model(agent.inputs.plan_input(agent.inputs.state(x))),
        "model": lambda: agent.imagine(x, a)}
    out: dict[str, list[float]] = {name: [] for name in ops}
    with torch.no_grad():
        for _ in range(rounds):
            for name, op in ops.items():
                t = time.perf_counter()
                op()
                out[name].append(time.perf_counter() - t)
    return {name: 1e3 * statistics.median(v[max(1, rounds // 10):]) for name, v in out.items()}


def price_ratios(one: dict[str, float], wide: dict[str, float], rows: int) -> dict[str, float]:
    """Each network's pass price relative to the actor's, and ``row``: an extra row's price relative to the
    actor's pass (the mean over the networks of ``(wide - one) / (rows - 1)``)."""
    ratios = {name: one[name] / one["actor"] for name in one}
    ratios["row"] = float(np.mean([(wide[n] - one[n]) / (rows - 1) for n in one])) / one["actor"]
    return ratios


def print_prices(task: str, E: int, rounds: int) -> None:
    """The time model's prices measured for ``E`` agents, and the timing fitted with them."""
    from apac_mj.run import timing

    agent, planner, ctx = setup(task, E, kind="apac_voc")
    rows = planner.p.candidates + 2
    one, wide = pass_timings(agent, ctx.state, 1, rounds), pass_timings(agent, ctx.state, rows, rounds)
    ratios = price_ratios(one, wide, rows)
    print(f"time model prices (apac_mj.run.timing), E = {E}, medians of {rounds} rounds:")
    for name in one:
        print(f"  {name:8s} pass {one[name]:7.4f} ms at 1 row, {wide[name]:7.4f} ms at {rows} rows "
              f"({ratios[name]:.2f} x the actor's)")
    print(f"  an extra row: {ratios['row']:.3f} x an actor pass; PASS_RATIOS in use: {timing.PASS_RATIOS}")
    fitted = timing.calibrate(ratios={k: round(v, 2) for k, v in ratios.items()})
    print("  the timing fitted with these ratios (calibrate):",
          ", ".join(f"{k} {v:.4g}" for k, v in dataclasses.asdict(fitted).items() if v is not None))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", default="changing_target", help="a task name (its sizes: torque tasks see velocities)")
    p.add_argument("--seeds", type=int, default=10, help="ensemble members E (every operation is for all of them)")
    p.add_argument("--rounds", type=int, default=30, help="interleaved rounds; medians are printed")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    p.add_argument("--pass-seeds", type=int, default=1, help="agents E for the time model's pass prices")
    p.add_argument("--passes-only", action="store_true", help="only the time model's pass prices")
    args = p.parse_args()
    if args.seeds < 1 or args.rounds < 3 or args.pass_seeds < 1:
        p.error("--seeds and --pass-seeds must be >= 1 and --rounds >= 3")
    torch.set_num_threads(args.threads)
    if args.passes_only:
        print_prices(args.task, args.pass_seeds, args.rounds)
        return
    agent, planner, ctx = setup(args.task, args.seeds)
    t = {k: statistics.median(v[1:]) for k, v in timings(agent, planner, ctx, args.rounds).items()}
    mpc = planner.p
    print(f"task {args.task}, E = {args.seeds}, torch threads {args.threads}, paper sizes, MPC defaults: horizon "
          f"{mpc.horizon}, {mpc.candidates} candidates + {mpc.habit_candidates} habit, {mpc.iterations} iterations")
    for name, sec in t.items():
        print(f"  {name:22s} {1e3 * sec:9.3f} ms  ({sec / t['habit (actor)']:7.1f} x the habit)")
    full = t[f"MPC {mpc.iterations} iterations" if mpc.iterations > 1 else "MPC 1 iteration"]
    per_iteration = np.polyfit(np.arange(1, mpc.iterations + 1),
                               [t[f"MPC {k} iteration{'s' if k > 1 else ''}"] for k in range(1, mpc.iterations + 1)],
                               1)[0] if mpc.iterations > 1 else full
    print(f"planning decision at the defaults / training update: {full / t['training update']:.2f} (goal <= 1)")
    print(f"inverse model / habit: {t['inverse model'] / t['habit (actor)']:.2f} (the paper assumes 3)")
    print(f"one MPC iteration / habit: {per_iteration / t['habit (actor)']:.1f} (agent.voc.iteration_cost)")
    print_prices(args.task, args.pass_seeds, 10 * args.rounds)


if __name__ == "__main__":
    main()
