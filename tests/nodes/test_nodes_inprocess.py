"""In-process node tests: a private rclpy Context per test, parameters by
``parameter_overrides``, and a test node that publishes inputs and asserts on the messages
the node under test sends back (bounded spin loops, no sleeps)."""

from __future__ import annotations

import contextlib
import subprocess
import sys
import time

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

from ..procs import spin_until, wait_emulator_ready  # noqa: E402


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


def test_link_emulator_delivers_the_batch_simulators_delay_stream(context):
    """Per link and tick, one message holding the pose labelled t - tau (tau from the delay
    stream of the trial) with its original label, or no pose while t - tau < 0."""
    from nav_msgs.msg import Path
    from std_msgs.msg import String

    from formation_ilc.config.runconfig import make_config
    from robot_sim.link_emulator import LinkEmulator

    cfg = make_config("paper-triangle3", seed=9)
    sc, clock = cfg.scenario, cfg.clock
    pb = Problem.from_scenario(sc)
    emu = LinkEmulator(context=context)
    tester = rclpy.create_node("tester", namespace=ms.NAMESPACE, context=context)
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(emu)
    ex.add_node(tester)
    try:
        got: dict[str, list[tuple[int, int | None]]] = {}

        def on_tick(msg: Path, link: str) -> None:
            tick, pose = ms.msg_to_link_tick(msg)
            got.setdefault(link, []).append(
                (tick, None if pose is None else ms.stamp_to_ns(pose.header.stamp)))

        links = [(2, "robot_1"), (3, "robot_1"), (1, ms.LEADER)]
        subs = [tester.create_subscription(Path, ms.link_topic(i, sender),
                                           lambda m, k=f"{sender}->{i}": on_tick(m, k),
                                           ms.SAMPLE_QOS) for i, sender in links]
        cfg_pub = tester.create_publisher(String, ms.CONFIG, ms.LATCHED_QOS)
        cfg_pub.publish(ms.json_to_msg(cfg.to_json()))
        spin_until(ex, lambda: emu.configured)
        shared = [tester.create_publisher(PoseStamped, ms.shared_pose_topic(j + 1),
                                          ms.SAMPLE_QOS) for j in range(pb.n)]
        ref = tester.create_publisher(PoseStamped, ms.REFERENCE, ms.SAMPLE_QOS)
        events = tester.create_publisher(String, ms.TRIAL_EVENTS, ms.SAMPLE_QOS)
        spin_until(ex, lambda: all(p.get_subscription_count() >= 1
                                   for p in [*shared, ref, events])
                   and all(sub.get_publisher_count() >= 1 for sub in subs))
        wait_emulator_ready(ex, tester, emu)
        ticks = 8
        # a hostile pose labelled with a later trial: dropped, it moves nothing
        shared[1].publish(ms.pose_to_msg(pb.eta_d[1, 0], clock.stamp_ns(5, 0),
                                         ms.WORLD_FRAME))
        events.publish(ms.json_to_msg({"event": ms.START, "trial": 0, "slot": 0, "seq": 0}))
        for t in range(ticks):  # lockstep: sample t+1 exists once tick t is delivered
            ns = clock.stamp_ns(0, t)
            for j in range(pb.n):
                shared[j].publish(ms.pose_to_msg(pb.eta_d[j, t], ns, ms.WORLD_FRAME))
            ref.publish(ms.pose_to_msg(sc.reference[t], ns, ms.WORLD_FRAME))
            spin_until(ex, lambda t=t: all(len(got.get(f"{s}->{i}", [])) == t + 1
                                           for i, s in links))
        tau, tau0 = sc.uncertainty.draw_delays(sc.seed, 0, pb.n, pb.src.shape[1], pb.samples)
        for i, sender in links:
            r = i - 1
            d = tau0[r] if sender == ms.LEADER else tau[r, list(pb.src[r]).index(0)]
            want = [(clock.stamp_ns(0, t),
                     clock.stamp_ns(0, t - int(d[t])) if t - int(d[t]) >= 0 else None)
                    for t in range(ticks)]
            assert got[f"{sender}->{i}"] == want, sender
        assert any(p is None for _, p in got["robot_1->2"])  # the early ticks carry nothing
        assert emu.links.k == 0 and emu.drops.counts["future"] == 1
    finally:
        ex.shutdown()
        emu.destroy_node()
        tester.destroy_node()


