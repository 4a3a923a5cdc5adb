"""The wire contract of the distributed stack: topic names, message types, QoS, converters.

This module is the one place that names a topic. Every node, the launcher and the tests
import names and profiles from here; numpy <-> message converters live here too and are
tested by round trip (tests/test_msgs_schema.py). Standard messages only.

Topics (robot ``i`` is 1-based in names, index ``i - 1`` in arrays):

========================================  ===========================  =====================
topic                                     type                         from -> to
========================================  ===========================  =====================
/formation/config                         std_msgs/String (JSON)       leader -> all (latched)
/formation/leader/reference               geometry_msgs/PoseStamped    leader -> links
/formation/leader/trial_events            std_msgs/String (JSON)       leader -> all
/formation/ready                          std_msgs/String (JSON)       all -> leader (latched)
/formation/diagnostics                    std_msgs/String (JSON)       all -> monitor (latched)
/formation/robot_i/pose                   geometry_msgs/PoseStamped    sim/bridge -> robot i
/formation/robot_i/cmd_vel                geometry_msgs/Twist          robot i -> sim/bridge
/formation/robot_i/shared_pose            geometry_msgs/PoseStamped    robot i -> links
/formation/robot_i/neighbour_poses        nav_msgs/Path                links -> robot i
/formation/robot_i/trajectory             nav_msgs/Path (trial end)    robot i -> neighbours
/formation/robot_i/true_trajectory        nav_msgs/Path (trial end)    sim -> monitor
/clock                                    rosgraph_msgs/Clock          sim -> all
========================================  ===========================  =====================

Time labels. A stamp is ``(k * period + s) * dT`` [ns] for trial ``k`` and sample ``s``
(``period`` samples per trial, longer than the trial so a trial's labels never mix with the
next one's). The shared pose's stamp is the send label St of eq. (11); the robot measures
each delay from it and its own clock Rt. ``neighbour_poses`` is one bundle per robot and
tick: the poses the links deliver at that tick, each with its ORIGINAL stamp and
``frame_id`` naming the sender (``robot_j`` or ``leader``); the bundle's own stamp is the
tick. Malformed input raises :class:`MalformedMessage`, which nodes count and drop.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped, Twist
from nav_msgs.msg import Path
from numpy.typing import NDArray
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from std_msgs.msg import String

__all__ = [
    "NAMESPACE", "CONFIG", "REFERENCE", "TRIAL_EVENTS", "READY", "DIAGNOSTICS", "CLOCK",
    "LEADER_FRAME", "robot_name", "robot_index", "pose_topic", "cmd_vel_topic",
    "shared_pose_topic", "neighbour_poses_topic", "trajectory_topic", "true_trajectory_topic",
    "SAMPLE_QOS", "LATCHED_QOS", "LATCHED_READER_QOS", "TRAJECTORY_QOS", "CLOCK_QOS",
    "MalformedMessage", "topic_table",
    "SampleClock", "stamp_to_ns", "ns_to_stamp", "pose_to_msg", "msg_to_pose", "u_to_twist",
    "twist_to_u", "trajectory_to_path", "path_to_trajectory", "bundle_to_msg",
    "msg_to_bundle", "json_to_msg", "msg_to_json", "clock_msg", "Delivery",
    "START", "END", "DONE",
]

NAMESPACE = "/formation"
CONFIG = f"{NAMESPACE}/config"
REFERENCE = f"{NAMESPACE}/leader/reference"
TRIAL_EVENTS = f"{NAMESPACE}/leader/trial_events"
READY = f"{NAMESPACE}/ready"
DIAGNOSTICS = f"{NAMESPACE}/diagnostics"
CLOCK = "/clock"

#: frame_id of the leader's reference poses (sender name in bundles)
LEADER_FRAME = "leader"
#: trial events (``event`` field of the JSON on TRIAL_EVENTS)
START, END, DONE = "start", "end", "done"


def robot_name(i: int) -> str:
    """Name of robot ``i`` (1-based): ``robot_i``; also its frame_id and namespace leaf."""
    return f"robot_{int(i)}"


def robot_index(name: str) -> int:
    """1-based robot number of ``robot_i``; MalformedMessage if ``name`` is not one."""
    if not name.startswith("robot_") or not name[6:].isdigit():
        raise MalformedMessage(f"not a robot name: {name!r}")
    return int(name[6:])


def _ns(i: int) -> str:
    return f"{NAMESPACE}/{robot_name(i)}"


def pose_topic(i: int) -> str:
    """Measured pose of robot ``i`` (simulator or hardware bridge -> robot)."""
    return f"{_ns(i)}/pose"


def cmd_vel_topic(i: int) -> str:
    return f"{_ns(i)}/cmd_vel"


def shared_pose_topic(i: int) -> str:
    """Robot ``i``'s labelled output, for its neighbours (stamp = send label St)."""
    return f"{_ns(i)}/shared_pose"


