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
"""
from __future__ import annotations

import dataclasses
import json
import re
import time
import tomllib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from apac_mj import kinds, paths
from apac_mj.config import AgentConfig, TrainConfig, to_dict, train_config_from_dict

#: The paper's four training conditions (task files in tasks/).
CONDITIONS = (
    "static_target",
    "static_target_changing_kinematics",
    "changing_target",
    "changing_target_changing_kinematics",
)
TRAIN_REGION_SUFFIX = "_train_region"
CELL_FILE = "cell.json"
MANIFEST = "manifest.json"


class PresetError(ValueError):
    """A preset file or a ``--set`` override is malformed."""


@dataclasses.dataclass(frozen=True)
class Tests:
    """Which frozen-network tests run after training."""

    #: The angle-grid test targets (static-target runs: their own target).
    grid: bool = True
    #: The occluded-vision test (SPAC and APAC only).
    occluded: bool = True
    #: The generalization study: extra cells trained on the train region, tested on the held-out region.
    generalization: bool = True
    #: Training conditions for which the generalization study runs.
    generalization_conditions: tuple[str, ...] = CONDITIONS
    #: Keep only the first ``limit`` test targets per seed (0: all, the paper's 100; smoke runs use a few).
    limit: int = 0


@dataclasses.dataclass(frozen=True)
class Preset:
    """A grid: which agents, conditions, seeds and tests. Field docs double as the file format's docs."""

    name: str
    description: str = ""
    #: Agent kinds (apac_mj.kinds): the paper's ddpg, spac, apac or any registered one.
    agents: tuple[str, ...] = kinds.BUILTIN
    #: Training conditions: task names without the "_train_region"/"_occluded" suffixes.
    conditions: tuple[str, ...] = CONDITIONS
    #: Seeds of every cell (all trained side by side as one ensemble).
    seeds: tuple[int, ...] = tuple(range(50))
    #: Training episodes per seed.
    episodes: int = 1000
    #: Episodes between checkpoints.
    checkpoint_every: int = 50
    device: str = "cpu"
    precision: str = "fp32"
    actuation: str = "servo"
    #: Torch CPU threads per cell. 1 is fastest for these small networks: more threads than free cores
    #: spin at barriers and were 25x slower on a loaded 2-core machine.
    threads: int = 1
    tests: Tests = Tests()
    #: AgentConfig overrides (apac_mj/config.py field names).
    agent: dict[str, Any] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        _check_subset(self.name, "agents", self.agents, kinds.names())
        _check_subset(self.name, "conditions", self.conditions, CONDITIONS)
        _check_subset(self.name, "tests.generalization_conditions", self.tests.generalization_conditions, CONDITIONS)
        if not self.seeds or len(set(self.seeds)) != len(self.seeds) or min(self.seeds) < 0:
            raise PresetError(f"preset {self.name!r}: seeds must be distinct non-negative ints, got {list(self.seeds)}")
        for key in ("episodes", "checkpoint_every", "threads"):
            if not isinstance(getattr(self, key), int) or getattr(self, key) < 1:
                raise PresetError(f"preset {self.name!r}: {key} must be an int >= 1, got {getattr(self, key)!r}")
        _check_subset(self.name, "device", (self.device.split(":")[0],), ("cpu", "cuda"))
        _check_subset(self.name, "precision", (self.precision,), ("fp32", "bf16"))
        _check_subset(self.name, "actuation", (self.actuation,), ("servo", "kinematic"))
        known = {f.name for f in dataclasses.fields(AgentConfig)} - {"agent"}
        unknown = sorted(set(self.agent) - known)
        if unknown:
            raise PresetError(f"preset {self.name!r}: unknown [agent] key(s) {unknown}; known: {sorted(known)}")
        try:
            AgentConfig(**_tuples(self.agent))
        except (TypeError, ValueError) as e:
            raise PresetError(f"preset {self.name!r}: [agent]: {e}") from e


