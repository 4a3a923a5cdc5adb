"""The progress of a long command on stderr: simulate and compare (trials), sweep and tune
(points), analyze (messages read). One look for all of them, drawn by tqdm.

On a terminal, a tqdm bar rewritten in place. In a log file or a pipe tqdm's carriage
returns would pile up into one garbled line, so the same text (tqdm's ``format_meter``,
with an ASCII bar) is written there as whole lines, now and then: every ``every`` seconds
(default 10), at each tenth of the total when asked (``tenths``), and at the end; nothing
before the first step. A job that has nothing left to do shows nothing anywhere.
"""

from __future__ import annotations

import math
import os
import sys
import time
from typing import IO, Any

from tqdm import tqdm

__all__ = ["Progress"]

#: the line: label, share done, bar, count, elapsed and time left, then the status
_WITH_TOTAL = ("{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} {unit} "
               "[{elapsed}<{remaining}{postfix}]")
#: without a total (analyze: messages read): no share, no bar, no time left
_OPEN_ENDED = "{desc}: {n_fmt} {unit} [{elapsed}{postfix}]"
#: steps with numbers of their own, said in the status (trials: 0..k-1): no count of them
_UNCOUNTED = "{desc}: {percentage:3.0f}%|{bar}| [{elapsed}<{remaining}{postfix}]"


class _Bar(tqdm):  # type: ignore[type-arg,misc,unused-ignore]
    # no monitor thread: sweep and tune fork worker processes while a bar is up
    monitor_interval = 0


class Progress:
    """Progress of ``total`` steps (None: not known) labelled ``label``, on ``file``
    (default: sys.stderr when the object is made).

    unit : what a step is ("trials", "points", "messages").
    initial : steps done before this session (a resumed sweep): counted in the position,
        not in the rate nor in the time left (in a log, the rate counts from the first
        step: the time before it, compiling or starting workers, is not a step's).
    interval : seconds between redraws on a terminal.
    every : seconds between lines elsewhere; tenths : a line also at each tenth of
        ``total`` there.
    count : show the count of steps done ("4/20 trials"); off where the status names the
        step by a number of its own (simulate's trials are numbered from 0), so that the
        line shows one numbering, not two.

    ``step`` or ``to`` moves it, with an optional status shown after the times (the last
    trial's errors); reaching ``total`` closes it, leaving the last line. ``close`` ends it
    earlier: with ``clear`` a terminal's bar is wiped so that a message can take its place.
    """

    def __init__(self, total: int | None, label: str, unit: str, *, initial: int = 0,
                 interval: float = 0.1, every: float = 10.0, tenths: bool = False,
                 count: bool = True, file: IO[str] | None = None):
        self.file = sys.stderr if file is None else file
        self.total, self.label, self.unit = total, label, unit
        self.initial = self.n = initial
        self.every, self.tenths, self.count = every, tenths, count
        self.t0 = time.monotonic()
        self.last, self.last_tenth = -math.inf, -1  # the first step writes a line
        self.status = ""
        self.first: tuple[float, int] | None = None  # (time, steps) of the first line
        self.closed = total is not None and initial >= total  # nothing left to show
        self.bar: _Bar | None = None
        if not self.closed and _is_terminal(self.file):
            # leave=False until the end: a bar dropped unfinished (an interrupted run)
            # wipes itself instead of drawing its line again below what came after it
            sized = _columns(self.file) > 0  # else a pseudo-terminal no one gave a size
            self.bar = _Bar(total=total, initial=initial, desc=label, unit=unit,
                            file=self.file, mininterval=interval, dynamic_ncols=sized,
                            ncols=None if sized else 100, leave=False,
                            bar_format=self._format())

    def _format(self) -> str:
        if self.total is None:
            return _OPEN_ENDED
        return _WITH_TOTAL if self.count else _UNCOUNTED

    def _tenth(self) -> int:
        return -1 if not self.total else (10 * self.n) // self.total

    def step(self, status: str = "") -> None:
        """One more step done."""
        self.to(self.n + 1, status)

    def to(self, n: int, status: str = "") -> None:
        """``n`` steps done (``initial`` included)."""
        if self.closed:
            return
        self.n, self.status = n, status
        done = self.total is not None and n >= self.total
        if self.bar is not None:
            if status:
                self.bar.set_postfix_str(status, refresh=False)
            self.bar.update(n - self.bar.n)
        else:
            now = time.monotonic()
            tenth = self._tenth()
            if done or now - self.last >= self.every or (self.tenths and
                                                          tenth != self.last_tenth):
                self.last, self.last_tenth = now, tenth
                self._line(now)
        if done:
            self.close()

    def _line(self, now: float) -> None:
        if self.first is None:
            self.first = (now, self.n)
        t1, n1 = self.first
        # the rate since the first step: what came before it (compiling the kernels,
        # starting the workers) says nothing of the steps left; 0 shows the time left as ?
        rate = (self.n - n1) / (now - t1) if self.n > n1 and now > t1 else 0.0
        text = tqdm.format_meter(self.n, self.total, now - self.t0, prefix=self.label,
                                 ascii=True, unit=self.unit, postfix=self.status or None,
                                 rate=rate, bar_format=self._format())
        print(text, file=self.file, flush=True)

    def close(self, clear: bool = False) -> None:
        """End the display: a terminal keeps the bar's last state on its line (``clear``:
        wipes it); elsewhere nothing more is written."""
        if self.closed:
            return
        self.closed = True
        if self.bar is not None:
            self.bar.leave = not clear
            self.bar.close()

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _columns(file: Any) -> int:
    try:
        return os.get_terminal_size(file.fileno()).columns
    except (AttributeError, ValueError, OSError):
        return 0


def _is_terminal(file: Any) -> bool:
    try:
        return bool(file.isatty())
    except (AttributeError, ValueError, OSError):  # no such method, or a closed file
        return False
