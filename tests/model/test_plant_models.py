"""The batch simulator's exact-arc plant model and the desired headings that fit it."""

import numpy as np
import pytest

from formation_ilc.config.scenario import load_scenario
from formation_ilc.model.simulate import Problem, simulate


@pytest.fixture(scope="module")
def quiet():
    return load_scenario("paper-triangle3").with_options(noise=False, delay=False, trials=100)


def floor(sc, plant, headings):
    s = sc.with_options(headings=headings)
    res = simulate(s, problem=Problem.from_scenario(s, plant))
    return float(res.column("max_position_error")[-10:].mean())


def test_arc_plant_needs_arc_headings(quiet):
    euler = floor(quiet, "euler", "chord")
    arc_arc = floor(quiet, "arc", "arc")
    arc_chord = floor(quiet, "arc", "chord")
    # arc headings on the arc plant learn as chord headings on the Euler plant ...
    assert arc_arc == pytest.approx(euler, rel=0.1)
    # ... chord headings on an arc plant leave a floor the gains cannot see
    assert arc_chord > 2 * arc_arc


def test_default_plant_and_auto_headings_unchanged(quiet):
    a = simulate(quiet)
    b = simulate(quiet, problem=Problem.from_scenario(quiet.with_options(headings="chord")))
    np.testing.assert_array_equal(a.metrics, b.metrics)
    # 'auto' reads as arc on the arc plant
    c = simulate(quiet, plant="arc")
    d = simulate(quiet.with_options(headings="arc"),
                 problem=Problem.from_scenario(quiet.with_options(headings="arc"), "arc"))
    np.testing.assert_array_equal(c.metrics, d.metrics)
    with pytest.raises(ValueError, match="plant model must be one of"):
        Problem.from_scenario(quiet, "rk4")
