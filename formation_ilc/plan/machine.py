"""What the planner knows of the machine it plans on: one value, found once.

``decide(options, machine)`` (``formation_ilc.plan.build``) is a pure function: everything it
would otherwise learn from the process and the machine, the caller's ROS domain and Fast DDS
profile, the clock, the shared-memory files of other runs, the optional extras installed, the
randomness of a new run's id, is read here, once, by :meth:`Machine.probe`. A test plans on a
``Machine`` of its own making: a domain taken, an extra missing, a fixed clock.

What ``decide`` still reads, it reads from the files the options name (the scenario, a params
file, an initial memory, a stored run's state to resume, a keystore's certificates) and the
libraries installed (whether the loaded Fast DDS can run secure); it writes nothing, binds
nothing and starts nothing: ``prepare(plan)`` makes the folders, files, ports and keys.
"""

from __future__ import annotations

import importlib.util
import os
import secrets
import time
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

__all__ = ["Machine", "DOMAINS"]

#: the ROS domains a launcher picks from when none is given (ids whose Fast DDS port files
#: another run holds are skipped)
DOMAINS = range(30, 101)


def _held_domains() -> frozenset[int]:
    """The domains of :data:`DOMAINS` whose Fast DDS shared-memory port files exist (another
    run on this machine): their locks name the domain's port, 7400 + 250 d."""
    from formation_ilc.system.shm import fastdds_files

    names = [Path(f).name for f in fastdds_files()]
    return frozenset(d for d in DOMAINS
                     if any(n.startswith(f"fastrtps_port{7400 + 250 * d}") for n in names))


@dataclass(frozen=True)
class Machine:
    """The machine a run is planned on, as the planner needs it.

    ros_domain_id : the caller's ``ROS_DOMAIN_ID`` as set ('' when unset)
    profiles_file : the caller's ``FASTRTPS_DEFAULT_PROFILES_FILE`` ('' when unset)
    pid : the launcher's process id (a picked domain differs between launchers)
    held_domains : domains other runs on this machine hold (their shared-memory files)
    now : the wall time of the plan: a default output folder's name
    time_ns : the same instant, for the emulated clocks' origin
    token : random bytes: a new run's id is made of them
    has_foxglove : whether foxglove-sdk (``--live``) is installed
    """

    ros_domain_id: str = ""
    profiles_file: str = ""
    pid: int = 1
    held_domains: frozenset[int] = field(default_factory=frozenset)
    now: datetime = datetime(2026, 1, 1)
    time_ns: int = 0
    token: bytes = b"\0" * 16
    has_foxglove: bool = True

    @classmethod
    def probe(cls) -> Machine:
        """This process on this machine, now."""
        return cls(ros_domain_id=os.environ.get("ROS_DOMAIN_ID", ""),
                   profiles_file=os.environ.get("FASTRTPS_DEFAULT_PROFILES_FILE", ""),
                   pid=os.getpid(), held_domains=_held_domains(), now=datetime.now(),
                   time_ns=time.time_ns(), token=secrets.token_bytes(16),
                   has_foxglove=importlib.util.find_spec("foxglove") is not None)

    @property
    def user_profile(self) -> Path | None:
        """The caller's Fast DDS profiles file, or None."""
        return Path(self.profiles_file) if self.profiles_file else None

    def run_id(self) -> str:
        """A new run's id: a letter first (an all-digit id would reach the leader as an
        integer parameter), then 12 hex digits of :attr:`token`."""
        return "r" + self.token.hex()[:12]

    def free_domain(self) -> int:
        """A ROS domain of :data:`DOMAINS`, distinct per launcher process, avoiding those
        another run holds."""
        base = self.pid % len(DOMAINS)
        for off in range(len(DOMAINS)):
            d = DOMAINS[(base + off) % len(DOMAINS)]
            if d not in self.held_domains:
                return d
        return DOMAINS[base]
