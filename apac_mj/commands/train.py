"""``apac-mj train``: train an ensemble of seeds on one task into a (resumable) run directory."""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
from collections.abc import Iterator
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from apac_mj.config import TrainConfig
    from apac_mj.recording.recording import EpisodeRecorder
    from apac_mj.run.run_dir import RunDir
    from apac_mj.suite.task_spec import TaskSpec

EPILOG = """\
examples:
  apac-mj train --task changing_target --agent apac --seeds 0-9 --episodes 1000 --out runs/apac_ct
  apac-mj train --task static_target --agent spac --seeds 0,3,5 --episodes 200 --out runs/spac_st \\
                --set batch_size=128 --set ou_sigma=5
  apac-mj evaluate runs/apac_ct

The run directory gets config.json (the resolved config and git commit), metrics.parquet (one row
per seed and episode: success, steps, return, final distance, habit and planning action counts,
link lengths, target, mean losses of the four networks), checkpoints/ (periodic and final) and
DONE when finished. Files get the usual permissions (0666 minus the umask). Re-running the same
command resumes from the last checkpoint with the same numbers as an uninterrupted run, and says so;
on a finished run it does nothing and says so. A larger --episodes (everything else the same)
extends a finished run, again with the numbers of an uninterrupted run of that length (each seed's
episodes; metrics.parquet lists rows in the order episodes end, which differs from that run's, so
compare by seed and episode); any other difference for an existing directory is an error. A damaged
checkpoints/latest.pt falls back, with a warning, to checkpoints/previous.pt. Everything is checked
before the directory is created.
One process writes a run directory at a time (RUN_DIR/.lock; a second is refused, naming the first's
PID). Ctrl-C and SIGTERM say what the last checkpoint holds; the same command resumes from it. A
config.json or metrics.parquet that disagrees with the checkpoint is named (docs/reliability.md).
At the end it prints one JSON line: episodes, seeds, and the success rate and habit share over each
seed's last N = min(100, episodes) training episodes (success_rate_last_N, habit_share_last_N; the
progress bar's rates are over the last 20)."""


