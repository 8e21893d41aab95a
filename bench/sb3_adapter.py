"""Stable-Baselines3 TD3, DDPG and SAC through the Gymnasium adapter (not in CI; needs the ``sb3`` extra).

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
minibatch 256, 400-300 networks; ``SAC("MlpPolicy", env, seed=s)``: 256-256 networks, learning rate
3e-4, entropy coefficient learned, replay 1e6, minibatch 256). SAC has only the ``sb3`` setting. One
torch thread (set here): on a busy 2-core machine torch's default 2 threads ran ~14x slower.

A step budget instead of episodes (a second CSV layout, :data:`STEP_FIELDS`: one row per run and
eval point; an ``--out`` file holds one layout or the other, its header says which):

    python bench/sb3_adapter.py --algos sac td3 --settings sb3 --tasks changing_target_torque \
        --seeds 0 1 2 --steps 40000 --eval-at 2000,4000,6000,10000,20000,40000 --out sb3_dynamics.csv

trains each run for ``--steps`` environment steps (``--steps`` is always an eval point) and, when
the step count reaches each ``--eval-at`` value, pauses (an SB3 callback, :func:`eval_at_steps`) and runs
:func:`frozen_test` with the deterministic policy on a *separate* environment instance, so the
training episodes (their targets, the episode counter, the current episode) are not disturbed. The
pause comes after that step's gradient update: the tested policy is the one after N environment
steps and their updates. The test environment is rebuilt (``reset(seed=seed)``) before every eval
point, so its episode counter starts at 0 each time: on a task whose plant changes with the episode
counter (``changing_target_compliant_curl_field``: the curl field on in training episodes 110-129;
``changing_target_compliant_load_change``: the hand load from an episode on) the grid test runs on
the plant *before any change* (the 100-odd test episodes are the counter's episodes 0-100), whatever
the training environment is in; each test episode checks that its load and field are episode 0's
(else an error). The row records the training environment's load and field at the pause
(``train_load_kg_now``, ``train_field_b_now``). ``seconds`` is the training wall time so far (the
tests excluded), ``test_seconds`` the eval's own. A run whose eval rows are all in ``--out`` is
skipped; a partly written one is trained again from the start (seeded) up to its last missing eval
point and only the missing rows are written. ``velocity_divisor``: what the observed joint
velocities were divided by (deg/s; ``observation="normalized"``: the plant's ``velocity_scale``,
``"cm"``: 1, raw deg/s; empty on a task that does not observe them).
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
#: The step-budget layout (``--steps``): one row per run and eval point; the first 8 fields are the key.
STEP_FIELDS = ("algo", "setting", "task", "seed", "action", "observation", "budget_steps", "eval_at",
               "velocity_divisor", "episodes", "train_success_last50", "noop_share_last50", "test_success",
               "test_final_distance_cm", "steps", "seconds", "test_seconds", "train_load_kg_now",
               "train_field_b_now")
ALGOS = ("td3", "ddpg", "sac")


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
    from stable_baselines3 import DDPG, SAC, TD3
    from stable_baselines3.common.noise import NormalActionNoise

    cls = {"td3": TD3, "ddpg": DDPG, "sac": SAC}[algo]
    if setting == "sb3":
        return cls("MlpPolicy", env, seed=seed, device="cpu")
    if algo == "sac":
        raise ValueError("SAC has only the 'sb3' setting (the paper's recipe is DDPG's)")
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


def frozen_test(model, env: gym.Env, initial_plant: bool = False) -> tuple[float, float]:
    """Success rate and mean final distance of the deterministic policy on :func:`test_targets`.

    ``initial_plant``: check that every test episode runs on episode 0's hand load and curl field
    (RuntimeError otherwise); the step-budget runs pass a freshly rebuilt test environment."""
    raw = env.unwrapped
    targets = test_targets(raw)
    plant = raw.task_spec.plant
    success, distance = [], []
    for target in targets:
        raw._env.task.set_target_override(target)
        obs, info = env.reset()
        physics = raw._env.physics
        if initial_plant and (physics.load != plant.load_at(0) or physics.field_b != plant.field_at(0)):
            raise RuntimeError(f"test episode {raw._env.task.episode} runs on load {physics.load} kg, field "
                               f"{physics.field_b} N·s/m, not episode 0's ({plant.load_at(0)}, {plant.field_at(0)})")
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


def eval_at_steps(eval_at: list[int], test_env: gym.Env, seed: int, train_log: EpisodeLog, base_row: dict,
                  on_row):
    """The SB3 callback that pauses training at the step counts ``eval_at`` and frozen-tests the policy.

    The test is run on ``test_env`` (a separate instance), rebuilt with ``reset(seed=seed)`` before each
    eval point so its episode counter starts at 0 (the plant before any scheduled change). The pause
    happens at the first rollout start after the step count is reached (after that step's gradient
    update), or at the end of training. ``on_row(row)`` gets each eval point's row."""

    from stable_baselines3.common.callbacks import BaseCallback  # lazily: the sb3 extra

    class EvalAtSteps(BaseCallback):
        def __init__(self, eval_at, test_env, seed, train_log, base_row, on_row):
            super().__init__()
            self.pending = sorted(eval_at)
            self.test_env, self.seed, self.train_log = test_env, seed, train_log
            self.base_row, self.on_row = base_row, on_row
            self.test_time = 0.0
            self.start = time.perf_counter()
            self.due: int | None = None

        def _on_training_start(self) -> None:
            self.start = time.perf_counter()

        def _on_step(self) -> bool:
            if self.pending and self.num_timesteps >= self.pending[0] and self.due is None:
                self.due = self.pending[0]
            return True

        def _on_rollout_start(self) -> None:
            self._evaluate()

        def _on_training_end(self) -> None:
            self._evaluate()

        def _evaluate(self) -> None:
            if self.due is None:
                return
            at, self.due = self.due, None
            self.pending.pop(0)
            train_seconds = time.perf_counter() - self.start - self.test_time
            physics = self.train_log.unwrapped._env.physics
            t0 = time.perf_counter()
            self.test_env.reset(seed=self.seed)  # rebuilt: episode counter 0, the initial plant
            success, distance = frozen_test(self.model, self.test_env, initial_plant=True)
            test_seconds = time.perf_counter() - t0
            self.test_time += test_seconds
            log = self.train_log
            row = self.base_row | {
                "eval_at": at, "episodes": len(log.success),
                "train_success_last50": float(np.mean(log.success[-LAST:])) if log.success else float("nan"),
                "noop_share_last50": float(np.mean(log.noop[-LAST:])) if log.noop else float("nan"),
                "test_success": success, "test_final_distance_cm": distance,
                "steps": int(self.num_timesteps), "seconds": round(train_seconds, 1),
                "test_seconds": round(test_seconds, 1), "train_load_kg_now": float(physics.load),
                "train_field_b_now": float(physics.field_b)}
            self.on_row(row)

    return EvalAtSteps(eval_at, test_env, seed, train_log, base_row, on_row)


