"""The wire contract of the distributed stack: topic names, message types, QoS, converters.

This module is the one place that names a topic. Every node, the launcher and the tests
import names and profiles from here; numpy <-> message converters live here too and are
tested by round trip (tests/nodes/test_msgs_schema.py). Standard messages only.

Names are relative: a node resolves them in its namespace (``NAMESPACE`` by default;
``--ros-args -r __ns:=/team2`` moves one node, ``formation-ilc launch --namespace /team2`` a
whole formation), so several formations share a ROS domain. ``/clock`` is the ROS
convention's absolute name; a namespaced launch remaps it into the namespace too.

Topics (robot ``i`` is 1-based in names, index ``i - 1`` in arrays; ``S`` a sender,
``robot_j`` or ``leader``):

=========================  ===========================  ==================================
topic                      type                         from -> to
=========================  ===========================  ==================================
config                     std_msgs/String (JSON)       leader -> all (latched)
leader/reference           geometry_msgs/PoseStamped    leader -> robots that see it, links
leader/trial_events        std_msgs/String (JSON)       leader -> all
ready                      std_msgs/String (JSON)       all -> leader (latched)
diagnostics                diagnostic_msgs/             all -> monitor, recorder,
                           DiagnosticArray              ROS tools (latched)
robot_i/pose               geometry_msgs/PoseStamped    plant -> robot i
robot_i/cmd_vel            geometry_msgs/Twist          robot i -> plant
robot_i/shared_pose        geometry_msgs/PoseStamped    robot i -> out-neighbours (direct),
                                                        link emulator (emulated)
robot_i/links/S            nav_msgs/Path (0 or 1 pose)  link emulator -> robot i (emulated)
robot_i/trajectory         nav_msgs/Path (trial end)    robot i -> out-neighbours, monitor
robot_i/true_trajectory    nav_msgs/Path (trial end)    simulator (optional) -> monitor
/clock                     rosgraph_msgs/Clock          plant, in simulated time -> all
preview/poses              nav_msgs/Path (every         simulator, <= PREVIEW_HZ while
                           robot's pose of a sample)    read -> live view (not recorded)
team/poses                 nav_msgs/Path (every         simulator, physics plant (every
                           robot's pose of a sample)    sample, with a safety filter) ->
                                                        robots' safety filters
=========================  ===========================  ==================================

Frames (REP-105). Every pose and path is in the world-fixed frame ``WORLD_FRAME`` ("map");
the topic names whose pose it is. Diagnostics and ready messages name their node in JSON.

Time labels (``formation_ilc.core.clock.SampleClock``). A stamp is ``(k * period + s) * dT``
[ns] for trial ``k`` and sample ``s``. The plant stamps robot i's pose with the label of
its sample: the robot's clock Rt of eq. (11). The shared pose keeps that stamp as the send
label St; the robot measures each delay from St and its own Rt. An emulated link's message
for tick t is stamped t (the tick) and holds the pose delivered then, with its ORIGINAL
stamp, or no pose when nothing is delivered at t. In ``mode: wallclock`` (real robots)
stamps are wall time instead (``formation_ilc.core.clock.WallGrid``): sample s of slot q is
stamped ``start(q) + s * dT``, the start agreed by the leader's ``start`` event, whose
remainder by dT is q; the label (q, s) follows from the stamp exactly. Malformed input raises
:class:`MalformedMessage`, which nodes count and drop.

The per-sample messages (poses, shared poses, references, link ticks, ``cmd_vel``,
``/clock``) travel as CDR bytes that ``msgs_schema.wire`` packs and reads without rclpy's
message objects (the same bytes, the same checks); the converters below remain for
everything else and for tests.

The plant contract
------------------
A plant (the kinematic simulator, a hardware bridge, a test's stand-in) closes the loop for
robots 1..N. It

1. reads the run configuration on ``config`` (latched) and follows ``leader/trial_events``;
2. publishes, for each robot i and each sample s = 0..T of trial k, the measured pose on
   ``robot_i/pose`` (PoseStamped in ``WORLD_FRAME``, stamp ``stamp_ns(k, s)``); sample 0
   after the ``start`` event of trial k, sample s+1 after it applied sample s's command
   (``mode: wallclock``, real robots: sample s at the wall time
   ``start_wall_ns + s * dT``, ``start_wall_ns`` being in the ``start`` event, and stamped
   with that time);
3. applies ``robot_i/cmd_vel`` (Twist: ``linear.x`` = v [m/s], ``angular.z`` = omega
   [rad/s]) from its sample to the next; in lockstep it waits for every robot's command,
   in realtime it holds the last command of a robot that is late;
4. in simulated time owns ``/clock``: it publishes the sample's time before that sample's
   poses, and the leader broadcasts the reference on it (not in ``wallclock``: nobody
   publishes ``/clock``, the leader follows its own wall timer);
5. says ``{"node": NAME, "trial": k}`` on ``ready`` (latched) when it can run trial k
   (k = 0 once its publishers are matched; k+1 after sample T of trial k).

It may publish ``robot_i/true_trajectory`` (its ground truth) at trial end and its own
``diagnostics``; nothing in the stack needs them (metrics then lack the true-state columns).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped, Twist, TwistStamped
from nav_msgs.msg import Odometry, Path
from numpy.typing import NDArray
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from std_msgs.msg import String

from formation_ilc.core.clock import Malformed, SampleClock
from formation_ilc.core.kinematics import yaw_and_tilt
from formation_ilc.core.links import LEADER, link_name
from formation_ilc.core.names import (
    BRIDGE_PREFIX,
    CLOCK,
    FAKE_DRIVER_NODE,
    LEADER_NODE,
    LINKS_NODE,
    MONITOR_NODE,
    NAMESPACE,
    RECORDER_NODE,
    SIM_NODE,
    bridge_name,
    robot_name,
)
from formation_ilc.core.names import robot_number as robot_index
from formation_ilc.protocol.schedule import ABORT, DONE, END, START
from msgs_schema import wire
from msgs_schema.wire import check_nanosec, check_twist, heading_from_quaternion

__all__ = [
    "NAMESPACE", "CONFIG", "REFERENCE", "TRIAL_EVENTS", "READY", "DIAGNOSTICS", "CLOCK",
    "WORLD_FRAME", "LEADER", "LEADER_FRAME", "robot_name", "robot_index", "link_name",
    "pose_topic", "cmd_vel_topic", "shared_pose_topic", "link_topic", "trajectory_topic",
    "true_trajectory_topic", "absolute", "relative",
    "SAMPLE_QOS", "LATCHED_QOS", "LATCHED_READER_QOS", "TRAJECTORY_QOS",
    "TRAJECTORY_READER_QOS", "CLOCK_QOS",
    "MalformedMessage", "topic_table", "trial_trajectory",
    "SampleClock", "stamp_to_ns", "ns_to_stamp", "pose_to_msg", "msg_to_pose", "u_to_twist",
    "twist_to_u", "world_pose", "trajectory_to_path", "path_to_trajectory", "link_tick_to_msg",
    "msg_to_link_tick", "json_to_msg", "msg_to_json", "json_int", "deserialize", "clock_msg",
    "path_limit", "path_from_raw", "within_path_limit", "trajectory_from_raw", "FRAME_ID_MAX",
    "START", "END", "ABORT", "DONE",
    "DriverSpec", "DRIVERS", "DRIVER_CMD_QOS", "ODOM_QOS", "BRIDGE_PREFIX", "bridge_name",
    "odometry_to_pose", "base_odometry_to_pose", "odometry_msg", "driver_twist", "wire",
    "LEADER_NODE", "SIM_NODE", "LINKS_NODE", "MONITOR_NODE", "RECORDER_NODE",
    "FAKE_DRIVER_NODE",
]

# NAMESPACE (the default namespace of every node of a formation), CLOCK and the node names
# (LEADER_NODE, SIM_NODE, ..., robot_name, bridge_name) are formation_ilc.core.names', re-exported
CONFIG = "config"
REFERENCE = "leader/reference"
TRIAL_EVENTS = "leader/trial_events"
READY = "ready"
DIAGNOSTICS = "diagnostics"

#: REP-105 world-fixed frame of every pose and path
WORLD_FRAME = "map"
#: sender name of the leader's reference (link names ``leader->robot_i``)
LEADER_FRAME = LEADER
#: trial events (``event`` field of the JSON on TRIAL_EVENTS): START, END, ABORT, DONE,
#: defined with the protocol (slots, aborts, ready) in ``formation_ilc.protocol.schedule``


def pose_topic(i: int) -> str:
    """Measured pose of robot ``i`` (plant -> robot)."""
    return f"{robot_name(i)}/pose"


def cmd_vel_topic(i: int) -> str:
    return f"{robot_name(i)}/cmd_vel"


def shared_pose_topic(i: int) -> str:
    """Robot ``i``'s labelled output, for its neighbours (stamp = send label St)."""
    return f"{robot_name(i)}/shared_pose"


