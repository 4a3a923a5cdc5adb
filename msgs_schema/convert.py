"""numpy <-> message converters of the stack's standard messages: stamps, poses, commands,
whole-trial paths, emulated links' ticks, JSON strings; tested by round trip
(tests/msgs_schema/). The per-sample messages travel as bytes (``msgs_schema.wire``); these
remain for everything else and for tests."""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped, Twist
from nav_msgs.msg import Path
from numpy.typing import NDArray
from rosgraph_msgs.msg import Clock
from std_msgs.msg import String

from formation_ilc.core.clock import Malformed, SampleClock
from formation_ilc.core.names import WORLD_FRAME
from formation_ilc.protocol import wire
from formation_ilc.protocol.wire import (
    check_nanosec,
    check_twist,
    heading_from_quaternion,
    json_int,
    json_object,
)
from msgs_schema.wire import as_bytes

__all__ = ["MalformedMessage", "stamp_to_ns", "ns_to_stamp", "clock_msg", "pose_to_msg",
           "msg_to_pose", "world_pose", "u_to_twist", "twist_to_u", "trajectory_to_path",
           "path_to_trajectory", "FRAME_ID_MAX", "path_limit", "path_from_raw",
           "trajectory_from_raw", "trial_trajectory", "within_path_limit", "link_tick_to_msg",
           "msg_to_link_tick", "deserialize", "json_int", "json_to_msg", "msg_to_json"]


#: a message that cannot be decoded into valid data: dropped and counted by nodes as
#: ``malformed`` (the core's ``Malformed``, a ``Rejected`` like every refused input)
MalformedMessage = Malformed



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
    th = heading_from_quaternion(q.x, q.y, q.z, q.w, previous_heading)
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
    return wire.read_trajectory(within_path_limit(as_bytes(data), poses, what),
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


def json_to_msg(data: dict[str, Any]) -> String:
    return String(data=json.dumps(data, separators=(",", ":")))


def msg_to_json(msg: String, required: Sequence[str] = ()) -> dict[str, Any]:
    """The JSON object in a String; MalformedMessage if it is not one or lacks a key
    (``wire.json_object``, which reads the same from the message's bytes)."""
    return json_object(msg.data, required)
