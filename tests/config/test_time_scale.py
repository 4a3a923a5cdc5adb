"""The scenario's ``desired`` section: heading rule and time scale."""

import numpy as np
import pytest

from formation_ilc.config.runconfig import RunConfig
from formation_ilc.config.scenario import ScenarioError, load_scenario, scenario_from_text

TRI = load_scenario("paper-triangle3")


def test_stretched_triangle_is_the_same_path_slower():
    slow = TRI.with_options(time_scale=2.0)
    assert slow.samples == 280 and slow.dt == TRI.dt and slow.time_scale == 2.0
    # every other sample of the stretched plan is the original one
    np.testing.assert_allclose(slow.desired.eta[:, ::2, :2], TRI.desired.eta[..., :2],
                               atol=1e-6)
    assert np.abs(slow.desired.u[..., 0]).max() == pytest.approx(
        np.abs(TRI.desired.u[..., 0]).max() / 2, rel=1e-3)


def test_time_scale_in_the_file_and_on_the_command_line():
    text = TRI.text + "\ndesired:\n  headings: arc\n  time_scale: 1.5\n"
    sc = scenario_from_text(text, "t.yaml")
    assert (sc.samples, sc.headings, sc.heading_rule) == (210, "arc", "arc")
    assert scenario_from_text(text, "t.yaml", time_scale=1.0).samples == 140
    cfg = RunConfig.from_json(RunConfig(sc.with_options(time_scale=2.5)).to_json())
    assert (cfg.scenario.samples, cfg.scenario.headings) == (350, "arc")


@pytest.mark.parametrize("field, msg", [
    ("time_scale: 0.5", "desired.time_scale: must be in \\[1, 20\\]"),
    ("time_scale: 0", "desired.time_scale: must be > 0"),
    ("headings: tangent", "desired.headings: must be one of auto, chord, arc"),
    ("speed: 2", "desired.speed: unknown field"),
])
def test_bad_desired_fields(field, msg):
    with pytest.raises(ScenarioError, match=msg):
        scenario_from_text(TRI.text + f"\ndesired:\n  {field}\n", "t.yaml")


def test_sampled_reference_is_not_stretched():
    text = """\
name: s
dt: 0.1
samples: 3
robots: 1
reference: {kind: samples, points: [[0, 0], [1, 0], [2, 0], [3, 0]]}
formation: {frame: world, offsets: {1: {x: 0, y: 0}}}
graph: {leader: {1: 1.0}}
desired: {time_scale: 2}
"""
    with pytest.raises(ScenarioError, match="reference.kind: a sampled reference cannot be "
                                            "stretched"):
        scenario_from_text(text, "s.yaml")


def test_a_new_time_scale_keeps_the_overrides_already_applied():
    """simulate applies --trials, --seed, --no-noise, --no-delay, --law, then --time-scale,
    which reads the scenario's text again: the overrides must survive that (they were
    lost: `simulate paper-triangle3 --trials 7 --time-scale 1.25` ran the file's 300)."""
    assert TRI.uncertainty.noisy and TRI.uncertainty.delay.kind != "none"
    bare = TRI.with_options(trials=7, seed=5, noise=False, delay=False, law=22,
                            memory="feedback")
    slow = bare.with_options(time_scale=1.25)
    assert slow.time_scale == 1.25 and slow.samples > TRI.samples
    assert (slow.trials, slow.seed) == (7, 5)
    assert not slow.uncertainty.noisy and slow.uncertainty.delay.kind == "none"
    assert (slow.law.kind, slow.law.memory) == (22, "feedback")
    # and an override given with the time scale still wins
    again = slow.with_options(time_scale=1.5, trials=9)
    assert (again.trials, again.seed, again.time_scale) == (9, 5, 1.5)
    # a copy that kept its noise keeps it
    assert TRI.with_options(time_scale=1.25).uncertainty.noisy
