from __future__ import annotations

import copy
import math
import textwrap
from typing import Any

import numpy as np
import pytest
import yaml

from formation_ilc.config.scenario import (
    ScenarioError,
    builtin_scenarios,
    load_scenario,
    scenario_from_text,
)

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


# ----------------------------------------------------------------------------------------
# Every validation rule of the scenario loader, one rule per case.

SRC = "s.yaml"
DELETE = object()

RULES_BASE: dict[str, Any] = {
    "name": "rules",
    "description": "a scenario every field of which is set, for the rule tests",
    "dt": 0.1,
    "samples": 10,
    "trials": 2,
    "seed": 0,
    "robots": 3,
    "reference": {"kind": "lemniscate", "x_amplitude": 7.5, "y_amplitude": 10.0,
                  "period": 45.0},
    "formation": {
        "frame": "world",
        "scales": {"S": {"mean": 1.0, "amplitude": 0.1, "period": 5.0, "phase": "10 deg"}},
        "offsets": {1: {"x": 0.5, "y": 0.0, "scale": "S"}, 2: {"x": -0.5, "y": 0.0},
                    3: {"x": 0.0, "y": 0.5}},
    },
    "graph": {"leader": {1: 1.0},
              "edges": [{"from": 1, "to": 2, "weight": 1.0}, {"from": 2, "to": 3}]},
    "law": {"kind": 9, "memory": "feedforward", "gain": 0.08, "gain_prime": [0.08, 0.1, 0.1],
            "gain_heading": "measured"},
    "uncertainty": {
        "initial_shift": [0.05, 0.05, "0.05 deg"],
        "disturbance": {"fixed": [{"amplitude": 0.01, "frequency": 0.02}, {}],
                        "uniform": [0.01, 0.0]},
        "noise": {"fixed": [{}, {}, {"amplitude": "0.1 deg", "frequency": 0.05}],
                  "uniform": [0.01, 0.01, 0.0]},
    },
    "delay": {"model": "paper", "leader_link": True},
}

UNICYCLE = {"kind": "unicycle", "speed": 0.35, "turn_radius": 1.5, "start": [0.0, 0.0, 0.0]}
SAMPLES = {"kind": "samples", "points": [[0.1 * i, 0.0] for i in range(11)]}
WAYPOINTS = {"kind": "waypoints", "times": [0.0, 2.0], "points": [[0.0, 0.0], [2.0, 0.0]]}


def variant(*changes: tuple[str, Any]) -> dict[str, Any]:
    """RULES_BASE with each (path, value) applied; a path reads like the error's field,
    ``graph.edges[1].to``; value DELETE removes the field."""
    data = copy.deepcopy(RULES_BASE)
    for path, value in changes:
        keys: list[Any] = []
        for part in path.split("."):
            name, _, rest = part.partition("[")
            keys.append(int(name) if name.isdigit() else name)
            if rest:
                keys.append(int(rest.rstrip("]")))
        node = data
        for k in keys[:-1]:
            node = node[k]
        if value is DELETE:
            del node[keys[-1]]
        else:
            node[keys[-1]] = value
    return data


def load(data: Any):
    return scenario_from_text(yaml.safe_dump(data, sort_keys=False), SRC)


def refused(data: Any, field: str, why: str) -> None:
    with pytest.raises(ScenarioError) as exc:
        load(data)
    msg = str(exc.value)
    assert msg.startswith(f"{SRC}: {field}: "), msg
    assert why in msg, msg


@pytest.mark.parametrize("reference", [None, UNICYCLE, SAMPLES, WAYPOINTS],
                         ids=["lemniscate", "unicycle", "samples", "waypoints"])
def test_base_loads(reference):
    data = RULES_BASE if reference is None else variant(("reference", reference))
    sc = load(data)
    assert sc.n == 3 and sc.samples == 10 and sc.law.gain_prime == (0.08, 0.1, 0.1)
    assert sc.desired.eta.shape == (3, 11, 3) and np.isfinite(sc.desired.eta).all()


def test_not_yaml_and_not_a_mapping():
    with pytest.raises(ScenarioError, match=r"^s\.yaml: not valid YAML"):
        scenario_from_text("name: [unclosed", SRC)
    refused([1, 2], "top level", "expected a mapping, got list")


