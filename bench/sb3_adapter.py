"""Stable-Baselines3 TD3 and DDPG through the Gymnasium adapter (not in CI; needs the ``sb3`` extra).

Trains each algorithm × setting × task × seed for a number of episodes through
``gym.make("apac_mj/<task>-v0", action=..., observation=...)``, then runs the
frozen deterministic policy on the test targets of the project's own ``grid``
protocol (:mod:`apac_mj.run.evaluate`): the 100 angle-grid targets inside the
plane, or, on a static-target task, the seed's own target 100 times. Prints one
row per run: training success over the last 50 episodes, the share of commands
there that moved nothing (``info["executable"]`` zero), test success and mean
final test distance; and appends it to ``--out`` (CSV; finished rows are not rerun).

    python bench/sb3_adapter.py [--algos td3 ddpg] [--settings paper sb3] \
        [--tasks static_target changing_target] [--seeds 0 1 2] [--episodes 300] \
        [--action feasible] [--observation normalized] [--out sb3.csv]

Settings: ``paper`` is the paper's DDPG recipe as far as SB3 expresses it (actor
400-300, critic [s, a] → 400 → 600, γ 0.99, replay 1000, minibatch 500, one
learning rate 1e-3, DDPG τ 0.001 / TD3 SB3's τ 0.005, Gaussian action noise σ 0.1
of the half range, the project's initial 18° of 180°); ``sb3`` is SB3's own
constructor defaults (``TD3("MlpPolicy", env, seed=s)``: no action noise, replay 1e6,
minibatch 256, 400-300 networks). One torch thread (set here): on a busy 2-core
machine torch's default 2 threads ran ~14x slower.
"""
from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

import apac_mj.suite.gym as apac_gym
from apac_mj.kinematics import angle_grid, motion_function

LAST = 50          # training episodes the success rate is taken over
NOOP_DEG = 1e-6    # an executable change below this (degrees, both joints) moved nothing
FIELDS = ("algo", "setting", "task", "seed", "action", "observation", "episodes", "train_success_last50",
          "noop_share_last50", "test_success", "test_final_distance_cm", "steps", "seconds")


class EpisodeLog(gym.Wrapper):
    """Records each finished episode's success (terminated) and the share of its commands that moved nothing."""

    def __init__(self, env: gym.Env, tag: str = "") -> None:
        super().__init__(env)
        self.tag, self.start = tag, time.perf_counter()
        self.success: list[bool] = []
        self.noop: list[float] = []
        self._noops: list[bool] = []

    def reset(self, **kwargs):
        self._noops = []
        return self.env.reset(**kwargs)

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._noops.append(bool(np.all(np.abs(info["executable"]) < NOOP_DEG)))
        if terminated or truncated:
            self.success.append(bool(terminated))
            self.noop.append(float(np.mean(self._noops)))
            if self.tag and len(self.success) % 50 == 0:
                print(f"# {self.tag}: episode {len(self.success)}, success over the last 50 "
                      f"{np.mean(self.success[-LAST:]):.2f}, {time.perf_counter() - self.start:.0f} s", flush=True)
        return obs, reward, terminated, truncated, info


def make_model(algo: str, setting: str, env: gym.Env, seed: int):
    from stable_baselines3 import DDPG, TD3
    from stable_baselines3.common.noise import NormalActionNoise

    cls = {"td3": TD3, "ddpg": DDPG}[algo]
    if setting == "sb3":
        return cls("MlpPolicy", env, seed=seed, device="cpu")
    half = (env.action_space.high - env.action_space.low) / 2
    noise = NormalActionNoise(np.zeros(2), 0.1 * half)
    return cls("MlpPolicy", env, seed=seed, device="cpu", gamma=0.99, buffer_size=1000, batch_size=500,
               learning_rate=1e-3, tau=1e-3 if algo == "ddpg" else 5e-3, action_noise=noise,
               policy_kwargs={"net_arch": {"pi": [400, 300], "qf": [400, 600]}})


def test_targets(env: apac_gym.PlanarArmEnv) -> np.ndarray:
    """The project's grid protocol: the angle-grid targets in the plane; a static target: its own, 100 times."""
    spec = env.task_spec
    if spec.target_mode == "static":
        return np.repeat(env._env.physics.target()[None], 100, axis=0)
    g = angle_grid()
    t, _ = motion_function(g[:, 0], g[:, 1], *env._env.physics.link_lengths(), spec.origin)
    w, h = spec.plane_size
    return t[(t[:, 0] >= 0) & (t[:, 0] <= w) & (t[:, 1] >= 0) & (t[:, 1] <= h)]


def frozen_test(model, env: gym.Env) -> tuple[float, float]:
    """Success rate and mean final distance of the deterministic policy on :func:`test_targets`."""
    raw = env.unwrapped
    targets = test_targets(raw)
    success, distance = [], []
    for target in targets:
        raw._env.task.set_target_override(target)
        obs, info = env.reset()
        terminated = truncated = False
        while not (terminated or truncated):
            action, _ = model.predict(obs, deterministic=True)
            obs, _, terminated, truncated, info = env.step(action)
        success.append(terminated)
        distance.append(info["distance"])
    raw._env.task.set_target_override(None)
    return float(np.mean(success)), float(np.mean(distance))


