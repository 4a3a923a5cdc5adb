"""Exit statuses of the stack's node processes, and what a supervisor does with each.

A launcher (or systemd) restarts a node that died of something a new process can get past
(a crash, a kill); it must not restart one whose cause a restart cannot change: the node
refused its input, the run is stuck, or the disk is full. Each is named here once.
"""

from __future__ import annotations

import errno

__all__ = ["OK", "CRASHED", "REFUSED", "FAILED", "STUCK", "DISK_FULL", "CONTACT", "STOPPED",
           "NO_RESTART",
           "DISK_FULL_TAG", "is_disk_full"]

OK = 0
#: an exception escaped (Python's own status): restartable
CRASHED = 1
#: bad input: a parameter, a scenario, a state file, another formation here
REFUSED = 2
#: the node stopped the run on purpose (a lockstep time-out naming a silent robot)
FAILED = 3
#: the leader's watchdog gave up: a phase passed its bound after every retry
STUCK = 4
#: a write failed for want of space (ENOSPC, EDQUOT): the node named the file
DISK_FULL = 5
#: a plant with bodies ended the run: robots touched (or one tipped) past what its
#: ``--on-contact`` policy allows; the node named the pair
CONTACT = 6
#: someone pressed the stop button: a call to the leader's ``stop`` service (std_srvs/
#: Trigger), or an e-stop on ``estop``; every robot was commanded zero, the leader names
#: who stopped it
STOPPED = 7
#: statuses a supervisor does not restart
NO_RESTART = frozenset({REFUSED, STUCK, DISK_FULL, CONTACT, STOPPED})
#: what a node's last line says when the disk is full (a supervisor looks for it)
DISK_FULL_TAG = "disk full"


def is_disk_full(exc: BaseException) -> bool:
    """Whether ``exc`` is a write that failed because the disk (or quota) is full."""
    return isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT)
