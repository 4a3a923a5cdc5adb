"""The per-sample messages as CDR bytes: packed and read without rclpy's message objects.

Every sample of a lockstep run moves about 20 messages per 6 robots (poses, shared poses,
references, link ticks, commands, ``/clock``). Through rclpy each one is a tree of Python
message objects converted to a C struct and serialised on publish, and the reverse on take:
on 2 shared cores that measured 60-80 us per publish and more per take, more than the
node's own work. The nodes' hot path instead publishes bytes (``Publisher.publish`` takes a
serialised message) and subscribes with ``raw=True``, and this module packs and reads those
bytes with ``struct`` (about 2 us a message).

Packing gives the bytes rclpy's serialiser gives (XCDR1, little endian; tested byte for
byte), and the doubles of a pose are computed exactly as ``pose_to_msg`` computes them, so
the numbers a node reads are the same bits either way. Reading accepts what a typed
subscription would decode: either byte order, XCDR1 or XCDR2 (final types, whose 8-byte
members align to 4), and a string read up to its first NUL. Bytes that do not decode raise
``Malformed`` instead of failing inside the middleware. The checks on the decoded values
(finite, planar, unit quaternion, nanoseconds below 1e9, the world frame) are the ones of
the message-object converters in ``msgs_schema``, written once here and called by both.

The module needs no ROS, so the recordings read what the nodes wrote with it too. The node
handlers take either bytes (from the wire) or a message object (tests call the handlers
directly with one): ``msgs_schema.wire.as_bytes()`` (ROS) turns the latter into its bytes.
"""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from formation_ilc.core.clock import Malformed

__all__ = ["RawPose", "pose_bytes", "read_pose", "raw_pose_bytes", "pose_eta",
           "world_eta", "twist_bytes", "read_twist", "clock_bytes", "read_clock",
           "applied_bytes", "read_applied",
           "link_tick_bytes", "read_link_tick", "path_bytes", "read_trajectory",
           "raw_pose", "pose_set_bytes", "read_pose_set", "read_pose_block",
           "read_time_reference",
           "check_nanosec", "heading_from_quaternion", "check_twist", "read_string",
           "read_diagnostics", "json_object", "json_int", "Frame", "tf_bytes"]

_LE = b"\x00\x01\x00\x00"  # CDR_LE encapsulation, no options
#: a PoseStamped in frame "map", little-endian XCDR1: sec, nanosec, frame length, frame,
#: then position and orientation (7 doubles, 8-aligned at offset 16 of the data)
_POSE_MAP = struct.Struct("<iII4s7d")
_TWIST = struct.Struct("<6d")
_CLOCK = struct.Struct("<iI")
_NS = 1_000_000_000


class RawPose(NamedTuple):
    """A PoseStamped as received: label [ns] (sec * 1e9 + nanosec, nanosec checked),
    frame_id, and the seven doubles of position (x, y, z) and orientation (qx, qy, qz,
    qw), bit for bit."""

    label_ns: int
    frame: str
    fields: tuple[float, float, float, float, float, float, float]


# --------------------------------------------------------------------------- value checks

def check_nanosec(nsec: int) -> None:
    """MalformedMessage if a stamp's ``nanosec`` is outside [0, 1e9)."""
    if not 0 <= nsec < _NS:
        raise Malformed(f"stamp nanosec {nsec} outside [0, 1e9)")


def heading_from_quaternion(x: float, y: float, z: float, w: float,
                            previous: float | None) -> float:
    """Yaw of a planar quaternion, unwrapped next to ``previous`` (same formula as
    formation_ilc.core.kinematics.heading_from_quaternion, inlined: this is the hot path)."""
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z) and math.isfinite(w)):
        raise Malformed("non-finite orientation")
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    if abs(norm - 1.0) > 1e-6 or abs(x) > 1e-6 or abs(y) > 1e-6:
        raise Malformed("orientation is not a unit rotation about z")
    th = 2.0 * math.atan2(z, w)
    ref = 0.0 if previous is None else previous
    d = th - ref
    return ref + (d - 2.0 * math.pi * math.ceil((d - math.pi) / (2.0 * math.pi)))


