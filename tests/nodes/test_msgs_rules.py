"""Every validation rule of the message converters in msgs_schema, one rule per case.

Only converter validation is tested here (what a malformed message is refused for, and
what the error names); topic names and frame_id conventions belong to
tests/nodes/test_msgs_schema.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped, Twist
from std_msgs.msg import String

import msgs_schema as ms

NAN, INF = math.nan, math.inf


def pose(x=1.0, y=2.0, theta=0.3) -> PoseStamped:
    return ms.pose_to_msg([x, y, theta], 0, "robot_1")


def set_quaternion(msg: PoseStamped, x: float, y: float, z: float, w: float) -> PoseStamped:
    q = msg.pose.orientation
    q.x, q.y, q.z, q.w = x, y, z, w
    return msg


def refused(fn, *args, why: str) -> None:
    with pytest.raises(ms.MalformedMessage) as exc:
        fn(*args)
    assert why in str(exc.value), str(exc.value)


# --------------------------------------------------------------------------- msg_to_pose

@pytest.mark.parametrize(("axis", "value"), [("x", NAN), ("x", INF), ("y", NAN), ("y", -INF)])
def test_pose_position_must_be_finite(axis, value):
    msg = pose()
    setattr(msg.pose.position, axis, value)
    refused(ms.msg_to_pose, msg, why="non-finite position")


@pytest.mark.parametrize("component", ["x", "y", "z", "w"])
@pytest.mark.parametrize("value", [NAN, INF, -INF])
def test_pose_orientation_must_be_finite(component, value):
    msg = pose()
    setattr(msg.pose.orientation, component, value)
    refused(ms.msg_to_pose, msg, why="non-finite orientation")


def _tilted(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of the unit quaternion of yaw, then pitch, then roll (ZYX)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy)


@pytest.mark.parametrize(("roll", "pitch", "yaw"), [
    (0.3, 0.0, 0.0),      # about x only
    (0.0, 0.3, 0.0),      # about y only
    (0.1, 0.0, 1.2),      # a yaw with some roll
    (0.0, -0.05, -2.9),   # a yaw with some pitch
    (math.pi, 0.0, 0.0),  # upside down: z = w = 0
    (1e-5, 0.0, 0.5),     # tilted by 10 urad, above the 1e-6 tolerance
])
def test_pose_tilted_unit_quaternion_is_not_planar(roll, pitch, yaw):
    q = _tilted(roll, pitch, yaw)
    assert abs(math.sqrt(sum(c * c for c in q)) - 1.0) < 1e-12  # a unit quaternion
    refused(ms.msg_to_pose, set_quaternion(pose(), *q), why="not a unit rotation about z")


@pytest.mark.parametrize("q", [
    (0.0, 0.0, 0.0, 3.0),                                  # scaled
    (0.0, 0.0, 2 * math.sin(0.15), 2 * math.cos(0.15)),    # a yaw of 0.3, twice too long
    (0.0, 0.0, 0.0, 0.0),                                  # all zero
    (0.0, 0.0, 0.0, 1.0 + 1e-5),                           # 10 ppm too long
])
def test_pose_orientation_must_be_unit(q):
    refused(ms.msg_to_pose, set_quaternion(pose(), *q), why="not a unit rotation about z")


def test_pose_within_the_tolerance_is_accepted():
    """A planar unit quaternion rounded in its last digits (a sender's float32) decodes."""
    q = _tilted(1e-7, 0.0, 0.3)
    eta, _, _ = ms.msg_to_pose(set_quaternion(pose(), *q))
    assert eta[2] == pytest.approx(0.3, abs=1e-6)


# --------------------------------------------------------------------------- twist_to_u

@pytest.mark.parametrize(("part", "axis", "value"), [
    ("linear", "x", NAN), ("linear", "x", INF), ("angular", "z", NAN), ("angular", "z", -INF),
    ("linear", "y", 0.1), ("linear", "z", -0.1), ("angular", "x", 0.1), ("angular", "y", 1e-9),
    ("linear", "y", NAN),
])
def test_twist_must_be_a_finite_planar_command(part, axis, value):
    msg = ms.u_to_twist([0.35, -0.2])
    setattr(getattr(msg, part), axis, value)
    refused(ms.twist_to_u, msg, why="cmd_vel is not a finite planar (v, omega) command")


def test_twist_zero_command_is_accepted():
    assert ms.twist_to_u(Twist()).tolist() == [0.0, 0.0]


# --------------------------------------------------------------------------- paths

def _path(n: int):
    eta = np.column_stack([np.arange(n) * 0.1, np.zeros(n), np.linspace(0, 1, n)])
    return ms.trajectory_to_path(eta, [s * 1000 for s in range(n)], "robot_2"), eta


@pytest.mark.parametrize("expected", [3, 5, 0])
def test_path_length_must_match_the_reference_headings(expected):
    path, _ = _path(4)
    refused(ms.path_to_trajectory, path, np.zeros(expected),
            why=f"trajectory has 4 poses, expected {expected}")


@pytest.mark.parametrize(("bad", "why"), [("position", "non-finite position"),
                                          ("orientation", "not a unit rotation about z")])
def test_path_with_a_bad_pose_is_refused(bad, why):
    path, eta = _path(4)
    if bad == "position":
        path.poses[2].pose.position.y = NAN
    else:
        set_quaternion(path.poses[2], *_tilted(0.2, 0.0, 0.0))
    refused(ms.path_to_trajectory, path, eta[:, 2], why=why)


def test_trajectory_to_path_needs_one_stamp_per_sample():
    with pytest.raises(ValueError, match="one stamp per sample is required"):
        ms.trajectory_to_path(np.zeros((3, 3)), [0, 1], "robot_1")


# --------------------------------------------------------------------------- JSON

@pytest.mark.parametrize("text", ["{", "", "{'a': 1}", "nope"])
def test_json_must_parse(text):
    refused(ms.msg_to_json, String(data=text), why="not JSON")


@pytest.mark.parametrize("text", ["[1, 2]", '"x"', "3", "null", "NaN", "true"])
def test_json_must_be_an_object(text):
    refused(ms.msg_to_json, String(data=text), why="JSON is not an object")


@pytest.mark.parametrize(("data", "missing"), [
    ({"event": "start"}, ["trial"]),
    ({}, ["event", "trial"]),
    ({"trial": 1, "Event": "start"}, ["event"]),
])
def test_json_must_have_the_required_keys(data, missing):
    refused(ms.msg_to_json, ms.json_to_msg(data), ("event", "trial"),
            why=f"JSON lacks {missing}")


# --------------------------------------------------------------------------- time labels

@pytest.mark.parametrize(("kwargs", "rule"), [
    (dict(dt=0.0, samples=10), "dt > 0"),
    (dict(dt=-0.1, samples=10), "dt > 0"),
    (dict(dt=0.1, samples=0), "samples >= 1"),
    (dict(dt=0.1, samples=10, gap=0), "gap >= 1"),
])
def test_sample_clock_for_run_rules(kwargs, rule):
    # one message states all three rules; it must at least state the broken one
    with pytest.raises(ValueError) as exc:
        ms.SampleClock.for_run(**kwargs)
    assert rule in str(exc.value)


def test_sample_clock_decode_refuses_a_negative_stamp():
    clk = ms.SampleClock.for_run(0.1, 10, gap=5)
    refused(clk.decode, -1, why="negative stamp -1 ns")


def test_sample_clock_decode_refuses_a_stamp_between_trials():
    """Sample T is the last of a trial; T + 1 .. period - 1 are the gap between trials.
    The stamp is rounded to the nearest sample first (half a sample rounds up)."""
    clk = ms.SampleClock.for_run(0.1, 10, gap=5)  # period 16 samples, dT = 1e8 ns
    dt = clk.dt_ns
    assert clk.decode(clk.stamp_ns(2, 10)) == (2, 10)
    assert clk.decode(clk.stamp_ns(2, 10) + dt // 2 - 1) == (2, 10)
    refused(clk.decode, clk.stamp_ns(2, 10) + dt // 2, why="is between trials (sample 11 of 10)")
    refused(clk.decode, clk.stamp_ns(2, 15), why="is between trials (sample 15 of 10)")
    assert clk.decode(clk.stamp_ns(2, 15) + dt // 2) == (3, 0)


# --------------------------------------------------------------------------- names

@pytest.mark.parametrize("name", ["leader", "robot_", "robot_x", "robot_-1", "robot_1a",
                                  "Robot_1", "", "robot 1", "robot_+1", "robot_1.0"])
def test_robot_index_refuses_what_is_not_a_robot_name(name):
    refused(ms.robot_index, name, why=f"not a robot name: {name!r}")


@pytest.mark.parametrize(("name", "index"), [("robot_1", 1), ("robot_12", 12)])
def test_robot_index_reads_robot_names(name, index):
    assert ms.robot_index(name) == index