@dataclasses.dataclass(frozen=True)
class Cell:
    """One ensemble job: an agent trained on a task, then tested."""

    agent: str
    #: The paper's training condition (one of CONDITIONS).
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
        agent = AgentConfig(agent=self.agent, **_tuples(preset.agent))
        return TrainConfig(task=self.task, seeds=preset.seeds, episodes=preset.episodes, device=preset.device,
                           precision=preset.precision, checkpoint_every=preset.checkpoint_every,
                           actuation=preset.actuation, agent=agent)


# -- presets ------------------------------------------------------------------------

def preset_path(name_or_path: str | Path) -> Path:
    """A preset's file: a path to a .toml file, or a name in tasks/presets/."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.is_file():
        if not p.is_file():
            raise FileNotFoundError(f"preset file {p} does not exist")
        return p
    candidate = paths.tasks_dir() / "presets" / f"{name_or_path}.toml"
    if not candidate.is_file():
        raise FileNotFoundError(f"unknown preset {str(name_or_path)!r}; known presets: {', '.join(preset_names())} "
                                "(or give a path to a .toml file)")
    return candidate


def preset_names() -> list[str]:
    return sorted(p.stem for p in (paths.tasks_dir() / "presets").glob("*.toml"))


def load_preset(name_or_path: str | Path, overrides: Sequence[str] = ()) -> Preset:
    """Read a preset file and apply ``key=value`` overrides (dotted keys for tables: ``agent.batch_size=64``)."""
    path = preset_path(name_or_path)
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise PresetError(f"preset file {path}: {e}") from e
    for item in overrides:
        key, value = parse_override(item)
        _set_dotted(data, key, value)
    return preset_from_dict(data, name=path.stem)


def parse_override(item: str) -> tuple[str, Any]:
    """``"episodes=50"`` -> ("episodes", 50); values are TOML values, bare words are strings."""
    key, sep, raw = item.partition("=")
    key = key.strip()
    if not sep or not key:
        raise PresetError(f"override {item!r} must look like key=value (e.g. episodes=50, agent.batch_size=64)")
    try:
        value = tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    return key, value


def _set_dotted(data: dict[str, Any], key: str, value: Any) -> None:
    *tables, leaf = key.split(".")
    node = data
    for t in tables:
        node = node.setdefault(t, {})
        if not isinstance(node, dict):
            raise PresetError(f"override {key!r}: {t!r} is not a table")
    node[leaf] = value


def preset_from_dict(data: dict[str, Any], name: str = "<dict>") -> Preset:
    """Validate a parsed preset; unknown keys and bad values raise :class:`PresetError`."""
    data = dict(data)
    fields = {f.name for f in dataclasses.fields(Preset)} - {"name"}
    unknown = sorted(set(data) - fields)
    if unknown:
        raise PresetError(f"preset {name!r}: unknown key(s) {unknown}; known: {sorted(fields)}")
    tests = data.pop("tests", {})
    test_fields = {f.name for f in dataclasses.fields(Tests)}
    if not isinstance(tests, dict) or set(tests) - test_fields:
        raise PresetError(f"preset {name!r}: [tests] keys must be among {sorted(test_fields)}, got {tests!r}")
    limit = tests.get("limit", 0)
    if isinstance(limit, bool) or not isinstance(limit, int) or limit < 0:
        raise PresetError(f"preset {name!r}: tests.limit must be an int >= 0 (0 = all targets), got {limit!r}")
    for key in ("grid", "occluded", "generalization"):
        if not isinstance(tests.get(key, True), bool):
            raise PresetError(f"preset {name!r}: tests.{key} must be true or false, got {tests[key]!r}")
    tests = Tests(**{k: _names(v) if k == "generalization_conditions" else v for k, v in tests.items()})
    if "seeds" in data:
        data["seeds"] = parse_seeds(data["seeds"], name)
    for key in ("agents", "conditions"):
        if key in data:
            data[key] = _names(data[key])
    agent = data.pop("agent", {})
    if not isinstance(agent, dict):
        raise PresetError(f"preset {name!r}: [agent] must be a table of AgentConfig overrides")
    return Preset(name=name, tests=tests, agent=agent, **data)


def parse_seeds(value: Any, name: str = "<dict>") -> tuple[int, ...]:
    """Seeds as an int N (0..N-1), a string "a-b" (inclusive) or "a,b,c", or a list of ints."""
    if isinstance(value, bool):
        raise PresetError(f"preset {name!r}: seeds must be an int, a range 'a-b' or a list, got {value!r}")
    if isinstance(value, int):
        if value < 1:
            raise PresetError(f"preset {name!r}: seeds = {value} must be >= 1")
        return tuple(range(value))
    if isinstance(value, str):
        m = re.fullmatch(r"\s*(\d+)\s*-\s*(\d+)\s*", value)
        if m:
            lo, hi = int(m[1]), int(m[2])
            if hi < lo:
                raise PresetError(f"preset {name!r}: seed range {value!r} is empty")
            return tuple(range(lo, hi + 1))
        if re.fullmatch(r"\s*\d+(\s*,\s*\d+)*\s*", value):
            return tuple(int(s) for s in value.split(","))
    if isinstance(value, (list, tuple)) and all(isinstance(s, int) and not isinstance(s, bool) for s in value):
        return tuple(value)
    raise PresetError(f"preset {name!r}: seeds must be an int N, a range 'a-b', 'a,b,c' or a list of ints, got {value!r}")


def _check_subset(name: str, key: str, values: Sequence[str], allowed: Sequence[str]) -> None:
    if not isinstance(values, tuple):
        raise PresetError(f"preset {name!r}: {key} must be a list, got {values!r}")
    bad = [v for v in values if v not in allowed]
    if bad:
        raise PresetError(f"preset {name!r}: {key} has unknown value(s) {bad}; allowed: {list(allowed)}")


def _names(v: Any) -> Any:
    """A list of names from a TOML list or a comma-separated string ("ddpg,apac")."""
    if isinstance(v, str):
        return tuple(s.strip() for s in v.split(",") if s.strip())
    return _as_tuple(v)


def _as_tuple(v: Any) -> Any:
    return tuple(v) if isinstance(v, list) else v


def _tuples(d: dict[str, Any]) -> dict[str, Any]:
    return {k: _as_tuple(v) for k, v in d.items()}


# -- cells ---------------------------------------------------------------------------

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
    info = read_json(cell_dir / CELL_FILE)
    if info is None or not (cell_dir / "DONE").exists():
        return False
    run = read_json(cell_dir / "config.json")
    if run is None or run.get("episodes") != info["train_config"]["episodes"]:
        return False  # being extended to more episodes
    return not info["protocols"] or (cell_dir / "eval" / "summary.json").exists()


def _cell_info(cell: Cell, preset: Preset) -> dict[str, Any]:
    cfg = to_dict(cell.train_config(preset))
    return {"agent": cell.agent, "condition": cell.condition, "region": cell.region,
            "protocols": list(cell.protocols), "test_limit": preset.tests.limit, "train_config": _jsonable(cfg)}


def cell_status(cell: Cell, preset: Preset, results: Path) -> tuple[str, str]:
    """What running ``cell`` into ``results`` would do, writing nothing: ("done" | "to run" | "to resume" |
    "to extend" | "refused", why). A cell that differs only by more episodes is extended."""
    cell_dir = Path(results) / cell.name
    info, old = _cell_info(cell, preset), read_json(cell_dir / CELL_FILE)
    if old is None:
        return "to run", ""
    was, now = old["train_config"]["episodes"], info["train_config"]["episodes"]
    same_but_episodes = _strip_episodes(old) == _strip_episodes(info)
    if old != info and not (same_but_episodes and now > was):
        why = (f"its run has {was} episodes, more than the {now} asked for" if same_but_episodes
               else _first_difference(old, info))
        return "refused", (f"{cell_dir} holds results of a different configuration ({why}); use another --out "
                           "or delete that directory")
    if now > was:
        return "to extend", f"from {was} to {now} episodes"
    if cell_done(cell_dir):
        return "done", ""
    return ("to resume", "") if (cell_dir / "config.json").is_file() else ("to run", "")


def _strip_episodes(info: dict[str, Any]) -> dict[str, Any]:
    return {**info, "train_config": {**info["train_config"], "episodes": None}}


def prepare_cell(cell: Cell, preset: Preset, results: Path) -> Path:
    """Create the cell's directory with cell.json (rewritten when extended); refuse one made by a different
    configuration."""
    cell_dir = results / cell.name
    status, why = cell_status(cell, preset, results)
    if status == "refused":
        raise ValueError(why)
    cell_dir.mkdir(parents=True, exist_ok=True)
    if status in ("to run", "to extend") and read_json(cell_dir / CELL_FILE) != _cell_info(cell, preset):
        atomic_write_text(cell_dir / CELL_FILE, json.dumps(_cell_info(cell, preset), indent=2))
    return cell_dir


def check_grid(preset: Preset, results: Path) -> dict[str, tuple[str, str]]:
    """Every cell's status; raises ValueError naming every refused cell (nothing is written)."""
    from apac_mj.trainer import check_device

    check_device(preset.device)
    statuses = {c.name: cell_status(c, preset, Path(results)) for c in cells(preset)}
    refused = [why for status, why in statuses.values() if status == "refused"]
    if refused:
        raise ValueError(f"{len(refused)} of {len(statuses)} cells refused, nothing run: " + "; ".join(refused))
    return statuses


