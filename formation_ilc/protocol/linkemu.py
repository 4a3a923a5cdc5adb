"""The emulated robot-to-robot links, free of ROS: poses in, one delivery per link and tick out.

The link emulator node (``robot_sim.link_emulator``) is a thin ROS wrapper around
``EmulatedLinks``: it decodes each shared pose, reference and ``/clock`` message into its
label, calls one method per event and publishes the link ticks that come back. Everything
that decides what the links deliver lives here:

* at tick t, on each link of robot i (an in-neighbour j, and the leader if robot i sees it),
  the pose labelled ``delivered_label(t, tau)``, tau being the delay stream of the trial's
  iteration as the batch simulator draws it; no pose while that label is negative, or when
  the link loses the sample (``delay: loss``);
* lockstep: robot i's deliveries of tick t go out as soon as the poses they need are in
  (with delays, often before the plant has even published sample t) and robot i's own
  sample t-1 pose is (it is at sample t-1 at least: its lookahead); tick t+1 opens once
  every robot's tick t is out. No robot waits for a pose it is not delivered;
* realtime: the tick is ``/clock``; robot i's deliveries of tick t go out as soon as the poses
  they need are in, and at the latest at the deadline (``deadline()``), without those still
  missing (counted ``late``);
* the trial window: labels of the current slot only (lockstep: each sample once, at most the
  one being collected); labels of the next slot, once this one is delivered, are held
  (at most one trial's worth) until its start and replayed then; the leader's start and
  abort are taken by ``schedule.Follower``.

Poses are carried as opaque payloads (``P``: the node's message, sent on as it came, its
label included); the core only reads their labels.

Each event returns an ``Emitted``: the link ticks to publish, in order; ``done`` when the
trial's last deliveries are out (the node then reports ``report()`` and says ready);
``arm`` when a realtime tick began (the node starts its delivery deadline, and stops it
whenever ``waiting`` is empty); and the held inputs a start replayed and refused.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

import numpy as np

from formation_ilc.config.runconfig import RunConfig
from formation_ilc.core.clock import Rejected
from formation_ilc.core.links import LEADER, LOST, delivered_label, link_name, robot_name
from formation_ilc.model.simulate import Problem
from formation_ilc.protocol.schedule import ABORT, Follower, TrialEvent

__all__ = ["SHARED", "REFERENCE", "CLOCK", "Emitted", "EmulatedLinks"]

P = TypeVar("P")

#: kinds of input (with a robot index j for SHARED, -1 otherwise)
SHARED, REFERENCE, CLOCK = "shared", "reference", "clock"


@dataclass
class Emitted(Generic[P]):
    """What an event makes the emulator send.

    ticks : (receiver i (0-based), link m (index into ``links[i]``), tick label [ns], the
        pose delivered or None), in publishing order.
    done : the trial's last deliveries are out.
    arm : realtime: a tick began; its delivery deadline starts now.
    refused : held inputs a start replayed and refused: (kind, j, why).
    """

    ticks: list[tuple[int, int, int, P | None]] = field(default_factory=list)
    done: bool = False
    arm: bool = False
    refused: list[tuple[str, int, Rejected]] = field(default_factory=list)


class EmulatedLinks(Generic[P]):
    """The links of run configuration ``cfg`` (lockstep or realtime, emulated links)."""

    def __init__(self, cfg: RunConfig):
        sc = cfg.scenario
        self.cfg, self.clock = cfg, cfg.clock
        self.pb = pb = Problem.from_scenario(sc)
        self.follower = Follower(cfg.run_id, clock=cfg.clock)
        self.realtime = cfg.mode == "realtime"
        n, n_t = pb.n, pb.samples
        self.n, self.T = n, n_t
        #: per receiver: (sender, link slot ell or -1 for the leader)
        self.links: list[list[tuple[str, int]]] = []
        self.injected: dict[str, Counter[int]] = {}
        for i in range(n):
            links = [(robot_name(int(j) + 1), ell) for ell, j in enumerate(pb.src[i]) if j >= 0]
            if pb.leader[i] != 0.0:
                links.append((LEADER, -1))
            self.links.append(links)
            for s, _ in links:
                self.injected[link_name(s, robot_name(i + 1))] = Counter()
        self.late = {link: 0 for link in self.injected}
        self.lost = {link: 0 for link in self.injected}  # samples the links lost (loss)
        self.active = False    # a trial has started and was not aborted
        self.reported = False  # its last deliveries are out
        # inputs of a slot whose start event has not come yet: (slot, kind, j, label, pose)
        self.early: list[tuple[int, str, int, int, P | None]] = []
        self.early_max = (n + 2) * (n_t + 1)
        self.clock_t = -1
        self.next_t = 0
        self.waiting: dict[int, int] = {}  # realtime: receiver -> tick it still waits for
        self.tau = np.zeros((n, pb.src.shape[1], n_t), dtype=np.int64)
        self.tau0 = np.zeros((n, n_t), dtype=np.int64)
        self.shared: list[list[P | None]] = [[None] * (n_t + 1) for _ in range(n)]
        self.ref: list[P | None] = [None] * (n_t + 1)
        self.count = np.zeros(n_t + 1, dtype=np.int64)
        self.sent = np.zeros((n, n_t), dtype=bool)  # robot i's deliveries of tick t went out
        self.unsent = 0  # realtime: (robot, tick) never sent, its /clock unheard (late)

    @property
    def k(self) -> int:
        """Slot of the current (or last) trial."""
        return self.follower.slot

    @property
    def iteration(self) -> int:
        return self.follower.trial

    # ------------------------------------------------------------------ the schedule
    def on_event(self, ev: TrialEvent) -> tuple[TrialEvent | None, Emitted[P]]:
        """The leader's event: the start or abort taken (None: nothing to do) and what it
        sends (a start replays the inputs held for its slot). Rejected for a start the
        emulator must not obey (``schedule.Follower``)."""
        out: Emitted[P] = Emitted()
        taken = self.follower.take(ev, idle=not self.active or self.reported)
        if taken is None:
            return None, out
        if taken.event == ABORT:
            if taken.slot == self.k:
                self.active = False
                self.waiting = {}
            self.early = [e for e in self.early if e[0] > taken.slot]
            return taken, out
        self.begin()
        early, self.early = self.early, []
        for slot, kind, j, ns, pose in early:
            if slot == taken.slot:
                try:
                    self._input(kind, j, ns, pose, out)
                except Rejected as exc:
                    out.refused.append((kind, j, exc))
            elif slot > taken.slot:
                self.early.append((slot, kind, j, ns, pose))
        return taken, out

    def begin(self) -> None:
        """The trial of the slot just started (``follower``): its delay stream, as the batch
        simulator draws it, and nothing delivered yet."""
        pb, sc = self.pb, self.cfg.scenario
        self.active = True
        self.clock_t = -1
        self.tau, self.tau0 = sc.uncertainty.draw_delays(sc.seed, self.iteration, pb.n,
                                                         pb.src.shape[1], pb.samples)
        self.shared = [[None] * (self.T + 1) for _ in range(self.n)]
        self.ref = [None] * (self.T + 1)
        self.count = np.zeros(self.T + 1, dtype=np.int64)
        self.sent = np.zeros((self.n, self.T), dtype=bool)
        self.next_t = 0
        # realtime: /clock arms each tick; lockstep: tick 0 is open for every robot
        self.waiting = {} if self.realtime else dict.fromkeys(range(self.n), 0)
        self.reported = False

    def said_ready(self) -> None:
        self.follower.said_ready()

    # ------------------------------------------------------------------ inputs
    def on_shared(self, j: int, label_ns: int, pose: P) -> Emitted[P]:
        """Robot ``j``'s (0-based) shared pose labelled ``label_ns``. Rejected: off the
        trial window (stale, future), a sample again (duplicate), lockstep a sample ahead
        of the one being collected (future)."""
        out: Emitted[P] = Emitted()
        self._input(SHARED, j, label_ns, pose, out)
        return out

    def on_reference(self, label_ns: int, pose: P) -> Emitted[P]:
        """The leader's reference labelled ``label_ns`` (Rejected as ``on_shared``)."""
        out: Emitted[P] = Emitted()
        self._input(REFERENCE, -1, label_ns, pose, out)
        return out

    def on_clock(self, label_ns: int) -> Emitted[P]:
        """Realtime: ``/clock`` says tick ``label_ns``. Rejected: off the trial window,
        the same tick again (duplicate) or an earlier one (out_of_order)."""
        out: Emitted[P] = Emitted()
        self._input(CLOCK, -1, label_ns, None, out)
        return out

    def _input(self, kind: str, j: int, ns: int, pose: P | None, out: Emitted[P]) -> None:
        s = self._sample_of(kind, j, ns, pose)
        if s is None:
            return
        if kind == CLOCK:
            self._tick(s, out)
            return
        box = self.ref if kind == REFERENCE else self.shared[j]
        if box[s] is not None:  # (lockstep: every pose before the open tick's is in)
            raise Rejected("duplicate", f"sample {s} again")
        box[s] = pose
        if kind == SHARED:
            self.count[s] += 1
        self._deliver_waiting(False, out) if self.realtime else self._deliver(out)

    def _sample_of(self, kind: str, j: int, ns: int, pose: P | None) -> int | None:
        """Sample of a label of the current trial; a later slot's is held until its start
        event (bounded): None. Rejected otherwise."""
        k, s = self.clock.decode(ns)
        # the next slot opens once this one is delivered (or aborted): before that no
        # real message of it can exist
        if k > self.k + 1 or (k == self.k + 1 and self.active and not self.reported):
            raise Rejected("future", f"label of slot {k} in slot {self.k}")
        if k > self.k:
            if len(self.early) >= self.early_max:
                raise Rejected("future", f"label of slot {k} before its start; "
                                         f"{len(self.early)} messages held already")
            self.early.append((k, kind, j, ns, pose))
            return None
        if k < self.k or not self.active:
            raise Rejected("stale", f"label of slot {k} in slot {self.k}"
                                    f"{'' if self.active else ' (over)'}")
        if not self.realtime and kind != CLOCK and s > self.next_t:
            raise Rejected("future", f"sample {s} while {self.next_t} is due")
        return s

    # ------------------------------------------------------------------ deliveries
    def _send(self, i: int, t: int, force: bool, out: Emitted[P]) -> bool:
        """Robot i's deliveries of tick t, if every due pose is in (``force``: regardless,
        the missing ones counted late). Returns whether they were sent."""
        needs = []
        for sender, ell in self.links[i]:
            tau = int(self.tau[i, ell, t] if ell >= 0 else self.tau0[i, t])
            s = delivered_label(t, tau)
            due = s >= 0
            src = self.ref if ell < 0 else self.shared[int(self.pb.src[i, ell])]
            needs.append((sender, src[s] if due else None, tau, due))
        if not force and any(due and m is None for _, m, _, due in needs):
            return False
        tick = self.clock.stamp_ns(self.k, t)
        to = robot_name(i + 1)
        self.sent[i, t] = True
        for m_idx, (sender, m, tau, due) in enumerate(needs):
            if tau >= LOST:
                self.lost[link_name(sender, to)] += 1
            elif due and m is None:
                self.late[link_name(sender, to)] += 1
            elif due:
                self.injected[link_name(sender, to)][tau] += 1
            out.ticks.append((i, m_idx, tick, m))
        return True

    def _deliver(self, out: Emitted[P]) -> None:
        """Lockstep: each robot's deliveries of the open tick whose poses are in (and whose
        robot is at the sample before it); the next tick once every robot's are out."""
        while self.waiting:
            t = self.next_t
            for i in list(self.waiting):
                if (t == 0 or self.shared[i][t - 1] is not None) and \
                        self._send(i, t, False, out):
                    del self.waiting[i]
            if self.waiting:
                return
            self.next_t = t + 1
            if self.next_t == self.T:
                self._done(out)
                return
            self.waiting = dict.fromkeys(range(self.n), self.next_t)

    def _tick(self, t: int, out: Emitted[P]) -> None:
        if t <= self.clock_t:
            raise Rejected("duplicate" if t == self.clock_t else "out_of_order",
                           f"tick {t} after {self.clock_t}")
        self.clock_t = t
        if self.waiting:  # the previous tick's deadline has not fired: it is over now
            self._deliver_waiting(True, out)
        if t >= self.T:
            return
        self.next_t = t
        self.waiting = {i: t for i in range(self.n)}
        out.arm = True
        self._deliver_waiting(False, out)

    def _deliver_waiting(self, force: bool, out: Emitted[P]) -> None:
        for i, t in list(self.waiting.items()):
            if self._send(i, t, force, out):
                del self.waiting[i]
        if not self.waiting and self.next_t == self.T - 1 and not self.reported:
            # the trial's last deliveries are out (as in lockstep, before sample T)
            self._done(out)

    def deadline(self) -> Emitted[P]:
        """Realtime: the delivery deadline of the current tick: what is still waiting goes
        out without the poses missing."""
        out: Emitted[P] = Emitted()
        self._deliver_waiting(True, out)
        return out

    def _done(self, out: Emitted[P]) -> None:
        if self.realtime:
            self._count_unsent()
        self.reported = True
        out.done = True

    def _count_unsent(self) -> None:
        """Realtime: a tick whose ``/clock`` never reached the emulator (a starved process,
        a lost message) sent nothing: its due deliveries are late, not lost from the count."""
        for i, t in zip(*np.nonzero(~self.sent), strict=True):
            self.unsent += 1
            to = robot_name(int(i) + 1)
            for sender, ell in self.links[i]:
                tau = int(self.tau[i, ell, t] if ell >= 0 else self.tau0[i, t])
                if tau >= LOST:
                    self.lost[link_name(sender, to)] += 1
                elif delivered_label(int(t), tau) >= 0:
                    self.late[link_name(sender, to)] += 1

    def report(self) -> dict[str, Any]:
        """The trial's diagnostics: trial, slot, the delays injected per link (histogram),
        realtime the deliveries late per link, with loss the samples lost per link."""
        d: dict[str, Any] = {"trial": self.iteration, "slot": self.k,
                             "injected": {link: {str(t): c for t, c in sorted(h.items())}
                                          for link, h in self.injected.items()}}
        if self.realtime:
            d["late"] = dict(self.late)
            d["ticks_unheard"] = self.unsent
        if self.cfg.scenario.uncertainty.link_loss > 0:
            d["lost"] = dict(self.lost)
        return d