def run_steps(algo: str, setting: str, task: str, seed: int, budget: int, eval_at: list[int], action: str,
              observation: str, on_row) -> None:
    """Train one run for ``max(eval_at)`` steps (of a ``budget``-step run), frozen-testing at each ``eval_at``."""
    env = EpisodeLog(gym.make(apac_gym.env_id(task), action=action, observation=observation),
                     tag=f"{algo} {setting} {task} seed {seed}")
    env.reset(seed=seed)
    test_env = gym.make(apac_gym.env_id(task), action=action, observation=observation)
    raw = env.unwrapped
    divisor = raw._velocity_scale if raw.task_spec.plant.observe_velocities else ""
    base = {"algo": algo, "setting": setting, "task": task, "seed": seed, "action": action,
            "observation": observation, "budget_steps": budget, "velocity_divisor": divisor}
    model = make_model(algo, setting, env, seed)
    callback = eval_at_steps(eval_at, test_env, seed, env, base, on_row)
    model.learn(total_timesteps=max(eval_at), callback=callback)
    test_env.close()
    env.close()


def _fmt(v) -> str:
    return f"{v:.3f}" if isinstance(v, float) else str(v)


def main_steps(args) -> None:
    """The step-budget mode (``--steps``): one CSV row per run and eval point."""
    eval_at = sorted({int(x) for x in args.eval_at.split(",") if x.strip()} | {args.steps}) if args.eval_at \
        else [args.steps]
    if eval_at[0] <= 0 or eval_at[-1] > args.steps:
        raise SystemExit(f"--eval-at must lie in 1..--steps ({args.steps}), got {args.eval_at}")
    done = finished_rows(args.out, STEP_FIELDS, 8, "step-budget")
    print(" | ".join(STEP_FIELDS), flush=True)
    written: list[dict] = []

    def write(row: dict) -> None:
        key = tuple(str(row[k]) for k in STEP_FIELDS[:8])
        if key in done:
            return
        print(" | ".join(_fmt(row[k]) for k in STEP_FIELDS), flush=True)
        written.append(row)
        if args.out is not None:
            new = not args.out.exists()
            args.out.parent.mkdir(parents=True, exist_ok=True)
            with args.out.open("a", newline="") as f:
                w = csv.DictWriter(f, fieldnames=STEP_FIELDS)
                if new:
                    w.writeheader()
                w.writerow(row)

    for task in args.tasks:
        for algo in args.algos:
            for setting in args.settings:
                for seed in args.seeds:
                    key = (algo, setting, task, str(seed), args.action, args.observation, str(args.steps))
                    missing = [a for a in eval_at if key + (str(a),) not in done]
                    if not missing:
                        continue
                    t0 = time.perf_counter()
                    print(f"# {algo} {setting} {task} seed {seed}: {args.steps} steps, eval at {eval_at} "
                          f"(missing {missing})", flush=True)
                    run_steps(algo, setting, task, seed, args.steps, missing, args.action, args.observation, write)
                    print(f"# {algo} {setting} {task} seed {seed}: done in {time.perf_counter() - t0:.0f} s wall",
                          flush=True)
    if args.out is not None and written:
        print(markdown(args.out, only=written))


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--algos", nargs="+", default=["td3", "ddpg"], choices=ALGOS,
                   help="sac: the 'sb3' setting only")
    p.add_argument("--settings", nargs="+", default=["paper", "sb3"], choices=["paper", "sb3"])
    p.add_argument("--tasks", nargs="+", default=["static_target", "changing_target"])
    p.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    p.add_argument("--episodes", type=int, default=300)
    p.add_argument("--steps", type=int, default=None,
                   help="a step budget per run instead of --episodes (the step-budget CSV layout)")
    p.add_argument("--eval-at", default=None,
                   help="with --steps: comma-separated step counts at which the frozen policy is tested "
                        "(--steps is always one)")
    p.add_argument("--action", default=apac_gym.ACTIONS[0], choices=apac_gym.ACTIONS)
    p.add_argument("--observation", default=apac_gym.OBSERVATIONS[0], choices=apac_gym.OBSERVATIONS)
    p.add_argument("--out", type=Path, default=None, help="CSV the rows are appended to (finished rows are skipped)")
    p.add_argument("--markdown", action="store_true", help="print --out's rows as docs/gym.md's table, train nothing")
    args = p.parse_args(argv)
    if args.markdown:
        print(markdown(args.out))
        return
    if "sac" in args.algos and "paper" in args.settings:
        p.error("SAC has only the 'sb3' setting: pass --settings sb3")
    if args.eval_at is not None and args.steps is None:
        p.error("--eval-at needs --steps")
    torch.set_num_threads(1)
    if args.steps is not None:
        main_steps(args)
        return
    done = finished_rows(args.out, FIELDS, 7, "episode")
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


