"""``apac-mj check-kinematics``: MuJoCo arm vs the paper's motion function."""
from __future__ import annotations

import argparse

DESCRIPTION = """\
Drive the MuJoCo arm through random actions and random link lengths (changed on
the running model) and compare its elbow and end-effector sites with the
paper's motion function (Algorithm 1) at the joint angles MuJoCo reports.
Prints the worst error of each (cm) and how many of the 100 angle-grid test
targets fall in the generalization test region; exits with status 1 when an
error exceeds --tolerance."""


def register(sub: argparse._SubParsersAction) -> None:
    from apac_mj.config import ACTUATIONS

    p = sub.add_parser("check-kinematics", help="check the MuJoCo arm against the motion function",
                       description=DESCRIPTION)
    p.add_argument("--samples", type=int, default=1000, help="random configurations to check (default 1000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random actions and lengths (default 0)")
    p.add_argument("--tolerance", type=float, default=1e-9,
                   help="largest allowed absolute coordinate error in cm (default 1e-9)")
    p.add_argument("--actuation", choices=ACTUATIONS, default="servo",
                   help="servo: position servos move the arm (default); kinematic: angles written exactly")
    p.add_argument("--task", default="changing_target",
                   help="task whose arm to check (default changing_target); a task with dynamics ([plant]) holds "
                        "its hand load and force field and is checked after every sub-step, while moving")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from apac_mj.suite.kinematics_check import check_kinematics
    from apac_mj.suite import load_spec
    from apac_mj.suite.regions import region_stats

    report = check_kinematics(args.samples, args.seed, args.tolerance, args.actuation, progress=not args.no_progress,
                              task=args.task)
    if report.max_joint_speed > 0:
        print(f"task {report.task}: checked {report.samples} actions x every sub-step while moving (joint speeds up "
              f"to {report.max_joint_speed:.0f} deg/s) + 4 joint-limit corners")
    else:
        print(f"checked {report.samples} configurations ({report.actuation} actuation) + 4 joint-limit corners")
    print(f"worst end-effector error: {report.worst_end_effector:.3e} cm")
    print(f"worst elbow error:        {report.worst_elbow:.3e} cm")
    stats = region_stats(load_spec("changing_target"))
    print(f"angle-grid targets in the test region (y >= {stats.test_y_min} cm, lengths {stats.link_lengths}): "
          f"{stats.grid_targets_in_test} of {stats.grid_targets}")
    if not report.passed:
        print(f"FAIL: error above the tolerance {report.tolerance:.1e} cm")
        return 1
    print(f"OK: within the tolerance {report.tolerance:.1e} cm")
    return 0
