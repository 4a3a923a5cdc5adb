"""Footprint clearance, and the batch simulator's prediction of contact."""

import numpy as np
import pytest

from formation_ilc.config.scenario import load_scenario
from formation_ilc.model.footprint import (
    Footprint,
    clearance,
    first_overlap,
    predict_clearance,
    trial_clearance,
)
from formation_ilc.model.simulate import simulate

P3DX = Footprint(0.455, 0.381)


@pytest.mark.parametrize("b, expect", [
    ((1.0, 0.0, 0.0), 0.5),           # side by side, 0.5 m apart
    ((0.4, 0.0, 0.0), -0.1),          # overlapping by 0.1 m
    ((1.0, 1.0, np.pi / 4), (1.646 - 0.5) / np.sqrt(2)),  # corner to a rotated edge
])
def test_clearance_of_squares(b, expect):
    xi = np.array([[[0.0, 0.0, 0.0]], [list(b)]])
    assert clearance(xi, Footprint(0.5, 0.5))[0, 0] == pytest.approx(expect, abs=1e-3)


def test_offset_moves_the_body():
    xi = np.array([[[0.0, 0.0, 0.0]], [[1.0, 0.0, np.pi]]])
    # both bodies 0.2 m ahead of their tracked points: they face each other, 0.4 m closer
    assert clearance(xi, Footprint(0.5, 0.5, 0.2))[0, 0] == pytest.approx(0.1)


def test_trial_clearance_names_pair_and_time():
    xi = np.zeros((3, 4, 3))
    xi[1, :, 1] = 2.0
    xi[2, :, 1] = [-2.0, -1.0, -0.3, -1.0]
    c = trial_clearance(7, xi, Footprint(0.5, 0.5))
    assert (c.robots, c.sample, c.overlapping) == ((1, 3), 2, 1)
    assert c.value == pytest.approx(-0.2)
    assert "robots 1 and 3 overlap by 0.200 m at t = 1.0 s" in c.line(0.5)


def test_cold_start_collides_warm_start_does_not():
    sc = load_scenario("paper-triangle3")
    cold = predict_clearance(sc, P3DX, 20)
    hit = first_overlap(cold)
    assert hit is not None and hit.trial == 1
    learned = simulate(sc.with_options(noise=False, delay=False, trials=100), plant="arc")
    warm = predict_clearance(sc, P3DX, 20, memory=learned.memory)
    assert first_overlap(warm) is None
    assert min(c.value for c in warm) > 0.2
