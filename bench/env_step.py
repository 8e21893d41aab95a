"""Microseconds per environment step: servo vs kinematic actuation vs raw MuJoCo.

    .venv/bin/python bench/env_step.py [--steps 2000] [--repeats 5]

All variants run side by side in one process on the same model; each figure
is the best of ``--repeats`` timed blocks, interleaved round-robin across the
variants (least disturbed by other load), and
the ratios to raw ``mujoco.mj_step`` (same number of physics sub-steps, same
model, no Python environment around it) are printed next to them.
"""
from __future__ import annotations

import argparse
import time
from typing import Callable

import mujoco
import numpy as np

import apac_mj  # noqa: F401  (sets MUJOCO_GL before dm_control loads)
from apac_mj import suite
from apac_mj.suite import planar_arm


def _actions(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-30.0, 30.0, size=(n, 2))


def _env_stepper(actuation: str) -> Callable[[np.ndarray], None]:
    env = suite.load("planar_arm", "changing_target", task_kwargs={"random": 0, "actuation": actuation})
    env.reset()

    def step(action: np.ndarray) -> None:
        if env.step(action).last():
            env.reset()

    return step


def _raw_stepper(n_sub_steps: int) -> Callable[[np.ndarray], None]:
    physics = planar_arm.make_physics()
    model, data = physics.model.ptr, physics.data.ptr
    lo, hi = np.deg2rad(planar_arm.JOINT_RANGE)

    def step(action: np.ndarray) -> None:
        data.ctrl[:] = np.clip(data.qpos[:2] + np.deg2rad(action), lo, hi)
        mujoco.mj_step(model, data, n_sub_steps)

    return step


def _time_all_us(steppers: dict[str, Callable[[np.ndarray], None]], actions: np.ndarray,
                 repeats: int) -> dict[str, float]:
    """Best time per step of each stepper; blocks interleave round-robin so load spikes hit all alike."""
    for step in steppers.values():
        for a in actions[:100]:
            step(a)  # warm-up
    best = {name: float("inf") for name in steppers}
    for _ in range(repeats):
        for name, step in steppers.items():
            t0 = time.perf_counter()
            for a in actions:
                step(a)
            best[name] = min(best[name], (time.perf_counter() - t0) / len(actions))
    return {name: t * 1e6 for name, t in best.items()}


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--steps", type=int, default=2000, help="env steps per timed block")
    p.add_argument("--repeats", type=int, default=5, help="timed blocks per variant (best is kept)")
    args = p.parse_args(argv)
    actions = _actions(args.steps)
    n_servo = planar_arm.N_SUB_STEPS
    n_kin = planar_arm.KINEMATIC_SUB_STEPS
    steppers = {
        f"raw mj_step x{n_servo}": _raw_stepper(n_servo),
        "env servo": _env_stepper("servo"),
        f"raw mj_step x{n_kin}": _raw_stepper(n_kin),
        "env kinematic": _env_stepper("kinematic"),
    }
    times = _time_all_us(steppers, actions, args.repeats)
    raw_servo, raw_kin = times[f"raw mj_step x{n_servo}"], times[f"raw mj_step x{n_kin}"]
    print(f"{'variant':24s} {'us/step':>10s} {'vs raw servo':>13s} {'vs raw kin':>11s}")
    for name, us in times.items():
        print(f"{name:24s} {us:10.1f} {us / raw_servo:13.2f} {us / raw_kin:11.2f}")
    print(f"env servo / env kinematic = {times['env servo'] / times['env kinematic']:.2f}")


if __name__ == "__main__":
    main()
