"""Runs as MCAP files: what the batch simulator writes, and what analysis reads back.

A recording is self-contained: it carries the run configuration (the scenario's YAML text
and overrides) on ``/formation/config``, the trial events, every robot's whole-trial
measured trajectory (``robot_i/trajectory``, the message its neighbours learn from) and
true trajectory, and the robots' diagnostics with the delays they measured (eq. 11). The
distributed stack's recorder node writes the same topics as received; ``SimRecorder``
writes them from the batch simulator.

What an analysis cannot do without is in more than one place, so that no single damaged
chunk or record loses it (``run_metadata``): the run configuration, the topic it is on and
the run key the leader sealed the events with are in a metadata record written when the
configuration comes, again after the first chunk, every ``mcap_io.REPEAT_BYTES`` of file
and at the end, and in the configuration channel's own metadata (the channel is written in
its chunk, again outside it, and in the summary). The message on the topic is a fourth
copy; a launched run's folder holds a fifth (``config.json``), which ``load_recording``
takes when a file has none left (``fallback``).
"""

from __future__ import annotations

import glob
import json
import os
import re
import struct
import sys
from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from formation_ilc.config.runconfig import RunConfig
from formation_ilc.config.scenario import Scenario
from formation_ilc.config.urdf import robot_description
from formation_ilc.core import names as ms
from formation_ilc.core.clock import Malformed, Rejected
from formation_ilc.core.links import (
    check_diagnostics,
    delivered_label,
    link_clocks,
    link_histograms,
)
from formation_ilc.core.metrics import METRIC_COLUMNS
from formation_ilc.model.simulate import Problem
from formation_ilc.protocol import wire
from formation_ilc.protocol.health import flatten, node_report, read_statuses, statuses
from formation_ilc.protocol.schedule import DONE, END, START, TrialEvent
from formation_ilc.protocol.trialrows import SlotRows
from formation_ilc.recordings import cdr
from formation_ilc.recordings.bagmeta import write_bag_metadata
from formation_ilc.recordings.mcap_io import (
    INFINITE_NS,
    FileInfo,
    RawMessage,
    ReadReport,
    RepairError,
    Repairing,
    RosMcapWriter,
    qos_yaml,
    read_messages,
    repair_with,
    type_hash,
)

__all__ = ["qos_of", "SimRecorder", "Recording", "RecordingError", "load_recording",
           "recording_parts", "root_of", "run_metadata", "run_copies", "META_NAME",
           "CHANNEL_META", "repair_run"]

#: metadata record name holding the run configuration (same JSON as /formation/config)
META_NAME = "formation_ilc"
#: the configuration channel's metadata key prefix for the same (beside rosbag2's keys)
CHANNEL_META = "formation_ilc."


def run_metadata(conf: dict[str, Any], topic: str, key: bytes | None) -> dict[str, str]:
    """The metadata record of a run (``META_NAME``): its configuration's JSON, the topic the
    configuration is on (its namespace), and the run key its events are sealed with (hex;
    "" for none)."""
    return {"config": json.dumps(conf, separators=(",", ":")), "topic": topic,
            "events_key": key.hex() if key else ""}


def run_copies(info: FileInfo) -> list[dict[str, str]]:
    """Every copy of the run's metadata a file holds (``run_metadata``'s fields), from its
    metadata records and its configuration channel's metadata, in file order."""
    out = [d for name, d in info.metadata if name == META_NAME and "config" in d]
    for topic, meta in info.channels.items():
        if CHANNEL_META + "config" in meta:
            out.append({k[len(CHANNEL_META):]: v for k, v in meta.items()
                        if k.startswith(CHANNEL_META)} | {"topic": topic})
    return out


def qos_of(profile: Any) -> str:
    """offered_qos_profiles YAML of an rclpy QoSProfile: a writer's, as the graph reports it
    (what rosbag2 records), or a profile a publisher is created with (the batch
    simulator's), whose unspecified (0) durations are what Fast DDS then offers: infinite."""
    def ns(d: Any) -> int:
        return int(d.nanoseconds) or INFINITE_NS

    return qos_yaml(reliability=profile.reliability.name.lower(),
                    durability=profile.durability.name.lower(),
                    history=profile.history.name.lower(), depth=int(profile.depth),
                    deadline=ns(profile.deadline), lifespan=ns(profile.lifespan),
                    liveliness=profile.liveliness.name.lower(),
                    lease=ns(profile.liveliness_lease_duration),
                    avoid_ros_namespace_conventions=bool(
                        profile.avoid_ros_namespace_conventions))