TOP = [
    ("name", DELETE, "required field is missing"),
    ("name", 5, "expected a string"),
    ("description", 3, "expected a string"),
    ("dt", DELETE, "required field is missing"),
    ("dt", "fast", "expected a number"),
    ("dt", True, "expected a number"),
    ("dt", 0, "the sample time must be > 0 s"),
    ("dt", -0.1, "the sample time must be > 0 s"),
    ("dt", math.nan, "must be finite"),
    ("dt", math.inf, "must be finite"),
    ("samples", DELETE, "required field is missing"),
    ("samples", 2.5, "expected an integer"),
    ("samples", 1, "must be >= 2"),
    ("trials", 0, "must be >= 1"),
    ("seed", -1, "must be >= 0"),
    ("seed", "one", "expected an integer"),
    ("robots", DELETE, "required field is missing"),
    ("robots", 0, "must be >= 1"),
    ("colour", "red", "unknown field"),
]


@pytest.mark.parametrize(("field", "value", "why"), TOP)
def test_top_level_rules(field, value, why):
    refused(variant((field, value)), field, why)


REFERENCE = [
    ("reference", None, "reference", DELETE, "required field is missing"),
    ("reference", None, "reference", 5, "expected a mapping, got int"),
    ("reference.kind", None, "reference.kind", DELETE, "required field is missing"),
    ("reference.kind", None, "reference.kind", "spiral", "must be one of lemniscate, unicycle"),
    ("reference.period", None, "reference.period", 0, "must be > 0"),
    ("reference.x_amplitude", None, "reference.x_amplitude", "a", "expected a number"),
    ("reference.wiggle", None, "reference.wiggle", 1, "unknown field"),
    ("reference.speed", UNICYCLE, "reference.speed", DELETE, "required field is missing"),
    ("reference.speed", UNICYCLE, "reference.speed", "fast", "expected 'paper-ivb' or a number"),
    ("reference.speed", UNICYCLE, "reference.speed", True, "expected 'paper-ivb' or a number"),
    ("reference.speed", UNICYCLE, "reference.speed", math.inf, "must be finite"),
    ("reference.speed", UNICYCLE, "reference.speed", math.nan, "must be finite"),
    ("reference.turn_radius", UNICYCLE, "reference.turn_radius", math.inf, "must be finite"),
    ("reference.start", UNICYCLE, "reference.start", [0.0, 0.0], "expected a list of 3 numbers"),
    ("reference.start", UNICYCLE, "reference.start[2]", [0, 0, "north"], "expected a number"),
    ("reference.start", UNICYCLE, "reference.start[2]", [0, 0, "1.2.3 deg"],
     "cannot read '1.2.3 deg' as an angle"),
    ("reference.file", SAMPLES, "reference", "path.csv", "give exactly one of 'points'"),
    ("reference.points", SAMPLES, "reference", DELETE, "give exactly one of 'points'"),
    ("reference.points", SAMPLES, "reference.points", [[0, "a"]] * 11,
     "expected a list of [x, y] pairs"),
    ("reference.points", SAMPLES, "reference.points", [[0, 0, 0]] * 11,
     "expected a list of [x, y] pairs, got shape (11, 3)"),
    ("reference.points", SAMPLES, "reference.points", [[0.1 * i, 0] for i in range(10)],
     "needs at least samples + 1 = 11 points, got 10"),
    ("reference.points", SAMPLES, "reference.points",
     [[0.1 * i, math.nan if i == 3 else 0.0] for i in range(11)], "must be finite"),
    ("reference.times", WAYPOINTS, "reference.times", DELETE, "required field is missing"),
    ("reference.points", WAYPOINTS, "reference.points", DELETE, "required field is missing"),
    ("reference.times", WAYPOINTS, "reference.points", ["a", 2.0],
     "times must be numbers and points [x, y] pairs"),
    ("reference.points", WAYPOINTS, "reference.points", [[0.0, 0.0]],
     "needs as many [x, y] points as times, at least 2"),
    ("reference.times", WAYPOINTS, "reference.times", [2.0, 2.0], "must be strictly increasing"),
    ("reference.times", WAYPOINTS, "reference.times", [0.0, math.inf], "must be finite"),
    ("reference.points", WAYPOINTS, "reference.points", [[0.0, 0.0], [math.inf, 0.0]],
     "must be finite"),
]


@pytest.mark.parametrize(("path", "kind", "field", "value", "why"), REFERENCE,
                         ids=[f"{r[2]}-{r[4]}" for r in REFERENCE])
def test_reference_rules(path, kind, field, value, why):
    changes = [] if kind is None else [("reference", copy.deepcopy(kind))]
    refused(variant(*changes, (path, value)), field, why)


