"""The launcher's ROS host ends within its bound: a DDS teardown that blocks (Fast DDS
waiting on the shared-memory port of a process that ended, seen once after a 53-process
run) does not keep the launcher from its results."""

from __future__ import annotations

import threading

import pytest

pytestmark = pytest.mark.ros


class _Monitor:
    diagnostics = {"robot_1": {"node": "robot_1", "trial": 1}}

    def __init__(self, block: threading.Event | None = None):
        self.block = block
        self.destroyed = False

    def get_name(self):
        return "monitor"

    def report(self):
        return {"node": "monitor", "foreign_events": 0}

    def destroy_node(self):
        if self.block is not None:
            self.block.wait()  # as rmw's last graph update did, for ever
        self.destroyed = True


@pytest.fixture
def host(monkeypatch):
    import rclpy

    from formation_ilc.nodes import host as mod

    monkeypatch.setattr(mod, "CLOSE_S", 0.5)
    monkeypatch.setattr(mod.LauncherHost, "teardown_hung", False)
    shut = []
    monkeypatch.setattr(rclpy, "try_shutdown", lambda: shut.append(1))
    h = mod.LauncherHost(plan=None, on_trial=lambda k, row: None)
    yield h, shut, mod


def test_a_blocked_teardown_returns_the_diagnostics_after_its_bound_and_says_so(host, capsys):
    h, shut, mod = host
    block = threading.Event()
    h.monitor = _Monitor(block)
    try:
        diag = h.close()
    finally:
        block.set()  # let the teardown thread end, and wait for it: ended later, it
        # called the next test's stand-in of rclpy.try_shutdown (seen beside a busy loop)
        for t in threading.enumerate():
            if t.name == "dds-teardown":
                t.join()
    assert diag == {"robot_1": {"node": "robot_1", "trial": 1},
                    "monitor": {"node": "monitor", "foreign_events": 0}}
    assert mod.LauncherHost.teardown_hung
    err = capsys.readouterr().err
    assert "the launcher's DDS teardown did not end within 0.5 s" in err, err
    assert "the results are written without it" in err


def test_a_teardown_that_ends_is_waited_for(host, capsys):
    h, shut, mod = host
    h.monitor = _Monitor()
    diag = h.close()
    assert h.monitor.destroyed and shut == [1]
    assert not mod.LauncherHost.teardown_hung
    assert set(diag) == {"robot_1", "monitor"}
    assert capsys.readouterr().err == ""
