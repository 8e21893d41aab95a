"""The agent's own planner through MuJoCo's own model: what the MPC's search reaches with a perfect model.

    python bench/planner_ceiling.py [--tasks torque_stop torque] [--episodes 100] \
        [--set horizon=2 --set iterations=8 ...] [--value zero|speed] [--out results/planner_ceiling.csv]

``bench/ceiling.py`` gives each dynamics task its ceiling with a planner of its own (CEM with a polish, 128
samples, through the true physics). The agents plan with :class:`apac_mj.agent.planner.MPCPlanner` (MPPI, 32
candidates, 4 iterations at the defaults) through a *learned* model, and close the horizon with a learned
critic. When an agent falls short of the ceiling, this bench tells which part is short: it runs the agent's
planner class itself -- its sampling, elites, temperature, warm start, anytime best, the same
``agent.mpc`` table and random streams -- with each imagined step taken on the environment's own physics
(``bench.ceiling.Model``: the task's ``before_step`` and the physics' sub-steps, from an ``MjData`` snapshot)
instead of the learned model. No networks: the habit's candidates are the zero action (no torque), and the
terminal value is zero (``--value zero``) or minus the hand's distance it would travel in one more step
(``--value speed``: the ceiling's own speed term, weight 1).

Rows: task, the ``mpc`` settings, successes of the grid targets (the 100 angle-grid targets on the plane, the
project's test), mean steps, mean final distance, seconds. The same seed gives the same numbers.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time
import types
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
import ceiling  # noqa: E402  (bench/ceiling.py: the environments, their true model, the grid targets)

from apac_mj.agent.planner import MPCPlanner  # noqa: E402
from apac_mj.rules import MPCParams  # noqa: E402
from apac_mj.types import END, TARGET, ArbitrationContext  # noqa: E402

FIELDS = ("condition", "value", "horizon", "candidates", "elites", "iterations", "habit_candidates", "temperature",
          "min_std", "max_std", "episodes", "successes", "success_pct", "mean_steps", "final_distance_cm", "seconds")


class TrueModelAgent:
    """What :class:`MPCPlanner` asks of an agent, with no networks: the zero action as the habit, no critic
    (the terminal value is set by :class:`TrueModelPlanner`), actions in tanh units scaled to the torque bound."""

    def __init__(self, model: ceiling.Model, gamma: float = 0.99) -> None:
        if not model.torque:
            raise ValueError("planner_ceiling runs on the torque tasks (the agent's tanh units are torques there)")
        self.cfg, self.bound = types.SimpleNamespace(gamma=gamma), float(model.high[0])

    def habit_u(self, s: torch.Tensor) -> torch.Tensor:
        return torch.zeros(*s.shape[:-1], 2)

    def to_action(self, u: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
        return u * self.bound

    def executable(self, a: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
        return a


class TrueModelPlanner(MPCPlanner):
    """:class:`MPCPlanner` whose imagined steps are the environment's own (the physics restored per sequence)."""

    def __init__(self, params: MPCParams, model: ceiling.Model, seed: int, value: str) -> None:
        super().__init__(params, [seed], 2, model.zone, model.stop_speed)
        self.model, self.value_kind = model, value

    def rollout(self, agent: Any, state: torch.Tensor, u: torch.Tensor | None = None,
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        H, gamma, m = self.p.horizon, agent.cfg.gamma, self.model
        if u is None:
            u = torch.zeros(state.shape[0], 1, H, 2)
        E, B = u.shape[:2]
        values, hands = torch.zeros(E, B), torch.zeros(E, B, H + 1, 2)
        torques = (u * agent.bound).double().numpy()
        for e in range(E):
            for b in range(B):
                m.restore()
                hands[e, b, 0] = state[e, END]
                v, alive = 0.0, 1.0
                for t in range(H):
                    d = m.step(torques[e, b, t])
                    v -= gamma ** t * alive * d
                    if alive and m.reached(d):
                        alive = 0.0
                    hands[e, b, t + 1] = torch.as_tensor(m.physics.end_effector())
                if self.value_kind == "speed" and alive:
                    v -= gamma ** H * float(np.hypot(*m.physics.hand_velocity())) * m.dt
                values[e, b] = v
        m.restore()
        return values, hands, u


class PlannerController(ceiling.Controller):
    """The agent's planner as a ceiling controller: plans from the current physics, executes the first action."""

    def __init__(self, params: MPCParams, seed: int, value: str) -> None:
        self.params, self.seed, self.value = params, seed, value

    def reset(self, model: ceiling.Model, rng: np.random.Generator) -> None:
        super().reset(model, rng)
        self.agent = TrueModelAgent(model)
        self.planner = TrueModelPlanner(self.params, model, int(rng.integers(2**31)), self.value)

    def act(self) -> np.ndarray:
        m = self.model
        m.save()
        ph = m.physics
        state = torch.as_tensor(np.concatenate([ph.end_effector(), ph.elbow(), ph.target(),
                                                ph.joint_velocities()]), dtype=torch.float32)[None]
        ctx = ArbitrationContext(episode=torch.zeros(1, dtype=torch.long), step=torch.zeros(1, dtype=torch.long),
                                 last_delta=torch.full((1,), float("nan")), state=state)
        proposal = self.planner.propose(self.agent, ctx, torch.full((1,), self.params.iterations))
        m.restore()
        return proposal.action[0].double().numpy()


def run_row(condition: str, params: MPCParams, value: str, episodes: int, seed: int, progress: bool) -> dict:
    env = ceiling.make_env(condition, seed)
    ctrl = PlannerController(params, seed, value)
    targets = list(ceiling.grid_targets(condition)[:episodes])
    start = time.perf_counter()
    it = enumerate(targets)
    if progress and ceiling.tqdm is not None:
        it = ceiling.tqdm(it, total=len(targets), desc=condition, unit="ep", leave=False, file=sys.stderr)
    results = [ceiling.run_episode(env, ctrl, np.random.default_rng([seed, i]), t) for i, t in it]
    ok = [r for r in results if r[0]]
    return {"condition": condition, "value": value, **{k: getattr(params, k) for k in FIELDS[2:10]},
            "episodes": len(results), "successes": len(ok), "success_pct": 100.0 * len(ok) / max(1, len(results)),
            "mean_steps": float(np.mean([r[1] for r in ok])) if ok else float("nan"),
            "final_distance_cm": float(np.mean([r[2] for r in results])),
            "seconds": time.perf_counter() - start}


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[1], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tasks", nargs="+", default=["torque_stop"], help="conditions of bench/ceiling.py (torque tasks)")
    p.add_argument("--episodes", type=int, default=100, help="grid targets per row (default 100: all)")
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="FIELD=VALUE",
                   help="an agent.mpc field (horizon, candidates, iterations, ...), repeatable; a comma-separated "
                        "VALUE gives one row per value")
    p.add_argument("--value", choices=("zero", "speed"), default="zero", help="terminal value (default zero)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=None, help="append the rows to this CSV")
    p.add_argument("--no-progress", action="store_true")
    return p.parse_args(argv)


def settings(sets: Sequence[str]) -> list[MPCParams]:
    """One MPCParams per combination of the ``--set`` values (the defaults where none is given)."""
    rows: list[dict[str, Any]] = [{}]
    for s in sets:
        key, _, text = s.partition("=")
        if key not in {f.name for f in dataclasses.fields(MPCParams)}:
            raise ValueError(f"--set {s!r}: {key!r} is not an agent.mpc field")
        kind = type(getattr(MPCParams(), key))
        rows = [{**r, key: kind(v)} for r in rows for v in text.split(",")]
    return [dataclasses.replace(MPCParams(), **r) for r in rows]


def main(argv: Sequence[str] | None = None) -> list[dict]:
    args = parse_args(argv)
    torch.set_num_threads(1)
    rows = []
    for condition in args.tasks:
        for params in settings(args.sets):
            row = run_row(condition, params, args.value, args.episodes, args.seed, not args.no_progress)
            rows.append(row)
            print(" ".join(f"{k}={row[k]:.2f}" if isinstance(row[k], float) else f"{k}={row[k]}" for k in FIELDS),
                  flush=True)
            if args.out is not None:
                ceiling.append_csv(row, args.out, FIELDS)
    return rows


if __name__ == "__main__":
    main()
