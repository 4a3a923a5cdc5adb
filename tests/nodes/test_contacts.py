"""What a plant node does with a contact that ends the run (``nodes.contacts``): its report
goes out and is acknowledged by its readers before the process is told to stop. Under load
the launcher once saw the exit before the report and lost the run's record of the contact
(summary.json's ``ended_by_contact``, its metrics row)."""

from __future__ import annotations

from concurrent.futures import Future
from types import SimpleNamespace
from typing import Any

import pytest

from formation_ilc.nodes import common
from formation_ilc.nodes.contacts import ACKED_WITHIN_S, ContactActing
from formation_ilc.protocol.physics_plant import ContactEvent, ContactWatch
from formation_ilc.system.exits import CONTACT


class _Log:
    def __init__(self, said: list[str]) -> None:
        self.said = said

    def warning(self, text: str) -> None:
        self.said.append("warning")

    def fatal(self, text: str) -> None:
        self.said.append("fatal")


class _Pub:
    def __init__(self, said: list[str]) -> None:
        self.said = said
        self.timeouts: list[float] = []

    def publish(self, msg: Any) -> None:
        self.said.append("publish")

    def wait_for_all_acked(self, timeout: float) -> bool:
        self.said.append("acked")
        self.timeouts.append(timeout)
        return True


class _Plant(ContactActing):
    def __init__(self) -> None:
        self.said: list[str] = []
        self.cfg = SimpleNamespace(scenario=SimpleNamespace(dt=0.2))
        self.diag_pub = _Pub(self.said)
        self.ready_pub = _Pub(self.said)

    def get_logger(self) -> _Log:
        return _Log(self.said)

    def get_name(self) -> str:
        return "physics_plant"

    def before_contact_end(self) -> None:
        self.said.append("last counts")

    def ready_msg(self, trial: int, **kw: Any) -> str:
        return "ready"


@pytest.fixture
def stop(monkeypatch):
    fut: Future = Future()
    monkeypatch.setattr(common.Exit, "stop", fut)
    monkeypatch.setattr(common.Exit, "code", 0)
    return fut


def _event(action: str, acts: bool = True) -> ContactEvent:
    return ContactEvent(trial=3, slot=4, sample=17, pairs=((2, 3, 0.4, 0.012),), tilt=0.0,
                        tilted=0, action=action, acts=acts)


@pytest.mark.parametrize("action", ["abort", "give_up"])
def test_a_contact_that_ends_the_run_is_acknowledged_before_the_node_stops(stop, action):
    plant = _Plant()
    # the stop is set inside fail(): record when, among the node's steps
    stop.add_done_callback(lambda f: plant.said.append(f"stop {f.result()}"))
    goes_on = plant.act_on_contact(_event(action), ContactWatch("abort"), 10**9)
    assert not goes_on
    assert plant.said == ["warning", "publish", "last counts", "acked", "fatal",
                          f"stop {CONTACT}"]
    # bounded: a reader that never answers does not keep a failed run alive
    assert plant.diag_pub.timeouts == [ACKED_WITHIN_S] and 0 < ACKED_WITHIN_S <= 5


@pytest.mark.parametrize("action,acts", [("stop", True), ("continue", True), ("stop", False)])
def test_a_contact_the_run_survives_does_not_wait(stop, action, acts):
    plant = _Plant()
    assert plant.act_on_contact(_event(action, acts), ContactWatch(action), 10**9)
    assert "acked" not in plant.said and not stop.done()
    assert plant.said[:2] == ["warning", "publish"]


def test_the_diagnostics_writer_waits_for_its_readers_acknowledgement(context):
    """The real ``Diagnostics`` (not the stand-in above) offers the wait the contact's end
    relies on, and it returns once a matched reader took the report."""
    import time

    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.node import Node

    import msgs_schema as ms
    from formation_ilc.nodes.common import Diagnostics

    a = Node("physics_plant", namespace="/acked", context=context)
    b = Node("monitor", namespace="/acked", context=context)
    try:
        diag = Diagnostics(a)
        b.create_subscription(DiagnosticArray, ms.DIAGNOSTICS, lambda m: None,
                              ms.LATCHED_QOS)
        end = time.monotonic() + 10
        while diag.pub.get_subscription_count() < 1 and time.monotonic() < end:
            time.sleep(0.02)
        assert diag.pub.get_subscription_count() == 1
        diag.publish(ms.diagnostics_to_msg({"node": "physics_plant", "trial": 0}, 10**9))
        assert diag.wait_for_all_acked(ACKED_WITHIN_S)
    finally:
        a.destroy_node()
        b.destroy_node()
