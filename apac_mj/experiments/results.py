"""A grid's results directory read back: every cell's metrics and test results as one table each.

Layout (written by :mod:`apac_mj.experiments.grid`): ``RESULTS/manifest.json`` and one run
directory per cell holding ``cell.json`` (the cell's agent kind, condition and
region), ``metrics.parquet`` and ``eval/<protocol>.parquet``.
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from apac_mj.run.run_dir import RunDir
from apac_mj.util.files import read_json

CELL_FILE = "cell.json"
MANIFEST = "manifest.json"
KEYS = ["agent", "condition", "region", "seed"]


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
    """Every cell's metrics.parquet as one table keyed by agent, condition, region, seed, episode."""
    frames = []
    for d in cell_dirs(results):
        if RunDir(d).has_metrics():
            frames.append(_tag(RunDir(d).metrics(), read_json(d / CELL_FILE)))
    if not frames:
        where = ", ".join(str(r) for r in result_roots(results))
        raise FileNotFoundError(f"no cell in {where} has a metrics.parquet yet")
    df = pd.concat(frames, ignore_index=True)
    return df.sort_values(KEYS + ["episode"], kind="stable").reset_index(drop=True)


def load_tests(results: Results) -> pd.DataFrame:
    """Every cell's eval/<protocol>.parquet as one table keyed by agent, condition, region, protocol, seed, target_index."""
    frames = []
    for d in cell_dirs(results):
        for f in RunDir(d).eval_paths():
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
