import numpy as np
import pytest

from formation_ilc.config.scenario import load_scenario
from formation_ilc.core import trajectory as tr
from formation_ilc.core.kinematics import heading_from_quaternion, quaternion_from_heading, rollout
from formation_ilc.core.kinematics import step as kstep


@pytest.mark.parametrize("name", ["paper-hexagon6", "paper-triangle3"])
def test_replaying_desired_input_reproduces_desired_output(name):
    sc = load_scenario(name)
    d = sc.desired
    xi = rollout(d.xi0, d.u, sc.dt)
    np.testing.assert_allclose(xi, d.eta, atol=1e-11)
    # positions are r + d_i exactly; headings are continuous (unwrapped)
    assert np.abs(np.diff(d.eta[..., 2], axis=1)).max() < 0.5


def test_nonholonomic_constraint_eq2_holds_on_desired_paths():
    sc = load_scenario("paper-hexagon6")
    eta = sc.desired.eta
    dx = np.diff(eta[..., 0], axis=1)
    dy = np.diff(eta[..., 1], axis=1)
    th = eta[:, :-1, 2]
    np.testing.assert_allclose(dx * np.sin(th) - dy * np.cos(th), 0, atol=1e-12)


def test_hexagon_offsets_in_world_frame_scale_with_s():
    sc = load_scenario("paper-hexagon6")
    eta = sc.desired.eta
    r = sc.reference[: eta.shape[1]]
    t = np.arange(eta.shape[1]) * sc.dt
    s = 1 + 0.5 * np.sin(4 * np.pi * t / 45)
    for i in range(6):
        ang = i * np.pi / 3
        np.testing.assert_allclose(eta[i, :, 0] - r[:, 0], s * np.cos(ang), atol=1e-12)
        np.testing.assert_allclose(eta[i, :, 1] - r[:, 1], s * np.sin(ang), atol=1e-12)


def test_triangle_offsets_in_leader_body_frame():
    sc = load_scenario("paper-triangle3")
    eta, r = sc.desired.eta, sc.reference
    m = eta.shape[1]
    sec = np.arange(m) * sc.dt
    d1 = 1 + 0.2 * np.cos(2 * np.pi * sec / 28)
    d2 = 0.6 + 0.1 * np.cos(2 * np.pi * sec / 28)
    c, s = np.cos(r[:m, 2]), np.sin(r[:m, 2])
    np.testing.assert_allclose(eta[0, :, 0] - r[:m, 0], d1 * c, atol=1e-12)
    np.testing.assert_allclose(eta[1, :, 1] - r[:m, 1], d2 * c, atol=1e-12)  # left: +y body
    np.testing.assert_allclose(eta[2, :, 0] - r[:m, 0], d2 * s, atol=1e-12)  # right: -y body


def test_paper_ivb_speed_erratum_fixed():
    v = tr.paper_ivb_speed(np.array([0, 20, 60, 120, 140, 150]))
    np.testing.assert_allclose(v, [0, 0.35, 0.35, 0.35, 0, 0], atol=1e-12)


def test_leader_circle_radius():
    m = 200
    v = lambda t: np.full(np.shape(t), 0.35)  # noqa: E731
    w = lambda t: np.full(np.shape(t), 0.35 / 1.5)  # noqa: E731
    r = tr.unicycle_reference(v, w, m, 0.2)
    np.testing.assert_allclose(np.hypot(r[:, 0], r[:, 1] - 1.5), 1.5, atol=1e-9)


def test_headings_unwrap_across_pi_and_back_up_on_reversal():
    ang = np.linspace(0, 4 * np.pi, 200)
    circle = np.column_stack([np.cos(ang), np.sin(ang)])
    th = tr.path_headings(circle)
    assert th[-1] - th[0] > 3.9 * np.pi  # unwrapped: two full turns
    # a path that goes forward then straight back: the robot backs up, no spin on the spot
    p = np.column_stack([np.r_[np.arange(10.0), np.arange(8.0, -1, -1)], np.zeros(19)])
    th, sign = tr.path_headings_signed(p)
    np.testing.assert_allclose(th, 0.0)
    assert (sign[:9] == 1).all() and (sign[9:] == -1).all()


def test_waypoints_and_samples_are_trackable():
    ref = tr.waypoint_reference(np.array([0.0, 5.0, 10.0]), np.array([[0, 0], [5, 0], [5, 5]]),
                                102, 0.1)
    pos = tr.formation_positions(ref, np.array([[0.0, 0.5], [0.0, -0.5]]),
                                 [tr.Sinusoid(), tr.Sinusoid()], 0.1, "leader")
    d = tr.desired_trajectories(pos, 0.1, ref)
    np.testing.assert_allclose(rollout(d.xi0, d.u, 0.1), d.eta, atol=1e-11)


def test_batch_step_equals_per_robot_step():
    rng = np.random.default_rng(3)
    xi = rng.normal(size=(5, 3))
    u = rng.normal(size=(5, 2))
    dist = rng.normal(size=(5, 2))
    batch = kstep(xi, u, 0.1, dist)
    for i in range(5):
        np.testing.assert_allclose(batch[i], kstep(xi[i], u[i], 0.1, dist[i]), rtol=0, atol=0)


@pytest.mark.parametrize("theta", [0.0, 1.0, np.pi, -np.pi + 1e-9, 3.5, -7.0, 20.0])
def test_quaternion_round_trip_unwraps_next_to_previous(theta):
    q = quaternion_from_heading(theta)
    back = heading_from_quaternion(q[2], q[3], previous=theta + 0.1)
    assert back == pytest.approx(theta, abs=1e-12)