def check_twist(v: float, w: float, other: Sequence[float]) -> NDArray[np.float64]:
    """(v, omega); MalformedMessage if non-finite or not planar (``other``: linear.y,
    linear.z, angular.x, angular.y, which must be 0)."""
    if not (math.isfinite(v) and math.isfinite(w)) or any(o != 0.0 for o in other):
        raise Malformed("cmd_vel is not a finite planar (v, omega) command")
    return np.array((v, w))


# --------------------------------------------------------------------------- reading

class _Reader:
    """Sequential reader of one CDR payload (alignment relative to the data after the
    4-byte encapsulation header); Malformed when the bytes run out."""

    __slots__ = ("data", "pos", "order", "max_align")

    def __init__(self, data: bytes):
        if len(data) < 4 or data[0] != 0 or data[1] not in (0, 1, 6, 7):
            raise Malformed(f"not a CDR message (encapsulation {bytes(data[:2]).hex()})")
        self.data = data
        self.pos = 4
        self.order = "<" if data[1] & 1 else ">"
        self.max_align = 4 if data[1] >= 6 else 8  # XCDR2 aligns 8-byte members to 4

    def take(self, fmt: str, size: int, align: int) -> tuple[Any, ...]:
        a = min(align, self.max_align)
        self.pos += (-(self.pos - 4)) % a
        end = self.pos + size
        if end > len(self.data):
            raise Malformed("message cut short")
        out = struct.unpack_from(self.order + fmt, self.data, self.pos)
        self.pos = end
        return out

    def string(self) -> str:
        (n,) = self.take("I", 4, 4)
        end = self.pos + n
        if end > len(self.data):
            raise Malformed("string past the end of the message")
        raw = self.data[self.pos:end]
        self.pos = end
        # a typed subscription reads the string as C does: up to its first NUL
        return raw.split(b"\x00", 1)[0].decode("utf-8", "replace")

    def stamp(self) -> int:
        sec, nsec = self.take("iI", 8, 4)
        check_nanosec(nsec)
        return sec * _NS + nsec

    def pose(self) -> RawPose:
        label = self.stamp()
        frame = self.string()
        return RawPose(label, frame, self.take("7d", 56, 8))


def read_pose(data: bytes) -> RawPose:
    """A geometry_msgs/PoseStamped's label, frame and doubles; MalformedMessage if the
    bytes do not decode or the stamp's nanoseconds are out of range."""
    if len(data) >= 76 and data[:4] == _LE and data[12:16] == b"\x04\x00\x00\x00":
        sec, nsec, _, frame, *f = _POSE_MAP.unpack_from(data, 4)
        if frame == b"map\x00":  # what every node of the stack sends
            check_nanosec(nsec)
            return RawPose(sec * _NS + nsec, "map", tuple(f))  # type: ignore[arg-type]
    return _Reader(data).pose()


def pose_eta(p: RawPose, previous_heading: float | None = None) -> NDArray[np.float64]:
    """eta (3,) = (x [m], y [m], theta [rad]) of a received pose, the heading unwrapped
    next to ``previous_heading``; MalformedMessage if not finite or not planar."""
    x, y, _, qx, qy, qz, qw = p.fields
    if not (math.isfinite(x) and math.isfinite(y)):
        raise Malformed("non-finite position")
    return np.array((x, y, heading_from_quaternion(qx, qy, qz, qw, previous_heading)))


def world_eta(p: RawPose, previous_heading: float | None = None) -> NDArray[np.float64]:
    """``pose_eta`` of a pose that must be in the world frame ("map")."""
    eta = pose_eta(p, previous_heading)
    if p.frame != "map":
        raise Malformed(f"pose in frame {p.frame!r}, expected 'map'")
    return eta


def read_twist(data: bytes) -> NDArray[np.float64]:
    """(v, omega) of a geometry_msgs/Twist; MalformedMessage as ``twist_to_u``."""
    if len(data) >= 52 and data[:4] == _LE:
        lx, ly, lz, ax, ay, az = _TWIST.unpack_from(data, 4)
    else:
        lx, ly, lz, ax, ay, az = _Reader(data).take("6d", 48, 8)
    return check_twist(lx, az, (ly, lz, ax, ay))


