"""What the dynamics tasks allow: success and steps of controllers that know the plant (the study's "ceiling").

    python bench/ceiling.py [--tasks torque gravity ...] [--controllers mpc greedy pd target_angles] \
        [--episodes 50] [--samples 128] [--horizon 3] [--iterations 3] [--polish 3] [--seed 0] [--targets task|grid] \
        [--out results/ceiling.csv]

Every controller acts through the task's own action interface (joint torques in N·m, or joint-angle changes in
degrees that set the compliant servos' set-point), one action per environment step (the task's control
interval), for the task's own step limit (30) and target zone; an episode succeeds when the environment ends it
inside the zone (on a task with a stop criterion, ``[target] stop_speed``: inside the zone with both joints at most
that fast; passing through the zone does not count). The controllers know the plant:

* ``mpc``: sampling model-predictive control. The cross-entropy method (``--iterations`` rounds of ``--samples``
  action sequences of ``--horizon`` steps, the best eighth refitting a Gaussian; warm-started from the previous
  plan), then ``--polish`` rounds of a shrinking 5 x 5 grid refining the best sequence's first action (without
  them the CEM is too coarse for the 0.5 cm zone, ~3 degrees of set-point, at the step that could reach it, and
  the MPC took more steps than ``greedy`` on the compliant arm). Each sequence is scored by running it on the
  environment's own physics and putting the physics back afterwards (:class:`Model`: a full ``MjData``
  snapshot, restored with ``mj_copyData``). A model step is the environment's step without the environment
  around it: the task's own ``before_step`` (so the action reaches the plant exactly as in ``env.step``:
  clipped torques, or the set-point = angles + change clipped to the joint range) and the physics' own ``step``
  (so the curl field is applied every sub-step, and the load is the model's). Cost: the hand's distance to the
  target at the end of each step, summed until the rollout ends in the zone, plus a small term for the hand's
  speed at the horizon (the distance it would travel in one more step) so that it does not arrive too fast to
  stop. On a task with a stop criterion a rollout ends only where the episode would (inside the zone *and*
  slower than ``stop_speed``, :meth:`Model.reached`), so a pass through the zone keeps paying distance for
  the steps after it, and the polish refines every action of the sequence, not only the first (arriving at rest
  asks for the accelerating and the braking step together: with the first alone the MPC reached 8 of 10
  grid targets spread over the grid, 10 of 10 with every step). The first action is executed, then it
  replans. ``dm_control``'s ``physics.copy()`` is not used: the copy is a bare ``Physics`` without the task's
  plant, so it would step without the curl field.
* ``greedy``: the one-step optimum: the action minimising the distance after one step, by a grid over the
  action box refined twice around its best cell (``--samples`` actions per grid). One step of look-ahead, as the
  paper's inverse model: on the stop task it drives the hand to the target however fast it gets there.
* ``pd`` (torque tasks): a saturated joint PD controller towards the target's joint angles (inverse
  kinematics), ``tau = clip(kp (q* - q) - kd dq/dt, +-max_torque)``, kp = 0.5 N·m/rad, kd = 0.03 N·m·s/rad
  (tuned on seed 1's targets at both torque bounds; larger kd oscillates at the 10 Hz control rate): reactive,
  no model.
* ``target_angles`` (compliant tasks): the target's joint angles as the servo set-point every step, with no
  gravity compensation.
* ``zero`` (not run by default): the zero action (no torque; hold the current angles): a negative control.

Conditions (``--tasks``): ``torque`` (changing_target_torque, |tau| <= 0.5 N·m), ``torque_half`` (the same at
0.25 N·m), ``torque_stop`` (changing_target_torque_stop: light joint damping, reached only inside the zone and
slower than its stop_speed), ``gravity`` (changing_target_compliant_gravity), ``gravity_1kg``
(changing_target_compliant_load_change with its 1 kg hand load from the first episode) and ``curl_field``
(changing_target_compliant_curl_field with the field on, b = the task's field_b, from the first episode). A task
file's name stands for its condition (``changing_target_torque`` for ``torque`` ...).

Targets: ``task`` draws ``--episodes`` targets from the task's own distribution (the environment seeded with
``--seed``: the same targets for every row); ``grid`` uses the project's test grid (the 100 angle-grid targets
on the plane, ``apac_mj.run.evaluate``; ``--episodes`` caps the count if given). The planners' sampling is
seeded per episode from ``--seed``, so the same seed gives the same numbers.

One row per (condition, controller): successes / episodes, mean steps over the successes, mean final distance
(cm) and seconds; printed as a table and written to ``--out`` (CSV).
"""
from __future__ import annotations

