"""What every node of the stack shares: drop counters, the config topic, spinning, warm-up.

The run configuration itself (``formation_ilc.config.runconfig.RunConfig``) is part of the core.
"""

from __future__ import annotations

import argparse
import os
import signal
import socket
import sys
import time
from collections import Counter
from collections.abc import Callable, Collection, Iterable
from typing import Any, TypeVar

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.subscription import Subscription
from rclpy.task import Future
from std_msgs.msg import String

import msgs_schema as ms
from formation_ilc.config.runconfig import RunConfig, make_config
from formation_ilc.core.clock import REASONS, Rejected
from formation_ilc.nodes.writers import REFRESH_HELD, CheckedSubscription
from formation_ilc.protocol.schedule import Follower, Ready, TrialEvent, boot_id, parse_key
from formation_ilc.protocol.writers import OK, WriterTable
from formation_ilc.system.exits import DISK_FULL, DISK_FULL_TAG, is_disk_full
from formation_ilc.system.heartbeat import beat
from formation_ilc.system.lifetime import (
    ORPHAN_GRACE,
    PARENT_ENV,
    bound_the_stop,
    die_with_parent,
    parent_gone,
    wait_at_gate,
)

__all__ = ["PARENT_ENV", "RUN_ENV", "KEY_ENV", "LAUNCHER_ENV", "run_key", "secure_enclaves",
           "DROP_REASONS",
           "DropCounter", "Diagnostics", "RunConfig", "make_config", "GuardedNode",
           "MESSAGE_ERRORS", "config_from_msg", "ConfiguredNode", "matched", "unmatched",
           "readers_wanting", "fail",
           "spin_main", "node_parser", "ros_param", "robot_node_from_args"]

R = TypeVar("R")

#: environment variable with the run a launcher started this node for (its run_id)
RUN_ENV = "FORMATION_ILC_RUN_ID"
#: environment variable with the key the run's leader seals its events with (hex): the
#: launcher gives it to every process it starts (``protocol.schedule.seal``)
KEY_ENV = "FORMATION_ILC_RUN_KEY"
#: environment variable with the identity of the launcher that started this node: part of
#: its ``boot`` (``protocol.schedule.boot_id``)
LAUNCHER_ENV = "FORMATION_ILC_LAUNCHER"


def run_key() -> bytes | None:
    """This process's run key (``KEY_ENV``), None without one; ValueError if unreadable."""
    try:
        return parse_key(os.environ.get(KEY_ENV))
    except ValueError as exc:
        raise ValueError(f"{KEY_ENV}: {exc}") from None

#: reasons a message is dropped (the diagnostics counters)
DROP_REASONS = REASONS


def secure_enclaves(namespace: str) -> dict[str, bytes]:
    """Under ``--secure`` (rcl's security variables: enabled, a keystore): node
    ``/ns/name`` -> the GUID prefix of a participant authenticated in its enclave, for the
    writer tables (``protocol.writers.WriterTable.enclaves``); empty otherwise."""
    keystore = os.environ.get("ROS_SECURITY_KEYSTORE", "")
    if os.environ.get("ROS_SECURITY_ENABLE", "").lower() != "true" or not keystore:
        return {}
    from formation_ilc.store.keystore import enclave_prefixes

    return enclave_prefixes(keystore, namespace)


def config_from_msg(msg: String, drops: DropCounter) -> RunConfig | None:
    """The run configuration on the config topic, or None (dropped and counted)."""
    try:
        return RunConfig.from_json(ms.msg_to_json(msg))
    except Rejected as exc:
        drops.reject(exc, ms.CONFIG)
        return None


