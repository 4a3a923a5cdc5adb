"""The Pioneer bridge node in process: commands clamped to the limits, a zero command once
the robot node is silent longer than the timeout, TwistStamped for diff_drive_controller,
and the fake driver's motors and watchdog (private rclpy Context, no sleeps)."""

from __future__ import annotations

import math
import time

import pytest

pytestmark = pytest.mark.ros

rclpy = pytest.importorskip("rclpy")
from geometry_msgs.msg import Twist, TwistStamped  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

import msgs_schema as ms  # noqa: E402

from ..procs import spin_until  # noqa: E402

TIMEOUT = 0.4


def make_bridge(context, cmd_type: str = "twist", driver: str = "rosaria"):
    from formation_ilc.nodes.pioneer_bridge import BridgeNode

    params = [Parameter("robot_id", value=1), Parameter("scenario", value="paper-triangle3"),
              Parameter("driver", value=driver), Parameter("driver_ns", value="/pioneer_1"),
              Parameter("cmd_timeout", value=TIMEOUT), Parameter("cmd_type", value=cmd_type),
              Parameter("v_max", value=0.5), Parameter("omega_max", value=90.0)]
    return BridgeNode(context=context, parameter_overrides=params)


@pytest.mark.parametrize("cmd_type", ["twist", "twist_stamped"])
def test_bridge_clamps_commands_and_zeroes_them_when_the_robot_is_silent(context, cmd_type):
    bridge = make_bridge(context, cmd_type)
    tester = rclpy.create_node("tester", namespace=ms.NAMESPACE, context=context)
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(bridge)
    ex.add_node(tester)
    try:
        assert bridge.get_fully_qualified_name() == "/formation/bridge_1"
        got: list[tuple[float, float, float]] = []  # (arrival, v, omega)
        stamped = cmd_type == "twist_stamped"

        def on_twist(m):
            t = m.twist if stamped else m
            got.append((time.monotonic(), t.linear.x, t.angular.z))

        # the bridge's own clock readings: each tick (its time, the command it sent or None)
        # and each robot command fed to the watchdog; the properties are checked on them,
        # so a tick that a loaded machine runs late cannot fail the test
        ticks: list[tuple[float, tuple[float, float] | None]] = []
        fed: list[float] = []
        out: list[tuple[float, float]] = []  # every command sent to the driver, in order
        core_tick, core_cmd = bridge.core.tick, bridge.core.on_cmd

        def tick(now, *a):
            t = core_tick(now, *a)
            ticks.append((now, t.cmd))
            if t.cmd is not None:
                out.append(t.cmd)
            return t

        def on_cmd(u, now, *a):
            cmd = core_cmd(u, now, *a)
            fed.append(now)
            out.append(cmd)
            return cmd

        bridge.core.tick, bridge.core.on_cmd = tick, on_cmd
        tester.create_subscription(TwistStamped if stamped else Twist, "/pioneer_1/cmd_vel",
                                   on_twist, ms.DRIVER_CMD_QOS)
        pub = tester.create_publisher(Twist, ms.cmd_vel_topic(1), ms.SAMPLE_QOS)
        spin_until(ex, lambda: pub.get_subscription_count() >= 1 and len(got) > 0)
        # before any robot command: zero, sent again by the first tick a period after the last
        assert got[-1][1:] == (0.0, 0.0)
        n0 = len(got)
        spin_until(ex, lambda: len(got) >= n0 + 5)
        period = bridge.core.period
        assert period <= 0.1  # >= 10 Hz
        sent = [now for now, cmd in ticks if cmd is not None]
        assert all(now - last < period for now, last in _last_sent(ticks) if last is not None)
        assert len(sent) >= 5

        # outside a trial a command is refused and counted: it would move the robot
        # outside the protocol
        pub.publish(ms.u_to_twist((0.3, 0.2)))
        spin_until(ex, lambda: bridge.drops.counts["unexpected"] == 1)
        assert got[-1][1:] == (0.0, 0.0)
        bridge.core.phase = "trial"  # inside a trial (its start is tested with the fake driver)
        cmds = [(2.0, 3.0), (-1.0, -3.0), (0.3, 0.2)]
        want = [(0.5, math.radians(90)), (-0.5, -math.radians(90)), (0.3, 0.2)]
        for (v, w), (wv, ww) in zip(cmds, want, strict=True):
            pub.publish(ms.u_to_twist((v, w)))
            spin_until(ex, lambda wv=wv, ww=ww: got and got[-1][1:] == pytest.approx((wv, ww)))
        assert bridge.core.counts["clipped"] == 2
        # the robot node falls silent: every tick within the timeout of the last command
        # holds it (sent again each period), the first tick past the timeout sends zero
        spin_until(ex, lambda: got[-1][1:] == (0.0, 0.0), timeout=5.0)
        t_last = fed[-1]
        after = [(now, cmd) for now, cmd in ticks if now >= t_last]
        held = [(now, cmd) for now, cmd in after if now - t_last <= TIMEOUT]
        first_zero = next(i for i, (now, _) in enumerate(after) if now - t_last > TIMEOUT)
        assert all(cmd in (None, pytest.approx((0.3, 0.2))) for _, cmd in held)
        assert sum(cmd is not None for _, cmd in held) >= 3  # >= 10 Hz while it holds
        assert after[first_zero][1] == (0.0, 0.0)
        assert bridge.core.counts["watchdog_zero"] == 1
        for _ in range(20):
            ex.spin_once(timeout_sec=0.01)
        assert all(cmd in (None, (0.0, 0.0)) for _, cmd in after[first_zero:])
        # the driver got what the bridge sent, in order, none lost after the first it got
        n = len(got)
        assert [(v, w) for _, v, w in got] in (out[k - n:k] for k in range(n, len(out) + 1))
    finally:
        bridge.destroy_node()
        tester.destroy_node()


