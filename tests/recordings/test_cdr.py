"""The batch simulator's CDR packing decodes like rclpy's bytes (rclpy leaves padding
bytes uninitialised, so the bytes are compared through the decoder and by length)."""

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped, Twist
from nav_msgs.msg import Path
from rclpy.serialization import deserialize_message, serialize_message
from rosgraph_msgs.msg import Clock
from std_msgs.msg import String

import msgs_schema as ms
from formation_ilc.recordings import cdr


def same(ours: bytes, theirs: bytes, typ) -> None:
    assert len(ours) == len(theirs)
    assert deserialize_message(ours, typ) == deserialize_message(theirs, typ)


@pytest.mark.parametrize("frame", ["robot_1", "robot_12", "leader", "r"])
@pytest.mark.parametrize("n", [0, 1, 2, 141])
def test_path_equals_rclpy(frame, n):
    rng = np.random.default_rng(n)
    eta = rng.normal(size=(n, 3))
    eta[:, 2] = 0.0  # cos/sin of 0 are exact in every libm
    stamps = (np.arange(n) + 7) * 200_000_000 + 3
    ref = serialize_message(ms.trajectory_to_path(eta, stamps.tolist(), frame))
    same(cdr.encode_path(eta, stamps, frame, int(stamps[-1]) if n else 0), ref, Path)


def test_path_headings_decode_back():
    eta = np.random.default_rng(0).normal(size=(50, 3))
    stamps = np.arange(50) * 100_000_000
    msg = deserialize_message(cdr.encode_path(eta, stamps, "robot_3", 5), Path)
    back, st, frame = ms.path_to_trajectory(msg, eta[:, 2])
    np.testing.assert_allclose(back, eta, rtol=0, atol=1e-14)
    assert st.tolist() == stamps.tolist() and frame == "robot_3"


def test_small_messages_equal_rclpy():
    same(cdr.encode_string('{"a": 1}'), serialize_message(String(data='{"a": 1}')), String)
    t = Twist()
    t.linear.x, t.angular.z = 0.5, -1.25
    same(cdr.encode_twist(0.5, -1.25), serialize_message(t), Twist)
    same(cdr.encode_clock(12_345_678_901), serialize_message(ms.clock_msg(12_345_678_901)),
         Clock)
    ps = ms.pose_to_msg((1.0, -2.0, 0.0), 42, "robot_2")
    same(cdr.encode_pose_stamped(np.array([1.0, -2.0, 0.0]), 42, "robot_2"),
         serialize_message(ps), PoseStamped)


@pytest.mark.parametrize("report", [
    {"node": "robot_sim", "trial": 3, "missed": {"robot_1": 0, "robot_2": 4}, "dropped": {}},
    {"node": "robot_1", "trial": 0, "delays": {"leader": {"0": 5, "2": 1}}, "note": "ä"},
])
def test_diagnostic_array_equals_rclpy(report):
    from diagnostic_msgs.msg import DiagnosticArray

    from formation_ilc.protocol.health import flatten, statuses

    ours = cdr.encode_diagnostic_array(1_700_000_000_123_456_789, [
        (s.level, s.name, s.message, s.hardware_id, flatten(s.values))
        for s in statuses(report, 0.1, 40, "robot_1")])
    theirs = serialize_message(ms.diagnostics_to_msg(report, 1_700_000_000_123_456_789, 0.1,
                                                     40, "robot_1"))
    same(ours, theirs, DiagnosticArray)
    assert ms.msg_to_report(deserialize_message(ours, DiagnosticArray)) == report
