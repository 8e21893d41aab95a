"""apac_mj: the Arbitrated Predictive Actor-Critic (Fard & Trappenberg) on a MuJoCo arm.

The public face, one import for scripts and notebooks::

    import apac_mj

    cfg = apac_mj.TrainConfig(task="changing_target", seeds=(0, 1, 2), episodes=300)
    apac_mj.train(cfg, "runs/apac")
    apac_mj.evaluate("runs/apac")
    apac_mj.run_grid(apac_mj.load_preset("smoke"), "results/smoke")
    apac_mj.write_report("results/smoke")

Names load on first use (module ``__getattr__``), so ``import apac_mj`` and ``apac-mj --help`` stay fast
and torch loads only when something needs it. The layers below are packages: ``suite`` (the plant),
``agent`` (the learner), ``run`` (one run), ``recording``, ``experiments`` (presets and the grid) and
``report``; docs/architecture.md maps them.
"""
from __future__ import annotations

import importlib
import os
from typing import TYPE_CHECKING, Any

# Offscreen rendering must pick its OpenGL backend before dm_control/mujoco load it.
os.environ.setdefault("MUJOCO_GL", "egl")

__version__ = "0.1.0"

#: Public name -> the module that defines it (``"module:attribute"``; a bare module path for modules).
_PUBLIC = {
    "AgentConfig": "apac_mj.config:AgentConfig",
    "TrainConfig": "apac_mj.config:TrainConfig",
    "train": "apac_mj.run.trainer:train",
    "evaluate": "apac_mj.run.evaluate:evaluate",
    "load_preset": "apac_mj.experiments.presets:load_preset",
    "run_grid": "apac_mj.experiments.grid:run_grid",
    "load_results": "apac_mj.experiments.results:load_results",
    "load_tests": "apac_mj.experiments.results:load_tests",
    "write_report": "apac_mj.report:write_report",
    "register_figure": "apac_mj.report:register_figure",
    "FigureSpec": "apac_mj.report:FigureSpec",
    "ReportData": "apac_mj.report:ReportData",
    "record": "apac_mj.recording.record:record",
    "run_demo": "apac_mj.demo:run_demo",
    "register_task": "apac_mj.suite.task_spec:register_task",
    "TaskSpec": "apac_mj.suite.task_spec:TaskSpec",
    "kinds": "apac_mj.kinds",
    "systems": "apac_mj.systems",
    "suite": "apac_mj.suite",
}

__all__ = ["__version__", *_PUBLIC]

if TYPE_CHECKING:  # what a type checker and an IDE see; at run time __getattr__ loads them
    from apac_mj import kinds, suite, systems
    from apac_mj.config import AgentConfig, TrainConfig
    from apac_mj.demo import run_demo
    from apac_mj.experiments.grid import run_grid
    from apac_mj.experiments.presets import load_preset
    from apac_mj.experiments.results import load_results, load_tests
    from apac_mj.recording.record import record
    from apac_mj.report import FigureSpec, ReportData, register_figure, write_report
    from apac_mj.run.evaluate import evaluate
    from apac_mj.run.trainer import train
    from apac_mj.suite.task_spec import TaskSpec, register_task


def __getattr__(name: str) -> Any:
    if name not in _PUBLIC:
        raise AttributeError(f"module 'apac_mj' has no attribute {name!r}")
    module, _, attr = _PUBLIC[name].partition(":")
    value = importlib.import_module(module)
    value = getattr(value, attr) if attr else value
    globals()[name] = value  # later look-ups skip __getattr__
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_PUBLIC))
