"""The per-sample messages as bytes (msgs_schema.wire): the same bytes as rclpy's serialiser,
the same values and the same refusals as the message-object converters."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

ms = pytest.importorskip("msgs_schema")
from geometry_msgs.msg import PoseStamped, Twist  # noqa: E402
from nav_msgs.msg import Path  # noqa: E402
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402

w = ms.wire


def _poses(n: int = 300, seed: int = 4):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        eta = np.array([rng.uniform(-50, 50), rng.uniform(-50, 50), rng.uniform(-30, 30)])
        yield eta, int(rng.integers(0, 10**13))


def _same(ours: bytes, msg) -> bool:
    """Our bytes are rclpy's but for padding (which rclpy's serialiser leaves
    uninitialised): the same length, and they decode to the same message."""
    return (len(ours) == len(serialize_message(msg))
            and deserialize_message(ours, type(msg)) == msg)


def test_packing_gives_rclpys_bytes():
    for eta, ns in _poses():
        # frame "map" (what the stack sends) leaves no padding: byte for byte
        assert w.pose_bytes(eta, ns) == serialize_message(ms.pose_to_msg(eta, ns, "map"))
        for frame in ("robot_2", ""):
            assert _same(w.pose_bytes(eta, ns, frame), ms.pose_to_msg(eta, ns, frame))
        u = eta[:2]
        assert w.twist_bytes(u) == serialize_message(ms.u_to_twist(u))
        assert w.clock_bytes(ns) == serialize_message(ms.clock_msg(ns))
        pose = ms.pose_to_msg(eta, ns, ms.WORLD_FRAME)
        raw = w.read_pose(serialize_message(pose))
        # a link tick pads before the pose's doubles
        assert _same(w.link_tick_bytes(ns + 7, raw), ms.link_tick_to_msg(ns + 7, pose))
    assert w.link_tick_bytes(5, None) == serialize_message(ms.link_tick_to_msg(5, None))


def test_a_received_pose_is_forwarded_bit_for_bit():
    # the link emulator forwards the doubles as sent, not recomputed from a heading
    msg = ms.pose_to_msg((1.0, 2.0, 0.5), 3, ms.WORLD_FRAME)
    msg.pose.orientation.z = math.nextafter(msg.pose.orientation.z, 1.0)
    raw = w.read_pose(serialize_message(msg))
    assert w.raw_pose_bytes(raw) == serialize_message(msg)
    back = deserialize_message(w.link_tick_bytes(9, raw), Path)
    assert back.poses[0] == msg
    other = ms.pose_to_msg((1.0, 2.0, 0.5), 3, "odom")
    assert _same(w.raw_pose_bytes(w.read_pose(serialize_message(other))), other)


def test_the_preview_holds_each_robots_pose_bytes():
    """The plant's preview (a Path of the team's poses of one sample) decodes as rclpy does
    to those PoseStamped, and each read back packs to the bytes sent on robot_i/pose."""
    poses = list(_poses(6, seed=8))
    stamp = poses[0][1]
    raw = [w.raw_pose(eta, stamp) for eta, _ in poses]
    data = w.pose_set_bytes(stamp, raw)
    msg = Path()
    msg.header.frame_id = "map"
    ms.ns_to_stamp(stamp, msg.header.stamp)
    msg.poses = [ms.pose_to_msg(eta, stamp, "map") for eta, _ in poses]
    assert _same(data, msg)
    got_stamp, got = w.read_pose_set(data, 6)
    assert got_stamp == stamp and got == raw
    assert [w.raw_pose_bytes(p) for p in got] == [w.pose_bytes(eta, stamp) for eta, _ in poses]
    with pytest.raises(ms.MalformedMessage, match="at most 5 poses expected, got 6"):
        w.read_pose_set(data, 5)
    with pytest.raises(ms.MalformedMessage):
        w.read_pose_set(data[:-8], 6)


def test_a_pose_block_reads_the_preview_as_the_one_by_one_reader_does():
    """``read_pose_block`` (the robots' reading of the plant's team/poses) gives every
    label and double of ``read_pose_set``, and None (no verdict) for any bytes it does not
    take whole: another frame, another byte order, a count past ``most``, a cut message, an
    invalid stamp."""
    for n in (1, 2, 6, 50):
        poses = list(_poses(n, seed=n))
        stamp = poses[0][1]
        raw = [w.raw_pose(eta, ns) for eta, ns in poses]  # a label of its own each
        data = w.pose_set_bytes(stamp, raw)
        block = w.read_pose_block(data, n)
        assert block is not None
        labels, fields = block
        assert labels.tolist() == [p.label_ns for p in raw]
        assert [tuple(row) for row in fields.tolist()] == [p.fields for p in raw]
    raw = [w.raw_pose(eta, ns) for eta, ns in _poses(4, seed=3)]
    data = w.pose_set_bytes(7, raw)
    assert w.read_pose_block(data, 3) is None  # more than ``most``
    assert w.read_pose_block(data[:-8], 4) is None
    assert w.read_pose_block(data + b"\0" * 8, 4) is None
    assert w.read_pose_block(w.pose_set_bytes(7, []), 4) is None
    other = raw[:2] + [raw[2]._replace(frame="robot_1")] + raw[3:]
    assert w.read_pose_block(w.pose_set_bytes(7, other), 4) is None
    # an out-of-range nanosecond in any pose's stamp, or in the path's own
    for offset in (8, 28, 176):  # the path's nanosec, pose 0's, pose 2's
        bad = bytearray(data)
        bad[offset:offset + 4] = (2 * 10**9).to_bytes(4, "little")
        assert w.read_pose_block(bytes(bad), 4) is None
        with pytest.raises(ms.MalformedMessage):
            w.read_pose_set(bytes(bad), 4)
    msg = Path()
    msg.header.frame_id = "map"
    msg.poses = [ms.pose_to_msg(eta, ns, "map") for eta, ns in _poses(3, seed=1)]
    big_endian = bytearray(serialize_message(msg))
    big_endian[1] = 0  # the same header claimed big endian: no longer the stack's layout
    assert w.read_pose_block(bytes(big_endian), 3) is None


def test_reading_gives_the_converters_values():
    for eta, ns in _poses():
        for frame in ("map", "robot_2"):
            msg = ms.pose_to_msg(eta, ns, frame)
            p = w.read_pose(serialize_message(msg))
            assert (p.label_ns, p.frame) == (ns, frame)
            for prev in (None, float(eta[2]) + 0.3):
                got = w.pose_eta(p, prev)
                want, _, _ = ms.msg_to_pose(msg, prev)
                assert got.tobytes() == want.tobytes()
        tw = ms.u_to_twist(eta[:2])
        assert w.read_twist(serialize_message(tw)).tobytes() == ms.twist_to_u(tw).tobytes()
        assert w.read_clock(serialize_message(ms.clock_msg(ns))) == ns
        tick, got = w.read_link_tick(serialize_message(ms.link_tick_to_msg(
            ns + 1, ms.pose_to_msg(eta, ns, ms.WORLD_FRAME))))
        assert tick == ns + 1 and got is not None and got.label_ns == ns
    assert w.read_link_tick(serialize_message(ms.link_tick_to_msg(4, None))) == (4, None)


def _bad_pose(bad: str) -> PoseStamped:
    msg = ms.pose_to_msg([1.0, 2.0, 0.3], 0, "map")
    if bad == "nan_x":
        msg.pose.position.x = float("nan")
    elif bad == "inf_y":
        msg.pose.position.y = -float("inf")
    elif bad == "inf_q":
        msg.pose.orientation.w = float("inf")
    elif bad == "tilted":
        msg.pose.orientation.x = 0.3
    elif bad == "not_unit":
        msg.pose.orientation.w = 3.0
    elif bad == "nanosec":
        msg.header.stamp.nanosec = 1_000_000_000
    elif bad == "frame":
        msg.header.frame_id = "odom"
    return msg


@pytest.mark.parametrize("bad", ["nan_x", "inf_y", "inf_q", "tilted", "not_unit", "nanosec",
                                 "frame"])
def test_reading_refuses_what_the_converters_refuse(bad):
    msg = _bad_pose(bad)
    with pytest.raises(ms.MalformedMessage):
        ms.stamp_to_ns(msg.header.stamp)
        ms.world_pose(msg)
    with pytest.raises(ms.MalformedMessage):
        w.world_eta(w.read_pose(serialize_message(msg)))


@pytest.mark.parametrize(("field", "value"), [("linear.x", math.nan), ("angular.z", math.inf),
                                              ("linear.y", 0.1), ("angular.x", -1e-300),
                                              ("linear.z", math.nan)])
def test_twist_must_be_a_finite_planar_command_in_bytes_too(field, value):
    tw = Twist()
    part, axis = field.split(".")
    setattr(getattr(tw, part), axis, value)
    with pytest.raises(ms.MalformedMessage):
        ms.twist_to_u(tw)
    with pytest.raises(ms.MalformedMessage):
        w.read_twist(serialize_message(tw))
    tw = Twist()
    tw.linear.y = -0.0  # minus zero is zero
    assert w.read_twist(serialize_message(tw)).tolist() == [0.0, 0.0]


def test_other_encodings_read_as_a_typed_subscription_reads_them():
    # big endian XCDR1, and XCDR2 (8-byte members aligned to 4), with a longer frame
    def pose(order: str, xcdr2: bool) -> bytes:
        enc = bytes([0, (6 if xcdr2 else 0) + (order == "<")]) + b"\x00\x00"
        frame = b"robot_10\x00"
        head = struct.pack(order + "iII", 7, 8, len(frame)) + frame
        pad = (-len(head)) % (4 if xcdr2 else 8)
        doubles = (1.5, -2.5, 0.0, 0.0, 0.0, math.sin(0.2), math.cos(0.2))
        return enc + head + b"\x00" * pad + struct.pack(order + "7d", *doubles)

    for order in "<>":
        for xcdr2 in (False, True):
            p = w.read_pose(pose(order, xcdr2))
            assert (p.label_ns, p.frame) == (7_000_000_008, "robot_10")
            assert w.pose_eta(p).tolist() == pytest.approx([1.5, -2.5, 0.4], abs=1e-15)
    be = b"\x00\x00\x00\x00" + struct.pack(">6d", 1.0, 0, 0, 0, 0, 2.0)
    assert w.read_twist(be).tolist() == [1.0, 2.0]
    assert w.read_clock(b"\x00\x00\x00\x00" + struct.pack(">iI", 3, 4)) == 3_000_000_004


@pytest.mark.parametrize("cut", [0, 3, 4, 11, 16, 40, 75])
def test_bytes_that_do_not_decode_are_malformed(cut):
    data = w.pose_bytes((1.0, 2.0, 0.3), 5)
    with pytest.raises(ms.MalformedMessage):
        w.read_pose(data[:cut])
    with pytest.raises(ms.MalformedMessage):
        w.read_pose(b"\x01\x07" + data[2:])  # no such encapsulation
    with pytest.raises(ms.MalformedMessage):
        w.read_twist(w.twist_bytes((1.0, 2.0))[:cut // 2 + 4])
    with pytest.raises(ms.MalformedMessage):
        w.read_link_tick(w.link_tick_bytes(3, w.read_pose(data))[:cut + 20])


def test_a_string_reads_up_to_its_first_nul_as_rclpy_reads_it():
    msg = ms.pose_to_msg((1.0, 2.0, 0.3), 5, "map")
    data = bytearray(serialize_message(msg))
    data[16:20] = b"a\x00p\x00"  # frame "a\0p" in 4 bytes: a typed reader sees "a"
    assert deserialize_message(bytes(data), PoseStamped).header.frame_id == "a"
    assert w.read_pose(bytes(data)).frame == "a"


def test_a_path_of_two_poses_is_not_a_link_tick():
    two = ms.link_tick_to_msg(3, ms.pose_to_msg((1.0, 2.0, 0.3), 2, ms.WORLD_FRAME))
    two.poses = two.poses * 2
    with pytest.raises(ms.MalformedMessage):
        ms.msg_to_link_tick(two)
    with pytest.raises(ms.MalformedMessage):
        w.read_link_tick(serialize_message(two))


def test_as_bytes_serialises_message_objects_only():
    msg = ms.pose_to_msg((1.0, 2.0, 0.3), 5, "map")
    data = serialize_message(msg)
    assert w.as_bytes(msg) == data
    assert w.as_bytes(data) is data
    assert w.as_bytes(bytearray(data)) == data


# --------------------------------------------------------------------------- trajectories

def _trajectory(n: int, seed: int = 6) -> tuple[np.ndarray, list[int]]:
    rng = np.random.default_rng(seed)
    eta = np.column_stack([rng.uniform(-50, 50, n), rng.uniform(-50, 50, n),
                           np.cumsum(rng.uniform(-1, 1, n)) * 3])
    stamps = [int(s) for s in np.sort(rng.integers(0, 10**13, n))]
    return eta, stamps


@pytest.mark.parametrize("n", [0, 1, 2, 301])
def test_a_trajectory_packs_to_rclpys_bytes(n):
    eta, stamps = _trajectory(n)
    for frame in ("map", "", "a", "robot_10", "x" * 64):
        assert _same(w.path_bytes(eta, stamps, frame), ms.trajectory_to_path(eta, stamps, frame))
    with pytest.raises(ValueError):
        w.path_bytes(eta, stamps + [1], "map")


@pytest.mark.parametrize("n", [0, 1, 301])
def test_a_trajectory_reads_to_the_converters_values(n):
    eta, stamps = _trajectory(n)
    for frame in ("map", "robot_2"):
        msg = ms.trajectory_to_path(eta, stamps, frame)
        data = serialize_message(msg)
        for ref in (None, eta[:, 2] + 0.2):
            got = w.read_trajectory(data, ref)
            want = ms.path_to_trajectory(msg, ref)
            assert got[0].tobytes() == want[0].tobytes()
            assert got[1].tobytes() == want[1].tobytes() and got[2] == want[2] == frame
            assert ms.trajectory_from_raw(data, n, ref)[0].tobytes() == want[0].tobytes()
            assert ms.trajectory_from_raw(msg, n, ref)[0].tobytes() == want[0].tobytes()


@pytest.mark.parametrize("bad", ["nan_x", "inf_y", "inf_q", "tilted", "not_unit", "nanosec",
                                 "frame", "count", "cut", "huge_count"])
def test_a_trajectory_is_refused_where_the_converters_refuse_it(bad):
    eta, stamps = _trajectory(5)
    msg = ms.trajectory_to_path(eta, stamps, "map")
    ref = eta[:, 2]
    if bad == "count":
        ref = ref[:4]
    elif bad not in ("cut", "huge_count"):
        pose = _bad_pose(bad)
        pose.header.stamp = msg.poses[3].header.stamp if bad != "nanosec" else pose.header.stamp
        msg.poses[3] = pose
    data = serialize_message(msg)
    if bad == "cut":
        data = data[:-9]
    elif bad == "huge_count":
        data = data[:20] + struct.pack("<I", 2**32 - 1) + data[24:]
    if bad not in ("cut", "huge_count"):
        with pytest.raises(ms.MalformedMessage):
            ms.path_to_trajectory(msg, ref)
    with pytest.raises(ms.MalformedMessage):
        w.read_trajectory(data, ref)
    with pytest.raises(ms.MalformedMessage):
        ms.trajectory_from_raw(data, 5, ref)


def test_a_trajectory_longer_than_a_trial_is_refused_by_its_size():
    eta, stamps = _trajectory(40)
    data = w.path_bytes(eta, stamps, "map")
    with pytest.raises(ms.MalformedMessage, match="longer than"):
        ms.trajectory_from_raw(data, 10)
    assert len(ms.trajectory_from_raw(data, 40)[0]) == 40


def test_texts_and_reports_read_from_bytes_as_the_message_converters_read_them():
    """What the recordings read without rclpy (a String's JSON, a DiagnosticArray's
    statuses: ``wire.read_string``, ``wire.read_diagnostics``) is what the converters give
    for the message rclpy deserialises from the same bytes; bytes that do not decode, and
    counts that cannot fit in them, are malformed."""
    from diagnostic_msgs.msg import DiagnosticArray
    from std_msgs.msg import String

    from formation_ilc.protocol.health import node_report, read_statuses

    text = ms.json_to_msg({"node": "robot_2", "trial": 3, "x": [1.5, "é"]})
    data = serialize_message(text)
    assert w.read_string(data) == deserialize_message(data, String).data
    assert w.json_object(w.read_string(data), ("node", "trial")) == ms.msg_to_json(text)
    with pytest.raises(ms.MalformedMessage, match="lacks"):
        w.json_object(w.read_string(data), ("seq",))
    report = {"node": "robot_sim", "trial": 4, "missed": {"robot_2": 3}, "timing": {"p50_ms": 1.5},
              "dropped": {"stale": 2}}
    diag = serialize_message(ms.diagnostics_to_msg(report, 12_000_000_001, 0.2, 140))
    want = ms.msg_to_statuses(deserialize_message(diag, DiagnosticArray))
    got = read_statuses(w.read_diagnostics(diag))
    assert len(got) > 1 and got == want
    assert node_report(got, ("node", "trial")) == ms.msg_to_report(
        deserialize_message(diag, DiagnosticArray), ("node", "trial"))
    for cut in (0, 3, 12, 20, len(diag) // 2, len(diag) - 1):
        with pytest.raises(ms.MalformedMessage):
            w.read_diagnostics(diag[:cut])
    huge = diag[:20] + struct.pack("<I", 10**9) + diag[24:]  # the count of statuses
    with pytest.raises(ms.MalformedMessage, match="cut short"):
        w.read_diagnostics(huge)
    with pytest.raises(ms.MalformedMessage):
        w.read_string(data[:6])


def test_a_told_command_is_a_twist_stamped_both_ways():
    """``robot_i/applied``: the command a robot applied over a sample, stamped with the
    sample's label; our bytes decode as rclpy's TwistStamped and rclpy's as ours."""
    from geometry_msgs.msg import TwistStamped

    for eta, ns in _poses(100):
        u = (eta[0] / 60.0, eta[2] / 30.0)
        for frame in ("robot_3/base_link", "r", ""):
            ours = w.applied_bytes(u, ns, frame)
            msg = TwistStamped()
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 10**9)
            msg.header.frame_id = frame
            msg.twist.linear.x, msg.twist.angular.z = u
            assert _same(ours, msg)
            assert w.read_applied(serialize_message(msg)) == (ns, u[0], u[1])
    bad = TwistStamped()
    bad.twist.linear.y = 0.1  # not a planar command
    with pytest.raises(ms.MalformedMessage):
        w.read_applied(serialize_message(bad))
    with pytest.raises(ms.MalformedMessage):
        w.read_applied(w.applied_bytes((0.1, 0.0), 5, "robot_1/base_link")[:30])  # cut short


