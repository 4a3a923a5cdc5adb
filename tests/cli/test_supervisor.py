"""The supervisor's restarts (formation_ilc.cli.supervisor): a server restarted on a port
it can bind, and every node process started through the runner that sets its
parent-death signal first (formation_ilc.system.lifetime)."""

from __future__ import annotations

import socket
import sys

from formation_ilc.cli.supervisor import Stack, bindable, free_port
from formation_ilc.system.lifetime import RUNNER, early_argv


def test_a_restarted_server_gets_a_port_it_can_bind(tmp_path):
    """Before: a live view killed mid-run was restarted on its port, held meanwhile (or
    in TIME_WAIT), exited "Address already in use" and stayed gone. Now a restart checks
    the port as the server binds it and, when it is taken, takes a free one and says so."""
    stack = Stack({}, tmp_path / "logs")
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        port = held.getsockname()[1]
        assert not bindable("127.0.0.1", port)
        argv = [sys.executable, "-c", "pass", "--host", "127.0.0.1", "--port", str(port)]
        stack.start("liveview", argv)
        stack.procs["liveview"].wait(timeout=60)
        note = stack.restart("liveview")
        assert note.startswith("; serving on port ") and f"(127.0.0.1:{port} is taken)" in note
        new = int(stack.argv["liveview"][-1])
        assert new != port and bindable("127.0.0.1", new)
    stack.procs["liveview"].wait(timeout=60)
    assert stack.restart("liveview") == ""  # a free port is kept
    stack.stop()
    assert free_port("127.0.0.1") is not None


def test_node_processes_start_through_the_runner():
    py = sys.executable
    assert early_argv([py, "-m", "robot_sim.node", "--ros-args"]) == \
        [py, "-m", RUNNER, "-m", "robot_sim.node", "--ros-args"]
    wrapped = ["ip", "netns", "exec", "r1", py, "-m", "formation_ilc.nodes.robot"]
    assert early_argv(wrapped) == [*wrapped[:5], "-m", RUNNER, *wrapped[5:]]
    assert early_argv(early_argv(wrapped)) == early_argv(wrapped)
    assert early_argv(["bash", "-c", "true"]) == ["bash", "-c", "true"]


def test_the_processes_that_died_are_told_without_asking_each(tmp_path):
    """``Stack.dead``: none while every process lives; a process that exits is told with
    its status, and still is once another owner reaped it; a child of someone else that
    exited does not make a live process dead."""
    import subprocess
    import time

    stack = Stack({}, tmp_path / "logs")
    other = subprocess.Popen([sys.executable, "-c", "pass"])  # not the stack's
    try:
        stack.start("sleeper", [sys.executable, "-c", "import time; time.sleep(60)"])
        stack.start("quitter", [sys.executable, "-c", "import sys; sys.exit(3)"])
        deadline = time.monotonic() + 60
        while not stack.dead() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert stack.dead() == [("quitter", 3)]
        other.wait(timeout=60)
        assert stack.dead() == [("quitter", 3)]
        stack.procs["sleeper"].kill()
        stack.procs["sleeper"].wait(timeout=60)  # reaped by another owner than dead()
        assert sorted(stack.dead()) == [("quitter", 3), ("sleeper", -9)]
    finally:
        stack.stop()
        other.kill()
        other.wait(timeout=60)
