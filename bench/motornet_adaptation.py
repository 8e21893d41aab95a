"""MotorNet beside the agents: the adaptation protocol on MotorNet 0.3.0's two-joint, six-muscle arm.

MotorNet (Codol et al. 2024; ``pip install 'apac-mj[motornet]'``, an optional extra) is the modelling tool of this
field: a differentiable arm trained by backpropagation through the plant. Here its ``RigidTendonArm26`` (lumped
Hill muscles, Nijhof & Kouwenhoven 2000; MotorNet's defaults: 10 ms step, delays of one step, no noise) with its
own ``PolicyGRU`` is first trained on centre-out reaches (10 cm, random directions, from one start posture; the
budget is ``--train-batches`` batches of ``--batch`` reaches, Adam at 1e-3, loss = mean hand-target distance +
``EFFORT`` x mean squared activation), then runs the agents' protocol (the ``[trials]`` blocks of
``tasks/changing_target_compliant_adaptation.toml``, trial types drawn by the same code, ``key = seed``) with
online learning as MotorNet does it: one trial is a batch of ``DIRECTIONS`` centre-out reaches, and after
each trial one gradient step (a fresh Adam at ``--online-lr``) on the same loss.

The fields act at the hand as MotorNet's ``endpoint_load``: the curl field F = B v, B = [[0, b], [-b, 0]]
(Shadmehr & Mussa-Ivaldi 1994's form; b > 0 clockwise), the reverse field -B v; a channel trial replaces the
field with a stiff spring-damper across the straight line to the target (``CHANNEL_K``, ``CHANNEL_C``), whose
force is recorded; a catch trial turns the field off. Per trial: the lateral error (cm, + where the adaptation
field pushes; mean over directions) and on channel trials the adaptation as the agents' (the learned lateral force over the
adaptation field's force at the peak hand speed; mean over directions). The adaptation field's b here is
``FIELD_B`` (human-sized arm), the task's (100 N·s/m) is for the agents' 13 cm arm: ``field`` is in units of each.

What MotorNet cannot express: which controller acted (one network, no arbitration: ``habit_share`` is NaN);
a go cue (the target is shown from the first step; MotorNet's roadmap lists it); a channel or a catch trial as
a trial type of its own (they are loads this script writes, as any user of MotorNet would).

    .venv/bin/python bench/motornet_adaptation.py --seeds 3 --out results/adaptation/motornet
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from apac_mj.experiments.adaptation import TASK, TRIAL_COLUMNS
from apac_mj.report.two_state import lateral_error

#: Start posture (shoulder, elbow; rad), reach length (m), reach directions per trial, episode length (s).
START_Q, REACH, DIRECTIONS, DURATION = (math.radians(45.0), math.radians(90.0)), 0.10, 8, 0.6
#: Curl field b (N·s/m; the magnitude of Shadmehr & Mussa-Ivaldi's field, ~10-15 N·s/m); channel stiffness
#: (N/m) and damping (N·s/m); the effort weight of the loss.
FIELD_B, CHANNEL_K, CHANNEL_C, EFFORT = 13.0, 2000.0, 50.0, 1e-3


def make_env():
    """MotorNet's arm26 with rigid-tendon Hill muscles, MotorNet's default environment settings."""
    import motornet as mn

    effector = mn.effector.RigidTendonArm26(muscle=mn.muscle.RigidTendonHillMuscle())
    return mn.environment.Environment(effector=effector, max_ep_duration=DURATION)


def reach(env, policy, angles: torch.Tensor, load: str, b: float) -> dict[str, torch.Tensor]:
    """One batch of centre-out reaches in directions ``angles`` (rad) under ``load`` ("none", "field",
    "channel"; field ``b``): the hand's path [T, B, 2], the lateral forces [T, B] and the loss."""
    n = angles.numel()
    q0 = torch.tensor([[*START_Q, 0.0, 0.0]]).repeat(n, 1)
    obs, info = env.reset(options={"batch_size": n, "joint_state": q0})
    start = info["states"]["fingertip"].detach()
    u = torch.stack([torch.cos(angles), torch.sin(angles)], 1)
    right = torch.stack([u[:, 1], -u[:, 0]], 1)  # clockwise from the direction: where b > 0 pushes
    env.goal = start + REACH * u
    obs = env.get_obs(deterministic=True)
    h, path, f_ch, speed, effort = policy.init_hidden(n), [], [], [], 0.0
    for _ in range(int(round(DURATION / env.dt))):
        a, h = policy(obs, h)
        x, v = env.states["cartesian"][:, :2], env.states["cartesian"][:, 2:]
        curl = b * torch.stack([v[:, 1], -v[:, 0]], 1)
        lateral = ((x - start) * right).sum(1, keepdim=True)
        channel = -(CHANNEL_K * lateral + CHANNEL_C * (v * right).sum(1, keepdim=True)) * right
        endpoint = {"none": torch.zeros_like(v), "field": curl, "channel": channel}[load]
        obs, *_ = env.step(a, deterministic=True, endpoint_load=endpoint)
        path.append(env.states["fingertip"])
        f_ch.append((channel * right).sum(1).detach())
        speed.append(v.norm(dim=1).detach())
        effort = effort + (a ** 2).mean()
    p = torch.stack(path)
    loss = (p - env.goal).norm(dim=-1).mean() + EFFORT * effort / len(path)
    return {"path": p.detach(), "start": start, "goal": env.goal.detach(), "channel_force": torch.stack(f_ch),
            "speed": torch.stack(speed), "loss": loss}