class SimRecorder:
    """Writes a batch simulation as the distributed stack's recorder would.

    Per trial: trial events, each robot's measured and true trajectory, and each robot's
    cumulative delay histogram (its diagnostics). For the trials in ``sample_trials`` also
    the per-sample topics: /clock, each robot's pose and cmd_vel, and the reference. With
    an observer (``observe``) also what the stack's recorder adds: every trial's largest
    errors, and for the kept trials the desired paths, poses, errors and the markers.
    Times are simulated time on the stack's sample grid (``SampleClock``). ``table``: every
    topic's (name, ROS type, QoS profile), the schema's (``msgs_schema.topic_table`` and
    ``view_topic_table``; the caller passes them: this layer sits below the ROS side).
    """

    def __init__(self, path: str | Path, sc: Scenario, table: Sequence[tuple[str, str, Any]],
                 sample_trials: Iterable[int] = (), gap: int = 20, first_trial: int = 0):
        self.sc = sc
        self.pb = Problem.from_scenario(sc)
        cfg = RunConfig(sc, mode="lockstep", gap=gap)
        self.clock = cfg.clock
        self.sample_trials = set(sample_trials)
        self.w = RosMcapWriter(path, flush_period=1.0)
        n = sc.n
        # channels by full name, in the stack's default namespace: the recorded topics and
        # what the stack's recorder adds beside them (formation_ilc.nodes.observer)
        self.full = {t: ms.absolute(t) for t in ms.recorded_topics(n) + ms.view_topics(n)}
        types = {topic: (typ, qos) for topic, typ, qos in table}
        # no e-stop in a batch run; the frames where tf2_msgs is installed (its definition
        # is the channel's schema; scripts/build_tf2_msgs.py)
        self.full.pop(ms.ESTOP)
        try:
            type_hash(types[ms.TF][0])
            self.frames = True
        except FileNotFoundError:
            self.frames = False
            self.full.pop(ms.TF)
            self.full.pop(ms.TF_STATIC)
        # its trials are first_trial .. first_trial + trials - 1 (simulate --first-trial)
        conf = cfg.to_json() | {"recorded_by": "formation-ilc simulate",
                                "first_trial": int(first_trial)}
        meta = run_metadata(conf, self.full[ms.CONFIG], None)
        for topic, full in self.full.items():
            # the type hash a ROS writer of the type offers, as the stack's recorder records it
            typ, qos = types[topic]
            extra = ({CHANNEL_META + k: v for k, v in meta.items() if k != "topic"}
                     if topic == ms.CONFIG else None)
            self.w.channel(full, typ, qos_of(qos), type_hash(typ), extra)
        self.cfg = cfg
        #: what the stack's recorder adds (``observe``); None: the formation's own topics
        self.observer: Any = None
        self._json(ms.CONFIG, conf, 0)
        body = cfg.safety.body if cfg.safety is not None else "p3dx"
        for r in range(n):  # each robot's body, as the simulator publishes it
            self._write(ms.robot_description_topic(r + 1), cdr.encode_string(
                robot_description(body, f"{ms.robot_name(r + 1)}/")), 0)
        if self.frames:  # the simulator's: robot_i/odom is map
            self._write(ms.TF_STATIC, wire.tf_bytes(0, [
                wire.Frame(ms.WORLD_FRAME, ms.odom_frame(r + 1), 0.0, 0.0, 0.0)
                for r in range(n)]), 0)
        self.w.keep(META_NAME, meta)
        self.delays: list[dict[str, Counter[int]]] = [{} for _ in range(n)]
        self.names = [ms.robot_name(i + 1) for i in range(n)]

    def observe(self, make: Callable[[RunConfig, Callable[[str, bytes, int], None]], Any]
                ) -> None:
        """Also record what the stack's recorder adds, from ``make(cfg, sink)``: an observer
        with the stack's (``formation_ilc.nodes.observer.Observer`` without a node; the CLI
        passes it: this layer sits below the nodes)."""
        self.observer = make(self.cfg, self._write)

    def _json(self, topic: str, data: dict[str, Any], ns: int) -> None:
        self._write(topic, cdr.encode_string(json.dumps(data, separators=(",", ":"))), ns)

    def _write(self, topic: str, data: bytes, ns: int) -> None:
        self.w.write(self.full[topic], data, ns, ns)

    def trial(self, k: int, xi: NDArray[np.float64], eta: NDArray[np.float64],
              u: NDArray[np.float64], tau: NDArray[np.int64], tau0: NDArray[np.int64]) -> None:
        pb, clk = self.pb, self.clock
        n, n_t = pb.n, pb.samples
        stamps = np.array([clk.stamp_ns(k, s) for s in range(n_t + 1)], dtype=np.int64)
        t0, t_end = int(stamps[0]), int(stamps[-1])
        self._json(ms.TRIAL_EVENTS, {"event": START, "trial": k, "stamp_ns": t0}, t0)
        obs = self.observer
        if k in self.sample_trials:
            # desired paths, and per pose its desired pose, error and the team's markers
            if obs is not None:
                obs.on_event(TrialEvent(START, k, k, stamp_ns=t0))
            ref = self.sc.reference
            world = ms.WORLD_FRAME
            for t in range(n_t + 1):
                ns = int(stamps[t])
                self._write(ms.CLOCK, cdr.encode_clock(ns), ns)
                self._write(ms.REFERENCE, cdr.encode_pose_stamped(ref[t], ns, world), ns)
                if self.frames:  # as the leader's and the simulator's (nodes.frames)
                    self._write(ms.TF, wire.tf_bytes(ns, [
                        wire.Frame(world, ms.LEADER_FRAME_ID, *map(float, ref[t]))]), ns)
                    self._write(ms.TF, wire.tf_bytes(ns, [
                        wire.Frame(ms.odom_frame(r + 1), ms.base_frame(r + 1),
                                   *map(float, eta[r, t])) for r in range(n)]), ns)
                for r in range(n):
                    pose = cdr.encode_pose_stamped(eta[r, t], ns, world)
                    self._write(ms.pose_topic(r + 1), pose, ns)
                    if obs is not None:
                        obs.on_pose(r, pose)  # the trial's errors after sample T
                    if t < n_t:
                        self._write(ms.cmd_vel_topic(r + 1),
                                    cdr.encode_twist(u[r, t, 0], u[r, t, 1]), ns)
        elif obs is not None:
            obs.whole_trial(k, eta, t_end)
        self._json(ms.TRIAL_EVENTS, {"event": END, "trial": k}, t_end)
        # what each robot counts: the deliveries of ticks 0..T-1 that carry a sample >= 0
        t_idx = np.arange(n_t)
        for i in range(n):
            for ell, j in enumerate(pb.src[i]):
                if j < 0:
                    continue
                d = tau[i, ell, :n_t]
                self.delays[i].setdefault(self.names[j], Counter()).update(
                    d[delivered_label(t_idx, d) >= 0].tolist())
            if pb.leader[i] != 0.0:
                d = tau0[i, :n_t]
                self.delays[i].setdefault(ms.LEADER, Counter()).update(
                    d[delivered_label(t_idx, d) >= 0].tolist())
        for r in range(n):
            self._write(ms.true_trajectory_topic(r + 1),
                        cdr.encode_path(xi[r], stamps, ms.WORLD_FRAME, t_end), t_end)
            self._write(ms.trajectory_topic(r + 1),
                        cdr.encode_path(eta[r], stamps, ms.WORLD_FRAME, t_end), t_end)
            hist = {sender: {str(a): b for a, b in sorted(c.items())}
                    for sender, c in self.delays[r].items()}
            report = {"node": self.names[r], "trial": k, "delays": hist, "dropped": {}}
            self._write(ms.DIAGNOSTICS, cdr.encode_diagnostic_array(t_end, [
                (st.level, st.name, st.message, st.hardware_id, flatten(st.values))
                for st in statuses(report, pb.dt, n_t, self.names[r])]), t_end)

    def close(self) -> None:
        self.w.close()
        write_bag_metadata(self.w.path)  # its folder opens as a rosbag2 bag


