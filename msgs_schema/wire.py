"""The per-sample messages as CDR bytes (``formation_ilc.protocol.wire``, which needs no
ROS), and ``as_bytes``: a message object a test hands a node's handler, serialised by
rclpy."""

from __future__ import annotations

from typing import Any

from formation_ilc.protocol.wire import *  # noqa: F403
from formation_ilc.protocol.wire import __all__ as _pure

__all__ = [*_pure, "as_bytes"]


def as_bytes(msg: Any) -> bytes:
    """The CDR bytes of a message: ``msg`` itself when it is bytes (a raw subscription),
    else a message object serialised by rclpy."""
    if isinstance(msg, bytes):
        return msg
    if isinstance(msg, (bytearray, memoryview)):
        return bytes(msg)
    from rclpy.serialization import serialize_message

    return serialize_message(msg)
