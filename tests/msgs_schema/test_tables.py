"""Every topic's name, type and QoS (formation_ilc.core.names, msgs_schema.tables):
relative names that resolve in any namespace, one row per recorded topic and robot."""

from __future__ import annotations

import pytest

pytest.importorskip("rclpy")
import msgs_schema as ms  # noqa: E402


def test_topics_are_relative_and_resolve_in_any_namespace():
    assert ms.pose_topic(3) == "robot_3/pose"
    assert ms.cmd_vel_topic(3) == "robot_3/cmd_vel"
    assert ms.shared_pose_topic(1) == "robot_1/shared_pose"
    assert ms.trajectory_topic(12) == "robot_12/trajectory"
    assert ms.link_topic(2, "leader") == "robot_2/links/leader"
    # every name but /clock and tf2's topics is relative, so one formation runs under any
    # namespace (tf2's are absolute as tf2 has them: its frames say whose they are)
    for name, _, _ in ms.topic_table(4):
        assert name.startswith("/") == (name in (ms.CLOCK, ms.TF, ms.TF_STATIC)), name
    assert ms.absolute(ms.pose_topic(3)) == "/formation/robot_3/pose"
    assert ms.absolute(ms.CONFIG, "/team2") == "/team2/config"
    assert ms.absolute(ms.CLOCK, "/team2") == "/clock"
    assert ms.relative("/team2/robot_1/pose", "/team2") == "robot_1/pose"
    assert ms.robot_index(ms.robot_name(7)) == 7
    with pytest.raises(ms.MalformedMessage):
        ms.robot_index("leader")
    from rclpy.qos import DurabilityPolicy
    assert ms.LATCHED_QOS.durability == DurabilityPolicy.TRANSIENT_LOCAL


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
