"""Wire contract: names, QoS and numpy <-> message converters, by round trip."""

from __future__ import annotations

import math

import numpy as np
import pytest

ms = pytest.importorskip("msgs_schema")


def test_topics_are_relative_and_resolve_in_any_namespace():
    assert ms.pose_topic(3) == "robot_3/pose"
    assert ms.cmd_vel_topic(3) == "robot_3/cmd_vel"
    assert ms.shared_pose_topic(1) == "robot_1/shared_pose"
    assert ms.trajectory_topic(12) == "robot_12/trajectory"
    assert ms.link_topic(2, "leader") == "robot_2/links/leader"
    # every name but /clock is relative, so one formation runs under any namespace
    for name, _, _ in ms.topic_table(4):
        assert name.startswith("/") == (name == ms.CLOCK), name
    assert ms.absolute(ms.pose_topic(3)) == "/formation/robot_3/pose"
    assert ms.absolute(ms.CONFIG, "/team2") == "/team2/config"
    assert ms.absolute(ms.CLOCK, "/team2") == "/clock"
    assert ms.relative("/team2/robot_1/pose", "/team2") == "robot_1/pose"
    assert ms.robot_index(ms.robot_name(7)) == 7
    with pytest.raises(ms.MalformedMessage):
        ms.robot_index("leader")
    from rclpy.qos import DurabilityPolicy
    assert ms.LATCHED_QOS.durability == DurabilityPolicy.TRANSIENT_LOCAL