def link_topic(i: int, sender: str) -> str:
    """Emulated link ``sender -> robot_i``: one message per tick (0 or 1 pose)."""
    return f"{robot_name(i)}/links/{sender}"


def trajectory_topic(i: int) -> str:
    """Robot ``i``'s whole-trial measured output, sent at trial end."""
    return f"{robot_name(i)}/trajectory"


def true_trajectory_topic(i: int) -> str:
    """A simulator's ground truth (true state) of robot ``i`` for one trial, for metrics."""
    return f"{robot_name(i)}/true_trajectory"


def absolute(topic: str, namespace: str = NAMESPACE) -> str:
    """The full name of a topic in ``namespace`` (absolute names stay as they are)."""
    if topic.startswith("/"):
        return topic
    ns = namespace.rstrip("/")
    return f"{ns}/{topic}"


def relative(name: str, namespace: str = NAMESPACE) -> str:
    """The schema's name of a full topic name in ``namespace`` (inverse of ``absolute``)."""
    prefix = namespace.rstrip("/") + "/"
    return name[len(prefix):] if name.startswith(prefix) else name


# Lockstep must not lose a sample on localhost: reliable, and deep enough for a burst.
# The depth is also how far a passive reader (the recorder, niced, outside the lockstep)
# may fall behind before a writer drops samples it has not acknowledged: at 64, a recorder
# that stalled for about 0.25 s of a 280 samples/s run lost samples 70-76 of trial 1 (seen
# in CI); 512 gives it about 2 s.
SAMPLE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=512,
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
# Readers of trajectories: deeper than the writers' 2, because a reader's KEEP_LAST history
# is shared by every writer of the topic, and two stray writers' messages (a restarted
# node's, a forger's) taken in the same instant as a trial's trajectory would evict it.
TRAJECTORY_READER_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=32,
                                   reliability=ReliabilityPolicy.RELIABLE,
                                   durability=DurabilityPolicy.TRANSIENT_LOCAL)
