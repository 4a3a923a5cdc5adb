"""Says on the console what numba compiles, while it compiles.

The batch simulator's kernels are compiled the first time they run after an install or an
edit of the package (then loaded from numba's cache: ``formation_ilc.core._jit``); that
takes tens of seconds, in which a command would otherwise print nothing. Inside
``compile_notes()`` the first kernel numba compiles prints a line saying so, each further
of the package's kernels a line naming it (at most one a second), and a line every
``every`` seconds while the compiling goes on (one kernel can take most of the time); at
the end, how many functions were compiled (numba's own helpers included) and in how long.
numba reports a compile only on a cache miss: a warm cache prints nothing.

Lines go through ``tqdm.write``, so a progress bar on a terminal is redrawn below them.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import IO, Any

__all__ = ["compile_notes"]


class _Notes:
    def __init__(self, file: IO[str], every: float, what: str, where: str):
        self.file, self.every, self.what, self.where = file, every, what, where
        self.t0: float | None = None  # when the first compile started
        self.last = 0.0  # when the last line was written
        self.done = 0  # kernels compiled
        self.depth = 0  # compiles in progress (a kernel's callees compile inside it)
        self.current = "the kernels"
        self.lock = threading.Lock()
        self.stop = threading.Event()
        self.thread: threading.Thread | None = None

    def say(self, text: str) -> None:
        from tqdm import tqdm

        tqdm.write(text, file=self.file)
        self.file.flush()
        self.last = time.monotonic()

    def on_start(self, event: Any) -> None:
        name = _name(event)
        with self.lock:
            now = time.monotonic()
            if self.t0 is None:
                self.t0 = now
                where = self.where
                self.say(f"compiling {self.what} with numba: once after an install or an "
                         f"update, then loaded from its cache"
                         + (f" ({where})" if where else "") + " ...")
                self.thread = threading.Thread(target=self._tick, name="compile-notes",
                                               daemon=True)
                self.thread.start()
            self.depth += 1
            if name:  # one of the package's kernels (not one of numba's own helpers)
                self.current = name
                if now - self.last >= 1.0:
                    self.say(f"  compiling {name} [{now - self.t0:.0f} s]")

    def on_end(self, event: Any) -> None:
        with self.lock:
            self.depth = max(0, self.depth - 1)
            self.done += 1

    def _tick(self) -> None:
        while not self.stop.wait(0.5):
            with self.lock:
                now = time.monotonic()
                if self.depth and self.t0 is not None and now - self.last >= self.every:
                    self.say(f"  compiling {self.current} ({self.done} functions done) "
                             f"[{now - self.t0:.0f} s]")

    def close(self) -> None:
        self.stop.set()
        if self.thread is not None:
            self.thread.join()
        if self.t0 is not None:
            self.say(f"  compiled {self.done} functions in {time.monotonic() - self.t0:.1f} s")


def _name(event: Any) -> str:
    disp = event.data.get("dispatcher") if isinstance(event.data, dict) else None
    fn = getattr(disp, "py_func", None)
    module = str(getattr(fn, "__module__", ""))
    if not module.startswith("formation_ilc."):
        return ""
    return f"{module.rsplit('.', 1)[-1]}.{getattr(fn, '__qualname__', '?')}"


@contextmanager
def compile_notes(what: str = "the batch simulator", where: str = "", every: float = 5.0,
                  file: IO[str] | None = None) -> Iterator[None]:
    """Within it, numba's compiles are said on ``file`` (default stderr): see the module.
    where : the cache directory, said in the first line."""
    from numba.core import event as ev

    notes = _Notes(sys.stderr if file is None else file, every, what, where)

    class Listener(ev.Listener):  # type: ignore[misc,unused-ignore]
        def on_start(self, event: Any) -> None:
            notes.on_start(event)

        def on_end(self, event: Any) -> None:
            notes.on_end(event)

    try:
        with ev.install_listener("numba:compile", Listener()):
            yield
    finally:
        notes.close()