import argparse
import csv
import dataclasses
import math
import sys
import time
from pathlib import Path
from typing import Any, Callable, NamedTuple, Sequence

import mujoco
import numpy as np

import apac_mj  # noqa: F401  (sets MUJOCO_GL before dm_control loads)
from apac_mj import suite
from apac_mj.kinematics import angle_grid, motion_function
from apac_mj.suite.planar_arm import stopped

try:
    from tqdm.auto import tqdm
except ImportError:  # pragma: no cover - tqdm is a dependency, but the bench runs without it
    tqdm = None


class Condition(NamedTuple):
    """A row's plant: a task file with ``[plant]`` overrides."""

    task: str
    plant: dict[str, Any]
    label: str


CONDITIONS: dict[str, Condition] = {
    "torque": Condition("changing_target_torque", {}, "torque arm, |tau| <= 0.5 N·m"),
    "torque_half": Condition("changing_target_torque", {"max_torque": 0.25}, "torque arm, |tau| <= 0.25 N·m"),
    "torque_stop": Condition("changing_target_torque_stop", {},
                             "torque arm, light damping, reached only inside the zone and slower than stop_speed"),
    "gravity": Condition("changing_target_compliant_gravity", {}, "compliant arm, gravity"),
    "gravity_1kg": Condition("changing_target_compliant_load_change", {"load_change_episode": 0},
                             "compliant arm, gravity, 1 kg in the hand"),
    "curl_field": Condition("changing_target_compliant_curl_field", {"field_on_episode": 0, "field_off_episode": -1},
                            "compliant arm, curl field on"),
}
#: A task file's name stands for its condition (the torque task: the full bound).
ALIASES = {"changing_target_torque": "torque", "changing_target_torque_stop": "torque_stop",
           "changing_target_compliant_gravity": "gravity",
           "changing_target_compliant_load_change": "gravity_1kg", "changing_target_compliant_curl_field": "curl_field"}
CONTROLLERS = ("mpc", "greedy", "pd", "target_angles", "zero")
DEFAULT_CONTROLLERS = ("mpc", "greedy", "pd", "target_angles")
#: Controllers for one actuation only (the others act through either).
ONLY_FOR = {"pd": "torque", "target_angles": "compliant"}
#: Saturated PD gains on the torque arm: N·m per rad and N·m·s per rad.
PD_KP, PD_KD = 0.5, 0.03
#: MPC: weight of the hand's speed at the horizon (as the cm it would move in one more step) in the cost.
SPEED_WEIGHT = 0.3
FIELDS = ("condition", "task", "controller", "targets", "episodes", "successes", "success_pct", "mean_steps",
          "final_distance_cm", "seconds", "samples", "horizon", "iterations", "polish", "seed")


# -- the environment and its model --------------------------------------------------------------------------------
def make_env(condition: str, seed: int):
    """The condition's environment (``dm_env``), seeded with ``seed``."""
    cond = CONDITIONS[condition]
    plant = dataclasses.replace(suite.load_spec(cond.task).plant, **cond.plant)
    return suite.load("planar_arm", cond.task, task_kwargs={"random": seed, "plant": plant})


