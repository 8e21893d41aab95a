"""A grid's results directory read back: every cell's metrics and test results as one table each.

Layout (written by :mod:`apac_mj.experiments.grid`): ``RESULTS/manifest.json`` and one run
directory per cell holding ``cell.json`` (the cell's agent kind, condition and
region), ``metrics.parquet`` and ``eval/<protocol>.parquet``.

Nothing is taken on trust: a table without a column the report reads, with a NaN where a count or key must be,
an infinite value anywhere, a training episode twice, or fewer test rows than its ``eval/summary.json`` counts is
an error naming the file and the column (:class:`ResultsError`). A grid that is not complete (a cell still
training, one without its tests, one the manifest lists but the directory lacks) is reported, and said so:
:func:`completeness`.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from apac_mj.run.run_dir import METRICS, RunDir
from apac_mj.util.files import read_json

CELL_FILE = "cell.json"
MANIFEST = "manifest.json"
KEYS = ["agent", "condition", "region", "seed"]
#: The columns of metrics.parquet the report reads; none of them may be NaN.
METRIC_REQUIRED = ("seed", "episode", "phase", "success", "steps", "habit_actions", "planning_actions")
#: The columns of eval/<protocol>.parquet the report reads; none of them may be NaN.
TEST_REQUIRED = ("seed", "target_index", "target_x", "target_y", "success", "steps", "final_distance",
                 "habit_actions", "planning_actions", "time_cost")
_WAY_OUT = "rerun the cell (apac-mj grid resumes it) or restore the file from a backup"


class ResultsError(ValueError):
    """A results table the report cannot trust (its message names the file, the column and the way out)."""


#: One results directory, or several read as one (each cell in only one of them).
Results = str | Path | Sequence[str | Path]


def result_roots(results: Results) -> list[Path]:
    """``results`` as a list of directories (one path, or several)."""
    return [Path(results)] if isinstance(results, (str, Path)) else [Path(r) for r in results]


def cell_dirs(results: Results) -> list[Path]:
    """The cells of one results directory, or of several. Across several, a cell (agent, condition, region)
    that holds metrics in two of them is an error naming both (the report could not tell which to use); one
    that a grid only prepared (no metrics yet, e.g. a grid stopped before it) gives way to the other."""
    roots = result_roots(results)
    if not roots:
        raise ValueError("no results directory given")
    for root in roots:
        if not root.is_dir():
            raise FileNotFoundError(f"results directory {root} does not exist")
    dirs = [p.parent for root in roots for p in sorted(root.glob(f"*/{CELL_FILE}"))]
    if len(roots) == 1:
        return dirs
    seen: dict[tuple[str, str, str], Path] = {}
    for d in dirs:
        info = read_json(d / CELL_FILE) or {}
        key = (info.get("agent"), info.get("condition"), info.get("region"))
        other = seen.get(key)
        if other is not None and RunDir(other).has_metrics() and RunDir(d).has_metrics():
            raise ValueError(f"the cell {d.name} has results in two of the results directories given ({other} "
                             f"and {d}); give each cell once")
        if other is None or not RunDir(other).has_metrics():
            seen[key] = d
    return list(seen.values())


def load_results(results: Results) -> pd.DataFrame:
    """Every cell's metrics.parquet as one table keyed by agent, condition, region, seed, episode (each file
    checked: :func:`check_metrics`)."""
    frames = []
    for d in cell_dirs(results):
        if RunDir(d).has_metrics():
            path = d / METRICS
            frames.append(_tag(check_metrics(RunDir(d).metrics(), path), read_json(d / CELL_FILE)))
    if not frames:
        where = ", ".join(str(r) for r in result_roots(results))
        raise FileNotFoundError(f"no cell in {where} has a metrics.parquet yet")
    df = pd.concat(frames, ignore_index=True)
    return df.sort_values(KEYS + ["episode"], kind="stable").reset_index(drop=True)


def load_tests(results: Results) -> pd.DataFrame:
    """Every cell's eval/<protocol>.parquet as one table keyed by agent, condition, region, protocol, seed,
    target_index (each file checked against its summary: :func:`check_tests`)."""
    frames = []
    for d in cell_dirs(results):
        summary = _summary(RunDir(d))
        for f in RunDir(d).eval_paths():
            counted = summary.get(f.stem, {}).get("episodes") if isinstance(summary.get(f.stem), dict) else None
            frames.append(_tag(check_tests(pd.read_parquet(f), f, counted), read_json(d / CELL_FILE),
                               protocol=f.stem))
    if not frames:
        return pd.DataFrame(columns=KEYS + ["protocol", "target_index"])
    df = pd.concat(frames, ignore_index=True)
    return df.sort_values(KEYS + ["protocol", "target_index"], kind="stable").reset_index(drop=True)


def check_metrics(df: pd.DataFrame, path: Path) -> pd.DataFrame:
    """``df`` (read from ``path``) if the report can trust it: rows, the columns it reads, no NaN in them, no
    infinite value, each (seed, episode) once; else a :class:`ResultsError` naming the file and the column."""
    if df.empty:
        raise ResultsError(f"{path} holds no rows; {_WAY_OUT}")
    _check_columns(df, path, METRIC_REQUIRED)
    dupes = df[df.duplicated(subset=["seed", "episode"], keep=False)]
    if len(dupes):
        first = dupes.iloc[0]
        raise ResultsError(f"{path}: columns 'seed', 'episode' repeat in {len(dupes)} rows (e.g. seed "
                           f"{first['seed']}, episode {first['episode']}): each training episode must appear "
                           f"once; {_WAY_OUT}")
    return df


def check_tests(df: pd.DataFrame, path: Path, counted: int | None = None) -> pd.DataFrame:
    """``df`` (read from ``path``) if the report can trust it: the columns it reads, no NaN in them, no infinite
    value, and as many rows as eval/summary.json counted (``counted``; None: not known)."""
    if df.empty:
        return df
    _check_columns(df, path, TEST_REQUIRED)
    if counted is not None and len(df) != counted:
        raise ResultsError(f"{path} holds {len(df)} test episodes, but eval/summary.json counted {counted}: rows "
                           f"were lost or added since the test; rerun apac-mj evaluate on the cell "
                           f"({path.parent.parent})")
    return df


def _check_columns(df: pd.DataFrame, path: Path, required: Sequence[str]) -> None:
    """The ``required`` columns are there and never NaN, and no numeric column holds an infinite value."""
    missing = [c for c in required if c not in df.columns]
    if missing:
        raise ResultsError(f"{path} has no column {', '.join(missing)} (the report reads it); {_WAY_OUT}")
    for column in required:
        n = int(df[column].isna().sum())
        if n:
            raise ResultsError(f"{path}: column {column!r} is NaN in {n} of {len(df)} rows; {_WAY_OUT}")
    for column in df.select_dtypes(include="number").columns:
        n = int(np.isinf(df[column].to_numpy(dtype=float)).sum())
        if n:
            raise ResultsError(f"{path}: column {column!r} is infinite in {n} of {len(df)} rows; {_WAY_OUT}")


def _summary(run: RunDir) -> dict[str, Any]:
    """The per-protocol entries of the run's eval/summary.json ({} where there is none or it does not read)."""
    try:
        protocols = run.eval_summary().get("protocols", {})
    except ValueError:
        return {}
    return protocols if isinstance(protocols, dict) else {}


