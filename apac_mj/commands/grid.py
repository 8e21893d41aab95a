"""``apac-mj grid``: run the paper's experiment grid (or a smaller preset) into a results directory."""
from __future__ import annotations

import argparse

EPILOG = """\
examples:
  apac-mj grid --preset smoke --out results/smoke
  apac-mj grid --preset quick --out results/quick
  apac-mj grid --preset paper --out results/paper --set seeds=0-9 --set agent.batch_size=256
  apac-mj grid --preset my_grid.toml --executor ray --ray-address auto

Re-running the same command skips finished cells and resumes unfinished ones from their last
checkpoint; the numbers equal those of an uninterrupted run. A larger episodes (--set episodes=N,
all else the same) extends finished cells and tests them again; any other change for an existing
--out is refused before anything is written. --dry-run shows what a run would do, refusals included.
One grid writes a results directory at a time (a second is refused, naming the first's PID). Ctrl-C
or SIGTERM stops every worker within seconds, also when the main process is killed; each running cell
keeps its last checkpoint (docs/reliability.md). Presets live in tasks/presets/
(copy one and edit it); docs/experiments.md describes the fields and the results layout."""


def fields_help() -> str:
    """Every key a preset (and --set) takes, with its doc: preset, [tests], run and [agent] fields."""
    from apac_mj.config import AgentConfig, TrainConfig
    from apac_mj.util.overrides import field_help
    from apac_mj.experiments.presets import Preset, Tests

    return ("Preset fields:\n" + field_help(Preset, skip=("name", "run", "agent", "tests"))
            + "\n\n[tests] fields (tests.NAME=VALUE):\n" + field_help(Tests, prefix="tests.")
            + "\n\nRun fields (TrainConfig; the paper's 50 seeds unless set):\n"
            + field_help(TrainConfig, skip=("task", "agent"))
            + "\n\n[agent] fields (AgentConfig; agent.NAME=VALUE or NAME=VALUE):\n"
            + field_help(AgentConfig, prefix="agent.", skip=("kind",)))


def _preset_names() -> list[str]:
    from apac_mj.util import paths

    return sorted(p.stem for p in (paths.tasks_dir() / "presets").glob("*.toml"))


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("grid", help="run the paper's experiment grid (train + test every cell, resumable)",
                       description="Train every (agent, condition) cell of a preset as one ensemble job, then run its "
                                   "frozen-network tests; results go to --out, one sub-directory per cell.",
                       epilog=EPILOG + "\n\n" + fields_help(), formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--preset", default="quick",
                   help=f"preset name in tasks/presets/ ({', '.join(_preset_names())}) or a path to a .toml "
                        "file (default: quick)")
    p.add_argument("--out", default=None, help="results directory (default: results/<preset name>)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a preset field (listed below; the grammar of train --set), repeatable: "
                        "seeds=0-2, episodes=50, agents=ddpg,apac, tests.occluded=false, agent.batch_size=64, "
                        "actor_hidden=64,64. Bad values are refused before anything runs")
    p.add_argument("--executor", choices=("local", "ray"), default="local",
                   help="local: this machine, no service needed (default); ray: one Ray task per cell")
    p.add_argument("--ray-address", default=None,
                   help="join an existing Ray cluster (e.g. auto or ray://head:10001); without it Ray starts locally")
    p.add_argument("--workers", type=int, default=1,
                   help="local executor: cells run at once in a process pool (default 1: the ensemble already "
                        "uses the cores)")
    p.add_argument("--dry-run", action="store_true", help="print the cells and their status, run nothing")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from apac_mj.experiments import grid
    from apac_mj.experiments.executors import make_executor
    from apac_mj.experiments.presets import load_preset

    preset = load_preset(args.preset, args.overrides)
    out = Path(args.out or f"results/{preset.name}")
    print(grid.describe(preset))
    if args.dry_run:
        for c in grid.cells(preset):
            status, why = grid.cell_status(c, preset, out)
            detail = f" ({why})" if status == "to extend" else f": {why}" if why else ""
            print(f"  {c.name:58s} tests={','.join(c.protocols) or '-':20s} {status}{detail}")
        grid.check_grid(preset, out)  # a refused cell: the same error (exit 2) as the real run
        return 0
    executor = make_executor(args.executor, workers=args.workers, ray_address=args.ray_address)
    manifest = grid.run_grid(preset, out, executor, progress=not args.no_progress)
    print(f"grid finished: {len(manifest['cells'])} cells in {out} ({manifest['wall_s_this_run']:.0f} s this run)")
    print(f"next: apac-mj report {out}")
    return 0
