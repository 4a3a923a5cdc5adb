"""The re-check of a node's writer-checked subscriptions (``GuardedNode.checked_subscription``):
one timer for all of them, each polled at its own period. A timer of each subscription
cost a wake-up of the executor each, 20 a second, even with nothing coming
(``scripts/bench_writers.py --idle``): a robot reads every in-neighbour's trajectory
through one."""

from __future__ import annotations

import time

import pytest

pytestmark = pytest.mark.ros

rclpy = pytest.importorskip("rclpy")
from geometry_msgs.msg import PoseStamped  # noqa: E402

import msgs_schema as ms  # noqa: E402


def test_one_timer_polls_every_checked_subscription_at_its_own_period(context):
    from rclpy.executors import SingleThreadedExecutor

    from formation_ilc.nodes.common import GuardedNode
    from formation_ilc.nodes.writers import REFRESH_HELD, REFRESH_TRIAL

    node = GuardedNode("reader", namespace=ms.NAMESPACE, context=context)
    ex = SingleThreadedExecutor(context=context)
    try:
        subs = [node.checked_subscription(PoseStamped, f"robot_{i}/pose", lambda m, g: None,
                                          ms.SAMPLE_QOS, raw=True, owners=(f"robot_{i}",),
                                          **({"poll": REFRESH_TRIAL} if i == 3 else {}))
                for i in (3, 1, 2)]
        running = [t for t in node.timers if not t.is_canceled()]
        assert len(running) == 1  # not one a subscription
        assert running[0].timer_period_ns == int(REFRESH_HELD * 1e9)
        polls = [0, 0, 0]
        for k, sub in enumerate(subs):
            take = sub.poll

            def counted(k: int = k, take=take) -> None:
                polls[k] += 1
                take()

            sub.poll = counted
        ex.add_node(node)
        # until the slow one was polled three times (an event, however loaded the machine)
        deadline = time.monotonic() + 60.0
        while polls[0] < 3 and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.05)
        slow, fast = polls[0], min(polls[1:])
        assert slow >= 3 and fast >= 3 * slow, polls
    finally:
        ex.shutdown()
        node.destroy_node()