def _last_sent(ticks):
    """(time, time of the last command sent before it) of each tick that sent nothing."""
    last = None
    for now, cmd in ticks:
        if cmd is None:
            yield now, last
        else:
            last = now


@pytest.mark.parametrize("driver", ["rosaria", "ros2aria"])
def test_bridge_is_ready_once_odometry_and_motors_are_in_and_maps_odometry_to_world(context,
                                                                                   driver):
    from robot_sim.fake_pioneer import FakePioneer

    bridge = make_bridge(context, driver=driver)
    fake = FakePioneer(context=context, namespace="/pioneer_1",
                       parameter_overrides=[Parameter("odom_noise", value=0.0),
                                            Parameter("driver", value=driver)])
    tester = rclpy.create_node("tester", namespace=ms.NAMESPACE, context=context)
    ex = SingleThreadedExecutor(context=context)
    for n in (bridge, fake, tester):
        ex.add_node(n)
    try:
        from geometry_msgs.msg import PoseStamped
        from std_msgs.msg import String

        ready: list[dict] = []
        tester.create_subscription(String, ms.READY, lambda m: ready.append(ms.msg_to_json(m)),
                                   ms.LATCHED_READER_QOS)
        odom: list[Odometry] = []
        tester.create_subscription(Odometry, f"/pioneer_1/{ms.DRIVERS[driver].odom}",
                                   odom.append, ms.ODOM_QOS)
        # the robot node's reader of the pose (the bridge waits for one)
        tester.create_subscription(PoseStamped, ms.pose_topic(1), lambda m: None,
                                   ms.SAMPLE_QOS)
        spin_until(ex, lambda: any(r["node"] == "bridge_1" for r in ready))
        assert fake.motors  # the bridge enabled them through enable_motors
        assert odom and odom[-1].header.frame_id == "odom"
        r = next(r for r in ready if r["node"] == "bridge_1")
        assert r["trial"] == 0 and r["return"] == "placed"
        assert r["initial_shift"] == pytest.approx([0.0, 0.0, 0.0], abs=1e-9)
        # the world pose is the scenario's desired start composed with the odometry
        assert bridge.core.world() == pytest.approx(bridge.core.initial, abs=1e-9)
    finally:
        for n in (bridge, fake, tester):
            n.destroy_node()




@pytest.mark.multiprocess
def test_p2os2_without_p2os_msgs_stops_with_a_clear_message(ros_env):
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "formation_ilc.nodes.pioneer_bridge",
                        "--ros-args", "-p", "robot_id:=2", "-p", "scenario:=paper-triangle3",
                        "-p", "driver:=p2os2"], capture_output=True, text=True, timeout=60,
                       env=ros_env)
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert "p2os_msgs" in r.stderr and "not on PyPI" in r.stderr


