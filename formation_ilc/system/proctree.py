"""A process's tree as /proc shows it: the live processes below it, and whether one has
ended. Read by the multi-process tests and the benchmarks (a launcher's nodes must end
with it)."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["children_of", "gone"]


def children_of(pid: int) -> set[int]:
    """Every live process below ``pid`` (its children, theirs, ...), from each task's
    ``children`` file: no scan of all of /proc, so a benchmark can poll it every 10 ms."""
    out: set[int] = set()
    todo = [pid]
    while todo:
        p = todo.pop()
        try:
            tasks = os.listdir(f"/proc/{p}/task")
        except OSError:
            continue
        for t in tasks:
            try:
                kids = Path(f"/proc/{p}/task/{t}/children").read_text().split()
            except OSError:
                continue
            for k in map(int, kids):
                if k not in out:
                    out.add(k)
                    todo.append(k)
    return out


def gone(pid: int) -> bool:
    """Whether process ``pid`` has ended (no such process, or a zombie nobody reaped)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except (OSError, IndexError):
        return True
