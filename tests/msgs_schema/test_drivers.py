"""A driver's messages (msgs_schema.drivers): odometry in, commands out; the drivers'
topic names (formation_ilc.core.names.DRIVERS) fixed."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

pytest.importorskip("rclpy")
from geometry_msgs.msg import Twist  # noqa: E402

import msgs_schema as ms  # noqa: E402


def test_driver_odometry_round_trip():
    """A fake driver's odometry decodes to the pose it was made from, twist included;
    a non-finite position is refused, whichever coordinate it is in."""
    from nav_msgs.msg import Odometry

    rng = np.random.default_rng(11)
    reuse = Odometry()
    for _ in range(50):
        pose = (rng.uniform(-9, 9), rng.uniform(-9, 9), rng.uniform(-3.1, 3.1))
        twist = (rng.uniform(-1, 1), rng.uniform(-2, 2))
        for out in (None, reuse):
            m = ms.odometry_msg(pose, twist, 123_000, out=out)
            assert (out is None) == (m is not reuse)
            x, y, yaw = ms.odometry_to_pose(m)
            assert (x, y) == (pose[0], pose[1])
            assert yaw == pytest.approx(pose[2], abs=1e-12)
            assert (m.twist.twist.linear.x, m.twist.twist.angular.z) == twist
            assert (m.header.frame_id, m.child_frame_id) == ("odom", "base_link")
            assert ms.stamp_to_ns(m.header.stamp) == 123_000
    for bad in ("x", "y"):
        m = ms.odometry_msg((1.0, 2.0, 0.3), (0.0, 0.0), 0)
        setattr(m.pose.pose.position, bad, float("nan"))
        with pytest.raises(ms.MalformedMessage, match="odometry"):
            ms.odometry_to_pose(m)


def test_driver_twist_plain_and_stamped():
    from geometry_msgs.msg import TwistStamped

    t = ms.driver_twist(0.3, -0.7, stamped=False)
    assert isinstance(t, Twist) and (t.linear.x, t.angular.z) == (0.3, -0.7)
    s = ms.driver_twist(0.3, -0.7, stamped=True, stamp_ns=5_000_000_001)
    assert isinstance(s, TwistStamped)
    assert (s.twist.linear.x, s.twist.angular.z) == (0.3, -0.7)
    assert ms.stamp_to_ns(s.header.stamp) == 5_000_000_001
    assert s.header.frame_id == "base_link"
    assert ms.stamp_to_ns(ms.driver_twist(0, 0, stamped=True).header.stamp) == 0


def test_driver_specs_cannot_be_changed_by_a_caller():

    spec = ms.DRIVERS["rosaria"]
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.cmd = "other"  # type: ignore[misc]
    assert ms.DRIVERS["rosaria"].cmd == "cmd_vel"