def neighbour_poses_topic(i: int) -> str:
    """Per-tick bundle of the poses delivered to robot ``i`` by its in-links."""
    return f"{_ns(i)}/neighbour_poses"


def trajectory_topic(i: int) -> str:
    """Robot ``i``'s whole-trial measured output, sent at trial end."""
    return f"{_ns(i)}/trajectory"


def true_trajectory_topic(i: int) -> str:
    """Simulator ground truth (true state) of robot ``i`` for one trial, for metrics."""
    return f"{_ns(i)}/true_trajectory"


# Lockstep must not lose a sample on localhost: reliable, and deep enough for a burst.
SAMPLE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=64,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)
# Configuration, readiness and diagnostics: a late joiner gets the last word of each writer.
LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Readers of a latched topic with many writers (ready, diagnostics): a reader's KEEP_LAST
# history is shared by all writers of a keyless topic, so depth 1 would lose messages.
LATCHED_READER_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=256,
                                reliability=ReliabilityPolicy.RELIABLE,
                                durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Trial-end trajectories: latched too, so a reader matched late still gets trial k's.
TRAJECTORY_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2,
                            reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.TRANSIENT_LOCAL)
# /clock: reliable writer (also serves rclpy's best-effort time-source readers).
CLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=64,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)


class MalformedMessage(ValueError):
    """A message that cannot be decoded into valid data (dropped and counted by nodes)."""


# --------------------------------------------------------------------------- time labels

@dataclass(frozen=True)
class SampleClock:
    """Sample grid of a run: stamp(k, s) = (k * period + s) * dT, integer nanoseconds.

    dt_ns : sample time [ns]; samples : T (a trial has samples 0..T); period : samples per
    trial slot (> T, so labels of consecutive trials never overlap).
    """

    dt_ns: int
    samples: int
    period: int

    @classmethod
    def for_run(cls, dt: float, samples: int, gap: int = 20) -> SampleClock:
        if dt <= 0 or samples < 1 or gap < 1:
            raise ValueError("dt > 0, samples >= 1 and gap >= 1 are required")
        return cls(int(round(dt * 1e9)), int(samples), int(samples) + 1 + int(gap))

    def stamp_ns(self, trial: int, sample: int) -> int:
        return (int(trial) * self.period + int(sample)) * self.dt_ns

    def decode(self, ns: int) -> tuple[int, int]:
        """(trial, sample) of the grid point nearest to ``ns``; MalformedMessage if off the
        trial (a negative time or a sample outside 0..T)."""
        if ns < 0:
            raise MalformedMessage(f"negative stamp {ns} ns")
        q = (ns + self.dt_ns // 2) // self.dt_ns
        k, s = divmod(q, self.period)
        if s > self.samples:
            raise MalformedMessage(f"stamp {ns} ns is between trials (sample {s} of "
                                   f"{self.samples})")
        return int(k), int(s)


def stamp_to_ns(stamp: Time) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def ns_to_stamp(ns: int, out: Time | None = None) -> Time:
    t = Time() if out is None else out
    t.sec, t.nanosec = divmod(int(ns), 1_000_000_000)
    return t


def clock_msg(ns: int) -> Clock:
    m = Clock()
    ns_to_stamp(ns, m.clock)
    return m


# --------------------------------------------------------------------------- poses

def _heading_from_quaternion(x: float, y: float, z: float, w: float,
                             previous: float | None) -> float:
    """Yaw of a planar quaternion, unwrapped next to ``previous`` (same formula as
    formation_ilc.kinematics.heading_from_quaternion, inlined: this is the hot path)."""
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z) and math.isfinite(w)):
        raise MalformedMessage("non-finite orientation")
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    if abs(norm - 1.0) > 1e-6 or abs(x) > 1e-6 or abs(y) > 1e-6:
        raise MalformedMessage("orientation is not a unit rotation about z")
    th = 2.0 * math.atan2(z, w)
    ref = 0.0 if previous is None else previous
    d = th - ref
    return ref + (d - 2.0 * math.pi * math.ceil((d - math.pi) / (2.0 * math.pi)))


