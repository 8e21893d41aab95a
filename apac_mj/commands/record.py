"""``apac-mj record``: roll out episodes and save them as a Rerun recording (and a video)."""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

DESCRIPTION = """\
Roll out episodes with a trained run's networks (--run RUN_DIR: its
checkpoints/latest.pt) or with untrained networks (--seed), and save them as a
Rerun .rrd file: the MuJoCo overhead render every step, the arm from MuJoCo
beside the paper's motion function and the forward model's prediction, the
target zone over the distance field, and the time series of reward, distance,
|delta| against the arbitration threshold, the controller that acted, the
forward-model and kinematics errors, link lengths and vision. Actions are the
arbitrator's choice without exploration noise. With --run the rollouts
continue the run's environments where training left off (link lengths, static
target, the next targets of its sequence). No viewer is started and no
display is needed; open the file with `rerun FILE.rrd`. docs/recording.md
describes every panel.

examples:
  apac-mj record --task changing_target --agent apac --episodes 5 --out rollout.rrd
  apac-mj record --run runs/apac --episodes 5 --out rollout.rrd --video rollout.mp4
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("record", help="roll out episodes into a Rerun recording (.rrd) and optionally a video",
                       description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--run", type=Path, default=None,
                   help="a training run directory: use its latest checkpoint's networks (default: untrained networks)")
    p.add_argument("--task", default=None, help="task name from tasks/ (default: the run's task, else changing_target)")
    p.add_argument("--agent", choices=("ddpg", "spac", "apac"), default=None,
                   help="controller arbitration mode (default: the run's, else apac)")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the untrained networks and of the rollout targets (default 0); with --run the "
                        "rollouts continue the run's environments (lengths, targets) unless --task names another task")
    p.add_argument("--member", type=int, default=0,
                   help="with --run: which of the run's seeds (index in its seed list) to record (default 0)")
    p.add_argument("--episodes", type=int, default=5, help="episodes to roll out (default 5)")
    p.add_argument("--as-episode", type=int, default=None,
                   help="training-episode number the arbitrator sees for the first rollout (default: the run's "
                        "trained episodes, or planning_episodes for untrained networks, so that APAC arbitrates)")
    p.add_argument("--out", type=Path, default=Path("rollout.rrd"), help="the .rrd file to write (default rollout.rrd)")
    p.add_argument("--video", type=Path, default=None, help="also write the frames as a .mp4 or .gif video")
    p.add_argument("--fps", type=int, default=5, help="video frames per second (default 5)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    _check_args(args)
    import torch
    from tqdm import tqdm

    from apac_mj.recording import EpisodeRecorder
    from apac_mj.render import write_video

    torch.set_num_threads(min(torch.get_num_threads(), 2))
    cfg, agent, as_episode, env_state = _load_agent(args)
    member = args.member if args.run is not None else 0
    config = _config_dict(cfg)
    with EpisodeRecorder(args.out.parent, 1, config, member=member, out=args.out,
                         keep_frames=args.video is not None) as recorder:
        vec_env = _vec_env(cfg, args, env_state)
        for k in tqdm(range(args.episodes), desc="record", unit="episode"):
            _rollout_episode(agent, cfg, vec_env, recorder, as_episode + k)
    size, steps = args.out.stat().st_size, _frames(args.out)
    print(f"wrote {args.out} ({size / 1e6:.2f} MB, {steps} frames, {size / max(steps, 1) / 1e3:.1f} KB per step)")
    if args.video is not None:
        write_video(args.video, recorder.frames, fps=args.fps)
        print(f"wrote {args.video} ({len(recorder.frames)} frames at {args.fps} fps)")
    return 0


def _check_args(args: argparse.Namespace) -> None:
    if args.episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
    if args.out.suffix != ".rrd":
        raise ValueError(f"--out must end in .rrd, got {str(args.out)!r}")
    if args.video is not None and args.video.suffix.lower() not in (".mp4", ".gif"):
        raise ValueError(f"--video must end in .mp4 or .gif, got {str(args.video)!r}")
    if args.fps < 1:
        raise ValueError(f"--fps must be >= 1, got {args.fps}")
    if args.seed < 0 or args.member < 0:
        raise ValueError("--seed and --member must be >= 0")
    if args.run is not None and not (args.run / "config.json").is_file():
        from apac_mj.evaluate import not_a_run_dir

        raise FileNotFoundError(f"--run: {not_a_run_dir(args.run, 'record --run')}")


def _load_agent(args: argparse.Namespace) -> tuple[Any, Any, int, dict[str, Any] | None]:
    """(TrainConfig, Agent, first arbitrator episode, environment state or None), from a run's latest
    checkpoint or fresh."""
    from apac_mj import checkpoint
    from apac_mj.agent import Agent
    from apac_mj.config import AgentConfig, TrainConfig, task_spec, train_config_from_dict
    from apac_mj.kinematics import Geometry

    if args.run is None:
        cfg = TrainConfig(task=args.task or "changing_target", seeds=(args.seed,),
                          agent=AgentConfig(agent=args.agent or "apac"))
        agent = Agent(cfg.agent, cfg.seeds, geometry=Geometry.from_spec(task_spec(cfg)))
        first = cfg.agent.planning_episodes if args.as_episode is None else args.as_episode
        return cfg, agent, first, None
    from apac_mj.evaluate import warn_user

    ckpt = checkpoint.load_run_checkpoint(args.run, required=("config", "agent", "loop", "env"), warn=warn_user)
    run_cfg = dict(ckpt["config"])
    run_cfg.pop("git_commit", None)
    cfg = train_config_from_dict(run_cfg)
    if args.member >= len(cfg.seeds):
        raise ValueError(f"--member {args.member} out of range: the run has {len(cfg.seeds)} seeds {list(cfg.seeds)}")
    agent = Agent(cfg.agent, cfg.seeds, geometry=Geometry.from_spec(task_spec(cfg)))
    agent.load_state_dict(ckpt["agent"])
    _say_overrides(args, cfg)
    if args.agent is not None:
        cfg.agent.agent = args.agent
    env_state = ckpt["env"] if args.task in (None, cfg.task) else None
    cfg.task = args.task or cfg.task
    trained = int(ckpt["loop"]["episode"][args.member])
    return cfg, agent, max(trained, 0) if args.as_episode is None else args.as_episode, env_state


def _say_overrides(args: argparse.Namespace, cfg: Any) -> None:
    """With --run, an --agent or --task other than the run's is allowed but said."""
    import sys

    if args.agent not in (None, cfg.agent.agent):
        print(f"note: {args.run} trained {cfg.agent.agent}; recording its networks arbitrated as {args.agent} "
              f"(--agent {args.agent})", file=sys.stderr)
    if args.task not in (None, cfg.task):
        print(f"note: {args.run} trained on {cfg.task}; recording on {args.task} (--task) with fresh environments "
              f"seeded from --seed {args.seed}, not the run's", file=sys.stderr)


