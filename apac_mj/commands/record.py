"""``apac-mj record``: roll out episodes and save them as a Rerun recording (and a video)."""
from __future__ import annotations

import argparse
from pathlib import Path

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
  apac-mj record --run runs/apac --episodes 5 --out rollout.rrd --force   # replace rollout.rrd
  apac-mj record --run zoo:apac_changing_target --episodes 5 --out apac.rrd   # a shipped APAC (docs/zoo.md)
"""


def register(sub: argparse._SubParsersAction) -> None:
    from apac_mj import kinds

    p = sub.add_parser("record", help="roll out episodes into a Rerun recording (.rrd) and optionally a video",
                       description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--run", type=Path, default=None,
                   help="a training run directory: use its latest checkpoint's networks (default: untrained networks);"
                        " or a zoo cell, zoo:NAME or its directory (docs/zoo.md)")
    p.add_argument("--task", default=None, help="task name from tasks/ (default: the run's task, else changing_target)")
    p.add_argument("--agent", choices=kinds.names(), default=None,
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
    p.add_argument("--force", action="store_true",
                   help="replace an existing --out (and --video); without it an existing file is refused")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from apac_mj.commands.hints import results_dir_hint
    from apac_mj.recording.record import record
    from apac_mj.run.zoo import resolve_run
    from apac_mj.util.threads import set_threads

    args.run = None if args.run is None else resolve_run(args.run)  # a zoo cell: its networks as a run
    if args.run is not None and (hint := results_dir_hint(args.run, "record --run")) is not None:
        raise FileNotFoundError(f"--run: {hint}")
    set_threads()  # 1, as train and evaluate (apac_mj/util/threads.py)
    r = record(args.out, run=args.run, task=args.task, agent=args.agent, seed=args.seed, member=args.member,
               episodes=args.episodes, as_episode=args.as_episode, video=args.video, fps=args.fps,
               overwrite=args.force)
    size = r.rrd.stat().st_size
    print(f"wrote {r.rrd} ({size / 1e6:.2f} MB, {r.frames} frames, {size / max(r.frames, 1) / 1e3:.1f} KB per step)")
    if r.video is not None:
        print(f"wrote {r.video} ({r.video_frames} frames at {args.fps} fps)")
    return 0
