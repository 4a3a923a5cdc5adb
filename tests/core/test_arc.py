"""Arc-consistent desired headings and the exact-arc unicycle."""

import numpy as np
import pytest

from formation_ilc.config.scenario import load_scenario
from formation_ilc.core import trajectory as tr
from formation_ilc.core.kinematics import arc_step, unicycle_step


def replay(d, stepf, dt):
    """Largest position gap between u_d replayed through ``stepf`` and eta_d."""
    worst = 0.0
    for r in range(d.eta.shape[0]):
        x = d.eta[r, 0].copy()
        for t in range(d.u.shape[1]):
            x = np.array(stepf(*x, *d.u[r, t], dt))
            worst = max(worst, float(np.hypot(*(x[:2] - d.eta[r, t + 1, :2]))))
    return worst


@pytest.fixture(scope="module")
def positions():
    sc = load_scenario("paper-triangle3")
    pos = tr.formation_positions(sc.reference, sc.offsets, list(sc.scales), sc.dt, sc.frame)
    return sc, pos


def test_each_heading_rule_fits_its_plant(positions):
    sc, pos = positions
    chord = tr.desired_trajectories(pos, sc.dt, sc.reference)
    arc = tr.desired_trajectories(pos, sc.dt, sc.reference, "arc")
    assert replay(chord, unicycle_step, sc.dt) < 1e-12
    assert replay(arc, arc_step, sc.dt) < 2e-3
    # the other plant drifts sideways: the mismatch the option removes
    assert replay(chord, arc_step, sc.dt) > 20 * replay(arc, arc_step, sc.dt)
    np.testing.assert_array_equal(arc.eta[..., :2], chord.eta[..., :2])
    assert not np.allclose(arc.eta[..., 2], chord.eta[..., 2])


def test_default_is_chord(positions):
    sc, pos = positions
    a = tr.desired_trajectories(pos, sc.dt, sc.reference)
    b = tr.desired_trajectories(pos, sc.dt, sc.reference, "chord")
    np.testing.assert_array_equal(a.eta, b.eta)
    np.testing.assert_array_equal(a.u, b.u)
    with pytest.raises(ValueError, match="headings must be one of"):
        tr.desired_trajectories(pos, sc.dt, sc.reference, "tangent")


def test_arc_headings_on_a_circle():
    # chords of a circle turn by a constant step: the arc heading is half a step back
    chord = np.array([[0.0, 0.1, 0.2, 0.3]])
    np.testing.assert_allclose(tr.arc_headings(chord), [[-0.05, 0.05, 0.15, 0.25]])


def test_arc_step_is_exact_on_a_circle():
    # v = 1, w = 1 from the origin heading +x: a circle of radius 1 about (0, 1)
    x, y, th = arc_step(0.0, 0.0, 0.0, 1.0, 1.0, np.pi / 2)
    assert (x, y, th) == pytest.approx((1.0, 1.0, np.pi / 2))
    assert arc_step(0.0, 0.0, 0.3, 2.0, 0.0, 0.5) == pytest.approx(
        unicycle_step(0.0, 0.0, 0.3, 2.0, 0.0, 0.5))
