"""The core's kernels: plain Python functions, compiled by numba only where a caller asks.

Every kernel of this package (the learning law, the plant step, the link model, the draws,
the batch simulator's loop) is written once, in the subset of Python that numba compiles,
and decorated with :func:`njit` from here. The decorator returns **the function itself**:
called like any function it runs in the interpreter, and importing it loads no numba and no
LLVM. The nodes of the distributed stack call their kernels this way, once per sample or
per trial: a robot process then holds no compiler (about 57 MB of numba and LLVM, plus the
compiled code) and has nothing to compile when it starts.

Batch callers that loop over many samples in one call (``model.simulate``, the studies) call
the compiled form, ``kernel.jit(...)``: a numba dispatcher, made on first use (numba is
imported then), cached on disk (below). Inside compiled code a kernel calls another by its
plain name, as before: each kernel is registered with numba as its own dispatcher
(:func:`numba_init`, numba's extension entry point, so that any numba function, even one of
a test, can call a kernel), so compiled code is the same as when every kernel was a
dispatcher, and each is cached under its own name. ``kernel.py_func`` is the kernel itself
(numba's name for the interpreted form).

numba's ``cache=True`` checks only the source file of the cached function itself: after an
edit of ``law.py``, ``simulate.run_trial`` (whose cached machine code has ``law.command``
and ``law.learn`` inlined) would still be loaded from the cache, stale. So every kernel's
dispatcher is cached in a directory named by a hash of all ``formation_ilc/**/*.py``: any
edit of any module of the package, new modules included, names a new, empty directory and
the next run compiles afresh; an unchanged tree finds its directory and loads the cache
(compile once).

Where the directories live (the first writable of):

1. ``$NUMBA_CACHE_DIR/formation-ilc/`` when the user set ``NUMBA_CACHE_DIR``;
2. ``formation_ilc/__pycache__/numba/`` beside the sources (numba's own default place);
3. ``$XDG_CACHE_HOME/formation-ilc/numba/`` (default ``~/.cache``), for a read-only install;
4. ``<temp dir>/formation-ilc-numba-<uid>/``.

Old directories (another hash) not used for :data:`PRUNE_AGE_S` are removed when the
package's kernels are next compiled or loaded. Several processes may share the cache, so
removal is race-free: a directory is first renamed away (atomic; one process wins, the
others skip it), then deleted. A process still running old code whose directory is removed
loses nothing but speed: numba finds no index, compiles, and recreates the directory to save
into. numba's own writes are atomic (write to a temporary name, then rename), so concurrent
readers and writers of one directory are safe.

The cache setting is scoped to the making of this package's dispatchers (numba fixes a
function's cache directory when its dispatcher is made): other numba users in the same
process are unaffected.
"""

from __future__ import annotations

import functools
import hashlib
import os
import re
import shutil
import sys
import tempfile
import time
import uuid
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

__all__ = ["njit", "Compiled", "numba_init", "kernels", "cache_dir", "source_hash",
           "PRUNE_AGE_S", "floats"]

PACKAGE = Path(__file__).resolve().parents[1]  # the whole formation_ilc package
#: seconds a cache directory of other sources is kept after its last use
PRUNE_AGE_S = 24 * 3600.0
_HASH_NAME = re.compile(r"^[0-9a-f]{16}$")
_TRASH = ".trash-"


def source_hash(root: Path = PACKAGE) -> str:
    """16 hex digits of SHA-256 over the relative paths and contents of ``root/**/*.py``."""
    h = hashlib.sha256()
    files: list[Path] = []
    for here, dirs, names in os.walk(root):
        dirs[:] = sorted(d for d in dirs if d != "__pycache__")
        files.extend(Path(here, n) for n in names if n.endswith(".py"))
    for path in sorted(files):
        h.update(path.relative_to(root).as_posix().encode())
        h.update(b"\0")
        h.update(path.read_bytes())
        h.update(b"\0")
    return h.hexdigest()[:16]


def candidate_parents() -> list[Path]:
    """Parent directories of the hash directories, in order of preference."""
    out = []
    user = os.environ.get("NUMBA_CACHE_DIR")
    if user:
        out.append(Path(user) / "formation-ilc")
    out.append(PACKAGE / "__pycache__" / "numba")
    xdg = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    out.append(Path(xdg) / "formation-ilc" / "numba")
    uid = os.getuid() if hasattr(os, "getuid") else 0
    out.append(Path(tempfile.gettempdir()) / f"formation-ilc-numba-{uid}")
    return out


def first_writable(dirs: Iterable[Path]) -> Path | None:
    """The first directory that can be created and written to (numba's own test)."""
    for d in dirs:
        try:
            d.mkdir(parents=True, exist_ok=True)
            tempfile.TemporaryFile(dir=d).close()
        except OSError:
            continue
        return d
    return None


