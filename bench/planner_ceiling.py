"""The agent's own planner through MuJoCo's own model: what the MPC's search reaches with a perfect model.

    python bench/planner_ceiling.py [--tasks torque_stop torque] [--episodes 100] \
        [--set horizon=2 --set iterations=8 ...] [--value zero|speed] [--out results/planner_ceiling.csv]

``bench/ceiling.py`` gives each dynamics task its ceiling with a planner of its own (CEM with a polish, 128
samples, through the true physics). The agents plan with :class:`apac_mj.agent.planner.MPCPlanner` (MPPI, 32
candidates, 4 iterations at the defaults) through a *learned* model, and close the horizon with a learned
critic. When an agent falls short of the ceiling, this bench tells which part is short: it runs the agent's
planner class itself, unchanged -- its valuation (``MPCPlanner.rollout``: discount, imagined arrival,
terminal value), sampling, elites, temperature, warm start, anytime best, the same ``agent.mpc`` table and
random streams -- with each imagined step taken on the environment's own physics (``TrueModelAgent.imagine``:
``bench.ceiling.Model``'s step, the task's ``before_step`` and the physics' sub-steps, from an ``MjData``
snapshot per sequence) instead of the learned model. No networks: the habit's candidates are the zero action
(no torque), and the terminal value is zero (``--value zero``) or minus the hand's distance it would travel in
one more step (``--value speed``: the ceiling's own speed term, weight 1).

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

import mujoco
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
import ceiling  # noqa: E402  (bench/ceiling.py: the environments, their true model, the grid targets)

from apac_mj.agent.planner import MPCPlanner  # noqa: E402
from apac_mj.layout import Sizes, StateLayout  # noqa: E402
from apac_mj.rules import MPCParams  # noqa: E402
from apac_mj.types import ArbitrationContext  # noqa: E402

FIELDS = ("condition", "value", "horizon", "candidates", "elites", "iterations", "habit_candidates", "temperature",
          "min_std", "max_std", "episodes", "successes", "success_pct", "mean_steps", "final_distance_cm", "seconds")


class TrueModelAgent:
    """What :class:`MPCPlanner` asks of an agent, with MuJoCo's physics as its model and no networks.

    ``imagine`` steps each imagined sequence on the environment's own physics (``ceiling.Model.step``) from its
    own ``MjData`` snapshot: a batch that is not the last one returned starts every sequence from the state
    ``Model.save`` kept; each step puts the physics back where it was. The habit is the zero action (no torque),
    actions are tanh units scaled to the torque bound, and ``value`` is the terminal value: 0 (``"zero"``) or
    minus the distance the hand would travel in one more step (``"speed"``). :meth:`MPCPlanner.rollout` itself
    discounts, stops at an imagined arrival (the state's joint speeds, as the agent reads them) and adds it."""

    def __init__(self, model: ceiling.Model, value: str = "zero", gamma: float = 0.99) -> None:
        if not model.torque:
            raise ValueError("planner_ceiling runs on the torque tasks (the agent's tanh units are torques there)")
        if value not in ("zero", "speed"):
            raise ValueError(f"value must be 'zero' or 'speed', got {value!r}")
        self.cfg, self.bound = types.SimpleNamespace(gamma=gamma), float(model.high[0])
        self.model, self.value_kind = model, value
        self.layout = StateLayout(Sizes(state_dim=8, extra_scale=(1.0, 1.0), action_bound=self.bound,
                                        angle_actions=False))
        self._snapshots: list[mujoco.MjData] = []
        self._last: torch.Tensor | None = None

    def habit_u(self, s: torch.Tensor) -> torch.Tensor:
        return torch.zeros(*s.shape[:-1], 2)

    def to_action(self, u: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
        return u * self.bound

    def executable(self, a: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
        return a

    def observe(self) -> torch.Tensor:
        """The physics now as the agent's state ``[8]``: hand, elbow, target (cm), joint velocities (deg/s)."""
        ph = self.model.physics
        return torch.as_tensor(np.concatenate([ph.end_effector(), ph.elbow(), ph.target(), ph.joint_velocities()]),
                               dtype=torch.float32)

    def imagine(self, s: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        """The states ``[1, B, 8]`` after one environment step of the torques ``a`` ``[1, B, 2]`` from ``s``."""
        if s.shape[0] != 1:
            raise ValueError("TrueModelAgent plans for one member (one physics)")
        m, B = self.model, s.shape[1]
        fresh = s is not self._last
        while len(self._snapshots) < B:
            self._snapshots.append(mujoco.MjData(m._m))
        nxt = torch.empty_like(s)
        torques = a[0].double().numpy()
        for b in range(B):
            snap = self._snapshots[b]
            mujoco.mj_copyData(m._d, m._m, m._saved if fresh else snap)
            m.step(torques[b])
            mujoco.mj_copyData(snap, m._m, m._d)
            nxt[0, b] = self.observe()
        m.restore()
        self._last = nxt
        return nxt

    def value(self, s: torch.Tensor) -> torch.Tensor:
        """The terminal value of the imagined states ``s`` (the last batch :meth:`imagine` returned)."""
        if self.value_kind == "zero":
            return torch.zeros(s.shape[:-1])
        if s is not self._last:
            raise ValueError("the speed value reads the physics of the last imagined batch only")
        m, out = self.model, torch.zeros(s.shape[:-1])
        for b in range(s.shape[1]):
            mujoco.mj_copyData(m._d, m._m, self._snapshots[b])
            out[0, b] = -float(np.hypot(*m.physics.hand_velocity())) * m.dt
        m.restore()
        return out


class PlannerController(ceiling.Controller):
    """The agent's planner as a ceiling controller: plans from the current physics, executes the first action."""

    def __init__(self, params: MPCParams, seed: int, value: str) -> None:
        self.params, self.seed, self.value = params, seed, value

    def reset(self, model: ceiling.Model, rng: np.random.Generator) -> None:
        super().reset(model, rng)
        self.agent = TrueModelAgent(model, self.value)
        self.planner = MPCPlanner(self.params, [int(rng.integers(2**31))], 2, model.zone, model.stop_speed)

    def act(self) -> np.ndarray:
        m = self.model
        m.save()
        state = self.agent.observe()[None]
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
