"""One robot on its own computer (ROS 2 Jazzy with this package installed, see
docs/real-robots.md): its robot node and its bridge to the base's driver, as TurtleBot and
Clearpath users launch per robot. The driver itself is the base's own launch (RosAria,
turtlebot4_bringup, ...); the leader and the other robots run on their own machines.

    ros2 launch formation_ilc robot.launch.py robot_id:=2 driver:=rosaria
    ros2 launch formation_ilc robot.launch.py robot_id:=1 base:=turtlebot4 lifecycle:=true

Launch arguments (``--show-args``): robot_id, namespace, driver, base, driver_ns,
lifecycle, init_memory, params_file.
"""

from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription

PACKAGE = "formation_ilc"

#: (name, default, description): the nodes' parameters of the same names
ARGUMENTS = (
    ("robot_id", "1", "this robot's number (its nodes: robot_<id>, bridge_<id>)"),
    ("namespace", "/formation", "the formation's ROS namespace (the leader's)"),
    ("driver", "rosaria", "the driver: rosaria, p2os2 or ros2aria (ignored with base)"),
    ("base", "", "a base preset (turtlebot3, turtlebot4, jackal, husky, ...; "
                 "docs/real-robots.md); empty: a Pioneer driver"),
    ("driver_ns", "", "the driver's namespace; empty: the driver's or preset's usual"),
    ("lifecycle", "false", "the bridge is a managed node, brought up by a lifecycle "
                           "manager (ros2 lifecycle set /formation/bridge_<id> configure)"),
    ("init_memory", "", "a memory.npz the robot starts from (formation-ilc simulate's); "
                        "empty: none"),
    ("params_file", "", "a --params-file given to both nodes before their own parameters "
                        "(which win); empty: none"),
)


def _nodes(context, *args, **kwargs):
    def get(name):
        return LaunchConfiguration(name).perform(context)

    i = int(get("robot_id"))
    extra = ["--params-file", get("params_file")] if get("params_file") else []
    ns = get("namespace")
    robot = {"robot_id": i}
    if get("init_memory"):
        robot["init_memory"] = get("init_memory")
    bridge = {"robot_id": i, "lifecycle": get("lifecycle").lower() in ("true", "1", "yes")}
    if get("base"):
        bridge["base"] = get("base")
    else:
        bridge["driver"] = get("driver")
    if get("driver_ns"):
        bridge["driver_ns"] = get("driver_ns")
    def ros(params):  # after the params file: a node's own parameters win
        out = list(extra)
        for k, v in params.items():
            out += ["-p", f"{k}:={str(v).lower() if isinstance(v, bool) else v}"]
        return out

    return [
        Node(package=PACKAGE, executable="robot", name=f"robot_{i}", namespace=ns,
             ros_arguments=ros(robot), output="screen"),
        Node(package=PACKAGE, executable="bridge", name=f"bridge_{i}", namespace=ns,
             ros_arguments=ros(bridge), output="screen"),
    ]


def generate_launch_description():
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=text)
         for name, default, text in ARGUMENTS] + [OpaqueFunction(function=_nodes)])