class DropCounter:
    """Counts dropped messages by reason and topic (published in diagnostics)."""

    def __init__(self, node: Node):
        self._node = node
        self.counts: Counter[str] = Counter({r: 0 for r in DROP_REASONS})
        self.by_topic: Counter[str] = Counter()

    def drop(self, reason: str, topic: str, why: str = "") -> None:
        self.counts[reason] += 1
        self.by_topic[f"{reason}:{topic}"] += 1
        # first few of each kind are logged; the rest only counted (a flood must not log-spam)
        if self.by_topic[f"{reason}:{topic}"] <= 3:
            self._node.get_logger().warning(f"dropped {reason} message on {topic}: {why}")

    def reject(self, exc: Rejected, topic: str) -> None:
        """Count a refused input under its reason."""
        self.drop(exc.reason, topic, str(exc))

    def as_dict(self) -> dict[str, Any]:
        """The counts for a report; ``forged``: the messages the node's writer table
        refused, by topic and sender (``protocol.writers``), when it refused any."""
        out = {"dropped": dict(self.counts), "dropped_by_topic": dict(self.by_topic)}
        writers = getattr(self._node, "writers", None)
        if writers is not None and writers.total:
            out["forged"] = writers.report()
        return out


#: what a handler may raise on a message it did not foresee (a field of the wrong type, a
#: key missing, a number out of range): counted as ``malformed``, never the node's end
MESSAGE_ERRORS = (ValueError, TypeError, KeyError, IndexError, AttributeError,
                  ArithmeticError)


