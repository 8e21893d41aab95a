"""Checkpoints: atomic save, code-free load (``torch.load(weights_only=True)``), clear errors.

A checkpoint is a nested dict of tensors, numbers, strings, lists and dicts.
:func:`save` writes it atomically (:func:`apac_mj.util.files.atomic_write_bytes`:
a crash leaves the old or the new file, never a half-written one).
:func:`load` never executes code from the file; a truncated, garbage or
incompatible file raises :class:`CheckpointError` naming the file.

:func:`save_rotating` keeps the checkpoint it replaces as a second file, and
:func:`load_newest_intact` falls back to the newest one that loads. Which files
a run keeps, and what they hold, is :mod:`apac_mj.run.run_dir`'s business.
"""
from __future__ import annotations

import io
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable

from apac_mj.util.files import atomic_write_bytes

if TYPE_CHECKING:  # torch loads on the first save or load: reading a run's other files needs none
    import torch

#: Bumped when the checkpoint layout changes.
FORMAT_VERSION = 1


class CheckpointError(RuntimeError):
    """A checkpoint file is missing, corrupt or incompatible."""


def save(obj: dict[str, Any], path: str | Path) -> Path:
    """Atomically write ``obj`` (with ``format_version`` added) to ``path``."""
    path = Path(path)
    data = _serialize({**obj, "format_version": FORMAT_VERSION})
    atomic_write_bytes(path, lambda f: f.write(data))
    return path


def _serialize(payload: dict[str, Any]) -> bytes:
    """The checkpoint's bytes, made in memory: a full disk then fails in the file write, as an OSError naming
    the file (torch's own writer reports it as an unrelated RuntimeError)."""
    import torch

    buf = io.BytesIO()
    torch.save(payload, buf)
    return buf.getvalue()


def load(path: str | Path, required: Iterable[str] = (), map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """Load a checkpoint without executing code; check ``format_version`` and ``required`` keys."""
    import torch

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


def save_rotating(obj: dict[str, Any], latest: Path, previous: Path) -> Path:
    """Write ``obj`` as ``latest``; the checkpoint that was ``latest`` becomes ``previous``.

    The new file is complete and fsynced before anything is renamed; a crash between the two
    renames leaves ``previous`` (and no ``latest``), which :func:`load_newest_intact` falls back to.
    """
    latest, previous = Path(latest), Path(previous)
    data = _serialize({**obj, "format_version": FORMAT_VERSION})

    def keep_old() -> None:
        if latest.exists():
            os.replace(latest, previous)

    atomic_write_bytes(latest, lambda f: f.write(data), before_rename=keep_old)
    return latest


def load_newest_intact(candidates: Iterable[Path], required: Iterable[str] = (),
                       check: Callable[[dict[str, Any], Path], None] | None = None,
                       warn: Callable[[str], None] | None = None) -> tuple[dict[str, Any], Path]:
    """Load the first of ``candidates`` (newest first) that loads and passes ``check``.

    Every damaged one is reported through ``warn``; if none loads, the error names each file and
    why. ``check(obj, path)`` raises :class:`CheckpointError` for a file that loads but does not fit.
    """
    candidates = [Path(c) for c in candidates]
    errors: list[str] = []
    for path in candidates:
        if not path.is_file():
            continue
        try:
            obj = load(path, required=required)
            if check is not None:
                check(obj, path)
        except CheckpointError as e:
            errors.append(str(e))
            continue
        if errors and warn is not None:
            warn(f"warning: {'; '.join(errors)}; using the newest intact checkpoint, {path}")
        return obj, path
    if not errors:
        raise CheckpointError(f"checkpoint {candidates[0]} does not exist" if candidates else "no checkpoint given")
    raise CheckpointError("; ".join(errors) + ("; no intact checkpoint is left, so the run cannot be resumed or "
                                               "tested: train it again into another --out" if len(errors) > 1 else ""))


def prune(directory: Path, pattern: str, keep: int) -> None:
    """Delete all but the ``keep`` newest (by name) files matching ``pattern``."""
    files = sorted(Path(directory).glob(pattern))
    for f in files[:-keep] if keep > 0 else files:
        f.unlink(missing_ok=True)