def read_applied(data: bytes) -> tuple[int, float, float]:
    """(label [ns], v [m/s], omega [rad/s]) of a geometry_msgs/TwistStamped: the command a
    robot applied over the sample its stamp labels; MalformedMessage if the bytes do not
    decode, the stamp is out of range, or the command is not a finite planar one."""
    r = _Reader(data)
    label = r.stamp()
    r.string()  # the frame: the robot's base, not read
    lx, ly, lz, ax, ay, az = r.take("6d", 48, 8)
    v, w = check_twist(lx, az, (ly, lz, ax, ay))
    return label, float(v), float(w)


def read_clock(data: bytes) -> int:
    """[ns] of a rosgraph_msgs/Clock; MalformedMessage as ``stamp_to_ns``."""
    if len(data) >= 12 and data[:4] == _LE:
        sec, nsec = _CLOCK.unpack_from(data, 4)
    else:
        sec, nsec = _Reader(data).take("iI", 8, 4)
    check_nanosec(nsec)
    return sec * _NS + nsec


def read_trajectory(data: bytes, reference_heading: NDArray[np.float64] | None = None
                    ) -> tuple[NDArray[np.float64], NDArray[np.int64], str]:
    """(eta (S, 3), stamps (S,) [ns], frame_id) of a whole-trial nav_msgs/Path: what
    ``msgs_schema.path_to_trajectory`` gives for the message of these bytes, with its
    checks (the same values, bit for bit), and MalformedMessage for bytes that do not
    decode. Headings are unwrapped next to ``reference_heading`` (S,) when given, else
    against the previous pose."""
    r = _Reader(data)
    r.take("iI", 8, 4)  # the path's stamp: not checked (as path_to_trajectory)
    frame = r.string()
    (n,) = r.take("I", 4, 4)
    if reference_heading is not None and n != len(reference_heading):
        raise Malformed(f"trajectory has {n} poses, expected {len(reference_heading)}")
    if n > (len(data) - r.pos) // 64:  # a pose takes at least 64 bytes
        raise Malformed("message cut short")
    eta = np.empty((n, 3))
    stamps = np.empty(n, dtype=np.int64)
    prev: float | None = None
    for s in range(n):
        sec, nsec = r.take("iI", 8, 4)
        f = r.string()
        x, y, _, qx, qy, qz, qw = r.take("7d", 56, 8)
        # msg_to_pose's checks, in its order
        if not (math.isfinite(x) and math.isfinite(y)):
            raise Malformed("non-finite position")
        ref = prev if reference_heading is None else float(reference_heading[s])
        th = heading_from_quaternion(qx, qy, qz, qw, ref)
        check_nanosec(nsec)
        if f != frame:
            raise Malformed(f"pose {s} of a {frame!r} trajectory is in frame {f!r}")
        eta[s] = (x, y, th)
        stamps[s] = sec * _NS + nsec
        prev = th
    return eta, stamps, frame


def read_pose_set(data: bytes, most: int,
                  too_many: str = "at most {most} poses expected, got {n}"
                  ) -> tuple[int, list[RawPose]]:
    """(stamp [ns], its poses as received) of a nav_msgs/Path of at most ``most`` poses
    (the plant's preview: one pose per robot; an emulated link's tick); MalformedMessage
    ``too_many`` if it holds more."""
    r = _Reader(data)
    stamp = r.stamp()
    r.string()  # the path's frame: not checked (each pose's is, by its reader)
    (n,) = r.take("I", 4, 4)
    if n > most:
        raise Malformed(too_many.format(most=most, n=n))
    return stamp, [r.pose() for _ in range(n)]


#: a Path's poses after the first, as every node of the stack packs them (little endian,
#: each in "map"): stamp, frame, then the seven doubles 8-aligned, 72 bytes a pose
_POSE_REC = np.dtype({"names": ["sec", "nsec", "len", "frame", "f"],
                      "formats": ["<i4", "<u4", "<u4", "S4", ("<f8", 7)],
                      "offsets": [0, 4, 8, 12, 16], "itemsize": 72})