@contextlib.contextmanager
def leader_and_tester(context, mode: str):
    """A leader of paper-triangle3 (one trial, direct links, ``mode``), a tester node
    beside it, and the executor of both; all three ended afterwards."""
    from virtual_leader.node import LeaderNode

    leader = LeaderNode(context=context, parameter_overrides=[
        Parameter("scenario", value="paper-triangle3"), Parameter("trials", value=1),
        Parameter("links", value="direct"), Parameter("mode", value=mode)])
    tester = rclpy.create_node("tester", namespace=ms.NAMESPACE, context=context)
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(leader)
    ex.add_node(tester)
    try:
        yield leader, tester, ex
    finally:
        ex.shutdown()
        leader.destroy_node()
        tester.destroy_node()


def all_ready(leader) -> None:
    """Every node the leader waits for says ready for trial 0."""
    from formation_ilc.protocol.schedule import Ready

    for node in leader.expected:
        leader._on_ready(ms.json_to_msg(Ready(node, 0, "boot").to_json()))


def test_leader_names_the_endpoints_its_start_waits_for(context):
    """Every node is ready, but no robot reads the reference yet: what the leader says it
    waits for names the topic and the count (it said "nobody" before), and the names go
    once the readers are there."""
    with leader_and_tester(context, "realtime") as (leader, tester, ex):
        leader._gate.cancel()  # no start: what it waits for is the question
        all_ready(leader)
        assert not leader.core.sched.explain_wait(leader.core.refused)  # every node is ready
        waits = leader.core.start_waits_for()
        ref = f"{ms.NAMESPACE}/{ms.REFERENCE}"
        assert f"{ref}: 0 of 1 readers" in waits  # robot 1 sees the leader
        assert "/clock: 0 of 1 writers" in waits  # no plant yet
        # the readers come: each phrase goes with its endpoint
        tester.create_subscription(PoseStamped, ms.REFERENCE, lambda m: None, ms.SAMPLE_QOS)
        spin_until(ex, lambda: not any(w.startswith(ref) for w in leader.core.start_waits_for()))
        assert leader.core.start_waits_for() == ["/clock: 0 of 1 writers"]


def test_leader_sends_a_start_again_while_its_slot_does_not_move(context):
    """A follower whose reader matched after the start went out never gets it (the events
    topic keeps nothing for a late reader), and a lockstep trial would wait for it until the
    plant's time-out: while the slot has no new sample for RESEND_S / 2 the leader sends the
    same start again (same seq), and stops once a sample comes."""
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import String

    from formation_ilc.protocol.plant import RESEND_S

    with leader_and_tester(context, "lockstep") as (leader, tester, ex):
        events: list[dict] = []
        tester.create_subscription(String, ms.TRIAL_EVENTS,
                                   lambda m: events.append(ms.msg_to_json(m)), ms.SAMPLE_QOS)
        clock_pub = tester.create_publisher(Clock, ms.CLOCK, ms.CLOCK_QOS)
        all_ready(leader)
        starts = lambda: [e for e in events if e["event"] == "start"]  # noqa: E731
        spin_until(ex, lambda: len(starts()) >= 1, timeout=30)
        first = starts()[0]
        assert first["slot"] == 0 and leader.core.sched.running
        # nobody sends sample 0: the same start goes out again, and again
        spin_until(ex, lambda: len(starts()) >= 3, timeout=6 * RESEND_S)
        assert all(e == first for e in starts())
        assert leader.core.repeat.count >= 2
        # the plant's first sample: the slot moves, the repeats stop until it stalls again
        clock_pub.publish(ms.clock_msg(first["stamp_ns"]))
        spin_until(ex, lambda: leader.core.t == 0)
        assert leader.core.repeat.due == leader.core.last_change + leader.core.repeat.every
        n = leader.core.repeat.count
        # an abort ends the slot: nothing is repeated after it
        leader.core.sched.begin_abort("test")
        leader.core.aborted("test")
        assert (leader.core.repeat.event is None
                and leader.core.repeat.again(time.monotonic() + 99) is None)
        assert leader.core.repeat.count == n