def test_a_tf_message_of_bytes_is_rclpys_tfmessage():
    """``tf_bytes`` (issue 54) decodes, with the built tf2_msgs' type support, to the
    TFMessage of the same transforms, whatever the frame names' lengths (alignment)."""
    from tf2_msgs.msg import TFMessage

    from formation_ilc.protocol.wire import Frame, tf_bytes

    frames = [Frame("map", "robot_1/odom", 1.0, -2.0, 0.3),
              Frame("robot_1/odom", "robot_12/base_link", -1.5, 2.5, -3.0),
              Frame("map", "leader", 0.0, 0.0, math.pi / 2)]
    for k in range(len(frames) + 1):
        data = tf_bytes(1_234_567_891_011, frames[:k])
        m = deserialize_message(data, TFMessage)
        assert len(serialize_message(m)) == len(data)
        assert len(m.transforms) == k
        for tr, f in zip(m.transforms, frames[:k], strict=True):
            assert (tr.header.stamp.sec, tr.header.stamp.nanosec) == (1234, 567_891_011)
            assert (tr.header.frame_id, tr.child_frame_id) == (f.parent, f.child)
            t, q = tr.transform.translation, tr.transform.rotation
            assert (t.x, t.y, t.z) == (f.x, f.y, 0.0)
            assert (q.x, q.y) == (0.0, 0.0)
            assert 2 * math.atan2(q.z, q.w) == pytest.approx(f.theta)