class GuardedNode(Node):
    """A node none of whose subscription callbacks can raise on a message: each callback
    is wrapped so that an error of ``MESSAGE_ERRORS`` drops the message, counted as
    ``malformed`` on its topic (the node's ``drops``), and the node goes on. A node's own
    decision to end (``fail``, a full disk) is not one of them."""

    def create_subscription(self, msg_type: Any, topic: str, callback: Callable[..., Any],
                            *args: Any, **kwargs: Any) -> Subscription:
        def guarded(msg: Any) -> Any:
            try:
                return callback(msg)
            except MESSAGE_ERRORS as exc:
                self._malformed(topic, exc)
                return None

        return super().create_subscription(msg_type, topic, guarded, *args, **kwargs)

    def checked_subscription(self, msg_type: Any, topic: str,
                             handler: Callable[[Any, bytes], None], qos: Any,
                             raw: bool = False, shared: bool = False,
                             owners: Collection[str] = (),
                             poll: float = REFRESH_HELD) -> Any:
        """A subscription whose every message is judged by its writer first
        (``nodes.writers.CheckedSubscription`` with this node's ``writers`` table):
        ``handler(msg, gid)``, guarded like every callback here; a refused message is a
        ``forged`` drop. ``owners``: the nodes that alone write the topic (``shared``: a
        topic every node writes in its own name; the handler asks ``from_named_writer``).
        ``poll`` [s]: how often it asks rcl for what a missed wake-up left there and
        judges its held samples again (``CheckedSubscription.poll``); one timer of the
        node, at the shortest of its subscriptions' periods, polls them all."""
        if not hasattr(self, "writers"):
            self.writers = WriterTable(self.get_namespace(),
                                       enclaves=secure_enclaves(self.get_namespace()))
        name = topic
        if owners:  # only these nodes (in the formation's namespace) write it
            self.writers.own(self.resolve_topic_name(topic), *owners)

        def guarded(msg: Any, gid: bytes) -> None:
            try:
                handler(msg, gid)
            except MESSAGE_ERRORS as exc:
                self._malformed(name, exc)

        sub = CheckedSubscription(self, msg_type, topic, qos, self.writers, guarded, raw=raw,
                                  shared=shared, on_refused=lambda why: self._forged(name, why),
                                  own_poll=False, period=poll)
        self._checked = [*getattr(self, "_checked", []), sub]
        period = min(s.period for s in self._checked)
        timer = getattr(self, "_checked_poll", None)
        if timer is None or period < self._poll_period:
            # one timer for all: its wake-up costs more than asking rcl (a timer of each
            # subscription: 0.82 ms a second each, 50 idle ones; one for all: 0.19 ms;
            # scripts/bench_writers.py --idle)
            from rclpy.clock import Clock, ClockType

            if timer is not None:
                self.destroy_timer(timer)
            self._poll_period = period
            self._checked_poll = self.create_timer(
                period, self._poll_checked, clock=Clock(clock_type=ClockType.STEADY_TIME))
        return sub

    def poll_period(self) -> float:
        """[s] how often the checked subscriptions are re-checked (inf: none)."""
        return float(getattr(self, "_poll_period", float("inf")))

    def polls_idle(self, idle: bool) -> None:
        """Stop the checked subscriptions' re-check (``idle``) while nothing they carry can
        be due (a robot inside a trial whose checked topics are trajectories only: a
        wake-up of its executor every 0.25 s for nothing), or start it again; a message
        that came meanwhile was taken on its own wake-up, or is at the first re-check."""
        timer = getattr(self, "_checked_poll", None)
        if timer is None or timer.is_canceled() == idle:
            return
        if idle:
            timer.cancel()
        else:
            timer.reset()

    def _poll_checked(self) -> None:
        """The node's re-check: each checked subscription whose period has come takes
        what waits in rcl (a wake-up the executor missed) and judges its held samples
        again."""
        now = time.monotonic()
        for sub in list(getattr(self, "_checked", [])):
            if now < sub.next_poll:
                continue
            sub.next_poll = now + sub.period - self._poll_period / 2  # a late tick skips none
            sub.poll()

    def checked_readies(self, on_ready: Callable[[String], None]) -> Any:
        """The ready topic, each ready handed to ``on_ready`` only when it comes from the
        node it names (the launcher's monitor may say another is ``down``): a ready in
        another node's name moves nothing. An undecodable one is dropped and counted."""
        def taken(msg: String, gid: bytes) -> None:
            try:
                d = ms.msg_to_json(msg)
            except Rejected as exc:
                drops = getattr(self, "drops", None)
                if drops is not None:
                    drops.reject(exc, ms.READY)
                return
            if self.from_named_writer(ms.READY, gid, d.get("node"), d.get("down") is True,
                                      str(d.get("boot", ""))[:64]):
                on_ready(msg)

        return self.checked_subscription(String, ms.READY, taken, ms.LATCHED_READER_QOS,
                                         shared=True)

    def from_named_writer(self, topic: str, gid: bytes, claimed: Any, down: bool = False,
                          boot: str = "") -> bool:
        """Whether the writer (``gid``) of a message on a shared topic is the node the
        message names (``claimed``; the launcher's monitor may say another is ``down``);
        a message that names no node is left to its handler (malformed there). Counted
        as ``forged`` when not."""
        if not isinstance(claimed, str):
            return True
        verdict = self.writers.claims(self.resolve_topic_name(topic), gid, claimed, down,
                                      boot)
        if verdict == OK:
            return True
        self._forged(topic, verdict)
        return False

    def _forged(self, topic: str, why: str) -> None:
        drops = getattr(self, "drops", None)
        if drops is not None:
            drops.drop("forged", topic, why)

    def _malformed(self, topic: str, exc: BaseException) -> None:
        why = f"{type(exc).__name__}: {str(exc)[:200]}"
        drops = getattr(self, "drops", None)
        if drops is not None:
            drops.drop("malformed", topic, why)
        else:
            self.get_logger().warning(f"dropped malformed message on {topic}: {why}")

    def destroy_node(self) -> None:
        for sub in getattr(self, "_checked", []):
            sub.destroy()
        self._checked = []
        super().destroy_node()


#: how often [s] a node not yet ready names the endpoints it waits for (its log, and its
#: diagnostics, which the leader's watchdog repeats)
MATCH_WARN = 10.0


