"""ROS environment fixtures: a private ROS_DOMAIN_ID per test, localhost discovery, and
clean-up of the Fast DDS shared-memory files that processes killed by a test leave."""

from __future__ import annotations

import itertools
import os
from collections.abc import Iterator

import pytest

from formation_ilc.system.shm import clean_leftovers, fastdds_files

_counter = itertools.count()


def next_domain_id() -> int:
    """Distinct per test in this run (pid + counter), within the free range 30..100."""
    return 30 + (os.getpid() * 13 + next(_counter)) % 71


def clean_shm(before: set[str]) -> list[str]:
    """Remove fastrtps_* files created since ``before`` that no live process holds."""
    return clean_leftovers(fastdds_files() - before)


@pytest.fixture
def ros_env(monkeypatch: pytest.MonkeyPatch) -> Iterator[dict[str, str]]:
    """Environment for ROS processes of one test: own domain, localhost discovery.

    Also applied to this process (for a test-side node) and undone afterwards; new
    Fast DDS shared-memory files that no process holds any more are removed at the end.
    """
    domain = next_domain_id()
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    before = fastdds_files()
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
