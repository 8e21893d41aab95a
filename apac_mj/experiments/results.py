"""A grid's results directory read back: every cell's metrics and test results as one table each.

Layout (written by :mod:`apac_mj.experiments.grid`): ``RESULTS/manifest.json`` and one run
directory per cell holding ``cell.json`` (the cell's agent kind, condition and
region), ``metrics.parquet`` and ``eval/<protocol>.parquet``.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd

from apac_mj.run.run_dir import RunDir
from apac_mj.util.files import read_json

CELL_FILE = "cell.json"
MANIFEST = "manifest.json"
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
        if RunDir(d).has_metrics():
            frames.append(_tag(RunDir(d).metrics(), read_json(d / CELL_FILE)))
    if not frames:
        raise FileNotFoundError(f"no cell in {results} has a metrics.parquet yet")
    df = pd.concat(frames, ignore_index=True)
    return df.sort_values(KEYS + ["episode"], kind="stable").reset_index(drop=True)


def load_tests(results: str | Path) -> pd.DataFrame:
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