#: a Path's header and first pose (its doubles need 4 bytes of padding to be 8-aligned)
_SET_HEAD = struct.Struct("<iII4sIiII4s4x7d")


def read_pose_block(data: bytes, most: int
                    ) -> tuple[NDArray[np.int64], NDArray[np.float64]] | None:
    """The poses of a nav_msgs/Path as arrays, in one pass: (labels [ns] (n,), the seven
    doubles of each (n, 7)), or None unless the bytes are the layout every node of the
    stack packs (``pose_set_bytes``: little endian, the path and every pose in "map",
    1 to ``most`` poses, stamps valid). None is no verdict: ``read_pose_set`` reads such
    bytes one pose at a time and says what is wrong, if anything. This is the reading of
    the plant's ``team/poses``, one pose per robot per sample for every robot's safety
    filter: one pose at a time it cost a 50-robot team's robots more than the rest of their
    sample."""
    if len(data) < 4 + _SET_HEAD.size or data[:4] != _LE:
        return None
    sec, nsec, flen, frame, n, *first = _SET_HEAD.unpack_from(data, 4)
    if not 1 <= n <= most or flen != 4 or frame != b"map\x00" or nsec >= _NS:
        return None
    if len(data) != 4 + _SET_HEAD.size + 72 * (n - 1):
        return None
    p0_sec, p0_nsec, p0_len, p0_frame, *f0 = first
    rest = np.frombuffer(data, _POSE_REC, n - 1, 4 + _SET_HEAD.size)
    if (p0_len != 4 or p0_frame != b"map\x00" or p0_nsec >= _NS
            or not (rest["len"] == 4).all() or not (rest["frame"] == b"map").all()
            or not (rest["nsec"] < _NS).all()):
        return None
    labels = np.empty(n, dtype=np.int64)
    labels[0] = p0_sec * _NS + p0_nsec
    labels[1:] = rest["sec"].astype(np.int64) * _NS + rest["nsec"]
    fields = np.empty((n, 7))
    fields[0] = f0
    fields[1:] = rest["f"]
    return labels, fields


def read_time_reference(data: bytes) -> tuple[int, str, int, str]:
    """A sensor_msgs/TimeReference's (header.stamp [ns], header.frame_id, time_ref [ns],
    source) (the clock exchanges' question and answer, ``msgs_schema.clocksync``);
    MalformedMessage if the bytes do not decode or a stamp's nanoseconds are out of range.
    A node reads every answer on a clock's answer topic, most of them to other askers: read
    from the bytes, one that is not its own costs no message object."""
    r = _Reader(data)
    stamp = r.stamp()
    frame = r.string()
    time_ref = r.stamp()
    return stamp, frame, time_ref, r.string()


def read_link_tick(data: bytes) -> tuple[int, RawPose | None]:
    """(tick [ns], the delivered pose or None) of an emulated link's nav_msgs/Path;
    MalformedMessage if it holds more than one pose (as ``msg_to_link_tick``)."""
    tick, poses = read_pose_set(data, 1, "a link delivers at most one pose per tick, got {n}")
    return tick, (poses[0] if poses else None)


# --------------------------------------------------------------------------- packing

def _stamp(ns: int) -> tuple[int, int]:
    return divmod(int(ns), _NS)


def raw_pose(eta: Sequence[float] | NDArray[np.float64], stamp_ns: int,
             frame_id: str = "map") -> RawPose:
    """The RawPose of ``pose_to_msg(eta, stamp_ns, frame_id)``: eta = (x [m], y [m],
    theta [rad]), orientation (0, 0, sin(theta/2), cos(theta/2))."""
    x, y, th = float(eta[0]), float(eta[1]), float(eta[2])
    return RawPose(int(stamp_ns), frame_id, (
        x, y, 0.0, 0.0, 0.0, math.sin(0.5 * th), math.cos(0.5 * th)))


