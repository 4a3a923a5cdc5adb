"""Link emulator (``formation-ilc-links``): the scenario's delays on the robot-to-robot links.

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

The run configuration comes from the latched ``config`` topic; no parameters.
"""

from __future__ import annotations

import sys
from collections import Counter
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
from rosgraph_msgs.msg import Clock
from std_msgs.msg import String

import msgs_schema as ms
from formation_ilc.core.clock import Rejected
from formation_ilc.core.links import LEADER, LOST, delivered_label, link_name
from formation_ilc.model.simulate import Problem
from formation_ilc.nodes.common import ConfiguredNode, RunConfig, matched, node_parser, spin_main
from formation_ilc.protocol.schedule import unexplained_gap

#: realtime: the emulator delivers at the latest this many dT after the tick
DELIVERY_WAIT = 0.5
#: the emulator's node name (what it says ready as)
NAME = ms.LINKS_NODE


class LinkEmulator(ConfiguredNode):
    """The robot-to-robot links, with the scenario's delays in simulated time."""

    def __init__(self, **kwargs: Any):
        super().__init__(NAME, **kwargs)
        self.follow_config()

    def configure(self, cfg: RunConfig) -> None:
        sc = cfg.scenario
        pb = Problem.from_scenario(sc)
        self.cfg, self.pb, self.clock = cfg, pb, cfg.clock
        n, n_t = pb.n, pb.samples
        self.n, self.T = n, n_t
        self.k = -1            # slot of the current (or last) trial
        self.iteration = -1
        self.active = False    # a trial has started and was not aborted
        # messages of a slot whose start event has not come yet: (slot, handler, msg)
        self.early: list[tuple[int, Any, Any]] = []
        self.early_max = (n + 2) * (n_t + 1)
        self.clock_t = -1
        self.next_t = 0
        self.realtime = cfg.mode == "realtime"
        # per receiver: (sender, link slot ell or -1 for the leader, publisher)
        self.out: list[list[tuple[str, int, Any]]] = []
        self.injected: dict[str, Counter[int]] = {}
        for i in range(n):
            to = ms.robot_name(i + 1)
            links = [(ms.robot_name(int(j) + 1), ell) for ell, j in enumerate(pb.src[i])
                     if j >= 0]
            if pb.leader[i] != 0.0:
                links.append((LEADER, -1))
            self.out.append([(s, ell, self.create_publisher(Path, ms.link_topic(i + 1, s),
                                                            ms.SAMPLE_QOS))
                             for s, ell in links])
            for s, _ in links:
                self.injected[link_name(s, to)] = Counter()
        self.late = {link: 0 for link in self.injected}
        self.lost = {link: 0 for link in self.injected}  # samples the links lost (loss)
        self.waiting: dict[int, int] = {}  # realtime: receiver -> tick it still waits for
        self.reported = False
        self.ready_pub = self.create_publisher(String, ms.READY, ms.LATCHED_QOS)
        self.diag_pub = self.create_publisher(String, ms.DIAGNOSTICS, ms.LATCHED_QOS)
        for j in range(n):
            self.create_subscription(PoseStamped, ms.shared_pose_topic(j + 1),
                                     lambda m, j=j: self._on_shared(m, j), ms.SAMPLE_QOS)
        self.create_subscription(PoseStamped, ms.REFERENCE, self._on_reference, ms.SAMPLE_QOS)
        self.create_subscription(String, ms.TRIAL_EVENTS, self._on_event, ms.SAMPLE_QOS)
        if self.realtime:
            self.create_subscription(Clock, ms.CLOCK, self._on_clock, ms.CLOCK_QOS)
            self._deadline = self.create_timer(DELIVERY_WAIT * sc.dt, self._on_deadline)
            self._deadline.cancel()
        self._gate = self.create_timer(0.02, self._check_ready)

    def _check_ready(self) -> None:
        pubs = [(p, 1) for links in self.out for _, _, p in links]
        if matched(pubs + [(self.ready_pub, 1)]):
            self._gate.cancel()
            self.ready_pub.publish(self.ready_msg(0))

    def _on_event(self, msg: String) -> None:
        ev = self.new_start_or_abort(msg)
        if ev is None:
            return
        self.seen = ev.seq
        if ev.event == ms.ABORT:
            if ev.slot == self.k:
                self.active = False
                self.waiting = {}
                if self.realtime:
                    self._deadline.cancel()
            self.early = [e for e in self.early if e[0] > ev.slot]
            if self._gate.is_canceled():
                self.ready_pub.publish(self.ready_msg(self.iteration + 1))
            return
        if ev.slot <= self.k or unexplained_gap(self.k, ev.slot, self.aborted_slots):
            self.drops.drop("stale" if ev.slot <= self.k else "future", ms.TRIAL_EVENTS,
                            f"start of slot {ev.slot} in {self.k}")
            return
        self._start(ev.trial, ev.slot)
        early, self.early = self.early, []
        for slot, handler, m in early:
            if slot == ev.slot:
                handler(m)
            elif slot > ev.slot:
                self.early.append((slot, handler, m))

    def _start(self, iteration: int, k: int) -> None:
        self.k = k
        self.iteration = iteration
        self.active = True
        self.clock_t = -1
        pb = self.pb
        # the delay stream of the iteration, as the batch simulator draws it
        self.tau, self.tau0 = self.cfg.scenario.uncertainty.draw_delays(
            self.cfg.scenario.seed, iteration, pb.n, pb.src.shape[1], pb.samples)
        self.shared: list[list[PoseStamped | None]] = [[None] * (self.T + 1)
                                                        for _ in range(self.n)]
        self.ref: list[PoseStamped | None] = [None] * (self.T + 1)
        self.count = np.zeros(self.T + 1, dtype=np.int64)
        self.next_t = 0
        self.waiting = {}
        self.reported = False

    def _slot_of(self, ns: int, msg: Any, handler: Any, topic: str) -> int | None:
        """Sample of a label of the current trial; a later slot's is held until its start
        event (bounded), anything else dropped and counted. None: not for now."""
        try:
            k, s = self.clock.decode(ns)
            # the next slot opens once this one is delivered (or aborted): before that no
            # real message of it can exist
            if k > self.k + 1 or (k == self.k + 1 and self.active and not self.reported):
                raise Rejected("future", f"label of slot {k} in slot {self.k}")
            if k > self.k:
                if len(self.early) >= self.early_max:
                    raise Rejected("future", f"label of slot {k} before its start; "
                                             f"{len(self.early)} messages held already")
                self.early.append((k, handler, msg))
                return None
            if k < self.k or not self.active:
                raise Rejected("stale", f"label of slot {k} in slot {self.k}"
                                        f"{'' if self.active else ' (over)'}")
        except Rejected as exc:
            self.drops.reject(exc, topic)
            return None
        if not self.realtime and topic != "clock" and s > self.next_t:
            self.drops.drop("future", topic, f"sample {s} while {self.next_t} is due")
            return None
        return s

    def _label(self, msg: PoseStamped, topic: str, handler: Any) -> int | None:
        try:
            ms.world_pose(msg)
            ns = ms.stamp_to_ns(msg.header.stamp)
        except Rejected as exc:
            self.drops.reject(exc, topic)
            return None
        return self._slot_of(ns, msg, handler, topic)

    def _on_shared(self, msg: PoseStamped, j: int) -> None:
        topic = ms.shared_pose_topic(j + 1)
        s = self._label(msg, topic, lambda m, j=j: self._on_shared(m, j))
        if s is None:
            return
        if self.shared[j][s] is not None or (s < self.next_t and not self.realtime):
            self.drops.drop("duplicate", topic, f"sample {s} again")
            return
        self.shared[j][s] = msg
        self.count[s] += 1
        self._deliver_waiting() if self.realtime else self._deliver()

    def _on_reference(self, msg: PoseStamped) -> None:
        s = self._label(msg, ms.REFERENCE, self._on_reference)
        if s is None:
            return
        if self.ref[s] is not None or (s < self.next_t and not self.realtime):
            self.drops.drop("duplicate", ms.REFERENCE, f"sample {s} again")
            return
        self.ref[s] = msg
        self._deliver_waiting() if self.realtime else self._deliver()

    def _needs(self, i: int, t: int) -> list[tuple[str, Any, PoseStamped | None, int, bool]]:
        """(sender, publisher, pose or None if not in yet, tau, whether anything is due) of
        each link of robot i at tick t."""
        out = []
        for sender, ell, pub in self.out[i]:
            tau = int(self.tau[i, ell, t] if ell >= 0 else self.tau0[i, t])
            s = delivered_label(t, tau)
            due = s >= 0
            src = self.ref if ell < 0 else self.shared[int(self.pb.src[i, ell])]
            out.append((sender, pub, src[s] if due else None, tau, due))
        return out

    def _send(self, i: int, t: int, force: bool = False) -> bool:
        """Robot i's messages of tick t, if every due pose is in (``force``: regardless,
        the missing ones counted late). Returns whether they were sent."""
        needs = self._needs(i, t)
        if not force and any(due and m is None for _, _, m, _, due in needs):
            return False
        tick = self.clock.stamp_ns(self.k, t)
        to = ms.robot_name(i + 1)
        for sender, pub, m, tau, due in needs:
            if tau >= LOST:
                self.lost[link_name(sender, to)] += 1
            elif due and m is None:
                self.late[link_name(sender, to)] += 1
            elif due:
                self.injected[link_name(sender, to)][tau] += 1
            pub.publish(ms.link_tick_to_msg(tick, m))
        return True

    def _deliver(self) -> None:
        """Lockstep: every tick whose poses are all in, in order."""
        while self.next_t < self.T and self.count[self.next_t] == self.n \
                and self.ref[self.next_t] is not None:
            t = self.next_t
            for i in range(self.n):
                self._send(i, t, force=True)
            self.next_t = t + 1
            if self.next_t == self.T:
                self._trial_done()

    # ------------------------------------------------------------------ realtime
    def _on_clock(self, msg: Clock) -> None:
        try:
            ns = ms.stamp_to_ns(msg.clock)
        except Rejected as exc:
            self.drops.reject(exc, "clock")
            return
        t = self._slot_of(ns, msg, self._on_clock, "clock")
        if t is None:
            return
        if t <= self.clock_t:
            self.drops.drop("duplicate" if t == self.clock_t else "out_of_order", "clock",
                            f"tick {t} after {self.clock_t}")
            return
        self.clock_t = t
        if self.waiting:  # the previous tick's deadline has not fired: it is over now
            self._on_deadline()
        if t >= self.T:
            return
        self.next_t = t
        self.waiting = {i: t for i in range(self.n)}
        self._deadline.reset()
        self._deliver_waiting()

    def _deliver_waiting(self, force: bool = False) -> None:
        for i, t in list(self.waiting.items()):
            if self._send(i, t, force):
                del self.waiting[i]
        if not self.waiting:
            self._deadline.cancel()
            if self.next_t == self.T - 1 and not self.reported:
                # the trial's last deliveries are out (as in lockstep, before sample T)
                self._trial_done()

    def _on_deadline(self) -> None:
        self._deliver_waiting(force=True)

    def _trial_done(self) -> None:
        self.reported = True
        d: dict[str, Any] = {"node": NAME, "trial": self.iteration, "slot": self.k,
                             "injected": {link: {str(t): c for t, c in sorted(h.items())}
                                          for link, h in self.injected.items()}}
        if self.realtime:
            d["late"] = dict(self.late)
        if self.cfg.scenario.uncertainty.link_loss > 0:
            d["lost"] = dict(self.lost)
        d.update(self.drops.as_dict())
        self.diag_pub.publish(ms.json_to_msg(d))
        self.ready_pub.publish(self.ready_msg(self.iteration + 1))


def main(args: list[str] | None = None) -> int:
    return spin_main(lambda ns, argv: [LinkEmulator()],
                     node_parser("formation-ilc-links", __doc__), args)


if __name__ == "__main__":
    sys.exit(main())
