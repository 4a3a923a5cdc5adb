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
