"""Edges of the unicycle model (eq. 1) and of the heading <-> quaternion helpers."""

import numpy as np

from formation_ilc.core.kinematics import (
    heading_from_quaternion,
    quaternion_from_heading,
    rollout,
    step,
    step_into,
    wrap_angle,
)


def test_step_into_updates_every_robot_of_a_batch_like_step():
    rng = np.random.default_rng(3)
    xi = rng.normal(size=(5, 3))  # more robots than state components
    u = rng.normal(size=(5, 2))
    dist = rng.normal(size=(5, 2))
    out = np.full((5, 3), np.nan)
    step_into(xi, u, dist, 0.2, out)
    np.testing.assert_allclose(out, step(xi, u, 0.2, dist), rtol=0, atol=1e-15)
    # by hand for robot 4: x += dt cos(th) (v + dv), th += dt (w + dw)
    v = u[4, 0] + dist[4, 0]
    assert out[4, 0] == xi[4, 0] + 0.2 * np.cos(xi[4, 2]) * v
    assert out[4, 1] == xi[4, 1] + 0.2 * np.sin(xi[4, 2]) * v
    assert out[4, 2] == xi[4, 2] + 0.2 * (u[4, 1] + dist[4, 1])


def test_step_broadcasts_one_state_over_a_batch_of_inputs():
    xi = np.array([1.0, 2.0, 0.5])
    u = np.array([[1.0, 0.0], [0.0, 1.0], [2.0, -1.0], [0.5, 0.5]])
    out = step(xi, u, 0.1)
    assert out.shape == (4, 3)
    np.testing.assert_allclose(out[2], [1.0 + 0.2 * np.cos(0.5), 2.0 + 0.2 * np.sin(0.5), 0.4])
    np.testing.assert_allclose(step(xi, u[0], 0.1), out[0])


def test_rollout_with_a_disturbance_equals_steps_with_it():
    rng = np.random.default_rng(4)
    xi0 = rng.normal(size=(2, 3))
    u = rng.normal(size=(2, 6, 2))
    dist = rng.normal(size=(2, 6, 2))
    xi = rollout(xi0, u, 0.2, dist)
    x = xi0
    for t in range(6):
        x = step(x, u[:, t], 0.2, dist[:, t])
        np.testing.assert_allclose(xi[:, t + 1], x, atol=1e-15)
    assert not np.allclose(xi, rollout(xi0, u, 0.2))


def test_quaternion_is_a_pure_yaw():
    for th in (0.0, 0.3, -2.0, np.pi):
        q = quaternion_from_heading(th)
        assert q[0] == 0.0 and q[1] == 0.0
        assert q[2] == np.sin(th / 2) and q[3] == np.cos(th / 2)
        assert abs(np.linalg.norm(q) - 1.0) < 1e-15


def test_heading_from_quaternion_wraps_or_unwraps_next_to_previous():
    z, w = np.sin(3.0 / 2), np.cos(3.0 / 2)
    assert abs(heading_from_quaternion(z, w) - 3.0) < 1e-12
    q = quaternion_from_heading(3.5)  # past pi: wrapped without a previous heading
    assert abs(heading_from_quaternion(q[2], q[3]) - (3.5 - 2 * np.pi)) < 1e-12
    assert abs(heading_from_quaternion(q[2], q[3], previous=3.4) - 3.5) < 1e-12
    assert abs(heading_from_quaternion(q[2], q[3], previous=3.4 + 4 * np.pi)
               - (3.5 + 4 * np.pi)) < 1e-12


def test_wrap_angle_range_is_half_open():
    assert wrap_angle(np.pi) == np.pi
    assert abs(wrap_angle(-np.pi) - np.pi) < 1e-15
    assert abs(wrap_angle(3 * np.pi / 2) + np.pi / 2) < 1e-15
    assert abs(wrap_angle(-7.0) - (-7.0 + 2 * np.pi)) < 1e-15