class ConfiguredNode(GuardedNode):
    """A node that builds itself (``configure``) from a run configuration: one given at
    start, or the latched one on the config topic (``follow_config``)."""

    def __init__(self, name: str, **kwargs: Any):
        kwargs.setdefault("namespace", ms.NAMESPACE)
        super().__init__(name, **kwargs)
        self.drops = DropCounter(self)
        #: the per-trial report and the standard stream (from the start: a node that waits
        #: for its configuration is alive)
        self.diag_pub = Diagnostics(self)
        self.configured = False
        # the first word half a period in: a node that matches in a few seconds says none
        self._waiting_said = time.monotonic() - MATCH_WARN / 2
        #: this process's identity in ``ready`` (a new one tells the leader it restarted)
        self.boot = boot_id(os.environ.get(LAUNCHER_ENV))
        #: the run key: only events the run's leader sealed with it are taken
        self.key = run_key()
        #: what this node takes of the leader's events (its core's, once configured)
        self.follower = Follower(self.run_id, key=self.key)

    def ready_msg(self, trial: int, passive: bool = False, abort_slot: int = -1,
                  why: str = "") -> String:
        """The ``ready`` message of this node (``formation_ilc.protocol.schedule``); the
        node then counts as ready for the next start. ``abort_slot``: a plant asks the
        leader to abort that slot, saying ``why``."""
        self.follower.said_ready()
        return ms.json_to_msg(Ready(self.get_name(), trial, self.boot, self.follower.seen,
                                    passive, self.run_id, abort_slot=abort_slot,
                                    why=why, config=self.own_config).to_json())

    def not_ready(self, waits: list[str]) -> None:
        """Not ready yet: every MATCH_WARN seconds say what it waits for (``waits``, one
        phrase an endpoint, :func:`unmatched`) in the log and, when the node has a
        diagnostics writer (``diag_pub``), as ``waiting`` in its diagnostics, for the
        leader's watchdog to name."""
        now = time.monotonic()
        if not waits or now - self._waiting_said < MATCH_WARN:
            return
        self._waiting_said = now
        self.get_logger().warning(f"not ready: waiting for {'; '.join(waits)}")
        pub = getattr(self, "diag_pub", None)
        if pub is not None:
            pub.publish(ms.diagnostics_to_msg(
                {"node": self.get_name(), "trial": -1, "waiting": list(waits)},
                self.get_clock().now().nanoseconds, hardware_id=self.get_name()))

    @property
    def run_id(self) -> str:
        cfg = getattr(self, "cfg", None)
        return cfg.run_id if cfg is not None else os.environ.get(RUN_ENV, "")

    def take_event(self, msg: String, take: Callable[[TrialEvent], R]) -> R | None:
        """What ``take`` (the node's core, which applies ``schedule.Follower``'s rule to a
        start or abort) makes of the event on ``leader/trial_events``, or None: dropped and
        counted (undecodable, or refused with its reason)."""
        try:
            return take(TrialEvent.from_json(ms.msg_to_json(msg)))
        except Rejected as exc:
            self.drops.reject(exc, ms.TRIAL_EVENTS)
            return None

    #: the fields of ``RunConfig.agreement`` this node runs with (None: all)
    AGREES_ON: tuple[str, ...] | None = None
    #: what a node that configured itself from its own parameters runs with (its readies
    #: carry it; the leader names a difference and stops); None when it follows ``config``
    own_config: dict[str, Any] | None = None

    def follow_config(self, cfg: RunConfig | None = None, own: bool = True) -> None:
        """Configure now from ``cfg`` (``own``: from the node's own parameters), or when the
        config topic delivers one."""
        if cfg is not None:
            if own:
                self.own_config = {k: v for k, v in cfg.agreement().items()
                                   if self.AGREES_ON is None or k in self.AGREES_ON}
            self.configured = True
            try:
                self.configure(cfg)
            except ValueError as exc:  # a configuration this node cannot run
                fail(self, str(exc), code=2)
            self.follower.key = self.key  # its core's follower takes sealed events only
        else:
            self._cfg_sub = self.create_subscription(String, ms.CONFIG, self._on_config,
                                                     ms.LATCHED_QOS)

    def _on_config(self, msg: String) -> None:
        if self.configured:  # the same one again is no news; another one is not followed
            try:
                d = ms.msg_to_json(msg)
            except Rejected as exc:
                self.drops.reject(exc, ms.CONFIG)
                return
            if d != getattr(self, "_config_json", None):
                other = str(d.get("run_id", ""))
                if other != self.run_id:
                    self.drops.drop("foreign", ms.CONFIG,
                                    f"run {other or '?'} on this domain and namespace; this "
                                    f"node belongs to run {self.run_id or '?'}")
                else:
                    self.drops.drop("unexpected", ms.CONFIG,
                                    "a second, different run configuration")
            return
        cfg = config_from_msg(msg, self.drops)
        if cfg is None:
            return
        mine = self.run_id  # the launcher's (environment), if it started this node
        if mine and cfg.run_id != mine:
            self.drops.drop("foreign", ms.CONFIG,
                            f"run {cfg.run_id or '?'} on this domain and namespace; this "
                            f"node belongs to run {mine}")
            return
        self._config_json = ms.msg_to_json(msg)
        self.follow_config(cfg, own=False)

    def configure(self, cfg: RunConfig) -> None:
        raise NotImplementedError


