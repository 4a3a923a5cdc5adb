#!/usr/bin/env python3
"""What taking a message with its writer's GID and judging the writer costs
(formation_ilc.nodes.writers.CheckedSubscription over protocol.writers.WriterTable),
against rclpy's own subscription, on the executor the nodes use (rclpy's EventsExecutor)
and on the SingleThreadedExecutor.

One process: a writer node and a reader node. Each round publishes ``--messages`` readies
(a ready's JSON, about 200 bytes) and spins until the reader has them all; it prints the
microseconds per message of publishing and taking, the median of ``--repeats`` rounds,
for each kind of subscription, and the difference: the cost of the check per message.

Usage: python scripts/bench_writers.py [--messages 2000] [--repeats 5]
(run it in a network namespace of its own, or with a ROS_DOMAIN_ID nobody else uses)
"""

from __future__ import annotations

import argparse
import statistics
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

from formation_ilc.nodes.common import GuardedNode

READY = ('{"node": "robot_1", "trial": 3, "boot": "0123456789ab", "seen": 12, '
         '"run": "20261128-140000-abcdef", "config": {"seed": 7, "trials": 20, '
         '"law": "9", "memory": "current", "headings": "chord"}}')


def one_round(kind: str, checked: bool, n: int) -> float:
    """Seconds per message for ``n`` messages through one subscription."""
    qos = QoSProfile(depth=n + 10, history=HistoryPolicy.KEEP_LAST,
                     reliability=ReliabilityPolicy.RELIABLE)
    writer = rclpy.create_node("robot_1", namespace="/formation")
    reader = GuardedNode("reader", namespace="/formation")
    got = [0]

    def take(msg: String, gid: bytes | None = None) -> None:
        if gid is not None and not reader.from_named_writer("ready", gid, "robot_1"):
            return
        got[0] += 1

    if checked:
        reader.checked_subscription(String, "ready", take, qos, shared=True)
    else:
        reader.create_subscription(String, "ready", take, qos)
    pub = writer.create_publisher(String, "ready", qos)
    ex = EventsExecutor() if kind == "events" else SingleThreadedExecutor()
    ex.add_node(writer)
    ex.add_node(reader)
    try:
        deadline = time.monotonic() + 10
        while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.01)
        pub.publish(String(data=READY))  # the writer is named in the graph from here on
        while got[0] < 1 and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.01)
        got[0] = 0
        msg = String(data=READY)
        t0 = time.perf_counter()
        for _ in range(n):
            pub.publish(msg)
        while got[0] < n and time.monotonic() < deadline + 30:
            ex.spin_once(timeout_sec=0.01)
        dt = time.perf_counter() - t0
        assert got[0] == n, f"{got[0]} of {n} messages"
        return dt / n
    finally:
        ex.shutdown()
        reader.destroy_node()
        writer.destroy_node()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--messages", type=int, default=2000)
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    rclpy.init()
    try:
        for kind in ("events", "single"):
            times: dict[bool, list[float]] = {False: [], True: []}
            for _ in range(a.repeats):
                for checked in (False, True):  # taking turns: load drifts hit both
                    times[checked].append(one_round(kind, checked, a.messages))
            plain, checked = (statistics.median(times[c]) * 1e6 for c in (False, True))
            print(f"{kind:>6} executor: rclpy subscription {plain:6.1f} us/message, "
                  f"checked (GID take + writer judged) {checked:6.1f} us/message: "
                  f"{checked - plain:+.1f} us per message")
    finally:
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