# /clock: reliable writer (also serves rclpy's best-effort time-source readers); as deep
# as SAMPLE_QOS, for the recorder.
CLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=512,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)


#: a message that cannot be decoded into valid data: dropped and counted by nodes as
#: ``malformed`` (the core's ``Malformed``, a ``Rejected`` like every refused input)
MalformedMessage = Malformed


# --------------------------------------------------------------------------- Pioneer drivers

@dataclass(frozen=True)
class DriverSpec:
    """A Pioneer driver's side of the bridge: topic names relative to the driver's
    namespace (the bridge's ``driver_ns`` parameter; remap further with ``-r``).

    cmd : velocity command in (Twist, or TwistStamped with the bridge's ``cmd_type``);
    odom : nav_msgs/Odometry out, starting at 0 where the robot was placed;
    motors : how motors are enabled; motors_kind: 'empty_service' (std_srvs/Empty),
        'setbool_service' (std_srvs/SetBool, data true), 'p2os_motor_state'
        (p2os_msgs/MotorState with state 1, a topic) or 'none' (a base whose motors are
        always on: TurtleBot, Jackal, Husky);
    default_ns : the driver's usual namespace.
    """

    cmd: str
    odom: str
    motors: str
    motors_kind: str
    default_ns: str


DRIVERS: dict[str, DriverSpec] = {
    # RosAria (ROS 1 via ros1_bridge, or its ROS 2 ports): node RosAria
    "rosaria": DriverSpec("cmd_vel", "pose", "enable_motors", "empty_service", "/RosAria"),
    # p2os2 (p2os_driver): motors on by publishing p2os_msgs/MotorState{state: 1}
    "p2os2": DriverSpec("cmd_vel", "pose", "cmd_motor_state", "p2os_motor_state", "/"),
    # ros2aria: odometry on ``odom``; the motors are engaged through ``clutch``. Assumed a
    # std_srvs/SetBool service (true = engaged); not verified against the driver's source:
    # check ``ros2 interface`` on the robot, and remap or change motors_kind if it differs
    "ros2aria": DriverSpec("cmd_vel", "odom", "clutch", "setbool_service", "/"),
    # any differential-drive base with the common interface: cmd_vel in, nav_msgs/Odometry
    # out, no motor service (formation_ilc.config.bases has presets of the topic names)
    "base": DriverSpec("cmd_vel", "odom", "", "none", "/"),
}

# Drivers publish odometry best effort or reliable: a best-effort reader matches both.
ODOM_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                      reliability=ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.VOLATILE)
# A reliable, volatile writer matches both reliable and best-effort cmd_vel readers.
DRIVER_CMD_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                            reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.VOLATILE)


def odometry_to_pose(msg: Odometry) -> tuple[float, float, float]:
    """(x, y, yaw) of a driver's planar odometry; MalformedMessage if not planar/finite."""
    p = msg.pose.pose.position
    x, y = float(p.x), float(p.y)
    if not (math.isfinite(x) and math.isfinite(y)):
        raise MalformedMessage("non-finite odometry position")
    q = msg.pose.pose.orientation
    return x, y, _heading_from_quaternion(q.x, q.y, q.z, q.w, None)


def base_odometry_to_pose(msg: Odometry, max_tilt: float
                          ) -> tuple[float, float, float, float]:
    """(x, y, yaw, tilt) of a base's odometry, yaw from the full quaternion
    (``kinematics.yaw_and_tilt``): a base on a slope, or whose IMU-fused odometry carries
    roll and pitch, still has a heading. MalformedMessage if not finite, or tilted more
    than ``max_tilt`` [rad] (the odometry of a robot on its side is no planar pose)."""
    p = msg.pose.pose.position
    x, y = float(p.x), float(p.y)
    if not (math.isfinite(x) and math.isfinite(y)):
        raise MalformedMessage("non-finite odometry position")
    q = msg.pose.pose.orientation
    try:
        yaw, tilt = yaw_and_tilt(float(q.x), float(q.y), float(q.z), float(q.w))
    except ValueError as exc:
        raise MalformedMessage(str(exc)) from None
    if tilt > max_tilt:
        raise MalformedMessage(f"odometry tilted by {math.degrees(tilt):.1f} deg, beyond "
                               f"the bound of {math.degrees(max_tilt):.1f} deg (max_tilt)")
    return x, y, yaw, tilt