def pose_bytes(eta: Sequence[float] | NDArray[np.float64], stamp_ns: int,
               frame_id: str = "map") -> bytes:
    """The bytes of ``pose_to_msg(eta, stamp_ns, frame_id)`` (see :func:`raw_pose`)."""
    return raw_pose_bytes(raw_pose(eta, stamp_ns, frame_id))


def _pose_body(p: RawPose, at: int) -> bytes:
    """A PoseStamped's fields, packed to start at data offset ``at`` (4-aligned)."""
    sec, nsec = _stamp(p.label_ns)
    frame = p.frame.encode() + b"\x00"
    head = struct.pack("<iII", sec, nsec, len(frame)) + frame
    pad = (-(at + len(head))) % 8
    return head + b"\x00" * pad + struct.pack("<7d", *p.fields)


def raw_pose_bytes(p: RawPose) -> bytes:
    """The PoseStamped bytes of a received pose (its doubles unchanged)."""
    if p.frame == "map":
        sec, nsec = _stamp(p.label_ns)
        return _LE + _POSE_MAP.pack(sec, nsec, 4, b"map\x00", *p.fields)
    return _LE + _pose_body(p, 0)


def pose_set_bytes(stamp_ns: int, poses: Sequence[RawPose]) -> bytes:
    """A nav_msgs/Path stamped ``stamp_ns``, in "map", holding ``poses`` as they were sent
    (their labels and doubles): an emulated link's tick, the plant's preview."""
    sec, nsec = _stamp(stamp_ns)
    parts = [_LE + struct.pack("<iII4sI", sec, nsec, 4, b"map\x00", len(poses))]
    at = len(parts[0]) - 4
    for p in poses:
        parts.append(_pose_body(p, at))
        at += len(parts[-1])
    return b"".join(parts)


class Frame(NamedTuple):
    """A planar transform of tf2: ``child`` in ``parent`` at (x [m], y [m], theta [rad])."""

    parent: str
    child: str
    x: float
    y: float
    theta: float


def tf_bytes(stamp_ns: int, frames: Sequence[Frame]) -> bytes:
    """The bytes of a tf2_msgs/msg/TFMessage of ``frames``, every transform stamped
    ``stamp_ns``: translation (x, y, 0), rotation (0, 0, sin(theta/2), cos(theta/2))."""
    sec, nsec = _stamp(stamp_ns)
    parts = [_LE + struct.pack("<I", len(frames))]
    at = 4
    for f in frames:
        parent = f.parent.encode() + b"\x00"
        child = f.child.encode() + b"\x00"
        head = b"\x00" * ((-at) % 4)
        head += struct.pack("<iII", sec, nsec, len(parent)) + parent
        head += b"\x00" * ((-(at + len(head))) % 4) + struct.pack("<I", len(child)) + child
        head += b"\x00" * ((-(at + len(head))) % 8)
        th = 0.5 * float(f.theta)
        body = head + struct.pack("<7d", float(f.x), float(f.y), 0.0, 0.0, 0.0, math.sin(th),
                                  math.cos(th))
        parts.append(body)
        at += len(body)
    return b"".join(parts)


def link_tick_bytes(tick_ns: int, pose: RawPose | None) -> bytes:
    """The bytes of ``link_tick_to_msg``: a Path stamped with the tick, in "map", holding
    the delivered pose as it was sent (its label and doubles) or nothing."""
    return pose_set_bytes(tick_ns, () if pose is None else (pose,))


def path_bytes(eta: NDArray[np.float64], stamps_ns: Sequence[int], frame_id: str) -> bytes:
    """The bytes of ``trajectory_to_path(eta, stamps_ns, frame_id)``: whole-trial output
    eta (T+1, 3) as a Path, pose s stamped with its label, the path with the last."""
    stamps = list(stamps_ns)
    if len(stamps) != len(eta):
        raise ValueError("one stamp per sample is required")
    sec, nsec = _stamp(stamps[-1]) if stamps else (0, 0)
    frame = frame_id.encode() + b"\x00"
    head = struct.pack("<iII", sec, nsec, len(frame)) + frame
    head += b"\x00" * ((-len(head)) % 4) + struct.pack("<I", len(stamps))
    parts = [_LE, head]
    at = len(head)
    sin, cos = math.sin, math.cos
    for e, ns in zip(eta.tolist(), stamps, strict=True):
        x, y, th = e
        body = _pose_body(RawPose(int(ns), frame_id, (
            x, y, 0.0, 0.0, 0.0, sin(0.5 * th), cos(0.5 * th))), at)
        parts.append(body)
        at += len(body)
    return b"".join(parts)