def _first_difference(old: dict, new: dict, prefix: str = "") -> str:
    for k in sorted(set(old) | set(new)):
        a, b = old.get(k), new.get(k)
        if isinstance(a, dict) and isinstance(b, dict):
            if a != b:
                return _first_difference(a, b, f"{prefix}{k}.")
        elif a != b:
            return f"{prefix}{k}: {a!r} there, {b!r} now"
    return "no difference"


def run_cell(cell_dir: str | Path, progress: bool = True, threads: int = 1) -> dict[str, Any]:
    """Train (or resume) and test one prepared cell with ``threads`` torch threads; returns its status."""
    import torch

    torch.set_num_threads(threads)
    cell_dir = Path(cell_dir)
    info = read_json(cell_dir / CELL_FILE)
    if info is None:
        raise FileNotFoundError(f"{cell_dir / CELL_FILE} missing: prepare the cell first")
    start = time.perf_counter()
    if not cell_done(cell_dir):
        from apac_mj.trainer import train

        train(train_config_from_dict(info["train_config"]), cell_dir, progress=progress)
        if info["protocols"]:
            _evaluate(cell_dir, tuple(info["protocols"]), info["test_limit"])
    return {"cell": cell_dir.name, "status": "done", "wall_s": round(time.perf_counter() - start, 3)}


