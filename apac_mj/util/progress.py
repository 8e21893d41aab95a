"""Progress bars that suit where they are written: tqdm's bar on a terminal, plain lines elsewhere.

On a terminal a bar redraws itself in place. Written to a file or a pipe (a log, a CI job, ``2> log``) the same
redraws are one cursor-coded line each: the demo's log once held 575 of them. There a :class:`PlainProgress`
prints at most one plain line per step of ``every`` (a finished grid cell, a tenth of a run's episodes) and
one at the end, each with the count, the elapsed time and the bar's postfix (success rate, habit share, the
cell's status), and one per new label shown between counts (motor babbling's episodes). :func:`progress_bar` picks one; ``plain=True`` asks for the lines also on a terminal (the grid's
``--no-progress``: one line per finished cell instead of nothing for minutes).
"""
from __future__ import annotations

import math
import sys
import time
from collections.abc import Iterable, Iterator
from typing import IO, Any

from tqdm.auto import tqdm

#: A plain run bar's lines: one per this share of its total (and one at the end).
PLAIN_SHARE = 0.1


class PlainProgress:
    """tqdm's interface as used here (update, set_postfix, set_postfix_str, close, n, postfix, disable), writing
    one plain line when the count crosses a multiple of ``every`` or reaches ``total``."""

    def __init__(self, total: int, initial: int = 0, desc: str = "", unit: str = "it", every: int = 1,
                 file: IO[str] | None = None) -> None:
        self.total, self.n, self.desc, self.unit = int(total), int(initial), desc, unit
        self.every = max(1, int(every))
        self.file = file
        self.postfix: str | None = None
        self.disable = False
        self._start = time.monotonic()

    def update(self, n: int = 1) -> None:
        """Count ``n`` more; a line if a multiple of ``every`` or the total was crossed."""
        before, self.n = self.n, self.n + int(n)
        if self.n // self.every > before // self.every or (self.n >= self.total > before):
            self._line()

    def set_postfix(self, ordered_dict: dict[str, Any] | None = None, refresh: bool = True, **kwargs: Any) -> None:
        """The text after the count, ``key=value`` pairs as tqdm writes them."""
        items = {**(ordered_dict or {}), **kwargs}
        self.postfix = ", ".join(f"{k}={v}" for k, v in items.items())

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
        """The text after the count; ``refresh`` (tqdm's "show it now") writes a line when a new, non-empty text
        comes between counts (the trainer's "motor babbling: episode k of N", once per babbling episode)."""
        changed, self.postfix = str(s) != (self.postfix or ""), str(s)
        if refresh and changed and self.postfix:
            self._line()

    def close(self) -> None:
        """Nothing left to draw (each line was written when it was due)."""

    def __enter__(self) -> "PlainProgress":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _line(self) -> None:
        elapsed = time.monotonic() - self._start
        text = f"{self.desc}: {self.n}/{self.total} {self.unit} ({elapsed:.0f} s)"
        if self.postfix:
            text += f" {self.postfix}"
        stream = self.file if self.file is not None else sys.stderr
        print(text, file=stream, flush=True)


def is_terminal(stream: IO[str] | None) -> bool:
    """``stream`` (default stderr) is a terminal; a closed or replaced stream counts as none."""
    stream = sys.stderr if stream is None else stream
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError, OSError):
        return False


def progress_bar(total: int, desc: str, unit: str, initial: int = 0, enabled: bool = True,
                 plain: bool | None = None, every: int | None = None, file: IO[str] | None = None,
                 **tqdm_kwargs: Any) -> tqdm | PlainProgress:
    """A bar for ``total`` steps: disabled (``enabled`` False), plain lines (``plain``; None: where ``file``,
    default stderr, is not a terminal) one per ``every`` steps (default: a tenth of ``total``), or tqdm's bar."""
    if not enabled:
        return tqdm(total=total, initial=initial, desc=desc, unit=unit, disable=True)
    if plain is None:
        plain = not is_terminal(file)
    if plain:
        every = every if every is not None else max(1, math.ceil(total * PLAIN_SHARE))
        return PlainProgress(total, initial, desc, unit, every, file)
    return tqdm(total=total, initial=initial, desc=desc, unit=unit, file=file, **tqdm_kwargs)


def progress_iter(items: Iterable[Any], total: int, desc: str, unit: str, enabled: bool = True,
                  file: IO[str] | None = None) -> Iterator[Any]:
    """``items`` with a :func:`progress_bar` counting them."""
    with progress_bar(total, desc, unit, enabled=enabled, file=file) as bar:
        for item in items:
            yield item
            bar.update(1)
