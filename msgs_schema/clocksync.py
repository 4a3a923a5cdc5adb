"""The clock exchanges on the wire (``formation_ilc.protocol.timesync``): questions and
answers as sensor_msgs/TimeReference, the standard message for "another clock's time at
this stamp".

A question for node X's clock, on ``X/clock/ping`` (``clock_ping_topic``):
``header.stamp`` = t1 (the asker's clock when it sent it), ``header.frame_id`` = the
question's number, ``source`` = the asker's node name. The answer, on the asker's
``clock/pong`` (``clock_pong_topic``): ``header.stamp`` = t3 (the answerer's clock when it
answered), ``time_ref`` = t2 (the answerer's clock when the question arrived),
``header.frame_id`` = the question's number, ``source`` = the answerer's name.

Best effort: a lost question or answer is an exchange less; a repaired one would carry a
round trip as long as the repair, which the estimate would only throw away.
"""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import TimeReference

from formation_ilc.core.clock import Malformed
from msgs_schema.convert import ns_to_stamp, stamp_to_ns

__all__ = ["CLOCK_SYNC_QOS", "ping_msg", "read_ping", "pong_msg", "read_pong",
           "TIME_REFERENCE_TYPE"]

TIME_REFERENCE_TYPE = "sensor_msgs/msg/TimeReference"
CLOCK_SYNC_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=16,
                            reliability=ReliabilityPolicy.BEST_EFFORT,
                            durability=DurabilityPolicy.VOLATILE)
#: the longest node name a question or answer may carry
NAME_MAX = 100


def ping_msg(seq: int, t1: int, asker: str) -> TimeReference:
    msg = TimeReference(source=asker)
    msg.header.frame_id = str(int(seq))
    ns_to_stamp(t1, msg.header.stamp)
    ns_to_stamp(t1, msg.time_ref)
    return msg


def pong_msg(seq: int, t2: int, t3: int, answerer: str) -> TimeReference:
    msg = TimeReference(source=answerer)
    msg.header.frame_id = str(int(seq))
    ns_to_stamp(t3, msg.header.stamp)
    ns_to_stamp(t2, msg.time_ref)
    return msg


def _seq(msg: TimeReference) -> int:
    text = msg.header.frame_id
    if not (0 < len(text) <= 19 and text.isascii() and text.isdigit()):
        raise Malformed(f"clock exchange number {text[:30]!r}")
    return int(text)


def _name(msg: TimeReference) -> str:
    if not (0 < len(msg.source) <= NAME_MAX and msg.source.isascii()):
        raise Malformed(f"clock exchange from {msg.source[:30]!r}")
    return str(msg.source)


def read_ping(msg: TimeReference) -> tuple[str, int, int]:
    """(asker, seq, t1); MalformedMessage if it is not a question."""
    return _name(msg), _seq(msg), stamp_to_ns(msg.header.stamp)


def read_pong(msg: TimeReference) -> tuple[str, int, int, int]:
    """(answerer, seq, t2, t3); MalformedMessage if it is not an answer."""
    return _name(msg), _seq(msg), stamp_to_ns(msg.time_ref), stamp_to_ns(msg.header.stamp)
