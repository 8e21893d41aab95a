"""Torch's CPU threads: the one place that decides how many the project's commands and library calls use.

These networks are small (a few 100-unit layers, minibatches of 64-500, one ensemble member per seed), so
one update or one frozen step is a few dozen small matrix products. Torch's default is one intra-op thread per
core; with two or more, every small product waits at a barrier for the other threads, and on a machine whose
cores are busy (a 2-core machine running anything else) a waiting thread is descheduled and each barrier costs
a scheduler slice. Measured on a shared 2-core CPU (issue 29, items 1 and 6): the README's
``apac_mj.train(...)`` at torch's default of 2 threads took 329.6 s where ``apac-mj train`` at 1 thread took
23.9 s for the same config and the same numbers (``bench/threads.py`` measures the two side by side: ratio
library/CLI 5.6 at 10 episodes before, 0.95-1.00 after); ``apac-mj evaluate`` spent 1.1-1.5 s per target
(2 seeds) at 2 threads, 80 % of it in ``torch.baddbmm`` (cProfile: 6.2 s for 3600 calls, 0.08 s at 1 thread),
and 0.08-0.15 s at 1. One thread is therefore the default of the CLI (``--threads``), of :func:`apac_mj.train`
and :func:`apac_mj.evaluate` (``threads=``) and of a grid preset (``threads``); more pay off only for large
ensembles (E >= 10) on cores that are free.

The library sets the count for the duration of its call and restores the caller's afterwards
(:func:`torch_threads`), so a notebook's own torch work keeps its setting. The count does not change a number
(fp32 on CPU: eval parquet files at 1 and 2 threads compared identical, issue 29 item 6).
"""
from __future__ import annotations

import contextlib
from typing import Iterator

#: Torch CPU threads when the caller does not ask for a number: the CLI's ``--threads`` default, and
#: :func:`apac_mj.train`'s and :func:`apac_mj.evaluate`'s ``threads=None``.
DEFAULT_THREADS = 1


def resolve(threads: int | None) -> int:
    """The thread count to use: ``threads`` (an int >= 1), or :data:`DEFAULT_THREADS` for None."""
    if threads is None:
        return DEFAULT_THREADS
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise ValueError(f"threads must be an int >= 1 (or None: {DEFAULT_THREADS}), got {threads!r}")
    return threads


def set_threads(threads: int | None = None) -> int:
    """Set torch's intra-op CPU threads to :func:`resolve` (``threads``) for the rest of the process (a
    command's whole run); returns the count."""
    import torch

    n = resolve(threads)
    torch.set_num_threads(n)
    return n


@contextlib.contextmanager
def torch_threads(threads: int | None = None) -> Iterator[int]:
    """Torch's intra-op CPU threads at :func:`resolve` (``threads``) inside the block, the caller's count
    restored after it (a library call leaves the process as it found it)."""
    import torch

    n = resolve(threads)
    before = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield n
    finally:
        torch.set_num_threads(before)