class Model:
    """The plant as the planners see it: the environment's own physics, stepped as ``env.step`` steps it
    (the task's ``before_step``, then ``physics.step`` for the plant's sub-steps), from a snapshot of the whole
    ``MjData`` taken by :meth:`save` and put back by :meth:`restore`. The task's counters are not touched."""

    def __init__(self, env) -> None:
        self.env, self.physics, self.task = env, env.physics, env.task
        spec = self.task.spec
        if self.task.growing:
            raise ValueError("the model holds the link lengths fixed: a task with growing links is not supported")
        self.torque = spec.plant.actuation == "torque"
        self.sub_steps = spec.plant.sub_steps
        self.dt = spec.plant.control_interval
        self.zone = spec.zone_radius
        #: The task's stop criterion (deg/s, each joint; None: the zone alone): a rollout ends only where the
        #: episode would, inside the zone and this slow.
        self.stop_speed = spec.stop_speed
        bound = spec.plant.max_torque
        #: The box the planners search: torques (N·m), or servo set-points (degrees) within the joint range.
        self.low, self.high = (np.full(2, -bound), np.full(2, bound)) if self.torque else \
            (np.full(2, spec.joint_range[0]), np.full(2, spec.joint_range[1]))
        self._m, self._d = self.physics.model.ptr, self.physics.data.ptr
        self._saved = mujoco.MjData(self._m)

    def save(self) -> None:
        mujoco.mj_copyData(self._saved, self._m, self._d)

    def restore(self) -> None:
        mujoco.mj_copyData(self._d, self._m, self._saved)

    def action(self, u: np.ndarray) -> np.ndarray:
        """The task's action for ``u`` now: the torques themselves, or the change from the current angles to the
        set-point ``u``."""
        return np.asarray(u, dtype=np.float64) if self.torque else u - self.physics.joint_angles()

    def step(self, u: np.ndarray) -> float:
        """One environment step of ``u`` on the physics (as ``env.step`` does it); the distance to the target."""
        self.task.before_step(self.action(u), self.physics)
        self.physics.step(self.sub_steps)
        return self.physics.distance_to_target()

    def reached(self, d: float) -> bool:
        """The episode would end here, the hand ``d`` cm from the target: inside the zone and, under the task's
        stop criterion, every joint at most ``stop_speed`` deg/s (``Reach.reached``)."""
        return d <= self.zone and (self.stop_speed is None or stopped(self.physics, self.stop_speed))

    def cost(self, seq: np.ndarray, speed_weight: float = 0.0) -> float:
        """From the saved state: the distances after each step of ``seq`` ``[H, 2]`` summed until the episode
        would end (:meth:`reached`: inside the zone, and slow enough where the task has a stop criterion), plus
        ``speed_weight`` x the hand's speed x one step if it does not. Passing through the zone too fast does
        not end a rollout on a stop task: the steps after it count."""
        self.restore()
        total = 0.0
        for u in seq:
            d = self.step(u)
            total += d
            if self.reached(d):
                return total
        if speed_weight:
            total += speed_weight * float(np.hypot(*self.physics.hand_velocity())) * self.dt
        return total


def inverse_kinematics(xy: np.ndarray, l1: float, l2: float, origin: Sequence[float]) -> np.ndarray:
    """(shoulder, elbow) angles in degrees that put the hand at ``xy``: the elbow in [0, 180] (the joint range's
    branch), the shoulder wrapped to [-90, 270); a target out of reach gets the nearest arm's angles towards it."""
    x, y = np.asarray(xy, dtype=np.float64) - np.asarray(origin, dtype=np.float64)
    c = np.clip((x * x + y * y - l1 * l1 - l2 * l2) / (2.0 * l1 * l2), -1.0, 1.0)
    beta = math.acos(c)
    alpha = math.degrees(math.atan2(y, x) - math.atan2(l2 * math.sin(beta), l1 + l2 * math.cos(beta)))
    return np.array([(alpha + 90.0) % 360.0 - 90.0, math.degrees(beta)])


def target_angles(model: Model) -> np.ndarray:
    spec, ph = model.task.spec, model.physics
    return inverse_kinematics(ph.target(), *ph.link_lengths(), spec.origin)


# -- controllers: reset at each episode, then one action per step -------------------------------------------------
class Controller:
    """Acts through the task's action interface; ``reset`` at each episode, ``act`` once per step."""

    def reset(self, model: Model, rng: np.random.Generator) -> None:
        self.model, self.rng = model, rng

    def act(self) -> np.ndarray:
        raise NotImplementedError


class Zero(Controller):
    def act(self) -> np.ndarray:
        return np.zeros(2)


