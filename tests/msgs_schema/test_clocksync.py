"""The clock exchanges' questions and answers (sensor_msgs/TimeReference) read the same from
a message object and from its bytes (the nodes' raw subscriptions), and refuse the same."""

from __future__ import annotations

import pytest
from rclpy.serialization import serialize_message

import msgs_schema as ms


def _both(msg):
    return msg, serialize_message(msg)


def test_a_question_and_an_answer_read_the_same_from_bytes():
    ping = ms.ping_msg(41, 1_795_000_000_123_456_789, "robot_3")
    for m in _both(ping):
        assert ms.read_ping(m) == ("robot_3", 41, 1_795_000_000_123_456_789)
    pong = ms.pong_msg(7, 5_000_000_001, 5_000_300_002, "leader")
    for m in _both(pong):
        assert ms.read_pong(m) == ("leader", 7, 5_000_000_001, 5_000_300_002)


@pytest.mark.parametrize("field, value, match", [
    ("frame", "", "number"), ("frame", "12a", "number"), ("frame", "9" * 20, "number"),
    ("source", "", "from"), ("source", "r\u00f6bot", "from"), ("source", "x" * 101, "from"),
    ("nanosec", 10**9, "nanosec"),
])
def test_what_is_no_answer_is_refused_from_bytes_as_from_the_object(field, value, match):
    msg = ms.pong_msg(7, 5_000_000_001, 5_000_300_002, "leader")
    if field == "frame":
        msg.header.frame_id = value
    elif field == "source":
        msg.source = value
    else:
        msg.time_ref.nanosec = value
    for m in _both(msg):
        with pytest.raises(ms.MalformedMessage, match=match):
            ms.read_pong(m)
        with pytest.raises(ms.MalformedMessage, match=match):
            ms.read_ping(m)


def test_bytes_that_are_no_time_reference_are_malformed():
    data = serialize_message(ms.pong_msg(7, 1, 2, "leader"))
    for bad in (data[:-3], b"\x00\x01", b"\x07\x07\x00\x00" + data[4:]):
        with pytest.raises(ms.MalformedMessage):
            ms.read_pong(bad)
