"""The fake Pioneer driver (robot_sim.fake_pioneer) in-process: motors, watchdog."""

from __future__ import annotations

import time

import pytest

pytestmark = pytest.mark.ros

rclpy = pytest.importorskip("rclpy")
from geometry_msgs.msg import Twist  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

import msgs_schema as ms  # noqa: E402

from ..procs import spin_until  # noqa: E402


def test_fake_driver_needs_its_motors_enabled_and_stops_on_its_own_watchdog(context):
    from std_srvs.srv import Empty

    from robot_sim.fake_pioneer import FakePioneer

    fake = FakePioneer(context=context, namespace="/pioneer_1",
                       parameter_overrides=[Parameter("odom_noise", value=0.0)])
    tester = rclpy.create_node("tester", context=context)
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(fake)
    ex.add_node(tester)
    try:
        odom: list[tuple[float, Odometry]] = []
        tester.create_subscription(Odometry, "/pioneer_1/pose",
                                   lambda m: odom.append((time.monotonic(), m)), ms.ODOM_QOS)
        pub = tester.create_publisher(Twist, "/pioneer_1/cmd_vel", ms.DRIVER_CMD_QOS)
        spin_until(ex, lambda: pub.get_subscription_count() >= 1 and len(odom) >= 3)
        pub.publish(ms.u_to_twist((0.5, 0.0)))
        n = len(odom)
        spin_until(ex, lambda: len(odom) >= n + 10)
        # motors off: the command is ignored
        assert all(m.twist.twist.linear.x == 0.0 for _, m in odom)
        assert odom[-1][1].pose.pose.position.x == 0.0
        client = tester.create_client(Empty, "/pioneer_1/enable_motors")
        spin_until(ex, client.service_is_ready)
        fut = client.call_async(Empty.Request())
        spin_until(ex, fut.done)
        assert fake.motors
        pub.publish(ms.u_to_twist((0.5, 0.0)))
        t_cmd = time.monotonic()
        spin_until(ex, lambda: odom[-1][1].twist.twist.linear.x == 0.5)
        # no newer command: the driver's own watchdog stops the robot 0.6 s after it (the
        # event: the odometry says it stands; not before 0.6 s, however the process is
        # scheduled: the watchdog cannot fire early)
        spin_until(ex, lambda: odom[-1][0] > t_cmd and odom[-1][1].twist.twist.linear.x == 0.0)
        stop = next(t for t, m in odom if t > t_cmd + 0.05 and m.twist.twist.linear.x == 0.0)
        assert stop - t_cmd >= 0.55, stop - t_cmd
        assert fake.watchdog_stops == 1
        # it drove 0.5 m/s for exactly the 0.6 s of its watchdog (however late its ticks
        # fired), and its odometry is 1 % long
        moved = odom[-1][1].pose.pose.position.x
        assert moved == pytest.approx(0.5 * 0.6 * 1.01, abs=1e-6), moved  # its turn bias bends it
        assert fake.true[0] == pytest.approx(0.5 * 0.6, abs=1e-9)
    finally:
        fake.destroy_node()
        tester.destroy_node()