@dataclasses.dataclass(frozen=True)
class Completeness:
    """How much of a grid the results directory holds: ``done`` of ``expected`` cells, and why each other one
    is missing (cell name -> reason)."""

    expected: int
    done: int
    missing: dict[str, str]

    @property
    def partial(self) -> bool:
        return self.done < self.expected

    def notice(self) -> str:
        """"partial: N of M cells complete (...)", or "" for a complete grid."""
        if not self.partial:
            return ""
        why = "; ".join(f"{name}: {reason}" for name, reason in sorted(self.missing.items()))
        return (f"partial: {self.done} of {self.expected} cells complete, the numbers cover only the cells "
                f"there are ({why})")


def completeness(results: Results) -> Completeness:
    """Which cells of the grid(s) are complete: trained to the end (DONE) with every test its cell.json lists.
    The cells expected are those of each manifest.json (else the cell directories found)."""
    dirs = {d.name: d for d in cell_dirs(results)}
    expected: set[str] = set(dirs)
    for root in result_roots(results):
        manifest = read_json(root / MANIFEST) or {}
        expected |= set(manifest.get("cells", {}) if isinstance(manifest.get("cells"), dict) else ())
    missing = {name: _missing_reason(dirs.get(name)) for name in sorted(expected)}
    missing = {name: why for name, why in missing.items() if why}
    return Completeness(len(expected), len(expected) - len(missing), missing)


def _missing_reason(cell_dir: Path | None) -> str:
    """Why the cell is not complete ("" when it is)."""
    if cell_dir is None:
        return "no directory"
    run = RunDir(cell_dir)
    if not run.has_metrics():
        return "not trained yet"
    if not run.finished():
        return "training not finished"
    protocols = (read_json(cell_dir / CELL_FILE) or {}).get("protocols", [])
    absent = [p for p in protocols if not (cell_dir / "eval" / f"{p}.parquet").is_file()]
    return f"no test results for {', '.join(absent)}" if absent else ""


def _tag(df: pd.DataFrame, info: dict[str, Any], **extra: str) -> pd.DataFrame:
    tags = {"agent": info["agent"], "condition": info["condition"], "region": info["region"], **extra}
    for i, (k, v) in enumerate(tags.items()):
        df.insert(i, k, v)
    return df
