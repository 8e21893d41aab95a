"""Presets: the experiment grid's configuration (``tasks/presets/*.toml``), read and validated here.

A preset names the agent kinds, training conditions and tests of a grid
(:mod:`apac_mj.experiments.grid` expands it into cells) and embeds the run configuration
every cell trains with: its top-level ``seeds``, ``episodes``,
``checkpoint_every``, ``device``, ``precision``, ``actuation`` and its
``[agent]`` table are :class:`~apac_mj.config.TrainConfig` and
:class:`~apac_mj.config.AgentConfig` fields, documented there; the rules'
and integrators' parameters are ``[agent.<table>]`` tables
(:mod:`apac_mj.rules`: ``[agent.kalman]``, ``window = 100``). Files and
``--set`` overrides share one grammar (:mod:`apac_mj.util.overrides`); every key
and value is checked when the preset is read, before anything runs, and a bad
one raises :class:`PresetError` naming it.
"""
from __future__ import annotations

import copy
import dataclasses
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from apac_mj import kinds
from apac_mj.util import overrides, paths
from apac_mj.config import ACTUATIONS, DEVICES, PRECISION_REQUESTS, AgentConfig, TrainConfig

#: The paper's four training conditions (task files in tasks/).
CONDITIONS = (
    "static_target",
    "static_target_changing_kinematics",
    "changing_target",
    "changing_target_changing_kinematics",
)
TRAIN_REGION_SUFFIX = "_train_region"
#: The TrainConfig fields a preset sets at its top level (the task is each cell's; ``agent`` is the [agent] table).
RUN_FIELDS = ("seeds", "episodes", "checkpoint_every", "device", "precision", "actuation", "task_overrides")
#: A preset's run configuration where the file says nothing: the paper's 50 seeds, TrainConfig's other defaults.
DEFAULT_RUN = {"seeds": tuple(range(50))}


class PresetError(ValueError):
    """A preset file or a ``--set`` override is malformed."""


@dataclasses.dataclass(frozen=True)
class Tests:
    """Which frozen-network tests run after training."""

    #: The angle-grid test targets (static-target runs: their own target).
    grid: bool = True
    #: The occluded-vision test (agent kinds that act in the dark: SPAC and APAC).
    occluded: bool = True
    #: The generalization study: extra cells trained on the train region, tested on the held-out region.
    generalization: bool = True
    #: Training conditions for which the generalization study runs.
    generalization_conditions: tuple[str, ...] = CONDITIONS
    #: Keep only the first ``limit`` test targets per seed (0: all, the paper's 100; smoke runs use a few).
    limit: int = 0


