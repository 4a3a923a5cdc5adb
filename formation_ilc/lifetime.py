"""Processes that must not outlive the launcher that started them.

A launcher puts its pid into the environment of every process it starts
(``FORMATION_ILC_PARENT``); each such process calls ``die_with_parent()`` first thing. Linux
then sends it SIGTERM when the launcher dies, whatever signal ended the launcher (SIGKILL
included: ``PR_SET_PDEATHSIG``), and a process whose launcher is already gone exits at once.
SIGTERM lets a node shut down cleanly (its Fast DDS files removed) and a packet delayer
release what it holds.
"""

from __future__ import annotations

import os
import signal
import sys

__all__ = ["PARENT_ENV", "die_with_parent"]

#: environment variable naming the pid of the launcher that supervises this process
PARENT_ENV = "FORMATION_ILC_PARENT"


def die_with_parent() -> None:
    parent = os.environ.get(PARENT_ENV)
    if not parent:
        return
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, int(signal.SIGTERM))  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    if str(os.getppid()) != parent:
        print(f"launcher {parent} is gone: not starting", file=sys.stderr)
        raise SystemExit(1)
