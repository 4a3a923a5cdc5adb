"""What a scenario file leaves out gets the documented default, each given field lands where
it belongs, and the command-line overrides (with_options) change only what they name.
(The validation rules, one per case: tests/config/test_scenario.py.)"""

import dataclasses

import numpy as np
import pytest

from formation_ilc.config.scenario import LawSettings, ScenarioError, scenario_from_text
from formation_ilc.core import trajectory as tr
from formation_ilc.core.delays import DelayModel
from formation_ilc.core.uncertainty import Harmonic

MINIMAL = """
name: m
dt: 0.5
samples: 4
robots: 2
reference: REF
formation:
  frame: world
  offsets: {1: {x: 1.0, y: 0.0}, 2: {x: 0.0, y: 1.0}}
graph: {leader: {1: 1.0}, edges: [{from: 1, to: 2}]}
"""


def load(ref="{kind: unicycle, speed: 0.5}", extra=""):
    return scenario_from_text(MINIMAL.replace("REF", ref) + extra)


def test_defaults_of_a_minimal_file():
    sc = load()
    assert (sc.trials, sc.seed, sc.description) == (100, 0, "")
    assert sc.law == LawSettings(9, "feedforward", (0.08, 0.08), (0.08, 0.08), "measured")
    assert LawSettings().kind == 9
    u = sc.uncertainty
    assert u.initial_shift == (0, 0, 0) and u.disturbance_uniform == (0, 0)
    assert u.noise_uniform == (0, 0, 0)
    assert u.disturbance_fixed == (Harmonic(0.0, 0.0, 0.0),) * 2
    assert u.noise_fixed == (Harmonic(0.0, 0.0, 0.0),) * 3
    assert u.delay == DelayModel() and u.delay_leader is True
    assert sc.scales == (tr.Sinusoid(1.0, 0.0, 0.0, 0.0),) * 2
    assert "text=" not in repr(sc)  # the file's text is kept, not printed


def test_unicycle_reference_start_and_turn():
    straight = load().reference
    np.testing.assert_allclose(straight[:, 1:], 0, atol=1e-15)  # from (0, 0, 0), no turn
    np.testing.assert_allclose(np.diff(straight[:, 0]), 0.25, atol=1e-12)
    start = load("{kind: unicycle, speed: 0.5, start: [1.0, 2.0, 90 deg]}").reference
    np.testing.assert_allclose(start[0], [1.0, 2.0, np.pi / 2])
    np.testing.assert_allclose(start[:, 0], 1.0, atol=1e-12)  # drives along +y
    for radius in (2.0, 1.0, -1.0):
        r = load(f"{{kind: unicycle, speed: 0.5, turn_radius: {radius}}}").reference
        np.testing.assert_allclose(np.diff(r[:, 2]), 0.5 / radius * 0.5, atol=1e-12)


def test_lemniscate_defaults_are_the_papers():
    got = load("{kind: lemniscate}").reference
    np.testing.assert_allclose(got, tr.paper_lemniscate(6, 0.5), atol=1e-15)
    other = load("{kind: lemniscate, x_amplitude: 1.0, y_amplitude: 2.0, period: 9.0}")
    np.testing.assert_allclose(other.reference, tr.paper_lemniscate(6, 0.5, 1.0, 2.0, 9.0))


def test_sampled_file_uses_its_first_two_columns(tmp_path):
    (tmp_path / "p.csv").write_text("# x, y, z\n" + "\n".join(
        f"{i}, {2 * i}, 99" for i in range(6)))
    sc = scenario_from_text(MINIMAL.replace("REF", "{kind: samples, file: p.csv}"),
                            base_dir=tmp_path)
    np.testing.assert_allclose(sc.reference[:, :2], [[i, 2 * i] for i in range(6)])
    (tmp_path / "one.csv").write_text("1, 2\n")
    with pytest.raises(ScenarioError, match="needs at least samples"):
        scenario_from_text(MINIMAL.replace("REF", "{kind: samples, file: one.csv}"),
                           base_dir=tmp_path)


def test_waypoints_close_in_time_and_too_few():
    sc = load("{kind: waypoints, times: [0, 0.5, 3], points: [[0, 0], [1, 0], [1, 1]]}")
    assert sc.reference[1, 0] == pytest.approx(1.0)
    with pytest.raises(ScenarioError, match="at least 2"):
        load("{kind: waypoints, times: [0], points: [[0, 0]]}")


def test_formation_scale_defaults_and_which_robot_gets_it():
    sc = scenario_from_text(MINIMAL.replace("REF", "{kind: unicycle, speed: 0.5}").replace(
        "offsets: {1: {x: 1.0, y: 0.0}, 2: {x: 0.0, y: 1.0}}",
        "scales: {D: {amplitude: 0.5, period: 2.0}}\n"
        "  offsets: {1: {x: 1.0, y: 0.0}, 2: {x: 0.0, y: 1.0, scale: D}}"))
    assert sc.scales[0] == tr.Sinusoid()
    assert sc.scales[1] == tr.Sinusoid(1.0, 0.5, 2.0, 0.0)
    with pytest.raises(ScenarioError, match=r"\(have: none\)"):
        scenario_from_text(MINIMAL.replace("REF", "{kind: unicycle, speed: 0.5}").replace(
            "2: {x: 0.0, y: 1.0}", "2: {x: 0.0, y: 1.0, scale: D}"))


