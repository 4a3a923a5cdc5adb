#!/usr/bin/env python3
"""What taking a message with its writer's GID and judging the writer costs
(formation_ilc.nodes.writers.CheckedSubscription over protocol.writers.WriterTable),
against rclpy's own subscription, on the executor the nodes use (rclpy's EventsExecutor)
and on the SingleThreadedExecutor.

One process: a writer node and a reader node. Each round publishes ``--messages``
messages and spins until the reader has them all; it prints the microseconds per message
of publishing and taking, the median of ``--repeats`` rounds, for each kind of
subscription, and the difference: the cost of the check per message. ``--topic``:

* ``ready``: a ready's JSON (about 200 bytes) on a shared topic, deserialized, its writer
  matched to the node it names (``claims``), as the leader and the monitor take readies;
* ``pose``: a PoseStamped as bytes (``raw``) on a topic one node owns (``judge``), as the
  robots take the per-sample topics (their pose, a neighbour's shared pose, the reference,
  a link tick, ``team/poses``).

``--apart``: the writer in a participant of its own (a second process's samples come
through the transport, not Fast DDS's delivery within one participant).

``--paced``: each message is published only once the one before was taken (the per-sample
topics of a lockstep run: one message, then a wait), so every message pays its own
wake-up; without it the messages go out in a burst.

Usage: python scripts/bench_writers.py [--messages 2000] [--repeats 5]
       [--topic ready|pose|both] [--paced] [--apart]
(run it in a network namespace of its own, or with a ROS_DOMAIN_ID nobody else uses)
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from std_msgs.msg import String

from formation_ilc.nodes.common import GuardedNode

READY = ('{"node": "robot_1", "trial": 3, "boot": "0123456789ab", "seen": 12, '
         '"run": "20261128-140000-abcdef", "config": {"seed": 7, "trials": 20, '
         '"law": "9", "memory": "current", "headings": "chord"}}')
POSE = PoseStamped()
POSE.header.frame_id = "world"
POSE.header.stamp.sec, POSE.header.stamp.nanosec = 1_700_000_012, 300_000_000
POSE.pose.position.x, POSE.pose.position.y, POSE.pose.orientation.w = 1.5, -2.25, 1.0


def one_round(kind: str, checked: bool, n: int, topic: str = "ready",
              paced: bool = False, apart: Context | None = None) -> float:
    """Seconds per message for ``n`` messages through one subscription (``apart``: the
    writer's node in this context, a participant of its own)."""
    qos = QoSProfile(depth=n + 10, history=HistoryPolicy.KEEP_LAST,
                     reliability=ReliabilityPolicy.RELIABLE)
    writer = rclpy.create_node("robot_1", namespace="/formation", context=apart)
    reader = GuardedNode("reader", namespace="/formation")
    got = [0]

    def take(msg: Any, gid: bytes | None = None) -> None:
        if gid is not None and not reader.from_named_writer("ready", gid, "robot_1"):
            return
        got[0] += 1

    def take_pose(msg: Any, gid: bytes | None = None) -> None:
        got[0] += 1

    msg: Any
    if topic == "ready":
        name, msg_type, msg = "ready", String, String(data=READY)
        if checked:
            reader.checked_subscription(String, name, take, qos, shared=True)
        else:
            reader.create_subscription(String, name, take, qos)
    else:
        name, msg_type = "robot_1/pose", PoseStamped
        msg = serialize_message(POSE)  # as the plant and the robots send them: bytes
        if checked:
            reader.checked_subscription(PoseStamped, name, take_pose, qos, raw=True,
                                        owners=("robot_1",))
        else:
            reader.create_subscription(PoseStamped, name, take_pose, qos, raw=True)
    pub = writer.create_publisher(msg_type, name, qos)
    ex = EventsExecutor() if kind == "events" else SingleThreadedExecutor()
    if apart is None:
        ex.add_node(writer)
    ex.add_node(reader)
    try:
        deadline = time.monotonic() + 10
        while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.01)
        pub.publish(msg)  # the writer is named in the graph from here on
        while got[0] < 1 and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.01)
        got[0] = 0
        t0 = time.perf_counter()
        if paced:
            for i in range(n):
                pub.publish(msg)
                while got[0] <= i and time.monotonic() < deadline + 60:
                    ex.spin_once(timeout_sec=0.01)
        else:
            for _ in range(n):
                pub.publish(msg)
        while got[0] < n and time.monotonic() < deadline + 60:
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
    ap.add_argument("--topic", choices=("ready", "pose", "both"), default="ready")
    ap.add_argument("--paced", action="store_true",
                    help="each message once the one before was taken")
    ap.add_argument("--apart", action="store_true",
                    help="the writer in a participant of its own")
    a = ap.parse_args()
    rclpy.init()
    apart = None
    if a.apart:
        apart = Context()
        rclpy.init(context=apart)
    try:
        for topic in (("ready", "pose") if a.topic == "both" else (a.topic,)):
            for kind in ("events", "single"):
                times: dict[bool, list[float]] = {False: [], True: []}
                for _ in range(a.repeats):
                    for checked in (False, True):  # taking turns: load drifts hit both
                        times[checked].append(one_round(kind, checked, a.messages, topic,
                                                        a.paced, apart))
                plain, checked = (statistics.median(times[c]) * 1e6 for c in (False, True))
                print(f"{topic:>5} {'paced' if a.paced else 'burst'}"
                      f"{' apart' if a.apart else ''} {kind:>6} executor: "
                      f"rclpy subscription {plain:6.1f} us/message, "
                      f"checked (GID take + writer judged) {checked:6.1f} us/message: "
                      f"{checked - plain:+.1f} us per message", flush=True)
    finally:
        if apart is not None:
            rclpy.try_shutdown(context=apart)
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