def prune(parent: Path, keep: str, max_age_s: float = PRUNE_AGE_S,
          now: float | None = None) -> list[str]:
    """Remove hash directories in ``parent`` other than ``keep`` unused for ``max_age_s``.

    Returns the names removed by this call. Safe against concurrent callers: a directory is
    renamed to a unique trash name first (exactly one caller's rename succeeds).
    """
    now = time.time() if now is None else now
    removed: list[str] = []
    try:
        entries = list(parent.iterdir())
    except OSError:
        return removed
    for entry in entries:
        name = entry.name
        try:
            age = now - entry.stat().st_mtime
        except OSError:
            continue  # removed meanwhile by another process
        if name.startswith(_TRASH):
            if age > 3600:  # left by a process that died while deleting it
                shutil.rmtree(entry, ignore_errors=True)
            continue
        if name == keep or not _HASH_NAME.match(name) or age < max_age_s:
            continue
        trash = parent / f"{_TRASH}{name}-{uuid.uuid4().hex[:8]}"
        try:
            os.rename(entry, trash)
        except OSError:
            continue  # another process got there first
        shutil.rmtree(trash, ignore_errors=True)
        removed.append(name)
    return removed


@functools.cache
def cache_dir() -> str:
    """This tree's numba cache directory (created; marked used now; old ones pruned)."""
    key = source_hash()
    parent = first_writable(candidate_parents())
    if parent is None:  # nowhere writable: numba will not cache either
        return ""
    path = parent / key
    path.mkdir(exist_ok=True)
    os.utime(path)  # last use, for prune() of other processes
    prune(parent, keep=key)
    return str(path)


class Compiled:
    """A kernel's compiled form: its numba dispatcher, made (and numba imported) on first
    use. Calling it calls the dispatcher."""

    def __init__(self, fn: Callable[..., Any], options: dict[str, Any]) -> None:
        self.py_func = fn
        self.options = options
        self._dispatcher: Any = None

    @property
    def dispatcher(self) -> Any:
        """The numba dispatcher (``numba.njit(**options)`` of the kernel, cached in
        :func:`cache_dir`)."""
        if self._dispatcher is None:
            self._dispatcher = _make_dispatcher(self.py_func, self.options)
            if not _numba_ready:
                numba_init()  # every kernel callable from compiled code: its callees too
        return self._dispatcher

    def __call__(self, *args: Any) -> Any:
        return self.dispatcher(*args)

    def __repr__(self) -> str:
        return f"<compiled {self.py_func.__module__}.{self.py_func.__qualname__}>"


#: every kernel decorated so far, in order
_KERNELS: list[Callable[..., Any]] = []
_registered: set[int] = set()
_numba_ready = False


def kernels() -> list[Callable[..., Any]]:
    """Every kernel decorated so far (the plain functions)."""
    return list(_KERNELS)


def _make_dispatcher(fn: Callable[..., Any], options: dict[str, Any]) -> Any:
    import numba
    from numba.core import config as numba_config

    if not options["cache"] or not cache_dir():
        return numba.njit(**{**options, "cache": False})(fn)
    config: Any = numba_config  # numba's settings module (attributes set at run time)
    saved = config.CACHE_DIR
    config.CACHE_DIR = cache_dir()
    try:
        return numba.njit(**options)(fn)
    finally:
        config.CACHE_DIR = saved


def _register(fn: Any) -> None:
    """Make the plain function ``fn`` callable from compiled code, as its own dispatcher."""
    if id(fn) in _registered:
        return
    from numba.core import config as numba_config
    from numba.core import types
    from numba.core.typing.templates import infer_global

    _registered.add(id(fn))
    if getattr(numba_config, "DISABLE_JIT", False):  # nothing is compiled: no typing needed
        return
    infer_global(fn, types.Dispatcher(fn.jit.dispatcher))


def floats(a: Any) -> Any:
    """The numbers of the array ``a`` for a kernel to read: Python numbers (``a.tolist()``)
    where the kernel runs as plain Python (a node), the array itself in compiled code (numba
    compiles no ``tolist``, and reads an array's elements at no cost). Plain Python pays
    about 0.2 us to read one element of an array and 3x for sums of numpy scalars; a row of
    a list costs a tenth of that. Index it only (``floats(a)[j][0]``, ``len``): the two forms
    agree on that, not on slices or writes."""
    return a.tolist()


def numba_init() -> None:
    """Register every kernel with numba, so that compiled code can call it by its plain
    name, and :func:`floats`' compiled form. numba calls this before it compiles anything
    (the package's ``numba_extensions`` entry point), and so does the first use of any
    ``kernel.jit``; a kernel decorated later is registered when it is decorated.
    Idempotent."""
    global _numba_ready
    if not _numba_ready:
        from numba.extending import overload

        overload(floats)(lambda a: lambda a: a)
    _numba_ready = True
    for fn in list(_KERNELS):
        _register(fn)


def njit(**options: Any) -> Callable[[Callable[..., Any]], Any]:
    """Mark a kernel: returns the function itself, with ``.jit`` (its compiled form,
    ``numba.njit(cache=True, **options)`` with the cache in :func:`cache_dir`, made on first
    use) and ``.py_func`` (itself)."""
    options.setdefault("cache", True)

    def decorate(fn: Callable[..., Any]) -> Any:
        kernel: Any = fn
        kernel.jit = Compiled(fn, dict(options))
        kernel.py_func = fn
        _KERNELS.append(fn)
        if _numba_ready and "numba" in sys.modules:
            _register(fn)
        return fn

    return decorate
