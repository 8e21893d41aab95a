"""One override grammar and one seed grammar for every command, and field docs for ``--help``.

``--set KEY=VALUE`` (``apac-mj train``, ``grid``, ``demo``) and preset files set
fields of the run's configuration (:class:`~apac_mj.config.TrainConfig` and its
``agent``, :class:`~apac_mj.config.AgentConfig`); a grid also has preset fields
(:class:`~apac_mj.experiments.presets.Preset`).

* ``KEY`` is a field name; ``agent.NAME`` names an AgentConfig field, and a bare
  AgentConfig field name (``batch_size=64``) means the same. A field of a table
  (a dataclass field marked ``metadata={"tables": True}``: a dict of small
  dataclasses, such as the rules' parameters ``AgentConfig.params``) is reached
  through the table's name, without the field's: ``agent.uncertainty.window=50``
  (or ``uncertainty.window=50``).
* ``VALUE`` is a TOML value (``64``, ``1e-3``, ``true``, ``"text"``, ``[64, 64]``,
  ``{at_limit = "unbounded"}``) or a bare word or comma list (``cpu``,
  ``64,64``), then typed by the field: every value is checked against its
  field's type here, before anything runs.
* Seeds (:func:`parse_seeds`): ``N`` means N seeds 0..N-1, ``a-b`` the range a..b
  (inclusive), ``a,b,c`` or ``[a, b, c]`` a list; ``k-k`` is the single seed k.

Field docs are the ``#:`` comments above each dataclass field; :func:`field_help`
turns them into the ``--help`` text.
"""
from __future__ import annotations

import dataclasses
import inspect
import re
import textwrap
import tomllib
import types
import typing
from typing import Any, Iterable, Sequence


#: At most this many seeds in one run (each is an ensemble member with its own networks and replay buffer).
MAX_SEEDS = 10_000
#: Seeds are below this (numpy's and MuJoCo's seeding take 32-bit seeds).
SEED_LIMIT = 2**32


class OverrideError(ValueError):
    """A ``--set`` override or a configuration value that does not fit its field."""


# -- seeds -----------------------------------------------------------------------------------

def parse_seeds(value: Any, what: str = "seeds") -> tuple[int, ...]:
    """Seeds from an int N (0..N-1), a string 'a-b' (inclusive), 'a,b,c' or 'N', or a list of ints."""
    if isinstance(value, str):
        value = value.strip()
        if re.fullmatch(r"\d+", value):
            value = int(value)
        elif value.startswith("["):
            value = parse_set(f"seeds={value}")[1]
    if isinstance(value, bool):
        raise OverrideError(_seed_grammar(what, value))
    if isinstance(value, int):
        if not 1 <= value <= MAX_SEEDS:
            raise OverrideError(f"{what} = {value} must be in [1, {MAX_SEEDS}] (N means the N seeds 0..N-1; each "
                                "seed is an ensemble member with its own networks)")
        return tuple(range(value))
    seeds = _seed_list(value, what)
    if len(set(seeds)) != len(seeds) or min(seeds) < 0 or max(seeds) >= SEED_LIMIT:
        shown = list(seeds) if len(seeds) <= 10 else f"{list(seeds[:10])} ... ({len(seeds)} seeds)"
        raise OverrideError(f"{what} must be distinct integers in [0, 2^32), got {shown}")
    return seeds


def _seed_list(value: Any, what: str) -> tuple[int, ...]:
    if isinstance(value, str):
        m = re.fullmatch(r"(\d+)\s*-\s*(\d+)", value)
        if m:
            lo, hi = int(m[1]), int(m[2])
            if hi < lo:
                raise OverrideError(f"{what} must be a non-empty range: seed range {value!r} is empty")
            _check_count(hi - lo + 1, what, value)
            return tuple(range(lo, hi + 1))
        if re.fullmatch(r"\d+(\s*,\s*\d+)+", value):
            _check_count(value.count(",") + 1, what, value)
            return tuple(int(s) for s in value.split(","))
    if isinstance(value, (list, tuple)) and value and all(isinstance(s, int) and not isinstance(s, bool)
                                                         for s in value):
        return tuple(value)
    raise OverrideError(_seed_grammar(what, value))


def _check_count(n: int, what: str, value: str) -> None:
    """At most MAX_SEEDS seeds (checked before a range is expanded)."""
    if n > MAX_SEEDS:
        raise OverrideError(f"{what} {value[:40]!r} names {n} seeds; at most {MAX_SEEDS} fit in one run (each is an "
                            "ensemble member with its own networks): split them over several runs")


def _seed_grammar(what: str, value: Any) -> str:
    return (f"{what} must be an int N (the seeds 0..N-1), a range 'a-b', a list 'a,b,c' or [a, b, c] "
            f"(one seed k: 'k-k'), got {value!r}")


