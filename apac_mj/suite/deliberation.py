"""The world that does not wait: a task file's ``[deliberation]`` table and what it does to the plant.

Without the table (every task before it) the world waits while the agent decides: a step is the command's
control interval and nothing else. With it, a decision takes time and the plant runs on meanwhile:

* the decision's time (ms, computed by the agent's side from what the decision computed:
  :mod:`apac_mj.run.deliberation`) elapses on the plant **before** the new command starts, at the plant's own
  time resolution: ``round(ms / timestep)`` MuJoCo sub-steps (2 ms on the arms with dynamics, so a decision is
  honoured to within 1 ms), under the **last command**, which MuJoCo's ``ctrl`` keeps (a zero-order hold: the
  torque arm keeps its last torques and coasts or accelerates on, the compliant arm's servos keep pulling to
  their last set-point). Then the new command runs for the control interval (100 ms). A step of a decision
  of 130 ms therefore lasts 230 ms of plant time, the new command starting 130 ms after the observation the
  decision read. (Holding instead was not chosen: on the torque arm holding still needs a torque that nobody
  computed, and zero torque is coasting, not holding.)
* the episode's time limit is a **deadline** in ms of plant time, deliberation included (``deadline_ms``,
  default the step limit's time at zero decision time: ``steps_per_episode`` control intervals). A reach counts
  only if the step that reached ends by the deadline; the episode is cut (a truncation) at the first step that
  ends at or after it, or at the step limit, whichever comes first. Planning longer therefore leaves fewer
  commands before the deadline.

The table needs a plant with dynamics (``[plant] actuation`` "compliant" or "torque"): the ideal arm reaches
every command within its step, whose plant time (40 sub-steps of 10 ms) is not the 100 ms control interval.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any

from apac_mj.suite.plant import TaskSpecError, check_table_keys

#: Keys of the ``[deliberation]`` table.
DELIBERATION_KEYS = ("deadline_ms", "time_scale")
#: Tolerance (ms) of comparisons of plant time with the deadline: MuJoCo's time is a float sum of sub-steps.
TIME_EPS_MS = 1e-6


@dataclasses.dataclass(frozen=True)
class DeliberationSpec:
    """A task where the world does not wait (file table ``[deliberation]``)."""

    #: File key ``[deliberation] deadline_ms``: the episode's time limit in ms of plant time, decisions included
    #: (at least one control interval; the step limit still ends an episode that comes to it first); None (no
    #: key): the step limit's time, ``steps_per_episode x control_interval``.
    deadline_ms: float | None = None
    #: File key ``[deliberation] time_scale``: every decision's time is multiplied by it (1: as mapped from
    #: what the decision computed; 0: the world waits again and only the deadline differs).
    time_scale: float = 1.0


def parse_deliberation(table: Any, source: str, base: DeliberationSpec | None = None) -> DeliberationSpec:
    """The ``[deliberation]`` table as a :class:`DeliberationSpec`, its keys and values checked; ``base``: the
    task's own table, whose keys an override's table keeps where it does not set them."""
    where = f"{source}: [deliberation]"
    if isinstance(table, DeliberationSpec):
        return table
    check_table_keys(table, DELIBERATION_KEYS, where, "[deliberation]")
    if base is not None:
        table = {**dataclasses.asdict(base), **table}
    deadline = table.get("deadline_ms")
    if deadline is not None:
        deadline = _number(deadline, f"{where} deadline_ms", positive=True)
    scale = _number(table.get("time_scale", 1.0), f"{where} time_scale", positive=False)
    return DeliberationSpec(deadline_ms=deadline, time_scale=scale)


def _number(value: Any, where: str, positive: bool) -> float:
    """``value`` as a float: a finite number, > 0 (``positive``) or >= 0."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or value < 0 or (positive and value == 0):
        raise TaskSpecError(f"{where} must be a finite number {'> 0' if positive else '>= 0'}, got {value!r}")
    return float(value)


def interval_ms(spec: Any) -> float:
    """One control interval of ``spec``'s plant (ms)."""
    return spec.plant.control_interval * 1000.0


def deadline_ms(spec: Any) -> float:
    """The episode's deadline (ms of plant time) of a task with a ``[deliberation]`` table."""
    d = spec.deliberation
    return spec.steps_per_episode * interval_ms(spec) if d.deadline_ms is None else d.deadline_ms


def check_deliberation(spec: Any) -> None:
    """A ``[deliberation]`` table fits its task: a plant with dynamics, a deadline of at least one control interval
    (the episode ends at the deadline or at the step limit, whichever comes first)."""
    where = f"task {spec.name!r}: [deliberation]"
    if not spec.plant.dynamic:
        raise TaskSpecError(f"{where} needs a plant with dynamics ([plant] actuation 'compliant' or 'torque'): "
                            "the ideal arm reaches every command within its step, so no plant time runs on "
                            "while the agent decides")
    if deadline_ms(spec) < interval_ms(spec) - TIME_EPS_MS:
        raise TaskSpecError(f"{where} deadline_ms must be at least one control interval ({interval_ms(spec):g} ms: "
                            f"a shorter deadline ends every episode before its first command), got "
                            f"{deadline_ms(spec)!r}")


def substeps(ms: float, timestep_s: float) -> int:
    """How many plant sub-steps of ``timestep_s`` seconds a time of ``ms`` takes: the nearest count (halves up)."""
    if not math.isfinite(ms) or ms < 0:
        raise ValueError(f"a decision's time must be a finite number of ms >= 0, got {ms!r}")
    return int(math.floor(ms / (timestep_s * 1000.0) + 0.5))


def elapse(physics: Any, ms: float) -> int:
    """Run ``physics`` on for ``ms`` (rounded to its sub-steps) under the command it holds; returns the
    sub-steps run."""
    n = substeps(ms, physics.model.opt.timestep)
    if n:
        physics.step(n)
    return n


def elapsed_ms(physics: Any) -> float:
    """Plant time since the episode's start (ms): MuJoCo's time, which the episode's reset sets to 0."""
    return float(physics.data.time) * 1000.0


def in_time(spec: Any, physics: Any) -> bool:
    """The plant's time is at most the deadline (no table: always)."""
    return spec.deliberation is None or elapsed_ms(physics) <= deadline_ms(spec) + TIME_EPS_MS


def time_up(spec: Any, physics: Any) -> bool:
    """The deadline has come (no table: never)."""
    return spec.deliberation is not None and elapsed_ms(physics) >= deadline_ms(spec) - TIME_EPS_MS
