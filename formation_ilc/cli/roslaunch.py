"""The processes of a ROS launch file (``launch/formation.launch.py``): a launch's plan,
from its arguments as ``formation-ilc launch`` options."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from formation_ilc.cli.launchargs import launch_parser
from formation_ilc.cli.runfile import launch_options, plan_of
from formation_ilc.config.roster import roster
from formation_ilc.config.runconfig import param_text, scenario_reference
from formation_ilc.core.names import LEADER_NODE
from formation_ilc.plan.processes import node_specs, ros2_executable

__all__ = ["ros_launch_processes"]


def ros_launch_processes(argv: list[str]) -> list[dict[str, Any]]:
    """The processes ``formation-ilc launch ARGV`` starts, as a ROS launch file starts them
    (``launch/formation.launch.py``): the same processes with the same arguments, ROS
    arguments and parameters, but no monitor (the launcher's own node: nobody waits for
    it), and the leader ends its process after the last trial (``exit_when_done``), which
    ends the launch. Each entry: name, node_name (the node's name when the process is one
    node of the roster, for ``Node(name=...)``; None for a container of robots or a node
    outside the roster), executable (``ros2 run formation_ilc``), arguments, ros_arguments
    (remaps, params files, ``-p`` parameters), and whether the launch ends with it. NoRun
    for options the launcher refuses."""
    args = launch_parser().parse_args(argv)
    opts = launch_options(args)
    plan = plan_of(args)
    lineup = replace(plan.roster.lineup, monitor=False)
    plan = replace(plan, config=replace(plan.config, monitored=False),
                   roster=roster(lineup))
    members = {m.name for m in plan.roster.members}
    out = []
    for spec in node_specs(plan, scenario_reference(opts.scenario or "")):
        params = dict(spec.params)
        if spec.name == LEADER_NODE:
            params["exit_when_done"] = True
        ros = [*spec.remaps]
        for k, v in params.items():
            ros += ["-p", f"{k}:={param_text(v)}"]
        single = spec.name in members and "--robots" not in spec.args
        out.append({"name": spec.name, "node_name": spec.name if single else None,
                    "executable": ros2_executable(spec.module),
                    "arguments": list(spec.args), "ros_arguments": ros,
                    "ends_launch": spec.name == LEADER_NODE})
    return out
