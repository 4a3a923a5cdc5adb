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

``--apart``: the writer in a participant of its own (its GID another participant's; Fast
DDS still delivers within the process, not through a transport).

``--process RATE``: the per-sample case as a run has it: the writer in a process of its
own publishes ``--messages`` raw poses at RATE a second, and the reader's process counts
the CPU time (``time.process_time``, all its threads: rmw's, the executor's) it spent from
the first of them to the last, per message: the reader's whole cost of a message, its
wake-ups included.

``--idle N``: a reader with N subscriptions and no writer, 5 s a round: the CPU a second a
checked subscription costs when nothing comes (its re-check every ``--poll`` s: 0.05, the
``REFRESH_HELD`` of readies, reports and ``team/poses``; a robot's trajectories 0.25).
Run it with ``PYTHONPATH`` at the checkout to measure (a script's directory comes first on
its path, and an editable install may point at another checkout).

``--table N``: the writer table alone, no ROS: what a ready's ``claims`` costs among N
members when each name is pinned to its first participant, and when it is pinned to its
enclave (``--secure``: ``WriterTable.enclaves``).

``--paced``: each message is published only once the one before was taken (the per-sample
topics of a lockstep run: one message, then a wait), so every message pays its own
wake-up; without it the messages go out in a burst.

Usage: python scripts/bench_writers.py [--messages 2000] [--repeats 5]
       [--topic ready|pose|both] [--paced] [--apart]
       python scripts/bench_writers.py --process 1000 [--messages 2000] [--repeats 5]
       python scripts/bench_writers.py --idle 50 [--poll 0.05] [--repeats 5]
       python scripts/bench_writers.py --table 8
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


def write_poses(n: int, rate: float) -> None:
    """The writer of ``--process``: robot_1's raw poses, ``n`` after one to be named by,
    at ``rate`` a second, once a reader matched; then it waits for them to be taken."""
    from rclpy.duration import Duration

    node = rclpy.create_node("robot_1", namespace="/formation")
    qos = QoSProfile(depth=n + 10, history=HistoryPolicy.KEEP_LAST,
                     reliability=ReliabilityPolicy.RELIABLE)
    pub = node.create_publisher(PoseStamped, "robot_1/pose", qos)
    data = serialize_message(POSE)
    deadline = time.monotonic() + 30
    while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(1.0)  # the reader's graph names this node
    pub.publish(data)
    time.sleep(0.5)
    t0 = time.monotonic()
    for i in range(n):
        time.sleep(max(0.0, t0 + i / rate - time.monotonic()))
        pub.publish(data)
    pub.wait_for_all_acked(Duration(seconds=10))
    time.sleep(0.5)
    node.destroy_node()


def cross_round(kind: str, checked: bool, n: int, rate: float) -> float:
    """CPU seconds the reader spent per message of ``n`` from a writer process."""
    import subprocess
    import sys

    qos = QoSProfile(depth=n + 10, history=HistoryPolicy.KEEP_LAST,
                     reliability=ReliabilityPolicy.RELIABLE)
    reader = GuardedNode("reader", namespace="/formation")
    got = [0]
    cpu = [0.0, 0.0]

    def take(msg: Any, gid: bytes | None = None) -> None:
        got[0] += 1
        if got[0] == 1:
            cpu[0] = time.process_time()
        elif got[0] == n + 1:
            cpu[1] = time.process_time()

    if checked:
        reader.checked_subscription(PoseStamped, "robot_1/pose", take, qos, raw=True,
                                    owners=("robot_1",))
    else:
        reader.create_subscription(PoseStamped, "robot_1/pose", take, qos, raw=True)
    ex = EventsExecutor() if kind == "events" else SingleThreadedExecutor()
    ex.add_node(reader)
    proc = subprocess.Popen([sys.executable, __file__, "--write-poses", str(n),
                             "--rate", str(rate)])
    try:
        deadline = time.monotonic() + 60 + n / rate
        while got[0] < n + 1 and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.01)
        assert got[0] == n + 1, f"{got[0] - 1} of {n} messages"
        return (cpu[1] - cpu[0]) / n
    finally:
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:  # a writer left waiting: stopped all the same
            proc.kill()
            proc.wait()
        ex.shutdown()
        reader.destroy_node()


def idle_round(checked: bool, subs: int, seconds: float, poll: float = 0.05) -> float:
    """CPU seconds a second of a reader node with ``subs`` subscriptions and no writer,
    on the events executor (a checked one's re-check every REFRESH_HELD seconds)."""
    qos = QoSProfile(depth=10, history=HistoryPolicy.KEEP_LAST,
                     reliability=ReliabilityPolicy.RELIABLE)
    reader = GuardedNode("reader", namespace="/formation")
    for i in range(subs):
        if checked:
            reader.checked_subscription(PoseStamped, f"robot_{i + 1}/pose",
                                        lambda m, gid: None, qos, raw=True,
                                        owners=(f"robot_{i + 1}",), poll=poll)
        else:
            reader.create_subscription(PoseStamped, f"robot_{i + 1}/pose",
                                       lambda m: None, qos, raw=True)
    ex = EventsExecutor()
    ex.add_node(reader)
    try:
        ex.spin_once(timeout_sec=0.1)
        c0, t0 = time.process_time(), time.monotonic()
        while time.monotonic() - t0 < seconds:
            ex.spin_once(timeout_sec=0.25)
        return (time.process_time() - c0) / (time.monotonic() - t0)
    finally:
        ex.shutdown()
        reader.destroy_node()