def pose_to_msg(eta: Sequence[float] | NDArray[np.float64], stamp_ns: int, frame_id: str,
                out: PoseStamped | None = None) -> PoseStamped:
    """Planar output eta = (x [m], y [m], theta [rad]) as a PoseStamped."""
    m = PoseStamped() if out is None else out
    ns_to_stamp(stamp_ns, m.header.stamp)
    m.header.frame_id = frame_id
    x, y, th = float(eta[0]), float(eta[1]), float(eta[2])
    m.pose.position.x = x
    m.pose.position.y = y
    m.pose.position.z = 0.0
    q = m.pose.orientation
    q.x = 0.0
    q.y = 0.0
    q.z = math.sin(0.5 * th)
    q.w = math.cos(0.5 * th)
    return m


def msg_to_pose(msg: PoseStamped, previous_heading: float | None = None
                ) -> tuple[NDArray[np.float64], int, str]:
    """(eta (3,), stamp [ns], frame_id). The heading is unwrapped next to
    ``previous_heading`` (pass the expected value, e.g. the desired heading), else wrapped
    to (-pi, pi]."""
    p = msg.pose.position
    x, y = float(p.x), float(p.y)
    if not (math.isfinite(x) and math.isfinite(y)):
        raise MalformedMessage("non-finite position")
    q = msg.pose.orientation
    th = _heading_from_quaternion(q.x, q.y, q.z, q.w, previous_heading)
    return np.array((x, y, th)), stamp_to_ns(msg.header.stamp), str(msg.header.frame_id)


def u_to_twist(u: Sequence[float] | NDArray[np.float64], out: Twist | None = None) -> Twist:
    """u = (v [m/s], omega [rad/s]) as a Twist (linear.x, angular.z)."""
    m = Twist() if out is None else out
    m.linear.x = float(u[0])
    m.angular.z = float(u[1])
    return m


def twist_to_u(msg: Twist) -> NDArray[np.float64]:
    """(v, omega); MalformedMessage if non-finite or not planar."""
    v, w = float(msg.linear.x), float(msg.angular.z)
    other = (msg.linear.y, msg.linear.z, msg.angular.x, msg.angular.y)
    if not (math.isfinite(v) and math.isfinite(w)) or any(o != 0.0 for o in other):
        raise MalformedMessage("cmd_vel is not a finite planar (v, omega) command")
    return np.array((v, w))


# --------------------------------------------------------------------------- trajectories

def trajectory_to_path(eta: NDArray[np.float64], stamps_ns: Iterable[int],
                       frame_id: str) -> Path:
    """Whole-trial output eta (T+1, 3) as a Path; pose s is stamped with its label."""
    m = Path()
    stamps = list(stamps_ns)
    if len(stamps) != len(eta):
        raise ValueError("one stamp per sample is required")
    m.header.frame_id = frame_id
    if stamps:
        ns_to_stamp(stamps[-1], m.header.stamp)
    m.poses = [pose_to_msg(e, s, frame_id) for e, s in zip(eta, stamps, strict=True)]
    return m


