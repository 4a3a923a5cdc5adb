"""Each kind of topic (``names.topic_kind``: ``robot_i/pose`` is a 'pose') with its message
type, the QoS its writers offer and the QoS its readers ask: what a node that makes its
publishers and subscriptions from its roster member's topics (``nodes.robot``) takes
them from. The kinds a robot node publishes or reads; the table in this package's
docstring says who else does."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, Twist, TwistStamped
from nav_msgs.msg import Path
from rclpy.qos import QoSProfile
from sensor_msgs.msg import TimeReference
from std_msgs.msg import Bool, String

from formation_ilc.core.names import (
    CONFIG,
    DIAGNOSTICS,
    ESTOP,
    LINKS,
    READY,
    REFERENCE,
    ROS_DIAGNOSTICS,
    TEAM_POSES,
    TRIAL_EVENTS,
)
from msgs_schema.clocksync import CLOCK_SYNC_QOS
from msgs_schema.qos import (
    LATCHED_QOS,
    LATCHED_READER_QOS,
    ROS_DIAGNOSTICS_QOS,
    SAMPLE_QOS,
    TRAJECTORY_QOS,
    TRAJECTORY_READER_QOS,
)

__all__ = ["Kind", "KINDS", "kind_of"]


@dataclass(frozen=True)
class Kind:
    """A kind of topic: its message ``type``, the QoS its writers offer (``offered``) and
    the QoS its readers ask (``read``: deeper where one reader's history is shared by many
    writers of a latched topic)."""

    type: Any
    offered: QoSProfile
    read: QoSProfile


def _same(t: Any, qos: QoSProfile) -> Kind:
    return Kind(t, qos, qos)


#: kind (``names.topic_kind``) -> its type and QoS
KINDS: dict[str, Kind] = {
    CONFIG: _same(String, LATCHED_QOS),
    TRIAL_EVENTS: _same(String, SAMPLE_QOS),
    READY: Kind(String, LATCHED_QOS, LATCHED_READER_QOS),
    DIAGNOSTICS: Kind(DiagnosticArray, LATCHED_QOS, LATCHED_READER_QOS),
    ROS_DIAGNOSTICS: _same(DiagnosticArray, ROS_DIAGNOSTICS_QOS),
    ESTOP: Kind(Bool, LATCHED_QOS, LATCHED_READER_QOS),
    REFERENCE: _same(PoseStamped, SAMPLE_QOS),
    TEAM_POSES: _same(Path, SAMPLE_QOS),
    "pose": _same(PoseStamped, SAMPLE_QOS),
    "cmd_vel": _same(Twist, SAMPLE_QOS),
    "shared_pose": _same(PoseStamped, SAMPLE_QOS),
    # a tick holds 0 or 1 pose
    LINKS: _same(Path, SAMPLE_QOS),
    "applied": _same(TwistStamped, SAMPLE_QOS),
    "trajectory": Kind(Path, TRAJECTORY_QOS, TRAJECTORY_READER_QOS),
    "clock/ping": _same(TimeReference, CLOCK_SYNC_QOS),
    "clock/pong": _same(TimeReference, CLOCK_SYNC_QOS),
}


def kind_of(kind: str) -> Kind:
    """The type and QoS of ``kind`` (ValueError naming the kinds there are)."""
    try:
        return KINDS[kind]
    except KeyError:
        raise ValueError(f"no topic kind {kind!r} in msgs_schema.kinds "
                         f"({', '.join(sorted(KINDS))})") from None
