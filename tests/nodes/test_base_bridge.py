"""The bridge's generic differential-drive driver: presets, tilted odometry, no motor
service, and acceleration limits on every command (private rclpy Context, no sleeps)."""

from __future__ import annotations

import math
import time

import pytest

pytestmark = pytest.mark.ros

rclpy = pytest.importorskip("rclpy")
from geometry_msgs.msg import TwistStamped  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

import msgs_schema as ms  # noqa: E402
from formation_ilc.config.bases import BASES  # noqa: E402
from formation_ilc.core.kinematics import yaw_and_tilt  # noqa: E402

from ..procs import spin_until  # noqa: E402


def quat(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy)


def odom(roll: float, pitch: float, yaw: float, x: float = 0.0) -> Odometry:
    m = Odometry()
    m.pose.pose.position.x = x
    q = m.pose.pose.orientation
    q.x, q.y, q.z, q.w = quat(roll, pitch, yaw)
    return m


@pytest.mark.parametrize("roll, pitch, yaw", [(0.0, 0.0, 2.0), (0.1, 0.0, -1.0),
                                              (0.0, 0.15, 3.0), (0.05, -0.08, 0.3)])
def test_yaw_and_tilt_of_any_quaternion(roll, pitch, yaw):
    y, t = yaw_and_tilt(*quat(roll, pitch, yaw))
    assert y == pytest.approx(yaw, abs=1e-12)
    assert t == pytest.approx(math.acos(math.cos(roll) * math.cos(pitch)), abs=1e-12)
    # scale does not matter; zero does
    assert yaw_and_tilt(*(2 * c for c in quat(roll, pitch, yaw)))[0] == pytest.approx(yaw)
    with pytest.raises(ValueError, match="not a rotation"):
        yaw_and_tilt(0.0, 0.0, 0.0, 0.0)


def test_tilt_within_the_bound_is_accepted_beyond_refused_with_a_reason():
    bound = math.radians(10)
    x, y, yaw, tilt = ms.base_odometry_to_pose(odom(math.radians(0.1), 0.0, 0.7, 1.5), bound)
    assert (x, yaw) == (1.5, pytest.approx(0.7)) and tilt == pytest.approx(math.radians(0.1))
    assert ms.base_odometry_to_pose(odom(0.0, math.radians(9.9), 0.7), bound)[2] == \
        pytest.approx(0.7)
    with pytest.raises(ms.MalformedMessage, match=r"odometry tilted by 12\.0 deg, beyond the "
                                                  r"bound of 10\.0 deg \(max_tilt\)"):
        ms.base_odometry_to_pose(odom(math.radians(12), 0.0, 0.7), bound)
    # the Pioneer drivers' strict reading refuses 0.1 deg of roll: the base driver is for that
    with pytest.raises(ms.MalformedMessage, match="not a unit rotation about z"):
        ms.odometry_to_pose(odom(math.radians(0.1), 0.0, 0.7))


def test_base_bridge_needs_no_motor_service_reads_tilt_and_limits_acceleration(context):
    from formation_ilc.nodes.pioneer_bridge import BridgeNode

    params = [Parameter("robot_id", value=1), Parameter("scenario", value="paper-triangle3"),
              Parameter("base", value="turtlebot4"), Parameter("driver_ns", value="/tb_1")]
    bridge = BridgeNode(context=context, parameter_overrides=params)
    tester = rclpy.create_node("tester", context=context)
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(bridge)
    ex.add_node(tester)
    try:
        assert bridge.driver == "base (turtlebot4)" and bridge.stamped  # the preset's
        assert bridge.rate == BASES["turtlebot4"].limits
        sent: list[tuple[float, float, float]] = []  # (stamp [s], v, omega)
        tester.create_subscription(TwistStamped, "/tb_1/cmd_vel",
                                   lambda m: sent.append((ms.stamp_to_ns(m.header.stamp) * 1e-9,
                                                          m.twist.linear.x,
                                                          m.twist.angular.z)),
                                   ms.DRIVER_CMD_QOS)
        pub = tester.create_publisher(Odometry, "/tb_1/odom", ms.ODOM_QOS)
        spin_until(ex, lambda: pub.get_subscription_count() >= 1 and sent)
        assert bridge.motors_on  # no service to wait for
        core = bridge.core
        pub.publish(odom(math.radians(3), 0.0, 0.25))
        spin_until(ex, lambda: core.odom is not None)
        assert core.odom[2] == pytest.approx(0.25)
        assert core.tilt_max == pytest.approx(math.radians(3))
        pub.publish(odom(math.radians(30), 0.0, 1.0))
        spin_until(ex, lambda: bridge.drops.counts["malformed"] == 1)
        assert core.odom[2] == pytest.approx(0.25)  # the tilted pose was not taken
        # every command to the base goes through the limits: from standing, 0.3 m/s is
        # reached no faster than the preset's 2.5 m/s^2 allows, on the messages' stamps
        # (the node publishes each with the wall time the core limited it at)
        n0 = len(sent)
        for _ in range(5):
            wall = time.time_ns()
            bridge._send(core.send((0.3, 0.0), time.monotonic(), wall), wall)
        spin_until(ex, lambda: len(sent) >= n0 + 5)
        assert core.out_cmd[0] < 0.3 and core.rate is not None
        assert core.rate.clipped_accel >= 5
        for (t1, v1, _), (t2, v2, _) in zip(sent[n0 - 1:], sent[n0:], strict=False):
            assert v2 - v1 <= 2.5 * (t2 - t1) + 1e-12
        assert core.report()["tilt_max_deg"] == pytest.approx(3.0)
    finally:
        ex.shutdown()
        bridge.destroy_node()
        tester.destroy_node()


def test_unknown_base_is_refused(context):
    from formation_ilc.nodes.pioneer_bridge import BridgeNode

    params = [Parameter("robot_id", value=1), Parameter("scenario", value="paper-triangle3"),
              Parameter("base", value="roomba")]
    with pytest.raises(ValueError, match="parameter base: one of '', turtlebot3, "
                       ".*; got 'roomba'"):
        BridgeNode(context=context, parameter_overrides=params)

