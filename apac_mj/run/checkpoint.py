"""Checkpoints: atomic save, code-free load (``torch.load(weights_only=True)``), clear errors.

A checkpoint is a nested dict of tensors, numbers, strings, lists and dicts.
:func:`save` writes a temporary file next to the destination, fsyncs it and
renames it over the destination, so a crash leaves either the old or the new
file, never a half-written one; the file gets the mode an ordinary ``open``
would give it (0666 minus the umask), so a shared results directory stays
readable. :func:`load` never executes code from the file; a truncated, garbage
or incompatible file raises :class:`CheckpointError` naming the file.

A run keeps two checkpoints (:func:`save_rotating`): ``latest.pt`` and the one
before it, ``previous.pt``; :func:`load_newest_intact` falls back to the newest
one that loads when ``latest.pt`` is damaged.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any, Callable, Iterable

import torch

#: Bumped when the checkpoint layout changes.
FORMAT_VERSION = 1
#: A run's checkpoints (in RUN_DIR/checkpoints): the newest, and the one before it.
LATEST, PREVIOUS = "latest.pt", "previous.pt"


class CheckpointError(RuntimeError):
    """A checkpoint file is missing, corrupt or incompatible."""


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


def save_rotating(obj: dict[str, Any], latest: Path, previous: Path) -> Path:
    """Write ``obj`` as ``latest``; the checkpoint that was ``latest`` becomes ``previous``.

    The new file is complete and fsynced before anything is renamed; a crash between the two
    renames leaves ``previous`` (and no ``latest``), which :func:`load_newest_intact` falls back to.
    """
    latest, previous = Path(latest), Path(previous)
    payload = {**obj, "format_version": FORMAT_VERSION}

    def keep_old() -> None:
        if latest.exists():
            os.replace(latest, previous)

    atomic_write_bytes(latest, lambda f: torch.save(payload, f), before_rename=keep_old)
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
    raise CheckpointError("; ".join(errors) + ("; no intact checkpoint is left: delete the run directory and train "
                                               "again" if len(errors) > 1 else ""))


def run_checkpoints(directory: Path) -> list[Path]:
    """A run's checkpoint files, newest first: latest.pt, previous.pt, then the ``ckpt_*.pt`` of older versions."""
    directory = Path(directory)
    named = [directory / LATEST, directory / PREVIOUS] + sorted(directory.glob("ckpt_*.pt"), reverse=True)
    return [p for p in named if p.is_file()]


def load_run_checkpoint(run_dir: Path, required: Iterable[str] = (),
                        warn: Callable[[str], None] | None = None) -> dict[str, Any]:
    """The newest intact checkpoint of a run directory (``warn`` says so when it is not latest.pt)."""
    run_dir = Path(run_dir)
    found = run_checkpoints(run_dir / "checkpoints")
    if not found:
        raise CheckpointError(f"checkpoint {run_dir / 'checkpoints' / LATEST} does not exist: {run_dir} has no "
                              "checkpoint yet (train it first)")
    return load_newest_intact(found, required=required, warn=warn)[0]


def prune(directory: Path, pattern: str, keep: int) -> None:
    """Delete all but the ``keep`` newest (by name) files matching ``pattern``."""
    files = sorted(Path(directory).glob(pattern))
    for f in files[:-keep] if keep > 0 else files:
        f.unlink(missing_ok=True)
