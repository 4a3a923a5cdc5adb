"""The numpy <-> message converters (msgs_schema.convert): round trips, every validation
rule one case each (what a malformed message is refused for, and what the error names),
the accepted boundaries, and the bound on a Path's bytes."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

pytest.importorskip("rclpy")

from geometry_msgs.msg import PoseStamped, Twist  # noqa: E402
from nav_msgs.msg import Path  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from std_msgs.msg import String  # noqa: E402

import msgs_schema as ms  # noqa: E402


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








def test_link_tick_takes_the_one_pose_it_holds():
    a = ms.pose_to_msg([1, 2, 3], 5_000, ms.WORLD_FRAME)
    m = ms.link_tick_to_msg(9_000, a)
    assert ms.msg_to_link_tick(m)[1] is m.poses[0]




# ----------------------------------------------------------------------------------------
# msgs_schema edges the rule tests leave open: the accepted boundaries of the sample clock
# and of a planar unit quaternion, what a pose and a path carry, the unwrapping of a
# path's headings. (One case per validation rule: below.)

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


# ----------------------------------------------------------------------------------------
# Every validation rule of the message converters in msgs_schema, one rule per case.

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


# ----------------------------------------------------------------------------------------
# Bounded message cost: a Path longer than a trial is refused from its length, before it
# is deserialized (a 14 MB forged Path stalled every node for about 85 s while rclpy built
# its Python objects); every real trajectory and link tick fits the bound.

def _bytes(poses: int, frame: str = ms.WORLD_FRAME) -> bytes:
    eta = np.zeros((poses, 3))
    return serialize_message(ms.trajectory_to_path(eta, range(poses), frame))


@pytest.mark.parametrize("poses", [0, 1, 141, 1001])
def test_every_real_path_fits_its_bound_even_with_the_longest_frame_id(poses):
    for frame in (ms.WORLD_FRAME, "f" * ms.FRAME_ID_MAX):
        data = _bytes(poses, frame)
        assert len(data) <= ms.path_limit(poses)
        msg = ms.path_from_raw(data, poses)
        assert len(msg.poses) == poses and msg.header.frame_id == frame


def test_a_path_longer_than_the_trial_is_refused_before_it_is_deserialized(monkeypatch):
    from msgs_schema import convert

    calls = []
    real = convert.deserialize
    monkeypatch.setattr(convert, "deserialize",
                        lambda data, cls: calls.append(1) or real(data, cls))
    big = _bytes(300)  # twice a trial of 140 samples (a size bound: 141 exactly is checked after)
    with pytest.raises(ms.MalformedMessage, match=r"trajectory of \d+ bytes: longer than 141 "
                                                  r"poses can be"):
        ms.path_from_raw(big, 141, "trajectory")
    forged = b"\x00\x01\x00\x00" + b"\x00" * (14 << 20)  # 14 MB of anything
    with pytest.raises(ms.MalformedMessage, match="longer than 1 poses"):
        ms.path_from_raw(forged, 1, "link tick")
    assert calls == []  # neither reached the deserializer
    assert ms.path_from_raw(_bytes(141), 141) is not None and calls == [1]
    built = Path()
    assert ms.path_from_raw(built, 1) is built  # an in-process caller's message
