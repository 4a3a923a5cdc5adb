"""Every recorded topic and every view topic with its ROS type and offered QoS: the names
are ``formation_ilc.core.names``' (``recorded_topics``, ``view_topics``), the types and
profiles this package's. The recorder subscribes to exactly ``topic_table``; the batch
simulator records on it too (``formation-ilc simulate --record``)."""

from __future__ import annotations

from rclpy.qos import QoSProfile

from formation_ilc.core.names import (
    CLOCK,
    CONFIG,
    DIAGNOSTICS,
    ESTOP,
    MARKERS,
    READY,
    REFERENCE,
    TF,
    TF_STATIC,
    TRIAL_EVENTS,
    recorded_topics,
    topic_kind,
    view_topics,
)
from msgs_schema.diagnostics import DIAGNOSTICS_TYPE
from msgs_schema.qos import (
    CLOCK_QOS,
    LATCHED_QOS,
    SAMPLE_QOS,
    TF_QOS,
    TF_STATIC_QOS,
    TRAJECTORY_QOS,
    VIEW_QOS,
)

__all__ = ["topic_table", "view_topic_table", "recorder_table", "TF_TYPE", "tf_message"]

_STRING = "std_msgs/msg/String"
_POSE = "geometry_msgs/msg/PoseStamped"
_PATH = "nav_msgs/msg/Path"
_VECTOR = "geometry_msgs/msg/Vector3Stamped"
#: tf2's message: not on PyPI, built into the venv by scripts/build_tf2_msgs.py
TF_TYPE = "tf2_msgs/msg/TFMessage"

#: type and offered QoS of each kind of topic (``names.topic_kind``: robot i's by the part
#: after ``robot_i/``)
_TYPES: dict[str, tuple[str, QoSProfile]] = {
    CONFIG: (_STRING, LATCHED_QOS),
    REFERENCE: (_POSE, SAMPLE_QOS),
    TRIAL_EVENTS: (_STRING, SAMPLE_QOS),
    READY: (_STRING, LATCHED_QOS),
    DIAGNOSTICS: (DIAGNOSTICS_TYPE, LATCHED_QOS),
    CLOCK: ("rosgraph_msgs/msg/Clock", CLOCK_QOS),
    ESTOP: ("std_msgs/msg/Bool", LATCHED_QOS),
    TF: (TF_TYPE, TF_QOS),
    TF_STATIC: (TF_TYPE, TF_STATIC_QOS),
    "pose": (_POSE, SAMPLE_QOS),
    "cmd_vel": ("geometry_msgs/msg/Twist", SAMPLE_QOS),
    "trajectory": (_PATH, TRAJECTORY_QOS),
    "true_trajectory": (_PATH, TRAJECTORY_QOS),
    "robot_description": (_STRING, LATCHED_QOS),
    MARKERS: ("visualization_msgs/msg/MarkerArray", VIEW_QOS),
    "desired_pose": (_POSE, VIEW_QOS),
    "desired_path": (_PATH, TRAJECTORY_QOS),
    "tracking_error": (_VECTOR, VIEW_QOS),
    "trial_error": (_VECTOR, TRAJECTORY_QOS),
}


def _row(topic: str) -> tuple[str, str, QoSProfile]:
    return (topic, *_TYPES[topic_kind(topic)[0]])


def topic_table(n: int) -> list[tuple[str, str, QoSProfile]]:
    """Every recorded topic of a run of ``n`` robots: (relative name, ROS type, offered QoS),
    in the order of ``names.recorded_topics`` (which says what is left out, and why)."""
    return [_row(t) for t in recorded_topics(n)]


def view_topic_table(n: int) -> list[tuple[str, str, QoSProfile]]:
    """The observer's topics for ``n`` robots: (relative name, ROS type, offered QoS)."""
    return [_row(t) for t in view_topics(n)]


def recorder_table(n: int) -> list[tuple[str, str, QoSProfile]]:
    """Every topic a recording of ``n`` robots holds: the recorded topics and the view
    topics the recorder's observer adds (``recordings.recording.SimRecorder``'s table)."""
    return topic_table(n) + view_topic_table(n)


def tf_message() -> type | None:
    """tf2_msgs/msg/TFMessage, or None where tf2_msgs is not installed (it is not on PyPI:
    ``scripts/build_tf2_msgs.py`` builds it into the venv); a node then has no frames."""
    try:
        from tf2_msgs.msg import TFMessage  # type: ignore[import-not-found]
    except ImportError:
        return None
    return TFMessage