def odometry_msg(pose: Sequence[float], twist: Sequence[float], stamp_ns: int,
                 frame_id: str = "odom", child: str = "base_link",
                 out: Odometry | None = None,
                 quat: Sequence[float] | None = None) -> Odometry:
    """A driver's odometry message (for fake drivers and physics bases): pose (x, y, yaw),
    twist (v, omega); ``quat`` (x, y, z, w): the orientation with roll and pitch (default:
    the yaw alone)."""
    m = Odometry() if out is None else out
    ns_to_stamp(stamp_ns, m.header.stamp)
    m.header.frame_id = frame_id
    m.child_frame_id = child
    m.pose.pose.position.x = float(pose[0])
    m.pose.pose.position.y = float(pose[1])
    o = m.pose.pose.orientation
    if quat is None:
        o.x, o.y = 0.0, 0.0
        o.z, o.w = math.sin(0.5 * float(pose[2])), math.cos(0.5 * float(pose[2]))
    else:
        o.x, o.y, o.z, o.w = (float(c) for c in quat)
    m.twist.twist.linear.x = float(twist[0])
    m.twist.twist.angular.z = float(twist[1])
    return m


def driver_twist(v: float, omega: float, stamped: bool, stamp_ns: int = 0,
                 frame_id: str = "base_link") -> Twist | TwistStamped:
    """The command to a driver: Twist, or TwistStamped (Jazzy's diff_drive_controller)."""
    t = Twist()
    t.linear.x = float(v)
    t.angular.z = float(omega)
    if not stamped:
        return t
    m = TwistStamped()
    ns_to_stamp(stamp_ns, m.header.stamp)
    m.header.frame_id = frame_id
    m.twist = t
    return m


# --------------------------------------------------------------------------- time labels

def stamp_to_ns(stamp: Time) -> int:
    """[ns] of a stamp; MalformedMessage if ``nanosec`` is outside [0, 1e9) (a stamp from
    raw bytes). A negative ``sec`` gives a negative time, which every label check refuses."""
    nsec = int(stamp.nanosec)
    check_nanosec(nsec)
    return int(stamp.sec) * 1_000_000_000 + nsec


def ns_to_stamp(ns: int, out: Time | None = None) -> Time:
    t = Time() if out is None else out
    t.sec, t.nanosec = divmod(int(ns), 1_000_000_000)
    return t


def clock_msg(ns: int) -> Clock:
    m = Clock()
    ns_to_stamp(ns, m.clock)
    return m


# --------------------------------------------------------------------------- poses

#: yaw of a planar quaternion (the check and formula shared with the bytes converters)
_heading_from_quaternion = heading_from_quaternion


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


def world_pose(msg: PoseStamped, previous_heading: float | None = None
               ) -> tuple[NDArray[np.float64], int]:
    """(eta (3,), stamp [ns]) of a pose that must be in ``WORLD_FRAME``; see msg_to_pose."""
    eta, ns, frame = msg_to_pose(msg, previous_heading)
    if frame != WORLD_FRAME:
        raise MalformedMessage(f"pose in frame {frame!r}, expected {WORLD_FRAME!r}")
    return eta, ns


def u_to_twist(u: Sequence[float] | NDArray[np.float64], out: Twist | None = None) -> Twist:
    """u = (v [m/s], omega [rad/s]) as a Twist (linear.x, angular.z)."""
    m = Twist() if out is None else out
    m.linear.x = float(u[0])
    m.angular.z = float(u[1])
    return m


def twist_to_u(msg: Twist) -> NDArray[np.float64]:
    """(v, omega); MalformedMessage if non-finite or not planar."""
    return check_twist(float(msg.linear.x), float(msg.angular.z),
                       (msg.linear.y, msg.linear.z, msg.angular.x, msg.angular.y))


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


#: [bytes] a frame id of at most this many characters fits the size bound of a Path
FRAME_ID_MAX = 64


def path_limit(poses: int) -> int:
    """[bytes] the most a CDR ``nav_msgs/Path`` of at most ``poses`` PoseStamped can take
    when every frame id has at most FRAME_ID_MAX characters: encapsulation, header and
    sequence length, then per pose its header (stamp, frame id) and pose (7 float64),
    alignment included."""
    header = 8 + 4 + FRAME_ID_MAX + 1 + 7  # stamp, string length, text, NUL, padding
    return 4 + header + 4 + int(poses) * (header + 7 * 8)


def path_from_raw(data: bytes | Path, poses: int, what: str = "Path") -> Path:
    """The Path in the CDR bytes of a raw subscription, refused (MalformedMessage) before
    it is deserialized when it is longer than a Path of ``poses`` poses can be: a forged
    trajectory of megabytes costs a length check, not a minute of building Python
    objects. A Path already built (an in-process caller) is returned as it is."""
    if isinstance(data, Path):
        return data
    msg: Path = deserialize(within_path_limit(data, poses, what), Path)
    return msg


def trajectory_from_raw(data: bytes | Path, poses: int,
                        reference_heading: NDArray[np.float64] | None = None,
                        what: str = "trajectory"
                        ) -> tuple[NDArray[np.float64], NDArray[np.int64], str]:
    """``path_to_trajectory`` of the Path in the CDR bytes of a raw subscription, refused
    first by its size (``path_from_raw``) and read without message objects
    (``wire.read_trajectory``: the same values and checks); a Path already built (an
    in-process caller) goes through ``path_to_trajectory``."""
    if isinstance(data, Path):
        return path_to_trajectory(data, reference_heading)
    return wire.read_trajectory(within_path_limit(wire.as_bytes(data), poses, what),
                                reference_heading)


