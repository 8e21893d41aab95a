"""``apac-mj tasks``: list the task conditions in tasks/."""
from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("tasks", help="list the task conditions (tasks/*.toml)",
                       description="List every task file in tasks/ with its conditions.")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from apac_mj.suite.task_spec import load_task, task_names

    for name in task_names():
        s = load_task(name)
        print(f"{name:48s} target={s.target_mode:8s} kinematics={s.kinematics_mode:8s} "
              f"vision={s.vision:8s} region={s.target_region}")
    return 0