class Diagnostics:
    """A node's diagnostics, two ways. ``publish`` sends its report (``diagnostics_to_msg``)
    on the formation's ``diagnostics`` (latched, at each trial's end: the launcher, the
    recorder and analyze read it, values as JSON), and the standard stream repeats the
    node's current statuses on ``/diagnostics`` every ``PERIOD`` seconds and at each
    report, as diagnostic_updater does: ``node: task`` names, hardware ids, plain values,
    so that the aggregator's staleness (5 s by default) sees a live node as live."""

    PERIOD = 1.0

    def __init__(self, node: Node):
        from rclpy.clock import Clock, ClockType

        self.node = node
        self.name = node.get_name()
        self.host = socket.gethostname()
        self.pub = node.create_publisher(DiagnosticArray, ms.DIAGNOSTICS, ms.LATCHED_QOS)
        self.ros_pub = node.create_publisher(DiagnosticArray, ms.ROS_DIAGNOSTICS,
                                             ms.ROS_DIAGNOSTICS_QOS)
        self.statuses = [ms.starting_status(self.name, self.host, "running; no report yet")]
        #: the standard statuses of the node's words between reports, by name
        self.words: dict[str, list[DiagnosticStatus]] = {}
        node.create_timer(self.PERIOD, self.tick,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))

    def publish(self, msg: DiagnosticArray) -> None:
        self.pub.publish(msg)
        self.statuses = ms.standard_statuses(msg, self.name, self.host)
        self.tick()

    def wait_for_all_acked(self, timeout: float) -> bool:
        """Wait up to ``timeout`` [s] until every reader matched on ``diagnostics`` (the
        launcher's monitor, the recorder) acknowledged the reports sent; whether they did.
        A node that ends the run says why in its last report: it must not be gone first."""
        from rclpy.duration import Duration

        return bool(self.pub.wait_for_all_acked(Duration(nanoseconds=int(timeout * 1e9))))

    def word(self, msg: DiagnosticArray, writer: Any, task: str) -> None:
        """A word between reports (a clock word: ``msg`` as ``diagnostics_to_msg`` makes
        it) on ``writer``, a latched writer of its own (the report's keeps one message),
        and on the standard stream as a status ``node: task`` beside the report's, with
        the word's level (a clock warning is a WARN there at once, not at the trial's
        end)."""
        writer.publish(msg)
        named = f"{self.name}: {task}"
        own = ms.standard_statuses(msg, self.name, self.host)[:1]  # the node's own status
        for st in own:
            st.name = named
        self.words[named] = own
        self.tick()

    def tick(self) -> None:
        out = DiagnosticArray()
        out.header.stamp = self.node.get_clock().now().to_msg()
        out.status = self.statuses + [st for sts in self.words.values() for st in sts]
        self.ros_pub.publish(out)


def _reader(e: Any) -> bool:
    """Whether endpoint ``e`` reads (rclpy's subscription, or a writer-checked one)."""
    return isinstance(e, Subscription | CheckedSubscription)


