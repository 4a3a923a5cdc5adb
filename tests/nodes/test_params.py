"""Parameters the ROS way: every node starts from ``--params-file`` YAML (node-keyed and
``/**``), its parameters have descriptors and are read-only, a bad value is one line and
status 2, ``use_sim_time`` is refused clearly; the shipped example files start the nodes."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.ros

rclpy = pytest.importorskip("rclpy")
from rclpy.context import Context  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

PARAMS = Path(__file__).resolve().parents[2] / "params"


@pytest.fixture
def params_context(ros_env):
    """A private context initialised with ROS arguments (what a launch file passes)."""
    made: list[Context] = []

    def make(*ros_args: str) -> Context:
        ctx = Context()
        rclpy.init(args=["node", "--ros-args", *ros_args], context=ctx)
        made.append(ctx)
        return ctx

    yield make
    for ctx in made:
        rclpy.try_shutdown(context=ctx)


def test_a_robot_starts_from_a_wildcard_params_file_alone(params_context):
    from formation_ilc.nodes.common import robot_node_from_args
    from formation_ilc.nodes.robot import RobotNode

    ctx = params_context("--params-file", str(PARAMS / "team.yaml"))
    robot = robot_node_from_args(RobotNode, [], "formation-ilc-robot", context=ctx)
    try:
        assert robot.get_fully_qualified_name() == "/formation/robot_2"
        assert robot.get_parameter("scenario").value == "paper-triangle3"
        assert robot.get_parameter("links").value == "direct"
        assert robot.configured and robot.cfg.scenario.name == "paper-triangle3"
    finally:
        robot.destroy_node()


def test_a_robot_starts_from_a_node_keyed_params_file_under_its_launch_name(params_context):
    from formation_ilc.nodes.common import robot_node_from_args
    from formation_ilc.nodes.robot import RobotNode

    ctx = params_context("-r", "__node:=robot_1", "--params-file", str(PARAMS / "robot.yaml"))
    robot = robot_node_from_args(RobotNode, [], "formation-ilc-robot", context=ctx)
    try:
        assert robot.get_fully_qualified_name() == "/formation/robot_1"
        assert robot.id == 1 and robot.configured
        # descriptors: a description with the range, read-only; a change is refused, with
        # the reason, and the value stays
        d = robot.describe_parameter("robot_id")
        assert d.read_only and "robot number" in d.description
        assert d.integer_range[0].from_value == 1
        res = robot.set_parameters([Parameter("seed", value=7)])
        assert not res[0].successful and "read-only" in res[0].reason
        # seed -1 keeps the scenario's: the parameter reads the seed that runs, and says so
        assert robot.get_parameter("seed").value == robot.cfg.scenario.seed == 1
        assert "reads the value in use once running" in \
            robot.describe_parameter("seed").description
        res = robot.set_parameters([Parameter("use_sim_time", value=True)])
        assert not res[0].successful and "use_sim_time is not supported" in res[0].reason
    finally:
        robot.destroy_node()


def test_a_bridge_starts_from_a_node_keyed_params_file(params_context):
    from formation_ilc.nodes.common import robot_node_from_args
    from formation_ilc.nodes.pioneer_bridge import BridgeNode

    ctx = params_context("-r", "__node:=bridge_1", "--params-file", str(PARAMS / "bridge.yaml"))
    bridge = robot_node_from_args(BridgeNode, [], "formation-ilc-bridge", "bridge", context=ctx)
    try:
        assert bridge.get_fully_qualified_name() == "/formation/bridge_1"
        assert bridge.configured and bridge.cfg.mode == "wallclock"
        assert bridge.get_parameter("return_timeout").value == 60.0
        assert "unit: s" in bridge.describe_parameter("return_timeout").description
    finally:
        bridge.destroy_node()


def test_the_leader_and_the_simulator_start_from_their_example_files(params_context):
    from robot_sim.node import SimNode
    from virtual_leader.node import LeaderNode

    ctx = params_context("--params-file", str(PARAMS / "virtual_leader.yaml"),
                         "--params-file", str(PARAMS / "robot_sim.yaml"))
    leader = LeaderNode(context=ctx)
    sim = SimNode(context=ctx)
    try:
        assert leader.cfg.scenario.name == "paper-triangle3"
        assert "robot_1" in leader.expected and "" not in leader.expected
        # the parameters read what runs: the scenario's values, the team waited for
        assert leader.get_parameter("trials").value == leader.cfg.scenario.trials == 20
        assert leader.get_parameter("law").value == 9  # 0 in the file: the scenario's
        assert leader.get_parameter("seed").value == 1
        assert leader.get_parameter("memory").value == "feedforward"
        assert leader.get_parameter("nodes_expected").value == leader.expected
        assert sim.get_parameter("timeout").value == 0.0  # until the configuration comes
    finally:
        leader.destroy_node()
        sim.destroy_node()


def run(module: str, *args: str, env=None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", module, *args], capture_output=True,
                          text=True, timeout=120, env=env)


@pytest.mark.multiprocess
@pytest.mark.parametrize("module, args, line", [
    ("virtual_leader.node", ["-p", "scenario:=paper-triangle3", "-p", "trials:=abc"],
     "formation-ilc-virtual-leader: parameter trials: expected an integer, got 'abc'"),
    ("virtual_leader.node", ["-p", "scenario:=paper-triangle3", "-p", "mode:=fast"],
     "formation-ilc-virtual-leader: parameter mode: one of lockstep, realtime, wallclock; "
     "got 'fast'"),
    ("virtual_leader.node", ["-p", "trials:=3"],
     "formation-ilc-virtual-leader: parameter scenario: a scenario name or file is required"),
    ("formation_ilc.nodes.robot", ["-p", "robot_id:=1", "-p", "seed:=x"],
     "formation-ilc-robot: parameter seed: expected an integer, got 'x'"),
    ("formation_ilc.nodes.robot", ["-p", "robot_id:=0"],
     "formation-ilc-robot: parameter robot_id: 0 is outside 1 .. inf (1-based robot number; "
     "the node is named robot_<id>)"),
    ("formation_ilc.nodes.robot", ["-p", "scenario:=paper-triangle3"],
     "formation-ilc-robot: parameter robot_id: a robot number >= 1 is required (-p "
     "robot_id:=I, or robot_id in a --params-file under /** or the node's name)"),
    ("robot_sim.node", ["-p", "timeout:=-1.0"],
     "formation-ilc-robot-sim: parameter timeout: -1.0 is outside 0 .. 1e+06 (lockstep: how long "
     "the simulator waits for a robot's command; 0: the run configuration's)"),
    ("robot_sim.link_emulator", ["-p", "use_sim_time:=true"],
     "formation-ilc-link-emulator: parameter use_sim_time is not supported: the stack "
     "keeps its own time (lockstep labels on /clock are read as messages, wallclock is the "
     "system clock)"),
    ("formation_ilc.nodes.pioneer_bridge", ["-p", "robot_id:=1", "-p", "rate:=0.0"],
     "formation-ilc-bridge: parameter rate: 0.0 is outside 0.1 .. 1000 (rate the command is "
     "republished to the driver)"),
    ("robot_sim.fake_pioneer", ["-p", "driver:=p2os2"],
     "fake_pioneer: parameter driver: one of rosaria, ros2aria; got 'p2os2'"),
    ("robot_sim.physics_node", ["-p", "model:=roomba"],
     "formation-ilc-physics-sim: parameter model: one of p3dx, husky, husky-imu; got 'roomba'"),
    ("robot_sim.physics_base", ["-p", "tick:=0.0"],
     "physics_bases: parameter tick: 0.0 is outside 0.0001 .. 10 (how often "
     "the world is stepped and odometry published)"),
    ("virtual_leader.node", ["-p", "scenario:=paper-triangle3", "-p", "law:=7"],
     "formation-ilc-virtual-leader: parameter law: one of 0, 9, 22, 23; got 7"),
    ("virtual_leader.node", ["-p", "scenario:=paper-triangle3", "-p", "memory:=xyz"],
     "formation-ilc-virtual-leader: parameter memory: one of '', feedforward, literal; got 'xyz'"),
    ("formation_ilc.nodes.robot", ["--params-file", "/nonexistent/robot.yaml"],
     "formation-ilc-robot: Failed to parse ROS arguments: Couldn't parse params file: "
     "'--params-file /nonexistent/robot.yaml'. Error: Error opening YAML file"),
])
def test_a_bad_parameter_is_one_line_and_status_2(ros_env, module, args, line):
    res = run(module, "--ros-args", *args, env=ros_env)
    assert res.returncode == 2, res.stdout + res.stderr
    assert [ln for ln in res.stderr.splitlines() if ln.strip()] == [line]


@pytest.mark.multiprocess
def test_the_recorder_refuses_sim_time_before_it_writes_anything(ros_env, tmp_path):
    out = tmp_path / "run.mcap"
    res = run("formation_ilc.nodes.recorder", "-o", str(out), "--ros-args", "-p",
              "use_sim_time:=true", env=ros_env)
    assert res.returncode == 2, res.stderr
    assert len(res.stderr.strip().splitlines()) == 1 and "use_sim_time" in res.stderr
    assert not out.exists()


def test_the_robot_node_is_made_while_its_probe_holds_the_participant(params_context):
    """The participant of the probe that reads robot_id is held (by a keeper node) until
    the robot's node exists: rmw destroys a context's DDS participant with its last node,
    and a robot process whose probe went first announced two participants (in a secure run, two
    handshakes with everyone). The probe itself is gone by then (a node of its name would
    take the real node's endpoints in the graph: test_a_node_named_as_its_probe_...)."""
    from rclpy.node import Node

    from formation_ilc.nodes.common import robot_node_from_args
    from formation_ilc.nodes.params import KEEPER

    ctx = params_context("-p", "robot_id:=2")
    seen: list[list[tuple[str, str]]] = []

    class Made(Node):
        def __init__(self, rid: int, **kwargs):
            super().__init__(f"robot_{rid}", namespace="/formation", **kwargs)
            seen.append(sorted(self.get_node_names_and_namespaces()))

    node = robot_node_from_args(Made, [], "formation-ilc-robot", context=ctx)
    try:
        assert (KEEPER, "/") in seen[0]  # the participant still held
        assert ("robot", "/formation") not in seen[0]  # the probe gone first
        assert ("robot_2", "/formation") in seen[0]
        assert ("robot", "/formation") not in node.get_node_names_and_namespaces()
    finally:
        node.destroy_node()


def test_a_node_named_as_its_probe_keeps_its_endpoints_in_the_graph(params_context):
    """The fake driver's probe has the driver's own name: the graph files the driver's
    publishers and subscriptions under it (made beside a probe of its name, they went
    with the probe, and the graph showed the driver with none)."""
    import msgs_schema as ms
    from formation_ilc.nodes.params import probe_overrides
    from robot_sim.fake_pioneer import FakePioneer

    ctx = params_context("-r", "__ns:=/pioneer_1")
    with probe_overrides(ms.FAKE_DRIVER_NODE, ms.DRIVERS["rosaria"].default_ns,
                         context=ctx) as found:
        fake = FakePioneer(found.get("driver", "rosaria"), context=ctx)
    try:
        key = (ms.FAKE_DRIVER_NODE, "/pioneer_1")
        pubs = {t for t, _ in fake.get_publisher_names_and_types_by_node(*key)}
        subs = {t for t, _ in fake.get_subscriber_names_and_types_by_node(*key)}
        assert {"/pioneer_1/pose", "/rosout"} <= pubs, pubs
        assert "/pioneer_1/cmd_vel" in subs, subs
        assert sum(k == key for k in fake.get_node_names_and_namespaces()) == 1
    finally:
        fake.destroy_node()


def test_the_fake_driver_starts_from_its_example_file(params_context):
    import msgs_schema as ms
    from formation_ilc.nodes.params import probe_overrides
    from robot_sim.fake_pioneer import FakePioneer

    ctx = params_context("--params-file", str(PARAMS / "fake_pioneer.yaml"))
    with probe_overrides(ms.FAKE_DRIVER_NODE, ms.DRIVERS["rosaria"].default_ns,
                         context=ctx) as found:
        fake = FakePioneer(found["driver"], context=ctx)
    try:
        assert fake.get_parameter("cmd_timeout").value == 0.6
        assert fake.describe_parameter("rate").read_only
    finally:
        fake.destroy_node()


def test_the_physics_nodes_start_from_their_example_files(params_context):
    pytest.importorskip("pybullet")  # the [physics] extra; CI installs it
    from robot_sim.physics_base import PhysicsBases
    from robot_sim.physics_node import PhysicsNode

    ctx = params_context("--params-file", str(PARAMS / "physics_sim.yaml"),
                         "--params-file", str(PARAMS / "physics_bases.yaml"))
    sim = PhysicsNode(context=ctx)
    bases = PhysicsBases(context=ctx)
    try:
        assert sim.get_parameter("rate").value == 240.0
        assert sim.describe_parameter("model").read_only
        assert "unit: Hz" in sim.describe_parameter("rate").description
        assert bases.get_parameter("robots").value == 3 and len(bases.odom_pubs) == 3
        assert bases.describe_parameter("tick").floating_point_range[0].to_value == 10.0
    finally:
        sim.destroy_node()
        bases.destroy_node()


def test_every_example_file_is_installed_and_every_node_has_one():
    import tomllib

    data = tomllib.loads((PARAMS.parent / "pyproject.toml").read_text())
    shipped = data["tool"]["setuptools"]["data-files"]["share/formation_ilc/params"]
    assert sorted(shipped) == sorted(f"params/{p.name}" for p in PARAMS.glob("*.yaml"))
    for node in ("robot", "bridge", "virtual_leader", "robot_sim", "fake_pioneer",
                 "physics_sim", "physics_bases"):
        assert (PARAMS / f"{node}.yaml").is_file()


@pytest.mark.multiprocess
@pytest.mark.parametrize("args, line", [
    (["formation_ilc.nodes.liveview", "--port", "70000"],
     "formation-ilc-liveview: error: argument --port: a port is in 1..65535, got 70000 "
     "(see formation-ilc-liveview --help)"),
    (["formation_ilc.nodes.recorder", "--output", "{tmp}"],
     "formation-ilc-recorder: --output {tmp}: is a folder, expected a file name"),
    (["formation_ilc.nodes.recorder", "--output", "{tmp}/new/run.mcap"],
     "formation-ilc-recorder: --output {tmp}/new/run.mcap: the folder {tmp}/new does not "
     "exist"),
])
def test_the_nodes_own_arguments_are_one_line_and_status_2(ros_env, tmp_path, args, line):
    """Before: --port 70000 an OverflowError traceback; --output a folder an
    IsADirectoryError traceback (exit 1); a missing folder was made (as root)."""
    argv = [a.replace("{tmp}", str(tmp_path)) for a in args]
    res = run(argv[0], *argv[1:], env=ros_env)
    assert res.returncode == 2, res.stdout + res.stderr
    assert [ln for ln in res.stderr.splitlines() if ln.strip()] == [
        line.replace("{tmp}", str(tmp_path))]
    assert not (tmp_path / "new").exists()


@pytest.mark.parametrize("key, close", [("sceanrio", "scenario"), ("robotid", "robot_id"),
                                        ("timout", "timeout"), ("drvier", "driver")])
def test_a_misspelt_key_is_refused_naming_the_closest_known_name(key, close):
    from formation_ilc.config.params import LEADER, ROBOT, unknown_key

    why = unknown_key(key, [p.name for p in LEADER + ROBOT])
    assert why == (f"parameter {key}: no node of formation-ilc has this parameter "
                   f"(did you mean {close}?)")
    # another node's parameter (a /** section holds the whole team's) is that node's
    assert unknown_key("robot_id", [p.name for p in LEADER]) is None
    assert unknown_key("qos_overrides./clock.subscription.depth", []) is None


def test_the_plant_names_are_those_of_the_plant_nodes_tables():
    from formation_ilc.config.params import PLANT_NAMES
    from robot_sim import physics_base, physics_node

    assert PLANT_NAMES == {p.name for p in physics_node.PARAMS + physics_base.PARAMS}


def test_every_node_refuses_a_misspelt_parameter_in_a_params_file(params_context, tmp_path):
    """A key no node takes, in a section keyed by the node or under ``/**``, is refused in
    one line naming it and the closest name, by every node of the stack."""
    from formation_ilc.nodes.params import ParameterError
    from formation_ilc.nodes.pioneer_bridge import BridgeNode
    from formation_ilc.nodes.robot import RobotNode
    from robot_sim.link_emulator import LinkEmulator
    from robot_sim.node import SimNode
    from virtual_leader.node import LeaderNode

    f = tmp_path / "typo.yaml"
    f.write_text("/**:\n  ros__parameters:\n    scenario: paper-triangle3\n"
                 "    sceanrio: paper-hexagon6\n")
    ctx = params_context("--params-file", str(f))
    for make in (lambda: LeaderNode(context=ctx), lambda: SimNode(context=ctx),
                 lambda: LinkEmulator(context=ctx), lambda: RobotNode(1, context=ctx),
                 lambda: BridgeNode(1, context=ctx)):
        with pytest.raises(ParameterError) as exc:
            make()
        assert str(exc.value) == ("parameter sceanrio: no node of formation-ilc has this "
                                  "parameter (did you mean scenario?)")