def test_sample_clock_round_trip_and_labels():
    clk = ms.SampleClock.for_run(0.2, 140, gap=20)
    assert clk.dt_ns == 200_000_000
    for k in (0, 1, 7, 1999):
        for s in (0, 1, 70, 140):
            ns = clk.stamp_ns(k, s)
            assert clk.decode(ns) == (k, s)
            t = ms.ns_to_stamp(ns)
            assert ms.stamp_to_ns(t) == ns
            # nearest sample: a label a bit off the grid still decodes
            assert clk.decode(ns + clk.dt_ns // 3) == (k, s)
    with pytest.raises(ms.MalformedMessage):
        clk.decode(clk.stamp_ns(0, 141))  # between trials
    with pytest.raises(ms.MalformedMessage):
        clk.decode(-1)


def test_pose_round_trip_with_unwrapped_heading():
    rng = np.random.default_rng(3)
    for _ in range(200):
        eta = np.array([rng.uniform(-50, 50), rng.uniform(-50, 50), rng.uniform(-30, 30)])
        ns = int(rng.integers(0, 10**12))
        msg = ms.pose_to_msg(eta, ns, "robot_2")
        back, st, frame = ms.msg_to_pose(msg, eta[2] + rng.uniform(-1, 1))
        assert st == ns and frame == "robot_2"
        assert back[:2].tolist() == eta[:2].tolist()  # positions are exact
        assert abs(back[2] - eta[2]) < 1e-13          # heading through a quaternion
        wrapped, _, _ = ms.msg_to_pose(msg)
        assert -math.pi < wrapped[2] <= math.pi
        assert abs(math.remainder(wrapped[2] - eta[2], 2 * math.pi)) < 1e-13


@pytest.mark.parametrize("bad", ["nan_x", "inf_q", "tilted", "not_unit"])
def test_malformed_pose_is_rejected(bad):
    msg = ms.pose_to_msg([1.0, 2.0, 0.3], 0, "robot_1")
    if bad == "nan_x":
        msg.pose.position.x = float("nan")
    elif bad == "inf_q":
        msg.pose.orientation.w = float("inf")
    elif bad == "tilted":
        msg.pose.orientation.x = 0.3
    else:
        msg.pose.orientation.w = 3.0
    with pytest.raises(ms.MalformedMessage):
        ms.msg_to_pose(msg)


def test_twist_round_trip():
    u = np.array([0.35, -0.2])
    assert ms.twist_to_u(ms.u_to_twist(u)).tolist() == u.tolist()
    t = ms.u_to_twist(u)
    t.linear.x = float("nan")
    with pytest.raises(ms.MalformedMessage):
        ms.twist_to_u(t)
    t = ms.u_to_twist(u)
    t.linear.y = 1.0
    with pytest.raises(ms.MalformedMessage):
        ms.twist_to_u(t)


def test_trajectory_round_trip():
    rng = np.random.default_rng(0)
    clk = ms.SampleClock.for_run(0.1, 30)
    eta = np.cumsum(rng.normal(size=(31, 3)) * 0.3, axis=0)
    stamps = [clk.stamp_ns(4, s) for s in range(31)]
    path = ms.trajectory_to_path(eta, stamps, "robot_5")
    back, st, frame = ms.path_to_trajectory(path, eta[:, 2])
    assert frame == "robot_5" and st.tolist() == stamps
    np.testing.assert_array_equal(back[:, :2], eta[:, :2])
    np.testing.assert_allclose(back[:, 2], eta[:, 2], atol=1e-13, rtol=0)
    # unwrapped against the previous pose when no reference is given
    back2, _, _ = ms.path_to_trajectory(path)
    np.testing.assert_allclose(back2[:, 2] - back2[0, 2], eta[:, 2] - eta[0, 2], atol=1e-12)
    with pytest.raises(ms.MalformedMessage):
        ms.path_to_trajectory(path, eta[:-1, 2])  # wrong length
    path.poses[3].header.frame_id = "robot_1"
    with pytest.raises(ms.MalformedMessage):
        ms.path_to_trajectory(path, eta[:, 2])


def test_link_tick_keeps_the_original_label():
    a = ms.pose_to_msg([1, 2, 3], 5_000, ms.WORLD_FRAME)
    tick, pose = ms.msg_to_link_tick(ms.link_tick_to_msg(9_000, a))
    assert tick == 9_000 and ms.stamp_to_ns(pose.header.stamp) == 5_000
    assert pose.header.frame_id == ms.WORLD_FRAME
    tick, pose = ms.msg_to_link_tick(ms.link_tick_to_msg(9_000, None))
    assert tick == 9_000 and pose is None
    two = ms.link_tick_to_msg(9_000, a)
    two.poses.append(a)
    with pytest.raises(ms.MalformedMessage):
        ms.msg_to_link_tick(two)


def test_world_pose_requires_the_world_frame():
    eta, ns = ms.world_pose(ms.pose_to_msg([1, 2, 0.5], 7, ms.WORLD_FRAME))
    assert ns == 7 and eta.tolist()[:2] == [1, 2]
    with pytest.raises(ms.MalformedMessage, match="frame 'robot_1'"):
        ms.world_pose(ms.pose_to_msg([1, 2, 0.5], 7, "robot_1"))


def test_json_messages():
    d = {"event": ms.START, "trial": 3}
    assert ms.msg_to_json(ms.json_to_msg(d), ("event", "trial")) == d
    from std_msgs.msg import String
    for bad in ("{", "[1, 2]", '"x"'):
        with pytest.raises(ms.MalformedMessage):
            ms.msg_to_json(String(data=bad))
    with pytest.raises(ms.MalformedMessage):
        ms.msg_to_json(ms.json_to_msg({"event": "start"}), ("event", "trial"))


def test_messages_serialize():
    """The converters build messages that survive CDR (what goes on the wire)."""
    from geometry_msgs.msg import PoseStamped
    from nav_msgs.msg import Path
    from rclpy.serialization import deserialize_message, serialize_message

    m = ms.pose_to_msg([1.5, -2.0, 2.9], 123_456_789_012, "robot_4")
    back = deserialize_message(serialize_message(m), PoseStamped)
    eta, ns, frame = ms.msg_to_pose(back, 2.9)
    assert ns == 123_456_789_012 and frame == "robot_4" and abs(eta[2] - 2.9) < 1e-15
    p = ms.link_tick_to_msg(1, m)
    assert len(deserialize_message(serialize_message(p), Path).poses) == 1


def test_topic_table_covers_every_robot_once_and_no_other():
    """What the recorder subscribes to: the run's topics, and per robot 1..n its pose,
    command and trajectories; nothing for a robot 0 or n+1, nothing twice."""
    for n in (1, 3, 6):
        names = [name for name, _, _ in ms.topic_table(n)]
        assert len(names) == len(set(names))
        robots = sorted({int(x.split("/")[0][6:]) for x in names if x.startswith("robot_")})
        assert robots == list(range(1, n + 1))
        for i in range(1, n + 1):
            for topic in (ms.pose_topic(i), ms.cmd_vel_topic(i), ms.trajectory_topic(i),
                          ms.true_trajectory_topic(i)):
                assert topic in names
            # repeats of other messages, bit for bit: not recorded
            assert ms.shared_pose_topic(i) not in names
        for topic in (ms.CONFIG, ms.REFERENCE, ms.TRIAL_EVENTS, ms.READY, ms.DIAGNOSTICS,
                      ms.CLOCK):
            assert topic in names


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
    from geometry_msgs.msg import Twist, TwistStamped

    t = ms.driver_twist(0.3, -0.7, stamped=False)
    assert isinstance(t, Twist) and (t.linear.x, t.angular.z) == (0.3, -0.7)
    s = ms.driver_twist(0.3, -0.7, stamped=True, stamp_ns=5_000_000_001)
    assert isinstance(s, TwistStamped)
    assert (s.twist.linear.x, s.twist.angular.z) == (0.3, -0.7)
    assert ms.stamp_to_ns(s.header.stamp) == 5_000_000_001
    assert s.header.frame_id == "base_link"
    assert ms.stamp_to_ns(ms.driver_twist(0, 0, stamped=True).header.stamp) == 0


def test_link_tick_takes_the_one_pose_it_holds():
    a = ms.pose_to_msg([1, 2, 3], 5_000, ms.WORLD_FRAME)
    m = ms.link_tick_to_msg(9_000, a)
    assert ms.msg_to_link_tick(m)[1] is m.poses[0]


def test_driver_specs_cannot_be_changed_by_a_caller():
    import dataclasses

    spec = ms.DRIVERS["rosaria"]
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.cmd = "other"  # type: ignore[misc]
    assert ms.DRIVERS["rosaria"].cmd == "cmd_vel"
