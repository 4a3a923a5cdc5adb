"""launch/formation.launch.py: the file parses, declares its launch arguments, and its
descriptions give the processes of ``formation-ilc launch`` for the same arguments. ROS's
``launch`` and ``launch_ros`` are not on PyPI: stand-ins record what the file asks of them
(the names and keywords of launch_ros.actions.Node and launch's actions, as in Jazzy)."""

from __future__ import annotations

import ast
import importlib.util
import sys
import types
from pathlib import Path

import pytest

from formation_ilc.cli.commands import build_parser
from formation_ilc.cli.runfile import plan_of
from formation_ilc.config.runconfig import param_text
from formation_ilc.plan.processes import ROS2_RUN, entry_module, ros2_executable

FILE = Path(__file__).resolve().parents[2] / "launch" / "formation.launch.py"
SHIMS = Path(__file__).resolve().parents[2] / "ros2_run"


class Recorded:
    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


class Configuration:
    def __init__(self, name):
        self.name = name

    def perform(self, context):
        return context[self.name]


@pytest.fixture
def launch_file(monkeypatch):
    return _load(monkeypatch, FILE)


def _load(monkeypatch, file):
    mods = {name: types.ModuleType(name) for name in
            ("launch", "launch.actions", "launch.substitutions", "launch_ros",
             "launch_ros.actions")}
    mods["launch"].LaunchDescription = Recorded
    for name in ("DeclareLaunchArgument", "OpaqueFunction", "Shutdown"):
        setattr(mods["launch.actions"], name, type(name, (Recorded,), {}))
    mods["launch.substitutions"].LaunchConfiguration = Configuration
    mods["launch_ros.actions"].Node = type("Node", (Recorded,), {})
    for name, mod in mods.items():
        monkeypatch.setitem(sys.modules, name, mod)
    spec = importlib.util.spec_from_file_location(file.stem.replace(".", "_"), file)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_file_parses_and_declares_its_arguments(launch_file):
    ast.parse(FILE.read_text())
    ld = launch_file.generate_launch_description()
    declared = {a.args[0]: a.kwargs for a in ld.args[0]
                if type(a).__name__ == "DeclareLaunchArgument"}
    assert set(declared) == {"scenario", "trials", "namespace", "robots_per_process", "plant",
                             "mode", "links", "record", "live", "params_file", "out",
                             "run_file"}
    assert all(d["description"] for d in declared.values())


@pytest.mark.parametrize("given, argv", [
    ({}, []),
    ({"namespace": "/team2", "trials": "3", "record": "REC"},
     ["--namespace", "/team2", "--trials", "3", "--record", "REC"]),
    ({"scenario": "paper-hexagon6", "links": "direct", "robots_per_process": "3"},
     ["--links", "direct", "--container", "3"]),
])
def test_its_processes_are_the_launchers_for_the_same_arguments(launch_file, tmp_path, given,
                                                                argv):
    context = {name: default for name, default, _ in launch_file.ARGUMENTS}
    context.update(given, out=str(tmp_path / "out"))
    if "record" in given:
        context["record"] = str(tmp_path / "run.mcap")
        argv = [str(tmp_path / "run.mcap") if a == "REC" else a for a in argv]
    ld = launch_file.generate_launch_description()
    (opaque,) = [a for a in ld.args[0] if type(a).__name__ == "OpaqueFunction"]
    nodes = opaque.kwargs["function"](context)
    # the launcher's plan for the same options: every process but its own monitor, with
    # the same arguments, ROS arguments and parameters; the leader also ends the launch
    plan = plan_of(build_parser().parse_args(
        ["launch", context["scenario"], *argv, "--out", str(tmp_path / "plan")]))
    assert [n.kwargs["executable"] for n in nodes] == [ros2_executable(s.module)
                                                       for s in plan.nodes]
    for node, spec in zip(nodes, plan.nodes, strict=True):
        assert node.kwargs["package"] == "formation_ilc"
        # each node under its own name (a container of robots keeps its nodes' names)
        assert node.kwargs.get("name") == (None if "--robots" in spec.args else spec.name)
        assert node.kwargs["arguments"] == list(spec.args)
        params = dict(spec.params)
        if spec.name == "virtual_leader":
            assert "monitor" in params["nodes_expected"]  # the launcher's monitor...
            params["nodes_expected"] = [n for n in params["nodes_expected"]
                                        if n != "monitor"]  # ...is not the launch file's
            params["monitored"] = False
            params["state_dir"] = str(tmp_path / "out" / "state")
            params["exit_when_done"] = True
            assert node.kwargs["on_exit"] and node.kwargs["on_exit"][0].kwargs["reason"]
        else:
            assert node.kwargs["on_exit"] is None
            if "state_dir" in params:
                params["state_dir"] = str(tmp_path / "out" / "state")
        ros = [*spec.remaps]
        for k, v in params.items():
            ros += ["-p", f"{k}:={param_text(v)}"]
        got = node.kwargs["ros_arguments"]
        if spec.name == "virtual_leader":  # run ids differ from plan to plan
            got = [a for a in got if not a.startswith("run_id:=")]
            ros = [a for a in ros if not a.startswith("run_id:=")]
        assert got == ros, spec.name


