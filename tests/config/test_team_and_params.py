"""The run configuration as ROS parameters (one mapping, both ways), the team the leader
waits for, and the node names: one owner each, no ROS needed."""

import pytest
import yaml

from formation_ilc.config.plants import PLANTS, default_plant
from formation_ilc.config.roster import Lineup, roster
from formation_ilc.config.runconfig import (
    PARAMS,
    RunConfig,
    make_config,
    param_text,
    scenario_reference,
)
from formation_ilc.config.scenario import ScenarioError
from formation_ilc.core.clock import Malformed
from formation_ilc.core.names import (
    CLOCK,
    NAMESPACE,
    bridge_name,
    namespace_remaps,
    robot_name,
    robot_number,
)

TINY = """\
name: tiny
dt: 0.1
samples: 20
robots: 2
trials: 4
seed: 11
reference: {kind: lemniscate}
formation:
  frame: world
  offsets: {1: {x: 0.5, y: 0.0}, 2: {x: -0.5, y: 0.0}}
graph:
  leader: {1: 1.0}
  edges: [{from: 1, to: 2}]
"""

CONFIGS = [
    dict(),
    dict(seed=3, trials=7, law=22, memory="literal", noise=False),
    dict(delay=False, mode="realtime", links="direct", gap=5, monitored=True, recorded=True,
         timeout=2.5, run_id="r0123abc"),
    dict(noise=False, delay=False, mode="wallclock", links="direct", law=23),
]


def _as_ros(params):
    """What a node gets from ``-p NAME:=TEXT``: ROS reads TEXT as YAML."""
    return {k: yaml.safe_load(param_text(v)) for k, v in params.items()}


@pytest.mark.parametrize("scenario", ["paper-triangle3", "file"])
@pytest.mark.parametrize("options", CONFIGS)
def test_a_configuration_survives_its_ros_parameters(tmp_path, scenario, options):
    if scenario == "file":
        (tmp_path / "tiny.yaml").write_text(TINY)
        scenario = str(tmp_path / "tiny.yaml")
    cfg = make_config(scenario, **options)
    params = cfg.to_params(scenario_reference(scenario))
    assert set(params) == set(PARAMS)
    back = RunConfig.from_params(_as_ros(params))
    assert back.to_json() == cfg.to_json()
    assert back.scenario.trials == cfg.scenario.trials and back.timeout == cfg.timeout


def test_parameters_keep_their_declared_types_on_the_command_line():
    cfg = make_config("paper-triangle3", timeout=20.0, run_id="r5")
    got = _as_ros(cfg.to_params("paper-triangle3"))
    # a node declares each parameter with its default's type; a value of another type
    # would be refused by rclpy
    for name, default in PARAMS.items():
        assert type(got[name]) is type(default), (name, got[name])
    assert param_text(True) == "true" and param_text(["robot_1", "monitor"]) == \
        "[robot_1,monitor]"
    assert yaml.safe_load(param_text(["robot_1", "monitor"])) == ["robot_1", "monitor"]


def test_missing_parameters_take_the_scenarios_values():
    cfg = RunConfig.from_params({"scenario": "paper-triangle3"})
    ref = make_config("paper-triangle3")
    assert cfg.to_json() == ref.to_json()
    with pytest.raises(ValueError, match="parameter scenario: a scenario name or file is "
                                         "required"):
        RunConfig.from_params({})
    with pytest.raises(ScenarioError, match="no such scenario"):
        RunConfig.from_params({"scenario": "no-such-scenario"})


def test_a_scenario_file_is_referenced_by_its_absolute_path(tmp_path, monkeypatch):
    (tmp_path / "tiny.yaml").write_text(TINY)
    monkeypatch.chdir(tmp_path)
    assert scenario_reference("tiny.yaml") == str(tmp_path / "tiny.yaml")
    assert scenario_reference("paper-hexagon6") == "paper-hexagon6"


def team(n: int, **kw):
    return roster(Lineup(n, **kw)).team


def test_the_team_by_plant_and_links():
    sim = team(3, plant="sim", links="emulated", monitor=True, record=True)
    assert sim.expected == ["robot_1", "robot_2", "robot_3", "robot_sim", "link_emulator",
                            "monitor", "recorder"]
    pioneer = team(2, plant="pioneer", links="direct", monitor=False)
    assert pioneer.expected == ["robot_1", "robot_2", "bridge_1", "bridge_2"]
    ext = team(2, plant="external", links="direct", external=("standin_plant",),
               monitor=True)
    assert ext.plants == ("standin_plant",) and ext.support == ()
    assert ext.expected[-1] == "monitor"
    with pytest.raises(ValueError, match="plant must be one of"):
        team(2, plant="gazebo", links="direct")


def test_a_leader_started_alone_waits_for_the_team_the_launcher_would_name():
    # the launcher adds its monitor (and a recorder); the rest is the same rule
    for mode, links in (("lockstep", "emulated"), ("realtime", "direct"),
                        ("wallclock", "direct")):
        plant = default_plant(mode)
        assert plant in PLANTS
        alone = team(4, plant=plant, links=links, monitor=False)
        launched = team(4, plant=plant, links=links, monitor=True)
        assert launched.expected == alone.expected + ["monitor"]
    assert default_plant("wallclock") == "pioneer" and default_plant("lockstep") == "sim"


def test_node_names():
    assert robot_name(12) == "robot_12" and robot_number("robot_12") == 12
    assert bridge_name(3) == "bridge_3"
    for bad in ("robot_0", "robot_01", "robot_x", "bridge_1", "robot_"):
        with pytest.raises(Malformed):
            robot_number(bad)
    assert namespace_remaps(None) == namespace_remaps(NAMESPACE) == []
    assert namespace_remaps("/team2") == ["-r", "__ns:=/team2", "-r",
                                          f"{CLOCK}:=/team2{CLOCK}"]


@pytest.mark.parametrize("text", ["", "true", "123", "1e3", "null", "it's", "a: b", "[x]",
                                  "r0123abc", "/tmp/my run/s.yaml", "paper-triangle3"])
def test_a_string_parameter_stays_a_string(text):
    assert yaml.safe_load(param_text(text)) == text
