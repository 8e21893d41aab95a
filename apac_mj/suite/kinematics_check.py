"""Check the MuJoCo arm against the paper's motion function (Algorithm 1).

Drives a live environment through random actions and random link lengths (set
on the running model, as changing kinematics does) and compares MuJoCo's
``elbow`` and ``end_effector`` sites with :func:`motion_function` at the joint
angles MuJoCo reports. For a task with dynamics (``[plant]``) the arm holds the
task's heaviest hand load and its force field the whole time, and the sites are
compared after every physics sub-step, while the arm moves. Used by
``apac-mj check-kinematics`` and the tests.
"""
from __future__ import annotations

import dataclasses

import numpy as np
from tqdm import tqdm

from apac_mj import kinematics, suite
from apac_mj.suite import planar_arm

#: Link lengths are drawn uniformly from this range (cm).
LENGTH_RANGE = (0.5, 15.0)
#: Fixed configurations checked first: all four corners of the joint range.
LIMIT_ANGLES = ((0.0, 0.0), (0.0, 180.0), (180.0, 0.0), (180.0, 180.0))


@dataclasses.dataclass(frozen=True)
class KinematicsReport:
    """Worst absolute coordinate errors (cm) over all checked configurations."""

    samples: int
    actuation: str
    tolerance: float
    worst_end_effector: float
    worst_elbow: float
    #: The task checked.
    task: str = "changing_target"
    #: Fastest joint speed met at a checked configuration (deg/s): the arm was moving when checked.
    max_joint_speed: float = 0.0

    @property
    def passed(self) -> bool:
        return max(self.worst_end_effector, self.worst_elbow) <= self.tolerance


def site_errors(physics: planar_arm.Physics) -> tuple[float, float]:
    """Max abs error (end-effector, elbow) of the sites vs the motion function, in cm."""
    alpha, beta = physics.joint_angles()
    end, elbow = kinematics.motion_function(alpha, beta, *physics.link_lengths(), physics.origin())
    return float(np.max(np.abs(end - physics.end_effector()))), float(np.max(np.abs(elbow - physics.elbow())))


def check_kinematics(
    samples: int = 1000,
    seed: int = 0,
    tolerance: float = 1e-9,
    actuation: str = "servo",
    progress: bool = False,
    task: str = "changing_target",
) -> KinematicsReport:
    """Compare sites and motion function over ``samples`` random configurations.

    Each sample sets new random link lengths on the live physics, then takes one
    environment step with a random action (uniform in [-180, 180] per joint, so
    the joint limits are hit often); the four limit corners are checked too.
    """
    if samples < 1:
        raise ValueError(f"samples must be >= 1, got {samples}")
    if not np.isfinite(tolerance) or tolerance < 0:
        raise ValueError(f"tolerance must be a finite number >= 0, got {tolerance}")
    env = suite.load("planar_arm", task, task_kwargs={"random": seed, "actuation": actuation})
    env.reset()
    physics = env.physics
    if env.task.spec.plant.dynamic:
        return _check_moving(env, samples, seed, float(tolerance), progress)
    rng = np.random.default_rng(seed)
    worst = np.zeros(2)
    for corner in LIMIT_ANGLES:
        physics.set_joint_angles(*corner)
        worst = np.maximum(worst, site_errors(physics))
    for _ in tqdm(range(samples), desc="check-kinematics", disable=not progress):
        physics.set_link_lengths(*rng.uniform(*LENGTH_RANGE, size=2))
        if env.step(rng.uniform(-planar_arm.ACTION_BOUND, planar_arm.ACTION_BOUND, size=2)).last():
            env.reset()
        worst = np.maximum(worst, site_errors(physics))
    return KinematicsReport(samples, actuation, float(tolerance), float(worst[0]), float(worst[1]))


def _check_moving(env, samples: int, seed: int, tolerance: float, progress: bool) -> KinematicsReport:
    """The check for a task with dynamics: the heaviest hand load and the force field on throughout, random
    actions (its own units: degrees or N·m) on random link lengths, the sites compared after every sub-step."""
    physics, task = env.physics, env.task
    plant = task.spec.plant
    physics.set_load(max(plant.load, plant.load_after))
    physics.set_field(plant.field_b)
    bound = planar_arm.action_bound(task.spec)
    rng = np.random.default_rng(seed)
    worst, speed = np.zeros(2), 0.0
    for corner in LIMIT_ANGLES:
        physics.set_joint_angles(*corner)
        worst = np.maximum(worst, site_errors(physics))
    for _ in tqdm(range(samples), desc="check-kinematics", disable=not progress):
        physics.set_link_lengths(*rng.uniform(*LENGTH_RANGE, size=2))
        task.before_step(rng.uniform(-bound, bound, size=2), physics)
        for _ in range(plant.sub_steps):
            physics.step(1)
            worst = np.maximum(worst, site_errors(physics))
            speed = max(speed, float(np.max(np.abs(physics.joint_velocities()))))
    return KinematicsReport(samples, "servo", tolerance, float(worst[0]), float(worst[1]), task.spec.name, speed)