@dataclasses.dataclass(frozen=True)
class Preset:
    """A grid: which agent kinds, conditions and tests, and the run every cell trains. Field docs double
    as the file format's docs (the run's fields: TrainConfig and AgentConfig in apac_mj/config.py)."""

    name: str
    #: One paragraph saying what the grid is for (shown in report.md).
    description: str = ""
    #: Agent kinds (apac_mj.kinds): the paper's ddpg, spac, apac or any registered one.
    agents: tuple[str, ...] = kinds.PAPER_KINDS
    #: Training conditions: the paper's four, or any task (file or registered) not ending in "_train_region"
    #: or "_occluded".
    conditions: tuple[str, ...] = CONDITIONS
    #: Torch CPU threads per cell. 1 is fastest for these small networks: more threads than free cores
    #: spin at barriers and were 25x slower on a loaded 2-core machine.
    threads: int = 1
    tests: Tests = Tests()
    #: The run every cell trains (its task is the cell's): the file's run keys and [agent] table applied
    #: (the table's AgentConfig overrides are ``run.agent``; each cell sets the kind).
    run: TrainConfig = dataclasses.field(default_factory=lambda: TrainConfig(**DEFAULT_RUN))

    def __post_init__(self) -> None:
        _check_subset(self.name, "agents", self.agents, kinds.names())
        for kind in self.agents:
            try:
                kinds.check(dataclasses.replace(self.run.agent, kind=kind))
            except ValueError as e:
                raise PresetError(f"preset {self.name!r}, agent {kind!r}: {e}") from None
        _check_subset(self.name, "conditions", self.conditions, known_conditions())
        _check_subset(self.name, "tests.generalization_conditions", self.tests.generalization_conditions,
                      known_conditions())
        if self.tests.generalization:
            tasks = set(_task_names())
            missing = [c for c in self.tests.generalization_conditions if c + TRAIN_REGION_SUFFIX not in tasks]
            if missing:
                raise PresetError(f"preset {self.name!r}: generalization needs a task "
                                  f"'<condition>{TRAIN_REGION_SUFFIX}' for {missing}; add it or set "
                                  "tests.generalization_conditions")
        if not isinstance(self.threads, int) or isinstance(self.threads, bool) or self.threads < 1:
            raise PresetError(f"preset {self.name!r}: threads must be an int >= 1, got {self.threads!r}")

    # The run's fields, read through (the preset does not declare them again).
    seeds = property(lambda self: self.run.seeds, doc="TrainConfig.seeds of every cell.")
    episodes = property(lambda self: self.run.episodes, doc="TrainConfig.episodes of every cell.")
    checkpoint_every = property(lambda self: self.run.checkpoint_every, doc="TrainConfig.checkpoint_every.")
    device = property(lambda self: self.run.device, doc="TrainConfig.device.")
    precision = property(lambda self: self.run.precision, doc="TrainConfig.precision.")
    actuation = property(lambda self: self.run.actuation, doc="TrainConfig.actuation.")

    def train_config(self, task: str, agent: str) -> TrainConfig:
        """The run of one cell: this preset's run on ``task`` with agent kind ``agent``."""
        run = copy.deepcopy(self.run)
        return dataclasses.replace(run, task=task, agent=dataclasses.replace(run.agent, kind=agent))


def known_conditions() -> tuple[str, ...]:
    """The paper's conditions first, then every other task that is not a variant (occluded, train region)."""
    others = [t for t in _task_names() if t not in CONDITIONS and not t.endswith((TRAIN_REGION_SUFFIX, "_occluded"))]
    return CONDITIONS + tuple(others)


def _task_names() -> list[str]:
    from apac_mj.suite.task_spec import task_names  # the environment layer, loaded when first needed

    return task_names()


# -- reading presets ------------------------------------------------------------

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


def top_level_keys() -> set[str]:
    """The keys a preset file has at its top level (tables included; ``agent`` is the run's [agent] table)."""
    return ({f.name for f in dataclasses.fields(Preset)} - {"name", "run"}) | set(RUN_FIELDS) | {"agent"}


def load_preset(name_or_path: str | Path, overrides_: Sequence[str] = ()) -> Preset:
    """Read a preset file and apply ``key=value`` overrides (the grammar of :mod:`apac_mj.util.overrides`:
    dotted keys for tables, ``agent.batch_size=64``; a bare AgentConfig field name means ``agent.NAME``)."""
    path = preset_path(name_or_path)
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise PresetError(f"preset file {path}: {e}") from e
    try:
        overrides.apply_sets(data, overrides_, agent_fields=_agent_fields(), top_level=top_level_keys())
    except overrides.OverrideError as e:
        raise PresetError(str(e)) from None
    return preset_from_dict(data, name=path.stem)


def parse_override(item: str) -> tuple[str, Any]:
    """``"episodes=50"`` -> ("episodes", 50) (:func:`apac_mj.util.overrides.parse_set`)."""
    try:
        return overrides.parse_set(item)
    except overrides.OverrideError as e:
        raise PresetError(str(e)) from None


def preset_from_dict(data: dict[str, Any], name: str = "<dict>") -> Preset:
    """Validate a parsed preset; unknown keys and bad values raise :class:`PresetError`."""
    data = dict(data)
    unknown = sorted(set(data) - top_level_keys())
    if unknown:
        raise PresetError(f"preset {name!r}: unknown key(s) {unknown}; known: {sorted(top_level_keys())}")
    tests = _tests(data.pop("tests", {}), name)
    for key in ("agents", "conditions"):
        if key in data:
            data[key] = _names(data[key])
    run = _run(data, _agent_table(data.pop("agent", {}), name), name)
    return Preset(name=name, tests=tests, run=run, **data)


