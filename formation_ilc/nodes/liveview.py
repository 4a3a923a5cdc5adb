"""Live view: the running formation served to Foxglove over its WebSocket protocol.

A bridge, started by ``formation-ilc launch --live [PORT]``: it offers every topic a
recording holds (``msgs_schema.topic_table`` and ``view_topic_table``), one channel per topic
with the type's ``ros2msg`` definition (the schemas of the recording, from
``formation_ilc.recordings.mcap_io.message_definition``), and forwards the raw CDR bytes it
takes unchanged. Open ``ws://127.0.0.1:PORT`` in Foxglove (docs/ros-tools.md).

Like Foxglove's own ROS bridge it subscribes to a per-sample topic only while a viewer
subscribes to its channel (or to a view topic computed from it): with no viewer, or a viewer
that shows two robots, it takes nothing else off the run. The latched and per-trial topics
(configuration, readiness, diagnostics, paths, trial events) it always takes.

With ``--preview`` (the plant is the simulator or the physics plant, which publish one) and
a rate up to ``msgs_schema.PREVIEW_HZ``, the robots' poses come from the plant's preview
instead: one message of the whole team's poses of a sample, at most PREVIEW_HZ a second,
which the bridge splits onto the robots' pose channels (the bytes the plant sent on
robot_i/pose) and from which it computes the desired poses, errors and markers (also with a
recorder, then for its viewers only); the trial errors come from the robots' trajectories.
A lockstep run makes hundreds of samples a second per robot; taking each off DDS in Python
cost the run a fifth of its speed.

It never holds the run back: its subscriptions to per-sample topics are best effort (a
bridge that falls behind loses samples, the writers never wait for it), it runs below the
control loop's priority (like the recorder), and the server keeps at most
``BACKLOG`` messages per viewer, dropping the oldest for a slow viewer; a viewer that goes
away is simply gone. With ``--observe`` (a launch that does not record) it computes the
desired poses, errors and markers itself (``formation_ilc.nodes.observer``); otherwise the
recorder does and it forwards them.

Its parameters capability shows every node's parameters read-only, named as
foxglove_bridge names them (``/formation/robot_1.robot``): each node of the run's namespace
is asked once, through its standard parameter services, for all of its parameters; the
run's configuration is listed under the leader (``/formation/virtual_leader.seed``;
``protocol.view.run_parameters``) from the start. A viewer's Parameters panel lists them,
and a change asked for is answered with the value the run keeps (the run's configuration
is fixed once its nodes started).

A viewer that joins in the middle of a trial gets that trial's start event at once (the
last ``start`` on the trial events' channel), as it gets the latched topics' last messages,
instead of learning which trial runs only at the next event.

  formation-ilc-liveview [--host 127.0.0.1] [--port 8765] [--rate HZ] [--observe]
                         [--preview] [--ros-args ...]
"""

from __future__ import annotations

import os
import sys
import threading
import time
from collections import Counter
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

import msgs_schema as ms
from formation_ilc.config.option_table import LIVE_PORT
from formation_ilc.core.clock import Rejected
from formation_ilc.core.names import LIVEVIEW_NODE
from formation_ilc.nodes.common import DropCounter, RunConfig, node_parser, run_key, spin_main
from formation_ilc.nodes.observer import Observer, msg_class
from formation_ilc.nodes.params import declare
from formation_ilc.protocol.view import run_parameters
from formation_ilc.recordings.mcap_io import message_definition

#: the default port of the live view (Foxglove's own default)
DEFAULT_PORT = LIVE_PORT
#: messages kept per viewer before the oldest are dropped (a slow viewer loses data)
BACKLOG = 4096
#: niceness: the view must not take CPU from the control loop
NICENESS = 10
#: messages a second forwarded per per-sample channel by default (what a screen shows; a
#: lockstep run makes several hundred samples a second per robot)
DEFAULT_RATE = 30.0
#: how soon [s] the subscriptions follow a viewer's (the server's thread only flags it: the
#: EventsExecutor takes no guard conditions)
FOLLOW = 0.1
#: the most writers a latched channel keeps a last message of (readies, diagnostics)
LATCHED_WRITERS = 256
#: how often [s] the bridge also looks whether DDS readers take the view topics it computes
RECHECK = 1.0
#: how often [s] it looks for nodes whose parameters it has not read yet
PARAMS_EVERY = 2.0
#: per-sample topics: a bridge that falls behind loses samples; the writers never wait
_VIEWER_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                         reliability=ReliabilityPolicy.BEST_EFFORT,
                         durability=DurabilityPolicy.VOLATILE)


