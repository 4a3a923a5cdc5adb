"""The view's CDR shortcuts (msgs_schema: world_pose_cdr, stamped_cdr, vector_cdr) agree
with rclpy's own (de)serialization, and refuse what world_pose refuses."""

from __future__ import annotations

import math

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped, Vector3Stamped
from rclpy.serialization import deserialize_message, serialize_message

import msgs_schema as ms


@pytest.mark.parametrize("frame", ["map"])
@pytest.mark.parametrize("stamp", [0, 1, 1_999_999_999, 123 * 10**9 + 456])
@pytest.mark.parametrize("eta", [(1.0, -2.5, 0.3), (0.0, 0.0, -3.0), (1e6, 3e-9, math.pi)])
def test_pose_and_vector_cdr_round_trip(frame, stamp, eta):
    data = serialize_message(ms.pose_to_msg(eta, stamp, frame))
    got, ns = ms.world_pose_cdr(data)
    want, wns = ms.world_pose(deserialize_message(data, PoseStamped))
    assert ns == wns == stamp
    np.testing.assert_array_equal(got, want)
    tpl = serialize_message(ms.pose_to_msg(eta, 0, frame))
    assert ms.stamped_cdr(tpl, stamp) == data
    v = ms.vector_cdr(serialize_message(ms.vector_msg(0, 0.0, 0.0)), stamp, *eta)
    assert v == serialize_message(ms.vector_msg(stamp, *eta))
    m = deserialize_message(v, Vector3Stamped)
    assert (m.vector.x, m.vector.y, m.vector.z) == eta


def test_pose_cdr_refuses_what_world_pose_refuses():
    ok = ms.pose_to_msg((1.0, 2.0, 0.5), 10, "map")
    with pytest.raises(ms.MalformedMessage):
        ms.world_pose_cdr(serialize_message(ms.pose_to_msg((1.0, 2.0, 0.5), 10, "odom")))
    bad = ms.pose_to_msg((1.0, 2.0, 0.5), 10, "map")
    bad.pose.orientation.x = 0.5
    with pytest.raises(ms.MalformedMessage):
        ms.world_pose_cdr(serialize_message(bad))
    bad = ms.pose_to_msg((float("nan"), 2.0, 0.5), 10, "map")
    with pytest.raises(ms.MalformedMessage):
        ms.world_pose_cdr(serialize_message(bad))
    with pytest.raises(ms.MalformedMessage):
        ms.world_pose_cdr(serialize_message(ok)[:40])
