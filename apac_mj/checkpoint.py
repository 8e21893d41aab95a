"""Checkpoints: atomic save, code-free load (``torch.load(weights_only=True)``), clear errors.

A checkpoint is a nested dict of tensors, numbers, strings, lists and dicts.
:func:`save` writes a temporary file next to the destination, fsyncs it and
renames it over the destination, so a crash leaves either the old or the new
file, never a half-written one. :func:`load` never executes code from the
file; a truncated, garbage or incompatible file raises :class:`CheckpointError`
naming the file.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any, Iterable

import torch

#: Bumped when the checkpoint layout changes.
FORMAT_VERSION = 1


class CheckpointError(RuntimeError):
    """A checkpoint file is missing, corrupt or incompatible."""


def atomic_write_bytes(path: Path, write: Any) -> None:
    """Call ``write(fileobj)`` on a temp file in ``path``'s folder, fsync, rename over ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    dir_fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)


def save(obj: dict[str, Any], path: str | Path) -> Path:
    """Atomically write ``obj`` (with ``format_version`` added) to ``path``."""
    path = Path(path)
    payload = {**obj, "format_version": FORMAT_VERSION}
    atomic_write_bytes(path, lambda f: torch.save(payload, f))
    return path


def load(path: str | Path, required: Iterable[str] = (), map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """Load a checkpoint without executing code; check ``format_version`` and ``required`` keys."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint {path} does not exist")
    try:
        obj = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as e:  # torch raises many types for bad bytes (pickle, zip, EOF, ...)
        raise CheckpointError(f"checkpoint {path} is corrupt or incompatible: {type(e).__name__}: {e}") from None
    if not isinstance(obj, dict):
        raise CheckpointError(f"checkpoint {path} is corrupt or incompatible: top level is "
                              f"{type(obj).__name__}, expected dict")
    version = obj.get("format_version")
    if version != FORMAT_VERSION:
        raise CheckpointError(f"checkpoint {path} is corrupt or incompatible: format version {version!r}, "
                              f"this code reads {FORMAT_VERSION}")
    missing = [k for k in required if k not in obj]
    if missing:
        raise CheckpointError(f"checkpoint {path} is corrupt or incompatible: missing key(s) {missing}")
    return obj


def prune(directory: Path, pattern: str, keep: int) -> None:
    """Delete all but the ``keep`` newest (by name) files matching ``pattern``."""
    files = sorted(Path(directory).glob(pattern))
    for f in files[:-keep] if keep > 0 else files:
        f.unlink(missing_ok=True)
