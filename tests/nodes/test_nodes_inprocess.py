"""In-process node tests: a private rclpy Context per test, parameters by
``parameter_overrides``, and a test node that publishes inputs and asserts on the messages
the node under test sends back (bounded spin loops, no sleeps)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

pytestmark = pytest.mark.ros

rclpy = pytest.importorskip("rclpy")
from geometry_msgs.msg import PoseStamped, Twist  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

import msgs_schema as ms  # noqa: E402
from formation_ilc.config.scenario import load_scenario  # noqa: E402
from formation_ilc.core.clock import SampleClock  # noqa: E402
from formation_ilc.model.simulate import Problem  # noqa: E402
from formation_ilc.protocol.learner import RobotLearner  # noqa: E402

from ..procs import spin_until  # noqa: E402


def test_robot_node_commands_what_the_core_computes(context):
    from formation_ilc.nodes.robot import RobotNode

    params = [Parameter("robot_id", value=2), Parameter("scenario", value="paper-triangle3"),
              Parameter("links", value="direct"), Parameter("delay", value=False),
              Parameter("noise", value=False)]
    robot = RobotNode(context=context, parameter_overrides=params)
    tester = rclpy.create_node("tester", namespace=ms.NAMESPACE, context=context)
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(robot)
    ex.add_node(tester)
    try:
        # the node is named after its robot_id without a remapping, in the default namespace
        assert robot.get_fully_qualified_name() == "/formation/robot_2"
        cmds: list[Twist] = []
        shared: list[PoseStamped] = []
        tester.create_subscription(Twist, ms.cmd_vel_topic(2), cmds.append, ms.SAMPLE_QOS)
        tester.create_subscription(PoseStamped, ms.shared_pose_topic(2), shared.append,
                                   ms.SAMPLE_QOS)
        pose_pub = tester.create_publisher(PoseStamped, ms.pose_topic(2), ms.SAMPLE_QOS)
        nb_pub = tester.create_publisher(PoseStamped, ms.shared_pose_topic(1), ms.SAMPLE_QOS)
        spin_until(ex, lambda: pose_pub.get_subscription_count() >= 1
                   and nb_pub.get_subscription_count() >= 1
                   and robot.cmd_pub.get_subscription_count() >= 1)

        sc = load_scenario("paper-triangle3").with_options(noise=False, delay=False)
        pb = Problem.from_scenario(sc)
        clock = SampleClock.for_run(sc.dt, sc.samples)
        rng = np.random.default_rng(4)
        own = pb.eta_d[1, :3] + rng.normal(scale=0.1, size=(3, 3))
        nb = pb.eta_d[0, :3] + rng.normal(scale=0.1, size=(3, 3))
        ref = RobotLearner(pb, 1, clock, direct=True)
        for t in range(3):
            ns = clock.stamp_ns(0, t)
            # a malformed pose first: dropped and counted, nothing sent for it
            bad = ms.pose_to_msg(own[t], ns, "robot_2")  # not the world frame
            pose_pub.publish(bad)
            pose_pub.publish(ms.pose_to_msg(own[t], ns, ms.WORLD_FRAME))
            nb_pub.publish(ms.pose_to_msg(nb[t], ns, ms.WORLD_FRAME))
            spin_until(ex, lambda t=t: len(cmds) == t + 1 and len(shared) == t + 1)
            ref.on_pose(ns, own[t])
            ref.on_link_pose("robot_1", ns, nb[t])
            u = ref.command()
            assert (cmds[t].linear.x, cmds[t].angular.z) == pytest.approx(tuple(u), abs=1e-12)
        assert [ms.stamp_to_ns(p.header.stamp) for p in shared] == [
            clock.stamp_ns(0, t) for t in range(3)]
        assert robot.drops.counts["malformed"] == 3
        assert robot.learner.delays["robot_1"] == {0: 3}
    finally:
        ex.shutdown()
        robot.destroy_node()
        tester.destroy_node()


def test_robot_node_needs_a_robot_id(context):
    from formation_ilc.nodes.robot import RobotNode

    with pytest.raises(ValueError, match="robot_id"):
        RobotNode(context=context)
    with pytest.raises(ValueError, match="robot_id"):
        RobotNode(context=context, parameter_overrides=[Parameter("robot_id", value=0)])


@pytest.mark.parametrize(("module", "words"), [
    ("formation_ilc.nodes.robot", ["robot_id", "links", "--robots"]),
    ("robot_sim.node", ["plant", "timeout"]),
    ("robot_sim.link_emulator", ["emulated", "delivered_label"]),
    ("virtual_leader.node", ["scenario", "links", "nodes_expected"]),
    ("formation_ilc.nodes.recorder", ["--output", "MCAP"]),
])
def test_every_entry_script_prints_help_and_exits(module, words):
    res = subprocess.run([sys.executable, "-m", module, "--help"], capture_output=True,
                         text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    for w in words:
        assert w in res.stdout, (w, res.stdout[:400])
    assert "--ros-args" in res.stdout


def test_a_clock_exchange_says_a_warning_and_then_news_from_its_one_timer(context):
    """The clock core's events come out of one timer callback at their own severities: a
    warning, then an estimate that converged, then a warning again. rclpy refuses a call
    site whose severity changes ("Logger severity cannot be changed between calls"): the
    first estimate after a warning killed nodes of a 50-robot run."""
    from formation_ilc.config.runconfig import make_config
    from formation_ilc.nodes.clocks import ClockExchange, node_clock

    cfg = make_config("paper-triangle3", mode="realtime")
    node = rclpy.create_node("robot_9", namespace=ms.NAMESPACE, context=context)
    try:
        said: list[tuple[str, str]] = []
        ex = ClockExchange(node, "robot_9", cfg, node_clock(cfg, None), peers=["robot_1"],
                           askers=[], drops=None, on_event=lambda lv, t: said.append((lv, t)))
        words = [("warn", "w1"), ("info", "i1"), ("warn", "w2"), ("info", "i2")]
        ex.sync.questions = lambda now: []  # type: ignore[method-assign]
        ex.sync.events = lambda now: [words.pop(0)] if words else []  # type: ignore[method-assign]
        for _ in range(4):
            ex._on_timer()
        assert said == [("warn", "w1"), ("info", "i1"), ("warn", "w2"), ("info", "i2")]
    finally:
        node.destroy_node()
