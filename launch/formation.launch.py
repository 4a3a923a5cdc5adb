"""A formation of paper-triangle3 in lockstep, started by ``ros2 launch`` (a full ROS 2
Jazzy install with this package built in its workspace):

    ros2 launch formation_ilc formation.launch.py

Every node takes its parameters from the example files in share/formation_ilc/params
(--params-file, as a launch file passes them) and is named the way those files are keyed.
``formation-ilc launch`` does more (a run folder, metrics, restarts, a recording); this file
is for fitting the nodes into a ROS system of one's own.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch_ros.actions import Node

from launch import LaunchDescription

NAMESPACE = "formation"
ROBOTS = (1, 2, 3)


def generate_launch_description():
    params = os.path.join(get_package_share_directory("formation_ilc"), "params")
    nodes = [
        Node(package="formation_ilc", executable="virtual_leader", name="virtual_leader",
             namespace=NAMESPACE,
             parameters=[os.path.join(params, "virtual_leader.yaml")]),
        Node(package="formation_ilc", executable="robot_sim", name="robot_sim",
             namespace=NAMESPACE, parameters=[os.path.join(params, "robot_sim.yaml")]),
        Node(package="formation_ilc", executable="link_emulator", name="link_emulator",
             namespace=NAMESPACE),
    ]
    for i in ROBOTS:
        # the node's name follows robot_id (give both); without a scenario of its own a
        # robot takes the run configuration from the leader's config topic
        nodes.append(Node(package="formation_ilc", executable="robot", name=f"robot_{i}",
                          namespace=NAMESPACE, parameters=[{"robot_id": i}]))
    return LaunchDescription(nodes)