# -- KEY=VALUE -------------------------------------------------------------------------------

def parse_set(item: str) -> tuple[str, Any]:
    """``"KEY=VALUE"`` -> (KEY, VALUE as TOML, or the bare text where it is not TOML)."""
    key, sep, raw = item.partition("=")
    key = key.strip()
    if not sep or not key:
        raise OverrideError(f"override {item!r} must look like key=value (e.g. episodes=50, agent.batch_size=64)")
    try:
        return key, tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        return key, raw.strip()


def coerce(value: Any, annotation: Any, where: str) -> Any:
    """``value`` as the type ``annotation`` (from a dataclass field), or :class:`OverrideError` naming ``where``."""
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin in (typing.Union, types.UnionType):
        if value is None or (isinstance(value, str) and value.lower() == "none"):
            if type(None) in args:
                return None
        return coerce(value, next(a for a in args if a is not type(None)), where)
    if annotation is Any:
        return value
    if origin is tuple:
        return _tuple(value, args, where)
    if origin is dict or annotation is dict:
        if not isinstance(value, dict):
            raise OverrideError(f"{where} must be a table such as {{key = value}}, got {value!r}")
        return dict(value)
    return _scalar(value, annotation, where)


def _tuple(value: Any, args: tuple, where: str) -> tuple:
    if isinstance(value, str):
        value = [v for v in value.strip("()[] ").split(",") if v.strip()]
    variable = len(args) == 2 and args[1] is Ellipsis
    if variable and isinstance(value, (int, float)) and not isinstance(value, bool):
        value = [value]  # one number of a list of any length: ``practice=1000`` as ``practice=1000,``
    if not isinstance(value, (list, tuple)):
        raise OverrideError(f"{where} must be a list (e.g. [64, 64] or 64,64), got {value!r}")
    if variable:
        return tuple(coerce(v, args[0], where) for v in value)
    if len(value) != len(args):
        raise OverrideError(f"{where} must have {len(args)} entries, got {list(value)!r}")
    return tuple(coerce(v, a, where) for v, a in zip(value, args))


def _scalar(value: Any, annotation: Any, where: str) -> Any:
    text = value.strip() if isinstance(value, str) else None
    if annotation is bool:
        if isinstance(value, bool):
            return value
        if text is not None and text.lower() in ("true", "false", "1", "0"):
            return text.lower() in ("true", "1")
        raise OverrideError(f"{where} must be true or false, got {value!r}")
    if annotation is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        if text is not None and re.fullmatch(r"[+-]?\d+", text):
            return int(text)
        raise OverrideError(f"{where} must be an integer, got {value!r}")
    if annotation is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        try:
            return float(text) if text is not None else _fail()
        except ValueError:
            raise OverrideError(f"{where} must be a number, got {value!r}") from None
    if annotation is str:
        if isinstance(value, str):
            return value
        raise OverrideError(f"{where} must be a string, got {value!r}")
    return value


def _fail() -> float:
    raise ValueError


def field_types(cls: type) -> dict[str, Any]:
    """``name -> type`` of a dataclass's fields (annotations resolved)."""
    hints = typing.get_type_hints(cls)
    return {f.name: hints[f.name] for f in dataclasses.fields(cls)}


def tables(cls: type) -> tuple[str | None, dict[str, type]]:
    """``cls``'s tables field (None: it has none) and its tables, name -> dataclass (read from a default ``cls()``)."""
    field = next((f.name for f in dataclasses.fields(cls) if f.metadata.get("tables")), None)
    return field, ({} if field is None else {k: type(v) for k, v in getattr(cls(), field).items()})


def keys(cls: type) -> set[str]:
    """The names ``--set`` reaches in dataclass ``cls``: its fields, with a tables field's tables instead of it."""
    field, named = tables(cls)
    return ({f.name for f in dataclasses.fields(cls)} - {field}) | set(named)


def typed_fields(cls: type, values: dict[str, Any], where: str, skip: Iterable[str] = ()) -> dict[str, Any]:
    """``values`` checked against ``cls``'s fields and typed (a table's fields by its dataclass, gathered into
    the tables field); unknown names are an error listing the known."""
    field, named = tables(cls)
    types_ = {k: v for k, v in field_types(cls).items() if k not in set(skip) and k != field}
    unknown = sorted(set(values) - set(types_) - set(named) - {field})
    if unknown:
        hint = did_you_mean(unknown[0], [*types_, *named]) if len(unknown) == 1 else ""
        raise OverrideError(f"{where.rstrip('.')}: unknown {cls.__name__} field(s) {unknown}{hint}; "
                            f"known: {sorted(types_)}" + (f", tables: {sorted(named)}" if named else ""))
    out = {k: coerce(v, types_[k], f"{where}{k}") for k, v in values.items() if k in types_}
    given = {**values.get(field, {}), **{k: v for k, v in values.items() if k in named}} if field else {}
    if given:
        out[field] = {k: _table(named, k, v, f"{where}{k}") for k, v in given.items()}
    return out