class TargetAngles(Controller):
    """The target's joint angles as the set-point (compliant arm)."""

    def act(self) -> np.ndarray:
        return self.model.action(target_angles(self.model))


class PD(Controller):
    """Saturated joint PD towards the target's joint angles (torque arm)."""

    def __init__(self, kp: float = PD_KP, kd: float = PD_KD) -> None:
        self.kp, self.kd = kp, kd

    def act(self) -> np.ndarray:
        ph, m = self.model.physics, self.model
        err = np.radians(target_angles(m) - ph.joint_angles())
        tau = self.kp * err - self.kd * np.radians(ph.joint_velocities())
        return np.clip(tau, m.low, m.high)


class Greedy(Controller):
    """The action minimising the distance after one step: a grid over the box, refined around its best cell."""

    def __init__(self, samples: int, refinements: int = 2) -> None:
        self.n = max(2, int(round(math.sqrt(samples))))
        self.refinements = refinements

    def act(self) -> np.ndarray:
        m = self.model
        m.save()
        lo, hi = m.low, m.high
        best, best_cost = None, math.inf
        for _ in range(self.refinements + 1):
            axes = [np.linspace(lo[k], hi[k], self.n) for k in range(2)]
            for a in axes[0]:
                for b in axes[1]:
                    u = np.array([a, b])
                    c = m.cost(u[None])
                    if c < best_cost:
                        best, best_cost = u, c
            cell = (hi - lo) / (self.n - 1)
            lo, hi = np.maximum(best - cell, m.low), np.minimum(best + cell, m.high)
        m.restore()
        return m.action(best)


