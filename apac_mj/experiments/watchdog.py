"""The Ray driver's watchdog: ``python -m apac_mj.experiments.watchdog DRIVER_PID``.

Started by :class:`~apac_mj.experiments.executors.RayExecutor` when it starts a local Ray instance (Linux
only: it reads /proc). Every second it notes the driver's descendants (PID and start time); once the driver
is gone (or a zombie), it sends SIGKILL to those still running (the same PID and start time: not a reused
PID) and exits. Ray's own agents outlive a driver killed with kill -9 by a minute or more (they wait 60 s to
report the death to the gone GCS); this stops them at once.

It imports nothing but the standard library, so it starts in milliseconds and has nothing to fail on.
"""
from __future__ import annotations

import os
import signal
import sys
import time
from collections.abc import Sequence

#: Seconds between two looks at the driver's descendants.
POLL_SECONDS = 1.0


def stat(pid: int) -> list[str] | None:
    """The fields of /proc/PID/stat after the command name (state first; the start time is ``[19]``), or None
    when the process is gone."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()
    except OSError:
        return None


def children(pid: int) -> list[int]:
    """The children of every thread of ``pid`` (empty when it is gone, also when it goes while being read)."""
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return []
    out: list[int] = []
    for task in tasks:
        try:
            with open(f"/proc/{pid}/task/{task}/children") as f:
                out += [int(c) for c in f.read().split()]
        except OSError:
            pass
    return out


def descendants(pid: int, skip: int) -> dict[int, str]:
    """Every living descendant of ``pid`` except ``skip`` (this watchdog) and its own descendants: PID -> start
    time."""
    todo, seen = children(pid), {}
    while todo:
        p = todo.pop()
        if p != skip and p not in seen and (ps := stat(p)) is not None:
            seen[p] = ps[19]
            todo += children(p)
    return seen


def kill_known(known: dict[int, str]) -> None:
    """SIGKILL to each process of ``known`` that still runs with the start time noted (not a reused PID)."""
    for p, start in known.items():
        ps = stat(p)
        if ps is not None and ps[19] == start:
            try:
                os.kill(p, signal.SIGKILL)
            except OSError:
                pass


def watch(driver: int, poll: float = POLL_SECONDS) -> None:
    """Note ``driver``'s descendants every ``poll`` seconds while it lives; once it is gone, kill them."""
    me, known = os.getpid(), {}
    while True:
        s = stat(driver)
        if s is None or s[0] == "Z":
            break
        known = descendants(driver, me)
        time.sleep(poll)
    kill_known(known)


def main(argv: Sequence[str] | None = None) -> None:
    """``watchdog DRIVER_PID``."""
    args = sys.argv[1:] if argv is None else list(argv)
    watch(int(args[0]))


if __name__ == "__main__":
    main()
