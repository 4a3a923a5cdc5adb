"""Virtual leader (``formation-ilc-leader``): the reference r(t), the trial schedule, the
run configuration.

Parameters
----------
scenario : str (required)
    Scenario name or YAML file.
seed : int, trials : int, law : int, memory : str
    Overrides (-1 / 0 / "" keep the scenario's).
noise, delay : bool
    As ``--no-noise`` / ``--no-delay`` of ``formation-ilc simulate`` when false.
mode : str
    'lockstep', 'realtime' or 'wallclock'.
start_margin : float
    wallclock: [s] from the ``start`` event to the agreed start time (default 1.0): long
    enough for the event to reach every node.
links : str
    'emulated' (the link emulator carries the scenario's delays) or 'direct' (the robots
    subscribe to each other; the network's delays).
nodes_expected : list of node names that must report ready before a trial starts
    (default: every robot_i, robot_sim, and link_emulator with emulated links; in
    wallclock every robot_i and bridge_i: ``formation_ilc.config.team``).
monitored : bool
    A monitor (the launcher) reads trajectories: nodes wait for it before trial 0.
state_dir : str
    Where the leader keeps its schedule (``leader.json``, written atomically at each
    change). A leader restarted with the same parameters aborts the trial it left open and
    goes on from the last one every robot learned. Empty: no state file.
run_id : str
    Identity of the run, carried in the configuration: nodes of another run on the same
    domain and namespace are refused (see ``formation-ilc launch``).
watchdog_scale : float
    Every bound of the leader's watchdog times this (default 1.0; see below).

The leader publishes the configuration on ``config`` (latched), waits until every node has
reported ready for trial k, publishes ``start`` k on ``leader/trial_events``, then follows
``/clock``: at each sample t of the trial it broadcasts r(t) on ``leader/reference`` (in the
world frame, stamped with the sample's label), and at t = T ``end`` k. Its readers are the
robots that see it, or with emulated links the link emulator; in lockstep with direct
links no robot reads it (``RunConfig.leader_in_step``), only the recorder and viewers.
While a slot has had no new sample for half of ``protocol.plant.RESEND_S`` (simulated
time) it sends the slot's start again, unchanged, for a follower whose reader matched
after the start went out (``protocol.schedule.StartRepeat``). After the last trial it
publishes ``done``. When a node restarts during a trial, the leader aborts that trial and runs it
again in the next slot of the label grid (``formation_ilc.protocol.schedule``: the
protocol, slots and aborts).

What it accepts (the rest is dropped and counted, with the reason, in its own
``diagnostics`` at each trial's end): ready messages from the nodes it waits for, for a
trial no later than the next one (the monitor and the recorder say ready once for the whole
run); ``/clock`` of the trial it started, in order (lockstep: sample by sample).

Liveness (``formation_ilc.protocol.watchdog``): each phase (start-up, readies between
trials, the plant's samples) has a bound derived from dT, the number of nodes and the
lockstep ``timeout``. Past it the leader names whom it waits for and why (log, stderr, and
its diagnostics, which the launcher prints); past it again it re-runs (aborts a slot
without samples, reads the readies anew); after 3 re-runs without progress it stops with
status 4. A start or abort on its topic that it did not send, or a ready that saw a ``seq``
it never gave out, makes it re-assert its schedule with a newer ``seq`` (the slot is
aborted and its iteration runs again).

Wall-clock trials (``mode: wallclock``, real robots behind bridges; no node publishes
``/clock``): the ``start`` event carries ``start_wall_ns``, the wall time (Unix epoch, ns)
``start_margin`` seconds ahead at which sample 0 is due; the leader publishes r(t) from its
own wall timer at start_wall_ns + t * dT, stamped with that time (``core.clock.WallGrid``:
the start's remainder by dT is the slot, so every stamp names its slot and sample), and
every plant samples its robot at the same instants (the machines' clocks synchronised,
e.g. chrony).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from std_msgs.msg import String

import msgs_schema as ms
from formation_ilc.config import params
from formation_ilc.config.runconfig import PARAMS, RunConfig
from formation_ilc.config.team import Team, default_plant
from formation_ilc.core.clock import Rejected, WallGrid
from formation_ilc.core.names import LEADER_NODE
from formation_ilc.nodes.common import (
    DropCounter,
    fail,
    matched,
    node_parser,
    spin_main,
    unmatched,
)
from formation_ilc.nodes.params import declare
from formation_ilc.protocol.plant import RESEND_S
from formation_ilc.protocol.schedule import (
    Ready,
    Schedule,
    ScheduleError,
    StartRepeat,
    TrialEvent,
)
from formation_ilc.protocol.wallclock import WallSchedule
from formation_ilc.protocol.watchdog import READY, SAMPLE, STARTUP, STUCK, Bounds, Watchdog

#: [s] how often an abort is repeated until every node has answered it
ABORT_REPEAT = 1.0
#: [s] the least time between the leader's start and the first trial (discovery)
FIRST_START_WAIT = 2.0
#: the leader's node name (its diagnostics name it)
NAME = LEADER_NODE


class LeaderNode(Node):
    def __init__(self, **kwargs: Any):
        kwargs.setdefault("namespace", ms.NAMESPACE)
        super().__init__(NAME, **kwargs)
        declare(self, params.LEADER)  # the run configuration's (runconfig) and the leader's
        g = lambda name: self.get_parameter(name).value  # noqa: E731
        _check_parameters(g)
        self.cfg = RunConfig.from_params({name: g(name) for name in PARAMS})
        sc = self.cfg.scenario
        self.clock = self.cfg.clock
        self.T = sc.samples
        self.trials = sc.trials
        expected = [str(e) for e in g("nodes_expected") if e]
        self.expected = expected if expected else Team.of(
            sc.n, plant=default_plant(self.cfg.mode), links=self.cfg.links).expected
        # who reads the reference: the link emulator, or each robot that sees the leader
        # (none in lockstep with direct links: RunConfig.leader_in_step)
        self.ref_readers = (1 if self.cfg.links == "emulated"
                            else 0 if self.cfg.leader_in_step
                            else int(sum(sc.graph.leader > 0)))
        robots = {ms.robot_name(i + 1) for i in range(sc.n)}
        self.sched = Schedule(self.expected, robots & set(self.expected), self.trials)
        sdir = str(g("state_dir"))
        self.state_file = Path(sdir) / "leader.json" if sdir else None
        if self.state_file is not None and self._restore():
            self.get_logger().info(
                f"continues from {self.state_file}: {self.sched.committed} trials learned"
                + (f"; slot {self.sched.slot} was open and is aborted"
                   if self.sched.abort_pending is not None else ""))
        self.drops = DropCounter(self)
        #: the last ready refused from each node, with why (named when the schedule waits)
        self.refused: dict[str, str] = {}
        #: what a node not yet ready last said it waits for (its unmatched endpoints)
        self.waiting: dict[str, str] = {}
        self.watch_reports = 0
        self.watchdog = Watchdog(Bounds.for_run(sc.dt, len(self.expected), self.cfg.mode,
                                               self.cfg.timeout,
                                               float(g("watchdog_scale"))))
        self.done_sent = False
        self._abort_sent = 0.0
        self._born = time.monotonic()
        self.t = -1          # last sample of the running slot whose reference went out
        #: simulated time: the running slot's start again while it does not move, for a
        #: follower whose reader matched after it went out; sooner than the plant re-sends
        #: a sample, so that the follower has the start when the sample comes again
        self.repeat = StartRepeat(RESEND_S / 2)
        self.ref_msg = PoseStamped()
        self.config_pub = self.create_publisher(String, ms.CONFIG, ms.LATCHED_QOS)
        self.ref_pub = self.create_publisher(PoseStamped, ms.REFERENCE, ms.SAMPLE_QOS)
        self.event_pub = self.create_publisher(String, ms.TRIAL_EVENTS, ms.SAMPLE_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, ms.DIAGNOSTICS, ms.LATCHED_QOS)
        self.ready_sub = self.create_subscription(String, ms.READY, self._on_ready,
                                                  ms.LATCHED_READER_QOS)
        # its own events come back here too; a start or abort it did not send is re-asserted
        self.create_subscription(String, ms.TRIAL_EVENTS, self._on_event, ms.SAMPLE_QOS)
        # a second formation's latched configuration is what this reader is for: a depth
        # of 1 (shared by every writer of the keyless topic) let this leader's own config
        # replace it before it was taken, and the second formation ran
        self.create_subscription(String, ms.CONFIG, self._on_config, ms.LATCHED_READER_QOS)
        # a node not yet ready says what it waits for in its diagnostics: the watchdog
        # names it (discovery that does not complete shows as endpoints never matched)
        self.create_subscription(DiagnosticArray, ms.DIAGNOSTICS, self._on_diagnostics,
                                 ms.LATCHED_READER_QOS)
        self.wall: WallSchedule | None = None
        if self.cfg.mode == "wallclock":
            self.margin_ns = int(float(g("start_margin")) * 1e9)
            self._wall_timer = self.create_timer(0.005, self._on_wall_timer)
        else:
            self.clock_sub = self.create_subscription(Clock, ms.CLOCK, self._on_clock,
                                                      ms.CLOCK_QOS, raw=True)
            self.create_timer(RESEND_S / 8, self._start_again)
        self.config_pub.publish(ms.json_to_msg(self.cfg.to_json()))
        self._gate = self.create_timer(0.05, self._maybe_start)
        self._last_change = time.monotonic()
        self.watchdog.moved(self._last_change, STARTUP)
        self.create_timer(5.0, self._report_wait)
        self.create_timer(1.0, self._on_watchdog)
        self.get_logger().info(f"{sc.name}: {sc.n} robots, {self.trials} trials of "
                               f"{self.T} samples, {self.cfg.mode}, {self.cfg.links} links; "
                               f"waiting for "
                               f"{', '.join(self.expected)}")

    def _on_ready(self, msg: String) -> None:
        r = None
        try:
            r = Ready.from_json(ms.msg_to_json(msg))
            if r.node not in self.expected:
                raise Rejected("unexpected", f"ready from {r.node[:100]}, not waited for")
            if r.run and r.run != self.cfg.run_id:
                raise Rejected("foreign", f"{r.node} of run {r.run}")
            # nobody can be ready for a trial after the next one (trial k+1 needs trial k);
            # the monitor and the recorder say ready once for the whole run
            if r.trial > self.sched.committed + 1 and not r.passive:
                raise Rejected("future", f"{r.node} ready for trial {r.trial}, but the "
                                         f"schedule has {self.sched.committed} trials learned")
        except Rejected as exc:
            self.drops.reject(exc, ms.READY)
            if r is not None and r.node in self.expected and exc.reason != "foreign":
                self.refused[r.node] = f"{exc.reason}: {exc}"
            return
        self.refused.pop(r.node, None)
        self.waiting.pop(r.node, None)
        committed = self.sched.committed
        first = r.node not in self.sched.ready
        why = self.sched.on_ready(r)
        why = self.sched.seen_unsent(r) or why
        self._last_change = time.monotonic()
        if self.sched.committed > committed:
            self.watchdog.moved(self._last_change, READY)
        elif first and self.watchdog.first_startup:
            # a node's first ready before any trial: the team's start-up moves on
            self.watchdog.moved(self._last_change, STARTUP)
        if why is not None:
            self._aborted(why)
        self._save()
        self._maybe_start()

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        """Keep what an expected node that has not said ready waits for (``waiting`` in
        its report); anything else on the topic is not the leader's business."""
        try:
            d = ms.msg_to_report(msg, ("node",))
        except Rejected:
            return  # the monitor counts malformed diagnostics; nothing to do here
        name, waits = d.get("node"), d.get("waiting")
        if name not in self.expected or not isinstance(waits, list) or name in \
                self.sched.ready:
            return
        text = "; ".join(str(w) for w in waits[:8])
        self.waiting[name] = text[:600] + (f" and {len(waits) - 8} more" if len(waits) > 8
                                           else "")

    def _aborted(self, why: str) -> None:
        """An abort is pending (just begun): say so, save it, then publish it (saved first:
        a leader killed in between must not come back with a seq that followers passed)."""
        self.wall = None
        self.repeat.stop()
        s = self.sched
        self.get_logger().warning(f"trial {s.committed} (slot {s.abort_pending}) aborted: "
                                  f"{why}; it runs again")
        self._save()
        self._publish_abort()
        self.watchdog.moved(time.monotonic(), READY, progress=False)

    def _on_event(self, msg: String) -> None:
        """An event on the leader's own topic: its own come back; a start or abort of this
        run that it did not send makes it re-assert its schedule."""
        try:
            ev = TrialEvent.from_json(ms.msg_to_json(msg))
        except Rejected:
            return  # followers count it; the leader only watches for starts and aborts
        if ev.run and ev.run != self.cfg.run_id:
            return
        why = self.sched.foreign(ev)
        if why is not None:
            self.drops.drop("unexpected", ms.TRIAL_EVENTS, why)
            self._aborted(why)

    def _restore(self) -> bool:
        assert self.state_file is not None
        try:
            return self.sched.restore(self.state_file)
        except ScheduleError as exc:
            raise ValueError(f"{exc} (remove the file to start the run afresh, or restore it "
                             f"from a copy)") from None

    def _on_config(self, msg: String) -> None:
        """Another leader's configuration here: a second formation on this domain and
        namespace. Refuse to start (before trial 0); an established run goes on."""
        try:
            d = ms.msg_to_json(msg)
        except Rejected as exc:
            self.drops.reject(exc, ms.CONFIG)
            return
        other = str(d.get("run_id", ""))
        if other == self.cfg.run_id:
            return
        if self.sched.slot < 0:
            fail(self, f"another formation (run {other or '?'}) publishes its configuration "
                       f"on {self.get_namespace()}/{ms.CONFIG} in this ROS domain: refusing "
                       f"to start a second one here (use another namespace or domain)",
                 code=2)
            return
        self.drops.drop("foreign", ms.CONFIG, f"configuration of run {other or '?'}")

    def _save(self) -> None:
        self.sched.save(self.state_file)

    def _publish_abort(self) -> None:
        s = self.sched
        assert s.abort_pending is not None
        self._abort_sent = time.monotonic()
        self.event_pub.publish(ms.json_to_msg(TrialEvent(
            ms.ABORT, s.committed, s.abort_pending, s.seq, why=s.why,
            run=self.cfg.run_id).to_json()))

    def _maybe_start(self) -> None:
        s = self.sched
        if s.abort_pending is not None:
            if not s.abort_done():
                if time.monotonic() - self._abort_sent > ABORT_REPEAT and matched(
                        [(self.event_pub, 1)]):
                    self._publish_abort()  # a node that came back after it was sent
                return
            self._save()
        if s.done:
            if not self.done_sent:
                self.done_sent = True
                self.event_pub.publish(ms.json_to_msg(TrialEvent(
                    ms.DONE, s.committed, s.slot + 1, s.seq, run=self.cfg.run_id).to_json()))
                self._publish_diagnostics()
                self.get_logger().info(f"done: {self.trials} trials")
            return
        try:
            nxt = s.next_start()
        except ScheduleError as exc:
            fail(self, str(exc))
            return
        if nxt is None:
            return
        if s.slot < 0:
            # before the first trial: give discovery time to show another formation's
            # leader here (its configuration may not have reached us, its writer has)
            if time.monotonic() - self._born < FIRST_START_WAIT:
                return
            if self.count_publishers(ms.CONFIG) > 1:
                fail(self, f"another formation's leader publishes on "
                           f"{self.get_namespace()}/{ms.CONFIG} in this ROS domain: refusing "
                           f"to start a second one here (use another namespace or domain)",
                     code=2)
                return
        if not matched(self._start_gate()):
            return
        i, q = nxt
        seq = s.started(q)
        self.t = -1
        self._save()
        self.watchdog.moved(time.monotonic(), SAMPLE, progress=False)
        wall_ns = None
        if self.cfg.mode == "wallclock":
            grid = self.clock
            assert isinstance(grid, WallGrid)  # the configuration's, in wallclock mode
            wall_ns = grid.start_for(q, time.time_ns() + self.margin_ns)
            grid.agree(q, wall_ns)  # its stamps are wall time: start + t * dT
            self.wall = WallSchedule(wall_ns, self.clock.dt_ns, self.T)
        start = TrialEvent(ms.START, i, q, seq, self.clock.stamp_ns(q, 0), wall_ns,
                           run=self.cfg.run_id)
        self.event_pub.publish(ms.json_to_msg(start.to_json()))
        if wall_ns is None:  # simulated time: the plant's samples show that it moves
            self.repeat.sent(start, time.monotonic())

    def _start_again(self) -> None:
        """Simulated time: the running slot's start once more while it has had no new
        sample for RESEND_S / 2 (``protocol.schedule.StartRepeat``)."""
        if not self.sched.running:
            self.repeat.stop()
            return
        start = self.repeat.again(time.monotonic())
        if start is not None:
            self.event_pub.publish(ms.json_to_msg(start.to_json()))

    def _on_wall_timer(self) -> None:
        """wallclock: r(t) for each sample due on the wall clock (the newest one if the
        timer fell behind; earlier ones are not sent late)."""
        if self.wall is None:
            return
        t = self.wall.due(time.time_ns())
        if t is None:
            return
        k = self.sched.slot
        ns = self.clock.stamp_ns(k, t)
        self._last_t = t
        self._last_change = time.monotonic()
        self.watchdog.moved(self._last_change, SAMPLE)
        self.ref_pub.publish(ms.pose_to_msg(self.cfg.scenario.reference[t], ns,
                                            ms.WORLD_FRAME, self.ref_msg))
        if t == self.T:
            self.wall = None
            self._end(k)

    def _end(self, slot: int) -> None:
        self.repeat.stop()
        s = self.sched
        self.event_pub.publish(ms.json_to_msg(TrialEvent(ms.END, s.committed, slot, s.seq,
                                                         run=self.cfg.run_id).to_json()))
        committed = s.committed
        s.ended(slot)
        self.watchdog.moved(time.monotonic(), READY, progress=s.committed > committed)
        self._save()
        self._publish_diagnostics()
        self._maybe_start()

    def _start_gate(self) -> list[tuple[Any, int]]:
        """The endpoints a trial's start waits for, beside the readies: the reference's
        readers, the events' reader, and (simulated time) a writer of /clock."""
        need: list[tuple[Any, int]] = [(self.ref_pub, self.ref_readers), (self.event_pub, 1)]
        if self.cfg.mode != "wallclock":  # its /clock reader matched the plant's writer too
            need.append((self.clock_sub, 1))
        return need

    def _start_waits_for(self) -> list[str]:
        """Whom the next start waits for, one phrase each: the nodes not ready (or not
        answering an abort), else the endpoints of ``_start_gate`` not yet matched."""
        late = self.sched.explain_wait(self.refused, self.waiting)
        return late or unmatched(self._start_gate())

    def _phase(self) -> str:
        s = self.sched
        if s.running:
            # until the plant's first sample of a slot it is starting the trial, which
            # may load its kernels first (measured: 76 s under a load of 33 on 2 cores)
            return SAMPLE if self.t >= 0 else STARTUP
        return STARTUP if s.slot < 0 and s.abort_pending is None else READY

    def _on_watchdog(self) -> None:
        """Past a phase's bound: say whom the run waits for and why, then re-run (abort a
        stuck slot; read the readies anew), or, after RETRIES times without progress,
        stop the leader (status STUCK) naming the cause."""
        s = self.sched
        if s.done:
            return
        now = time.monotonic()
        phase = self._phase()
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
            late = self._start_waits_for()
            if s.running:
                late = [f"the plant's first sample of slot {s.slot}"]
            what = (f"trial {s.committed} has waited {waited:.0f} s in {phase} (bound "
                    f"{bound:.0f} s) for: "
                    + "; ".join(late or ["nobody (its readers: the monitor, recorder)"]))
        if wd.gave_up:
            self._report(what, "giving up")
            tried = ("the readies read anew once" if wd.first_startup
                     else f"{wd.retries} retries")
            fail(self, f"stuck: {what} ({tried} without progress)", code=STUCK)
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
            self._aborted(s.why)
            return
        # read every node's latched ready again, and repeat a pending abort
        self.destroy_subscription(self.ready_sub)
        self.ready_sub = self.create_subscription(String, ms.READY, self._on_ready,
                                                  ms.LATCHED_READER_QOS)
        if s.abort_pending is not None:
            self._publish_abort()

    def _report(self, what: str, then: str) -> None:
        """A watchdog finding: in the log, on stderr, and in the leader's diagnostics (the
        launcher prints it on its console)."""
        self.get_logger().error(f"{what}: {then}")
        print(f"{NAME}: {what}: {then}", file=sys.stderr, flush=True)
        self.watch_reports += 1
        self._publish_diagnostics({"count": self.watch_reports, "what": f"{what}: {then}"})

    def _report_wait(self) -> None:
        """Say whom the schedule waits for when it has not moved for a while."""
        s = self.sched
        if time.monotonic() - self._last_change < 5.0 or s.done:
            return
        if s.running:
            self.get_logger().warning(f"trial {s.committed} (slot {s.slot}) has not ended "
                                      f"(last clock: {getattr(self, '_last_t', None)})")
            return
        late = s.waiting_for()
        what = "the abort's answer" if s.abort_pending is not None else "ready"
        if late:
            self.get_logger().warning(f"trial {s.committed} waits for {what} from "
                                      f"{', '.join(late)}")
            return
        gate = "; ".join(unmatched(self._start_gate())) or "readers"
        self.get_logger().warning(f"trial {s.committed}: waiting for {gate}")

    def _publish_diagnostics(self, watchdog: dict[str, Any] | None = None) -> None:
        d: dict[str, Any] = {"node": NAME, "trial": self.sched.committed,
                             "slot": self.sched.slot,
                             "foreign_events": self.sched.foreign_events,
                             "starts_repeated": self.repeat.count}
        if watchdog is not None:
            d["watchdog"] = watchdog
        d.update(self.drops.as_dict())
        self.diag_pub.publish(ms.diagnostics_to_msg(
            d, self.get_clock().now().nanoseconds, self.cfg.scenario.dt, self.T))

    def _on_clock(self, msg: Clock | bytes) -> None:
        try:
            # bytes, as the per-sample messages are (msgs_schema.wire); the stamp, not
            # now(): see notes on /clock callbacks
            ns = ms.wire.read_clock(ms.wire.as_bytes(msg))
            k, t = self.clock.decode(ns)
            if k != self.sched.slot or not self.sched.running:
                raise Rejected("stale" if k <= self.sched.slot else "future",
                               f"time of slot {k}, slot {self.sched.slot} "
                               f"{'runs' if self.sched.running else 'is over'}")
            if t == self.t:
                if self.cfg.mode == "lockstep" and t < self.T:
                    # the plant sent the sample again (a command still due after
                    # RESEND_S): the reference of it again too, for a reader that lost it
                    self.ref_pub.publish(ms.wire.pose_bytes(self.cfg.scenario.reference[t], ns,
                                                            ms.WORLD_FRAME))
                raise Rejected("duplicate", f"time of sample {t} again")
            if t < self.t:
                raise Rejected("out_of_order", f"sample {t} after {self.t}")
            if self.cfg.mode == "lockstep" and t > self.t + 1:
                raise Rejected("future", f"sample {t} while {self.t + 1} is due")
        except Rejected as exc:
            self.drops.reject(exc, "clock")
            return
        self.t = t
        self._last_t = t
        self._last_change = time.monotonic()
        self.watchdog.moved(self._last_change, SAMPLE)
        self.repeat.moved(self._last_change)
        ref = self.cfg.scenario.reference[t]
        self.ref_pub.publish(ms.wire.pose_bytes(ref, ns, ms.WORLD_FRAME))
        if t == self.T:
            self._end(k)


def _check_parameters(g: Any) -> None:
    """ValueError naming a parameter no run can have (it is refused before anything is
    published: a leader with ``trials:=-5`` would say "done" at once)."""
    if int(g("trials")) < 0:
        raise ValueError(f"parameter trials: {g('trials')}: the number of trials is at least "
                         f"1 (0 keeps the scenario's)")
    if int(g("gap")) < 1:
        raise ValueError(f"parameter gap: {g('gap')}: at least 1 sample between trials")
    for name in ("timeout", "start_margin", "watchdog_scale"):
        v = float(g(name))
        if not (v > 0 and v < 1e6):
            raise ValueError(f"parameter {name}: {v}: a time in seconds > 0 is required")


def _build(ns: Any, argv: list[str]) -> list[Node]:
    try:
        return [LeaderNode()]
    except ValueError as exc:  # a parameter, the scenario or the state file: one line
        print(f"formation-ilc-leader: {exc}", file=sys.stderr, flush=True)
        raise SystemExit(2) from None


def main(args: list[str] | None = None) -> int:
    return spin_main(_build, node_parser("formation-ilc-leader", __doc__), args)


if __name__ == "__main__":
    sys.exit(main())
