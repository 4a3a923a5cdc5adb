"""Guards against runs that cannot end well: memory checked before it is spent, and a run
stopped once its errors are no longer finite.

* ``available_memory`` and ``memory_shortfall``: what this process may still allocate
  (``MemAvailable`` of ``/proc/meminfo``, lowered by a cgroup's ``memory.max`` or an
  address-space limit ``ulimit -v``; free physical pages where ``/proc`` is missing), and
  a one-line reason to refuse a job whose estimate does not fit. The callers estimate
  (``scenario.load_bytes``, ``simulate.simulate_bytes``, ``checks.check_bytes``).
* ``check_finite`` and ``DivergedError``: a trial whose outputs, inputs or learned memory
  hold inf or nan means the learning diverged (a gain far too large, e.g. g = 50 or
  1e300); every later trial would only carry nan. The batch simulator calls it after each
  trial (``simulate(stop_on_divergence=True)``, what ``formation-ilc simulate`` runs), and
  the launcher's monitor can call it on each trial's metrics row.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["available_memory", "memory_shortfall", "format_bytes", "DivergedError",
           "check_finite"]


def format_bytes(n: float) -> str:
    """``n`` bytes for a reader: '512 B', '3.4 MiB', '52.2 GiB'."""
    n = float(n)
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.3g} {unit}"
        n /= 1024
    return f"{n:.3g} PiB"  # pragma: no cover


def _meminfo(path: Path = Path("/proc/meminfo")) -> int | None:
    try:
        with path.open() as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _cgroup_room(root: Path = Path("/sys/fs/cgroup")) -> int | None:
    """memory.max - memory.current of this process's cgroup (v2), if it has a limit."""
    try:
        rel = Path("/proc/self/cgroup").read_text().strip().splitlines()[0].split(":", 2)[2]
        group = root / rel.lstrip("/")
        limit = (group / "memory.max").read_text().strip()
        if limit == "max":
            return None
        return max(0, int(limit) - int((group / "memory.current").read_text()))
    except (OSError, ValueError, IndexError):
        return None


def _address_space_room() -> int | None:
    """What ``ulimit -v`` (RLIMIT_AS) leaves of this process's address space."""
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
        if soft == resource.RLIM_INFINITY:
            return None
        with open("/proc/self/status") as fh:
            vm = next(int(line.split()[1]) * 1024 for line in fh if line.startswith("VmSize:"))
        return max(0, soft - vm)
    except (ImportError, OSError, ValueError, StopIteration):
        return None


def available_memory() -> tuple[int | None, str]:
    """(bytes this process can still allocate without swapping, where the figure comes
    from); (None, reason) if no figure is known."""
    found: list[tuple[int, str]] = []
    mem = _meminfo()
    if mem is not None:
        found.append((mem, "MemAvailable"))
    else:
        try:
            pages = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
            found.append((int(pages), "free memory"))
        except (ValueError, OSError, AttributeError):
            pass
    room = _cgroup_room()
    if room is not None:
        found.append((room, "cgroup memory.max"))
    room = _address_space_room()
    if room is not None:
        found.append((room, "ulimit -v"))
    if not found:
        return None, "unknown"
    return min(found)


def memory_shortfall(need: float) -> str | None:
    """None if ``need`` bytes fit in what is available, else why not, e.g. 'needs about
    52.2 GiB, 20.9 GiB available (MemAvailable)'. With no figure known, nothing is refused."""
    have, source = available_memory()
    if have is None or need <= have:
        return None
    return f"needs about {format_bytes(need)}, {format_bytes(have)} available ({source})"


class DivergedError(ArithmeticError):
    """A trial's errors stopped being finite: the learning diverged.

    trial : the trial's index; robot : 1-based, or None when unknown; what : the quantity
    (e.g. 'output', 'input', 'learned memory', 'errors'). result : what the caller kept
    (``simulate`` puts the finished trials' SimResult there).
    """

    result: Any = None

    def __init__(self, trial: int, what: str, robot: int | None = None):
        self.trial = int(trial)
        self.what = what
        self.robot = robot
        who = f"robot {robot}'s " if robot is not None else ""
        super().__init__(f"trial {self.trial}: {who}{what} is not finite (inf or nan): the "
                         f"learning diverged")


def check_finite(trial: int, row: NDArray[np.float64] | None = None,
                 **arrays: NDArray[np.float64]) -> None:
    """Raise DivergedError if a trial's data hold inf or nan.

    row : a metrics row (``metrics.METRIC_COLUMNS``: the trial, then errors); its
        ``true_`` columns may be nan when the plant does not report the true state, so
        only the measured ones are checked here (and no count: ``contacts`` is nan on a
        plant without bodies).
    arrays : named arrays with the robot axis first, e.g. ``output=eta`` (N, T+1, 3),
        ``input=u`` (N, T, 2), ``learned_memory=memory`` (N, T, 2); the first robot with a
        non-finite value is named. Cost: one pass over each array. The arrays are checked
        before the row.
    """
    for name, a in arrays.items():
        a = np.asarray(a)
        if np.isfinite(a).all():
            continue
        robot = None
        if a.ndim:
            finite_rows = np.isfinite(a.reshape(a.shape[0], -1)).all(axis=1)
            robot = int(np.flatnonzero(np.logical_not(finite_rows))[0]) + 1
        raise DivergedError(trial, name.replace("_", " "), robot)
    if row is not None:
        from formation_ilc.core.metrics import COUNT_COLUMNS, METRIC_COLUMNS, TRUE_COLUMNS

        for name, value in zip(METRIC_COLUMNS[1:], np.asarray(row)[1:], strict=False):
            if name not in TRUE_COLUMNS and name not in COUNT_COLUMNS \
                    and not math.isfinite(float(value)):
                raise DivergedError(trial, f"{name.replace('_', ' ')}")