def _reader_qos(offered: QoSProfile) -> QoSProfile:
    if offered.durability == DurabilityPolicy.TRANSIENT_LOCAL:
        return ms.LATCHED_READER_QOS  # config, ready, diagnostics, paths: the last word
    return _VIEWER_QOS


class _Viewers:
    """The server's listener: which channels viewers subscribe to (foxglove ServerListener;
    called on the server's thread)."""

    def __init__(self, node: LiveViewNode):
        self.node = node

    def on_subscribe(self, client: Any, channel: Any) -> None:
        self.node.viewers_want(channel.topic, +1, client.id)

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        self.node.viewers_want(channel.topic, -1)

    def on_get_parameters(self, client: Any, param_names: list[str],
                          request_id: str | None = None) -> list[Any]:
        return self.node.parameters(param_names)

    def on_set_parameters(self, client: Any, parameters: list[Any],
                          request_id: str | None = None) -> list[Any]:
        # read-only: each asked for as the run keeps it
        return self.node.parameters([p.name for p in parameters])


class LiveViewNode(Node):
    def __init__(self, start_server: Any, observe: bool = False, rate: float = DEFAULT_RATE,
                 preview: bool = False, **kwargs: Any):
        kwargs.setdefault("namespace", ms.NAMESPACE)
        super().__init__(LIVEVIEW_NODE, **kwargs)
        declare(self, ())  # no parameters of its own; a misspelt one is refused
        import foxglove

        self.foxglove = foxglove
        # the server starts once every channel of the run exists: a client then gets them in
        # one advertisement (a channel made while a client subscribed was, at times, unknown
        # to the server when the client's subscription reached it, which closed the link)
        self.start_server = start_server
        self.server: Any = None
        self.observe = observe
        #: per-sample channels forward at most one message per ``1/rate`` s (0: every one)
        self.period = 1.0 / rate if rate > 0 else 0.0
        #: the robots' poses come from the plant's preview (it publishes one, and the rate
        #: asks no more of them than it gives): the view computes its topics from those
        self.sampled = preview and 0 < rate <= ms.PREVIEW_HZ
        self._due: dict[str, float] = {}
        self.drops = DropCounter(self)
        self.channels: dict[str, Any] = {}
        self.subs: dict[str, Any] = {}
        self.observer: Observer | None = None
        self.cfg: RunConfig | None = None
        #: per-sample DDS topics taken on demand: topic -> (type, offered QoS)
        self.on_demand: dict[str, tuple[str, QoSProfile]] = {}
        #: channel (relative topic) -> the DDS topics it is made of
        self.sources: dict[str, frozenset[str]] = {}
        #: channel (absolute topic, as the server names it) -> viewers subscribed
        self.wanted: Counter[str] = Counter()
        self._lock = threading.Lock()
        self._changed = False
        #: latched channels (relative topic) -> the last message of each writer, as
        #: foxglove_bridge's per-client subscriptions give a late viewer (transient local)
        self.latched: dict[str, dict[str, bytes]] = {}
        #: (client id, absolute topic) of subscriptions that still get the latched state
        self._joined: list[tuple[int, str]] = []
        #: every node's parameters (full node name -> {name: value}), read once per node
        self.node_params: dict[str, dict[str, Any]] = {}
        self._param_clients: dict[str, Any] = {}
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(FOLLOW, self._follow, clock=steady)
        self.create_timer(RECHECK, self._reconcile, clock=steady)
        self.create_timer(PARAMS_EVERY, self._read_parameters, clock=steady)
        self._forward(ms.CONFIG, "std_msgs/msg/String", ms.LATCHED_QOS)

    def _channel(self, topic: str, type_name: str) -> Any:
        ch = self.channels.get(topic)
        if ch is None:
            fg = self.foxglove
            schema = fg.Schema(name=type_name, encoding="ros2msg",
                               data=message_definition(type_name).encode())
            ch = self.channels[topic] = fg.Channel(self.resolve_topic_name(topic),
                                                   schema=schema, message_encoding="cdr")
        return ch

    def _forward(self, topic: str, type_name: str, qos: QoSProfile) -> None:
        """Forward a DDS topic on its channel: at once if latched or per trial, else while
        a viewer wants it."""
        self._channel(topic, type_name)
        self.sources[topic] = frozenset({topic})
        if qos.durability == DurabilityPolicy.TRANSIENT_LOCAL or topic == ms.TRIAL_EVENTS:
            self.latched.setdefault(topic, {})  # trial events: the current trial's start
        if qos.durability == DurabilityPolicy.TRANSIENT_LOCAL or topic == ms.TRIAL_EVENTS:
            self._subscribe(topic, type_name, qos)
        else:
            self.on_demand[topic] = (type_name, qos)

    def _subscribe(self, topic: str, type_name: str, qos: QoSProfile) -> None:
        if topic in self.subs:
            return
        ch = self.channels.get(topic)

        def on(data: bytes) -> None:
            self._on(topic, ch, data)

        self.subs[topic] = self.create_subscription(msg_class(type_name), topic, on,
                                                    _reader_qos(qos), raw=True)

    def viewers_want(self, absolute: str, change: int, client: int | None = None) -> None:
        """A viewer subscribed (+1) to a channel or left it (-1): the subscriptions follow
        on the executor's thread, and a new subscriber gets the channel's latched state."""
        with self._lock:
            self.wanted[absolute] += change
            self._changed = True
            if change > 0 and client is not None:
                self._joined.append((client, absolute))

    def _follow(self) -> None:
        with self._lock:
            changed, self._changed = self._changed, False
            joined, self._joined = self._joined, []
        if changed:
            self._reconcile()
        for client, absolute in joined:
            self._send_latched(client, absolute)
        if self.server is not None:
            self.server.broadcast_time(time.time_ns())  # the time capability: log times

    def _send_latched(self, client: int, absolute: str) -> None:
        """The last message of each writer of a latched channel, to one new subscriber
        (the SDK logs to a single client by its id: ``sink_id``)."""
        for topic, last in self.latched.items():
            if self.resolve_topic_name(topic) != absolute:
                continue
            ch = self.channels.get(topic)
            for data in list(last.values()):
                ch.log(data, log_time=time.time_ns(), sink_id=client)

    def _keep(self, topic: str, data: bytes) -> None:
        """Keep ``data`` as the last word of its writer on a latched channel: readies and
        diagnostics have a writer per node (told apart by the node they name), the others
        one."""
        last = self.latched.get(topic)
        if last is None:
            return
        key = ""
        try:
            if topic == ms.TRIAL_EVENTS:
                event = ms.msg_to_json(ms.deserialize(data, String)).get("event")
                if event != ms.START:
                    return  # only the current trial's start is given to a late viewer
            elif topic == ms.READY:
                key = str(ms.msg_to_json(ms.deserialize(data, String)).get("node", ""))
            elif topic == ms.DIAGNOSTICS:
                from diagnostic_msgs.msg import DiagnosticArray

                sts = ms.deserialize(data, DiagnosticArray).status
                key = sts[0].name if sts else ""
        except Exception:  # noqa: BLE001 - a message that does not decode is not kept
            return
        if key not in last and len(last) >= LATCHED_WRITERS:
            return  # bounded: a flood of made-up writers keeps no more
        last[key] = data

    def _reconcile(self) -> None:
        """Take exactly the per-sample topics that the viewers' channels (and DDS readers of
        the view topics computed here) are made of."""
        with self._lock:
            viewed = {t for t, k in self.wanted.items() if k > 0}
        need: set[str] = set()
        for topic, made_of in self.sources.items():
            if self.resolve_topic_name(topic) in viewed:
                need |= made_of
        if self.observer is not None:
            for topic in self.observer.listened():
                need |= self.sources.get(topic, frozenset())
        for topic, (type_name, qos) in self.on_demand.items():
            if topic in need and topic not in self.subs:
                self._subscribe(topic, type_name, qos)
            elif topic not in need and topic in self.subs:
                self.destroy_subscription(self.subs.pop(topic))

    @staticmethod
    def _made_of(topic: str, poses: list[str], sampled: bool = False) -> list[str]:
        """The per-sample topics the observer computes a view topic from: none for a
        desired path (from the trial's start) and, sampled, for a trial error (from the
        trajectories, always taken); else the preview when sampled; else the whole team's
        poses (markers) or its robot's."""
        robot, _, kind = topic.partition("/")
        if ms.desired_path_topic(1).endswith("/" + kind):
            return []
        if sampled:
            return [] if ms.trial_error_topic(1).endswith("/" + kind) else [ms.PREVIEW]
        if topic == ms.MARKERS:
            return poses
        return [p for p in poses if p.partition("/")[0] == robot]

    def _take(self, topic: str) -> bool:
        """Whether a per-sample channel forwards a message now (its rate)."""
        if not self.period:
            return True
        now = time.monotonic()
        if now < self._due.get(topic, 0.0):
            return False
        self._due[topic] = now + self.period
        return True

    def _on(self, topic: str, channel: Any, data: bytes) -> None:
        if topic == ms.PREVIEW:
            self._on_preview(data)
            return
        if channel is not None and (topic not in self.on_demand or self._take(topic)):
            channel.log(data, log_time=time.time_ns())
        if topic in self.latched:
            self._keep(topic, data)
        if topic == ms.CONFIG and self.cfg is None:
            self._configure(data)
        elif self.observer is not None:
            try:
                self.observer.take(topic, data)
            except Rejected as exc:
                self.drops.reject(exc, topic)

    def _on_preview(self, data: bytes) -> None:
        """The team's poses of one sample: each on its robot's pose channel (the bytes the
        plant sent on robot_i/pose), and to the observer."""
        n = len(self.observer.pose_topics) if self.observer is not None else 0
        try:
            _, poses = ms.wire.read_pose_set(data, n)
        except Rejected as exc:
            self.drops.reject(exc, ms.PREVIEW)
            return
        for r, p in enumerate(poses):
            topic = ms.pose_topic(r + 1)
            pose = ms.wire.raw_pose_bytes(p)
            if self._take(topic):
                self.channels[topic].log(pose, log_time=time.time_ns())
            try:
                self.observer.take(topic, pose)  # type: ignore[union-attr]
            except Rejected as exc:
                self.drops.reject(exc, ms.PREVIEW)

    def _view_sink(self, topic: str, data: bytes, stamp: int) -> None:
        self.channels[topic].log(data, log_time=time.time_ns())
        if topic in self.latched:
            self._keep(topic, data)

    def parameters(self, names: list[str]) -> list[Any]:
        """The parameters ``names`` (none: all) of every node read so far and the run's
        configuration, as the server sends them; none before the configuration came (the
        server starts after it)."""
        if self.cfg is None:
            return []
        from foxglove.websocket import Parameter

        every = dict(run_parameters(self.cfg, self.get_namespace()))
        with self._lock:
            for node, params in self.node_params.items():
                every.update({f"{node}.{k}": v for k, v in params.items()})
        wanted = list(names)
        got = every if not wanted else {n: every[n] for n in wanted if n in every}
        return [Parameter(k, value=v) for k, v in sorted(got.items())]

    def _read_parameters(self) -> None:
        """Ask each node of the namespace not asked yet for all of its parameters (its
        standard list and get services, once they are matched; answers come on the
        executor's thread)."""
        from rclpy.parameter_client import AsyncParameterClient

        own = self.get_fully_qualified_name()
        for name, ns in self.get_node_names_and_namespaces():
            full = ms.absolute(name, ns)
            if ns != self.get_namespace() or full == own or full in self._param_clients:
                continue
            services = {s for s, _ in self.get_service_names_and_types_by_node(name, ns)}
            if f"{full}/list_parameters" in services:  # a node with parameter services
                self._param_clients[full] = [AsyncParameterClient(self, full), False]
        for full, entry in self._param_clients.items():
            client, asked = entry
            if not asked and client.services_are_ready():
                entry[1] = True
                client.list_parameters(
                    callback=lambda f, c=client, n=full: self._listed(c, n, f))

    def _listed(self, client: Any, node: str, future: Any) -> None:
        try:
            names = list(future.result().result.names)
        except Exception:  # noqa: BLE001 - a node that went away: its parameters unknown
            return
        client.get_parameters(names, callback=lambda f: self._got(node, names, f))

    def _got(self, node: str, names: list[str], future: Any) -> None:
        from rclpy.parameter import parameter_value_to_python

        try:
            values = future.result().values
        except Exception:  # noqa: BLE001
            return
        params: dict[str, Any] = {}
        for name, value in zip(names, values, strict=False):
            v = parameter_value_to_python(value)
            params[name] = list(v) if isinstance(v, (tuple, bytes)) or hasattr(v, "tolist") \
                else v
        with self._lock:
            self.node_params[node] = params

    def _configure(self, data: bytes) -> None:
        try:
            self.cfg = RunConfig.from_json(ms.msg_to_json(ms.deserialize(data, String)))
        except Rejected as exc:
            self.drops.reject(exc, ms.CONFIG)
            return
        n = self.cfg.scenario.n
        for topic, type_name, qos in ms.topic_table(n):
            if type_name == ms.TF_TYPE and ms.tf_message() is None:
                continue  # tf2_msgs not built (scripts/build_tf2_msgs.py): no frames
            self._forward(topic, type_name, qos)
        poses = [ms.pose_topic(i) for i in range(1, n + 1)]
        if self.sampled:  # every robot's pose channel, and all computed here, from one topic
            self.on_demand[ms.PREVIEW] = ("nav_msgs/msg/Path", ms.PREVIEW_QOS)
            for p in poses:
                self.sources[p] = frozenset({ms.PREVIEW})
        for topic, type_name, qos in ms.view_topic_table(n):
            if not (self.observe or self.sampled):
                self._forward(topic, type_name, qos)
                continue
            self._channel(topic, type_name)
            self.sources[topic] = frozenset(self._made_of(topic, poses, self.sampled))
            if qos.durability == DurabilityPolicy.TRANSIENT_LOCAL:
                self.latched.setdefault(topic, {})
        if self.observe or self.sampled:
            # with a recorder (which publishes the view topics on DDS) only to the viewers
            self.observer = Observer(self if self.observe else None, self.cfg,
                                     self._view_sink, gate=self._take, sampled=self.sampled,
                                     key=run_key())
        self.server = self.start_server(_Viewers(self))
        self.get_logger().info(f"serving {len(self.channels)} topics on port "
                               f"{self.server.port}")