def trial_trajectory(data: bytes | Path, clock: SampleClock,
                     reference_heading: NDArray[np.float64]
                     ) -> tuple[int, NDArray[np.float64], NDArray[np.int64]]:
    """A robot's whole-trial trajectory (``robot_i/trajectory``), as the launcher's monitor
    and the live view take it: (slot, eta (T+1, 3), stamps [ns]), headings unwrapped next
    to ``reference_heading`` (T+1,); MalformedMessage if it is not in the world frame or
    its stamps are not samples 0..T of one slot."""
    eta, stamps, frame = trajectory_from_raw(data, len(reference_heading), reference_heading)
    if frame != WORLD_FRAME:
        raise MalformedMessage(f"trajectory in frame {frame[:50]!r}")
    k, s0 = clock.decode(int(stamps[0]))
    if s0 != 0 or any(int(x) != clock.stamp_ns(k, s) for s, x in enumerate(stamps)):
        raise MalformedMessage("stamps are not samples 0..T of one trial")
    return k, eta, stamps


def within_path_limit(data: bytes, poses: int, what: str = "Path") -> bytes:
    """``data``, the CDR bytes of a Path; MalformedMessage if they are longer than a Path
    of ``poses`` poses can be (``path_limit``), checked before anything reads them."""
    limit = path_limit(poses)
    if len(data) > limit:
        raise MalformedMessage(f"{what} of {len(data)} bytes: longer than {poses} poses can "
                               f"be ({limit} bytes)")
    return data


# --------------------------------------------------------------------------- emulated links

def link_tick_to_msg(tick_ns: int, pose: PoseStamped | None) -> Path:
    """What an emulated link delivers at the tick ``tick_ns``: the pose as it was sent
    (original stamp St), or nothing."""
    m = Path()
    ns_to_stamp(tick_ns, m.header.stamp)
    m.header.frame_id = WORLD_FRAME
    m.poses = [] if pose is None else [pose]
    return m


def msg_to_link_tick(msg: Path) -> tuple[int, PoseStamped | None]:
    """(tick [ns], the delivered pose or None); MalformedMessage if it holds more than one."""
    if len(msg.poses) > 1:
        raise MalformedMessage(f"a link delivers at most one pose per tick, got "
                               f"{len(msg.poses)}")
    return stamp_to_ns(msg.header.stamp), (msg.poses[0] if msg.poses else None)


# --------------------------------------------------------------------------- JSON strings

def deserialize(data: bytes, cls: Any) -> Any:
    """The message of type ``cls`` in CDR bytes (a raw subscription, a recording);
    MalformedMessage if they do not decode."""
    from rclpy.serialization import deserialize_message

    try:
        return deserialize_message(bytes(data), cls)
    except (RuntimeError, ValueError, TypeError) as exc:  # rclpy's RMWError is a RuntimeError
        raise MalformedMessage(f"undecodable {cls.__name__}: {exc}"[:200]) from None


def json_int(data: dict[str, Any], key: str) -> int:
    """The integer ``data[key]``; MalformedMessage if absent or not an integer (JSON
    ``true``, ``1.5`` and ``"3"`` are not trial numbers)."""
    v = data.get(key)
    if isinstance(v, bool) or not isinstance(v, int):
        raise MalformedMessage(f"{key!r} is not an integer: {v!r}"[:200])
    return v


def json_to_msg(data: dict[str, Any]) -> String:
    return String(data=json.dumps(data, separators=(",", ":")))


def msg_to_json(msg: String, required: Sequence[str] = ()) -> dict[str, Any]:
    """The JSON object in a String; MalformedMessage if it is not one or lacks a key."""
    try:
        data = json.loads(msg.data)
    except (ValueError, TypeError, RecursionError) as exc:  # nesting beyond the parser's
        raise MalformedMessage(f"not JSON: {exc}"[:200]) from None
    if not isinstance(data, dict):
        raise MalformedMessage("JSON is not an object")
    missing = [k for k in required if k not in data]
    if missing:
        raise MalformedMessage(f"JSON lacks {missing}")
    return data


# --------------------------------------------------------------------------- topic table

def topic_table(n: int) -> list[tuple[str, str, QoSProfile]]:
    """Every recorded topic of a run of ``n`` robots: (relative name, ROS type, offered QoS).

    The recorder subscribes to exactly these; the batch simulator records on them too. Two
    kinds of message are left out because they repeat others bit for bit: the shared poses
    (``shared_pose_topic``: a robot re-sends its measured pose unchanged, label included)
    and the emulated links' per-tick messages (``link_topic``: shared poses and the
    reference, forwarded). The delays the links carried are in each robot's diagnostics.
    """
    rows: list[tuple[str, str, QoSProfile]] = [
        (CONFIG, "std_msgs/msg/String", LATCHED_QOS),
        (REFERENCE, "geometry_msgs/msg/PoseStamped", SAMPLE_QOS),
        (TRIAL_EVENTS, "std_msgs/msg/String", SAMPLE_QOS),
        (READY, "std_msgs/msg/String", LATCHED_QOS),
        (DIAGNOSTICS, DIAGNOSTICS_TYPE, LATCHED_QOS),
        (CLOCK, "rosgraph_msgs/msg/Clock", CLOCK_QOS),
    ]
    for i in range(1, n + 1):
        rows += [
            (pose_topic(i), "geometry_msgs/msg/PoseStamped", SAMPLE_QOS),
            (cmd_vel_topic(i), "geometry_msgs/msg/Twist", SAMPLE_QOS),
            (trajectory_topic(i), "nav_msgs/msg/Path", TRAJECTORY_QOS),
            (true_trajectory_topic(i), "nav_msgs/msg/Path", TRAJECTORY_QOS),
        ]
    return rows