def run_one(algo: str, setting: str, task: str, seed: int, episodes: int, action: str, observation: str) -> dict:
    from stable_baselines3.common.callbacks import StopTrainingOnMaxEpisodes

    env = EpisodeLog(gym.make(apac_gym.env_id(task), action=action, observation=observation),
                     tag=f"{algo} {setting} {task} seed {seed}")
    env.reset(seed=seed)
    model = make_model(algo, setting, env, seed)
    start = time.perf_counter()
    steps = episodes * env.unwrapped.task_spec.steps_per_episode
    model.learn(total_timesteps=steps, callback=StopTrainingOnMaxEpisodes(max_episodes=episodes))
    seconds = time.perf_counter() - start
    trained, last_success, last_noop = len(env.success), env.success[-LAST:], env.noop[-LAST:]
    env.tag = ""  # no progress lines for the test episodes
    success, distance = frozen_test(model, env)
    return {"algo": algo, "setting": setting, "task": task, "seed": seed, "action": action,
            "observation": observation, "episodes": trained,
            "train_success_last50": float(np.mean(last_success)),
            "noop_share_last50": float(np.mean(last_noop)), "test_success": success,
            "test_final_distance_cm": distance, "steps": int(model.num_timesteps), "seconds": round(seconds, 1)}


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--algos", nargs="+", default=["td3", "ddpg"], choices=["td3", "ddpg"])
    p.add_argument("--settings", nargs="+", default=["paper", "sb3"], choices=["paper", "sb3"])
    p.add_argument("--tasks", nargs="+", default=["static_target", "changing_target"])
    p.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    p.add_argument("--episodes", type=int, default=300)
    p.add_argument("--action", default=apac_gym.ACTIONS[0], choices=apac_gym.ACTIONS)
    p.add_argument("--observation", default=apac_gym.OBSERVATIONS[0], choices=apac_gym.OBSERVATIONS)
    p.add_argument("--out", type=Path, default=None, help="CSV the rows are appended to (finished rows are skipped)")
    p.add_argument("--markdown", action="store_true", help="print --out's rows as docs/gym.md's table, train nothing")
    args = p.parse_args(argv)
    if args.markdown:
        print(markdown(args.out))
        return
    torch.set_num_threads(1)
    done = set()
    if args.out is not None and args.out.exists():
        with args.out.open() as f:
            done = {tuple(r[k] for k in FIELDS[:7]) for r in csv.DictReader(f)}
    print(" | ".join(FIELDS), flush=True)
    for task in args.tasks:
        for algo in args.algos:
            for setting in args.settings:
                for seed in args.seeds:
                    key = (algo, setting, task, str(seed), args.action, args.observation, str(args.episodes))
                    if key in done:
                        continue
                    row = run_one(algo, setting, task, seed, args.episodes, args.action, args.observation)
                    print(" | ".join(f"{row[k]:.3f}" if isinstance(row[k], float) else str(row[k]) for k in FIELDS),
                          flush=True)
                    if args.out is not None:
                        new = not args.out.exists()
                        with args.out.open("a", newline="") as f:
                            w = csv.DictWriter(f, fieldnames=FIELDS)
                            if new:
                                w.writeheader()
                            w.writerow(row)


def markdown(path: Path) -> str:
    """The CSV's runs as a Markdown table: one row per (task, algo, setting), per-seed values in seed order."""
    with path.open() as f:
        rows = list(csv.DictReader(f))
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["task"], r["algo"], r["setting"], r["action"], r["observation"]), []).append(r)
    out = ["| task | agent | setting | seeds | success, last 50 training episodes | commands that moved nothing "
           "(last 50) | test success (frozen) | test final distance (cm) | steps | s per run |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for (task, algo, setting, action, obs), rs in sorted(groups.items(), key=lambda kv: (kv[0][0] != "static_target",
                                                                                          kv[0])):
        rs = sorted(rs, key=lambda r: int(r["seed"]))
        def col(k: str, fmt: str = "{:.2f}") -> str:
            return ", ".join(fmt.format(float(r[k])) for r in rs)
        label = f"SB3 {algo.upper()}" + ("" if (action, obs) == (apac_gym.ACTIONS[0], apac_gym.OBSERVATIONS[0])
                                         else f" ({action}, {obs})")
        out.append(f"| {task} | {label} | {setting} | {', '.join(r['seed'] for r in rs)} | {col('train_success_last50')} "
                   f"| {col('noop_share_last50', '{:.0%}')} | {col('test_success')} | {col('test_final_distance_cm')} "
                   f"| {col('steps', '{:.0f}')} | {col('seconds', '{:.0f}')} |")
    return "\n".join(out)


if __name__ == "__main__":
    main()
