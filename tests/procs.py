"""Process helpers of the multi-process tests: find a node process, stop a launcher's
whole process group (also when a test fails)."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

# a launcher's process tree: the benchmarks read it through the same module
from formation_ilc.system.proctree import children_of, gone  # noqa: F401


def stop_group(proc: subprocess.Popen, first: int = signal.SIGINT, grace: float = 15.0) -> None:
    """Stop ``proc``'s process group (started with start_new_session=True) if it still
    runs: ``first``, then SIGKILL after ``grace`` seconds."""
    if proc.poll() is not None:
        return
    os.killpg(proc.pid, first)
    try:
        proc.wait(timeout=grace)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def end_forger(proc: subprocess.Popen, grace: float = 60.0) -> str:
    """What a second process (``tests/stack/forger.py``) said, once it ended. It ends by
    itself when it sees the run's leader leave the graph; if it has not seen that within
    ``grace`` s of the run's end (its reader's discovery late under load), it is told by
    SIGINT, and says what it forged then."""
    try:
        return str(proc.communicate(timeout=grace)[0])
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGINT)
        return str(proc.communicate(timeout=60)[0])


def same_netns(pid: int | str) -> bool:
    """Whether process ``pid`` is in this process's network namespace: a domain id names a
    run only within one (other sessions may run the same id in namespaces of their own)."""
    try:
        return os.readlink(f"/proc/{pid}/ns/net") == os.readlink("/proc/self/ns/net")
    except OSError:
        return False


def processes() -> Iterator[tuple[int, str, list[bytes]]]:
    """(pid, command line with spaces, environment entries) of every live process but this
    one that can be read."""
    for pid in os.listdir("/proc"):
        if not pid.isdigit() or int(pid) == os.getpid():
            continue
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
            env = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
        except OSError:
            continue
        yield int(pid), cmd, env


def find_child(domain: str, needle: str, deadline: float) -> int:
    """pid of a process of this test's domain (and network namespace) whose command line
    contains ``needle``."""
    while time.monotonic() < deadline:
        for pid, cmd, env in processes():
            if needle in cmd and f"ROS_DOMAIN_ID={domain}".encode() in env \
                    and same_netns(pid):
                return pid
        time.sleep(0.1)  # polling the process table, bounded by the deadline
    raise AssertionError(f"no process {needle!r} found")


def spin_until(ex, cond, timeout: float = 10.0, step: float = 0.01) -> None:
    """Spin executor ``ex`` until ``cond()`` holds; fail after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, "timed out"
        ex.spin_once(timeout_sec=step)


def wait_emulator_ready(ex, tester, emu) -> None:
    """Give the link emulator ``emu`` a reader on each of its links and on ``ready``, and
    spin until it has said ready: it obeys a start only after its ready (as every follower
    of the schedule does)."""
    from nav_msgs.msg import Path as PathMsg
    from std_msgs.msg import String

    import msgs_schema as ms

    said: list[str] = []
    tester.create_subscription(String, ms.READY,
                               lambda m: said.append(ms.msg_to_json(m).get("node")),
                               ms.LATCHED_READER_QOS)
    for i, links in enumerate(emu.links.links):
        for sender, _ in links:
            tester.create_subscription(PathMsg, ms.link_topic(i + 1, sender), lambda m: None,
                                       ms.SAMPLE_QOS)
    spin_until(ex, lambda: "link_emulator" in said)