# =========================================================================== view topics
# What the formation should be, for the live view and the recording (issue 18, part B).
# Published by one observer (``formation_ilc.nodes.observer``: in the recorder, or in the
# live view's bridge when nothing records); the robots are untouched.
#
# =========================  ===============================  ================================
# topic                      type                             content
# =========================  ===============================  ================================
# robot_i/desired_pose       geometry_msgs/PoseStamped        eta_d of each sample (its label)
# robot_i/desired_path       nav_msgs/Path (latched)          eta_d of a whole trial, at start
# robot_i/tracking_error     geometry_msgs/Vector3Stamped     per sample: x position error
#                                                             |p_d - p| [m], y heading error
#                                                             wrap(th_d - th) [rad], z 0
# robot_i/trial_error        geometry_msgs/Vector3Stamped     per trial: x max position error,
#                                                             y max |heading error|, z trial
# markers                    visualization_msgs/MarkerArray   outline, links, labels, errors
# =========================  ===============================  ================================

from geometry_msgs.msg import Point, Vector3Stamped  # noqa: E402
from visualization_msgs.msg import Marker, MarkerArray  # noqa: E402

__all__ += ["MARKERS", "desired_pose_topic", "desired_path_topic", "tracking_error_topic",
            "trial_error_topic", "VIEW_QOS", "view_topic_table", "vector_msg", "markers_msg",
           "MarkersTemplate"]

MARKERS = "markers"
#: per-sample view messages: reliable to the recorder, never held for a viewer (depth-bound)
VIEW_QOS = SAMPLE_QOS


def desired_pose_topic(i: int) -> str:
    return f"{robot_name(i)}/desired_pose"


def desired_path_topic(i: int) -> str:
    return f"{robot_name(i)}/desired_path"


def tracking_error_topic(i: int) -> str:
    return f"{robot_name(i)}/tracking_error"


def trial_error_topic(i: int) -> str:
    return f"{robot_name(i)}/trial_error"


#: the plant's preview of the team for viewers: a nav_msgs/Path stamped with a sample's
#: label holding every robot's measured pose of that sample (the bytes it sends on
#: robot_i/pose), at most ``PREVIEW_HZ`` a second of wall time, and only while a reader
#: takes it. A lockstep run makes hundreds of samples a second; a viewer that takes the
#: preview instead of every pose costs the run one message per frame, not one per robot
#: and sample. Best effort: the plant never waits for a viewer. Not recorded (the poses
#: are).
PREVIEW = "preview/poses"
#: every robot's measured pose of a sample in one message, for the robots' safety filters
#: (``core.safety``): what a motion-capture system gives, once per sample from the plant
#: (the simulator, the physics plant) when the run has a filter with ``sensing: team``.
#: Pose i is robot i + 1's, each stamped with the sample's label as on robot_i/pose.
#: Reliable, like every per-sample topic: in lockstep a robot waits for it.
TEAM_POSES = "team/poses"
PREVIEW_HZ = 30.0
PREVIEW_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2,
                         reliability=ReliabilityPolicy.BEST_EFFORT,
                         durability=DurabilityPolicy.VOLATILE)
__all__ += ["PREVIEW", "PREVIEW_HZ", "PREVIEW_QOS", "TEAM_POSES"]


def view_topic_table(n: int) -> list[tuple[str, str, QoSProfile]]:
    """The observer's topics for ``n`` robots: (relative name, ROS type, offered QoS)."""
    rows: list[tuple[str, str, QoSProfile]] = [
        (MARKERS, "visualization_msgs/msg/MarkerArray", VIEW_QOS)]
    for i in range(1, n + 1):
        rows += [
            (desired_pose_topic(i), "geometry_msgs/msg/PoseStamped", VIEW_QOS),
            (desired_path_topic(i), "nav_msgs/msg/Path", TRAJECTORY_QOS),
            (tracking_error_topic(i), "geometry_msgs/msg/Vector3Stamped", VIEW_QOS),
            (trial_error_topic(i), "geometry_msgs/msg/Vector3Stamped", TRAJECTORY_QOS),
        ]
    return rows


def vector_msg(stamp_ns: int, x: float, y: float, z: float = 0.0,
               frame_id: str = WORLD_FRAME) -> Vector3Stamped:
    m = Vector3Stamped()
    ns_to_stamp(stamp_ns, m.header.stamp)
    m.header.frame_id = frame_id
    m.vector.x, m.vector.y, m.vector.z = float(x), float(y), float(z)
    return m


def _marker(stamp_ns: int, ns: str, mid: int, kind: int, rgba: tuple[float, ...],
            width: float) -> Marker:
    m = Marker()
    ns_to_stamp(stamp_ns, m.header.stamp)
    m.header.frame_id = WORLD_FRAME
    m.ns, m.id, m.type, m.action = ns, mid, kind, Marker.ADD
    m.pose.orientation.w = 1.0
    m.scale.x = m.scale.y = m.scale.z = width
    m.color.r, m.color.g, m.color.b, m.color.a = rgba
    m.frame_locked = False
    return m


