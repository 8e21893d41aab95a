"""One writer per directory: an advisory ``fcntl.flock`` on ``DIR/.lock``.

The operating system releases the lock when its holder exits, however it exits (kill -9 included), so
a lock never outlives its process and there is nothing stale to clean up. The file holds the holder's
PID and command line, read back only to name the holder when a second writer is refused
(:class:`DirectoryLocked`). The lock is re-entrant within a process (a grid cell's runner holds it
while training and testing, which take it again), and it is not inherited by child processes.
"""
from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import sys
import time
from pathlib import Path
from typing import Iterator

#: The lock file in a locked directory.
LOCK_FILE = ".lock"

#: Locks this process holds: resolved directory -> (file descriptor, depth).
_HELD: dict[Path, list[int]] = {}


class DirectoryLocked(RuntimeError):
    """Another process writes the directory; the message names it by PID."""


def holder(directory: Path) -> str:
    """Who holds ``directory``'s lock, as its lock file says ("PID 123 (apac-mj train ...)")."""
    try:
        text = (Path(directory) / LOCK_FILE).read_text(errors="replace").strip()
    except OSError:
        return "another process"
    pid, _, rest = text.partition("\n")
    return f"PID {pid} ({rest.strip()})" if pid.isdigit() else "another process"


@contextlib.contextmanager
def locked(directory: str | Path, what: str = "run directory") -> Iterator[Path]:
    """Hold ``directory``'s lock (created with the directory if needed) for the ``with`` block.

    A directory another process holds raises :class:`DirectoryLocked` naming that process's PID at once
        (no waiting: two writers of one run are a mistake to point out, not to serialize). In a directory
    that cannot be written (read-only file system, no permission) the block runs without the lock: there
    is no writer to keep out, and reads still work (a finished run on a read-only disk). A directory this
    call created is removed again if nothing but the lock file is in it at the end (a refused or failed
    start leaves nothing behind)."""
    directory = Path(directory)
    created = not directory.exists()
    key = directory.resolve()
    if key in _HELD:
        _HELD[key][1] += 1
        try:
            yield directory
        finally:
            _HELD[key][1] -= 1
        return
    try:
        fd: int | None = _acquire(directory, what)
    except OSError as e:
        if created:  # e.g. a full disk: leave nothing behind
            _remove_if_only_lock(directory)
        if e.errno not in (errno.EROFS, errno.EACCES, errno.EPERM) or not directory.is_dir():
            raise
        fd = None  # nobody can write here: no second writer to keep out (a write fails with its own message)
    if fd is None:
        yield directory
        return
    _HELD[key] = [fd, 1]
    try:
        yield directory
    finally:
        del _HELD[key]
        if created and [p.name for p in directory.iterdir()] == [LOCK_FILE]:
            (directory / LOCK_FILE).unlink()  # still locked: nobody else can hold the file being removed
            directory.rmdir()
        try:
            os.ftruncate(fd, 0)  # a released lock names nobody
        except OSError:
            pass
        os.close(fd)  # releases the flock


def holds(directory: str | Path) -> bool:
    """This process holds ``directory``'s lock."""
    return Path(directory).resolve() in _HELD


def _acquire(directory: Path, what: str) -> int:
    path = directory / LOCK_FILE
    while True:
        directory.mkdir(parents=True, exist_ok=True)
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            who = holder(directory)
            stop = f" (kill {who.split()[1]})" if who.startswith("PID ") else ""
            raise DirectoryLocked(f"{directory} is in use: {who} is writing this {what}; wait for it to finish or "
                                  f"stop it{stop}, then run the same command again (nothing was written)") from None
        except OSError:
            os.close(fd)
            raise
        try:  # the file we locked is still the one at the path (not replaced in between)
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    command = " ".join(Path(sys.argv[0]).name if i == 0 else a for i, a in enumerate(sys.argv))
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n{command} (since {time.strftime('%Y-%m-%d %H:%M:%S')})\n".encode(), 0)
    except OSError as e:
        os.close(fd)
        raise OSError(e.errno, e.strerror, str(path)) from None
    return fd


def _remove_if_only_lock(directory: Path) -> None:
    """Remove ``directory`` if nothing but (at most) its lock file is in it."""
    try:
        if {p.name for p in directory.iterdir()} <= {LOCK_FILE}:
            (directory / LOCK_FILE).unlink(missing_ok=True)
            directory.rmdir()
    except OSError:
        pass
