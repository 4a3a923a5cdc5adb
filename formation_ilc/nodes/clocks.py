"""The clock exchanges of a node (robot, bridge, leader): the ROS side of
``formation_ilc.protocol.timesync``.

A node that estimates other clocks asks them on its own ``clock/ping`` and takes their
answers on each one's ``clock/pong``; a node whose clock others estimate reads their
questions on each one's ``clock/ping`` and answers on its own ``clock/pong``
(``msgs_schema.clocksync``: each node publishes only topics of its name, so the enclaves'
permissions say who asked and who answered). Every time is read here, on
the node's clock (the machine's, or in an emulated run its robot's emulated clock over it:
``config.clocks``), and passed to the core; what the core decides is published and logged.
"""

from __future__ import annotations

import secrets
import time
from collections.abc import Callable, Iterable
from functools import partial
from typing import Any

from rclpy.node import Node
from sensor_msgs.msg import TimeReference

import msgs_schema as ms
from formation_ilc.config.runconfig import RunConfig
from formation_ilc.core.clock import Rejected
from formation_ilc.core.clocksync import EmulatedClock
from formation_ilc.protocol.timesync import (
    BURST_HZ,
    PING_HZ,
    ClockSync,
    NodeClock,
    converged_for,
)

__all__ = ["ClockExchange", "node_clock"]

#: [s] how often a node with peers says where its estimates are (a word on diagnostics:
#: the recording and analyze follow them over time) until every estimate converged, and
#: after: every robot's word is read by the leader, the monitor and the recorder (at 50
#: robots, 25 words a second as message objects every 2 s)
REPORT_EVERY_S = 2.0
STEADY_REPORT_EVERY_S = 10.0


def node_clock(cfg: RunConfig, robot: int | None) -> NodeClock:
    """The clock a node of robot ``robot`` (its robot node, its bridge; None: the leader,
    the ground station's machine) reads in run ``cfg``."""
    emulated: EmulatedClock | None = None
    if robot is not None:
        emulated = cfg.clocks.robot_clock(cfg.scenario.seed, robot)
    return NodeClock(emulated)


class ClockExchange:
    """Node ``node``'s questions to ``peers`` and answers to ``askers``.

    Every node publishes on topics of its own name only (``me/clock/ping``, its questions;
    ``me/clock/pong``, its answers): it reads each peer's answers and each asker's
    questions, and takes those that name it (``msgs_schema.clocksync``).

    askers : the node names allowed to ask this node's clock (empty: nobody).
    on_event : called with ('info' | 'warn', text) for what the core says once (an
        estimate converged, a clock step, no convergence, a silent peer).
    on_report : called every ``REPORT_EVERY_S`` while there are peers, every
        ``STEADY_REPORT_EVERY_S`` once every estimate converged (the node publishes
        its clock block as a word on diagnostics).
    """

    def __init__(self, node: Node, me: str, cfg: RunConfig, clock: NodeClock, *,
                 peers: Iterable[str], askers: Iterable[str], drops: Any,
                 on_event: Callable[[str, str], None] | None = None,
                 on_report: Callable[[], None] | None = None):
        self.node, self.me, self.clock, self.drops = node, me, clock, drops
        peers, askers = list(peers), list(askers)
        self.sync = ClockSync(
            me, peers, fallback=cfg.clocks.fallback, estimating=cfg.clocks.sync,
            truth=cfg.clocks.truth(cfg.scenario.seed, cfg.scenario.n),
            converged_ns=converged_for(cfg.clock.dt_ns))
        # numbers of another incarnation of this node cannot be taken for this one's
        self.sync.seq = secrets.randbelow(1 << 40)
        self.on_event, self.on_report = on_event, on_report
        self.subs = []
        self.ping_pub: Any = None
        if peers:
            self.ping_pub = node.create_publisher(TimeReference, ms.clock_ping_topic(me),
                                                  ms.CLOCK_SYNC_QOS)
            # bytes: a clock's answer topic carries its answers to every asker, each of
            # which reads them all (the leader of a 50-robot team answers 17 robots)
            self.subs += [node.create_subscription(
                TimeReference, ms.clock_pong_topic(p), partial(self._on_pong, peer=p),
                ms.CLOCK_SYNC_QOS, raw=True) for p in peers]
            # BURST_HZ while a peer's first questions go out, then PING_HZ: a wake-up of
            # the node each sample only to find nothing due cost a robot of a 50-robot
            # team CPU every sample (docs/distributed-stack.md)
            self._timer = node.create_timer(clock.scale / BURST_HZ, self._on_timer)
            self._report_due = 0.0
        self.pong_pub: Any = None
        if askers:
            self.pong_pub = node.create_publisher(TimeReference, ms.clock_pong_topic(me),
                                                  ms.CLOCK_SYNC_QOS)
            self.subs += [node.create_subscription(
                TimeReference, ms.clock_ping_topic(a), partial(self._on_ping, asker=a),
                ms.CLOCK_SYNC_QOS, raw=True) for a in askers]

    def now(self) -> int:
        """This node's clock now [ns]."""
        return self.clock.now(time.time_ns())

    # ------------------------------------------------------------------ asking
    def _on_timer(self) -> None:
        now = self.now()
        for peer, seq in self.sync.questions(now):
            self.ping_pub.publish(ms.ping_msg(seq, self.now(), peer))
        if not self.sync.early_ns and not self.sync.bursting(now):
            # every peer past its burst: wake once a question period, and ask what falls
            # due before the next wake-up (half a period) now
            self._timer.timer_period_ns = int(self.clock.scale / PING_HZ * 1e9)
            self.sync.early_ns = max(1, self.sync.period_ns // 2)
        for level, text in self.sync.events(now):
            # one call site per severity: rclpy refuses a call site whose severity
            # changes ("Logger severity cannot be changed between calls"), which killed
            # nodes of a 50-robot run at their first estimate after a warning
            log = self.node.get_logger()
            if level == "warn":
                log.warning(text)
            else:
                log.info(text)
            if self.on_event is not None:
                self.on_event(level, text)
        mono = time.monotonic()
        if self.on_report is not None and mono >= self._report_due:
            self._report_due = mono + (STEADY_REPORT_EVERY_S if self.sync.all_converged()
                                       else REPORT_EVERY_S)
            self.on_report()

    def _on_pong(self, msg: TimeReference | bytes, peer: str) -> None:
        """``peer``'s answer (its pong topic carries its answers to every asker)."""
        t4 = self.now()
        try:
            asker, seq, t2, t3 = ms.read_pong(msg)
            if asker != self.me:
                return  # an answer to another node's question
            self.sync.on_answer(peer, seq, t2, t3, t4)
        except Rejected as exc:
            self.drops.reject(exc, ms.clock_pong_topic(peer))

    # ------------------------------------------------------------------ answering
    def _on_ping(self, msg: TimeReference | bytes, asker: str) -> None:
        """``asker``'s question (its ping topic carries its questions to every clock it
        asks): answered when it asks this node's clock."""
        t2 = self.now()
        try:
            asked, seq, _ = ms.read_ping(msg)
        except Rejected as exc:
            self.drops.reject(exc, ms.clock_ping_topic(asker))
            return
        if asked == self.me:
            self.pong_pub.publish(ms.pong_msg(seq, t2, self.now(), asker))

    def report(self) -> dict[str, Any]:
        """The diagnostics block (``ClockSync.report``) now."""
        return self.sync.report(self.now())

    def remote_time(self, peer: str) -> tuple[int, str]:
        """``peer``'s clock now, and how it was had (``ClockSync.remote_time``)."""
        return self.sync.remote_time(peer, self.now())
