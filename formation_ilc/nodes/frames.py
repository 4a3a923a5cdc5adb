"""A node's frames on tf2's topics: ``/tf`` and ``/tf_static`` (tf2_msgs/msg/TFMessage).

The stack's frames make one tree (REP-105): ``map`` at its root, per robot
``robot_i/odom`` under it and ``robot_i/base_link`` under that, and the virtual leader's
``leader`` under ``map``. Who publishes what:

* a simulator (the kinematic simulator, the physics plant): ``map -> robot_i/odom``, the
  identity, on ``/tf_static`` (its measured pose is a measurement in ``map``, as a
  motion-capture system's), and at each sample ``robot_i/odom -> robot_i/base_link``, the
  pose it measured, on ``/tf``, stamped with the sample's label;
* robot i's bridge: ``map -> robot_i/odom``, where the robot was placed (its
  ``initial_pose``), on ``/tf_static``, and ``robot_i/odom -> robot_i/base_link``, the
  driver's odometry, on ``/tf`` at most ``BRIDGE_TF_HZ`` a second, stamped with the team's
  time (as its poses); a bridge given the robot's world pose (``pose_topic``: motion
  capture, the physics bases' truth) publishes ``map -> robot_i/odom`` on ``/tf`` with the
  odometry instead, where the two put the odometry's origin (it moves as the odometry
  drifts, as a localiser's ``map -> odom`` does);
* the leader: ``map -> leader``, the reference r(t), with each reference sample.

The plant that drives a robot also publishes its body, a URDF whose one link is
``robot_i/base_link`` (``config.urdf``), on ``robot_i/robot_description`` (latched
std_msgs/String), as robot_state_publisher does: the simulators every robot's (the
safety filter's body, else a Pioneer 3-DX; the physics plant its model's), each bridge
its own (its base preset's, else a Pioneer 3-DX).

Messages go as CDR bytes (``protocol.wire.tf_bytes``), as the per-sample messages do. Where
tf2_msgs is not installed (it is not on PyPI: ``scripts/build_tf2_msgs.py`` builds it) a
node has no frames and says so once.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from rclpy.node import Node
from std_msgs.msg import String

import msgs_schema as ms
from formation_ilc.config.urdf import robot_description
from formation_ilc.protocol.wire import Frame, tf_bytes

__all__ = ["Frames", "Frame", "BRIDGE_TF_HZ", "describe_body"]

#: [1/s] how often a bridge publishes its robot's odometry frame at most
BRIDGE_TF_HZ = 20.0


class Frames:
    """``node``'s writers of ``/tf`` (``dynamic``) and ``/tf_static`` (``static``: its
    frames published once, latched)."""

    def __init__(self, node: Node, static: Sequence[Frame] = (), dynamic: bool = True):
        self.type: Any = ms.tf_message()
        self.tf: Any = None
        self.static: Any = None
        if self.type is None:
            node.get_logger().warning(
                "no frames on /tf: the tf2_msgs package is not installed (it is not on "
                "PyPI; scripts/build_tf2_msgs.py builds it into the venv)")
            return
        if dynamic:
            self.tf = node.create_publisher(self.type, ms.TF, ms.TF_QOS)
        if static:
            self.static = node.create_publisher(self.type, ms.TF_STATIC, ms.TF_STATIC_QOS)
            self.static.publish(tf_bytes(0, list(static)))

    def publish(self, stamp_ns: int, frames: Sequence[Frame]) -> None:
        """``frames`` on ``/tf``, stamped ``stamp_ns``."""
        if self.tf is not None:
            self.tf.publish(tf_bytes(stamp_ns, frames))


def describe_body(node: Node, i: int, base: str) -> Any:
    """Publish robot ``i``'s URDF (``base``'s body, its link ``robot_i/base_link``) on
    ``robot_i/robot_description``, latched; the publisher."""
    pub = node.create_publisher(String, ms.robot_description_topic(i), ms.LATCHED_QOS)
    pub.publish(String(data=robot_description(base, f"{ms.robot_name(i)}/")))
    return pub