def _config_dict(cfg: Any) -> dict[str, Any]:
    from apac_mj.trainer import config_dict

    return config_dict(cfg)


def _vec_env(cfg: Any, args: argparse.Namespace, env_state: dict[str, Any] | None) -> Any:
    """The run's environments where training left off (``env_state``), else fresh ones seeded from --seed."""
    from apac_mj.suite import load_spec
    from apac_mj.vec_env import VecEnv

    if env_state is None:
        return VecEnv(cfg.task, [args.seed + k for k in range(len(cfg.seeds))], actuation=cfg.actuation,
                      overrides=dict(cfg.task_overrides))
    # Built as the trainer builds it (growth starts after babbling + growth_start_episode episodes), then
    # restored: the run's link lengths, static targets and the next targets of its sequence.
    growth = load_spec(cfg.task).growth_start_episode + cfg.agent.babbling_episodes
    vec_env = VecEnv(cfg.task, list(cfg.seeds), cfg.actuation,
                     overrides={**cfg.task_overrides, "growth_start_episode": growth})
    vec_env.set_state(env_state)
    return vec_env


def _rollout_episode(agent: Any, cfg: Any, vec_env: Any, recorder: Any, episode: int) -> None:
    """One episode for every member, no exploration noise; the recorder logs its member."""
    import numpy as np
    import torch

    from apac_mj.arbitrator import Arbitrator
    from apac_mj.rollout import agent_step, observed_state

    E = vec_env.E
    obs = vec_env.reset()
    recorder.on_episode_start(np.ones(E, dtype=bool), vec_env)
    state = observed_state(obs, agent.device)
    step, last_delta = np.zeros(E, dtype=np.int64), np.full(E, np.nan)
    active = np.ones(E, dtype=bool)
    arbitrator = Arbitrator(cfg.agent)
    while active.any():
        info = agent_step(agent, arbitrator, vec_env, state, np.full(E, episode), step, last_delta, active,
                          explore=False)
        recorder.on_step(info, vec_env)
        rows = torch.as_tensor(active, device=state.device)
        state = torch.where(rows[:, None], torch.as_tensor(info.next_state, device=state.device), state)
        last_delta = np.where(active, info.delta, last_delta)
        step += active
        active = active & ~info.done


def _frames(path: Path) -> int:
    from apac_mj.recording import RENDER, read_recording

    entities, _, _ = read_recording(path)
    return len(entities[RENDER].times["frame"])
