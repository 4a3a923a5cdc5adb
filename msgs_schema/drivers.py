"""A robot driver's messages, for the bridge, the fake drivers and the physics bases:
odometry in (planar, or a base's with roll and pitch), velocity commands out (Twist or
TwistStamped). The drivers' topic names are ``formation_ilc.core.names.DRIVERS``."""

from __future__ import annotations

import math
from collections.abc import Sequence

from geometry_msgs.msg import Twist, TwistStamped
from nav_msgs.msg import Odometry

from formation_ilc.core.kinematics import yaw_and_tilt
from formation_ilc.protocol.wire import heading_from_quaternion
from msgs_schema.convert import MalformedMessage, ns_to_stamp

__all__ = ["odometry_to_pose", "base_odometry_to_pose", "odometry_msg", "driver_twist"]


def odometry_to_pose(msg: Odometry) -> tuple[float, float, float]:
    """(x, y, yaw) of a driver's planar odometry; MalformedMessage if not planar/finite."""
    p = msg.pose.pose.position
    x, y = float(p.x), float(p.y)
    if not (math.isfinite(x) and math.isfinite(y)):
        raise MalformedMessage("non-finite odometry position")
    q = msg.pose.pose.orientation
    return x, y, heading_from_quaternion(q.x, q.y, q.z, q.w, None)


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

