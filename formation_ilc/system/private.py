"""A run's files are its user's alone while the run lives.

The key the leader seals its events with (``protocol.schedule.seal``) is in the
recording's metadata, so that ``analyze`` can tell the leader's events from forgeries;
while the run lives, whoever reads it can forge the leader's events. ``private`` sets the
launcher's umask to 077 for the run (every process it starts inherits it: the recording,
the state files, the logs, the metrics are made mode 0600, folders 0700) and, when the run
is over (a new launch has a new key), gives the files the run made the modes the user's
own umask would have given them.
"""

from __future__ import annotations

import os
import stat
import time
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["private", "RUN_UMASK"]

#: the umask of a run while it lives
RUN_UMASK = 0o077
#: at most this many files are given their modes back (a folder of a long run is small)
MOST = 100_000


@contextmanager
def private(roots: Iterable[Path]) -> Iterator[None]:
    """While the block runs, files made by this process and its children are the user's
    alone; afterwards the files made under ``roots`` (folders, or files: a recording's
    parts are found by their name's prefix) since it began get the modes of the user's
    umask back."""
    roots = [Path(r) for r in roots]
    began = time.time() - 0.01  # a file system with coarse times: kept private
    old = os.umask(RUN_UMASK)
    try:
        yield
    finally:
        os.umask(old)
        for p in _made_since(roots, began):
            _relax(p, old)


def _made_since(roots: list[Path], began: float) -> Iterator[Path]:
    seen = 0
    for root in roots:
        if root.is_dir():
            found: Iterable[Path] = root.rglob("*")
        else:  # a recording: its file and its parts and resumed parts beside it
            found = root.parent.glob(f"{root.stem}*") if root.parent.is_dir() else ()
        for p in found:
            seen += 1
            if seen > MOST:
                return
            try:
                st = p.lstat()
            except OSError:
                continue
            if st.st_ctime >= began and st.st_uid == os.getuid() and \
                    (stat.S_ISREG(st.st_mode) or stat.S_ISDIR(st.st_mode)):
                yield p


def _relax(p: Path, umask: int) -> None:
    """``p``'s group and other bits as ``umask`` gives them (read, and for folders
    search; never more than the owner has)."""
    try:
        mode = stat.S_IMODE(p.lstat().st_mode)
        full = 0o777 if p.is_dir() else 0o666 | (mode & 0o111)
        want = (mode & 0o700) | (full & ~umask & 0o077)
        if want != mode:
            os.chmod(p, want)
    except OSError:
        pass