def test_reference_file_that_cannot_be_read(tmp_path):
    data = variant(("reference", {"kind": "samples", "file": "missing.csv"}))
    with pytest.raises(ScenarioError) as exc:
        scenario_from_text(yaml.safe_dump(data), SRC, tmp_path)
    assert str(exc.value).startswith(f"{SRC}: reference.file: cannot read "), exc.value


FORMATION = [
    ("formation", DELETE, "formation", "required field is missing"),
    ("formation.frame", DELETE, "formation.frame", "required field is missing"),
    ("formation.frame", "body", "formation.frame", "must be one of world, leader"),
    ("formation.scales", [1, 2], "formation.scales", "expected a mapping name -> "),
    ("formation.scales.S", 3, "formation.scales.S", "expected a mapping, got int"),
    ("formation.scales.S.wobble", 1, "formation.scales.S.wobble", "unknown field"),
    ("formation.scales.S.period", -5.0, "formation.scales.S.period", "must be >= 0"),
    ("formation.scales.S.phase", "north", "formation.scales.S.phase", "expected a number"),
    ("formation.offsets", DELETE, "formation.offsets", "required field is missing"),
    ("formation.offsets", [[0, 0]] * 3, "formation.offsets", "expected a mapping robot -> "),
    ("formation.offsets.4", {"x": 0, "y": 0}, "formation.offsets.4",
     "robot 4 does not exist (robots are 1..3)"),
    ("formation.offsets.a", {"x": 0, "y": 0}, "formation.offsets.a",
     "expected a robot number, got 'a'"),
    ("formation.offsets.1.x", DELETE, "formation.offsets.1.x", "required field is missing"),
    ("formation.offsets.1.y", math.nan, "formation.offsets.1.y", "must be finite"),
    ("formation.offsets.1.scale", "D9", "formation.offsets.1.scale", "no scale named 'D9'"),
    ("formation.offsets.1.z", 0.0, "formation.offsets.1.z", "unknown field"),
    ("formation.offsets.3", DELETE, "formation.offsets", "no offset for robot(s) 3"),
    ("formation.shape", "hexagon", "formation.shape", "unknown field"),
]


@pytest.mark.parametrize(("path", "value", "field", "why"), FORMATION,
                         ids=[f"{f[2]}-{f[3]}" for f in FORMATION])
def test_formation_rules(path, value, field, why):
    refused(variant((path, value)), field, why)


GRAPH = [
    ("graph", DELETE, "graph", "required field is missing"),
    ("graph.leader", DELETE, "graph.leader", "required field is missing"),
    ("graph.leader", {}, "graph.leader", "expected a mapping {robot: weight} with at least one"),
    ("graph.leader", [1], "graph.leader", "expected a mapping {robot: weight} with at least one"),
    ("graph.leader", {4: 1.0}, "graph.leader.4", "robot 4 does not exist (robots are 1..3)"),
    ("graph.leader", {1: 0.0}, "graph.leader.1", "must be > 0"),
    ("graph.leader", {1: 1.0, 2: 0}, "graph.leader.2", "must be > 0"),
    ("graph.leader", {1: -1.0}, "graph.leader.1", "must be > 0"),
    ("graph.leader", {1: "one"}, "graph.leader.1", "expected a number"),
    ("graph.edges", {"from": 1, "to": 2}, "graph.edges", "expected a list of {from, to, weight}"),
    ("graph.edges[1]", 7, "graph.edges[1]", "expected a mapping, got int"),
    ("graph.edges[1].from", DELETE, "graph.edges[1].from", "required field is missing"),
    ("graph.edges[1].to", DELETE, "graph.edges[1].to", "required field is missing"),
    ("graph.edges[1].to", 4, "graph.edges[1].to", "robot 4 does not exist (robots are 1..3)"),
    ("graph.edges[1].from", 0, "graph.edges[1].from", "robot 0 does not exist"),
    ("graph.edges[1].from", True, "graph.edges[1].from", "expected a robot number"),
    ("graph.edges[1].weight", 0, "graph.edges[1].weight", "must be > 0"),
    ("graph.edges[1].weight", -2.0, "graph.edges[1].weight", "must be > 0"),
    ("graph.edges[1].delay", 2, "graph.edges[1].delay", "unknown field"),
    ("graph.edges[1]", {"from": 3, "to": 3}, "graph.edges[1].to",
     "robot 3 cannot listen to itself"),
    ("graph.edges[1]", {"from": 1, "to": 2, "weight": 2.0}, "graph.edges[1]",
     "duplicate edge 1 -> 2"),
    ("graph.kind", "tree", "graph.kind", "unknown field"),
]


