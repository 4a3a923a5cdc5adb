"""Files that a crash leaves whole: the old version or the new one, never a part.

Every file the stack relies on after a crash (a robot's state, the leader's schedule, a
learned memory, a sweep's finished points and table, a run's run.yaml) is written here:
into a temporary file beside it (``.<name>.<random>.tmp``, so globs for ``*.json`` or ``*.npz``
never see it), flushed to the disk, renamed over the target, and the folder flushed too so
that the rename itself survives a power cut. A write that fails (a full disk) raises
OSError naming the target file, and the old version stays.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any


@contextlib.contextmanager
def atomic_open(path: Path | str, mode: str = "wb", *, durable: bool = True,
                **kwargs: Any) -> Iterator[IO[Any]]:
    """Open a temporary file for writing that replaces ``path`` when the block ends without
    an exception (and is removed when it raises). ``durable`` adds the fsyncs (file, then
    folder); without them a crash still never shows a part, but a power cut may lose the
    newest version. ``kwargs`` go to ``open`` (``newline=""`` for csv, say)."""
    if "w" not in mode:
        raise ValueError(f"atomic_open writes: mode {mode!r} has no 'w'")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, mode, **kwargs) as fh:
            yield fh
            if durable:
                fh.flush()
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError) and exc.filename in (None, tmp):
            # name the file the caller writes, not its temporary (a full disk's message)
            raise OSError(exc.errno, exc.strerror, str(path)) from exc
        raise
    if durable:
        dfd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)


def atomic_write_text(path: Path | str, text: str, *, durable: bool = True) -> None:
    """Write ``text`` to ``path`` through :func:`atomic_open`."""
    with atomic_open(path, "w", durable=durable) as fh:
        fh.write(text)