def matched(pairs: Iterable[tuple[Any, int | Collection[str]]], node: Node | None = None
            ) -> bool:
    """True when every publisher has at least ``count`` matched subscriptions and every
    subscription at least ``count`` matched publishers; for a publisher, ``count`` may
    instead name the reader nodes it must have (``node``'s graph, ``readers_wanting``).

    DDS matches each side on its own: a writer may see its reader before the reader has
    seen the writer, and a reliable reader drops what an unmatched writer sends; the
    sample then waits for the writer's next heartbeat (seconds). A node that says ready
    only once both sides of its per-sample topics are matched loses no first sample.

    It stops at the first endpoint that is not matched, and asks the graph for named
    readers (a query each) only once every count holds: a node polls this until it is
    ready, and the simulator of a 50-robot team has about 150 endpoints to check.
    """
    pairs = list(pairs)
    for e, want in pairs:
        if isinstance(want, int):
            sub = _reader(e)
            have = e.get_publisher_count() if sub else e.get_subscription_count()
            if have < want:
                return False
    for e, want in pairs:
        if not isinstance(want, int):
            assert node is not None and not _reader(e), \
                "named readers: a publisher and its node"
            if readers_wanting(node, e, want):
                return False
    return True


def unmatched(pairs: Iterable[tuple[Any, int | Collection[str]]], node: Node | None = None
              ) -> list[str]:
    """What :func:`matched` still waits for, one phrase an endpoint: "TOPIC: 0 of 1
    readers" (for a log line naming why a node is not ready)."""
    out = []
    for e, want in pairs:
        sub = _reader(e)
        have = e.get_publisher_count() if sub else e.get_subscription_count()
        if isinstance(want, int):
            if have < want:
                out.append(f"{e.topic_name}: {have} of {want} {'writers' if sub else 'readers'}")
            continue
        assert node is not None and not sub, "named readers: a publisher and its node"
        phrase = readers_wanting(node, e, want)
        if phrase:
            out.append(phrase)
    return out


#: the node name the ROS graph gives an endpoint whose participant's node list it lacks
#: (rmw_dds_common's GraphCache)
UNKNOWN_NODE = "_NODE_NAME_UNKNOWN_"


def readers_wanting(node: Node, pub: Any, names: Collection[str]) -> str:
    """Why ``pub`` has not yet matched the reader nodes ``names`` (in ``node``'s
    namespace), or "" when it has.

    A count cannot say *which* readers a writer matched: the recorder, a live view or a
    user's tool read the same topics as the monitor, and any of them could stand in for
    it. rclpy names no matched reader, but the graph names every reader discovered on the
    topic; the writer matches a reader as discovery finds it (both come from the same
    endpoint discovery). So: every named node has a reader on the topic in the graph, and
    the writer has matched at least as many readers as the graph lists (a discovered
    reader it has not matched yet keeps it waiting, whoever that reader is).

    A reader the graph lists without its node's name (UNKNOWN_NODE) may be any named one
    still missing. The graph learns node names from each participant's
    ``ros_discovery_info``, sent once per change; a participant dropped on its lease (not
    heard from for about 10 s: a saturated start-up of 50 processes) and found again is
    matched again, but Fast DDS does not deliver the ``ros_discovery_info`` it had already
    taken from it, so its nodes stay unnamed until it changes again (measured: a process
    stopped for 45 s, then resumed; its reader still unnamed a minute later). Waiting for
    the name then waited for ever: robot_48 of a 50-robot lockstep run, its trajectory's
    only reader matched, the monitor "not yet discovered" for ten minutes.
    """
    listed = node.get_subscriptions_info_by_topic(pub.topic_name)
    ns = node.get_namespace()
    seen = {i.node_name for i in listed if i.node_namespace == ns}
    unnamed = sum(i.node_name == UNKNOWN_NODE for i in listed)
    missing = sorted(set(names) - seen)
    have = pub.get_subscription_count()
    need = max(len(listed), len(set(names)))
    if len(missing) <= unnamed and have >= need:
        return ""
    return (f"{pub.topic_name}: {have} of {need} readers"
            + (f" (not yet discovered: {', '.join(missing)})" if missing else "")
            + (f" ({unnamed} of unknown node)" if unnamed else ""))


