"""The e-stop as a bridge obeys it on its own, with no leader on the graph (issue 54): an
e-stop latched before the bridge started reaches it at once; its driver gets zero and only
zero while it holds, whatever the bridge is asked to send; false releases it (private
rclpy Context)."""

from __future__ import annotations

import time

import pytest

pytestmark = pytest.mark.ros

rclpy = pytest.importorskip("rclpy")
from geometry_msgs.msg import Twist  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from std_msgs.msg import Bool  # noqa: E402

import msgs_schema as ms  # noqa: E402

from ..procs import spin_until  # noqa: E402


def test_a_latched_estop_holds_a_bridge_at_zero_without_a_leader(context):
    from formation_ilc.nodes.pioneer_bridge import BridgeNode
    from robot_sim.fake_pioneer import FakePioneer

    operator = rclpy.create_node("operator", context=context)
    estop = operator.create_publisher(Bool, "/formation/estop", ms.LATCHED_QOS)
    estop.publish(Bool(data=True))  # latched before the bridge exists
    got: list[tuple[float, float, float]] = []  # (arrival, v, omega) at the driver
    operator.create_subscription(Twist, "/pioneer_1/cmd_vel", lambda m: got.append(
        (time.monotonic(), m.linear.x, m.angular.z)), ms.DRIVER_CMD_QOS)
    driver = FakePioneer(context=context, namespace="/pioneer_1")
    bridge = BridgeNode(context=context, parameter_overrides=[
        Parameter("robot_id", value=1), Parameter("scenario", value="paper-triangle3"),
        Parameter("driver_ns", value="/pioneer_1")])
    ex = SingleThreadedExecutor(context=context)
    for n in (operator, driver, bridge):
        ex.add_node(n)
    try:
        spin_until(ex, lambda: bridge.core.estopped)
        # whatever the bridge would send (here a hard turn, as a trial's command or a
        # return's), the driver gets zero: the core holds it
        t = time.monotonic()
        bridge._send(bridge.core.send((0.5, 1.0), t), bridge._wall_ns())
        spin_until(ex, lambda: got and got[-1][0] > t)
        assert all((v, w) == (0.0, 0.0) for _, v, w in got), got
        assert bridge.core.report()["estops"] == 1
        estop.publish(Bool(data=False))  # released: commands go through again
        spin_until(ex, lambda: not bridge.core.estopped)
        assert bridge.core.send((0.5, 0.1), time.monotonic()) == (0.5, 0.1)
    finally:
        ex.shutdown()
        for n in (bridge, driver, operator):
            n.destroy_node()
