"""File helpers: atomic writes of bytes, text, JSON and parquet, JSON reads, and the removal of the
temporary files a killed writer left (one copy of each).

An atomic write goes to a temporary file in the destination's folder, is fsynced and renamed over the
destination, so a crash leaves either the old or the new file, never a half-written one; the file gets
the mode an ordinary ``open`` would give it (0666 minus the umask), so a shared results directory stays
readable. The temporary is ``.NAME.PID.XXXXXXXX.tmp`` (PID: the writing process): an exception removes
it at once; after a kill -9 it stays until :func:`remove_stale_temporaries` (run by the next writer of
the directory) removes it. A write that fails for the file system (disk full, read-only, permissions)
raises an :class:`OSError` whose ``filename`` is the file being written.
"""
from __future__ import annotations

import io
import json
import os
import re
import tempfile
from pathlib import Path
from typing import Any, Callable

import pandas as pd

#: The name of an atomic write's temporary file: ``.NAME.PID.RANDOM.tmp`` (older releases: ``.NAME.RANDOM.tmp``).
_TEMPORARY = re.compile(r"^\.(?P<name>.+?)\.(?:(?P<pid>\d+)\.)?(?P<random>[A-Za-z0-9_]{8})\.tmp$")


class DamagedFile(ValueError):
    """A file of a run or a grid that cannot be read (invalid JSON, bad encoding); the message names it."""


def current_umask() -> int:
    """The process's umask (read by setting and restoring it; there is no read-only call)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def temporary_name(path: Path) -> str:
    """The prefix of an atomic write's temporary file for ``path`` (this process's PID in it)."""
    return f".{Path(path).name}.{os.getpid()}."


def atomic_write_bytes(path: Path, write: Any, before_rename: Callable[[], None] | None = None) -> None:
    """Call ``write(fileobj)`` on a temp file in ``path``'s folder, fsync, rename over ``path``.

    The file's mode is ``0666 & ~umask``, as ``open(path, "wb")`` would make it (``mkstemp``
    alone makes it 0600). ``before_rename`` runs after the data is on disk, just before the rename.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=temporary_name(path), suffix=".tmp", dir=path.parent)
    except OSError as e:
        raise _naming(e, path) from None
    try:
        os.fchmod(fd, 0o666 & ~current_umask())
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        if before_rename is not None:
            before_rename()
        os.replace(tmp, path)
    except BaseException as e:
        Path(tmp).unlink(missing_ok=True)
        if isinstance(e, OSError):
            raise _naming(e, path) from None
        raise
    _fsync_dir(path.parent)


def _naming(e: OSError, path: Path) -> OSError:
    """``e`` with ``filename`` the destination (a failed write into a temporary names the file meant)."""
    if e.errno is None:
        return e
    out = type(e)(e.errno, e.strerror, str(path))
    return out


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


def read_json(path: Path, fix: str = "") -> dict[str, Any] | None:
    """The JSON document at ``path``, or None if there is none; a :class:`DamagedFile` naming the file (and
    ``fix``, the way out) if it is not valid JSON."""
    path = Path(path)
    if not path.exists():
        return None
    try:
        return json.loads(path.read_bytes().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise DamagedFile(f"{path} is not valid JSON ({e}): it was damaged or edited by hand; "
                          + (fix or "restore it from a backup")) from None


def jsonable(obj: Any) -> Any:
    """``obj`` as JSON would give it back (tuples as lists)."""
    return json.loads(json.dumps(obj))


def pid_alive(pid: int) -> bool:
    """A process with this PID exists on this machine."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def remove_stale_temporaries(directory: Path, recursive: bool = True, name: str | None = None) -> list[Path]:
    """Remove the temporary files of atomic writes whose writer is gone (killed mid-write) in ``directory``
    (and its sub-directories); return them. A temporary of a live process is kept; one without a PID
    (older releases) is removed, so call this only as the directory's one writer (:mod:`apac_mj.util.lock`).
    With ``name``: only the temporaries of that file, and only those that carry a PID (a folder that is
    not a run's, such as the one a recording goes to)."""
    directory = Path(directory)
    if not directory.is_dir():
        return []
    removed = []
    for f in (directory.rglob(".*.tmp") if recursive else directory.glob(".*.tmp")):
        m = _TEMPORARY.match(f.name)
        if m is None or not f.is_file() or (m["pid"] is not None and pid_alive(int(m["pid"]))):
            continue
        if name is not None and (m["name"] != name or m["pid"] is None):
            continue
        f.unlink(missing_ok=True)
        removed.append(f)
    return removed
