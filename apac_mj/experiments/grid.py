"""The paper's experiment grid: presets, cells, a results directory that survives kills.

A *preset* (``tasks/presets/*.toml``) names the agents, training conditions,
seeds, episodes and tests. It expands into *cells*, one per (agent,
condition) plus one per (agent, condition) of the generalization study; each
cell trains all its seeds as one ensemble (``trainer.train``) and then runs
its frozen-network tests (``evaluate.evaluate``).

Layout::

    RESULTS/
      manifest.json                      # the resolved preset and every cell's status (atomic writes)
      <agent>__<condition>/              # a run directory (docs/architecture.md) + cell.json
      <agent>__<condition>_train_region/ # generalization: trained on the train region, tested on the held-out one

A finished cell (``DONE`` and ``eval/summary.json``) is skipped; an unfinished
one resumes from its last checkpoint, so re-running the same command after a
kill continues where it stopped and gives the numbers of an uninterrupted run.

One grid writes a results directory (its lock, :mod:`apac_mj.util.lock`; a second grid on it is refused,
naming the first's PID), and each cell is written by the one process that holds the cell's own lock
(a run directory's: :meth:`apac_mj.run.run_dir.RunDir.lock`).
"""
from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import Any

from apac_mj import kinds
from apac_mj.config import TrainConfig, migrate, to_dict, train_config_from_dict
from apac_mj.experiments.executors import Executor, LocalExecutor
from apac_mj.util.files import atomic_write_text, jsonable as _jsonable, read_json, remove_stale_temporaries
from apac_mj.experiments.presets import TRAIN_REGION_SUFFIX, Preset
from apac_mj.experiments.results import CELL_FILE, MANIFEST
from apac_mj.run.build import check
from apac_mj.run.run_dir import RunDir, diff, say
from apac_mj.suite import spec_for
from apac_mj.suite.task_spec import TaskSpec
from apac_mj.util.lock import locked

#: The way out for a damaged cell.json.
_CELL_FIX = ("delete that one file: the grid writes it again from the preset, and the cell's run is checked against "
             "it before anything is trained")


def _cell_file(cell_dir: Path) -> dict[str, Any] | None:
    return read_json(cell_dir / CELL_FILE, fix=_CELL_FIX)


@dataclasses.dataclass(frozen=True)
class Cell:
    """One ensemble job: an agent trained on a task, then tested."""

    agent: str
    #: The training condition (a task; the paper's are CONDITIONS).
    condition: str
    #: "all" (the main study) or "train" (generalization: trained on the train region).
    region: str
    #: Evaluation protocols run after training.
    protocols: tuple[str, ...]

    @property
    def task(self) -> str:
        return self.condition + (TRAIN_REGION_SUFFIX if self.region == "train" else "")

    @property
    def name(self) -> str:
        return f"{self.agent}__{self.task}"

    def train_config(self, preset: Preset) -> TrainConfig:
        return preset.train_config(self.task, self.agent)


def cells(preset: Preset) -> list[Cell]:
    """The grid's cells: main study first (agent-major), then the generalization study."""
    out = []
    for condition in preset.conditions:
        for agent in preset.agents:
            protocols = ("grid",) if preset.tests.grid else ()
            if preset.tests.occluded and kinds.get(agent).acts_occluded:
                protocols += ("occluded",)
            out.append(Cell(agent, condition, "all", protocols))
    if preset.tests.generalization:
        for condition in preset.tests.generalization_conditions:
            for agent in preset.agents:
                out.append(Cell(agent, condition, "train", ("generalization",)))
    return out


def cell_done(cell_dir: Path) -> bool:
    """Finished: training DONE for the cell's episode count and, if it has tests, the evaluation summary written."""
    info, run = _cell_file(cell_dir), RunDir(cell_dir)
    if info is None or not run.finished():
        return False
    if run.episodes() != info["train_config"]["episodes"]:
        return False  # being extended to more episodes
    return not info["protocols"] or run.evaluated()


def _cell_info(cell: Cell, preset: Preset) -> dict[str, Any]:
    cfg = to_dict(cell.train_config(preset))
    return {"agent": cell.agent, "condition": cell.condition, "region": cell.region,
            "protocols": list(cell.protocols), "test_limit": preset.tests.limit, "train_config": _jsonable(cfg)}


