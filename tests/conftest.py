"""ROS environment fixtures: a private ROS_DOMAIN_ID per test, localhost discovery, and
clean-up of the Fast DDS shared-memory files that processes killed by a test leave."""

from __future__ import annotations

import itertools
import os
from collections.abc import Iterator
from pathlib import Path

import pytest

_counter = itertools.count()
SHM = Path("/dev/shm")


def next_domain_id() -> int:
    """Distinct per test in this run (pid + counter), within the free range 30..100."""
    return 30 + (os.getpid() * 13 + next(_counter)) % 71


def _in_use() -> set[str]:
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


def clean_shm(before: set[str]) -> list[str]:
    """Remove fastrtps_* files created since ``before`` that no live process holds."""
    new = {str(p) for p in SHM.glob("*fastrtps_*")} - before
    if not new:
        return []
    used = _in_use()
    removed = []
    for p in sorted(new - used):
        try:
            os.unlink(p)
            removed.append(p)
        except OSError:
            pass
    return removed


@pytest.fixture
def ros_env(monkeypatch: pytest.MonkeyPatch) -> Iterator[dict[str, str]]:
    """Environment for ROS processes of one test: own domain, localhost discovery.

    Also applied to this process (for a test-side node) and undone afterwards; new
    Fast DDS shared-memory files that no process holds any more are removed at the end.
    """
    domain = next_domain_id()
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    before = {str(p) for p in SHM.glob("*fastrtps_*")}
    env = dict(os.environ)
    yield env
    clean_shm(before)


@pytest.fixture
def context(ros_env):
    """A private rclpy Context for an in-process node test, shut down afterwards."""
    import rclpy
    from rclpy.context import Context

    ctx = Context()
    rclpy.init(context=ctx)
    yield ctx
    rclpy.try_shutdown(context=ctx)