def _tests(tests: Any, name: str) -> Tests:
    test_fields = {f.name for f in dataclasses.fields(Tests)}
    if not isinstance(tests, dict) or set(tests) - test_fields:
        raise PresetError(f"preset {name!r}: [tests] keys must be among {sorted(test_fields)}, got {tests!r}")
    limit = tests.get("limit", 0)
    if isinstance(limit, bool) or not isinstance(limit, int) or limit < 0:
        raise PresetError(f"preset {name!r}: tests.limit must be an int >= 0 (0 = all targets), got {limit!r}")
    for key in ("grid", "occluded", "generalization"):
        if not isinstance(tests.get(key, True), bool):
            raise PresetError(f"preset {name!r}: tests.{key} must be true or false, got {tests[key]!r}")
    return Tests(**{k: _names(v) if k == "generalization_conditions" else v for k, v in tests.items()})


def _agent_fields() -> set[str]:
    return overrides.keys(AgentConfig) - {"kind"}


def _agent_table(agent: Any, name: str) -> dict[str, Any]:
    """The [agent] table typed by AgentConfig's fields and tables (the kind is each cell's, so ``kind`` is
    refused)."""
    if not isinstance(agent, dict):
        raise PresetError(f"preset {name!r}: [agent] must be a table of AgentConfig overrides")
    unknown = sorted(set(agent) - _agent_fields())
    if unknown:
        hint = overrides.did_you_mean(unknown[0], _agent_fields()) if len(unknown) == 1 else ""
        raise PresetError(f"preset {name!r}: unknown [agent] key(s) {unknown}{hint}; known: {sorted(_agent_fields())}")
    try:
        return overrides.typed_fields(AgentConfig, agent, "agent.")
    except overrides.OverrideError as e:
        raise PresetError(f"preset {name!r}: {e}") from None


def agent_overrides(items: Sequence[str]) -> dict[str, Any]:
    """``KEY=VALUE`` strings (``NAME`` or ``agent.NAME``) -> AgentConfig keyword arguments, for scripts that
    build their own configs (bench/learning.py): the grammar of an [agent] table and of ``--set``, typed by the
    field, an unknown name or a bad value refused (:class:`~apac_mj.util.overrides.OverrideError`)."""
    fields = _agent_fields()
    data = overrides.apply_sets({}, items, agent_fields=fields, top_level=())
    stray = sorted(set(data) - {"agent"})
    if stray:
        raise overrides.OverrideError(f"--set: unknown AgentConfig field(s) {stray}; known: {', '.join(sorted(fields))}")
    return overrides.typed_fields(AgentConfig, data.get("agent", {}), "--set agent.", skip=("kind",))


def _run(data: dict[str, Any], agent: dict[str, Any], name: str) -> TrainConfig:
    """The preset's run (popping its keys from ``data``), every value checked before anything runs."""
    run = {**DEFAULT_RUN, **{k: data.pop(k) for k in RUN_FIELDS if k in data}}
    for key in ("episodes", "checkpoint_every"):
        if key in run and (not isinstance(run[key], int) or isinstance(run[key], bool) or run[key] < 1):
            raise PresetError(f"preset {name!r}: {key} must be an int >= 1, got {run[key]!r}")
    if "device" in run:
        _check_subset(name, "device", (str(run["device"]).split(":")[0],), DEVICES)
    _check_subset(name, "precision", (run.get("precision", "fp32"),), PRECISION_REQUESTS)
    _check_subset(name, "actuation", (run.get("actuation", "servo"),), ACTUATIONS)
    try:
        run["seeds"] = overrides.parse_seeds(run["seeds"])
        typed = overrides.typed_fields(TrainConfig, run, "", skip=("agent", "task"))
        return TrainConfig(agent=AgentConfig(**agent), **typed)
    except (TypeError, ValueError) as e:
        raise PresetError(f"preset {name!r}: {e}") from None


def parse_seeds(value: Any, name: str = "<dict>") -> tuple[int, ...]:
    """Seeds in the one seed grammar (:func:`apac_mj.util.overrides.parse_seeds`); errors name the preset."""
    try:
        return overrides.parse_seeds(value)
    except overrides.OverrideError as e:
        raise PresetError(f"preset {name!r}: {e}") from None


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
    return tuple(v) if isinstance(v, list) else v