def _evaluate(cell_dir: Path, protocols: tuple[str, ...], limit: int) -> None:
    from apac_mj.evaluate import evaluate

    evaluate(cell_dir, protocols=protocols, limit=limit or None)


# -- the grid ------------------------------------------------------------------------

def run_grid(preset: Preset, results: str | Path, executor: Any = None, progress: bool = True) -> dict[str, Any]:
    """Run every unfinished cell with ``executor`` (default: LocalExecutor) and keep the manifest current."""
    from apac_mj.executors import LocalExecutor

    results = Path(results)
    check_grid(preset, results)  # before anything is created
    results.mkdir(parents=True, exist_ok=True)
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
    executor.run([str(dirs[n]) for n in todo], on_result, progress=progress, done=len(dirs) - len(todo),
                 total=len(dirs), threads=preset.threads)
    manifest["wall_s_this_run"] = round(time.perf_counter() - start, 3)
    write_manifest(results, manifest)
    failed = {n: c["error"] for n, c in manifest["cells"].items() if c["status"] == "failed"}
    if failed:
        raise RuntimeError(f"{len(failed)} cell(s) failed: " + "; ".join(f"{n}: {e}" for n, e in failed.items()))
    return manifest


def _new_manifest(preset: Preset, grid_cells: list[Cell], dirs: dict[str, Path], executor: Any) -> dict[str, Any]:
    cells_info = {}
    for c in grid_cells:
        status = "done" if cell_done(dirs[c.name]) else "pending"
        cells_info[c.name] = {"agent": c.agent, "condition": c.condition, "region": c.region,
                              "protocols": list(c.protocols), "status": status}
    return {"preset": _jsonable(dataclasses.asdict(preset)), "executor": type(executor).__name__,
            "cells": cells_info}