def twist_bytes(u: Sequence[float] | NDArray[np.float64]) -> bytes:
    """The bytes of ``u_to_twist(u)``: linear.x = v [m/s], angular.z = omega [rad/s]."""
    return _LE + _TWIST.pack(float(u[0]), 0.0, 0.0, 0.0, 0.0, float(u[1]))


def applied_bytes(u: Sequence[float] | NDArray[np.float64], stamp_ns: int,
                  frame_id: str) -> bytes:
    """The bytes of a geometry_msgs/TwistStamped stamped ``stamp_ns`` in ``frame_id``:
    linear.x = v [m/s], angular.z = omega [rad/s] (what ``read_applied`` reads)."""
    sec, nsec = _stamp(stamp_ns)
    frame = frame_id.encode() + b"\x00"
    head = struct.pack("<iII", sec, nsec, len(frame)) + frame
    pad = (-len(head)) % 8
    return (_LE + head + b"\x00" * pad
            + _TWIST.pack(float(u[0]), 0.0, 0.0, 0.0, 0.0, float(u[1])))


def clock_bytes(ns: int) -> bytes:
    """The bytes of ``clock_msg(ns)``."""
    return _LE + _CLOCK.pack(*_stamp(ns))


# --------------------------------------------------------------------------- text, reports

def read_string(data: bytes) -> str:
    """The text of a std_msgs/String's CDR bytes, read as a typed subscription reads it
    (up to its first NUL, invalid UTF-8 replaced); Malformed for bytes that do not
    decode."""
    return _Reader(data).string()


def read_diagnostics(data: bytes) -> list[tuple[int, str, str, str, list[tuple[str, str]]]]:
    """The statuses of a diagnostic_msgs/DiagnosticArray's CDR bytes: (level, name,
    message, hardware_id, [(key, value)]) each, as ``protocol.health.read_statuses`` takes
    them; Malformed for bytes that do not decode (a count that cannot fit in the bytes
    left is refused before anything is built)."""
    r = _Reader(data)
    r.take("iI", 8, 4)  # the header's stamp and frame: not read by anyone
    r.string()
    (count,) = r.take("I", 4, 4)
    # a status takes at least a level, three string lengths and a count (17 bytes)
    if count > (len(data) - r.pos) // 17:
        raise Malformed("message cut short")
    out = []
    for _ in range(count):
        (level,) = r.take("B", 1, 1)
        name, message, hardware_id = r.string(), r.string(), r.string()
        (n,) = r.take("I", 4, 4)
        if n > (len(data) - r.pos) // 8:  # a key/value takes at least two lengths
            raise Malformed("message cut short")
        out.append((int(level), name, message, hardware_id,
                    [(r.string(), r.string()) for _ in range(n)]))
    return out


def json_object(text: str, required: Sequence[str] = ()) -> dict[str, Any]:
    """The JSON object in a String's text; Malformed if it is not one or lacks a key."""
    try:
        data = json.loads(text)
    except (ValueError, TypeError, RecursionError) as exc:  # nesting beyond the parser's
        raise Malformed(f"not JSON: {exc}"[:200]) from None
    if not isinstance(data, dict):
        raise Malformed("JSON is not an object")
    missing = [k for k in required if k not in data]
    if missing:
        raise Malformed(f"JSON lacks {missing}")
    return data


def json_int(data: dict[str, Any], key: str) -> int:
    """The integer ``data[key]``; Malformed if absent or not an integer (JSON ``true``,
    ``1.5`` and ``"3"`` are not trial numbers)."""
    v = data.get(key)
    if isinstance(v, bool) or not isinstance(v, int):
        raise Malformed(f"{key!r} is not an integer: {v!r}"[:200])
    return v