def path_to_trajectory(msg: Path, reference_heading: NDArray[np.float64] | None = None
                       ) -> tuple[NDArray[np.float64], NDArray[np.int64], str]:
    """(eta (S, 3), stamps (S,) [ns], frame_id). Headings are unwrapped next to
    ``reference_heading`` (S,) when given (e.g. the desired headings), else against the
    previous pose. MalformedMessage if a pose is invalid or names another frame."""
    n = len(msg.poses)
    if reference_heading is not None and len(reference_heading) != n:
        raise MalformedMessage(f"trajectory has {n} poses, expected {len(reference_heading)}")
    eta = np.empty((n, 3))
    stamps = np.empty(n, dtype=np.int64)
    frame = str(msg.header.frame_id)
    prev: float | None = None
    for s, ps in enumerate(msg.poses):
        ref = prev if reference_heading is None else float(reference_heading[s])
        e, ns, f = msg_to_pose(ps, ref)
        if f != frame:
            raise MalformedMessage(f"pose {s} of a {frame!r} trajectory is in frame {f!r}")
        eta[s] = e
        stamps[s] = ns
        prev = float(e[2])
    return eta, stamps, frame


# --------------------------------------------------------------------------- bundles

@dataclass(frozen=True)
class Delivery:
    """One pose a link delivered: sender (``robot_j`` or ``leader``), its original label
    [ns], and the decoded output (heading wrapped; unwrap at the receiver)."""

    sender: str
    stamp_ns: int
    eta: NDArray[np.float64]


def bundle_to_msg(tick_ns: int, receiver: str, poses: Iterable[PoseStamped]) -> Path:
    """A tick's deliveries for ``receiver``; the poses are forwarded unchanged (original
    stamp and sender frame)."""
    m = Path()
    ns_to_stamp(tick_ns, m.header.stamp)
    m.header.frame_id = receiver
    m.poses = list(poses)
    return m


def msg_to_bundle(msg: Path) -> tuple[int, str, list[PoseStamped]]:
    """(tick [ns], receiver, raw poses). Poses are decoded one by one by the receiver, so
    one bad pose costs only itself."""
    return stamp_to_ns(msg.header.stamp), str(msg.header.frame_id), list(msg.poses)


# --------------------------------------------------------------------------- JSON strings

def json_to_msg(data: dict[str, Any]) -> String:
    return String(data=json.dumps(data, separators=(",", ":")))


def msg_to_json(msg: String, required: Sequence[str] = ()) -> dict[str, Any]:
    """The JSON object in a String; MalformedMessage if it is not one or lacks a key."""
    try:
        data = json.loads(msg.data)
    except (ValueError, TypeError) as exc:
        raise MalformedMessage(f"not JSON: {exc}") from None
    if not isinstance(data, dict):
        raise MalformedMessage("JSON is not an object")
    missing = [k for k in required if k not in data]
    if missing:
        raise MalformedMessage(f"JSON lacks {missing}")
    return data


# --------------------------------------------------------------------------- topic table

def topic_table(n: int) -> list[tuple[str, str, QoSProfile]]:
    """Every topic of a run of ``n`` robots: (name, ROS type name, offered QoS).

    The recorder subscribes to exactly these; the batch simulator records on them too.
    """
    rows: list[tuple[str, str, QoSProfile]] = [
        (CONFIG, "std_msgs/msg/String", LATCHED_QOS),
        (REFERENCE, "geometry_msgs/msg/PoseStamped", SAMPLE_QOS),
        (TRIAL_EVENTS, "std_msgs/msg/String", SAMPLE_QOS),
        (READY, "std_msgs/msg/String", LATCHED_QOS),
        (DIAGNOSTICS, "std_msgs/msg/String", LATCHED_QOS),
        (CLOCK, "rosgraph_msgs/msg/Clock", CLOCK_QOS),
    ]
    for i in range(1, n + 1):
        rows += [
            (pose_topic(i), "geometry_msgs/msg/PoseStamped", SAMPLE_QOS),
            (cmd_vel_topic(i), "geometry_msgs/msg/Twist", SAMPLE_QOS),
            (shared_pose_topic(i), "geometry_msgs/msg/PoseStamped", SAMPLE_QOS),
            (neighbour_poses_topic(i), "nav_msgs/msg/Path", SAMPLE_QOS),
            (trajectory_topic(i), "nav_msgs/msg/Path", TRAJECTORY_QOS),
            (true_trajectory_topic(i), "nav_msgs/msg/Path", TRAJECTORY_QOS),
        ]
    return rows
