"""Recorder: every formation topic of a run into one MCAP file, as ROS 2 data.

The file is what rosbag2's MCAP storage writes (profile ``ros2``; schemas ``ros2msg`` with
their full definitions; messages as the CDR bytes received, never re-encoded; each
channel's offered QoS and type hash in its metadata), so ``ros2 bag`` and Foxglove open it.
Log time is the receive time (system clock, as rosbag2); publish time is the send label
(the header stamp) for stamped messages, else the receive time, and the receive time too
where the stamp is not a valid time (negative, or nanoseconds past 1e9): such messages are
recorded as they are and counted (``invalid_stamps`` in its diagnostics). The recorder
never stops on a message: one it cannot write is counted (``unwritable``) and logged.

It learns the run from the ``config`` topic (latched, recorded too, and copied into a
metadata record), subscribes to every topic of ``msgs_schema.topic_table``, and says ready
on ``ready`` once every topic with a single writer is matched, so a launcher
that waits for it loses no sample. When it holds a trial's every trajectory and every
robot's diagnostics of that trial, it says so on ``diagnostics``
(``{"node": "recorder", "trial": k}``), so a launcher knows when it may stop it. Only
trajectories and diagnostics of a trial the leader has started count toward that, each
once (everything is recorded all the same). Chunks are flushed every 0.5 s and at most
``CHUNK_BYTES`` long: a SIGKILL loses at most the chunk in progress, and damage to the
file loses the chunks it hits (``formation-ilc analyze`` reads on past them);
``formation-ilc mcap-repair`` writes a complete copy.

It hosts the observer (``formation_ilc.nodes.observer``): from each measured pose it
publishes and records the robot's desired pose, its tracking error and the markers, per
trial the desired paths and the largest errors (``msgs_schema.view_topic_table``);
``--no-view`` records without them.

  formation-ilc-recorder --output RUN.mcap [--ros-args ...]
"""

from __future__ import annotations

import importlib
import os
import struct
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile
from std_msgs.msg import String

import msgs_schema as ms
from formation_ilc.core.clock import Rejected
from formation_ilc.core.links import check_diagnostics
from formation_ilc.nodes.common import (
    Diagnostics,
    DropCounter,
    RunConfig,
    node_parser,
    run_key,
    spin_main,
)
from formation_ilc.nodes.observer import Observer
from formation_ilc.nodes.params import declare
from formation_ilc.protocol.schedule import Ready, TrialEvent, sealed
from formation_ilc.recordings.bagmeta import METADATA, write_bag_metadata
from formation_ilc.recordings.mcap_io import CHUNK_BYTES, RosMcapWriter, type_hash
from formation_ilc.recordings.recording import (
    CHANNEL_META,
    META_NAME,
    qos_of,
    recording_parts,
    root_of,
    run_metadata,
)
from formation_ilc.system.exits import is_disk_full

#: types whose CDR starts with a header stamp (int32 sec, uint32 nanosec) right after the
#: 4-byte encapsulation: their publish time is that send label
_STAMPED = {"geometry_msgs/msg/PoseStamped", "nav_msgs/msg/Path", "rosgraph_msgs/msg/Clock",
            "geometry_msgs/msg/Vector3Stamped"}
#: reader queue depth of the recorder's subscriptions [messages per topic]
_READER_DEPTH = 20000
#: niceness of the recorder: recording must not take CPU from the control loop, nor fall
#: behind it for good (see _lower_priority)
NICENESS = 5
#: topics written by many nodes (not waited for before saying ready)
_MANY_WRITERS = {ms.READY, ms.DIAGNOSTICS}
#: topics recorded when written, never waited for: the e-stop, the frames, the bodies
_UNWAITED = {ms.ESTOP, ms.TF, ms.TF_STATIC}
_UNWAITED_KIND = "/robot_description"


def _msg_class(type_name: str) -> Any:
    pkg, _, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


