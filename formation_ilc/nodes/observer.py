"""The observer: what the formation should be, next to what it does, on topics.

Not a node of its own: the recorder hosts it (``formation_ilc.nodes.recorder``), or the live
view's bridge when nothing records (``formation_ilc.nodes.liveview``), since both already
take every measured pose. Per measured pose it publishes the robot's desired pose and its
tracking error, at a marker sample (``protocol.view.marker_every``) once the whole team's
poses are in the 3D view's markers; at a trial's start each robot's desired path (latched);
once a trial's every pose is in, each robot's largest errors of the trial
(``msgs_schema.view_topic_table``; the numbers from ``formation_ilc.protocol.view``). Every
message is serialized once, published as those bytes and handed to ``sink`` (the recorder
writes it into its file, the bridge to its viewers): the robots and the plant are untouched
and no sample waits for it. A per-sample topic is published on DDS only while some reader
there takes it (checked every ``LISTENERS_EVERY`` seconds), as ``rviz`` and the live view do
on demand; the latched ones (paths, trial errors) always, for late joiners.

``sampled`` (the live view fed by the plant's preview, ``msgs_schema.PREVIEW``): the poses
come a few samples a second, the whole team's of a sample at once; markers go out at each,
and the trial errors come from the robots' whole-trial trajectories instead.
"""

from __future__ import annotations

import importlib
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy
from rclpy.serialization import serialize_message
from std_msgs.msg import String

import msgs_schema as ms
from formation_ilc.config.runconfig import RunConfig
from formation_ilc.config.urdf import body_of
from formation_ilc.core.clock import Rejected
from formation_ilc.protocol.schedule import TrialEvent, is_repeat, sealed
from formation_ilc.protocol.view import TrackingView, graph_links, marker_every, outline_order
from formation_ilc.recordings import cdr

#: sink(relative topic, CDR bytes, send label [ns]) of every message the observer publishes
Sink = Callable[[str, bytes, int], None]
#: how often [s] the observer asks DDS which of its per-sample topics have readers
LISTENERS_EVERY = 0.5


def msg_class(type_name: str) -> Any:
    """The message class of ``pkg/msg/Name``."""
    pkg, _, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


