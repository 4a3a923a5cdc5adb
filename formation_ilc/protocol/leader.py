"""The virtual leader as a pure core: every decision of ``formation-ilc-virtual-leader``,
without ROS.

The node (``virtual_leader.node``) declares parameters, publishers, subscriptions and
timers, and makes one call into :class:`Leader` per event: a ready, a trial event on its
own topic, another formation's configuration, a sample of ``/clock`` (or its wall timer in
wall-clock trials), its start gate and watchdog timers. The core decides; it acts through
the node's :class:`LeaderIO` (publish a trial event, a reference sample or diagnostics,
log, drop, stop) and asks it what only DDS knows (which endpoints a start still waits for,
whether the events have a reader, how many writers the ``config`` topic has). Time is
injected: the core reads the monotonic clock and the wall clock it is given.

What it decides:

* **Readies** (``on_ready``): from the nodes it waits for, of this run, for a trial no later
  than the next one (the monitor and the recorder say ready once for the whole run); the
  schedule (``protocol.schedule.Schedule``) takes them, and a restarted node aborts the
  slot it left open. The last refusal of each node is kept, to be named while the start
  waits.
* **The start gate** (``maybe_start``): the next trial starts once every node is ready, the
  endpoints are matched, and (before the first trial) discovery has had ``FIRST_START_WAIT``
  to show another formation's leader; an abort is repeated every ``ABORT_REPEAT`` until
  every node has answered it; after the last trial ``done``.
* **Samples** (``on_clock``, ``on_wall_timer``): the reference of each sample of the trial it
  started, in order (lockstep: sample by sample; a sample the plant sent again gets its
  reference again), and the trial's ``end`` at sample T.
* **Repeats** (``start_again``): while a slot has had no new sample for ``RESEND_S / 2`` its
  start goes out again, unchanged (``protocol.schedule.StartRepeat``).
* **Liveness** (``on_watchdog``): past a phase's bound it names whom it waits for, then
  re-runs (aborts a stuck slot, reads the readies anew), and after the watchdog's retries
  stops with status ``STUCK`` (``protocol.watchdog``).
* **Another formation** (``on_config``, ``on_event``): a second formation's configuration
  before trial 0 stops it (status 2); a start or abort of this run it did not send makes it
  re-assert its schedule.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

from formation_ilc.config.runconfig import RunConfig, disagreement
from formation_ilc.core.clock import Rejected, WallGrid
from formation_ilc.core.names import CONFIG, LEADER_NODE, TRIAL_EVENTS, robot_name
from formation_ilc.protocol.plant import RESEND_S
from formation_ilc.protocol.schedule import (
    ABORT,
    DONE,
    END,
    START,
    Ready,
    Schedule,
    ScheduleError,
    StartRepeat,
    TrialEvent,
    seal,
    sealed,
)
from formation_ilc.protocol.wallclock import WallSchedule
from formation_ilc.protocol.watchdog import READY as READY_PHASE
from formation_ilc.protocol.watchdog import SAMPLE, STARTUP, STUCK, Bounds, Watchdog

__all__ = ["Leader", "LeaderIO", "ABORT_REPEAT", "FIRST_START_WAIT", "NAME"]

#: [s] how often an abort is repeated until every node has answered it
ABORT_REPEAT = 1.0
#: [s] the least time between the leader's start and the first trial (discovery)
FIRST_START_WAIT = 2.0
#: the leader's node name (its diagnostics name it)
NAME = LEADER_NODE


def _shown(value: Any) -> str:
    return str(value) if not isinstance(value, (dict, list)) else json.dumps(value)[:200]


class LeaderIO(Protocol):
    """What the leader's core asks of its node."""

    def publish_event(self, event: TrialEvent) -> None:
        """Publish a trial event on ``leader/trial_events``."""

    def publish_reference(self, t: int, stamp_ns: int) -> None:
        """Publish the reference r(t) stamped ``stamp_ns`` on ``leader/reference``."""

    def publish_diagnostics(self, report: dict[str, Any]) -> None:
        """Publish the leader's report (with the node's drop counts) on ``diagnostics``."""

    def log(self, level: str, text: str) -> None:
        """Log ``text`` at ``level`` ('info', 'warning', 'error')."""

    def alert(self, text: str) -> None:
        """A watchdog finding: log it as an error and say it on stderr."""

    def drop(self, reason: str, topic: str, why: str) -> None:
        """Count (and log the first few of) a message dropped for ``reason``."""

    def fail(self, text: str, code: int) -> None:
        """Stop the leader's process with exit status ``code``, ``text`` its last word."""

    def reread_readies(self) -> None:
        """Subscribe to ``ready`` anew, so that every node's latched ready comes again."""

    def start_gate(self) -> list[str]:
        """The endpoints a start still waits for, one phrase each (empty: all matched):
        the reference's readers, the events' readers (one per node waited for, and the
        leader's own), and in simulated time a writer of ``/clock``."""

    def events_read(self) -> bool:
        """Whether the trial events have a reader."""

    def config_writers(self) -> int:
        """How many writers the formation's ``config`` topic has."""


