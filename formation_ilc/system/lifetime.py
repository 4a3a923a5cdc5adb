"""Processes that must not outlive the launcher that started them.

A launcher puts its pid into the environment of every process it starts
(``FORMATION_ILC_PARENT``); each such process calls ``die_with_parent()`` first thing. Linux
then sends it SIGTERM when the launcher dies, whatever signal ended the launcher (SIGKILL
included: ``PR_SET_PDEATHSIG``), and a process whose launcher is already gone exits at once.
SIGTERM lets a node shut down cleanly (its Fast DDS files removed) and a packet delayer
release what it holds.

A clean shutdown is not bounded by itself: after rclpy has shut down (milliseconds), the
process still runs the interpreter's exit and Fast DDS's own teardown, measured at 1 to
3.6 s per node on 2 cores with 6 busy processes beside them, growing with the load. While
the launcher lives it ends a slow node with SIGKILL; once it is gone nobody does. So a
process that starts to stop calls ``bound_the_stop()``: SIGALRM (default action:
terminate) ends it ``STOP_GRACE`` seconds later wherever it is, ``ORPHAN_GRACE`` when its
launcher is already gone (nothing waits for its clean end then, and it must be gone within
``ORPHAN_BOUND`` of its launcher). Nothing is lost by that: every state a node keeps is
written atomically as it changes.

Start-up is the window a call in the node's own code cannot cover: a node process imports
rclpy and numpy before its first line runs, seconds on a loaded machine, and a
launcher killed then left it running until its imports were done (15-22 s measured). So
the launcher starts every node through this module (``early_argv``): ``python -m
formation_ilc.system.lifetime -m MODULE ARGS`` sets the parent-death signal before
anything else is imported (about 0.1 s after the fork, stdlib only), then runs MODULE as
``python -m MODULE ARGS`` would. A SIGTERM before the node installs its own handler ends it
at once (the default action).

A launcher may also hold its processes at a gate (``GATE_ENV``): they start, import what
they need (the longest part of a process's start), and call ``wait_at_gate()`` before they
join DDS; the gate opens when the launcher closes their stdin (a pipe). So the processes
start while the launcher still looks for another formation on the domain, and none of them
joins a domain the launcher then refuses: it stops them at the gate.
"""

from __future__ import annotations

import os
import signal
import sys

__all__ = ["PARENT_ENV", "GATE_ENV", "STOP_GRACE", "ORPHAN_GRACE", "ORPHAN_BOUND",
           "bound_the_stop", "die_with_parent", "parent_gone", "wait_at_gate", "early_argv",
           "RUNNER"]

#: environment variable naming the pid of the launcher that supervises this process
PARENT_ENV = "FORMATION_ILC_PARENT"
#: environment variable: "stdin" holds the process until its stdin reaches its end
GATE_ENV = "FORMATION_ILC_GATE"
#: seconds a stopping process has to end cleanly before SIGALRM ends it
STOP_GRACE = 10.0
#: the same once its launcher is gone (nobody waits for it: it must end within
#: ORPHAN_BOUND of the launcher, start-up and a loaded machine included)
ORPHAN_GRACE = 3.0
ORPHAN_BOUND = 5.0
#: the module that starts a node process with the parent-death signal set first
RUNNER = "formation_ilc.system.lifetime"


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


def wait_at_gate() -> None:
    """With ``GATE_ENV`` set to "stdin": return once stdin is at its end (the launcher
    closed the pipe: go on), reading and dropping whatever comes. A signal while waiting
    ends the process as it would anyway (the launcher refused the run)."""
    if os.environ.get(GATE_ENV) != "stdin":
        return
    try:
        while os.read(0, 4096):
            pass
    except OSError:  # no stdin at all: nothing to wait for
        return


def parent_gone() -> bool:
    """Whether this process was started by a launcher that is no longer its parent (a
    check beside PR_SET_PDEATHSIG, for a loop that runs anyway)."""
    parent = os.environ.get(PARENT_ENV)
    return bool(parent) and str(os.getppid()) != parent


def bound_the_stop(grace: float | None = None) -> None:
    """End this process ``grace`` seconds from now (SIGALRM, default action), unless it
    has ended by then; a second call does not push the bound back. Default: STOP_GRACE,
    ORPHAN_GRACE when the launcher is already gone."""
    if grace is None:
        grace = ORPHAN_GRACE if parent_gone() else STOP_GRACE
    left = signal.getitimer(signal.ITIMER_REAL)[0]
    if 0 < left <= grace:
        return
    signal.signal(signal.SIGALRM, signal.SIG_DFL)
    signal.setitimer(signal.ITIMER_REAL, grace)


def early_argv(argv: list[str]) -> list[str]:
    """``argv`` (a command line ``... python -m MODULE ARGS``, possibly behind a wrapper such
    as ``ip netns exec NS``) run through RUNNER: ``... python -m RUNNER -m MODULE ARGS``;
    any other command line unchanged."""
    for i in range(len(argv) - 2):
        if argv[i + 1] == "-m" and os.path.basename(argv[i]).startswith("python") \
                and argv[i + 2] != RUNNER:
            return [*argv[: i + 1], "-m", RUNNER, *argv[i + 1:]]
    return list(argv)


def _run(argv: list[str]) -> None:
    """``python -m formation_ilc.system.lifetime -m MODULE ARGS``: the parent-death signal
    first, then MODULE as ``__main__`` with ``sys.argv`` as ``python -m MODULE ARGS`` sets
    it."""
    die_with_parent()
    from formation_ilc.system.heartbeat import beat

    beat("importing")  # the supervisor's first sign of it (system.heartbeat)
    if len(argv) < 2 or argv[0] != "-m":
        print(f"usage: python -m {RUNNER} -m MODULE [ARGS...]", file=sys.stderr)
        raise SystemExit(2)
    import runpy

    sys.argv = [argv[1], *argv[2:]]
    runpy.run_module(argv[1], run_name="__main__", alter_sys=True)


if __name__ == "__main__":
    _run(sys.argv[1:])
