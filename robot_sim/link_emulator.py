"""Link emulator (``formation-ilc-link-emulator``): the scenario's delays on the
robot-to-robot links.

Started only for ``links: emulated`` runs. It reads every robot's ``shared_pose`` and the
leader's ``reference`` and, at tick t, delivers to robot i on each link (an in-neighbour j,
and the leader if robot i sees it) the pose labelled ``delivered_label(t, tau)`` with its
original label, tau being the delay stream of trial k as the batch simulator draws it. Each
link gets one message per tick on ``robot_i/links/<sender>``: the delivered pose, or no
pose while the label would be negative. So a robot knows when a tick is complete, and a
lockstep run equals the batch simulator. It reports the injected delay histograms per link
on ``diagnostics`` (``injected``). With ``delay: loss: p`` in the scenario, a link loses
each sample with probability p (drawn as the batch simulator draws it): at that tick it
delivers nothing, and the robot leaves the link out of that sample's term (``lost``).

* lockstep: tick t's messages go out when every robot's sample-t shared pose and the
  reference are in.
* realtime: the tick is ``/clock``. Robot i's messages for tick t go out as soon as the poses
  they need are in, at the latest ``DELIVERY_WAIT`` dT after the tick, without the ones
  still missing (counted as ``late`` per link; not in ``injected``, so the robots' eq. (11)
  measurements still equal ``injected``).

Trials follow the leader's events (``formation_ilc.protocol.schedule``): ``start`` names the
iteration (whose delay stream is drawn) and the slot (whose labels are accepted). Poses and
ticks of the next slot that come before its start event are held (at most one trial's
worth) and replayed when it comes; any other label is dropped and counted, so no message
can move the emulator to another trial. On ``abort`` it drops the trial and reports ready.
Within a trial it takes each sample once (lockstep: at most the sample being collected;
realtime: any, since a stalled emulator may find poses ahead of its ``/clock``), and
``/clock`` ticks in order.

Everything it decides is in ``formation_ilc.protocol.linkemu.EmulatedLinks`` (the start
and abort by the rule every follower of the schedule applies,
``formation_ilc.protocol.schedule.Follower``); this node decodes and publishes, and makes one
call into it per event.

The run configuration comes from the latched ``config`` topic; no parameters.
"""

from __future__ import annotations

import sys
from typing import Any

from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
from rosgraph_msgs.msg import Clock
from std_msgs.msg import String

import msgs_schema as ms
from formation_ilc.core.clock import Rejected
from formation_ilc.nodes.common import (
    ConfiguredNode,
    RunConfig,
    matched,
    node_parser,
    spin_main,
    unmatched,
)
from formation_ilc.nodes.params import declare
from formation_ilc.protocol.linkemu import CLOCK, REFERENCE, SHARED, Emitted, EmulatedLinks
from msgs_schema import wire
from msgs_schema.wire import RawPose

#: realtime: the emulator delivers at the latest this many dT after the tick
DELIVERY_WAIT = 0.5
#: the emulator's node name (what it says ready as)
NAME = ms.LINKS_NODE