class Leader:
    """The leader of one run: its schedule, liveness and samples.

    cfg : the run configuration (the leader publishes it; in wall-clock trials its grid
        agrees each slot's start).
    expected : the nodes it waits for (``nodes_expected``: the roster's team).
    io : the node's side (:class:`LeaderIO`).
    state_file : where the schedule is kept (``leader.json``), or None; a leader restarted
        with one goes on from it (``restored`` says how), ValueError if it cannot.
    namespace : the formation's, for messages. watchdog_scale : every liveness bound times
        this. start_margin : [s] wall-clock trials: from the start event to sample 0.
    monotonic, wall_ns : the clocks (seconds; Unix epoch, nanoseconds).
    key : the run key its events are sealed with (``protocol.schedule.seal``), None: none.
    secure : the team runs under SROS2 (a longer start-up bound: ``Bounds.for_run``).
    """

    def __init__(self, cfg: RunConfig, expected: list[str], io: LeaderIO, *,
                 state_file: Path | None = None, namespace: str = "",
                 watchdog_scale: float = 1.0, start_margin: float = 1.0,
                 monotonic: Callable[[], float] = time.monotonic,
                 wall_ns: Callable[[], int] = time.time_ns, key: bytes | None = None,
                 secure: bool = False):
        sc = cfg.scenario
        self.cfg, self.io, self.namespace = cfg, io, namespace
        #: the run key every event is sealed with (``schedule.seal``; None: unsealed)
        self.key = key
        self.monotonic, self.wall_ns = monotonic, wall_ns
        self.clock = cfg.clock
        self.T = sc.samples
        self.trials = sc.trials
        self.expected = list(expected)
        robots = {robot_name(i + 1) for i in range(sc.n)}
        self.sched = Schedule(self.expected, robots & set(self.expected), self.trials)
        self.state_file = state_file
        #: how the leader went on from its state file (None: a new run)
        self.restored: str | None = None
        if state_file is not None and self._restore():
            self.restored = (
                f"continues from {state_file}: {self.sched.committed} trials learned"
                + (f"; slot {self.sched.slot} was open and is aborted"
                   if self.sched.abort_pending is not None else ""))
        #: the last ready refused from each node, with why (named when the schedule waits)
        self.refused: dict[str, str] = {}
        #: what a node not yet ready last said it waits for (its unmatched endpoints)
        self.waiting: dict[str, str] = {}
        self.watch_reports = 0
        self.watchdog = Watchdog(Bounds.for_run(sc.dt, len(self.expected), cfg.mode,
                                               cfg.timeout, watchdog_scale, secure))
        self.margin_ns = int(start_margin * 1e9)
        self.done_sent = False
        self._abort_sent = 0.0
        self.born = monotonic()
        self.t = -1          # last sample of the running slot whose reference went out
        self.last_t: int | None = None  # the last sample seen (for the log)
        #: simulated time: the running slot's start again while it does not move, for a
        #: follower whose reader matched after it went out; sooner than the plant re-sends
        #: a sample, so that the follower has the start when the sample comes again
        self.repeat = StartRepeat(RESEND_S / 2)
        self.wall: WallSchedule | None = None
        #: wall-clock trials: reference samples the timer fell behind past (never sent late)
        self.missed_references = 0
        self.last_change = self.born
        self.watchdog.moved(self.last_change, STARTUP)

    @property
    def run_id(self) -> str:
        return self.cfg.run_id

    # ------------------------------------------------------------------ readies, events
    def on_ready(self, data: dict[str, Any]) -> None:
        """A ready (its JSON); Rejected (the node counts it) for one it does not take."""
        r = None
        try:
            r = Ready.from_json(data)
            if r.node not in self.expected:
                raise Rejected("unexpected", f"ready from {r.node[:100]}, not waited for")
            if r.run and r.run != self.run_id:
                raise Rejected("foreign", f"{r.node} of run {r.run}")
            # nobody can be ready for a trial after the next one (trial k+1 needs trial k);
            # the monitor and the recorder say ready once for the whole run
            if r.trial > self.sched.committed + 1 and not r.passive:
                raise Rejected("future", f"{r.node} ready for trial {r.trial}, but the "
                                         f"schedule has {self.sched.committed} trials learned")
            if r.config is not None:
                self.check_agreement(r.node, r.config)
        except Rejected as exc:
            if r is not None and r.node in self.expected and exc.reason != "foreign":
                self.refused[r.node] = f"{exc.reason}: {exc}"
            raise
        self.refused.pop(r.node, None)
        self.waiting.pop(r.node, None)
        committed = self.sched.committed
        first = r.node not in self.sched.ready
        why = self.sched.on_ready(r)
        why = self.sched.seen_unsent(r) or why
        self.last_change = self.monotonic()
        if self.sched.committed > committed:
            self.watchdog.moved(self.last_change, READY_PHASE)
        elif first and self.watchdog.first_startup:
            # a node's first ready before any trial: the team's start-up moves on
            self.watchdog.moved(self.last_change, STARTUP)
        if why is not None:
            self.aborted(why)
        self._save()
        self.maybe_start()

    def on_waiting(self, report: dict[str, Any]) -> None:
        """A node's diagnostics report: keep what an expected node that has not said ready
        waits for (its ``waiting``: unmatched endpoints, one phrase each), for the watchdog
        to name; anything else is not the leader's business."""
        name, waits = report.get("node"), report.get("waiting")
        if (not isinstance(name, str) or name not in self.expected
                or not isinstance(waits, list) or name in self.sched.ready):
            return
        text = "; ".join(str(w) for w in waits[:8])
        self.waiting[name] = text[:600] + (f" and {len(waits) - 8} more" if len(waits) > 8
                                           else "")

    def check_agreement(self, node: str, config: dict[str, Any]) -> None:
        """A node that configured itself from its own parameters runs ``config``
        (``RunConfig.agreement``): where it differs from the leader's, the leader names
        both values and stops (status 2; it adopts neither: a team of two configurations
        would run trials that neither describes). Rejected after the stop."""
        diff = disagreement(self.cfg.agreement(), config)
        if not diff:
            return
        said = "; ".join(f"{k}: {node} runs {_shown(theirs)}, {NAME} {_shown(mine)}"
                         for k, mine, theirs in diff)
        self.io.fail(f"the nodes' configurations disagree: {said}. {NAME} stops: start "
                     f"every node from the same parameters, or start {node} without a "
                     f"scenario so that it takes the leader's configuration", 2)
        raise Rejected("unexpected", f"{node} runs another configuration")

    def aborted(self, why: str) -> None:
        """An abort is pending (just begun): say so, save it, then publish it (saved first:
        a leader killed in between must not come back with a seq that followers passed)."""
        self.wall = None
        self.repeat.stop()
        s = self.sched
        self.io.log("warning", f"trial {s.committed} (slot {s.abort_pending}) aborted: "
                               f"{why}; it runs again")
        self._save()
        self._publish_abort()
        self.watchdog.moved(self.monotonic(), READY_PHASE, progress=False)

    def on_event(self, data: dict[str, Any]) -> None:
        """An event on the leader's own topic (its JSON): its own come back; a start or
        abort of this run that it did not send makes it re-assert its schedule. With a
        run key, one it did not seal moved no follower: it is only counted."""
        try:
            ev = TrialEvent.from_json(data)
        except Rejected:
            return  # followers count it; the leader only watches for starts and aborts
        if ev.run and ev.run != self.run_id:
            return
        if not sealed(ev, self.key):
            if ev.event in (START, ABORT):
                self.sched.foreign_events += 1
                self.io.drop("foreign", TRIAL_EVENTS, f"a {ev.event} of slot {ev.slot} "
                                                      f"(seq {ev.seq}) not sealed by this "
                                                      f"leader: no follower takes it")
            return
        why = self.sched.foreign(ev)
        if why is not None:
            self.io.drop("unexpected", TRIAL_EVENTS, why)
            self.aborted(why)

    def on_config(self, data: dict[str, Any]) -> None:
        """A configuration on ``config`` (its JSON): another leader's is a second formation
        on this domain and namespace; refuse to start (before trial 0), else go on."""
        other = str(data.get("run_id", ""))
        if other == self.run_id:
            return
        if self.sched.slot < 0:
            self.io.fail(f"another formation (run {other or '?'}) publishes its configuration "
                         f"on {self.namespace}/{CONFIG} in this ROS domain: refusing to start "
                         f"a second one here (use another namespace or domain)", 2)
            return
        self.io.drop("foreign", CONFIG, f"configuration of run {other or '?'}")

    def _restore(self) -> bool:
        assert self.state_file is not None
        try:
            return self.sched.restore(self.state_file)
        except ScheduleError as exc:
            raise ValueError(f"{exc} (remove the file to start the run afresh, or restore it "
                             f"from a copy)") from None

    def _save(self) -> None:
        self.sched.save(self.state_file)

    def _publish_abort(self) -> None:
        s = self.sched
        assert s.abort_pending is not None
        self._abort_sent = self.monotonic()
        self._publish(TrialEvent(ABORT, s.committed, s.abort_pending, s.seq, why=s.why,
                                 run=self.run_id, kept=s.kept))

    def _publish(self, ev: TrialEvent) -> TrialEvent:
        """Publish ``ev`` sealed with the run key (``schedule.seal``); returns it sealed."""
        ev = seal(ev, self.key)
        self.io.publish_event(ev)
        return ev

    # ------------------------------------------------------------------ starts
    def maybe_start(self) -> None:
        """Start the next trial if everything it needs is there (the start gate); repeat a
        pending abort; say ``done`` after the last trial."""
        s = self.sched
        now = self.monotonic()
        if s.abort_pending is not None:
            if not s.abort_done():
                if now - self._abort_sent > ABORT_REPEAT and self.io.events_read():
                    self._publish_abort()  # a node that came back after it was sent
                return
            self._save()
        if s.done:
            if not self.done_sent:
                self.done_sent = True
                self._publish(TrialEvent(DONE, s.committed, s.slot + 1, s.seq,
                                         run=self.run_id))
                self.publish_diagnostics()
                self.io.log("info", f"done: {self.trials} trials")
            return
        why = s.undone()  # a robot undid a committed step on an abort not ours
        if why is not None:
            self.aborted(why)
            return
        try:
            nxt = s.next_start()
        except ScheduleError as exc:
            self.io.fail(str(exc), 3)
            return
        if nxt is None:
            return
        if s.slot < 0:
            # before the first trial: give discovery time to show another formation's
            # leader here (its configuration may not have reached us, its writer has)
            if now - self.born < FIRST_START_WAIT:
                return
            if self.io.config_writers() > 1:
                self.io.fail(f"another formation's leader publishes on {self.namespace}/"
                             f"{CONFIG} in this ROS domain: refusing to start a second one "
                             f"here (use another namespace or domain)", 2)
                return
        if self.io.start_gate():
            return
        i, q = nxt
        seq = s.started(q)
        self.t = -1
        self._save()
        self.watchdog.moved(self.monotonic(), SAMPLE, progress=False)
        wall_ns = None
        if self.cfg.mode == "wallclock":
            grid = self.clock
            assert isinstance(grid, WallGrid)  # the configuration's, in wallclock mode
            wall_ns = grid.start_for(q, self.wall_ns() + self.margin_ns)
            grid.agree(q, wall_ns)  # its stamps are wall time: start + t * dT
            self.wall = WallSchedule(wall_ns, self.clock.dt_ns, self.T)
        start = self._publish(TrialEvent(START, i, q, seq, self.clock.stamp_ns(q, 0), wall_ns,
                                         run=self.run_id))
        if wall_ns is None:  # simulated time: the plant's samples show that it moves
            self.repeat.sent(start, self.monotonic())

    def start_again(self) -> None:
        """Simulated time: the running slot's start once more while it has had no new
        sample for RESEND_S / 2 (``protocol.schedule.StartRepeat``)."""
        if not self.sched.running:
            self.repeat.stop()
            return
        start = self.repeat.again(self.monotonic())
        if start is not None:
            self.io.publish_event(start)

    # ------------------------------------------------------------------ samples
    def on_wall_timer(self) -> None:
        """Wall-clock trials: r(t) for each sample due on the wall clock (the newest one if
        the timer fell behind; earlier ones are not sent late)."""
        if self.wall is None:
            return
        t = self.wall.due(self.wall_ns())
        if t is None:
            return
        k = self.sched.slot
        ns = self.clock.stamp_ns(k, t)
        self.last_t = t
        self.last_change = self.monotonic()
        self.watchdog.moved(self.last_change, SAMPLE)
        self.io.publish_reference(t, ns)
        if t == self.T:
            self.missed_references += self.wall.skipped
            self.wall = None
            self._end(k)

    def on_clock(self, ns: int) -> None:
        """Simulated time: the plant's ``/clock`` at ``ns``; Rejected (the node counts it)
        for a time that is not the running slot's next sample (a sample the plant sent again
        gets its reference again first, in lockstep)."""
        k, t = self.clock.decode(ns)
        if k != self.sched.slot or not self.sched.running:
            raise Rejected("stale" if k <= self.sched.slot else "future",
                           f"time of slot {k}, slot {self.sched.slot} "
                           f"{'runs' if self.sched.running else 'is over'}")
        if t == self.t:
            if self.cfg.mode == "lockstep" and t < self.T:
                # the plant sent the sample again (a command still due after RESEND_S):
                # the reference of it again too, for a reader that lost it
                self.io.publish_reference(t, ns)
            raise Rejected("duplicate", f"time of sample {t} again")
        if t < self.t:
            raise Rejected("out_of_order", f"sample {t} after {self.t}")
        if self.cfg.mode == "lockstep" and t > self.t + 1:
            raise Rejected("future", f"sample {t} while {self.t + 1} is due")
        self.t = t
        self.last_t = t
        self.last_change = self.monotonic()
        self.watchdog.moved(self.last_change, SAMPLE)
        self.repeat.moved(self.last_change)
        self.io.publish_reference(t, ns)
        if t == self.T:
            self._end(k)

    def _end(self, slot: int) -> None:
        self.repeat.stop()
        s = self.sched
        self._publish(TrialEvent(END, s.committed, slot, s.seq, run=self.run_id))
        committed = s.committed
        s.ended(slot)
        self.watchdog.moved(self.monotonic(), READY_PHASE, progress=s.committed > committed)
        self._save()
        self.publish_diagnostics()
        self.maybe_start()

    # ------------------------------------------------------------------ liveness
    def start_waits_for(self) -> list[str]:
        """Whom the next start waits for, one phrase each: the nodes not ready (or not
        answering an abort), else the endpoints of the start gate not yet matched."""
        late = self.sched.explain_wait(self.refused, self.waiting)
        return late or self.io.start_gate()

    def phase(self) -> str:
        s = self.sched
        if s.running:
            # until the plant's first sample of a slot it is starting the trial, which
            # may load its kernels first (measured: 76 s under a load of 33 on 2 cores)
            return SAMPLE if self.t >= 0 else STARTUP
        return STARTUP if s.slot < 0 and s.abort_pending is None else READY_PHASE

    def on_watchdog(self) -> None:
        """Past a phase's bound: say whom the run waits for and why, then re-run (abort a
        stuck slot; read the readies anew), or, after RETRIES times without progress,
        stop the leader (status STUCK) naming the cause."""
        s = self.sched
        if s.done:
            return
        now = self.monotonic()
        phase = self.phase()
        if not self.watchdog.expired(now, phase):
            return
        wd = self.watchdog
        bound = wd.expired_bound
        waited = wd.waited(now)
        if phase == SAMPLE:
            who = ("the plant's /clock" if self.cfg.mode != "wallclock"
                   else "the leader's wall timer")
            what = (f"trial {s.committed} (slot {s.slot}) has had no new sample for "
                    f"{bound:.0f} s (last sample {self.t}; no progress for {waited:.0f} s): "
                    f"waiting for {who}")
        else:
            late = self.start_waits_for()
            if s.running:
                late = [f"the plant's first sample of slot {s.slot}"]
            bounds = (f"bound {wd.full_bound(phase):.0f} s, then {bound:.0f} s after "
                      f"reading the readies anew" if wd.first_startup and wd.strikes > 1
                      else f"bound {bound:.0f} s")
            what = (f"trial {s.committed} has waited {waited:.0f} s in {phase} ({bounds}) "
                    f"for: "
                    + "; ".join(late or ["nobody (its readers: the monitor, recorder)"]))
        if wd.gave_up:
            self._report(what, "giving up")
            tried = ("the readies read anew once" if wd.first_startup
                     else f"{wd.retries} retries")
            self.io.fail(f"stuck: {what} ({tried} without progress)", STUCK)
            return
        if not wd.acting:
            self._report(what, f"retries follow after {bound:.0f} s more")
            return
        if wd.first_startup:
            self._report(what, f"reading the readies anew; giving up in "
                               f"{wd.bound(phase):.0f} s if nothing moves")
        else:
            self._report(what, f"retry {wd.strikes - 1} of {wd.retries}")
        if s.running:
            s.begin_abort(f"no progress for {bound:.0f} s")
            self.aborted(s.why)
            return
        # read every node's latched ready again, and repeat a pending abort
        self.io.reread_readies()
        if s.abort_pending is not None:
            self._publish_abort()

    def _report(self, what: str, then: str) -> None:
        """A watchdog finding: in the log, on stderr, and in the leader's diagnostics (the
        launcher prints it on its console)."""
        self.io.alert(f"{what}: {then}")
        self.watch_reports += 1
        self.publish_diagnostics({"count": self.watch_reports, "what": f"{what}: {then}"})

    def report_wait(self) -> None:
        """Say whom the schedule waits for when it has not moved for a while."""
        s = self.sched
        if self.monotonic() - self.last_change < 5.0 or s.done:
            return
        if s.running:
            self.io.log("warning", f"trial {s.committed} (slot {s.slot}) has not ended "
                                   f"(last clock: {self.last_t})")
            return
        late = s.waiting_for()
        what = "the abort's answer" if s.abort_pending is not None else "ready"
        if late:
            self.io.log("warning", f"trial {s.committed} waits for {what} from "
                                   f"{', '.join(late)}")
            return
        gate = "; ".join(self.io.start_gate()) or "readers"
        self.io.log("warning", f"trial {s.committed}: waiting for {gate}")

    def publish_diagnostics(self, watchdog: dict[str, Any] | None = None) -> None:
        """The leader's report: its trial and slot, foreign events, repeated starts, and a
        watchdog finding."""
        d: dict[str, Any] = {"node": NAME, "trial": self.sched.committed,
                             "slot": self.sched.slot,
                             "foreign_events": self.sched.foreign_events,
                             "starts_repeated": self.repeat.count}
        if self.cfg.mode == "wallclock":
            d["missed_references"] = self.missed_references
        if watchdog is not None:
            d["watchdog"] = watchdog
        self.io.publish_diagnostics(d)