def write_manifest(results: Path, manifest: dict[str, Any]) -> None:
    manifest = dict(manifest, updated=time.strftime("%Y-%m-%dT%H:%M:%S%z"))
    atomic_write_text(results / MANIFEST, json.dumps(manifest, indent=2))


# -- results -------------------------------------------------------------------------

KEYS = ["agent", "condition", "region", "seed"]


def cell_dirs(results: str | Path) -> list[Path]:
    results = Path(results)
    if not results.is_dir():
        raise FileNotFoundError(f"results directory {results} does not exist")
    return sorted(p.parent for p in results.glob(f"*/{CELL_FILE}"))


def load_results(results: str | Path) -> pd.DataFrame:
    """Every cell's metrics.parquet as one table keyed by agent, condition, region, seed, episode."""
    frames = []
    for d in cell_dirs(results):
        if (d / "metrics.parquet").exists():
            frames.append(_tag(pd.read_parquet(d / "metrics.parquet"), read_json(d / CELL_FILE)))
    if not frames:
        raise FileNotFoundError(f"no cell in {results} has a metrics.parquet yet")
    df = pd.concat(frames, ignore_index=True)
    return df.sort_values(KEYS + ["episode"], kind="stable").reset_index(drop=True)


def load_tests(results: str | Path) -> pd.DataFrame:
    """Every cell's eval/<protocol>.parquet as one table keyed by agent, condition, region, protocol, seed, target_index."""
    frames = []
    for d in cell_dirs(results):
        for f in sorted((d / "eval").glob("*.parquet")):
            frames.append(_tag(pd.read_parquet(f), read_json(d / CELL_FILE), protocol=f.stem))
    if not frames:
        return pd.DataFrame(columns=KEYS + ["protocol", "target_index"])
    df = pd.concat(frames, ignore_index=True)
    return df.sort_values(KEYS + ["protocol", "target_index"], kind="stable").reset_index(drop=True)


def _tag(df: pd.DataFrame, info: dict[str, Any], **extra: str) -> pd.DataFrame:
    tags = {"agent": info["agent"], "condition": info["condition"], "region": info["region"], **extra}
    for i, (k, v) in enumerate(tags.items()):
        df.insert(i, k, v)
    return df


# -- files ---------------------------------------------------------------------------

def atomic_write_text(path: Path, text: str) -> None:
    """Write to a temporary file in the same directory, fsync, then rename over ``path``."""
    from apac_mj.checkpoint import atomic_write_bytes

    atomic_write_bytes(Path(path), lambda f: f.write(text.encode()))


def read_json(path: Path) -> dict[str, Any] | None:
    return json.loads(path.read_text()) if path.exists() else None


def _jsonable(obj: Any) -> Any:
    return json.loads(json.dumps(obj))


def describe(preset: Preset) -> str:
    """One paragraph saying what a preset runs."""
    cs = cells(preset)
    steps = len(preset.seeds) * preset.episodes
    return (f"preset {preset.name!r}: {len(cs)} cells ({len(preset.agents)} agents x {len(preset.conditions)} conditions"
            f" + {len(cs) - len(preset.agents) * len(preset.conditions)} generalization), {len(preset.seeds)} seeds x "
            f"{preset.episodes} episodes per cell ({steps} seed-episodes), device {preset.device}, {preset.precision}")


ProgressCallback = Callable[[dict[str, Any]], None]
