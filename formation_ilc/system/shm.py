"""Fast DDS shared-memory leftovers: find and remove the files of dead processes.

Fast DDS keeps its shared-memory transport in ``/dev/shm/fastrtps_*`` (segments, port
queues and their lock files, about 0.5 MB each). A process that ends normally removes its
own; one killed with SIGKILL cannot, and the files stay until reboot. A file is a leftover
when no live process has it mapped or open (``/proc/*/maps`` and ``/proc/*/fd``); a file
younger than ``min_age`` seconds is never touched (its creator may not have mapped it yet).
A port's named semaphore (``sem.fastrtps_port<N>_mutex``) is opened only while a process
works on the port, so it is removed only together with its port file: once
``fastrtps_port<N>`` is gone (or was never there).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

__all__ = ["SHM", "fastdds_files", "in_use", "clean_leftovers"]

SHM = Path("/dev/shm")


def fastdds_files() -> set[str]:
    return {str(p) for p in SHM.glob("*fastrtps_*")} if SHM.is_dir() else set()


def in_use() -> set[str]:
    """Shared-memory paths some live process has mapped or open."""
    used: set[str] = set()
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            with open(f"/proc/{pid}/maps") as fh:
                used.update(line.split()[-1] for line in fh if "/dev/shm/" in line)
            for fd in os.listdir(f"/proc/{pid}/fd"):
                try:
                    target = os.readlink(f"/proc/{pid}/fd/{fd}")
                except OSError:
                    continue
                if target.startswith("/dev/shm/"):
                    used.add(target)
        except OSError:
            continue
    return used


def clean_leftovers(candidates: set[str] | None = None, min_age: float = 0.0) -> list[str]:
    """Remove the Fast DDS files among ``candidates`` (default: all of them) that no live
    process holds and that are at least ``min_age`` seconds old; returns what was removed."""
    files = fastdds_files() if candidates is None else candidates & fastdds_files()
    if not files:
        return []
    used = in_use()
    now = time.time()
    removed = []
    sems = sorted(p for p in files if os.path.basename(p).startswith("sem."))
    for p in sorted(files - used - set(sems)) + sems:
        name = os.path.basename(p)
        if name.startswith("sem."):
            port = name[len("sem."):].removesuffix("_mutex")
            if os.path.exists(os.path.join(os.path.dirname(p), port)):
                continue
        try:
            if now - os.stat(p).st_mtime < min_age:
                continue
            os.unlink(p)
            removed.append(p)
        except OSError:
            pass
    return removed