def cell_status(cell: Cell, preset: Preset, results: Path) -> tuple[str, str]:
    """What running ``cell`` into ``results`` would do, writing nothing: ("done" | "to run" | "to resume" |
    "to extend" | "refused", why). A cell that differs only by more episodes is extended."""
    cell_dir = Path(results) / cell.name
    if (why := cued_refusal(cell, spec_for(cell.train_config(preset)))) is not None:
        return "refused", why
    info, old = _cell_info(cell, preset), _cell_file(cell_dir)
    if old is None:
        return "to run", ""
    old = {**old, "train_config": migrate(old["train_config"])}
    was, now = old["train_config"]["episodes"], info["train_config"]["episodes"]
    same_but_episodes = _strip_episodes(old) == _strip_episodes(info)
    if old != info and not (same_but_episodes and now > was):
        why = (f"its run has {was} episodes, more than the {now} asked for" if same_but_episodes
               else "; ".join(diff(old, info, "there")))
        return "refused", (f"{cell_dir} holds results of a different configuration ({why}); use another --out "
                           "or delete that directory")
    if now > was:
        return "to extend", f"from {was} to {now} episodes"
    if cell_done(cell_dir):
        return "done", ""
    return ("to resume", "") if RunDir(cell_dir).exists() else ("to run", "")


def _strip_episodes(info: dict[str, Any]) -> dict[str, Any]:
    return {**info, "train_config": {**info["train_config"], "episodes": None}}


def prepare_cell(cell: Cell, preset: Preset, results: Path) -> Path:
    """Create the cell's directory with cell.json (rewritten when extended); refuse one made by a different
    configuration."""
    cell_dir = results / cell.name
    status, why = cell_status(cell, preset, results)
    if status == "refused":
        raise ValueError(why)
    with RunDir(cell_dir).lock():  # no other process writes the cell; a killed writer's temporaries removed
        if status in ("to run", "to extend") and _cell_file(cell_dir) != _cell_info(cell, preset):
            atomic_write_text(cell_dir / CELL_FILE, json.dumps(_cell_info(cell, preset), indent=2))
    return cell_dir


class CuedConditionError(ValueError):
    """A grid condition is a cued task (``[cues]``), whose targets the grid's frozen tests do not test."""


def cued_refusal(cell: Cell, spec: TaskSpec) -> str | None:
    """Why ``cell`` (its task ``spec``) cannot be tested by the grid: a cued task with tests; None: it can."""
    if not spec.cued or not cell.protocols:
        return None
    return (f"condition {cell.condition!r} is a cued task ([cues]): the grid's tests ({', '.join(cell.protocols)}) "
            "reach the angle grid's targets, not its cues, and would fail every cell after its training; remove it "
            "from conditions, or set tests.grid=false and tests.occluded=false to only train it, and study it "
            "with apac-mj forced-response run (docs/forced_response.md)")


def check_grid(preset: Preset, results: Path) -> dict[str, tuple[str, str]]:
    """Every cell's status; raises ValueError naming every refused cell or invalid run (nothing is written), a
    :class:`CuedConditionError` for a cued condition with tests."""
    for c in cells(preset):
        spec = check(c.train_config(preset))  # devices, seeds, the task and its overrides: before anything runs
        if (why := cued_refusal(c, spec)) is not None:
            raise CuedConditionError(f"preset {preset.name!r}: {why}; nothing run")
    statuses = {c.name: cell_status(c, preset, Path(results)) for c in cells(preset)}
    refused = [why for status, why in statuses.values() if status == "refused"]
    if refused:
        raise ValueError(f"{len(refused)} of {len(statuses)} cells refused, nothing run: " + "; ".join(refused))
    return statuses


def run_cell(cell_dir: str | Path, progress: bool = True, threads: int = 1) -> dict[str, Any]:
    """Train (or resume) and test one prepared cell with ``threads`` torch threads; returns its status."""
    from apac_mj.util.threads import set_threads

    set_threads(threads)  # the worker process's, for the whole cell (train and evaluate keep it: threads=)
    cell_dir = Path(cell_dir)
    start = time.perf_counter()
    with RunDir(cell_dir).lock():  # this process is the cell's one writer while it trains and tests it
        info = _cell_file(cell_dir)
        if info is None:
            raise FileNotFoundError(f"{cell_dir / CELL_FILE} missing: prepare the cell first")
        if not cell_done(cell_dir):
            from apac_mj.run.trainer import train

            train(train_config_from_dict(info["train_config"]), cell_dir, progress=progress, threads=threads)
            if info["protocols"]:
                _evaluate(cell_dir, tuple(info["protocols"]), info["test_limit"], threads)
    return {"cell": cell_dir.name, "status": "done", "wall_s": round(time.perf_counter() - start, 3)}