def _point(xy: Sequence[float]) -> Point:
    return Point(x=float(xy[0]), y=float(xy[1]), z=0.0)


def markers_msg(stamp_ns: int, desired: Sequence[Sequence[float]], outline: Sequence[int],
                links: Sequence[tuple[int, int]],
                positions: dict[int, tuple[float, float]]) -> MarkerArray:
    """The 3D view's markers at one sample (robot index r is ``robot_{r+1}``):
    ``formation`` the desired positions (N, >=2) joined in ``outline`` order (closed);
    ``links`` the graph's links (sender, receiver) between measured ``positions``;
    ``errors`` each measured position to its desired one; ``labels`` the robots' names."""
    out = MarkerArray()
    shape = _marker(stamp_ns, "formation", 0, Marker.LINE_STRIP, (0.6, 0.6, 0.6, 1.0), 0.03)
    shape.points = [_point(desired[r]) for r in (*outline, outline[0])]
    lk = _marker(stamp_ns, "links", 0, Marker.LINE_LIST, (0.2, 0.4, 1.0, 0.8), 0.02)
    lk.points = [_point(positions[r]) for j, i in links for r in (j, i)]
    err = _marker(stamp_ns, "errors", 0, Marker.LINE_LIST, (1.0, 0.2, 0.2, 1.0), 0.02)
    err.points = [_point(xy) for r in sorted(positions) for xy in (positions[r], desired[r])]
    out.markers = [shape, lk, err]
    for r in sorted(positions):
        label = _marker(stamp_ns, "labels", r + 1, Marker.TEXT_VIEW_FACING,
                        (1.0, 1.0, 1.0, 1.0), 0.25)
        label.pose.position = _point(positions[r])
        label.pose.position.z = 0.3
        label.text = robot_name(r + 1)
        out.markers.append(label)
    return out


# Per-sample view messages are built from CDR templates: a message serialized once, whose
# stamp (and vector) are then written in place. The observer's cost per pose is then a few
# struct calls, not rclpy's (de)serialization (about 0.5 ms a pose on a loaded 2-core box).

import struct as _struct  # noqa: E402

_STAMP = _struct.Struct("<iI")
_VEC = _struct.Struct("<3d")
_POSE7 = _struct.Struct("<7d")


def _little_endian(data: bytes) -> bool:
    return len(data) >= 16 and data[0] == 0 and data[1] == 1  # CDR_LE encapsulation


def stamped_cdr(template: bytes | bytearray, stamp_ns: int) -> bytes:
    """A serialized stamped message (little-endian CDR, header first) with its stamp set."""
    out = bytearray(template)
    _STAMP.pack_into(out, 4, *divmod(int(stamp_ns), 1_000_000_000))
    return bytes(out)