@pytest.mark.parametrize(("path", "value", "field", "why"), GRAPH,
                         ids=[f"{g[2]}-{g[3]}" for g in GRAPH])
def test_graph_rules(path, value, field, why):
    refused(variant((path, value)), field, why)


def test_an_edge_in_each_direction_is_not_a_duplicate():
    sc = load(variant(("graph.edges[1]", {"from": 2, "to": 1})))
    assert sc.graph.adjacency[0, 1] == 1.0 and sc.graph.adjacency[1, 0] == 1.0


LAW = [
    ("law", 5, "law", "expected a mapping, got int"),
    ("law.kind", 10, "law.kind", "must be one of 9, 22, 23; got 10"),
    ("law.kind", 0, "law.kind", "must be one of 9, 22, 23"),
    ("law.kind", "9", "law.kind", "expected an integer"),
    ("law.memory", "sometimes", "law.memory", "must be one of feedforward, literal"),
    ("law.gain", -0.1, "law.gain", "must be >= 0"),
    ("law.gain", [0.1, 0.1], "law.gain", "expected one gain per robot (3), got 2"),
    ("law.gain", [0.1, -1.0, 0.1], "law.gain[1]", "must be >= 0"),
    ("law.gain_prime", "x", "law.gain_prime", "expected a number"),
    ("law.gain_prime", [0.1, 0.1, math.inf], "law.gain_prime[2]", "must be finite"),
    ("law.gain_heading", "estimated", "law.gain_heading", "must be one of measured, desired"),
    ("law.order", 2, "law.order", "unknown field"),
]


@pytest.mark.parametrize(("path", "value", "field", "why"), LAW,
                         ids=[f"{x[2]}-{x[3]}" for x in LAW])
def test_law_rules(path, value, field, why):
    refused(variant((path, value)), field, why)


@pytest.mark.parametrize("kind", [9, 22, 23])
def test_every_law_kind_loads(kind):
    assert load(variant(("law.kind", kind))).law.kind == kind


UNCERTAINTY = [
    ("uncertainty", [1], "uncertainty", "expected a mapping, got list"),
    ("uncertainty.initial_shift", [0.0, 0.0], "uncertainty.initial_shift",
     "expected a list of 3 numbers"),
    ("uncertainty.initial_shift", [-0.1, 0.0, 0.0], "uncertainty.initial_shift[0]",
     "must be >= 0"),
    ("uncertainty.initial_shift", [0.0, 0.0, "-1 deg"], "uncertainty.initial_shift[2]",
     "must be >= 0"),
    ("uncertainty.disturbance.fixed", [{}], "uncertainty.disturbance.fixed",
     "expected a list of 2 harmonics"),
    ("uncertainty.disturbance.fixed[0].offset", 1.0, "uncertainty.disturbance.fixed[0].offset",
     "unknown field"),
    ("uncertainty.disturbance.fixed[1]", 0.5, "uncertainty.disturbance.fixed[1]",
     "expected a mapping, got float"),
    ("uncertainty.disturbance.fixed[0].frequency", "fast",
     "uncertainty.disturbance.fixed[0].frequency", "expected a number"),
    ("uncertainty.disturbance.uniform", [0.01], "uncertainty.disturbance.uniform",
     "expected a list of 2 numbers"),
    ("uncertainty.disturbance.uniform", [0.01, -0.1], "uncertainty.disturbance.uniform[1]",
     "must be >= 0"),
    ("uncertainty.disturbance.colour", 1, "uncertainty.disturbance.colour", "unknown field"),
    ("uncertainty.noise.fixed", [{}, {}], "uncertainty.noise.fixed",
     "expected a list of 3 harmonics"),
    ("uncertainty.noise.fixed[2].amplitude", "big", "uncertainty.noise.fixed[2].amplitude",
     "expected a number (a number, or a string like '0.05 deg')"),
    ("uncertainty.noise.uniform", [0.0, 0.0, -1.0], "uncertainty.noise.uniform[2]",
     "must be >= 0"),
    ("uncertainty.noise.colour", 1, "uncertainty.noise.colour", "unknown field"),
    ("uncertainty.drift", 1, "uncertainty.drift", "unknown field"),
]


