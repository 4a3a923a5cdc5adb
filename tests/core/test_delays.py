import numpy as np
import pytest

from formation_ilc.core.delays import DelayModel, measure_delay, measure_delay_ns, measure_delays


@pytest.mark.parametrize(
    ("lag_in_dt", "expected"),
    [(0.0, 0), (0.49, 0), (0.5, 1), (0.51, 1), (1.0, 1), (1.49, 1), (1.5, 2), (2.5, 3),
     (3.0, 3), (-0.3, 0), (-2.0, 0)],
)
def test_eq11_rounds_half_up(lag_in_dt, expected):
    dt_ns = 100_000_000
    st = 12 * dt_ns
    rt = st + round(lag_in_dt * dt_ns)
    assert measure_delay_ns(rt, st, dt_ns) == expected
    # floats: exact where the boundary is representable
    assert measure_delay(2.0 + lag_in_dt * 0.25, 2.0, 0.25) == expected


def test_eq11_vectorised_matches_scalar():
    rng = np.random.default_rng(0)
    st = rng.uniform(0, 10, 100)
    rt = st + rng.uniform(-0.1, 0.5, 100)
    v = measure_delays(rt, st, 0.1)
    assert [measure_delay(a, b, 0.1) for a, b in zip(rt, st, strict=True)] == v.tolist()


def test_paper_delay_table_frequencies():
    m = DelayModel.paper()
    d = m.draw(np.random.default_rng(1), (200_000,))
    freq = np.bincount(d, minlength=5)[1:] / d.size
    np.testing.assert_allclose(freq, [0.15, 0.30, 0.35, 0.20], atol=0.005)
    assert m.max_delay == 4


def test_other_delay_models():
    rng = np.random.default_rng(2)
    assert (DelayModel("none").draw(rng, (5,)) == 0).all()
    assert (DelayModel("fixed", samples=3).draw(rng, (5,)) == 3).all()
    u = DelayModel("uniform", low=1, high=3).draw(rng, (30_000,))
    assert set(np.unique(u)) == {1, 2, 3}
    np.testing.assert_allclose(np.bincount(u)[1:] / u.size, 1 / 3, atol=0.01)


@pytest.mark.parametrize("kwargs", [dict(kind="bogus"), dict(kind="uniform", low=3, high=1),
                                    dict(kind="table", values=(1, 2), probabilities=(0.5,)),
                                    dict(kind="table", values=(1, 2), probabilities=(0.5, 0.6))])
def test_bad_delay_models_are_refused(kwargs):
    with pytest.raises(ValueError):
        DelayModel(**kwargs)
