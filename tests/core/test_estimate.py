"""The box of positions (``core.estimate``): it holds the truth, and it is tighter than a pose."""

from __future__ import annotations

import math

import numpy as np

from formation_ilc.core.estimate import box_centre, box_error, box_start, box_step
from formation_ilc.core.kinematics import arc_step


def _drive(seed: int, b: float, q: float, samples: int = 400, slip: float | None = None):
    """A unicycle driving a wandering arc, its poses with uniform noise ``b`` per axis,
    its motion off the told command by up to ``slip`` per axis (default ``q``); yields
    (true position, box row) per sample."""
    rng = np.random.default_rng(seed)
    slip = q if slip is None else slip
    dt = 0.2
    x, y, th = 0.0, 0.0, 0.3
    box = np.zeros((1, 4))
    box_start(box, 0, x + rng.uniform(-b, b), y + rng.uniform(-b, b), b)
    for _ in range(samples):
        v, w = rng.uniform(0.0, 0.6), rng.uniform(-0.5, 0.5)
        th_measured = th
        x, y, th = arc_step(x, y, th, v, w, dt)
        x += rng.uniform(-slip, slip)
        y += rng.uniform(-slip, slip)
        ok = box_step(box, 0, th_measured, v, w, dt, x + rng.uniform(-b, b),
                      y + rng.uniform(-b, b), b, q, 0.0)
        yield (x, y), box, ok


def test_the_box_holds_the_true_position_at_every_sample():
    b, q = 0.025, 0.004
    for seed in range(5):
        for (x, y), box, ok in _drive(seed, b, q):
            assert ok
            assert box[0, 0] - 1e-12 <= x <= box[0, 1] + 1e-12
            assert box[0, 2] - 1e-12 <= y <= box[0, 3] + 1e-12


def test_the_estimate_is_tighter_than_one_pose():
    """With the paper's uniform noise (0.025 m per axis) and 4 mm of motion per sample
    unknown, the box's half-diagonal averages well under a single pose's hypot(b, b) and
    never exceeds it; its centre is nearer the truth than the poses are."""
    b, q = 0.025, 0.004
    errors, centre_off = [], []
    for (x, y), box, _ in _drive(7, b, q, samples=2000):
        errors.append(box_error(box, 0))
        cx, cy = box_centre(box, 0)
        centre_off.append(math.hypot(cx - x, cy - y))
    errors = np.array(errors[20:])
    assert errors.max() <= math.hypot(b, b) + 1e-12
    assert errors.mean() < 0.7 * math.hypot(b, b)
    # a raw pose is off by hypot of two uniforms: about 0.0204 m on average
    assert np.mean(centre_off[20:]) < 0.8 * 0.0204


def test_a_pose_the_box_misses_starts_it_afresh():
    """A robot that does not move as it told (pushed 0.3 m aside) lands outside its moved
    box: the step says so and the box is the new pose's own."""
    box = np.zeros((1, 4))
    box_start(box, 0, 0.0, 0.0, 0.02)
    ok = box_step(box, 0, 0.0, 0.5, 0.0, 0.2, 0.1, 0.3, 0.02, 0.004, 0.0)
    assert not ok
    np.testing.assert_allclose(box[0], [0.08, 0.12, 0.28, 0.32])


def test_a_wrong_bound_is_caught_when_the_motion_leaves_it_far_behind():
    """A process bound too small for the robot's real slip makes poses miss the box (the
    step returns False), so a body that does not move as told is noticed, not trusted."""
    misses = sum(not ok for _, _, ok in _drive(3, 0.01, 0.0005, samples=300, slip=0.03))
    assert misses > 10
