"""File helpers: atomic writes of bytes, text, JSON and parquet, and JSON reads (one copy of each).

An atomic write goes to a temporary file in the destination's folder, is fsynced and renamed over the
destination, so a crash leaves either the old or the new file, never a half-written one; the file gets
the mode an ordinary ``open`` would give it (0666 minus the umask), so a shared results directory stays
readable.
"""
from __future__ import annotations

import io
import json
import os
import tempfile
from pathlib import Path
from typing import Any, Callable

import pandas as pd


def current_umask() -> int:
    """The process's umask (read by setting and restoring it; there is no read-only call)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def atomic_write_bytes(path: Path, write: Any, before_rename: Callable[[], None] | None = None) -> None:
    """Call ``write(fileobj)`` on a temp file in ``path``'s folder, fsync, rename over ``path``.

    The file's mode is ``0666 & ~umask``, as ``open(path, "wb")`` would make it (``mkstemp``
    alone makes it 0600). ``before_rename`` runs after the data is on disk, just before the rename.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, 0o666 & ~current_umask())
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        if before_rename is not None:
            before_rename()
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)


def _fsync_dir(directory: Path) -> None:
    dir_fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically."""
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
