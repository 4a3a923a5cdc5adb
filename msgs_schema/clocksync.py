"""The clock exchanges on the wire (``formation_ilc.protocol.timesync``): questions and
answers as sensor_msgs/TimeReference, the standard message for "another clock's time at
this stamp".

Each node publishes on topics of its own name only. A's question for B's clock, on
``A/clock/ping`` (``clock_ping_topic``): ``header.stamp`` = t1 (A's clock when it sent it),
``header.frame_id`` = the question's number, ``source`` = B (the clock asked). B's answer,
on ``B/clock/pong`` (``clock_pong_topic``): ``header.stamp`` = t3 (B's clock when it
answered), ``time_ref`` = t2 (B's clock when the question arrived), ``header.frame_id`` =
the question's number, ``source`` = A (who asked). A node reads the questions of those
allowed to ask it and the answers of the clocks it asks, and takes those naming it.

Best effort: a lost question or answer is an exchange less; a repaired one would carry a
round trip as long as the repair, which the estimate would only throw away.
"""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import TimeReference

from formation_ilc.core.clock import Malformed
from formation_ilc.protocol.wire import read_time_reference
from msgs_schema.convert import ns_to_stamp, stamp_to_ns

__all__ = ["CLOCK_SYNC_QOS", "ping_msg", "read_ping", "pong_msg", "read_pong",
           "TIME_REFERENCE_TYPE"]

TIME_REFERENCE_TYPE = "sensor_msgs/msg/TimeReference"
CLOCK_SYNC_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=16,
                            reliability=ReliabilityPolicy.BEST_EFFORT,
                            durability=DurabilityPolicy.VOLATILE)
#: the longest node name a question or answer may carry
NAME_MAX = 100


def ping_msg(seq: int, t1: int, asked: str) -> TimeReference:
    """A question for ``asked``'s clock, sent at t1."""
    msg = TimeReference(source=asked)
    msg.header.frame_id = str(int(seq))
    ns_to_stamp(t1, msg.header.stamp)
    ns_to_stamp(t1, msg.time_ref)
    return msg


def pong_msg(seq: int, t2: int, t3: int, asker: str) -> TimeReference:
    """The answer to ``asker``'s question ``seq``, taken at t2, answered at t3."""
    msg = TimeReference(source=asker)
    msg.header.frame_id = str(int(seq))
    ns_to_stamp(t3, msg.header.stamp)
    ns_to_stamp(t2, msg.time_ref)
    return msg


def _fields(msg: TimeReference | bytes) -> tuple[int, str, int, str]:
    """(header.stamp [ns], header.frame_id, time_ref [ns], source) of a message object or
    of its bytes (a raw subscription: ``formation_ilc.protocol.wire.read_time_reference``)."""
    if isinstance(msg, (bytes, bytearray, memoryview)):
        return read_time_reference(bytes(msg))
    return (stamp_to_ns(msg.header.stamp), msg.header.frame_id, stamp_to_ns(msg.time_ref),
            msg.source)


def _seq(text: str) -> int:
    if not (0 < len(text) <= 19 and text.isascii() and text.isdigit()):
        raise Malformed(f"clock exchange number {text[:30]!r}")
    return int(text)


def _name(source: str) -> str:
    if not (0 < len(source) <= NAME_MAX and source.isascii()):
        raise Malformed(f"clock exchange from {source[:30]!r}")
    return str(source)


def read_ping(msg: TimeReference | bytes) -> tuple[str, int, int]:
    """(the clock asked, seq, t1) of a question (a message object or its bytes);
    MalformedMessage if it is not a question."""
    stamp, frame, _, source = _fields(msg)
    return _name(source), _seq(frame), stamp


def read_pong(msg: TimeReference | bytes) -> tuple[str, int, int, int]:
    """(who asked, seq, t2, t3) of an answer (a message object or its bytes);
    MalformedMessage if it is not an answer."""
    stamp, frame, time_ref, source = _fields(msg)
    return _name(source), _seq(frame), time_ref, stamp