def _port(text: str) -> int:
    """An argparse type: a TCP port 1..65535 (one line and status 2 otherwise)."""
    import argparse

    try:
        port = int(text, 10)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a port number, got {text!r}") from None
    if not 1 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"a port is in 1..65535, got {port}")
    return port


def _lower_priority() -> None:
    """Run below the control loop, before rclpy's threads start (they inherit it):
    FORMATION_ILC_LIVEVIEW_SCHED=nice (default: niceness ``NICENESS``), idle (SCHED_IDLE:
    only what the run leaves) or normal."""
    how = os.environ.get("FORMATION_ILC_LIVEVIEW_SCHED", "nice")
    if how == "idle":
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
    elif how != "normal":
        os.nice(NICENESS)


def main(args: list[str] | None = None) -> int:
    parser = node_parser("formation-ilc-liveview", __doc__)
    parser.add_argument("--host", default="127.0.0.1",
                        help="address to serve on (default 127.0.0.1: this machine only)")
    parser.add_argument("--port", type=_port, default=DEFAULT_PORT,
                        help=f"WebSocket port, 1..65535 (default {DEFAULT_PORT})")
    parser.add_argument("--rate", type=float, default=DEFAULT_RATE, metavar="HZ",
                        help=f"messages a second forwarded per per-sample topic (default "
                             f"{DEFAULT_RATE:g}; 0: every message). Latched and per-trial "
                             f"topics always go whole")
    parser.add_argument("--preview", action="store_true",
                        help=f"the plant publishes a preview of the team's poses "
                             f"({ms.PREVIEW}, at most {ms.PREVIEW_HZ:g} a second): at a rate "
                             f"up to that, take the robots' poses from it, not every sample")
    parser.add_argument("--observe", action="store_true",
                        help="publish the desired poses, errors and markers here (when no "
                             "recorder does)")
    _lower_priority()

    def build(ns: Any, argv: list[str]) -> list[Node]:
        import socket

        import foxglove

        def start(listener: Any) -> Any:
            try:
                return foxglove.start_server(
                    name="formation-ilc", host=ns.host, port=ns.port,
                    message_backlog_size=BACKLOG, server_listener=listener,
                    capabilities=[foxglove.Capability.Time,
                                  foxglove.Capability.Parameters])
            except Exception as exc:  # noqa: BLE001 - the SDK's own error type: port in use
                print(f"formation-ilc-liveview: cannot serve on {ns.host}:{ns.port}: {exc}",
                      file=sys.stderr)
                raise SystemExit(2) from None

        try:  # a taken port is refused at once, before the run's channels exist
            with socket.socket(socket.AF_INET6 if ":" in ns.host else socket.AF_INET) as s:
                # as the server binds it: a killed predecessor's connections in TIME_WAIT
                # do not hold the port (before, a restarted live view exited "Address
                # already in use" and stayed gone)
                s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                s.bind((ns.host, ns.port))
        except OSError as exc:
            print(f"formation-ilc-liveview: cannot serve on {ns.host}:{ns.port}: "
                  f"{exc.strerror}", file=sys.stderr)
            raise SystemExit(2) from None
        if not ns.rate >= 0:
            raise ValueError(f"--rate {ns.rate}: a rate >= 0 is required")
        return [LiveViewNode(start, observe=ns.observe, rate=ns.rate, preview=ns.preview)]

    return spin_main(build, parser, args)


if __name__ == "__main__":
    sys.exit(main())
