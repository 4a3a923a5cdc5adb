"""Live view: the running formation served to Foxglove over its WebSocket protocol.

A bridge, started by ``formation-ilc launch --live [PORT]``: it subscribes to every topic a
recording holds (``msgs_schema.topic_table`` and ``view_topic_table``) as raw CDR and
forwards those bytes unchanged on a ``foxglove-sdk`` WebSocket server, one channel per topic
with the type's ``ros2msg`` definition (the schemas of the recording, from
``formation_ilc.recordings.mcap_io.message_definition``). Open ``ws://127.0.0.1:PORT`` in
Foxglove (docs/ros-tools.md).

It never holds the run back: its subscriptions to per-sample topics are best effort (a
bridge that falls behind loses samples, the writers never wait for it), it runs below the
control loop's priority (like the recorder), and the server keeps at most
``BACKLOG`` messages per viewer, dropping the oldest for a slow viewer; a viewer that goes
away is simply gone. With ``--observe`` (a launch that does not record) it publishes the
desired poses, errors and markers itself (``formation_ilc.nodes.observer``); otherwise the
recorder does and it forwards them.

  formation-ilc-liveview [--host 127.0.0.1] [--port 8765] [--observe] [--ros-args ...]
"""

from __future__ import annotations

import os
import sys
import time
from typing import Any

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

import msgs_schema as ms
from formation_ilc.core.clock import Rejected
from formation_ilc.core.names import LIVEVIEW_NODE
from formation_ilc.nodes.common import DropCounter, RunConfig, node_parser, spin_main
from formation_ilc.nodes.observer import Observer, msg_class
from formation_ilc.recordings.mcap_io import message_definition

#: the default port of the live view (Foxglove's own default)
DEFAULT_PORT = 8765
#: messages kept per viewer before the oldest are dropped (a slow viewer loses data)
BACKLOG = 4096
#: niceness: the view must not take CPU from the control loop
NICENESS = 10
#: per-sample topics: a bridge that falls behind loses samples; the writers never wait
_VIEWER_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                         reliability=ReliabilityPolicy.BEST_EFFORT,
                         durability=DurabilityPolicy.VOLATILE)


def _reader_qos(offered: QoSProfile) -> QoSProfile:
    if offered.durability == DurabilityPolicy.TRANSIENT_LOCAL:
        return ms.LATCHED_READER_QOS  # config, ready, diagnostics, paths: the last word
    return _VIEWER_QOS


class LiveViewNode(Node):
    def __init__(self, start_server: Any, observe: bool = False, **kwargs: Any):
        kwargs.setdefault("namespace", ms.NAMESPACE)
        super().__init__(LIVEVIEW_NODE, **kwargs)
        import foxglove

        self.foxglove = foxglove
        # the server starts once every channel of the run exists: a client then gets them in
        # one advertisement (a channel made while a client subscribed was, at times, unknown
        # to the server when the client's subscription reached it, which closed the link)
        self.start_server = start_server
        self.server: Any = None
        self.observe = observe
        self.drops = DropCounter(self)
        self.channels: dict[str, Any] = {}
        self.subs: dict[str, Any] = {}
        self.observer: Observer | None = None
        self.cfg: RunConfig | None = None
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
        if topic in self.subs:
            return
        ch = self._channel(topic, type_name)
        self.subs[topic] = self.create_subscription(
            msg_class(type_name), topic, lambda data, t=topic, c=ch: self._on(t, c, data),
            _reader_qos(qos), raw=True)

    def _on(self, topic: str, channel: Any, data: bytes) -> None:
        channel.log(data, log_time=time.time_ns())
        if topic == ms.CONFIG and self.cfg is None:
            self._configure(data)
        elif self.observer is not None:
            try:
                self.observer.take(topic, data)
            except Rejected as exc:
                self.drops.reject(exc, topic)

    def _view_sink(self, topic: str, data: bytes, stamp: int) -> None:
        self.channels[topic].log(data, log_time=time.time_ns())

    def _configure(self, data: bytes) -> None:
        try:
            self.cfg = RunConfig.from_json(ms.msg_to_json(ms.deserialize(data, String)))
        except Rejected as exc:
            self.drops.reject(exc, ms.CONFIG)
            return
        n = self.cfg.scenario.n
        for topic, type_name, qos in ms.topic_table(n):
            self._forward(topic, type_name, qos)
        for topic, type_name, qos in ms.view_topic_table(n):
            if self.observe:
                self._channel(topic, type_name)
            else:
                self._forward(topic, type_name, qos)
        if self.observe:
            self.observer = Observer(self, self.cfg, self._view_sink)
        self.server = self.start_server()
        self.get_logger().info(f"serving {len(self.channels)} topics on port "
                               f"{self.server.port}")


def main(args: list[str] | None = None) -> int:
    parser = node_parser("formation-ilc-liveview", __doc__)
    parser.add_argument("--host", default="127.0.0.1",
                        help="address to serve on (default 127.0.0.1: this machine only)")
    parser.add_argument("--port", type=int, default=DEFAULT_PORT,
                        help=f"WebSocket port (default {DEFAULT_PORT})")
    parser.add_argument("--observe", action="store_true",
                        help="publish the desired poses, errors and markers here (when no "
                             "recorder does)")
    if os.environ.get("FORMATION_ILC_LIVEVIEW_SCHED", "nice") != "normal":
        os.nice(NICENESS)  # before rclpy's threads start: they inherit it

    def build(ns: Any, argv: list[str]) -> list[Node]:
        import socket

        import foxglove

        def start() -> Any:
            try:
                return foxglove.start_server(name="formation-ilc", host=ns.host,
                                             port=ns.port, message_backlog_size=BACKLOG)
            except Exception as exc:  # noqa: BLE001 - the SDK's own error type: port in use
                print(f"error: cannot serve on {ns.host}:{ns.port}: {exc}", file=sys.stderr)
                raise SystemExit(2) from None

        try:  # a taken port is refused at once, before the run's channels exist
            with socket.socket(socket.AF_INET6 if ":" in ns.host else socket.AF_INET) as s:
                s.bind((ns.host, ns.port))
        except OSError as exc:
            print(f"error: cannot serve on {ns.host}:{ns.port}: {exc.strerror}",
                  file=sys.stderr)
            raise SystemExit(2) from None
        return [LiveViewNode(start, observe=ns.observe)]

    return spin_main(build, parser, args)


if __name__ == "__main__":
    sys.exit(main())