class LinkEmulator(ConfiguredNode):
    """The robot-to-robot links, with the scenario's delays in simulated time."""

    def __init__(self, **kwargs: Any):
        super().__init__(NAME, **kwargs)
        declare(self, ())  # no parameters of its own; use_sim_time refused
        self.follow_config()

    def configure(self, cfg: RunConfig) -> None:
        self.links: EmulatedLinks[RawPose] = EmulatedLinks(cfg)
        self.follower = self.links.follower
        self.cfg = cfg
        self.realtime = self.links.realtime
        # per receiver, per link (the order of ``links.links``): its publisher
        self.out = [[self.create_publisher(Path, ms.link_topic(i + 1, s), ms.SAMPLE_QOS)
                     for s, _ in links] for i, links in enumerate(self.links.links)]
        self.ready_pub = self.create_publisher(String, ms.READY, ms.LATCHED_QOS)
        # the per-sample messages as bytes (msgs_schema.wire: no message objects)
        self.pose_subs = [
            self.create_subscription(PoseStamped, ms.shared_pose_topic(j + 1),
                                     lambda m, j=j: self._on_shared(m, j), ms.SAMPLE_QOS,
                                     raw=True) for j in range(self.links.n)]
        self.pose_subs.append(self.create_subscription(
            PoseStamped, ms.REFERENCE, self._on_reference, ms.SAMPLE_QOS, raw=True))
        self.create_subscription(String, ms.TRIAL_EVENTS, self._on_event, ms.SAMPLE_QOS)
        if self.realtime:
            self.create_subscription(Clock, ms.CLOCK, self._on_clock, ms.CLOCK_QOS, raw=True)
            self._deadline = self.create_timer(DELIVERY_WAIT * cfg.scenario.dt,
                                               self._on_deadline)
            self._deadline.cancel()
        self._gate = self.create_timer(0.05, self._check_ready)

    def _check_ready(self) -> None:
        pubs = [(p, 1) for pubs in self.out for p in pubs]
        subs = [(s, 1) for s in self.pose_subs]  # both ends matched: no first pose lost
        need = pubs + subs + [(self.ready_pub, 1)]
        if matched(need):
            self._gate.cancel()
            self.ready_pub.publish(self.ready_msg(0))
            return
        self.not_ready(unmatched(need))

    def _on_event(self, msg: String) -> None:
        res = self.take_event(msg, self.links.on_event)
        if res is None or res[0] is None:
            return
        ev, out = res
        if ev.event == ms.ABORT:
            if self.realtime and not self.links.waiting:
                self._deadline.cancel()
            if self._gate.is_canceled():
                self.ready_pub.publish(self.ready_msg(self.links.iteration + 1))
            return
        self._emit(out)

    def _emit(self, out: Emitted[RawPose]) -> None:
        """Publish what the links send, count the held inputs they refused, and report the
        trial once its last deliveries are out."""
        for kind, j, exc in out.refused:
            self.drops.reject(exc, self._topic(kind, j))
        for i, m, tick, pose in out.ticks:
            self.out[i][m].publish(wire.link_tick_bytes(tick, pose))
        if self.realtime:
            if out.arm:
                self._deadline.reset()
            if not self.links.waiting:
                self._deadline.cancel()
        if out.done:
            d: dict[str, Any] = {"node": NAME, **self.links.report()}
            d.update(self.drops.as_dict())
            self.diag_pub.publish(ms.diagnostics_to_msg(
                d, self.get_clock().now().nanoseconds, self.cfg.scenario.dt,
                self.cfg.scenario.samples))
            self.ready_pub.publish(self.ready_msg(self.links.iteration + 1))

    @staticmethod
    def _topic(kind: str, j: int) -> str:
        return {SHARED: ms.shared_pose_topic(j + 1), REFERENCE: ms.REFERENCE,
                CLOCK: "clock"}[kind]

    def _on_pose(self, msg: PoseStamped | bytes, kind: str, j: int) -> None:
        try:
            p = wire.read_pose(wire.as_bytes(msg))  # the pose as received, bit for bit
            wire.world_eta(p)
            out = (self.links.on_reference(p.label_ns, p) if kind == REFERENCE
                   else self.links.on_shared(j, p.label_ns, p))
        except Rejected as exc:
            self.drops.reject(exc, self._topic(kind, j))
            return
        self._emit(out)

    def _on_shared(self, msg: PoseStamped | bytes, j: int) -> None:
        self._on_pose(msg, SHARED, j)

    def _on_reference(self, msg: PoseStamped | bytes) -> None:
        self._on_pose(msg, REFERENCE, -1)

    def _on_clock(self, msg: Clock | bytes) -> None:
        try:
            out = self.links.on_clock(wire.read_clock(wire.as_bytes(msg)))
        except Rejected as exc:
            self.drops.reject(exc, "clock")
            return
        self._emit(out)

    def _on_deadline(self) -> None:
        self._emit(self.links.deadline())


def main(args: list[str] | None = None) -> int:
    return spin_main(lambda ns, argv: [LinkEmulator()],
                     node_parser("formation-ilc-link-emulator", __doc__), args)


if __name__ == "__main__":
    sys.exit(main())
