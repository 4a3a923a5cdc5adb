"""The draws of one trial are a contract shared by every process of the stack (the batch
simulator, the kinematic simulator, the link emulator): their order, ranges and shapes are
pinned here against the generator they come from."""

import dataclasses

import numpy as np
import pytest

from formation_ilc.core.delays import DelayModel
from formation_ilc.core.uncertainty import (
    DELAY_STREAM,
    PLANT_STREAM,
    Harmonic,
    TrialDraws,
    Uncertainty,
    trial_rng,
)

H = (Harmonic(0.1, 0.2, 0.3), Harmonic(0.4, 0.5, 0.6), Harmonic(0.7, 0.8, 0.9))
U = Uncertainty(initial_shift=(0.1, 0.2, 0.3), disturbance_fixed=H[:2],
                disturbance_uniform=(0.4, 0.5), noise_fixed=H, noise_uniform=(0.6, 0.7, 0.8),
                delay=DelayModel("uniform", low=1, high=3))


def test_streams_and_generator():
    assert (PLANT_STREAM, DELAY_STREAM) == (0, 1)
    a = trial_rng(4, 2, 1).random(3)
    np.testing.assert_array_equal(a, np.random.default_rng([4, 2, 1]).random(3))


def test_harmonic():
    t = np.arange(4.0)
    np.testing.assert_allclose(Harmonic(2.0, 0.5, 0.25)(t), 2.0 * np.sin(0.5 * t + 0.25))
    np.testing.assert_array_equal(Harmonic()(t), np.zeros(4))


def test_plant_draws_in_their_documented_order():
    shift, dist, noise = U.draw_plant(7, 3, 2, 5)
    rng = np.random.default_rng([7, 3, 0])
    np.testing.assert_array_equal(shift, rng.uniform(-1, 1, (2, 3)) * [0.1, 0.2, 0.3])
    d = rng.uniform(-1, 1, (2, 5, 2)) * [0.4, 0.5]
    n = rng.uniform(-1, 1, (2, 6, 3)) * [0.6, 0.7, 0.8]
    for c in range(2):
        d[..., c] += H[c](np.arange(5.0))
    for c in range(3):
        n[..., c] += H[c](np.arange(6.0))
    np.testing.assert_array_equal(dist, d)
    np.testing.assert_array_equal(noise, n)


def test_delay_draws_in_their_documented_order():
    tau, tau0 = U.draw_delays(7, 3, 2, 4, 5)
    assert tau.shape == (2, 4, 6) and tau0.shape == (2, 6)
    rng = np.random.default_rng([7, 3, 1])
    np.testing.assert_array_equal(tau, U.delay.draw(rng, (2, 4, 6)))
    np.testing.assert_array_equal(tau0, U.delay.draw(rng, (2, 6)))
    tau_b, tau0_b = dataclasses.replace(U, delay_leader=False).draw_delays(7, 3, 2, 4, 5)
    np.testing.assert_array_equal(tau_b, tau)
    assert tau0_b.shape == (2, 6) and tau0_b.dtype == np.int64 and not tau0_b.any()


def test_no_uncertainty_draws_nothing():
    u = Uncertainty()
    assert not u.noisy and u.delay_leader
    shift, dist, noise = u.draw_plant(1, 0, 3, 4)
    assert not shift.any() and not dist.any() and not noise.any()
    assert noise.shape == (3, 5, 3) and dist.shape == (3, 4, 2)


@pytest.mark.parametrize("field, value", [
    ("initial_shift", (0.0, 0.0, 0.1)), ("disturbance_uniform", (0.0, 0.1)),
    ("noise_uniform", (0.0, 0.0, 0.1)),
    ("disturbance_fixed", (Harmonic(), Harmonic(0.1))),
    ("noise_fixed", (Harmonic(), Harmonic(), Harmonic(0.1))),
])
def test_any_one_source_is_noisy(field, value):
    u = dataclasses.replace(Uncertainty(), **{field: value})
    assert u.noisy
    assert not u.without_noise().noisy
    assert u.without_delay().noisy


def test_without_keeps_the_other_half():
    q = U.without_noise()
    assert q.delay == U.delay and q.delay_leader == U.delay_leader and not q.noisy
    p = dataclasses.replace(U, delay_leader=False).without_delay()
    assert p.delay == DelayModel() and p.delay_leader is False
    assert (p.initial_shift, p.noise_fixed, p.noise_uniform) == (
        U.initial_shift, U.noise_fixed, U.noise_uniform)
    assert (p.disturbance_fixed, p.disturbance_uniform) == (
        U.disturbance_fixed, U.disturbance_uniform)


def test_value_types_are_frozen():
    for obj, field in ((Harmonic(), "amplitude"), (U, "delay_leader"),
                       (TrialDraws(*[np.zeros(1)] * 5), "shift")):
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(obj, field, 1)


def test_harmonic_defaults_leave_only_the_amplitude():
    t = np.arange(5.0)
    assert Harmonic(2.0)(t).tolist() == [0.0] * 5  # 2 sin(0 t + 0)
    np.testing.assert_allclose(Harmonic(2.0, phase=0.5)(t), 2 * np.sin(0.5))


def test_link_loss_must_be_a_probability_below_one():
    Uncertainty(link_loss=0.0)
    Uncertainty(link_loss=0.999)
    for bad in (-0.1, 1.0, 1.5):
        with pytest.raises(ValueError, match="link loss must be in"):
            Uncertainty(link_loss=bad)


def test_losses_come_from_stream_two_of_the_trial():
    """The loss stream is default_rng([seed, trial, 2]), apart from the plant (0) and delay
    (1) streams: a lossless scenario keeps the numbers it always drew."""
    from formation_ilc.core.links import LOST

    u = Uncertainty(delay=DelayModel("fixed", samples=1), link_loss=0.4)
    tau, _ = u.draw_delays(11, 3, 2, 2, 20)
    lost = np.random.default_rng([11, 3, 2]).random(tau.shape) < 0.4
    np.testing.assert_array_equal(tau == LOST, lost)
    np.testing.assert_array_equal(tau[~lost], 1)


def test_the_cached_draw_arguments_are_read_only():
    """plant_arrays / delay_arrays are cached per scenario: a caller must not be able to
    change what the next run gets."""
    from formation_ilc.core.uncertainty import delay_arrays, plant_arrays

    u = Uncertainty(initial_shift=(0.1, 0.2, 0.3), disturbance_fixed=H[:2], noise_fixed=H,
                    delay=DelayModel("table", values=(1, 2), probabilities=(0.5, 0.5)))
    for a in plant_arrays(u, 5):
        assert not a.flags.writeable
    d = delay_arrays(u)
    assert not d[4].flags.writeable and not d[5].flags.writeable