#: [s] how long the executor spins before the process's loop looks at its stop again (1 s
#: saved an idle node 0.034 ms of CPU per 100 ms, but a stop waits for the slice's end)
SPIN_SLICE = 0.25


class Exit:
    """Exit status a node asks for; ``stop`` is done when the process should end."""

    code = 0
    stop: Future | None = None


def fail(node: Node, message: str, code: int = 3) -> None:
    """Log ``message`` as the node's last word and stop its process with ``code``."""
    node.get_logger().fatal(message)
    print(f"{node.get_name()}: {message}", file=sys.stderr, flush=True)
    Exit.code = code
    if Exit.stop is not None:
        Exit.stop.set_result(code)


def make_executor(kind: str = "events") -> Any:
    if kind == "events":
        from rclpy.experimental import EventsExecutor

        return EventsExecutor()
    from rclpy.executors import SingleThreadedExecutor

    return SingleThreadedExecutor()


class _OneLineParser(argparse.ArgumentParser):
    """argparse with its usage errors in one line: 'PROG: error: why (see PROG --help)',
    status 2."""

    def error(self, message: str) -> Any:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def node_parser(prog: str, doc: str | None) -> argparse.ArgumentParser:
    """The argument parser of a node's entry script: ``--help`` prints the node's docstring
    (its parameters and topics) and exits before any ROS set-up; a bad argument is one
    line and status 2."""
    return _OneLineParser(
        prog=prog, description=doc, formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="ROS arguments follow --ros-args, e.g. --ros-args -p NAME:=VALUE "
               "-r __ns:=/team2")


def ros_param(argv: list[str], name: str) -> str | None:
    """The value of ``-p name:=VALUE`` (or ``--param``) among ROS arguments, as written."""
    value = None
    for flag, arg in zip(argv, argv[1:], strict=False):
        if flag in ("-p", "--param") and arg.startswith(f"{name}:="):
            value = arg.split(":=", 1)[1]
    return value


def robot_node_from_args(cls: Callable[..., Node], argv: list[str], prog: str,
                         probe_name: str = "robot", **kwargs: Any) -> Node:
    """The node of one robot whose ``robot_id`` is a ROS parameter (``-p robot_id:=I``, or
    a ``--params-file`` keyed ``/**`` or by the node's name as a launch file gives it with
    ``-r __node:=NAME``): read before the node exists, since its name follows it. A
    missing or invalid id is a ``ParameterError`` (one line and status 2 in spin_main)."""
    from formation_ilc.config.params import ROBOT
    from formation_ilc.nodes.params import ParameterError, check, probe_overrides

    with probe_overrides(probe_name, ms.NAMESPACE, **kwargs) as found:
        if "robot_id" not in found:
            raise ParameterError("parameter robot_id: a robot number >= 1 is required "
                                 "(-p robot_id:=I, or robot_id in a --params-file under /** "
                                 "or the node's name)")
        rid = check(ROBOT[0], found["robot_id"])
        return cls(int(rid), **kwargs)  # while the probe holds the participant


def _first_line(exc: BaseException) -> str:
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    # rcl's messages end with where in its C source they were raised
    text = lines[0].split(", at /")[0] if lines else type(exc).__name__
    return text[:400]


