"""``apac-mj tasks``: list the task conditions in tasks/."""
from __future__ import annotations

import argparse


#: ``tasks --show``'s first line: what the ``*`` before a value means (in the "  name = value" form of the lines below).
SHOW_LEGEND = ("  * = differs from the default (TaskSpec in apac_mj/suite/task_spec.py): what the task file sets; "
               "[unit] and (source) follow the [plant] values")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("tasks", help="list the task conditions (tasks/*.toml)",
                       description="List every task file in tasks/ with its conditions. With --regions, also "
                                   "measure each task's generalization split at its initial link lengths: the "
                                   "fraction of the reachable area in the test region and how many of the 100 "
                                   "angle-grid test targets fall in it.")
    p.add_argument("--regions", action="store_true", help="measure the test region of each task (a few seconds)")
    p.add_argument("--show", metavar="NAME", default=None,
                   help="print every value of task NAME (its file states only what differs from the defaults), "
                        "the [plant] values with their units")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from apac_mj.suite.regions import region_stats
    from apac_mj.suite.task_spec import describe, load_task, task_names

    if args.show is not None:
        print(SHOW_LEGEND)
        print(describe(load_task(args.show)))
        return 0
    for name in task_names():
        s = load_task(name)
        line = (f"{name:48s} target={s.target_mode:8s} kinematics={s.kinematics_mode:8s} "
                f"vision={s.vision:12s} region={s.target_region}")
        if s.plant.dynamic:
            line += f"  plant={s.plant.actuation}"
        if args.regions:
            r = region_stats(s)
            line += (f"  test y>={r.test_y_min}: {r.test_area_fraction:.3f} of area, "
                     f"{r.grid_targets_in_test}/{r.grid_targets} grid targets")
        print(line)
    return 0