def table_round(writers: int, secure: bool, n: int) -> float:
    """[s] per ``claims`` of a ready in robot_3's name from its own writer, by a table of
    ``writers`` members that pins each name to its first participant, or (``secure``) to
    its enclave (``WriterTable.enclaves``); the best of 5 runs of ``n``."""
    import timeit

    from formation_ilc.config.enclaves import enclave_prefix
    from formation_ilc.protocol.writers import WriterTable

    ns, topic = "/formation", "/formation/ready"
    names = [f"robot_{i}" for i in range(1, writers + 1)]
    prefix = {m: enclave_prefix(f"CN={ns}/{m}".encode()) for m in names}
    gids = {m: prefix[m] + bytes([i]) * 6 + (1).to_bytes(4, "big")
            for i, m in enumerate(names)}
    table = WriterTable(ns, enclaves={f"{ns}/{m}": prefix[m] for m in names} if secure
                        else {})
    table.learn(topic, [(gids[m], m, ns) for m in names])
    for m in names:
        assert table.claims(topic, gids[m], m) == "ok"
    gid = gids["robot_3"]
    return min(timeit.repeat(lambda: table.claims(topic, gid, "robot_3"), number=n,
                             repeat=5)) / n


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
    ap.add_argument("--process", type=float, metavar="RATE",
                    help="the writer in a process of its own, RATE raw poses a second; "
                         "the reader's CPU time per message")
    ap.add_argument("--idle", type=int, metavar="N",
                    help="CPU a second of N idle subscriptions (events executor)")
    ap.add_argument("--poll", type=float, default=0.05,
                    help="--idle: the subscriptions' re-check period [s]")
    ap.add_argument("--executor", choices=("events", "single", "both"), default="both")
    ap.add_argument("--table", type=int, metavar="N",
                    help="the writer table alone (no ROS): a ready's claims among N "
                         "members, the participant pin against the enclave pin (--secure)")
    ap.add_argument("--write-poses", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--rate", type=float, default=1000.0, help=argparse.SUPPRESS)
    a = ap.parse_args()
    kinds = ("events", "single") if a.executor == "both" else (a.executor,)
    if a.table:
        pin, enclave = (table_round(a.table, secure, 100_000) * 1e6 for secure in (False, True))
        print(f"a ready's claims among {a.table} members: participant pin {pin:.2f} us, "
              f"enclave pin (--secure) {enclave:.2f} us: {enclave - pin:+.2f} us", flush=True)
        return
    rclpy.init()
    if a.write_poses:  # the writer process of --process
        try:
            write_poses(a.write_poses, a.rate)
        finally:
            rclpy.try_shutdown()
        return
    if a.idle:
        try:
            idle: dict[bool, list[float]] = {False: [], True: []}
            for _ in range(a.repeats):
                for checked in (False, True):
                    idle[checked].append(idle_round(checked, a.idle, 5.0, a.poll))
            plain, checked = (statistics.median(idle[c]) * 1e6 for c in (False, True))
            print(f"{a.idle} idle subscriptions (re-checked every {a.poll:g} s), events "
                  f"executor: CPU rclpy {plain:.0f} us/s, checked {checked:.0f} us/s: "
                  f"{(checked - plain) / a.idle:+.1f} us a second per subscription",
                  flush=True)
        finally:
            rclpy.try_shutdown()
        return
    if a.process:
        try:
            for kind in kinds:
                cross: dict[bool, list[float]] = {False: [], True: []}
                for _ in range(a.repeats):
                    for checked in (False, True):
                        cross[checked].append(cross_round(kind, checked, a.messages,
                                                          a.process))
                plain, checked = (statistics.median(cross[c]) * 1e6 for c in (False, True))
                spread = "; ".join(
                    f"{'checked' if c else 'rclpy'} {min(cross[c]) * 1e6:.1f}-"
                    f"{max(cross[c]) * 1e6:.1f}" for c in (False, True))
                print(f" pose from a process at {a.process:g}/s {kind:>6} executor: reader "
                      f"CPU rclpy subscription {plain:6.1f} us/message, checked "
                      f"{checked:6.1f} us/message: {checked - plain:+.1f} us per message "
                      f"(rounds: {spread})", flush=True)
        finally:
            rclpy.try_shutdown()
        return
    apart = None
    if a.apart:
        apart = Context()
        rclpy.init(context=apart)
    try:
        for topic in (("ready", "pose") if a.topic == "both" else (a.topic,)):
            for kind in kinds:
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
