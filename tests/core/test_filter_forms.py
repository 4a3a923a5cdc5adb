"""The safety filter's two forms give the same bits: ``filter_command`` as plain Python (what
a robot node runs; it reads its arrays through ``_jit.floats`` as Python numbers) and
compiled (``.jit``, the batch simulator's), over varied calls: 1 to 3 discs, told and
estimated motion, old poses, robots near, far and overlapping, commands in and out of the
box. ``scripts/check_filter_same.py`` compares a change against another revision so."""

from __future__ import annotations

import math

import numpy as np
import pytest

from formation_ilc.core._jit import floats
from formation_ilc.core.safety import OTHER_FIELDS, filter_command
from formation_ilc.model.physics import MODELS
from formation_ilc.model.safety import spec_for


def _specs() -> list[np.ndarray]:
    p3, husky = MODELS["p3dx"], MODELS["husky"]
    return [spec_for(p3.footprint, p3.limits, 0.1).params(),
            spec_for(p3.footprint, p3.limits, 0.2, discs=1).params(),
            spec_for(p3.footprint, p3.limits, 0.1, discs=3, pose_jitter=0.005).params(),
            spec_for(p3.footprint, p3.limits, 0.1, commands=True, heading_error=0.03,
                     noise=0.01, process=0.005).params(),
            spec_for(husky.footprint, husky.limits, 0.05, stale_speed=0.0).params()]


def _calls(count: int, seed: int = 11) -> list[tuple]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(count):
        n = int(rng.integers(1, 7))
        others = np.zeros((n + 1, OTHER_FIELDS))  # a row more than heard: not read
        others[:n, 0:2] = rng.normal(scale=rng.choice([0.6, 1.5, 4.0]), size=(n, 2))
        others[:n, 2] = rng.uniform(-math.pi, math.pi, n)
        others[:n, 3:5] = rng.normal(scale=0.3, size=(n, 2))
        others[:n, 5] = rng.normal(scale=0.5, size=n)
        others[:n, 6] = rng.random(n) < 0.5
        others[:n, 7] = rng.choice([0.0, 0.02], size=n)
        ages = rng.choice([0.0, 0.1, 0.25], size=n + 1)
        prev = rng.uniform(-1.0, 1.4), rng.uniform(-2.0, 2.0)
        step = rng.choice([0.02, 0.3])
        out.append((i % 5, prev[0] + rng.normal(scale=step),
                    prev[1] + rng.normal(scale=3 * step), rng.normal(scale=0.1),
                    rng.normal(scale=0.1), rng.uniform(-math.pi, math.pi), *prev, others,
                    ages, n))
    return out


def test_floats_are_the_arrays_numbers_read_by_index():
    a = np.arange(6.0).reshape(2, 3) / 7.0
    rows = floats(a)
    assert [[type(x) for x in row] for row in rows] == [[float] * 3] * 2
    assert all(rows[j][i] == a[j, i] for j in range(2) for i in range(3))


@pytest.mark.parametrize("seed", [11, 12])
def test_the_plain_and_the_compiled_filter_give_the_same_bits(seed):
    params = _specs()
    calls = _calls(300, seed)
    plain, comp = np.zeros((len(calls), 2)), np.zeros((len(calls), 2))
    flags = []
    for i, (s, *args) in enumerate(calls):
        flags.append((filter_command(*args, params[s], plain[i]),
                      filter_command.jit(*args, params[s], comp[i])))
    assert all(a == b for a, b in flags)
    assert np.array_equal(plain, comp)
    assert len({f for f, _ in flags}) >= 4  # the calls reach passes, barriers, infeasible
