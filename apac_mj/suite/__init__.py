"""dm_control-style suite for the APAC arm.

    env = apac_mj.suite.load("planar_arm", "changing_target", task_kwargs={"random": 0})

Tasks are the TOML files in ``tasks/``; ``ALL_TASKS`` lists their ``(domain, task)``
pairs. :func:`register_task` adds one from user code (docs/extending.md). ``task_kwargs`` takes ``random`` (seed or RandomState), ``actuation``
("servo", the default, or "kinematic") and any :class:`TaskSpec` field as an
override (e.g. ``target_region="test"``).
"""
from __future__ import annotations

from typing import Any

from dm_control.rl import control

from apac_mj.config import TrainConfig

from apac_mj.suite import planar_arm
from apac_mj.suite.task_spec import (TaskSpec, TaskSpecError, load_task, load_task_file, register_task,
                                     task_names, unregister_task)

DOMAINS = {"planar_arm": planar_arm}
ALL_TASKS: tuple[tuple[str, str], ...] = tuple(("planar_arm", name) for name in task_names())


def load_spec(task_name: str, **overrides: Any) -> TaskSpec:
    spec = load_task(task_name)
    return spec.replace(**overrides) if overrides else spec


def spec_for(cfg: TrainConfig) -> TaskSpec:
    """A run's task: ``tasks/<cfg.task>.toml`` (or a registered task) with ``cfg.task_overrides`` applied."""
    return load_spec(cfg.task).replace(**cfg.task_overrides)


def load(
    domain_name: str = "planar_arm",
    task_name: str = "changing_target",
    task_kwargs: dict[str, Any] | None = None,
    environment_kwargs: dict[str, Any] | None = None,
) -> control.Environment:
    """Build a task's ``dm_env.Environment`` (a dm_control ``control.Environment``)."""
    if domain_name not in DOMAINS:
        raise KeyError(f"unknown domain {domain_name!r}; known domains: {', '.join(DOMAINS)}")
    task_kwargs = dict(task_kwargs or {})
    random = task_kwargs.pop("random", None)
    actuation = task_kwargs.pop("actuation", "servo")
    spec = load_spec(task_name, **task_kwargs)
    return planar_arm.make_environment(spec, actuation=actuation, random=random, **(environment_kwargs or {}))


__all__ = ["ALL_TASKS", "TaskSpec", "TaskSpecError", "load", "load_spec", "load_task_file", "register_task",
           "spec_for", "unregister_task"]