def _table(named: dict[str, type], name: str, value: Any, where: str) -> dict[str, Any]:
    if name not in named:
        raise OverrideError(f"{where}: unknown table; known: {sorted(named)}")
    if not isinstance(value, dict):
        raise OverrideError(f"{where} is a table of {named[name].__name__} fields (e.g. {where}.NAME=VALUE), "
                            f"got {value!r}")
    return typed_fields(named[name], value, f"{where}.")


def set_dotted(data: dict[str, Any], key: str, value: Any) -> None:
    """``data[a][b] = value`` for ``key = "a.b"`` (tables created as needed)."""
    *tables, leaf = key.split(".")
    node = data
    for t in tables:
        node = node.setdefault(t, {})
        if not isinstance(node, dict):
            raise OverrideError(f"override {key!r}: {t!r} is not a table")
    node[leaf] = value


def apply_sets(data: dict[str, Any], items: Sequence[str], agent_fields: Iterable[str],
               top_level: Iterable[str]) -> dict[str, Any]:
    """``data`` (a parsed config: top-level keys and an ``agent`` table) with every ``KEY=VALUE`` of
    ``items`` set; a key whose first name is an AgentConfig one (:func:`keys`) and not a top-level key
    goes into ``agent``."""
    agent_fields, top_level = set(agent_fields), set(top_level)
    for item in items:
        key, value = parse_set(item)
        first = key.split(".")[0]
        if first not in top_level and first in agent_fields:
            key = f"agent.{key}"
        elif top_level and first not in top_level | {"agent"}:
            raise OverrideError(f"--set {key}: unknown key(s) [{first!r}]{did_you_mean(first, top_level | agent_fields)} "
                                "(--help lists the fields)")
        set_dotted(data, key, value)
    return data


def did_you_mean(name: str, known: Iterable[str]) -> str:
    """"; did you mean 'batch_size'?" with the known names nearest to a misspelled ``name`` ("" if none is)."""
    import difflib

    close = difflib.get_close_matches(name, sorted(known), n=3, cutoff=0.6)
    return f"; did you mean {' or '.join(repr(c) for c in close)}?" if close else ""


# -- docs for --help -------------------------------------------------------------------------

def field_docs(cls: type) -> dict[str, str]:
    """``name -> doc`` of every field of dataclass ``cls``: the ``#:`` comment lines right above it, or
    for a field without them the title of its section comment (``# -- title ---``)."""
    fields = {f.name for f in dataclasses.fields(cls)}
    docs, pending, section = {}, [], ""
    for line in inspect.getsource(cls).splitlines():
        stripped = line.strip()
        if stripped.startswith("#:"):
            pending.append(stripped[2:].strip())
            continue
        if stripped.startswith("# --"):
            section = stripped.strip("# -")
        m = re.match(r"(\w+)\s*:", stripped)
        if m and m[1] in fields and m[1] not in docs:
            docs[m[1]] = " ".join(pending) if pending else (f"(section: {section})" if section else "")
        if stripped and not stripped.startswith("#"):
            pending = []
    return docs


def field_help(cls: type, prefix: str = "", skip: Iterable[str] = ()) -> str:
    """One line per field of ``cls``: ``prefix+name = default  doc``, a table's as ``prefix+table.name``;
    for an argparse epilog."""
    docs, skip = field_docs(cls), set(skip)
    field, named = tables(cls)
    lines = []
    for f in dataclasses.fields(cls):
        if f.name == field:
            lines += [field_help(table, prefix=f"{prefix}{name}.") for name, table in named.items()]
            continue
        if f.name in skip or dataclasses.is_dataclass(f.type) or f.name.startswith("_"):
            continue
        default = f.default if f.default is not dataclasses.MISSING else (
            f.default_factory() if f.default_factory is not dataclasses.MISSING else "(required)")
        if dataclasses.is_dataclass(default):
            continue
        doc = textwrap.fill(docs.get(f.name, ""), width=100, initial_indent=" " * 6, subsequent_indent=" " * 6)
        lines.append(f"  {prefix}{f.name} = {_show(default)}" + (f"\n{doc}" if doc else ""))
    return "\n".join(lines)


def _show(value: Any) -> str:
    if isinstance(value, tuple):
        return "[" + ", ".join(map(str, value)) + "]"
    return repr(value) if isinstance(value, str) else str(value)