class RecorderNode(Node):
    def __init__(self, output: Path, observe: bool = True, **kwargs: Any):
        kwargs.setdefault("namespace", ms.NAMESPACE)
        super().__init__(ms.RECORDER_NODE, **kwargs)
        declare(self, ())  # no parameters of its own; use_sim_time refused
        self.output = Path(output)
        #: this process in its ready (the launcher's ``down`` names it by its pid)
        self.boot = f"{os.getpid()}"
        #: the run key: events it did not seal are recorded, never counted
        self.key = run_key()
        #: [s] when the process stops, what has arrived until then is still recorded
        #: (``nodes.common.spin_main``): a trial that ended just before its launcher was
        #: killed reaches the file
        self.linger = 0.5
        self.writer = RosMcapWriter(self.output, flush_period=0.5, chunk_size=int(
            os.environ.get("FORMATION_ILC_RECORDER_CHUNK_BYTES", CHUNK_BYTES)))
        self.drops = DropCounter(self)      # not counted toward progress (still recorded)
        self.invalid_stamps: Counter[str] = Counter()
        self.unwritable: Counter[str] = Counter()
        self.started = -1                   # the last slot the leader started
        self.types: dict[str, str] = {}
        self.qos: dict[str, Any] = {}
        self.subs: dict[str, Any] = {}
        self.names: dict[str, str] = {}      # schema name -> full channel name
        self.cfg: RunConfig | None = None
        self.path_topics: set[str] = set()
        self.progress_topics: set[str] = set()  # what _progress reads (once configured)
        self.said_ready = False
        self.ready_pub = self.create_publisher(String, ms.READY, ms.LATCHED_QOS)
        self.diag_pub = Diagnostics(self)  # per-trial report and /diagnostics
        self.paths: dict[int, set[str]] = {}  # slot -> topics of its trajectories recorded
        self.iteration_of: dict[int, int] = {}  # slot -> iteration (start events)
        self.aborted: set[int] = set()
        self.recorded: set[int] = set()  # iterations whose trajectories are all in the file
        self.robot_diag: dict[str, int] = {}  # robot -> last trial of its diagnostics
        self.complete = -1
        self.truth = True
        self.robots: set[str] = set()
        #: the view topics (desired poses, errors, markers) from the poses it records
        self.observe = observe
        self.observer: Observer | None = None
        self._subscribe(ms.CONFIG, "std_msgs/msg/String", ms.LATCHED_QOS)
        self.create_timer(0.5, self.writer.flush)  # idle periods too
        self._gate = self.create_timer(0.05, self._check_ready)
        self.get_logger().info(f"recording to {self.output}")

    def _subscribe(self, topic: str, type_name: str, qos: Any) -> None:
        if topic in self.subs:
            return
        try:
            cls = _msg_class(type_name)
        except (ImportError, AttributeError):  # tf2_msgs not built: no frames to record
            self.get_logger().warning(f"{topic} not recorded: {type_name} is not installed")
            return
        self.types[topic] = type_name
        self.qos[topic] = qos
        if topic in _MANY_WRITERS:
            reader_qos = ms.LATCHED_READER_QOS
        else:
            # a deep reader queue: the recorder runs at a lower CPU priority than the
            # control loop (see main) and may fall behind for a moment, never lose a sample
            reader_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=_READER_DEPTH,
                                    reliability=qos.reliability, durability=qos.durability)
        self.subs[topic] = self.create_subscription(
            cls, topic, lambda data, t=topic: self._on(t, data), reader_qos,
            raw=True)

    def _channel(self, topic: str, extra: dict[str, str] | None = None) -> str:
        """The channel of a topic, by its full name (namespace and remappings resolved),
        with the offered QoS and type hash of the writer, as rosbag2 records them (and
        ``extra`` metadata)."""
        name = self.resolve_topic_name(topic)
        info = self.get_publishers_info_by_topic(name)
        qos = info[0].qos_profile if info else self.qos[topic]
        type_hash = str(info[0].topic_type_hash) if info else ""
        self.writer.channel(name, self.types[topic], qos_of(qos), type_hash, extra)
        self.names[topic] = name
        return name

    def _run_meta(self, data: bytes) -> dict[str, str]:
        """What an analysis cannot do without, from the run configuration's message (its
        JSON, its topic, the run key of the events), or {} for one that does not read."""
        try:
            conf = ms.msg_to_json(ms.deserialize(data, String))
            RunConfig.from_json(conf)
        except (Rejected, ValueError):
            return {}
        meta = run_metadata(conf, self.resolve_topic_name(ms.CONFIG), self.key)
        return {CHANNEL_META + k: v for k, v in meta.items() if k != "topic"}

    def _on(self, topic: str, data: bytes) -> None:
        now = time.time_ns()
        try:
            sent = self._publish_time(topic, data, now)
            name = self.names.get(topic)
            if name is None:
                # the configuration's channel carries the configuration itself too: its
                # copies outside the chunks and in the summary keep it when a chunk is lost
                name = self._channel(topic, self._run_meta(data) if topic == ms.CONFIG
                                     else None)
            self.writer.write(name, data, now, sent)
        except Exception as exc:  # noqa: BLE001 - a recorder must outlive any one message
            if is_disk_full(exc):
                raise  # not one message: nothing more can be recorded (spin_main says so)
            self.unwritable[topic] += 1
            if self.unwritable[topic] <= 3:
                self.get_logger().error(f"could not record a message on {topic}: {exc!r}")
            return
        if topic == ms.CONFIG and self.cfg is None:
            self._configure(data)
        elif topic == ms.READY and self.said_ready and len(data) < 4096:
            self._refute_down(data)
        elif topic in self.progress_topics:
            try:
                self._progress(topic, data, sent)
            except Rejected as exc:
                self.drops.reject(exc, topic)
        if self.observer is not None:
            self._observe(topic, data)

    def _observe(self, topic: str, data: bytes) -> None:
        """The observer's view of a pose or trial event; it never stops the recording."""
        assert self.observer is not None
        try:
            self.observer.take(topic, data)
        except Rejected:
            pass  # counted where the message is read for the run (or a pose: by its robot)
        except Exception as exc:  # noqa: BLE001 - the view must not cost the recording
            if is_disk_full(exc):
                raise
            self.unwritable["observer"] += 1
            if self.unwritable["observer"] <= 3:
                self.get_logger().error(f"observer: {exc!r}")

    def _write_view(self, topic: str, data: bytes, stamp: int) -> None:
        """Record a message the observer published (as rosbag2 would have received it)."""
        name = self.names.get(topic)
        if name is None:
            name = self.names[topic] = self.resolve_topic_name(topic)
            self.writer.channel(name, self.types[topic], qos_of(self.qos[topic]),
                                type_hash(self.types[topic]))
        self.writer.write(name, data, time.time_ns(), stamp)

    def _refute_down(self, data: bytes) -> None:
        """A ``down`` for this very process (the launcher says so only of a recorder that
        died): a forgery or a mistake, which would make the leader wait for a recorder
        that is alive and has said ready. It says ready again."""
        try:
            r = Ready.from_json(ms.msg_to_json(ms.deserialize(data, String)))
        except Rejected:
            return
        if r.down and r.node == ms.RECORDER_NODE and r.boot == self.boot:
            self.drops.drop("unexpected", ms.READY, f"'down' of this live recorder ({r.boot})")
            self.ready_pub.publish(self._ready_msg())

    def _ready_msg(self) -> String:
        assert self.cfg is not None
        # ready for every trial of the run: it only watches (formation_ilc.protocol.schedule)
        return ms.json_to_msg({"node": ms.RECORDER_NODE, "passive": True,
                               "trial": self.cfg.scenario.trials, "boot": self.boot,
                               "run": self.cfg.run_id})

    def _publish_time(self, topic: str, data: bytes, now: int) -> int:
        """The send label of a stamped message, else (or if it is no valid time) ``now``."""
        if self.types[topic] not in _STAMPED:
            return now
        if len(data) < 12:
            self.invalid_stamps[topic] += 1
            return now
        sec, nsec = struct.unpack_from("<iI", data, 4)
        if sec < 0 or nsec >= 1_000_000_000:
            self.invalid_stamps[topic] += 1
            if self.invalid_stamps[topic] <= 3:
                self.get_logger().warning(f"{topic}: invalid stamp ({sec} s, {nsec} ns): "
                                          f"recorded with the receive time")
            return now
        return sec * 1_000_000_000 + nsec

    def _progress(self, topic: str, data: bytes, sent: int) -> None:
        """Count a trial's trajectories and robot diagnostics toward its completion (only
        of a trial the leader started, each once); Rejected otherwise."""
        assert self.cfg is not None
        if topic == ms.TRIAL_EVENTS:
            ev = TrialEvent.from_json(ms.msg_to_json(ms.deserialize(data, String),
                                                     ("event", "trial")))
            if ev.run and self.cfg.run_id and ev.run != self.cfg.run_id:
                raise Rejected("foreign", f"event of run {ev.run}")
            if not sealed(ev, self.key):
                raise Rejected("foreign", f"{ev.event} of slot {ev.slot} not sealed by this "
                                          f"run's leader")
            if ev.event == ms.START:
                self.started = max(self.started, ev.slot)
                self.iteration_of[ev.slot] = ev.trial
                self._slot_done(ev.slot)
            elif ev.event == ms.ABORT:
                self.aborted.add(ev.slot)
            if ev.event in (ms.START, ms.ABORT):
                # into the file at once: without its start, a killed recorder's next part
                # cannot tell which trial a slot ran (formation_ilc.protocol.trialrows)
                self.writer.flush()
            self._advance()
            return
        if topic == ms.DIAGNOSTICS:
            d = check_diagnostics(ms.msg_to_report(ms.deserialize(data, DiagnosticArray),
                                                   ("node", "trial")))
            name, k = d["node"], d["trial"]
            if name not in self.robots:
                return
            if k > self.started:
                raise Rejected("future", f"{name} diagnostics of trial {k}, trial "
                                         f"{self.started} started")
            self.robot_diag[name] = max(k, self.robot_diag.get(name, -1))
        else:
            k, _ = self.cfg.clock.decode(sent)  # the slot
            if k > self.started:
                raise Rejected("future", f"trajectory of slot {k}, slot {self.started} "
                                         f"started")
            if k in self.aborted:
                raise Rejected("stale", f"trajectory of slot {k}, aborted")
            if topic in self.paths.get(k, set()):
                raise Rejected("duplicate", f"trajectory of slot {k} again")
            self.paths.setdefault(k, set()).add(topic)
            self._slot_done(k)
        self._advance()

    def _slot_done(self, k: int) -> None:
        """Count slot k's iteration as recorded once all its trajectories are (an abort
        that comes later does not take them back: an analysis keeps the first complete
        copy, formation_ilc.protocol.trialrows)."""
        assert self.cfg is not None
        full = self.cfg.scenario.n * (2 if self.truth else 1)
        if k in self.iteration_of and k not in self.aborted and \
                len(self.paths.get(k, ())) >= full:
            self.recorded.add(self.iteration_of[k])
            self.paths.pop(k, None)

    def _advance(self) -> None:
        """Publish the recorder's progress: the last trial k such that every trial up to it
        (from the first this recorder saw) has its trajectories and robot diagnostics in
        the file."""
        assert self.cfg is not None
        n = self.cfg.scenario.n
        if self.complete < 0 and self.recorded:
            # a restarted recorder (or a resumed run's) starts where its first trial is
            self.complete = min(self.recorded) - 1
        k = self.complete + 1
        while k in self.recorded and len(self.robot_diag) == n and \
                min(self.robot_diag.values()) >= k:
            self.complete = k
            self.writer.flush()
            d = {"node": ms.RECORDER_NODE, "trial": k, "messages": self.writer.count,
                 "file": str(self.output), "invalid_stamps": dict(self.invalid_stamps),
                 "unwritable": dict(self.unwritable)}
            d.update(self.drops.as_dict())
            self.diag_pub.publish(ms.diagnostics_to_msg(d, self.get_clock().now().nanoseconds))
            k += 1

    def _configure(self, data: bytes) -> None:
        try:
            conf = ms.msg_to_json(ms.deserialize(data, String))
            self.cfg = RunConfig.from_json(conf)
        except Rejected as exc:
            self.drops.reject(exc, ms.CONFIG)
            self.get_logger().error(f"bad run configuration, recording it as is: {exc}")
            return
        # kept: written now, after the first chunk, every REPEAT_BYTES and at the end
        self.writer.keep(META_NAME, run_metadata(conf, self.resolve_topic_name(ms.CONFIG),
                                                 self.key))
        n = self.cfg.scenario.n
        for topic, type_name, qos in ms.topic_table(n):
            self._subscribe(topic, type_name, qos)
        self.robots = {ms.robot_name(i + 1) for i in range(n)}
        self.path_topics = {f(i + 1) for i in range(n)
                            for f in (ms.trajectory_topic, ms.true_trajectory_topic)}
        self.progress_topics = self.path_topics | {ms.DIAGNOSTICS, ms.TRIAL_EVENTS}
        # a plant's true state is optional in its contract
        self.optional = {ms.true_trajectory_topic(i + 1) for i in range(n)}
        if self.observe:
            for topic, type_name, qos in ms.view_topic_table(n):
                self.types[topic], self.qos[topic] = type_name, qos
            self.observer = Observer(self, self.cfg, self._write_view, key=self.key)

    def _check_ready(self) -> None:
        if self.cfg is None or self.said_ready:
            return
        # in wall-clock trials no node publishes /clock: waiting for it would block the run
        absent = {ms.CLOCK} if self.cfg.mode == "wallclock" else set()
        single = [t for t in self.subs if t not in _MANY_WRITERS and t != ms.CONFIG
                  and t not in self.optional and t not in absent and t not in _UNWAITED
                  and not t.endswith(_UNWAITED_KIND)]
        if all(self.subs[t].get_publisher_count() >= 1 for t in single) and \
                self.ready_pub.get_subscription_count() >= 1:
            self.said_ready = True
            self.truth = all(self.subs[t].get_publisher_count() >= 1 for t in self.optional)
            self._gate.cancel()
            self.ready_pub.publish(self._ready_msg())
            self.get_logger().info(f"ready: {len(self.subs)} topics")

    def destroy_node(self) -> None:
        try:
            self.writer.close()
            self.get_logger().info(f"closed {self.output}: {self.writer.count} messages")
            # its folder opens as a rosbag2 bag (ros2 bag info, rosbags)
            meta = write_bag_metadata(recording_parts(root_of(self.output)))
            self.get_logger().info(f"wrote {meta}")
        except ValueError as exc:  # no summary to describe
            self.get_logger().error(f"no {METADATA} for {self.output}: {exc}")
        except OSError as exc:  # a full disk: what was flushed before reads back
            self.get_logger().error(f"could not close {self.output}: {exc.strerror}; the "
                                    f"chunks written before read back")
        super().destroy_node()


