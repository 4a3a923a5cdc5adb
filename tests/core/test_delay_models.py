"""Delay models (pmf, draws, defaults, validation boundaries) and eq. (11)'s argument checks.
(Eq. 11 against a reference: tests/core/test_reference.py.)"""

import dataclasses

import numpy as np
import pytest

from formation_ilc.core.delays import DelayModel, measure_delay, measure_delay_ns


def test_defaults_are_no_delay():
    for m in (DelayModel(), DelayModel("fixed"), DelayModel("uniform")):
        assert m.max_delay == 0
        assert not m.draw(np.random.default_rng(0), (3, 4)).any()
    assert DelayModel().pmf() == {0: 1.0}
    assert DelayModel("fixed").pmf() == {0: 1.0}
    assert DelayModel("uniform").pmf() == {0: 1.0}
    with pytest.raises(dataclasses.FrozenInstanceError):
        DelayModel().samples = 2  # type: ignore[misc]


def test_pmfs():
    assert DelayModel("fixed", samples=3).pmf() == {3: 1.0}
    assert DelayModel("uniform", low=2, high=4).pmf() == pytest.approx({2: 1 / 3, 3: 1 / 3,
                                                                         4: 1 / 3})
    assert DelayModel("table", values=(1, 5), probabilities=(0.25, 0.75)).pmf() == {
        1: 0.25, 5: 0.75}
    assert DelayModel("table", values=(2, 7), probabilities=(0.5, 0.5)).max_delay == 7


def test_uniform_draws_cover_the_range_evenly():
    m = DelayModel("uniform", low=2, high=4)
    d = m.draw(np.random.default_rng(1), (30000,))
    assert d.dtype == np.int64 and d.min() == 2 and d.max() == 4
    np.testing.assert_allclose(np.bincount(d)[2:] / len(d), 1 / 3, atol=0.01)
    single = DelayModel("uniform", low=3, high=3).draw(np.random.default_rng(1), (50,))
    assert (single == 3).all()


def test_validation_boundaries():
    DelayModel("fixed", samples=0)
    DelayModel("uniform", low=0, high=0)
    DelayModel("uniform", low=2, high=2)
    DelayModel("table", values=(0, 1), probabilities=(0.0, 1.0))
    with pytest.raises(ValueError, match="fixed delay must be >= 0"):
        DelayModel("fixed", samples=-1)
    with pytest.raises(ValueError, match="0 <= low <= high"):
        DelayModel("uniform", low=-1, high=0)
    with pytest.raises(ValueError, match="as many probabilities as values"):
        DelayModel("table", values=(), probabilities=())
    with pytest.raises(ValueError, match="as many probabilities as values"):
        DelayModel("table", values=(1, 2), probabilities=(1.0,))
    with pytest.raises(ValueError, match="delays must be >= 0"):
        DelayModel("table", values=(-1, 1), probabilities=(0.5, 0.5))
    with pytest.raises(ValueError, match="sum to 1"):
        DelayModel("table", values=(1, 2), probabilities=(-0.5, 1.5))
    with pytest.raises(ValueError, match="unknown delay model"):
        DelayModel("gauss")


def test_measure_delay_refuses_a_non_positive_sample_time():
    for dt in (0.0, -0.5):
        with pytest.raises(ValueError, match="dt must be positive"):
            measure_delay(1.0, 0.0, dt)


def test_measure_delay_ns_is_an_exact_integer():
    got = measure_delay_ns(10**18 + 3, 10**18, 5)  # odd dt: rounding at half a sample
    assert type(got) is int and got == 1
    assert measure_delay_ns(7, 0, 5) == 1 and measure_delay_ns(8, 0, 5) == 2