def register(sub: argparse._SubParsersAction) -> None:
    from apac_mj import kinds
    from apac_mj.config import ACTUATIONS, PRECISION_REQUESTS, AgentConfig, TrainConfig
    from apac_mj.util.overrides import field_docs, field_help
    from apac_mj.util.threads import DEFAULT_THREADS

    d, doc = TrainConfig(), field_docs(TrainConfig)
    p = sub.add_parser("train", help="train an ensemble of seeds on a task (resumable run directory)",
                       description="Train an agent kind (DDPG, SPAC, APAC or a registered one) on one task, every "
                                   "seed as an independent member of one batched ensemble: motor babbling first, "
                                   "then the training episodes. Shows a progress bar (episodes of the slowest seed, "
                                   "success rate and habit share over the last 20 episodes of all seeds).",
                       epilog=EPILOG + "\n\nTrainConfig fields (--set KEY=VALUE; the flags above set some of them):\n"
                       + field_help(TrainConfig, skip=("agent",)) + "\n\nAgentConfig fields (--set NAME=VALUE or "
                       "agent.NAME=VALUE):\n" + field_help(AgentConfig, skip=("kind",)),
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", default=d.task, help=f"{doc['task']} (see apac-mj tasks; default {d.task})")
    p.add_argument("--agent", choices=kinds.names(), default=kinds.DEFAULT,
                   help="agent kind (apac_mj.kinds): ddpg: always the actor; spac: always the inverse model; "
                        "apac: the paper's arbitrator decides; apac_uncertainty, apac_reliability, "
                        "apac_speed_accuracy, apac_vision: the rules beyond the paper (docs/arbitrators.md); "
                        "spac_mpc, apac_mpc, apac_voc: planning several steps through the learned model, always, "
                        "by the delta rule, or for as long as it is worth its cost (docs/agent.md); "
                        f"or one registered from your code (default {kinds.DEFAULT})")
    p.add_argument("--seeds", default=None,
                   help="seeds: N (the seeds 0..N-1), a range '0-9' (inclusive), a list '0,3,5', one seed k as "
                        "'k-k' (the grammar of grid --set seeds=...; default: seed 0)")
    p.add_argument("--episodes", type=int, default=d.episodes, help=f"{doc['episodes']} (default {d.episodes})")
    p.add_argument("--out", required=True, help="run directory (created; an existing one is resumed)")
    p.add_argument("--device", default=d.device, help=f"{doc['device']} (default {d.device})")
    p.add_argument("--precision", choices=PRECISION_REQUESTS, default=d.precision,
                   help="fp32 (reference, bit-reproducible on CPU), bf16 autocast of the matrix products, or "
                        "auto: bf16 where the hardware has bf16 dot products (a CPU with avx512_bf16 or amx_bf16, "
                        "a CUDA GPU with bf16), else fp32; the run says which and why, and config.json records "
                        "the choice (a resumed run keeps its own)")
    p.add_argument("--checkpoint-every", type=int, default=d.checkpoint_every,
                   help=f"{doc['checkpoint_every']} (default {d.checkpoint_every})")
    p.add_argument("--actuation", choices=ACTUATIONS, default=d.actuation,
                   help="servo: MuJoCo position servos (default); kinematic: joint angles written exactly")
    p.add_argument("--record-every", type=int, default=None, metavar="N",
                   help="record every N-th episode to RUN_DIR/recordings/*.rrd (Rerun; apac_mj.recording.recording)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="set a TrainConfig or AgentConfig field (listed below), repeatable: batch_size=128, "
                        "ou_sigma=5, actor_hidden=64,64, agent.babbling_episodes=20, task_overrides={at_limit=\"unbounded\"}")
    p.add_argument("--threads", type=int, default=DEFAULT_THREADS,
                   help=f"torch CPU threads (default {DEFAULT_THREADS}, as apac_mj.train: these networks are small, "
                        "and on a busy 2-core machine 2 threads measured 10-25x slower; raise it for E >= 10 on "
                        "free cores; apac_mj/util/threads.py)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def parse_seeds(text: str) -> tuple[int, ...]:
    """The one seed grammar (apac_mj.util.overrides.parse_seeds): '4' -> 0..3, '0-9' -> 0..9, '0,3,5', '7-7' -> (7,)."""
    from apac_mj.util.overrides import parse_seeds as parse

    return parse(text, "--seeds")


def agent_overrides(items: list[str]) -> dict:
    """``KEY=VALUE`` strings (``NAME`` or ``agent.NAME``) -> AgentConfig keyword arguments, in the one
    --set grammar (apac_mj.util.overrides): typed by the field, an unknown name or a bad value refused."""
    from apac_mj.experiments.presets import agent_overrides as parse

    return parse(items)


def train_config(args: argparse.Namespace) -> TrainConfig:
    """The run's TrainConfig: the flags, then every --set (one grammar, typed and checked here)."""
    from apac_mj.util import overrides
    from apac_mj.config import AgentConfig, TrainConfig

    data = {"task": args.task, "episodes": args.episodes, "device": args.device, "precision": args.precision,
            "checkpoint_every": args.checkpoint_every, "actuation": args.actuation, "agent": {"kind": args.agent}}
    if args.seeds is not None:
        data["seeds"] = parse_seeds(args.seeds)
    agent_fields = overrides.keys(AgentConfig)
    top = {f.name for f in dataclasses.fields(TrainConfig)}
    overrides.apply_sets(data, args.overrides, agent_fields=agent_fields, top_level=top)
    if "seeds" in data and not isinstance(data["seeds"], tuple):
        data["seeds"] = overrides.parse_seeds(data["seeds"])
    agent = overrides.typed_fields(AgentConfig, data.pop("agent"), "--set agent.")
    return TrainConfig(agent=AgentConfig(**agent), **overrides.typed_fields(TrainConfig, data, "--set ", skip=("agent",)))


def recorder(out: str, record_every: int, cfg: TrainConfig) -> EpisodeRecorder:
    """``--record-every N``: the hook that records every N-th episode into RUN_DIR/recordings/."""
    from apac_mj.recording.recording import EpisodeRecorder
    from apac_mj.run.run_dir import RunDir, config_dict

    return EpisodeRecorder(RunDir(out).recordings, record_every=record_every, config=config_dict(cfg))


#: The final summary's success rate and habit share are over each seed's last this many training episodes (or
#: all of them in a shorter run; the keys name the window: ``success_rate_last_30`` for a 30-episode run).
SUMMARY_WINDOW = 100


def run_summary(run_dir: RunDir) -> dict:
    """:meth:`RunDir.summary` over the last ``min(SUMMARY_WINDOW, episodes)`` training episodes, the keys naming
    that window (a 30-episode run once printed ``success_rate_last_100``, the rate over all 30)."""
    train = run_dir.metrics().query("phase == 'train'")
    return run_dir.summary(last=max(1, min(SUMMARY_WINDOW, int(train["episode"].max()) + 1)))


def planning_phase_note(cfg: TrainConfig) -> str | None:
    """A note when an arbitrating kind's run ends within its planning phase (the paper's first
    ``planning_episodes`` = 100 episodes always plan): the habit would never act (the README's quick look at
    100 episodes once showed ``habit=0.00`` throughout). None otherwise."""
    from apac_mj import kinds

    phase = cfg.agent.planning_episodes
    if not kinds.get(cfg.agent.kind).arbitrates or cfg.episodes > phase:
        return None
    return (f"note: {cfg.agent.kind} plans in all {cfg.episodes} episodes of this run (agent.planning_episodes = "
            f"{phase}: the paper's planning phase), so its habit never acts; for a short look at arbitration "
            f"set the phase shorter, e.g. --set agent.planning_episodes={max(1, cfg.episodes * 2 // 5)}")



def _progress_mark(run_dir: RunDir) -> tuple[int, int | None]:
    """What changes when train trains: the metric rows and latest.pt's modification time (an extension lost to a
    damaged latest.pt is trained again into the same rows, so the rows alone would say nothing was trained)."""
    from apac_mj.run.run_dir import LATEST

    latest = run_dir.checkpoints / LATEST
    return run_dir.metric_rows(), latest.stat().st_mtime_ns if latest.is_file() else None

def run(args: argparse.Namespace) -> int:
    import sys

    from apac_mj.run.run_dir import RunDir
    from apac_mj.run.trainer import train
    from apac_mj.util.threads import set_threads

    if args.threads < 1:
        raise ValueError(f"--threads must be >= 1, got {args.threads}")
    cfg = train_config(args)
    spec = check(cfg)  # refuse (unknown task, missing device, a plant its actuation cannot drive) before any note
    if (note := planning_phase_note(cfg)) is not None:
        print(note, file=sys.stderr)
    set_threads(args.threads)  # the whole command (the recorder's renders too), as train() does for its call
    run_dir = RunDir(args.out)
    before = _progress_mark(run_dir)
    with contextlib.ExitStack() as stack:
        hooks = [] if args.record_every is None else [stack.enter_context(recorder(args.out, args.record_every, cfg))]
        with unstable_plant(spec, cfg.task_overrides):
            train(cfg, run_dir.path, progress=not args.no_progress, hooks=hooks, threads=args.threads)
    trained = _progress_mark(run_dir) != before
    summary = {"run_dir": str(run_dir.path), "status": "trained" if trained else "already finished; nothing trained",
               **run_summary(run_dir)}
    print(json.dumps(summary))
    print(f"next: {next_command(spec, run_dir.path)}")
    return 0


def check(cfg: TrainConfig) -> TaskSpec:
    """:func:`apac_mj.run.build.check` (writes nothing): the run's task, or a ValueError naming what cannot run."""
    from apac_mj.run import build

    return build.check(cfg)


def next_command(spec: TaskSpec, run_dir: object) -> str:
    """What to run after training: the frozen tests (``evaluate``), or the forced-response test of a cued task."""
    if spec.cued:
        return f"apac-mj forced-response test {run_dir} --out TESTS.parquet (a cued task: docs/forced_response.md)"
    return f"apac-mj evaluate {run_dir}"


@contextlib.contextmanager
def unstable_plant(spec: TaskSpec, overrides: dict | None = None) -> Iterator[None]:
    """MuJoCo's invalid-state stop (``mjWARN_BADQACC``...) re-raised naming its likely cause: the run's ``[plant]``
    overrides (the campaign's DYN-5: ``link_masses=[1e-12,1e-12]``), else the task's plant settings that differ
    from the defaults."""
    from dm_control.rl.control import PhysicsError

    try:
        yield
    except PhysicsError as e:
        raise PhysicsError(physics_error_message(spec, e, overrides)) from e


def physics_error_message(spec: TaskSpec, e: BaseException, overrides: dict | None = None) -> str:
    """``e`` (MuJoCo's unstable-state error) with the plant settings that likely caused it."""
    from apac_mj.suite.plant import describe_plant

    given = (overrides or {}).get("plant")
    if isinstance(given, dict) and given:
        cause = "the override " + ", ".join(f"plant.{k} = {v!r}" for k, v in given.items())
    else:
        changed = [line[2:].split("  ")[0] for line in describe_plant(spec.plant).splitlines() if line.startswith("*")]
        if not spec.plant.dynamic or not changed:
            return str(e)
        cause = "its plant's " + "; ".join(changed)
    return (f"{e}: the physics became unstable on task {spec.name!r}; {cause} is the likely cause (an extreme mass, "
            "torque, stiffness, field or time step): bring it back towards its default (apac-mj tasks --show "
            f"{spec.name} lists the plant's values and their sources)")
