"""Virtual leader (``formation-ilc-virtual-leader``): the reference r(t), the trial schedule, the
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
    wallclock every robot_i and bridge_i: the team of ``formation_ilc.config.roster``).
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
exit_when_done : bool
    End the process with status 0 once ``done`` is out (default false): a launch file
    shuts the other nodes down with it (``launch/formation.launch.py``).

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
every plant samples its robot at the same instants: each bridge estimates the leader's
clock and samples on it (``formation_ilc.protocol.timesync``).

Clock questions (realtime and wallclock): the leader answers, on ``leader/clock/pong``,
the questions for its time on ``robot_i/clock/ping`` (a robot that sees the leader) and,
in wall-clock trials, ``bridge_i/clock/ping`` (every bridge); its clock is the team's
reference (the ground station's machine clock, never emulated).

The stop button: the leader serves ``stop`` (std_srvs/srv/Trigger, ``/formation/stop``).
A call latches ``estop`` (std_msgs/Bool true), which every bridge and robot obeys at once
(zero commands), answers success, starts no trial after it and ends the process with
status 7 (``formation_ilc.system.exits.STOPPED``) naming the caller (the nodes with a
client of the service). A true ``estop`` someone else latched ends the run the same way.
Frames: ``map -> leader`` on ``/tf`` with each reference sample (``nodes.frames``).

Every decision above is the pure core's (``formation_ilc.protocol.leader.Leader``, tested
without ROS); this node declares the parameters, the publishers, subscriptions and timers,
and makes one call into it per event.
"""

from __future__ import annotations

import dataclasses
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from rclpy.duration import Duration
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Bool, String
from std_srvs.srv import Trigger

import msgs_schema as ms
from formation_ilc.config import params
from formation_ilc.config.plants import default_plant
from formation_ilc.config.roster import Lineup, leader_clock_askers, roster
from formation_ilc.config.runconfig import PARAMS, RunConfig, clocks_param
from formation_ilc.core.clock import Rejected
from formation_ilc.nodes.clocks import ClockExchange, node_clock
from formation_ilc.nodes.common import (
    Diagnostics,
    DropCounter,
    Exit,
    GuardedNode,
    fail,
    matched,
    node_parser,
    run_key,
    spin_main,
    unmatched,
)
from formation_ilc.nodes.frames import Frame, Frames
from formation_ilc.nodes.params import declare, effective
from formation_ilc.protocol.leader import NAME, Leader
from formation_ilc.protocol.plant import RESEND_S
from formation_ilc.protocol.schedule import TrialEvent
from formation_ilc.system.exits import STOPPED

#: [s] how long a stopped leader waits for every reader of the e-stop to acknowledge it
#: before its process ends (the bridges hold zero on their own meanwhile and after)
STOP_ACK_S = 1.0
#: [s] how long it waits for the graph to name who stopped it (a caller's node can reach
#: the graph after its call)
NAME_WAIT_S = 2.0