def test_every_executable_is_a_ros2_run_shim():
    for script, exe in ROS2_RUN.items():
        assert f"from {entry_module(script)} import main" in (SHIMS / exe).read_text()


def test_the_robot_file_starts_one_robot_and_its_bridge_under_their_names(monkeypatch):
    """launch/robot.launch.py: what a robot's own computer runs (docs/real-robots.md)."""
    file = FILE.with_name("robot.launch.py")
    ast.parse(file.read_text())
    mod = _load(monkeypatch, file)
    ld = mod.generate_launch_description()
    context = {name: default for name, default, _ in mod.ARGUMENTS}
    context.update(robot_id="3", base="turtlebot4", lifecycle="true")
    (opaque,) = [a for a in ld.args[0] if type(a).__name__ == "OpaqueFunction"]
    robot, bridge = opaque.kwargs["function"](context)
    assert (robot.kwargs["name"], robot.kwargs["executable"]) == ("robot_3", "robot")
    assert (bridge.kwargs["name"], bridge.kwargs["executable"]) == ("bridge_3", "bridge")
    assert robot.kwargs["namespace"] == bridge.kwargs["namespace"] == "/formation"
    assert robot.kwargs["ros_arguments"] == ["-p", "robot_id:=3"]
    assert bridge.kwargs["ros_arguments"] == ["-p", "robot_id:=3", "-p", "lifecycle:=true",
                                              "-p", "base:=turtlebot4"]
    for exe in ("robot", "bridge"):  # what ros2 run formation_ilc finds
        assert (SHIMS / exe).exists()


def test_a_run_file_gives_the_processes_its_launch_gives(launch_file, tmp_path):
    from formation_ilc.cli.commands import main

    run_file = tmp_path / "run.yaml"
    assert main(["run-file", "paper-hexagon6", "--links", "direct", "--trials", "3",
                 "-o", str(run_file)]) == 0
    context = {name: default for name, default, _ in launch_file.ARGUMENTS}
    context.update(run_file=str(run_file), namespace="/team2", out=str(tmp_path / "out"))
    assert launch_file.launcher_argv(context.__getitem__) == [
        str(run_file), "--namespace", "/team2", "--out", str(tmp_path / "out")]
    ld = launch_file.generate_launch_description()
    (opaque,) = [a for a in ld.args[0] if type(a).__name__ == "OpaqueFunction"]
    nodes = opaque.kwargs["function"](context)
    plan = plan_of(build_parser().parse_args(
        ["launch", str(run_file), "--namespace", "/team2", "--out", str(tmp_path / "plan")]))
    assert [n.kwargs["executable"] for n in nodes] == [ros2_executable(s.module)
                                                       for s in plan.nodes]
    assert "robot_6" in [s.name for s in plan.nodes] and plan.config.links == "direct"