def finished_rows(out: Path | None, fields: tuple[str, ...], key: int, mode: str) -> set[tuple[str, ...]]:
    """The keys (the first ``key`` fields) of the rows ``out`` already holds; a CSV of another layout is refused."""
    if out is None or not out.exists():
        return set()
    with out.open() as f:
        reader = csv.DictReader(f)
        if tuple(reader.fieldnames or ()) != fields:
            raise SystemExit(f"{out} has another layout (fields {reader.fieldnames}); the {mode} mode writes "
                             f"{fields}: use another --out")
        return {tuple(r[k] for k in fields[:key]) for r in reader}


def markdown(path: Path, only: list[dict] | None = None) -> str:
    """The CSV's runs as a Markdown table: one row per (task, algo, setting), per-seed values in seed order
    (the step-budget layout: :func:`markdown_steps`; ``only``: just these rows of it)."""
    with path.open() as f:
        reader = csv.DictReader(f)
        rows = list(reader)
    if tuple(reader.fieldnames or ()) == STEP_FIELDS:
        if only is not None:
            keys = {tuple(str(r[k]) for k in STEP_FIELDS[:8]) for r in only}
            rows = [r for r in rows if tuple(r[k] for k in STEP_FIELDS[:8]) in keys]
        return markdown_steps(rows)
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


def markdown_steps(rows: list[dict]) -> str:
    """Step-budget rows as a Markdown table: one row per (task, algo, setting, action, observation, budget,
    eval point), per-seed values in seed order and their mean."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        key = (r["task"], r["algo"], r["setting"], r["action"], r["observation"], r["velocity_divisor"],
               int(r["budget_steps"]), int(r["eval_at"]))
        groups.setdefault(key, []).append(r)
    out = ["| task | agent | setting | seeds | steps | test success (frozen, per seed) | mean | test final distance "
           "(cm) | mean | training success, last 50 episodes | training episodes | s of training so far |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for (task, algo, setting, action, obs, divisor, budget, at), rs in sorted(groups.items()):
        rs = sorted(rs, key=lambda r: int(r["seed"]))

        def col(k: str, fmt: str = "{:.2f}") -> str:
            return ", ".join(fmt.format(float(r[k])) for r in rs)

        def mean(k: str) -> str:
            return f"{np.mean([float(r[k]) for r in rs]):.2f}"

        extra = [v for v, default in ((action, apac_gym.ACTIONS[0]), (obs, apac_gym.OBSERVATIONS[0])) if v != default]
        if divisor:
            extra.append("velocities in deg/s" if float(divisor) == 1.0 else f"velocities / {float(divisor):g} deg/s")
        label = f"SB3 {algo.upper()}" + (f" ({', '.join(extra)})" if extra else "")
        out.append(f"| {task} | {label} | {setting} | {', '.join(r['seed'] for r in rs)} | {at} of {budget} "
                   f"| {col('test_success')} | {mean('test_success')} | {col('test_final_distance_cm')} "
                   f"| {mean('test_final_distance_cm')} | {col('train_success_last50')} | {col('episodes', '{:.0f}')} "
                   f"| {col('seconds', '{:.0f}')} |")
    return "\n".join(out)


if __name__ == "__main__":
    main()
