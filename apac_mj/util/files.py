"""File helpers: atomic writes of text, JSON and parquet, and JSON reads (one copy of each)."""
from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import pandas as pd

from apac_mj.run.checkpoint import atomic_write_bytes


def atomic_write_text(path: Path, text: str) -> None:
    """Write to a temporary file in the same directory, fsync, then rename over ``path``."""
    atomic_write_bytes(Path(path), lambda f: f.write(text.encode()))


def atomic_write_parquet(path: Path, df: pd.DataFrame) -> None:
    """Write ``df`` (without its index) as parquet, atomically."""
    buf = io.BytesIO()
    df.to_parquet(buf, index=False)
    atomic_write_bytes(Path(path), lambda f: f.write(buf.getvalue()))


def read_json(path: Path) -> dict[str, Any] | None:
    """The JSON document at ``path``, or None if there is none."""
    return json.loads(Path(path).read_text()) if Path(path).exists() else None


def jsonable(obj: Any) -> Any:
    """``obj`` as JSON would give it back (tuples as lists)."""
    return json.loads(json.dumps(obj))
