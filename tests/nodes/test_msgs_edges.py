"""msgs_schema edges the rule tests leave open: the accepted boundaries of the sample clock
and of a planar unit quaternion, what a pose and a path carry, the unwrapping of a path's
headings. (One case per validation rule: tests/nodes/test_msgs_rules.py.)"""

import dataclasses
import math

import numpy as np
import pytest

import msgs_schema as ms


def test_sample_clock_smallest_run_and_default_gap():
    clk = ms.SampleClock.for_run(0.1, 1, gap=1)
    assert (clk.samples, clk.period) == (1, 3)
    assert ms.SampleClock.for_run(0.1, 5).period == 5 + 1 + 20
    assert ms.SampleClock.for_run(0.123456789, 5).dt_ns == 123456789
    assert ms.SampleClock.for_run(2.0, 5).dt_ns == 2_000_000_000
    with pytest.raises(dataclasses.FrozenInstanceError):
        clk.samples = 2  # type: ignore[misc]


def test_quaternion_at_the_tolerance_boundary_is_accepted():
    # |x|, |y| and | |q| - 1 | exactly at 1e-6 are accepted (the rule is "more than")
    for x, y in ((1e-6, 0.0), (0.0, 1e-6)):
        w = math.sqrt(1.0 - x * x - y * y)
        assert ms.wire.heading_from_quaternion(x, y, 0.0, w, None) == pytest.approx(0.0, abs=1e-5)
    with pytest.raises(ms.MalformedMessage):
        ms.wire.heading_from_quaternion(0.0, 0.0, 0.6, 0.6, None)  # |q| = 0.85


def test_pose_message_is_planar():
    m = ms.pose_to_msg((1.0, 2.0, -2.5), 7, "robot_1")
    assert m.pose.position.z == 0.0
    assert (m.pose.orientation.z, m.pose.orientation.w) == (math.sin(-1.25), math.cos(-1.25))
    eta, ns, frame = ms.msg_to_pose(m)
    np.testing.assert_allclose(eta, [1.0, 2.0, -2.5])
    assert (ns, frame) == (7, "robot_1")


def test_path_header_stamp_is_the_last_label_and_headings_unwrap_along_it():
    th = np.array([3.0, 3.3, 3.6, 3.9])  # crosses pi: wrapped, 3.3 would read -2.98
    eta = np.column_stack([np.arange(4.0), np.zeros(4), th])
    m = ms.trajectory_to_path(eta, [10, 20, 30, 40], "robot_2")
    assert ms.stamp_to_ns(m.header.stamp) == 40
    got, stamps, frame = ms.path_to_trajectory(m)
    np.testing.assert_allclose(got[:, 2], th, atol=1e-12)
    assert stamps.tolist() == [10, 20, 30, 40] and frame == "robot_2"
    empty = ms.trajectory_to_path(np.zeros((0, 3)), [], "robot_2")
    assert ms.stamp_to_ns(empty.header.stamp) == 0 and len(empty.poses) == 0


def test_delivery_is_frozen():
    from formation_ilc.core.links import Delivery

    d = Delivery("robot_1", 5, np.zeros(3))
    with pytest.raises(dataclasses.FrozenInstanceError):
        d.label_ns = 6  # type: ignore[misc]