def _body_offset(data: bytes | bytearray) -> int:
    """Where the body after a Header starts in little-endian CDR (aligned to 8 bytes,
    alignment counted from after the 4-byte encapsulation)."""
    n = _struct.unpack_from("<I", data, 12)[0]
    end = 16 + n
    return 4 + ((end - 4 + 7) // 8) * 8


def vector_cdr(template: bytes | bytearray, stamp_ns: int, x: float, y: float,
               z: float) -> bytes:
    """A Vector3Stamped's CDR (``template`` from ``vector_msg``) with stamp and vector set."""
    out = bytearray(template)
    _STAMP.pack_into(out, 4, *divmod(int(stamp_ns), 1_000_000_000))
    _VEC.pack_into(out, _body_offset(out), float(x), float(y), float(z))
    return bytes(out)


class MarkersTemplate:
    """``markers_msg`` of one team layout as CDR bytes, written in place per sample.

    The markers of an ``n``-robot team with a given ``outline`` and ``links`` always have
    the same size: ``markers_msg`` is serialized once with sentinel coordinates and stamp,
    the offsets of each sentinel are found, and :meth:`cdr` writes a sample's stamp and
    coordinates there (about 50 struct calls instead of building and serializing six
    Markers: 1.2 ms a sample with rclpy). The bytes equal ``markers_msg``'s serialized
    (tests/protocol/test_view.py)."""

    _SEC, _NSEC = 2_000_000_011, 123_456_789

    def __init__(self, n: int, outline: Sequence[int], links: Sequence[tuple[int, int]]):
        from rclpy.serialization import serialize_message

        sentinel = lambda k: 1.0e9 + 7.0 * k + 0.3125  # noqa: E731 (exact in binary)
        desired = [(sentinel(2 * r), sentinel(2 * r + 1)) for r in range(n)]
        positions = {r: (sentinel(2 * (n + r)), sentinel(2 * (n + r) + 1)) for r in range(n)}
        stamp = self._SEC * 1_000_000_000 + self._NSEC
        self.template = bytes(serialize_message(
            markers_msg(stamp, desired, outline, links, positions)))
        self.n = n

        def find(packed: bytes) -> list[int]:
            out, at = [], self.template.find(packed)
            while at >= 0:
                out.append(at)
                at = self.template.find(packed, at + 1)
            return out

        self.stamps = find(_STAMP.pack(self._SEC, self._NSEC))
        #: (offsets, source index): 0..2n-1 desired x/y of robot r, 2n.. measured x/y
        self.coords = [(find(_struct.pack("<d", sentinel(k))), k) for k in range(4 * n)]
        if len(self.stamps) != 3 + n or any(not offs for offs, _ in self.coords):
            raise RuntimeError("the markers template did not find every field")

    def cdr(self, stamp_ns: int, desired: NDArray[np.float64] | Sequence[Sequence[float]],
            positions: dict[int, tuple[float, float]]) -> bytes:
        """The serialized ``markers_msg(stamp_ns, desired, ..., positions)``; ``positions``
        has every robot of the team."""
        out = bytearray(self.template)
        sec_nsec = divmod(int(stamp_ns), 1_000_000_000)
        for at in self.stamps:
            _STAMP.pack_into(out, at, *sec_nsec)
        n = self.n
        pack = _struct.Struct("<d").pack_into
        for offs, k in self.coords:
            if k < 2 * n:
                v = float(desired[k // 2][k % 2])
            else:
                v = float(positions[(k - 2 * n) // 2][k % 2])
            for at in offs:
                pack(out, at, v)
        return bytes(out)


def world_pose_cdr(data: bytes) -> tuple[NDArray[np.float64], int]:
    """(eta, stamp [ns]) of a PoseStamped's CDR bytes, checked as ``world_pose`` checks the
    message (heading wrapped); MalformedMessage otherwise."""
    if not _little_endian(data):
        return world_pose(deserialize(data, PoseStamped))
    try:
        sec, nsec = _STAMP.unpack_from(data, 4)
        n = _struct.unpack_from("<I", data, 12)[0]
        frame = bytes(data[16:16 + n]).rstrip(b"\0")
        px, py, _pz, qx, qy, qz, qw = _POSE7.unpack_from(data, _body_offset(data))
    except _struct.error:
        raise MalformedMessage("truncated PoseStamped") from None
    if frame != WORLD_FRAME.encode():
        raise MalformedMessage(f"pose in frame {frame[:50]!r}, expected {WORLD_FRAME!r}")
    if not 0 <= nsec < 1_000_000_000 or not (math.isfinite(px) and math.isfinite(py)):
        raise MalformedMessage("invalid stamp or non-finite position")
    th = _heading_from_quaternion(qx, qy, qz, qw, None)
    return np.array((px, py, th)), sec * 1_000_000_000 + nsec


__all__ += ["stamped_cdr", "vector_cdr", "world_pose_cdr"]


# =========================================================================== diagnostics
# Standard diagnostics (diagnostic_msgs/DiagnosticArray on ``diagnostics``): a node's report
# as statuses with levels and key/value pairs (formation_ilc.protocol.health), which the
# monitor, the recorder and analyze read back without loss, and ROS tools show.

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue  # noqa: E402

from formation_ilc.protocol.health import Status, flatten, statuses, unflatten  # noqa: E402

__all__ += ["DIAGNOSTICS_TYPE", "diagnostics_to_msg", "msg_to_statuses", "msg_to_report"]

DIAGNOSTICS_TYPE = "diagnostic_msgs/msg/DiagnosticArray"
#: the most statuses and key/value pairs a diagnostics message may carry to be read
DIAG_STATUS_MAX = 1024
DIAG_VALUES_MAX = 100_000


def diagnostics_to_msg(report: dict[str, Any], stamp_ns: int, dt: float | None = None,
                       samples: int | None = None, hardware_id: str = "") -> DiagnosticArray:
    """The DiagnosticArray of one node's report (``health.statuses``: levels by the
    documented thresholds; ``dt`` [s] and ``samples`` per trial make the relative ones)."""
    msg = DiagnosticArray()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    for st in statuses(report, dt, samples, hardware_id):
        msg.status.append(DiagnosticStatus(
            level=bytes([st.level]), name=st.name, message=st.message,
            hardware_id=st.hardware_id,
            values=[KeyValue(key=k, value=v) for k, v in flatten(st.values)]))
    return msg


def msg_to_statuses(msg: DiagnosticArray) -> list[Status]:
    """Every status of a DiagnosticArray with its fields back (MalformedMessage if one's
    values are not the pairs ``diagnostics_to_msg`` writes, or there are too many)."""
    if len(msg.status) > DIAG_STATUS_MAX:
        raise MalformedMessage(f"{len(msg.status)} statuses in one diagnostics message")
    out = []
    for st in msg.status:
        if len(st.values) > DIAG_VALUES_MAX:
            raise MalformedMessage(f"{len(st.values)} values in one status")
        try:
            values = unflatten((kv.key, kv.value) for kv in st.values)
        except (ValueError, RecursionError) as exc:
            raise MalformedMessage(f"status {st.name[:100]!r}: {exc}"[:200]) from None
        level = st.level[0] if isinstance(st.level, (bytes, bytearray)) else int(st.level)
        out.append(Status(level, st.name, st.message, st.hardware_id, values))
    return out


def msg_to_report(msg: DiagnosticArray, required: Sequence[str] = ()) -> dict[str, Any]:
    """The node's own report in a DiagnosticArray (the status that names its ``node``);
    MalformedMessage if there is none or it lacks a key of ``required``."""
    for st in msg_to_statuses(msg):
        if "node" in st.values:
            missing = [k for k in required if k not in st.values]
            if missing:
                raise MalformedMessage(f"diagnostics lack {missing}")
            return st.values
    raise MalformedMessage("diagnostics without a node's report")