class MPC(Controller):
    """Cross-entropy-method MPC on :class:`Model`; executes the best sequence's first action, warm-starts the
    next plan from the rest of it."""

    def __init__(self, samples: int, horizon: int, iterations: int, speed_weight: float = SPEED_WEIGHT,
                 rounds: int = 3) -> None:
        self.samples, self.horizon, self.iterations, self.rounds = samples, horizon, iterations, rounds
        self.elites = max(2, samples // 8)
        self.speed_weight = speed_weight

    def reset(self, model: Model, rng: np.random.Generator) -> None:
        super().reset(model, rng)
        self.plan: np.ndarray | None = None

    def act(self) -> np.ndarray:
        m = self.model
        m.save()
        hold = np.zeros(2) if m.torque else m.physics.joint_angles()
        if self.plan is None:
            mean = np.repeat(hold[None], self.horizon, axis=0)
        else:
            mean = np.concatenate([self.plan[1:], self.plan[-1:]])
        std = np.broadcast_to((m.high - m.low) / 2.0, mean.shape).copy()
        best, best_cost = mean, math.inf
        for _ in range(self.iterations):
            seqs = np.clip(mean + std * self.rng.standard_normal((self.samples, *mean.shape)), m.low, m.high)
            seqs[0] = np.clip(mean, m.low, m.high)
            costs = np.array([m.cost(s, self.speed_weight) for s in seqs])
            order = np.argsort(costs, kind="stable")
            if costs[order[0]] < best_cost:
                best, best_cost = seqs[order[0]].copy(), costs[order[0]]
            elite = seqs[order[:self.elites]]
            mean, std = elite.mean(axis=0), elite.std(axis=0) + 1e-3 * (m.high - m.low)
        steps = self.horizon if m.stop_speed is not None else 1
        for t in range(steps):
            best, best_cost = self.polish(best, best_cost, np.maximum(2.0 * std[t], (m.high - m.low) / 16.0), t)
        m.restore()
        self.plan = best
        return m.action(best[0])

    def polish(self, best: np.ndarray, best_cost: float, width: np.ndarray, t: int = 0) -> tuple[np.ndarray, float]:
        """Refine action ``t`` of ``best`` (the rest kept): ``self.rounds`` 5 x 5 grids of +-``width`` around
        the best so far, the width halved each round: the precision the zone asks of the step that reaches it."""
        m = self.model
        for _ in range(self.rounds):
            for a in np.linspace(-1.0, 1.0, 5):
                for b in np.linspace(-1.0, 1.0, 5):
                    seq = best.copy()
                    seq[t] = np.clip(best[t] + width * (a, b), m.low, m.high)
                    c = m.cost(seq, self.speed_weight)
                    if c < best_cost:
                        best, best_cost = seq, c
            width = width / 2.0
        return best, best_cost


def make_controller(name: str, samples: int, horizon: int, iterations: int, polish: int = 3) -> Controller:
    """A fresh controller ``name`` (:data:`CONTROLLERS`)."""
    makers: dict[str, Callable[[], Controller]] = {
        "mpc": lambda: MPC(samples, horizon, iterations, rounds=polish), "greedy": lambda: Greedy(samples), "pd": PD,
        "target_angles": TargetAngles, "zero": Zero}
    if name not in makers:
        raise ValueError(f"unknown controller {name!r}; known: {', '.join(CONTROLLERS)}")
    return makers[name]()


def applies(controller: str, condition: str) -> bool:
    """Whether ``controller`` acts on the condition's actuation (pd: torque; target_angles: compliant)."""
    need = ONLY_FOR.get(controller)
    return need is None or suite.load_spec(CONDITIONS[condition].task).plant.actuation == need


# -- episodes and rows ------------------------------------------------------------------------------------------
def run_episode(env, controller: Controller, rng: np.random.Generator,
                target: np.ndarray | None = None) -> tuple[bool, int, float]:
    """One episode (``target``: override the task's draw); (success, steps, final distance in cm)."""
    env.task.set_target_override(target)
    ts = env.reset()
    controller.reset(Model(env), rng)
    while not ts.last():
        ts = env.step(controller.act())
    return ts.discount == 0.0, env.task.step_count, env.physics.distance_to_target()


def grid_targets(condition: str) -> np.ndarray:
    """The project's test grid (:func:`apac_mj.run.evaluate.evaluation_targets`): the 100 angle-grid targets
    through the motion function at the task's link lengths, those on the plane."""
    spec = suite.load_spec(CONDITIONS[condition].task)
    g = angle_grid()
    t, _ = motion_function(g[:, 0], g[:, 1], *spec.link_lengths, spec.origin)
    w, h = spec.plane_size
    return t[(t[:, 0] >= 0) & (t[:, 0] <= w) & (t[:, 1] >= 0) & (t[:, 1] <= h)]


def run_row(condition: str, controller: str, episodes: int | None = 50, samples: int = 128, horizon: int = 3,
            iterations: int = 3, seed: int = 0, targets: str = "task", progress: bool = False,
            polish: int = 3) -> dict[str, Any]:
    """Every episode of one (condition, controller); its result row (:data:`FIELDS`)."""
    if condition not in CONDITIONS:
        raise ValueError(f"unknown task {condition!r}; known: {', '.join(CONDITIONS)}")
    env = make_env(condition, seed)
    ctrl = make_controller(controller, samples, horizon, iterations, polish)
    if targets == "grid":
        fixed: list[np.ndarray | None] = list(grid_targets(condition)[:episodes])
    elif targets == "task":
        fixed = [None] * (50 if episodes is None else episodes)
    else:
        raise ValueError(f"unknown targets {targets!r}; known: task, grid")
    start = time.perf_counter()
    it = enumerate(fixed)
    if progress and tqdm is not None:
        it = tqdm(it, total=len(fixed), desc=f"{condition}/{controller}", unit="ep", leave=False, file=sys.stderr)
    results = [run_episode(env, ctrl, np.random.default_rng([seed, i]), t) for i, t in it]
    ok = [r for r in results if r[0]]
    return {"condition": condition, "task": CONDITIONS[condition].task, "controller": controller,
            "targets": targets, "episodes": len(results), "successes": len(ok),
            "success_pct": 100.0 * len(ok) / max(1, len(results)),
            "mean_steps": float(np.mean([r[1] for r in ok])) if ok else float("nan"),
            "final_distance_cm": float(np.mean([r[2] for r in results])) if results else float("nan"),
            "seconds": time.perf_counter() - start, "samples": samples, "horizon": horizon,
            "iterations": iterations, "polish": polish, "seed": seed}


def table(rows: list[dict[str, Any]]) -> str:
    """The rows as a markdown table."""
    lines = ["| task | controller | success | mean steps | final dist (cm) | s |", "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['condition']} | {r['controller']} | {r['successes']}/{r['episodes']} "
                     f"({r['success_pct']:.0f}%) | {r['mean_steps']:.2f} | {r['final_distance_cm']:.2f} | "
                     f"{r['seconds']:.0f} |")
    return "\n".join(lines)


def append_csv(row: dict[str, Any], out: Path, fields: Sequence[str]) -> None:
    """Append ``row`` to the CSV ``out`` (its header first when the file is new)."""
    new = not out.exists()
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("a", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(fields))
        if new:
            w.writeheader()
        w.writerow(row)


def write_csv(rows: list[dict[str, Any]], out: Path) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=FIELDS)
        w.writeheader()
        w.writerows(rows)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tasks", nargs="+", default=list(CONDITIONS), metavar="TASK",
                   help=f"conditions to run (default: all): {', '.join(CONDITIONS)}; a task file's name "
                        f"stands for its condition ({', '.join(f'{k} = {v}' for k, v in ALIASES.items())})")
    p.add_argument("--controllers", nargs="+", default=list(DEFAULT_CONTROLLERS), metavar="CTRL",
                   help=f"controllers (default: {' '.join(DEFAULT_CONTROLLERS)}); known: {', '.join(CONTROLLERS)}. "
                        "pd runs on torque tasks only, target_angles on compliant ones")
    p.add_argument("--episodes", type=int, default=None,
                   help="episodes per row (default 50; with --targets grid: all grid targets)")
    p.add_argument("--targets", choices=("task", "grid"), default="task",
                   help="the task's own target draws (seeded) or the project's 100-target test grid")
    p.add_argument("--samples", type=int, default=128, help="MPC: sequences per CEM round; greedy: actions per grid")
    p.add_argument("--horizon", type=int, default=3, help="MPC horizon (env steps)")
    p.add_argument("--iterations", type=int, default=3, help="MPC: CEM rounds per step")
    p.add_argument("--polish", type=int, default=3, help="MPC: refinement rounds of the first action (0: plain CEM)")
    p.add_argument("--seed", type=int, default=0, help="seeds the targets and the planners' sampling")
    p.add_argument("--out", type=Path, default=Path("results/ceiling.csv"), help="CSV written here")
    p.add_argument("--no-progress", action="store_true", help="no per-episode progress bar")
    args = p.parse_args(argv)
    args.tasks = [ALIASES.get(t, t) for t in args.tasks]
    for t in args.tasks:
        if t not in CONDITIONS:
            p.error(f"unknown task {t!r}; known: {', '.join(CONDITIONS)}")
    for c in args.controllers:
        if c not in CONTROLLERS:
            p.error(f"unknown controller {c!r}; known: {', '.join(CONTROLLERS)}")
    for name in ("samples", "horizon", "iterations"):
        if getattr(args, name) < 1:
            p.error(f"--{name} must be >= 1")
    if args.polish < 0:
        p.error("--polish must be >= 0")
    if args.episodes is not None and args.episodes < 1:
        p.error("--episodes must be >= 1")
    return args


def main(argv: list[str] | None = None) -> list[dict[str, Any]]:
    args = parse_args(argv)
    episodes = args.episodes if args.episodes is not None or args.targets == "grid" else 50
    rows = []
    for task in args.tasks:
        for ctrl in args.controllers:
            if not applies(ctrl, task):
                continue
            row = run_row(task, ctrl, episodes, args.samples, args.horizon, args.iterations, args.seed,
                          args.targets, progress=not args.no_progress, polish=args.polish)
            print(f"{task:12s} {ctrl:14s} {row['successes']}/{row['episodes']} mean steps {row['mean_steps']:.2f} "
                  f"final {row['final_distance_cm']:.2f} cm  {row['seconds']:.0f} s", flush=True)
            rows.append(row)
    print(table(rows))
    write_csv(rows, args.out)
    print(f"wrote {args.out}")
    return rows


if __name__ == "__main__":
    main()
