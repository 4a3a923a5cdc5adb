"""A node that is not ready says what it waits for: ``unmatched`` names each endpoint whose
other side is missing, as ``matched`` counts them."""

from __future__ import annotations

import time

import pytest

pytestmark = pytest.mark.ros


def test_unmatched_names_the_endpoints_still_missing_their_other_side(context):
    from rclpy.node import Node
    from std_msgs.msg import String

    from formation_ilc.nodes.common import matched, unmatched

    a = Node("a", namespace="/m", context=context)
    b = Node("b", namespace="/m", context=context)
    try:
        pub = a.create_publisher(String, "out", 10)
        sub = a.create_subscription(String, "in", lambda m: None, 10)
        need = [(pub, 1), (sub, 1)]
        assert not matched(need)
        assert unmatched(need) == ["/m/out: 0 of 1 readers", "/m/in: 0 of 1 writers"]
        b.create_subscription(String, "out", lambda m: None, 10)
        end = time.monotonic() + 10
        while unmatched(need) != ["/m/in: 0 of 1 writers"] and time.monotonic() < end:
            time.sleep(0.05)
        assert unmatched(need) == ["/m/in: 0 of 1 writers"]
        b.create_publisher(String, "in", 10)
        while unmatched(need) and time.monotonic() < end:
            time.sleep(0.05)
        assert unmatched(need) == [] and matched(need)
    finally:
        a.destroy_node()
        b.destroy_node()


def _until(cond, timeout=10.0):
    end = time.monotonic() + timeout
    while not cond() and time.monotonic() < end:
        time.sleep(0.05)
    return cond()


def test_a_writer_waiting_for_named_readers_takes_no_other_reader_for_one(context):
    """The recorder (or any other reader) matched first does not stand in for the monitor:
    the trajectory writer waits until the monitor itself is there and matched."""
    from rclpy.node import Node
    from std_msgs.msg import String

    import msgs_schema as ms
    from formation_ilc.config.runconfig import RunConfig
    from formation_ilc.config.scenario import load_scenario
    from formation_ilc.nodes.common import matched, unmatched

    cfg = RunConfig(load_scenario("paper-triangle3"), monitored=True, recorded=True)
    assert cfg.result_readers == (ms.MONITOR_NODE, ms.RECORDER_NODE)
    plant = Node("robot_sim", namespace=ms.NAMESPACE, context=context)
    readers = []
    try:
        pub = plant.create_publisher(String, "robot_1/true_trajectory", 2)
        need = [(pub, cfg.result_readers)]
        assert not matched(need, plant)
        for name in (ms.RECORDER_NODE, "liveview"):  # two readers, neither the monitor
            readers.append(Node(name, namespace=ms.NAMESPACE, context=context))
            readers[-1].create_subscription(String, "robot_1/true_trajectory",
                                            lambda m: None, 2)
        assert _until(lambda: pub.get_subscription_count() == 2)
        time.sleep(0.3)  # and the graph has them
        assert not matched(need, plant)  # two readers for two names: not the right ones
        assert unmatched(need, plant) == [
            f"/formation/robot_1/true_trajectory: 2 of 2 readers (not yet discovered: "
            f"{ms.MONITOR_NODE})"]
        readers.append(Node(ms.MONITOR_NODE, namespace=ms.NAMESPACE, context=context))
        readers[-1].create_subscription(String, "robot_1/true_trajectory", lambda m: None, 2)
        assert _until(lambda: matched(need, plant))
        assert pub.get_subscription_count() == 3
        # without a recording, the monitor alone is named
        assert RunConfig(cfg.scenario, monitored=True).result_readers == (ms.MONITOR_NODE,)
    finally:
        for n in readers + [plant]:
            n.destroy_node()


class _Info:
    def __init__(self, name: str, ns: str = "/formation"):
        self.node_name, self.node_namespace = name, ns


class _Graph:
    """A node's graph as readers_wanting reads it: the readers listed on a topic."""

    def __init__(self, *names: str):
        self.listed = [_Info(n) for n in names]

    def get_subscriptions_info_by_topic(self, topic):
        return self.listed

    def get_namespace(self):
        return "/formation"


class _Writer:
    topic_name = "/formation/robot_48/trajectory"

    def __init__(self, matched: int):
        self.matched = matched

    def get_subscription_count(self):
        return self.matched


def test_a_reader_of_unknown_node_may_be_the_named_one_still_missing():
    """Seen in a 50-robot run: the monitor's participant dropped on its lease and found
    again; its reader is matched but the graph no longer names its node (rmw's
    _NODE_NAME_UNKNOWN_), and robot_48 waited for the monitor for ten minutes. A reader
    without a name counts for one missing name, never for more, and only once matched."""
    from formation_ilc.nodes.common import UNKNOWN_NODE, readers_wanting

    want = ("monitor",)
    assert readers_wanting(_Graph(UNKNOWN_NODE), _Writer(1), want) == ""
    # not matched yet: it waits, and says what the graph shows
    assert readers_wanting(_Graph(UNKNOWN_NODE), _Writer(0), want) == (
        "/formation/robot_48/trajectory: 0 of 1 readers (not yet discovered: monitor) "
        "(1 of unknown node)")
    # one unnamed reader cannot be both the monitor and the recorder
    both = ("monitor", "recorder")
    assert readers_wanting(_Graph(UNKNOWN_NODE, "liveview"), _Writer(2), both) != ""
    assert readers_wanting(_Graph(UNKNOWN_NODE, "recorder"), _Writer(2), both) == ""
    # a named reader of another node still stands in for nobody
    assert readers_wanting(_Graph("liveview"), _Writer(1), want) != ""