def test_a_bases_truth_is_taken_from_the_physics_bases_only(context, executor):
    """A true pose on the base's ``truth`` from any node but the physics bases is dropped
    and counted by sender (forged truths once made the true error read 63.9 m)."""
    from geometry_msgs.msg import PoseStamped

    from formation_ilc.nodes.pioneer_bridge import BridgeNode

    ex, nodes = executor
    params = [Parameter("robot_id", value=1), Parameter("scenario", value="paper-triangle3"),
              Parameter("driver", value="rosaria"), Parameter("driver_ns", value="/base_1"),
              Parameter("truth", value=True)]
    bridge = BridgeNode(context=context, parameter_overrides=params)
    bases = rclpy.create_node(ms.BASES_NODE, namespace=ms.NAMESPACE, context=context)
    forger = rclpy.create_node("forger", namespace=ms.NAMESPACE, context=context)
    nodes += [bridge, bases, forger]
    for n in nodes:
        ex.add_node(n)
    for node, x in ((forger, 1000.0), (bases, 1.0)):
        pub = node.create_publisher(PoseStamped, "/base_1/truth", ms.ODOM_QOS)
        spin_until(ex, lambda pub=pub: pub.get_subscription_count() >= 1)
        msg = PoseStamped()
        msg.header.frame_id = ms.WORLD_FRAME
        msg.pose.position.x, msg.pose.position.y = x, 2.0
        msg.pose.orientation.w = 1.0
        pub.publish(msg)
    spin_until(ex, lambda: bridge.core.truth is not None and bridge.writers.total >= 1)
    spin_until(ex, lambda: bridge.core.truth[0] == 1.0, timeout=2.0)
    assert bridge.writers.report() == {"/base_1/truth": {"/formation/forger": 1}}
    assert bridge.drops.counts["forged"] == 1


def test_a_robots_whereabouts_are_taken_from_its_own_bridge_only(context, executor):
    """With a safety filter the bridges read each other's whereabouts between trials; one
    in robot 2's name from any node but bridge_2 is dropped and counted by sender (a forged
    one, stamped ahead, would stand for robot 2 and hide where it really is)."""
    from geometry_msgs.msg import PoseStamped
    from std_msgs.msg import String

    from formation_ilc.config.bases import base_preset
    from formation_ilc.config.runconfig import make_config
    from formation_ilc.config.safety import SafetySettings, default_margin
    from formation_ilc.nodes.pioneer_bridge import BridgeNode

    ex, nodes = executor
    safety = SafetySettings("p3dx", base_preset("p3dx").limits, default_margin("p3dx"))
    cfg = make_config("paper-triangle3", links="direct", mode="wallclock", safety=safety)
    params = [Parameter("robot_id", value=1), Parameter("driver", value="rosaria"),
              Parameter("driver_ns", value="/pioneer_1")]
    bridge = BridgeNode(context=context, parameter_overrides=params)
    leader = rclpy.create_node(ms.LEADER_NODE, namespace=ms.NAMESPACE, context=context)
    other = rclpy.create_node(ms.bridge_name(2), namespace=ms.NAMESPACE, context=context)
    forger = rclpy.create_node("forger", namespace=ms.NAMESPACE, context=context)
    nodes += [bridge, leader, other, forger]
    for n in nodes:
        ex.add_node(n)
    leader.create_publisher(String, ms.CONFIG, ms.LATCHED_QOS).publish(
        ms.json_to_msg(cfg.to_json()))
    spin_until(ex, lambda: bridge.configured)
    assert bridge.core.safety is not None  # the run's filter: the returns are filtered
    for node, x, stamp in ((forger, 1000.0, 10**18), (other, 1.0, 10**9)):
        pub = node.create_publisher(PoseStamped, ms.whereabouts_topic(2), ms.SAMPLE_QOS)
        spin_until(ex, lambda pub=pub: pub.get_subscription_count() >= 1)
        pub.publish(ms.pose_to_msg((x, 2.0, 0.0), stamp, ms.WORLD_FRAME))
    spin_until(ex, lambda: 2 in bridge.core.peers and bridge.writers.total >= 1)
    assert bridge.core.peers[2][1] == (1.0, 2.0, 0.0)
    assert bridge.writers.report() == {
        f"/formation/{ms.whereabouts_topic(2)}": {"/formation/forger": 1}}
    assert bridge.drops.counts["forged"] == 1