def test_every_uncertainty_field_lands_in_its_place():
    sc = load(extra="""
uncertainty:
  initial_shift: [0.1, 0.2, 0.3]
  disturbance:
    fixed: [{amplitude: 1.0, frequency: 2.0, phase: 3.0}, {amplitude: 4.0}]
    uniform: [0.4, 0.5]
  noise:
    fixed: [{amplitude: 5.0}, {frequency: 6.0}, {phase: 7.0}]
    uniform: [0.6, 0.7, 0.8]
delay: {model: uniform, low: 0, high: 0, leader_link: false}
""")
    u = sc.uncertainty
    assert u.initial_shift == (0.1, 0.2, 0.3)
    assert u.disturbance_fixed == (Harmonic(1.0, 2.0, 3.0), Harmonic(4.0, 0.0, 0.0))
    assert u.disturbance_uniform == (0.4, 0.5)
    assert u.noise_fixed == (Harmonic(5.0, 0.0, 0.0), Harmonic(0.0, 6.0, 0.0),
                             Harmonic(0.0, 0.0, 7.0))
    assert u.noise_uniform == (0.6, 0.7, 0.8)
    assert u.delay == DelayModel("uniform", low=0, high=0) and u.delay_leader is False


def test_errors_name_the_first_unknown_field_and_the_first_repeated_delay():
    with pytest.raises(ScenarioError, match=r": aaa: unknown field"):
        load(extra="aaa: 1\nzzz: 2\n")
    with pytest.raises(ScenarioError, match="delay 1 is listed twice"):
        load(extra="delay: {model: table, values: [1, 1, 2, 2], "
                   "probabilities: [0.25, 0.25, 0.25, 0.25]}\n")


def test_with_options_changes_only_what_it_names():
    base = load(extra="law: {kind: 23, memory: literal}\n"
                      "uncertainty: {initial_shift: [0.1, 0.1, 0.1]}\n"
                      "delay: {model: fixed, samples: 1}\n")
    same = base.with_options()
    assert same == dataclasses.replace(base)
    assert same.uncertainty.noisy and same.uncertainty.delay.kind == "fixed"
    only_law = base.with_options(law=9)
    assert (only_law.law.kind, only_law.law.memory) == (9, "literal")
    only_memory = base.with_options(memory="feedforward")
    assert (only_memory.law.kind, only_memory.law.memory) == (23, "feedforward")
    quiet = base.with_options(noise=False)
    assert not quiet.uncertainty.noisy and quiet.uncertainty.delay.kind == "fixed"
    prompt = base.with_options(delay=False)
    assert prompt.uncertainty.noisy and prompt.uncertainty.delay.kind == "none"
    other = base.with_options(seed=11, trials=3)
    assert (other.seed, other.trials) == (11, 3) and other.law == base.law
    assert (same.seed, same.trials) == (0, 100)


def test_scenario_and_law_settings_are_frozen():
    sc = load()
    for obj in (sc, sc.law):
        with pytest.raises(dataclasses.FrozenInstanceError):
            obj.name = "x"  # type: ignore[union-attr]


def test_degrees_only_where_an_angle_is_expected_and_negative_start_allowed():
    with pytest.raises(ScenarioError, match=r"dt: expected a number, got '0\.1 deg'"):
        scenario_from_text(MINIMAL.replace("REF", "{kind: unicycle, speed: 0.5}").replace(
            "dt: 0.5", "dt: 0.1 deg"))
    with pytest.raises(ScenarioError, match=r"graph.leader.1: expected a number, got '1 deg'"):
        scenario_from_text(MINIMAL.replace("REF", "{kind: unicycle, speed: 0.5}").replace(
            "leader: {1: 1.0}", "leader: {1: 1 deg}"))
    sc = load("{kind: unicycle, speed: 0.5, start: [-1.0, -2.0, -10 deg]}")
    np.testing.assert_allclose(sc.reference[0], [-1.0, -2.0, -np.pi / 18])
    assert load().reference[0].tolist() == [0.0, 0.0, 0.0]


def test_scale_with_only_a_mean_is_constant():
    sc = scenario_from_text(MINIMAL.replace("REF", "{kind: unicycle, speed: 0.5}").replace(
        "offsets: {1: {x: 1.0, y: 0.0}, 2: {x: 0.0, y: 1.0}}",
        "scales: {D: {mean: 2.0}}\n  offsets: {1: {x: 1.0, y: 0.0, scale: D}, "
        "2: {x: 0.0, y: 1.0}}"))
    assert sc.scales[0] == tr.Sinusoid(2.0, 0.0, 0.0, 0.0)


def test_negative_uniform_delay_bound_names_its_field():
    with pytest.raises(ScenarioError, match=r"delay\.high: .*>= 0"):
        load(extra="delay: {model: uniform, low: 0, high: -1}\n")