# --------------------------------------------------------------------------- reading


class RecordingError(ValueError):
    """A file that holds no formation-ilc run (no readable run configuration)."""


@dataclass(frozen=True)
class ClockPoint:
    """A node's estimate of a peer's clock as recorded: the recorder's time [ns], the node,
    the peer, the offset and its uncertainty [ms], the emulation's truth [ms] (nan on
    real machines), and whether it had converged."""

    time_ns: int
    node: str
    peer: str
    offset_ms: float
    uncertainty_ms: float
    true_offset_ms: float
    converged: bool


@dataclass
class Recording:
    """What an analysis needs, read from one MCAP file.

    metrics : shape (K, len(METRIC_COLUMNS)), trials in order (from the trajectories).
    eta, xi : {trial: shape (N, T+1, 3)} of the trials kept (``keep`` of load_recording).
    delays : {"sender->robot_i": {tau: count}} measured by the robots (last diagnostics).
    injected : the same as injected by the link emulator, when recorded.
    events : trial events in file order. config : the run configuration (JSON).
    incomplete : trials of the run up to the last one seen whose data is not all in the
        file (cut short, damaged, or never sent).
    missing : every trial of the run (its configuration's ``trials``, from its
        ``first_trial``) that is not complete in the files: ``incomplete`` and the trials
        after the last one seen. A run is whole only when this is empty.
    ended : the leader's ``done`` event is in the files (the run reached its end).
    Trials are iterations: a slot the leader aborted (a node restarted, docs/reliability.md)
    is dropped and its iteration counted where it ran again.
    undecodable : per topic, messages skipped because they do not decode (junk JSON, a
        malformed trajectory, a label off the run's grid).
    report : what reading the file found (``mcap_io.ReadReport``: damage, cut short).
    """

    scenario: Scenario
    config: dict[str, Any]
    metrics: NDArray[np.float64]
    eta: dict[int, NDArray[np.float64]] = field(default_factory=dict)
    xi: dict[int, NDArray[np.float64]] = field(default_factory=dict)
    delays: dict[str, dict[int, int]] = field(default_factory=dict)
    injected: dict[str, dict[int, int]] = field(default_factory=dict)
    events: list[dict[str, Any]] = field(default_factory=list)
    incomplete: list[int] = field(default_factory=list)
    messages: int = 0
    undecodable: dict[str, int] = field(default_factory=dict)
    report: ReadReport = field(default_factory=ReadReport)
    #: every file read, with what reading it found (``report`` is the first one's)
    parts: list[tuple[Path, ReadReport]] = field(default_factory=list)
    #: messages of aborted slots, or repeating a trial already complete (not errors)
    superseded: int = 0
    missing: list[int] = field(default_factory=list)
    ended: bool = False
    #: every clock estimate the nodes said (realtime and wall-clock runs), in file order
    clocks: list[ClockPoint] = field(default_factory=list)
    #: each link's last clock block (``core.links.link_clocks``): delays.csv's one-way delays
    clock_links: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: trial events refused as foreign: another run's, or not sealed by the run's leader
    foreign: int = 0
    #: how the run configuration was found, when not from its own message
    notes: list[str] = field(default_factory=list)