def output_problem(path: Path) -> str | None:
    """Why the recorder cannot write its file at ``path``, or None: a folder, a device or
    FIFO, a missing or unwritable folder (the recorder makes none: the launcher makes the
    folder of ``--record`` before it starts the recorder)."""
    import stat

    try:
        st = path.stat()
    except OSError:
        st = None
    if st is not None and stat.S_ISDIR(st.st_mode):
        return "is a folder, expected a file name"
    if st is not None and not stat.S_ISREG(st.st_mode):
        return "is not a regular file"
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        return f"the folder {folder} does not exist"
    if not os.access(folder, os.W_OK | os.X_OK):
        return f"the folder {folder} is not writable"
    return None


def _lower_priority() -> None:
    """Run below the control loop, before rclpy starts its threads: on Linux a niceness is
    per thread and only threads started later inherit it.

    Measured on paper-hexagon6 (6 robot processes, 2 cores, 8 trials, median of 4 runs):
    recording at normal priority cost 18 % of lockstep throughput, niced 6 %. SCHED_IDLE
    starved the recorder's DDS threads and lost samples. Niceness 10 lost samples too once
    lockstep got faster (paper-triangle3, 40 trials, a recorder restarted at trial 4: 7 to 8
    trials incomplete in each of 3 runs; it never caught up), niceness 5 none in 4 runs,
    one of them beside a busy loop. FORMATION_ILC_RECORDER_SCHED=normal records at normal
    priority."""
    if os.environ.get("FORMATION_ILC_RECORDER_SCHED", "nice") != "normal":
        os.nice(NICENESS)


def main(args: list[str] | None = None) -> int:
    parser = node_parser("formation-ilc-recorder", __doc__)
    parser.add_argument("--output", "-o", type=Path, required=True, metavar="RUN.mcap")
    parser.add_argument("--no-view", action="store_true",
                        help="record only what the formation publishes: no desired poses, "
                             "tracking errors or markers (formation_ilc.nodes.observer)")
    _lower_priority()

    def build(ns: Any, argv: list[str]) -> list[Node]:
        why = output_problem(ns.output)
        if why is not None:  # one line and status 2 (spin_main), no folder made
            raise ValueError(f"--output {ns.output}: {why}")
        return [RecorderNode(ns.output, observe=not ns.no_view)]

    return spin_main(build, parser, args)


if __name__ == "__main__":
    sys.exit(main())
