"""Reading a state file without trusting it: a bounded size, a regular file, never a wait.

A state file (``leader.json``, ``run.json``, ``robot_<i>.npz``) is what a crash left, what a
copy brought, or what somebody put there: a link to ``/dev/zero`` (read whole: memory
without end), a FIFO (``open`` waits for a writer forever), a file of gigabytes. Every
reader of such a file goes through :func:`open_regular` or :func:`read_bounded`, which open
it without blocking, refuse anything but a regular file, and check its size against the
most the format can need before a byte is read.
"""

from __future__ import annotations

import contextlib
import os
import stat
from collections.abc import Iterator
from pathlib import Path
from typing import IO

__all__ = ["StateFileError", "open_regular", "read_bounded", "kind_of"]


class StateFileError(ValueError):
    """A state file that cannot be used; the message names the file and the cause."""


def kind_of(mode: int) -> str:
    """What a file of ``st_mode`` is, in words (for a message)."""
    for test, word in ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"),
                       (stat.S_ISDIR, "a folder")):
        if test(mode):
            return word
    return "not a regular file"


@contextlib.contextmanager
def open_regular(path: Path | str, limit: int, what: str) -> Iterator[IO[bytes] | None]:
    """The open file ``path`` (binary, read-only), or None when there is no such file.

    StateFileError naming the file when it is not a regular file (a device, a FIFO, a
    folder: refused without waiting for a FIFO's writer) or holds more than ``limit``
    bytes, the most a ``what`` file can be."""
    path = Path(path)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC | os.O_NOCTTY)
    except FileNotFoundError:
        yield None
        return
    except OSError as exc:
        raise StateFileError(f"{path}: cannot read {what}: {exc.strerror or exc}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise StateFileError(f"{path}: {kind_of(st.st_mode)}, not {what} (a regular "
                                 f"file is needed)")
        if st.st_size > limit:
            raise StateFileError(f"{path}: {st.st_size} bytes, more than {what} can be "
                                 f"({limit} bytes at most)")
        os.set_blocking(fd, True)
        fh = os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise
    with fh:
        yield fh


def read_bounded(path: Path | str, limit: int, what: str) -> bytes | None:
    """The bytes of the regular file ``path`` (at most ``limit``), None when there is no
    such file; StateFileError as :func:`open_regular` (also for a file that grew past
    ``limit`` while it was read)."""
    try:
        with open_regular(path, limit, what) as fh:
            if fh is None:
                return None
            data = fh.read(limit + 1)
    except OSError as exc:
        raise StateFileError(f"{path}: cannot read {what}: {exc.strerror or exc}") from None
    if len(data) > limit:
        raise StateFileError(f"{path}: more than {what} can be ({limit} bytes at most)")
    return data