def _path_outputs(data: bytes, ref_heading: NDArray[np.float64]
                  ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """eta (S, 3) and stamps of a recorded trajectory, decoded as the monitor decodes it
    (``wire.read_trajectory``: same heading function, unwrapped next to the desired
    heading), with the bytes parsed by numpy when the layout allows it. Malformed if it is
    not a valid trajectory of ``len(ref_heading)`` poses."""
    try:
        f, stamps, frame, _ = cdr.decode_path(data)
    except (ValueError, struct.error, IndexError):
        eta, stamps, frame = wire.read_trajectory(data, ref_heading)
        f = None
    if frame != ms.WORLD_FRAME:
        raise Malformed(f"trajectory in frame {frame[:50]!r}")
    if f is None:
        return eta, stamps
    if len(f) != len(ref_heading):
        raise Malformed(f"trajectory has {len(f)} poses, expected {len(ref_heading)}")
    if not np.isfinite(f[:, :2]).all():
        raise Malformed("non-finite position")
    eta = np.empty((len(f), 3))
    eta[:, :2] = f[:, :2]
    hq = wire.heading_from_quaternion
    for s, (qx, qy, qz, qw) in enumerate(f[:, 3:].tolist()):
        eta[s, 2] = hq(qx, qy, qz, qw, float(ref_heading[s]))
    return eta, stamps


#: topics (by their last part) that an analysis reads; the per-sample ones it skips
_ANALYSED = ("/trajectory", "/true_trajectory", "/diagnostics", "/trial_events")


def recording_parts(first: str | Path) -> list[Path]:
    """The files of the run recorded in ``first`` (``RUN.mcap``), in the order they were
    written: ``first``, the parts of its restarted recorder (``RUN.part1.mcap``, ...), then
    each resumed launch's file (``RUN.resumed1.mcap``) and its parts
    (``RUN.resumed1.part1.mcap``, ...). ``first`` itself may be missing (a launch killed
    before its recorder wrote it, then resumed): the parts that exist are the run. Only
    ``first`` when it is itself a part (``root_of`` names the run's first file)."""
    first = Path(first)
    stem = first.name[: -len(".mcap")] if first.name.endswith(".mcap") else None
    if stem is None or re.search(r"\.(part|resumed)\d+$", stem):
        return [first]

    def numbered(prefix: str, kind: str) -> list[tuple[int, Path]]:
        pat = re.compile(re.escape(prefix) + rf"\.{kind}(\d+)\.mcap$")
        found = []
        for p in first.parent.glob(f"{glob.escape(prefix)}.{kind}*.mcap"):
            m = pat.fullmatch(p.name)
            if m:
                found.append((int(m.group(1)), p))
        return sorted(found)

    # the first file may be missing (a run resumed before its first recording existed)
    out = ([first] if first.exists() else []) + [p for _, p in numbered(stem, "part")]
    for n, resumed in numbered(stem, "resumed"):
        out += [resumed] + [p for _, p in numbered(f"{stem}.resumed{n}", "part")]
    return out or [first]


def root_of(part: str | Path) -> Path:
    """The first file of the run a recording part belongs to: ``RUN.mcap`` for
    ``RUN.part2.mcap``, ``RUN.resumed1.mcap`` or ``RUN.resumed1.part1.mcap``."""
    part = Path(part)
    m = re.fullmatch(r"(.+?)(\.resumed\d+)?(\.part\d+)?\.mcap", part.name)
    if m is None or not (m.group(2) or m.group(3)):
        return part
    return part.with_name(m.group(1) + ".mcap")


def load_recording(path: str | Path | Sequence[str | Path],
                   keep: Callable[[int, int], bool] | None = None,
                   progress: Callable[[int], None] | None = None,
                   fallback: dict[str, Any] | None = None) -> Recording:
    """Read a recording and compute its per-trial metrics exactly as the launcher does.

    ``path``: one file, or the files of one run in the order they were written
    (``recording_parts``): they are read as one stream, so a trial whose data spans two
    parts is complete. Every part must hold the same run (its run id); RecordingError names
    the one that does not.

    Nothing in the file stops the reading: a message that does not decode is skipped and
    counted per topic (``undecodable``), damaged bytes are skipped up to the next readable
    chunk (``report``), and trials whose data is not all there are listed (``incomplete``).
    The run configuration comes from whichever of its copies reads back first
    (``run_metadata``); with the run key among them, only the events the leader sealed
    count. RecordingError if none reads back and there is no ``fallback``.

    keep : (trial, total trials) -> whether to keep the trial's trajectories.
    progress : called with the number of messages read so far, now and then.
    fallback : the run configuration to use when the files have none left (a launched
        run's ``config.json``, its ``namespace`` beside it), checked against the run id of
        the events the files hold.
    """
    paths = [Path(path)] if isinstance(path, (str, Path)) else [Path(p) for p in path]
    if not paths:
        raise ValueError("load_recording: no file given")
    reader = _RunReader(keep)
    for part in paths:
        reader.read(part, progress)
    if reader.config is None and fallback is not None:
        reader.rebuild(fallback)
    return reader.result(paths)


class _RunReader:
    """The state of ``load_recording`` over the parts of one run: the run configuration
    once read, the trials' rows (``SlotRows``, as the launcher's monitor keeps them), the
    kept trajectories, the last diagnostics of each node, and what was skipped."""

    def __init__(self, keep: Callable[[int, int], bool] | None):
        self.keep = keep
        self.parts: list[tuple[Path, ReadReport]] = []
        self.config: dict[str, Any] | None = None
        self.cfg: RunConfig | None = None
        self.slots: SlotRows | None = None
        self.eta: dict[int, NDArray[np.float64]] = {}
        self.xi: dict[int, NDArray[np.float64]] = {}
        self.diags: dict[str, dict[str, Any]] = {}
        self.clocks: list[ClockPoint] = []
        self.events: list[dict[str, Any]] = []
        self.bad: Counter[str] = Counter()
        self.count = 0
        self.superseded = 0
        self.foreign = 0
        self.traj_topic: dict[str, tuple[int, bool]] = {}
        # the formation's namespace is where its config topic is
        self.events_topic = self.diag_topic = ""
        self.true_seen = False
        self.early: list[RawMessage] = []  # what came before the configuration (damage, a late one)
        self.last_seen = -1                # the latest trial with any data in the file
        #: the run key of the part being read (its events are sealed with it), None: none
        self.key: bytes | None = None
        #: where the configuration came from, when not from its message (for the report)
        self.notes: list[str] = []
        self.copy_in = ""           # the part whose metadata gave the configuration
        self.message_seen = False   # a configuration message read back

    def text(self, m: RawMessage, required: tuple[str, ...]) -> dict[str, Any]:
        """A JSON text message's fields (MalformedMessage if ``required`` are missing)."""
        return wire.json_object(wire.read_string(m.data), required)

    def read(self, part: Path, progress: Callable[[int], None] | None) -> None:
        """Every message of one part, in file order."""
        report = ReadReport()
        info = FileInfo()
        self.parts.append((part, report))
        first = True
        for msg in read_messages(part, report=report, info=info):
            if first:  # the copies of the run's metadata, before any message
                first = False
                self._copies(part, info)
            self.count += 1
            if progress is not None and self.count % 5000 == 0:
                progress(self.count)
            if msg.topic.endswith("/" + ms.CONFIG):
                self._on_config(part, msg)
            elif self.config is None:
                if msg.topic.endswith(_ANALYSED):
                    self.early.append(msg)
            else:
                self.dispatch(msg)

    def _copies(self, part: Path, info: FileInfo) -> None:
        """The copies of the run's metadata in ``part`` (``run_copies``): the run key of its
        events, and the configuration when none has been read yet."""
        self.key = None
        for copy in run_copies(info):
            try:
                conf = json.loads(copy["config"])
                if not isinstance(conf, dict):
                    continue
                if self.config is None:
                    self.setup(conf, copy.get("topic", ""))
                    self.copy_in = part.name
                elif conf.get("run_id") != self.config.get("run_id"):
                    continue
                key = copy.get("events_key", "")
                self.key = bytes.fromhex(key) if key else None
            except (ValueError, TypeError):  # a damaged copy: the next one
                continue
            break
        if self.slots is not None:
            self.slots.key = self.key

    def rebuild(self, conf: dict[str, Any]) -> None:
        """No copy of the configuration read back: take ``conf`` (a run folder's), once
        the events held say it is their run's; RecordingError if they are another's."""
        other = another_run(conf, (event_run(m.data) for m in self.early
                                   if m.topic.endswith("/" + ms.TRIAL_EVENTS)))
        if other is not None:
            raise RecordingError(other)
        ns = str(conf.get("namespace") or ms.NAMESPACE)
        try:
            self.setup(conf, ms.absolute(ms.CONFIG, ns))
        except ValueError as exc:
            raise RecordingError(f"the run folder's configuration does not load: "
                                 f"{exc}") from None
        self.notes.append("no copy of the run configuration read back from the files: "
                          "taken from the run's folder (config.json)")

    def _on_config(self, part: Path, msg: RawMessage) -> None:
        """The first configuration sets the run up (and the messages held before it are
        read); a later part's must be the same run's."""
        self.message_seen = True
        if self.config is not None:
            _same_run(part, self.config, msg, self.text)
            return
        try:
            self.setup(self.text(msg, ()), msg.topic)
        except ValueError:  # junk, or a configuration that does not load
            self.bad[msg.topic] += 1

    def setup(self, conf: dict[str, Any], topic: str) -> None:
        """The run of configuration ``conf`` (on ``topic``: the formation's namespace);
        the messages held before it are read. ValueError if it does not load."""
        c = RunConfig.from_json(conf)
        pb = Problem.from_scenario(c.scenario)
        self.config, self.cfg = conf, c
        self.slots = SlotRows(pb, strict=False, safety=c.safety is not None, key=self.key)
        self.slots.run = c.run_id
        namespace = topic[: -len(ms.CONFIG) - 1] or "/"
        for r in range(pb.n):
            self.traj_topic[ms.absolute(ms.trajectory_topic(r + 1), namespace)] = (r, False)
            self.traj_topic[ms.absolute(ms.true_trajectory_topic(r + 1), namespace)] = (r, True)
        self.events_topic = ms.absolute(ms.TRIAL_EVENTS, namespace)
        self.diag_topic = ms.absolute(ms.DIAGNOSTICS, namespace)
        held, self.early = self.early, []
        for m in held:
            self.dispatch(m)

    def kept(self, done: list[Any]) -> None:
        """Keep the trajectories of the trials just completed that ``keep`` asks for."""
        assert self.cfg is not None
        for d in done:
            if self.keep is None or self.keep(d.trial, self.cfg.scenario.trials):
                self.eta[d.trial] = d.eta
                if d.xi is not None:
                    self.xi[d.trial] = d.xi

    def handle(self, m: RawMessage) -> None:
        slots, cfg = self.slots, self.cfg
        assert slots is not None and cfg is not None
        if m.topic == self.events_topic:
            d = self.text(m, ("event", "trial"))
            ev = TrialEvent.from_json(d)
            if ev.run and cfg.run_id and ev.run != cfg.run_id:
                raise Rejected("foreign", f"event of run {ev.run}")
            if slots.repeat(ev):
                return  # the leader's repeat of a stalled slot's start: not an event
            done = slots.event(ev)  # Rejected (foreign) unless the leader sealed it
            ev.agree(cfg.clock)
            if ev.event == START:
                self.last_seen = max(self.last_seen, ev.trial)
            self.events.append(d)
            self.kept(done)
        elif m.topic == self.diag_topic:
            dg = check_diagnostics(node_report(read_statuses(wire.read_diagnostics(m.data)),
                                               ("node", "trial")))
            slots.note_diagnostics(dg)
            self.note_clock(m.log_time, dg)
            if "contact" not in dg and "clock_word" not in dg:  # a word, not the report
                self.diags[dg["node"]] = dg
        elif m.topic in self.traj_topic:
            r, is_true = self.traj_topic[m.topic]
            eta, stamps = _path_outputs(m.data, slots.pb.eta_d[r, :, 2])
            k, s0 = cfg.clock.decode(int(stamps[0]))
            if s0 != 0 or k < 0:
                raise Malformed(f"trajectory of slot {k} sample {s0}: not a trial of this "
                                f"run")
            self.true_seen = self.true_seen or is_true
            self.kept(slots.trajectory(k, r, is_true, eta))

    def note_clock(self, log_time: int, dg: Mapping[str, Any]) -> None:
        """Every estimate a node's diagnostics (its reports and its clock words) hold, at
        the time the recorder took it: the estimates over time."""
        clock = dg.get("clock")
        if not isinstance(clock, Mapping) or not isinstance(clock.get("peers"), Mapping):
            return
        for peer, p in clock["peers"].items():
            if isinstance(p, Mapping) and isinstance(p.get("offset_ms"), (int, float)):
                self.clocks.append(ClockPoint(
                    int(log_time), str(dg["node"]), str(peer), float(p["offset_ms"]),
                    float(p.get("uncertainty_ms", float("nan"))),
                    float(p.get("true_offset_ms", float("nan"))),
                    bool(p.get("converged", False))))

    def dispatch(self, m: RawMessage) -> None:
        """``handle``, counting what it refuses: superseded, or skipped as undecodable."""
        try:
            self.handle(m)
        except Rejected as exc:
            if exc.reason in ("stale", "duplicate"):
                self.superseded += 1  # an aborted slot's, or a trial run again
            elif exc.reason == "foreign":
                self.foreign += 1     # not the leader's: recorded as evidence, not counted
            else:
                self.bad[m.topic] += 1
        except (Malformed, ValueError) as exc:
            self.bad[m.topic] += 1
            if os.environ.get("FORMATION_ILC_DEBUG"):
                print(f"{m.topic}: skipped a message: {exc}", file=sys.stderr)

    def result(self, paths: list[Path]) -> Recording:
        """The recording read from ``paths``; RecordingError if no configuration read."""
        slots, cfg, config = self.slots, self.cfg, self.config
        if slots is not None:
            # slots whose start was lost with a killed recorder or a damaged chunk; in a
            # batch simulation's recording every slot runs its own number
            sim = config is not None and config.get("recorded_by") == "formation-ilc simulate"
            first = config.get("first_trial", 0) if config is not None else 0
            first = first if isinstance(first, int) and not isinstance(first, bool) else 0
            self.kept(slots.infer(identity=range(first, first + cfg.scenario.trials)
                                  if sim and cfg is not None else None))
            if not self.true_seen:
                # a plant without a true state (hardware): the true_ columns are nan
                self.kept(slots.measured_only())
        if config is None or cfg is None or slots is None:
            report = self.parts[0][1]
            found = (f"{report.messages} messages read" if report.messages
                     else "no MCAP record read back")
            where = paths[0] if len(paths) == 1 else f"{paths[0]} (and {len(paths) - 1} parts)"
            raise RecordingError(f"{where}: no readable run configuration on a "
                                 f".../{ms.CONFIG} topic or in the file's metadata ({found}): "
                                 f"not a formation-ilc recording, or cut or damaged before "
                                 f"the run started (a launched run's folder holds a copy: "
                                 f"--run-dir DIR)")
        if self.copy_in and not self.message_seen:
            self.notes.append(f"the run configuration's message did not read back: taken "
                              f"from its copy in {self.copy_in}'s metadata")
        topic_of = {v: t for t, v in self.traj_topic.items()}
        for _, r, is_true in slots.unstarted():  # of no trial the run started
            self.bad[topic_of[(r, is_true)]] += 1
        rows = slots.rows
        last_seen = max([self.last_seen, *rows, *slots.iteration_of.values()])
        metrics = (np.array([rows[k] for k in sorted(rows)]) if rows
                   else np.empty((0, len(METRIC_COLUMNS))))
        delays, injected = link_histograms(self.diags)
        first = config.get("first_trial", 0)
        first = first if isinstance(first, int) and not isinstance(first, bool) else 0
        return Recording(missing=[k for k in range(first, first + cfg.scenario.trials)
                                  if k not in rows],
                         ended=any(e.get("event") == DONE for e in self.events),
                         scenario=cfg.scenario, config=config, metrics=metrics, eta=self.eta,
                         xi=self.xi, delays=delays, injected=injected, events=self.events,
                         incomplete=[k for k in range(min(last_seen + 1, cfg.scenario.trials))
                                     if k not in rows],
                         messages=self.count, undecodable=dict(self.bad),
                         report=self.parts[0][1], parts=self.parts,
                         superseded=self.superseded, clocks=self.clocks,
                         clock_links=link_clocks(self.diags), foreign=self.foreign,
                         notes=self.notes)


def repair_run(src: Path, dst: Path, report: ReadReport | None = None,
               fallback: dict[str, Any] | None = None) -> tuple[int, list[str]]:
    """``mcap_io.repair_with`` for a recording of a run: a complete copy of what reads back,
    and the run configuration's message put back when the damage took it (from a copy in
    the file's metadata, else from ``fallback``, a run folder's ``config.json``), with its
    metadata record. Returns (messages kept, what was rebuilt). RepairError, with nothing
    written, when ``fallback`` is another run's than the recording's events (as ``analyze``
    refuses it)."""
    runs: list[str] = []

    def peek(topic: str, data: bytes) -> None:
        """The run ids of the recording's trial events."""
        if topic.endswith("/" + ms.TRIAL_EVENTS):
            runs.append(event_run(data))

    def rebuild(st: Repairing) -> list[str]:
        if any(t.endswith("/" + ms.CONFIG) for t in st.topics):
            return []
        found: tuple[dict[str, Any], str, dict[str, str] | None, str] | None = None
        for copy in run_copies(st.info):
            try:
                conf = json.loads(copy["config"])
                RunConfig.from_json(conf)
            except (ValueError, TypeError, Rejected):
                continue
            found = (conf, copy.get("topic") or ms.absolute(ms.CONFIG), copy, "its copy in "
                     "the file's metadata")
            break
        if found is None and fallback is not None:
            other = another_run(fallback, runs)
            if other is not None:
                raise RepairError(f"{other}: give --run-dir the folder of this "
                                  f"recording's run; nothing written")
            found = (fallback, ms.absolute(ms.CONFIG, str(fallback.get("namespace")
                                                            or ms.NAMESPACE)),
                     None, "the run's folder (config.json)")
        if found is None:
            return ["the run configuration's message is lost and no copy of it reads back "
                    "(give --run-dir DIR, the launched run's folder)"]
        conf, topic, kept, where = found
        meta = kept if kept is not None else run_metadata(conf, topic, None)
        extra = {CHANNEL_META + k: v for k, v in meta.items() if k not in ("topic",)}
        cid = st.channel(topic, "std_msgs/msg/String",
                         {"offered_qos_profiles": qos_yaml(durability="transient_local",
                                                           depth=1), **extra})
        t = st.first_log_time or 0
        st.writer.add_message(cid, t, cdr.encode_string(json.dumps(conf,
                                                                   separators=(",", ":"))),
                              t, 0)
        if not any(name == META_NAME for name, _ in st.info.metadata):
            st.writer.add_metadata(META_NAME, {**meta, "topic": topic})
        return [f"the run configuration's message on {topic} was lost: rebuilt from {where}"]

    return repair_with(src, dst, report, rebuild, peek)


def event_run(data: bytes) -> str:
    """The run id a trial event (its bytes) carries; "" for none, or an event that does
    not decode."""
    try:
        return str(wire.json_object(wire.read_string(data), ("event",)).get("run", ""))
    except ValueError:
        return ""


def another_run(conf: Mapping[str, Any], runs: Iterable[str]) -> str | None:
    """The line that refuses a run folder's configuration ``conf`` of another run than the
    recording's events (their run ids ``runs``), or None (theirs, or no event says)."""
    said = set(runs) - {""}
    if said and conf.get("run_id") not in said:
        return (f"the run folder's configuration is of run {conf.get('run_id')}, the "
                f"recording's events of run {', '.join(sorted(said))}")
    return None


def _same_run(part: Path, config: dict[str, Any], msg: RawMessage,
              text: Callable[[RawMessage, tuple[str, ...]], dict[str, Any]]) -> None:
    """RecordingError if ``msg`` (a configuration in a later part) is another run's."""
    try:
        other = text(msg, ())
    except ValueError:
        return  # junk: counted nowhere, the first configuration stands
    mine, theirs = config.get("run_id", ""), other.get("run_id", "")
    if mine != theirs or other.get("scenario") != config.get("scenario"):
        raise RecordingError(f"{part}: another run's recording (run {theirs or '?'}, the "
                             f"first part's is {mine or '?'}): give the parts of one run")
