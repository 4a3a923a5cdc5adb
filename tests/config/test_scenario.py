import textwrap

import numpy as np
import pytest

from formation_ilc.config.scenario import ScenarioError, builtin_scenarios, load_scenario

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


def test_a_reference_built_once_is_reused_and_not_shared(tmp_path):
    """Scenarios with the same reference mapping, samples and dt get the reference built
    for the first (a unicycle reference takes 0.4 s); each its own copy. A reference file is
    read every time: its contents may change."""
    from formation_ilc.config import scenario as scenario_mod

    a = load_scenario("paper-triangle3")
    b = load_scenario("paper-triangle3")
    assert a.reference.tobytes() == b.reference.tobytes()
    assert not np.shares_memory(a.reference, b.reference)
    a.reference[:] = 0.0
    c = load_scenario("paper-triangle3")
    assert c.reference.tobytes() == b.reference.tobytes()
    assert any('"kind": "unicycle"' in k for k in scenario_mod._REFERENCES)
    # samples from a file: rebuilt from the file each time
    pts = tmp_path / "p.csv"
    n = 40
    pts.write_text("\n".join(f"{i * 0.1},{0.0}" for i in range(n)))
    doc = (f"name: f\ndt: 0.1\nsamples: {n - 2}\nrobots: 1\nreference: {{kind: samples, "
           f"file: p.csv}}\nformation: {{frame: world, offsets: {{1: {{x: 0, y: 0}}}}}}\n"
           f"graph: {{leader: {{1: 1}}}}\n")
    (tmp_path / "f.yaml").write_text(doc)
    first = load_scenario(tmp_path / "f.yaml").reference.copy()
    pts.write_text("\n".join(f"{i * 0.2},{0.0}" for i in range(n)))
    second = load_scenario(tmp_path / "f.yaml").reference
    assert not np.array_equal(first, second)