def spin_main(build: Callable[[argparse.Namespace, list[str]], list[Node]],
              parser: argparse.ArgumentParser, args: list[str] | None = None,
              executor: str = "events") -> int:
    """The Jazzy main idiom for one process holding one or more nodes on one executor.

    parser : the entry script's own arguments (``--help`` exits here, before rclpy).
    build : gets the parsed arguments and the raw argv, and returns the nodes.
    """
    argv = list(args if args is not None else sys.argv)
    try:
        own = rclpy.utilities.remove_ros_args(argv)[1:]
    except RuntimeError as exc:  # rcl's: a params file that is missing or not YAML
        print(f"{parser.prog}: {_first_line(exc)}", file=sys.stderr, flush=True)
        return 2
    ns = parser.parse_args(own)
    die_with_parent()
    beat("at the gate")  # the heartbeat (system.heartbeat): from this, the main, thread
    try:
        wait_at_gate()  # imports done; the launcher says when to join the domain
    except KeyboardInterrupt:  # stopped at the gate: the run was refused
        return 130
    beat("joining the domain")
    # rclpy's own SIGINT handling raises KeyboardInterrupt inside whatever callback runs,
    # which aborts the process from C++; a flag for the spin loop is enough
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    Exit.stop = Future()

    def on_signal(signum: int, frame: Any) -> None:
        # SIGTERM: the launcher died (PR_SET_PDEATHSIG) or gave up on a clean stop; either
        # way nobody waits for a slow teardown (system.lifetime.ORPHAN_GRACE)
        bound_the_stop(ORPHAN_GRACE if signum == signal.SIGTERM else None)
        if Exit.stop is not None and not Exit.stop.done():
            Exit.stop.set_result(0)

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    nodes: list[Node] = []
    ex: Any = None
    try:
        try:
            beat("building its node")
            nodes = build(ns, argv)
        except (ValueError, ParameterException) as exc:
            # a parameter, a scenario or a state file no run can have: one line, status 2
            print(f"{parser.prog}: {_first_line(exc)}", file=sys.stderr, flush=True)
            return 2
        ex = make_executor(executor)
        for n in nodes:
            ex.add_node(n)
        # EventsExecutor.spin() never returns to Python, so SIGINT would go unseen: spin in
        # slices, which costs one return to the interpreter every 0.25 s
        beat("spinning")
        while rclpy.ok() and not Exit.stop.done():
            ex.spin_until_future_complete(Exit.stop, timeout_sec=SPIN_SLICE)
            # out of the executor: this thread is not stuck in it (a freeze stops this)
            beat(_doing(nodes))
            if parent_gone():  # its SIGTERM was missed: the launcher is gone all the same
                break
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except OSError as exc:
        if not is_disk_full(exc):
            raise
        # one line naming the file; a supervisor does not restart this status (a new
        # process would hit the same full disk)
        name = nodes[0].get_name() if nodes else parser.prog
        print(f"{name}: {DISK_FULL_TAG}: cannot write {exc.filename or '?'} "
              f"({exc.strerror}); what was written before is kept", file=sys.stderr,
              flush=True)
        Exit.code = DISK_FULL
    finally:
        bound_the_stop()  # the teardown below, and the interpreter's exit after it
        _linger(ex, nodes)
        for n in nodes:
            n.destroy_node()
        rclpy.try_shutdown()
    return Exit.code


def _doing(nodes: list[Node]) -> str | None:
    """What the first node that says so does now (its ``doing`` attribute: a robot's
    trial and sample), for the heartbeat; None: unchanged."""
    for n in nodes:
        doing = getattr(n, "doing", None)
        if doing:
            return str(doing() if callable(doing) else doing)
    return None


def _linger(ex: Any, nodes: list[Node]) -> None:
    """Before a stopping process tears its nodes down: spin for the longest ``linger`` [s]
    its nodes ask for, so that what has arrived is still taken (the recorder: a trial's
    trajectories that came just before its launcher was killed reach the file)."""
    linger = max((float(getattr(n, "linger", 0.0)) for n in nodes), default=0.0)
    if ex is None or linger <= 0 or Exit.code == DISK_FULL or not rclpy.ok():
        return
    try:
        ex.spin_until_future_complete(Future(), timeout_sec=linger)
    except Exception:  # noqa: BLE001 - a teardown goes on whatever the last callbacks do
        pass
