"""The view messages (what the formation should be, for the live view and the recording):
desired poses and paths, tracking and trial errors, the 3D view's markers; built from CDR
templates per sample. Published by one observer (``formation_ilc.nodes.observer``: in the
recorder, or in the live view's bridge when nothing records); the robots are untouched.

=========================  ===============================  ================================
topic                      type                             content
=========================  ===============================  ================================
robot_i/desired_pose       geometry_msgs/PoseStamped        eta_d of each sample (its label)
robot_i/desired_path       nav_msgs/Path (latched)          eta_d of a whole trial, at start
robot_i/tracking_error     geometry_msgs/Vector3Stamped     per sample: x position error
                                                            |p_d - p| [m], y heading error
                                                            wrap(th_d - th) [rad], z 0
robot_i/trial_error        geometry_msgs/Vector3Stamped     per trial: x max position error,
                                                            y max |heading error|, z trial
markers                    visualization_msgs/MarkerArray   outline, links, labels, errors
=========================  ===============================  ================================
"""

from __future__ import annotations

import math
import struct as _struct
from collections.abc import Sequence

import numpy as np
from geometry_msgs.msg import Point, PoseStamped, Vector3Stamped
from numpy.typing import NDArray
from visualization_msgs.msg import Marker, MarkerArray

from formation_ilc.core.names import WORLD_FRAME, robot_name
from formation_ilc.protocol.wire import heading_from_quaternion
from msgs_schema.convert import MalformedMessage, deserialize, ns_to_stamp, world_pose

__all__ = ["vector_msg", "markers_msg", "MarkersTemplate", "stamped_cdr", "vector_cdr",
           "world_pose_cdr"]


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
                positions: dict[int, tuple[float, float]],
                footprint: tuple[float, float, float] | None = None) -> MarkerArray:
    """The 3D view's markers at one sample (robot index r is ``robot_{r+1}``):
    ``formation`` the desired positions (N, >=2) joined in ``outline`` order (closed);
    ``links`` the graph's links (sender, receiver) between measured ``positions``;
    ``errors`` each measured position to its desired one; ``labels`` the robots' names.
    With ``footprint`` (length, width, centre ahead of base_link [m]), per robot its
    ``footprint`` (the body's outline) and ``heading`` (an arrow along x) in its own frame
    ``robot_i/base_link``, locked to it (they move with /tf)."""
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
    if footprint is not None:
        length, width, cx = footprint
        hx, hy = length / 2.0, width / 2.0
        corners = [(cx + hx, hy), (cx - hx, hy), (cx - hx, -hy), (cx + hx, -hy), (cx + hx, hy)]
        for r in sorted(positions):
            frame = f"{robot_name(r + 1)}/base_link"
            fp = _marker(stamp_ns, "footprint", r + 1, Marker.LINE_STRIP,
                         (0.2, 0.9, 0.3, 1.0), 0.02)
            fp.header.frame_id, fp.frame_locked = frame, True
            fp.points = [_point(c) for c in corners]
            arrow = _marker(stamp_ns, "heading", r + 1, Marker.ARROW, (1.0, 0.8, 0.1, 1.0),
                            0.03)
            arrow.header.frame_id, arrow.frame_locked = frame, True
            arrow.scale.y, arrow.scale.z = 0.08, 0.1  # head diameter and length
            arrow.points = [_point((0.0, 0.0)), _point((cx + hx + 0.15, 0.0))]
            out.markers += [fp, arrow]
    return out


# Per-sample view messages are built from CDR templates: a message serialized once, whose
# stamp (and vector) are then written in place. The observer's cost per pose is then a few
# struct calls, not rclpy's (de)serialization (about 0.5 ms a pose on a loaded 2-core box).

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

    def __init__(self, n: int, outline: Sequence[int], links: Sequence[tuple[int, int]],
                 footprint: tuple[float, float, float] | None = None):
        from rclpy.serialization import serialize_message

        sentinel = lambda k: 1.0e9 + 7.0 * k + 0.3125  # noqa: E731 (exact in binary)
        desired = [(sentinel(2 * r), sentinel(2 * r + 1)) for r in range(n)]
        positions = {r: (sentinel(2 * (n + r)), sentinel(2 * (n + r) + 1)) for r in range(n)}
        stamp = self._SEC * 1_000_000_000 + self._NSEC
        self.template = bytes(serialize_message(
            markers_msg(stamp, desired, outline, links, positions, footprint)))
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
        stamps = 3 + n + (2 * n if footprint is not None else 0)
        if len(self.stamps) != stamps or any(not offs for offs, _ in self.coords):
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
    th = heading_from_quaternion(qx, qy, qz, qw, None)
    return np.array((px, py, th)), sec * 1_000_000_000 + nsec