def _evaluate(cell_dir: Path, protocols: tuple[str, ...], limit: int, threads: int = 1) -> None:
    from apac_mj.run.evaluate import evaluate

    evaluate(cell_dir, protocols=protocols, limit=limit or None, threads=threads)


# -- the grid ------------------------------------------------------------------------

def run_grid(preset: Preset, results: str | Path, executor: Executor | None = None,
             progress: bool = True) -> dict[str, Any]:
    """Run every unfinished cell with ``executor`` (default: LocalExecutor) and keep the manifest current."""
    results = Path(results)
    check_grid(preset, results)  # before anything is created
    with locked(results, "grid's results directory"):  # one grid per results directory
        remove_stale_temporaries(results, recursive=False)  # the cells' own: by their writers, under their locks
        return _run_grid(preset, results, executor, progress)


def _run_grid(preset: Preset, results: Path, executor: Executor | None, progress: bool) -> dict[str, Any]:
    """:func:`run_grid` as the results directory's one grid."""
    executor = executor or LocalExecutor()
    grid_cells = cells(preset)
    dirs = {c.name: prepare_cell(c, preset, results) for c in grid_cells}
    manifest = _new_manifest(preset, grid_cells, dirs, executor)
    write_manifest(results, manifest)
    todo = [name for name in dirs if manifest["cells"][name]["status"] != "done"]

    def on_result(res: dict[str, Any]) -> None:
        manifest["cells"][res["cell"]].update({k: v for k, v in res.items() if k != "cell"})
        write_manifest(results, manifest)

    start = time.perf_counter()
    try:
        executor.run([str(dirs[n]) for n in todo], run_cell, on_result, progress=progress,
                     done=len(dirs) - len(todo), total=len(dirs), threads=preset.threads)
    except KeyboardInterrupt:
        finished = sum(c["status"] == "done" for c in manifest["cells"].values())
        say(f"interrupted: {finished} of {len(dirs)} cells of {results} are finished; each unfinished cell keeps its "
            "last checkpoint (said above): run the same command again to resume")
        raise
    manifest["wall_s_this_run"] = round(time.perf_counter() - start, 3)
    write_manifest(results, manifest)
    failed = {n: c["error"] for n, c in manifest["cells"].items() if c["status"] == "failed"}
    if failed:
        raise RuntimeError(f"{len(failed)} cell(s) failed: " + "; ".join(f"{n}: {e}" for n, e in failed.items()))
    return manifest


def _new_manifest(preset: Preset, grid_cells: list[Cell], dirs: dict[str, Path],
                  executor: Executor) -> dict[str, Any]:
    cells_info = {}
    for c in grid_cells:
        status = "done" if cell_done(dirs[c.name]) else "pending"
        cells_info[c.name] = {"agent": c.agent, "condition": c.condition, "region": c.region,
                              "protocols": list(c.protocols), "status": status}
    preset_info = {**dataclasses.asdict(preset), "run": to_dict(preset.run)}  # the run as config.json has it
    return {"preset": _jsonable(preset_info), "executor": type(executor).__name__, "cells": cells_info}


def write_manifest(results: Path, manifest: dict[str, Any]) -> None:
    manifest = dict(manifest, updated=time.strftime("%Y-%m-%dT%H:%M:%S%z"))
    atomic_write_text(results / MANIFEST, json.dumps(manifest, indent=2))


def describe(preset: Preset) -> str:
    """One paragraph saying what a preset runs."""
    cs = cells(preset)
    steps = len(preset.seeds) * preset.episodes
    return (f"preset {preset.name!r}: {len(cs)} cells ({len(preset.agents)} agents x {len(preset.conditions)} conditions"
            f" + {len(cs) - len(preset.agents) * len(preset.conditions)} generalization), {len(preset.seeds)} seeds x "
            f"{preset.episodes} episodes per cell ({steps} seed-episodes), device {preset.device}, {preset.precision}")