class LeaderNode(GuardedNode):
    """The leader's node: parameters, publishers, subscriptions, timers; its decisions are
    ``self.core``'s (``formation_ilc.protocol.leader.Leader``), and it is the core's
    ``LeaderIO``."""

    def __init__(self, **kwargs: Any):
        kwargs.setdefault("namespace", ms.NAMESPACE)
        super().__init__(NAME, **kwargs)
        declare(self, params.LEADER)  # the run configuration's (runconfig) and the leader's
        g = lambda name: self.get_parameter(name).value  # noqa: E731
        _check_parameters(g)
        cfg = RunConfig.from_params({name: g(name) for name in PARAMS})
        self.cfg = cfg = dataclasses.replace(cfg, clocks=clocks_param(str(g("clocks"))))
        sc = cfg.scenario
        expected = [str(e) for e in g("nodes_expected") if e]
        if not expected:  # started alone: the team the launcher would name, no monitor
            expected = roster(Lineup(sc.n, plant=default_plant(cfg.mode), links=cfg.links,
                                     monitor=False)).team.expected
        # the parameters that keep the scenario's read the scenario's; the team, whom
        # the leader waits for
        effective(self, {"seed": sc.seed, "trials": sc.trials, "law": sc.law.kind,
                         "memory": sc.law.memory, "headings": sc.headings,
                         "time_scale": float(sc.time_scale),
                         "nodes_expected": list(expected)})
        # who reads the reference: the link emulator, or each robot that sees the leader
        # (none in lockstep with direct links: RunConfig.leader_in_step)
        self.ref_readers = (1 if cfg.links == "emulated"
                            else 0 if cfg.leader_in_step
                            else int(sum(sc.graph.leader > 0)))
        sdir = str(g("state_dir"))
        # a state file that cannot be gone on from is refused before anything is published
        self.core = Leader(cfg, expected, self, state_file=Path(sdir) / "leader.json"
                           if sdir else None, namespace=self.get_namespace(),
                           watchdog_scale=float(g("watchdog_scale")),
                           start_margin=float(g("start_margin")), key=run_key(),
                           secure=os.environ.get("ROS_SECURITY_ENABLE", "") == "true")
        if self.core.restored is not None:
            self.get_logger().info(self.core.restored)
        self.drops = DropCounter(self)
        self.ref_msg = PoseStamped()
        self.config_pub = self.create_publisher(String, ms.CONFIG, ms.LATCHED_QOS)
        self.ref_pub = self.create_publisher(PoseStamped, ms.REFERENCE, ms.SAMPLE_QOS)
        self.event_pub = self.create_publisher(String, ms.TRIAL_EVENTS, ms.SAMPLE_QOS)
        self.diag_pub = Diagnostics(self)  # per-trial report and /diagnostics
        self.frames = Frames(self)  # map -> leader, the reference (nodes.frames)
        # every ready and report from the node it names (protocol.writers)
        self.ready_sub = self.checked_readies(self._on_ready)
        # its own events come back here too; a start or abort it did not send is re-asserted
        self.create_subscription(String, ms.TRIAL_EVENTS, self._on_event, ms.SAMPLE_QOS)
        # a second formation's latched configuration is what this reader is for: a depth
        # of 1 (shared by every writer of the keyless topic) let this leader's own config
        # replace it before it was taken, and the second formation ran
        self.create_subscription(String, ms.CONFIG, self._on_config, ms.LATCHED_READER_QOS)
        # a node not yet ready says what it waits for in its diagnostics: the watchdog
        # names it (discovery that does not complete shows as endpoints never matched)
        self.checked_subscription(DiagnosticArray, ms.DIAGNOSTICS, self._on_diagnostics_from,
                                  ms.LATCHED_READER_QOS, shared=True)
        if cfg.mode == "wallclock":
            self._wall_timer = self.create_timer(0.005, self.core.on_wall_timer)
        else:
            self.clock_sub = self.create_subscription(Clock, ms.CLOCK, self._on_clock,
                                                      ms.CLOCK_QOS, raw=True)
            self.create_timer(RESEND_S / 8, self.core.start_again)
        if cfg.clock_exchanges:
            self._answer_clocks(cfg, expected)
        # the stop button: a call stops every robot and ends the run (status 7); an e-stop
        # someone else latched ends it too
        self.stopped_by: str | None = None
        self.estop_pub = self.create_publisher(Bool, ms.ESTOP, ms.LATCHED_QOS)
        self.create_service(Trigger, ms.STOP_SERVICE, self._on_stop)
        self.create_subscription(Bool, ms.ESTOP, self._on_estop, ms.LATCHED_READER_QOS)
        self.config_pub.publish(ms.json_to_msg(cfg.to_json()))
        self._gate = self.create_timer(0.05, self.core.maybe_start)
        self.create_timer(5.0, self.core.report_wait)
        if g("exit_when_done"):
            self.create_timer(0.5, self._exit_when_done)
        self.create_timer(1.0, self.core.on_watchdog)
        self.get_logger().info(f"{sc.name}: {sc.n} robots, {sc.trials} trials of "
                               f"{sc.samples} samples, {cfg.mode}, {cfg.links} links; "
                               f"waiting for {', '.join(expected)}")

    def _answer_clocks(self, cfg: RunConfig, expected: list[str]) -> None:
        """The team's clock reference (the ground station's machine clock, never emulated):
        answers the robots that hear it and the bridges of the team it waits for
        (``expected``), as the roster grants (``config.roster.leader_clock_askers``)."""
        bridges = [e for e in expected if e.startswith(ms.BRIDGE_PREFIX)
                   and e[len(ms.BRIDGE_PREFIX):].isdigit()]
        askers = leader_clock_askers(cfg.scenario.graph.leader, bridges)
        self.clocks = ClockExchange(self, ms.LEADER, cfg, node_clock(cfg, None), peers=(),
                                    askers=askers, drops=self.drops)

    def _exit_when_done(self) -> None:
        """The run is over: end this process with status 0 (``exit_when_done``); the
        ``done`` event went out at least one timer period before."""
        if self.core.done_sent:
            if getattr(self, "_done_seen", False):
                self.get_logger().info("done: the leader exits (exit_when_done)")
                Exit.code = 0
                if Exit.stop is not None and not Exit.stop.done():
                    Exit.stop.set_result(0)
            self._done_seen = True

    @property
    def expected(self) -> list[str]:
        return self.core.expected

    # ------------------------------------------------------------------ the stop button
    def _on_stop(self, request: Trigger.Request, response: Trigger.Response
                 ) -> Trigger.Response:
        """``stop`` called: every robot commands zero at once (the e-stop, latched), and the
        run ends with status 7, naming who called."""
        if self.stopped_by is None:
            srv = self.resolve_service_name(ms.STOP_SERVICE)
            self._stop(f"{srv} called by", lambda: self._clients_of(srv))
            response.message = (f"stopped: every robot commands zero; the run ends with "
                                f"status {STOPPED}")
        else:
            response.message = f"already stopped ({self.stopped_by})"
        response.success = True
        return response

    def _on_estop(self, msg: Bool) -> None:
        if not msg.data or self.stopped_by is not None:
            return
        topic = self.resolve_topic_name(ms.ESTOP)
        self._stop(f"an e-stop on {topic} from", lambda: sorted({
            f"{i.node_namespace.rstrip('/')}/{i.node_name}"
            for i in self.get_publishers_info_by_topic(topic)
            if i.node_name != self.get_name()}))

    def _clients_of(self, service: str) -> list[str]:
        """The nodes with a client of ``service`` (the graph's word: rclpy gives a service
        callback no caller)."""
        out = []
        for name, ns in self.get_node_names_and_namespaces():
            try:
                clients = self.get_client_names_and_types_by_node(name, ns)
            except Exception:  # noqa: BLE001 - a node gone between the two queries
                continue
            if any(c == service for c, _ in clients):
                out.append(f"{ns.rstrip('/')}/{name}")
        return sorted(out)

    def _stop(self, how: str, who: Callable[[], list[str]]) -> None:
        """Latch the e-stop (every bridge sends its driver zero and holds it, every robot
        commands zero), start no trial, and end the process with ``STOPPED`` once the
        e-stop's readers have it, naming ``who()`` stopped it (the graph's answer now, or
        within ``NAME_WAIT_S``: a caller's node may reach this node's graph after its call)."""
        self.estop_pub.publish(Bool(data=True))
        self._gate.cancel()
        if hasattr(self, "_wall_timer"):
            self._wall_timer.cancel()
        self._who, self._how = who, how
        self._named = who()
        self.stopped_by = f"{how} {', '.join(self._named) or '...'}"
        text = (f"stop: every robot commands zero (e-stop latched on "
                f"{self.resolve_topic_name(ms.ESTOP)}); the run ends with status {STOPPED}")
        self.get_logger().warning(text)
        # the answer goes out before the process ends: the exit is a timer later
        self._stop_timer = self.create_timer(0.05, self._stop_exit)

    def _stop_exit(self) -> None:
        self._stop_timer.cancel()
        self.estop_pub.wait_for_all_acked(Duration(seconds=STOP_ACK_S))
        end = time.monotonic() + NAME_WAIT_S
        while not self._named and time.monotonic() < end:
            time.sleep(0.05)  # the graph cache fills on DDS's threads, not this one
            self._named = self._who()
        self.stopped_by = (f"{self._how} "
                           f"{', '.join(self._named) or 'a node the graph did not name'}")
        fail(self, f"stopped by {self.stopped_by}; every robot was commanded zero "
                   f"(status {STOPPED}, docs/real-robots.md, \"Stopping\")", STOPPED)

    # ------------------------------------------------------------------ callbacks
    def _on_ready(self, msg: String) -> None:
        try:
            self.core.on_ready(ms.msg_to_json(msg))
        except Rejected as exc:
            self.drops.reject(exc, ms.READY)

    def _on_diagnostics_from(self, msg: DiagnosticArray, gid: bytes) -> None:
        try:
            report = ms.msg_to_report(msg, ("node",))
        except Rejected:
            return  # the monitor counts malformed diagnostics
        if self.from_named_writer(ms.DIAGNOSTICS, gid, report.get("node")):
            self.core.on_waiting(report)

    def _on_event(self, msg: String) -> None:
        try:
            data = ms.msg_to_json(msg)
        except Rejected:
            return  # followers count it; the leader only watches for starts and aborts
        self.core.on_event(data)

    def _on_config(self, msg: String) -> None:
        try:
            data = ms.msg_to_json(msg)
        except Rejected as exc:
            self.drops.reject(exc, ms.CONFIG)
            return
        self.core.on_config(data)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        try:
            report = ms.msg_to_report(msg, ("node",))
        except Rejected:
            return  # the monitor counts malformed diagnostics; nothing to do here
        self.core.on_waiting(report)

    def _on_clock(self, msg: Clock | bytes) -> None:
        try:
            # bytes, as the per-sample messages are (msgs_schema.wire); the stamp, not
            # now(): see notes on /clock callbacks
            self.core.on_clock(ms.wire.read_clock(ms.wire.as_bytes(msg)))
        except Rejected as exc:
            self.drops.reject(exc, "clock")

    # ------------------------------------------------------------------ LeaderIO
    def publish_event(self, event: TrialEvent) -> None:
        self.event_pub.publish(ms.json_to_msg(event.to_json()))

    def publish_reference(self, t: int, stamp_ns: int) -> None:
        ref = self.cfg.scenario.reference[t]
        self.frames.publish(stamp_ns, [Frame(ms.WORLD_FRAME, ms.LEADER_FRAME_ID,
                                             float(ref[0]), float(ref[1]), float(ref[2]))])
        if self.cfg.mode == "wallclock":
            self.ref_pub.publish(ms.pose_to_msg(ref, stamp_ns, ms.WORLD_FRAME, self.ref_msg))
        else:  # bytes, as the per-sample messages are
            self.ref_pub.publish(ms.wire.pose_bytes(ref, stamp_ns, ms.WORLD_FRAME))

    def publish_diagnostics(self, report: dict[str, Any]) -> None:
        report.update(self.drops.as_dict())
        self.diag_pub.publish(ms.diagnostics_to_msg(
            report, self.get_clock().now().nanoseconds, self.cfg.scenario.dt,
            self.cfg.scenario.samples))

    def log(self, level: str, text: str) -> None:
        # one call site per severity: rclpy refuses a call site whose severity changes
        # ("Logger severity cannot be changed between calls")
        lg = self.get_logger()
        if level == "info":
            lg.info(text)
        elif level == "warning":
            lg.warning(text)
        elif level == "debug":
            lg.debug(text)
        else:
            lg.error(text)

    def alert(self, text: str) -> None:
        self.get_logger().error(text)
        print(f"{NAME}: {text}", file=sys.stderr, flush=True)

    def drop(self, reason: str, topic: str, why: str) -> None:
        self.drops.drop(reason, topic, why)

    def fail(self, text: str, code: int) -> None:
        fail(self, text, code=code)

    def reread_readies(self) -> None:
        self.ready_sub.destroy()
        self._checked.remove(self.ready_sub)
        self.ready_sub = self.checked_readies(self._on_ready)

    def _gate_pairs(self) -> list[tuple[Any, int]]:
        """The endpoints a trial's start waits for, beside the readies: the reference's
        readers, the events' readers, and (simulated time) a writer of /clock.

        Every node waited for reads the trial events, and the leader its own: the start
        waits until the events' writer has matched that many readers. A follower says
        ready once *its* reader matched the leader's writer; the writer may match it
        later (a secure team of 50: seconds later), and a volatile start sent before is
        never delivered to it (the monitor of that run missed trial 0's start)."""
        need: list[tuple[Any, int]] = [(self.ref_pub, self.ref_readers),
                                       (self.event_pub, len(self.core.expected) + 1)]
        if self.cfg.mode != "wallclock":  # its /clock reader matched the plant's writer too
            need.append((self.clock_sub, 1))
        return need

    def start_gate(self) -> list[str]:
        return unmatched(self._gate_pairs())

    def events_read(self) -> bool:
        return matched([(self.event_pub, 1)])

    def config_writers(self) -> int:
        return self.count_publishers(ms.CONFIG)


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
        print(f"formation-ilc-virtual-leader: {exc}", file=sys.stderr, flush=True)
        raise SystemExit(2) from None


def main(args: list[str] | None = None) -> int:
    return spin_main(_build, node_parser("formation-ilc-virtual-leader", __doc__), args)


if __name__ == "__main__":
    sys.exit(main())
