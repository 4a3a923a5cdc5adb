"""A formation run by ``ros2 launch`` (ROS 2 Jazzy with this package installed, see
docs/ros-tools.md):

    ros2 launch formation_ilc formation.launch.py scenario:=paper-hexagon6 trials:=10
    ros2 launch formation_ilc formation.launch.py namespace:=/team2 record:=run.mcap live:=8765

It starts the processes ``formation-ilc launch`` starts for the same options (its defaults
too: 20 trials), each node under its own name, with the same arguments and parameters
(``formation_ilc.cli.roslaunch.ros_launch_processes``): the virtual leader, the plant, the
link emulator, the robots, and a recorder and the live view when asked. One robot on its own
computer: ``robot.launch.py``. The leader ends its process after the last trial, and the
launch stops every node with it. The launcher's own monitor (metrics.csv, the error
table, restarts) is not part of a launch file's run: ``formation-ilc analyze RUN.mcap``
gives the metrics of a recording.

Launch arguments (``ros2 launch formation_ilc formation.launch.py --show-args``):
scenario, trials, namespace, robots_per_process, plant, mode, links, record, live,
params_file, out, run_file (a run file of ``formation-ilc run-file``: the others override
its keys).
"""

from launch.actions import DeclareLaunchArgument, OpaqueFunction, Shutdown
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription

PACKAGE = "formation_ilc"

#: (name, default, description): every option has the launcher's meaning
ARGUMENTS = (
    ("scenario", "paper-triangle3", "a built-in scenario or a scenario YAML file"),
    ("trials", "20", "number of trials (formation-ilc launch's default); 0 keeps the "
                     "scenario's"),
    ("namespace", "/formation", "the formation's ROS namespace (/clock is moved with it)"),
    ("robots_per_process", "0", "robot nodes per process (0: one process per robot)"),
    ("plant", "sim", "sim, physics, external, pioneer or base (formation-ilc launch --help)"),
    ("mode", "", "lockstep, realtime or wallclock; empty: the plant's default"),
    ("links", "", "emulated or direct; empty: the plant's default"),
    ("record", "", "an MCAP file to record the run to; empty: no recording"),
    ("live", "", "a port for the Foxglove live view (the 'live' extra); empty: none"),
    ("params_file", "", "a --params-file given to every node before its own parameters "
                        "(which win); empty: none"),
    ("out", "formation_ilc_run", "folder of the nodes' state files (a restarted node goes "
                                 "on from them)"),
    ("run_file", "", "a run file (formation-ilc run-file): every option of the run; the "
                     "arguments above given with it override its keys; empty: none"),
)


def launcher_argv(get) -> list[str]:
    """The ``formation-ilc launch`` options of the launch arguments (``get(name)``); with a
    run file, the arguments given (other than their defaults) override its keys."""
    if get("run_file"):
        defaults = {name: default for name, default, _ in ARGUMENTS}
        argv = [get("run_file")]
        for option, name in (("--scenario", "scenario"), ("--namespace", "namespace"),
                             ("--plant", "plant"), ("--out", "out"), ("--trials", "trials"),
                             ("--container", "robots_per_process"), ("--mode", "mode"),
                             ("--links", "links"), ("--record", "record"), ("--live", "live")):
            if get(name) != defaults[name]:
                if name == "scenario":
                    raise ValueError("scenario:= and run_file:= both name the scenario: "
                                     "give one")
                argv += [option, get(name)]
        return argv
    argv = [get("scenario"), "--namespace", get("namespace"), "--plant", get("plant"),
            "--out", get("out")]
    for option, name in (("--trials", "trials"), ("--container", "robots_per_process")):
        if get(name) not in ("", "0"):
            argv += [option, get(name)]
    for option, name in (("--mode", "mode"), ("--links", "links"), ("--record", "record"),
                         ("--live", "live")):
        if get(name):
            argv += [option, get(name)]
    return argv


def _nodes(context, *args, **kwargs):
    from formation_ilc.cli.roslaunch import ros_launch_processes

    def get(name):
        return LaunchConfiguration(name).perform(context)

    extra = ["--params-file", get("params_file")] if get("params_file") else []
    nodes = []
    for p in ros_launch_processes(launcher_argv(get)):
        # each node under its own name (robot_1, virtual_leader, ...), as the launch prints
        # it; a container of several robot nodes keeps theirs
        named = {"name": p["node_name"]} if p["node_name"] else {}
        nodes.append(Node(package=PACKAGE, executable=p["executable"], **named,
                          arguments=p["arguments"], ros_arguments=extra + p["ros_arguments"],
                          output="screen",
                          # the leader ends after the last trial: the whole launch ends
                          on_exit=[Shutdown(reason="the run is done")] if p["ends_launch"]
                          else None))
    return nodes


def generate_launch_description():
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=text)
         for name, default, text in ARGUMENTS] + [OpaqueFunction(function=_nodes)])
