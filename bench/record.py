"""Cost of recording a step (render + JPEG + Rerun logging) as a fraction of a training step.

    .venv/bin/python bench/record.py [--steps 150] [--repeats 3] [--seeds 1]

One process, side by side on the same environment:

* **training step**: what the trainer does per step for one ensemble of
  ``--seeds`` members: both proposals (actor and inverse model), the forward
  model's prediction, one environment step per member, the replay insert and
  one ``Agent.update`` (batch 500 from a full replay memory, the paper's
  networks);
* **recording step**: what a recorded step adds: the MuJoCo offscreen render
  (240 x 320), the JPEG encode and ``Recording.log_step`` (render, three arms,
  path, ten time series, events) into a real .rrd file.

Each figure is the best of ``--repeats`` timed blocks, interleaved (least
disturbed by other load on a shared machine). The goal is a ratio <= 10%. The
"in situ" line times training steps with and without the step recorded in the
same loop, so it also counts what rendering and logging cost the update that
follows (caches, memory traffic); it is the higher and the more honest figure. The bytes per
recorded step are read off the .rrd file.
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path
from typing import Callable

import numpy as np
import torch

import apac_mj  # noqa: F401  (sets MUJOCO_GL before mujoco loads)
from apac_mj.recording import recording as R
from apac_mj.suite import render
from apac_mj import suite
from apac_mj.config import TrainConfig
from apac_mj.layout import Sizes
from apac_mj.run.build import make_agent



def _state(env) -> np.ndarray:
    p = env.physics
    return np.concatenate([p.end_effector(), p.elbow(), p.target()])


def _training_step(seeds: int) -> Callable[[], None]:
    run_cfg = TrainConfig(task="changing_target", seeds=tuple(range(seeds)))
    cfg = run_cfg.agent
    envs = [suite.load("planar_arm", "changing_target", task_kwargs={"random": k}) for k in range(seeds)]
    sizes = Sizes.from_specs(envs[0].observation_spec(), envs[0].action_spec())
    agent = make_agent(run_cfg, suite.spec_for(run_cfg), sizes)
    for env in envs:
        env.reset()
    rng = np.random.default_rng(0)
    E, full = agent.E, torch.ones(agent.E, dtype=torch.bool)
    for _ in range(cfg.replay_size):  # a full replay memory, so every update uses a whole batch
        s = torch.as_tensor(rng.uniform(0, 30, (E, 6)), dtype=torch.float32)
        agent.replay.add(s, torch.as_tensor(rng.uniform(-180, 180, (E, 2)), dtype=torch.float32),
                         -torch.rand(E), s, torch.zeros(E), full)

    def step() -> None:
        s = torch.as_tensor(np.stack([_state(e) for e in envs]), dtype=torch.float32)
        a = agent.actor_action(s) + agent.noise.sample()
        agent.inverse_action(s)
        agent.predict_arm(s, a)
        rewards = []
        for env, ak in zip(envs, a.numpy().astype(np.float64)):
            ts = env.step(ak)
            rewards.append(ts.reward)
            if ts.last():
                env.reset()
        s2 = torch.as_tensor(np.stack([_state(e) for e in envs]), dtype=torch.float32)
        agent.replay.add(s, a, torch.tensor(rewards, dtype=torch.float32), s2, torch.zeros(E), full)
        agent.update(full)

    return step


class _RecordingStep:
    """One environment and its recording: ``advance`` steps the env (untimed, it belongs to the
    training step); calling the object records the current step, episode starts included."""

    def __init__(self, path: Path) -> None:
        self.env = suite.load("planar_arm", "changing_target", task_kwargs={"random": 0})
        self.rng = np.random.default_rng(1)
        self.ts = self.env.reset()
        self.renderer = render.Renderer(self.env.physics)
        self.rec = R.recording_for_env(path, self.env, {"bench": "record"})
        self.episode, self.new_episode = 0, True
        #: Seconds spent per part: render, jpeg, log (log_step and episode starts).
        self.parts = {"render": 0.0, "jpeg": 0.0, "log": 0.0}

    def advance(self) -> None:
        if self.ts.last():
            self.ts = self.env.reset()
            self.episode, self.new_episode = self.episode + 1, True
        self.ts = self.env.step(self.rng.uniform(-40, 40, size=2))

    def __call__(self) -> None:
        t0 = time.perf_counter()
        frame = self.renderer.render()
        t1 = time.perf_counter()
        jpeg = render.encode_jpeg(frame)
        t2 = time.perf_counter()
        if self.new_episode:  # also sends the previous episode's time series
            self.rec.start_episode(self.episode, self.env.physics.target(), self.env.physics.link_lengths())
            self.new_episode = False
        step = R.step_record_from_env(self.env, self.episode, self.ts, habit=bool(self.rng.integers(2)),
                                      delta=float(self.rng.normal()),
                                      predicted_arm=self.rng.uniform(0, 30, size=4))
        self.rec.log_step(step, jpeg)
        t3 = time.perf_counter()
        for k, dt in zip(self.parts, (t1 - t0, t2 - t1, t3 - t2)):
            self.parts[k] += dt

    def close(self) -> None:
        self.rec.close()
        self.renderer.close()


def _block_ms(fn: Callable[[], None], steps: int, between: Callable[[], None] | None = None) -> float:
    """Mean ms per call of ``fn`` over ``steps`` calls (``between`` runs untimed before each)."""
    total = 0.0
    for _ in range(steps):
        if between is not None:
            between()
        t = time.perf_counter()
        fn()
        total += time.perf_counter() - t
    return total / steps * 1e3


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--steps", type=int, default=150, help="timed steps per block (default 150)")
    p.add_argument("--repeats", type=int, default=3, help="timed blocks per variant; the best counts (default 3)")
    p.add_argument("--seeds", type=int, default=1, help="ensemble members in the training step (default 1)")
    p.add_argument("--record-every", type=int, default=10,
                   help="for the averaged figure: one episode in this many is recorded (default 10)")
    args = p.parse_args()
    if min(args.steps, args.repeats, args.seeds, args.record_every) < 1:
        p.error("--steps, --repeats, --seeds and --record-every must be >= 1")
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.rrd"
        train = _training_step(args.seeds)
        record = _RecordingStep(path)
        train_ms = record_ms = plain_ms = both_ms = float("inf")

        def plain() -> None:  # a training step plus the recorded env's step, not recorded
            record.advance()
            train()

        def both() -> None:  # the same with the step recorded: what a recorded training step costs in situ
            record.advance()
            record()
            train()

        for _ in range(args.repeats):  # interleaved blocks: all see the same load
            train_ms = min(train_ms, _block_ms(train, args.steps))
            record_ms = min(record_ms, _block_ms(record, args.steps, between=record.advance))
            plain_ms = min(plain_ms, _block_ms(plain, args.steps))
            both_ms = min(both_ms, _block_ms(both, args.steps))
        record.close()
        size, frames = path.stat().st_size, record.rec.frames
        total = sum(record.parts.values())
        shares = ", ".join(f"{k} {v / total:.0%}" for k, v in record.parts.items())
    print(f"torch threads: 1, ensemble members: {args.seeds}, steps per block: {args.steps}, best of {args.repeats}")
    print(f"training step (proposals + env step + replay + update): {train_ms:8.2f} ms")
    print(f"recording step (render + JPEG + log_step):              {record_ms:8.2f} ms  ({shares})")
    ratio = record_ms / train_ms
    print(f"recording / training step:                              {ratio:8.1%}  (goal <= 10%)")
    print(f"averaged over training with --record-every {args.record_every}:           "
          f"{ratio / args.record_every:8.1%}  (only recorded episodes are rendered)")
    in_situ = (both_ms - plain_ms) / plain_ms
    print(f"in situ: training step {plain_ms:.2f} ms, with the step recorded {both_ms:.2f} ms: "
          f"+{in_situ:.1%}; with --record-every {args.record_every}: +{in_situ / args.record_every:.1%}")
    print("  (in situ includes what rendering and logging cost the update afterwards: caches, memory)")
    print(f"bytes per recorded step (.rrd size / steps):            {size / frames:8.0f} B  ({frames} steps)")


if __name__ == "__main__":
    main()