class Observer:
    """Publishes the view topics of a run (``cfg``) on ``node``; see the module doc."""

    def __init__(self, node: Node | None, cfg: RunConfig, sink: Sink | None = None,
                 gate: Callable[[str], bool] | None = None, *, sampled: bool = False,
                 key: bytes | None = None):
        """``node`` None: no publishers, every message only goes to ``sink`` (the batch
        simulator's recording). ``gate(topic)``: whether the sink takes this per-sample
        message (the live view's rate; asked once per message, None: it takes all).
        ``sampled``: the poses come a few samples at a time, the whole team's of each at
        once (the plant's preview, ``msgs_schema.PREVIEW``): markers at every such sample,
        and the trial errors from the robots' trajectories (:meth:`take` of
        ``robot_i/trajectory``), not from every pose."""
        sc = cfg.scenario
        self.cfg, self.clock, self.sink, self.gate = cfg, cfg.clock, sink, gate
        #: the run key: only the leader's sealed events move the view
        self.key = key
        self.sampled = sampled
        eta_d = sc.desired.eta
        self.view = TrackingView(eta_d, 1 if sampled else marker_every(sc.dt))
        self.outline = outline_order(eta_d[:, 0])
        src, _ = sc.graph.in_links()
        self.links = graph_links(src)
        self.pubs: dict[str, Any] = {}
        #: per-sample topics (volatile): published only while they have a reader
        self.on_demand: set[str] = set()
        for topic, type_name, qos in ms.view_topic_table(sc.n) if node is not None else ():
            self.pubs[topic] = node.create_publisher(  # type: ignore[union-attr]
                msg_class(type_name), topic, qos)
            if qos.durability != DurabilityPolicy.TRANSIENT_LOCAL:
                self.on_demand.add(topic)
        self._heard: set[str] = set()
        self._heard_at = -math.inf
        self.iteration_of: dict[int, int] = {}
        #: (slot, seq) of the last start (seq -1: none, or an abort since): the leader
        #: repeats it while its slot does not move
        self._start = (-1, -1)
        #: what the observer reads: each robot's measured pose (topic -> robot index)
        self.pose_topics = {ms.pose_topic(i + 1): i for i in range(sc.n)}
        #: sampled: each robot's trajectory (topic -> robot index), and those of a slot so far
        self.trajectory_topics = ({ms.trajectory_topic(i + 1): i for i in range(sc.n)}
                                  if sampled else {})
        self._trials: dict[int, dict[int, Any]] = {}
        # CDR templates: the desired pose of every robot and sample, an error message
        self._desired = [[serialize_message(ms.pose_to_msg(eta_d[r, s], 0, ms.WORLD_FRAME))
                          for s in range(eta_d.shape[1])] for r in range(sc.n)]
        self._error = serialize_message(ms.vector_msg(0, 0.0, 0.0))
        # each robot's footprint and heading in its own frame (the body of config.urdf)
        b = body_of(cfg.safety.body if cfg.safety is not None else "p3dx")
        self._markers = ms.MarkersTemplate(sc.n, self.outline, self.links,
                                           (b.length, b.width, b.body_x))

    def listened(self) -> set[str]:
        """The per-sample topics that some DDS reader takes (asked at most every
        ``LISTENERS_EVERY`` seconds)."""
        now = time.monotonic()
        if now - self._heard_at >= LISTENERS_EVERY:
            self._heard_at = now
            self._heard = {t for t in self.on_demand if self.pubs[t].get_subscription_count()}
        return self._heard

    def _to(self, topic: str) -> tuple[bool, bool]:
        """Where a per-sample message of ``topic`` goes now: (published on DDS, to the
        sink)."""
        pub = topic in self.pubs and (topic not in self.on_demand or topic in self.listened())
        return pub, self.sink is not None and (self.gate is None or self.gate(topic))

    def _send(self, topic: str, data: bytes, stamp_ns: int,
              to: tuple[bool, bool] | None = None) -> None:
        """Publish and sink a message; ``to`` from :meth:`_to` (None: a latched or
        per-trial one, which goes everywhere)."""
        pub, sink = to if to is not None else (topic in self.pubs, self.sink is not None)
        if pub:
            self.pubs[topic].publish(data)
        if sink and self.sink is not None:
            self.sink(topic, data, stamp_ns)

    def _emit(self, topic: str, msg: Any, stamp_ns: int) -> None:
        self._send(topic, serialize_message(msg), stamp_ns)

    def take(self, topic: str, data: bytes) -> None:
        """A message its host received, as CDR: a trial event or a robot's pose is observed,
        any other topic ignored; Rejected if it cannot be read."""
        if topic == ms.TRIAL_EVENTS:
            ev = TrialEvent.from_json(ms.msg_to_json(ms.deserialize(data, String),
                                                     ("event", "trial")))
            if not sealed(ev, self.key) or ev.run and ev.run != self.cfg.run_id:
                raise Rejected("foreign", f"{ev.event} not sealed by this run's leader")
            self.on_event(ev)
        elif topic in self.pose_topics:
            self.on_pose(self.pose_topics[topic], data)
        elif topic in self.trajectory_topics:
            self.on_trajectory(self.trajectory_topics[topic], data)

    def on_event(self, ev: TrialEvent) -> None:
        """A trial event: a start publishes the desired paths (once: a repeat of it is no
        news); an abort forgets the slot."""
        if ev.event == ms.START:
            if is_repeat(ev, *self._start):
                return
            self._start = (ev.slot, ev.seq)
            ev.agree(self.clock)
            self.iteration_of[ev.slot] = ev.trial
            stamps = [self.clock.stamp_ns(ev.slot, s) for s in range(self.view.samples + 1)]
            for r in range(self.view.n):  # the bytes trajectory_to_path serializes to
                path = cdr.encode_path(self.view.eta_d[r], np.array(stamps), ms.WORLD_FRAME,
                                       stamps[-1])
                self._send(ms.desired_path_topic(r + 1), path, stamps[0])
        elif ev.event == ms.ABORT:
            self._start = (-1, -1)
            self.view.forget(ev.slot)

    def on_pose(self, r: int, data: bytes) -> None:
        """Robot r's (0-based) measured pose, as received (CDR); MalformedMessage (a
        Rejected) if it is not a world pose of a sample."""
        eta, stamp = ms.world_pose_cdr(bytes(data))
        slot, s = self.clock.decode(stamp)
        pos, head = self.view.observe(slot, r, s, eta)
        i = r + 1
        # a per-sample message is built only if it goes somewhere
        if any(to := self._to(topic := ms.desired_pose_topic(i))):
            self._send(topic, ms.stamped_cdr(self._desired[r][s], stamp), stamp, to)
        if any(to := self._to(topic := ms.tracking_error_topic(i))):
            self._send(topic, ms.vector_cdr(self._error, stamp, pos, head, 0.0), stamp, to)
        team = self.view.position(slot, r, s, eta)
        if team is not None and any(to := self._to(ms.MARKERS)):
            self._send(ms.MARKERS, self._markers.cdr(stamp, self.view.eta_d[:, s, :2], team),
                       stamp, to)
        if s == self.view.samples and not self.sampled:
            self._trial_end(slot, stamp)

    def on_trajectory(self, r: int, data: bytes) -> None:
        """Robot r's (0-based) measured trajectory of a trial (sampled): once the whole
        team's of a slot are in, their trial errors. MalformedMessage if it is not a world
        trajectory of one trial's samples."""
        v = self.view
        slot, eta, stamps = ms.trial_trajectory(data, self.clock, v.eta_d[r, :, 2])
        got = self._trials.setdefault(slot, {})
        got[r] = eta
        if len(got) == v.n:
            del self._trials[slot]
            self.whole_trial(slot, np.stack([got[i] for i in range(v.n)]), int(stamps[-1]))
        for old in sorted(self._trials)[:-4]:  # slots whose team never completed
            del self._trials[old]

    def _trial_end(self, slot: int, stamp: int) -> None:
        peaks = self.view.trial_peaks(slot)
        if peaks is not None:
            self._trial_errors(slot, peaks, stamp)

    def whole_trial(self, slot: int, eta: Any, stamp: int) -> None:
        """A trial's measured outputs (N, T+1, 3) all at once, none of its poses observed
        (the batch simulator's trials without per-sample topics): its trial errors."""
        self._trial_errors(slot, self.view.whole_trial_peaks(eta), stamp)

    def _trial_errors(self, slot: int, peaks: list[Any], stamp: int) -> None:
        trial = self.iteration_of.get(slot, slot)
        for r, pk in enumerate(peaks):
            self._emit(ms.trial_error_topic(r + 1),
                       ms.vector_msg(stamp, pk.position, pk.heading, float(trial)), stamp)
        self.view.forget(slot)


def sim_recorder(path: Any, sc: Any, sample_trials: Any, first_trial: int) -> Any:
    """A ``SimRecorder`` (``formation-ilc simulate --record``) writing what the stack's
    recorder writes: the schema's topics with their types and QoS, and this observer's."""
    from formation_ilc.recordings.recording import SimRecorder

    rec = SimRecorder(path, sc, ms.recorder_table(sc.n), sample_trials=sample_trials,
                      first_trial=first_trial)
    rec.observe(lambda cfg, sink: Observer(None, cfg, sink))
    return rec
