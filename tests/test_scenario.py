import textwrap

import numpy as np
import pytest

from formation_ilc.scenario import ScenarioError, builtin_scenarios, load_scenario

BASE = """\
name: tiny
dt: 0.1
samples: 20
robots: 2
reference: {kind: lemniscate}
formation:
  frame: world
  offsets:
    1: {x: 0.5, y: 0.0}
    2: {x: -0.5, y: 0.0}
graph:
  leader: {1: 1.0}
  edges:
    - {from: 1, to: 2}
"""


def write(tmp_path, text):
    p = tmp_path / "s.yaml"
    p.write_text(text)
    return p


def test_builtins_load():
    assert {"paper-hexagon6", "paper-triangle3"} <= set(builtin_scenarios())
    hexa = load_scenario("paper-hexagon6")
    assert hexa.n == 6 and hexa.samples == 300 and hexa.dt == 0.1
    assert hexa.uncertainty.initial_shift[2] == pytest.approx(np.radians(0.05))
    assert hexa.uncertainty.delay.pmf() == {1: 0.15, 2: 0.30, 3: 0.35, 4: 0.20}


def test_minimal_file_loads(tmp_path):
    sc = load_scenario(write(tmp_path, BASE))
    assert sc.n == 2 and sc.law.kind == 9 and sc.law.memory == "feedforward"
    assert sc.desired.eta.shape == (2, 21, 3)


@pytest.mark.parametrize(
    ("change", "field", "why"),
    [
        (("dt: 0.1", "dt: 0"), "dt", "must be > 0"),
        (("dt: 0.1", "dt: -0.2"), "dt", "must be > 0"),
        (("dt: 0.1", "dt: fast"), "dt", "expected a number"),
        (("samples: 20", "samples: 2.5"), "samples", "expected an integer"),
        (("    - {from: 1, to: 2}", "    - {from: 7, to: 2}"), "graph.edges[0].from",
         "robot 7 does not exist (robots are 1..2)"),
        (("  leader: {1: 1.0}", "  leader: {3: 1.0}"), "graph.leader.3", "robot 3 does not exist"),
        (("name: tiny", "name: tiny\ncolour: red"), "colour", "unknown field"),
        (("  frame: world", "  frame: world\n  frme: x"), "formation.frme", "unknown field"),
        (("  frame: world", "  frame: body"), "formation.frame", "must be one of world, leader"),
        (("    2: {x: -0.5, y: 0.0}", ""), "formation.offsets", "no offset for robot(s) 2"),
        (("reference: {kind: lemniscate}", "reference: {kind: spiral}"), "reference.kind",
         "must be one of"),
    ],
)
def test_errors_name_file_field_and_reason(tmp_path, change, field, why):
    p = write(tmp_path, BASE.replace(*change))
    with pytest.raises(ScenarioError) as exc:
        load_scenario(p)
    msg = str(exc.value)
    assert msg.startswith(f"{p}: {field}: "), msg
    assert why in msg


def test_delay_and_uncertainty_sections(tmp_path):
    text = BASE + textwrap.dedent("""\
        uncertainty:
          initial_shift: [0.01, 0.01, 1 deg]
          noise: {uniform: [0.01, 0.01, 0.5 deg]}
        delay: {model: uniform, low: 1, high: 3, leader_link: false}
        law: {kind: 23, memory: literal, gain: [0.1, 0.2]}
        """)
    sc = load_scenario(write(tmp_path, text))
    assert sc.uncertainty.delay.max_delay == 3 and not sc.uncertainty.delay_leader
    assert sc.law.gain == (0.1, 0.2) and sc.law.kind == 23
    bad = text.replace("gain: [0.1, 0.2]", "gain: [0.1]")
    with pytest.raises(ScenarioError, match="law.gain: expected one gain per robot"):
        load_scenario(write(tmp_path, bad))
    bad = text.replace("high: 3", "high: 99")
    with pytest.raises(ScenarioError, match="exceed the trial"):
        load_scenario(write(tmp_path, bad))


def test_unknown_scenario_lists_builtins():
    with pytest.raises(ScenarioError, match="paper-hexagon6"):
        load_scenario("no-such-thing")


def test_bad_yaml(tmp_path):
    with pytest.raises(ScenarioError, match="not valid YAML"):
        load_scenario(write(tmp_path, "name: [unclosed"))