def train(seed: int, batches: int, batch: int, hidden: int) -> tuple[object, object, list[float]]:
    """MotorNet's GRU trained on null-field centre-out reaches; the environment, the policy and the losses."""
    import motornet as mn

    torch.manual_seed(seed)
    env = make_env()
    policy = mn.policy.PolicyGRU(env.observation_space.shape[0], hidden, env.n_muscles, "cpu")
    opt = torch.optim.Adam(policy.parameters(), lr=1e-3)
    losses = []
    for _ in range(batches):
        out = reach(env, policy, torch.rand(batch) * 2 * math.pi, "none", 0.0)
        opt.zero_grad()
        out["loss"].backward()
        opt.step()
        losses.append(float(out["loss"].detach()))
    return env, policy, losses


def schedule(task: str, seed: int) -> pd.DataFrame:
    """The task's [trials] blocks as trials (the agents' protocol): per trial its block, the field in units of the
    adaptation field's b, and the channel and catch flags, drawn as the agents' are with ``key = seed``."""
    from apac_mj.config import TrainConfig
    from apac_mj.experiments.adaptation import adaptation_b, check_task

    cfg = TrainConfig(task=task)
    spec, b = check_task(cfg), adaptation_b(cfg)
    trials = [spec.trial_at(seed, e) for e in range(sum(blk.episodes for blk in spec.blocks))]
    return pd.DataFrame({"trial": range(len(trials)), "block": [t.name for t in trials],
                         "field": [t.field_b / b for t in trials], "channel": [t.type == "channel" for t in trials],
                         "catch": [t.type == "catch" for t in trials]})


def protocol(env, policy, trials: pd.DataFrame, seed: int, lr: float) -> pd.DataFrame:
    """The protocol with one online gradient step after each trial; one row per trial (:data:`TRIAL_COLUMNS`)."""
    opt = torch.optim.Adam(policy.parameters(), lr=lr)
    angles = torch.arange(DIRECTIONS) * (2 * math.pi / DIRECTIONS)
    rows = []
    for t in trials.itertuples():
        load = "channel" if t.channel else ("field" if t.field != 0 else "none")
        out = reach(env, policy, angles, load, FIELD_B * t.field)
        opt.zero_grad()
        out["loss"].backward()
        opt.step()
        rows.append({"seed": seed, "trial": t.trial, "block": t.block, "field": t.field, "channel": t.channel,
                     "catch": t.catch, **_measures(out, bool(t.channel)), "habit_share": math.nan,
                     "direction": -1})  # every trial all 8 directions, averaged: one baseline for all
    return pd.DataFrame(rows, columns=list(TRIAL_COLUMNS))


def _measures(out: dict[str, torch.Tensor], channel: bool) -> dict[str, float]:
    """Lateral error (cm, mean over directions; NaN on a channel trial) and, on a channel trial, the adaptation as
    the agents' (apac_mj.experiments.adaptation.trial_table): the learned lateral force (the channel's force on
    the hand along n) over the adaptation field's force b v at the peak hand speed, mean over directions."""
    path, start, goal = out["path"].numpy(), out["start"].numpy(), out["goal"].numpy()
    if channel:
        speed = out["speed"].numpy()  # [T, B]
        peak = speed.argmax(0)
        cols = np.arange(speed.shape[1])
        ratio = out["channel_force"].numpy()[peak, cols] / (FIELD_B * speed[peak, cols])
        return {"lateral_error": math.nan, "adaptation": float(ratio.mean())}
    errors = [lateral_error(path[:, i], start[i], goal[i]) for i in range(path.shape[1])]
    return {"lateral_error": 100.0 * float(np.mean(errors)), "adaptation": math.nan}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=3, help="networks trained and run (seeds 0..N-1)")
    p.add_argument("--train-batches", type=int, default=600, help="training batches per network")
    p.add_argument("--batch", type=int, default=32, help="reaches per training batch")
    p.add_argument("--hidden", type=int, default=64, help="GRU units")
    p.add_argument("--online-lr", type=float, default=3e-4, help="Adam step size of the online learning")
    p.add_argument("--task", default=TASK, help="the task whose [trials] blocks are the protocol (default %(default)s)")
    p.add_argument("--out", type=Path, required=True, help="folder for trials.csv and budget.json")
    args = p.parse_args(argv)
    if args.seeds < 1 or args.train_batches < 1:
        p.error("--seeds and --train-batches must be >= 1")
    torch.set_num_threads(1)
    frames, budget = [], {"train_s": [], "protocol_s": [], "final_train_loss_cm": []}
    for seed in range(args.seeds):
        t0 = time.process_time()
        env, policy, losses = train(seed, args.train_batches, args.batch, args.hidden)
        t1 = time.process_time()
        frames.append(protocol(env, policy, schedule(args.task, seed), seed, args.online_lr))
        budget["train_s"].append(t1 - t0)
        budget["protocol_s"].append(time.process_time() - t1)
        budget["final_train_loss_cm"].append(100.0 * float(np.mean(losses[-20:])))
        print(f"seed {seed}: trained {args.train_batches} batches in {t1 - t0:.0f} CPU-s (loss "
              f"{budget['final_train_loss_cm'][-1]:.2f} cm), protocol in {budget['protocol_s'][-1]:.0f} CPU-s",
              file=sys.stderr, flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    pd.concat(frames).to_csv(args.out / "trials.csv", index=False)
    budget.update(vars(args) | {"out": None, "motornet": _version(), "cpu_seconds_total": time.process_time()})
    (args.out / "budget.json").write_text(json.dumps(budget, indent=1) + "\n")
    return 0


def _version() -> str:
    import motornet

    return motornet.__version__


if __name__ == "__main__":
    sys.exit(main())
