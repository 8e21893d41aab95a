"""Presets: the experiment grid's configuration (``tasks/presets/*.toml``), read and validated here.

A preset names the agent kinds, training conditions, seeds, episodes and tests
of a grid (:mod:`apac_mj.grid` expands it into cells). Every key is checked
when the file is read and every ``--set`` override before anything runs; an
unknown key or a bad value raises :class:`PresetError` naming it.
"""
from __future__ import annotations

import dataclasses
import re
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from apac_mj import kinds, paths
from apac_mj.config import AgentConfig

#: The paper's four training conditions (task files in tasks/).
CONDITIONS = (
    "static_target",
    "static_target_changing_kinematics",
    "changing_target",
    "changing_target_changing_kinematics",
)


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