@pytest.mark.parametrize(("path", "value", "field", "why"), UNCERTAINTY,
                         ids=[f"{u[2]}-{u[3]}" for u in UNCERTAINTY])
def test_uncertainty_rules(path, value, field, why):
    refused(variant((path, value)), field, why)


DELAY = [
    ({"model": "gaussian"}, "delay.model", "must be one of none, fixed, uniform, table, paper"),
    ({"model": "fixed"}, "delay.samples", "required field is missing"),
    ({"model": "fixed", "samples": -1}, "delay.samples", "must be >= 0"),
    ({"model": "fixed", "samples": 1.5}, "delay.samples", "expected an integer"),
    ({"model": "uniform", "high": 2}, "delay.low", "required field is missing"),
    ({"model": "uniform", "low": -1, "high": 2}, "delay.low", "must be >= 0"),
    ({"model": "uniform", "low": 1}, "delay.high", "required field is missing"),
    # DelayModel's own rules, reached through the scenario
    ({"model": "uniform", "low": 3, "high": 1}, "delay", "uniform delay needs 0 <= low <= high"),
    ({"model": "table", "values": [-1, 2], "probabilities": [0.5, 0.5]}, "delay",
     "delays must be >= 0 samples"),
    ({"model": "table", "values": [1, 2], "probabilities": [0.5, 0.6]}, "delay",
     "delay probabilities must be >= 0 and sum to 1"),
    ({"model": "table", "values": [], "probabilities": []}, "delay",
     "a delay table needs as many probabilities as values"),
    # the scenario's table rules
    ({"model": "table", "probabilities": [1.0]}, "delay.values", "required field is missing"),
    ({"model": "table", "values": [1]}, "delay.probabilities", "required field is missing"),
    ({"model": "table", "values": "1, 2", "probabilities": [0.5, 0.5]}, "delay.values",
     "expected a list of delays in samples (integers)"),
    ({"model": "table", "values": [1.5, 2], "probabilities": [0.5, 0.5]}, "delay.values",
     "expected a list of delays in samples (integers)"),
    ({"model": "table", "values": [True, 2], "probabilities": [0.5, 0.5]}, "delay.values",
     "expected a list of delays in samples (integers)"),
    ({"model": "table", "values": [1, 1], "probabilities": [0.5, 0.5]}, "delay.values",
     "delay 1 is listed twice"),
    ({"model": "table", "values": [1, 2], "probabilities": [1.0]}, "delay.probabilities",
     "expected one probability per value"),
    ({"model": "table", "values": [1, 2], "probabilities": [-0.5, 1.5]}, "delay.probabilities[0]",
     "must be >= 0"),
    ({"model": "paper", "leader_link": "yes"}, "delay.leader_link", "expected true or false"),
    ({"model": "paper", "jitter": 1}, "delay.jitter", "unknown field"),
]


@pytest.mark.parametrize(("section", "field", "why"), DELAY,
                         ids=[f"{d[1]}-{d[2]}" for d in DELAY])
def test_delay_rules(section, field, why):
    refused(variant(("delay", section)), field, why)


@pytest.mark.parametrize("section", [
    {"model": "fixed", "samples": "N"},
    {"model": "uniform", "low": 0, "high": "N"},
    {"model": "table", "values": [0, "N"], "probabilities": [0.5, 0.5]},
])
def test_a_delay_of_the_whole_trial_is_accepted_one_more_is_refused(section):
    """Boundary: tau = samples (T) is a valid delay (eq. 11 allows 0 <= tau <= T), T + 1
    is not."""
    n_t = RULES_BASE["samples"]

    def with_delay(d):
        s = {k: (d if v == "N" else [d if x == "N" else x for x in v] if isinstance(v, list)
                 else v) for k, v in section.items()}
        return variant(("delay", s))

    assert load(with_delay(n_t)).uncertainty.delay.max_delay == n_t
    refused(with_delay(n_t + 1), "delay",
            f"delays of up to {n_t + 1} samples exceed the trial ({n_t} samples)")


def test_load_scenario_errors(tmp_path):
    with pytest.raises(ScenarioError) as exc:
        load_scenario(tmp_path / "absent.yaml")
    assert str(exc.value).startswith(f"{tmp_path / 'absent.yaml'}: cannot read: ")
    with pytest.raises(ScenarioError) as exc:
        load_scenario("no-such-scenario")
    assert str(exc.value).startswith("no-such-scenario: no such scenario file, and not a "
                                     "built-in scenario (built-in: ")
