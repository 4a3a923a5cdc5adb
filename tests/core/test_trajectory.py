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


# ----------------------------------------------------------------------------------------
# trajectory.py on small paths with closed forms: scales, tangents (stand-stills,
# reversing), the paper's references, the leader's integration, sampled and waypoint
# paths, offsets.

def test_sinusoid_and_its_constant_cases():
    s = np.array([0.0, 0.7, 3.1])
    f = tr.Sinusoid(mean=1.5, amplitude=0.5, period=4.0, phase=0.3)
    np.testing.assert_allclose(f(s), 1.5 + 0.5 * np.sin(2 * np.pi * s / 4.0 + 0.3), atol=1e-15)
    for const in (tr.Sinusoid(2.0, 0.5, 0.0), tr.Sinusoid(2.0, 0.5, -1.0),
                  tr.Sinusoid(2.0, 0.0, 4.0)):
        np.testing.assert_array_equal(const(s), [2.0, 2.0, 2.0])
    assert tr.Sinusoid()(s).tolist() == [1.0, 1.0, 1.0]
    tiny = tr.Sinusoid(0.0, 1.0, 1e-9)  # a positive period, however short, is a sinusoid
    assert tiny(np.array([0.25e-9]))[0] == pytest.approx(1.0)


def test_tangent_keeps_the_heading_through_stand_stills():
    p = np.array([[0, 0], [0, 0], [1, 0], [1, 0], [1, 1], [1, 1 + 1e-14], [1, 2]], float)
    # steps: still, +x, still, +y, ~still (1e-14 of a 1 m path), +y
    np.testing.assert_allclose(tr.path_headings(p, fallback=5.0),
                               [0, 0, 0, np.pi / 2, np.pi / 2, np.pi / 2], atol=1e-15)
    np.testing.assert_array_equal(tr.path_headings(np.zeros((4, 2)), fallback=0.7),
                                  [0.7, 0.7, 0.7])
    # a very short path is still a path: the threshold is relative to the longest step
    small = np.array([[0, 0], [0, 1e-6], [-1e-6, 1e-6]])
    np.testing.assert_allclose(tr.path_headings(small), [np.pi / 2, np.pi], atol=1e-12)


def test_tangent_headings_are_unwrapped():
    ang = np.linspace(0, 3 * np.pi, 40)
    p = np.column_stack([np.cos(ang), np.sin(ang)])
    th = tr.path_headings(p)
    assert th[-1] > 3 * np.pi and np.all(np.diff(th) > 0)


def test_signed_headings_back_up_instead_of_turning():
    # right, right, then back by half a step: the robot backs up, facing +x
    p = np.array([[0, 0], [1, 0], [2, 0], [1.5, 0]], float)
    th, sign = tr.path_headings_signed(p)
    np.testing.assert_allclose(th, [0, 0, 0], atol=1e-15)
    np.testing.assert_array_equal(sign, [1, 1, -1])
    # the anchor (longest step) is the last one: the steps before it are walked backwards
    q = np.array([[0.5, 0], [0, 0], [2, 0]], float)
    th, sign = tr.path_headings_signed(q)
    np.testing.assert_allclose(th, [0, 0], atol=1e-15)
    np.testing.assert_array_equal(sign, [-1, 1])
    np.testing.assert_allclose(tr.path_headings(q, reverse=True), th)
    np.testing.assert_allclose(tr.path_headings(q), [np.pi, 0], atol=1e-15)
    # a genuine turn (less than pi/2 off the neighbour) is driven forwards
    r = np.array([[0, 0], [1, 0], [2, 0], [2.5, 0.4]], float)
    th, sign = tr.path_headings_signed(r)
    np.testing.assert_allclose(th, [0, 0, np.arctan2(0.4, 0.5)], atol=1e-15)
    np.testing.assert_array_equal(sign, [1, 1, 1])
    # a turn a little more than pi/2 is backed along: heading within pi/2 of the previous
    s = np.array([[0, 0], [1, 0], [2, 0], [1.95, 0.5]], float)
    th, sign = tr.path_headings_signed(s)
    assert sign[2] == -1 and th[2] == pytest.approx(np.arctan2(0.5, -0.05) - np.pi)


def test_paper_lemniscate():
    r = tr.paper_lemniscate(7, 0.5)
    t = np.arange(8) * 0.5
    x, y = 7.5 * np.sin(2 * np.pi * t / 45), 10.0 * np.sin(4 * np.pi * t / 45)
    assert r.shape == (7, 3)
    np.testing.assert_allclose(r[:, 0], x[:-1], atol=1e-15)
    np.testing.assert_allclose(r[:, 1], y[:-1], atol=1e-15)
    np.testing.assert_allclose(r[:, 2], np.arctan2(np.diff(y), np.diff(x)), atol=1e-15)
    r2 = tr.paper_lemniscate(3, 1.0, ax=1.0, ay=2.0, period=10.0)
    np.testing.assert_allclose(r2[1, :2], [np.sin(2 * np.pi / 10), 2 * np.sin(4 * np.pi / 10)])


def test_paper_ivb_speed_profile():
    t = np.array([0, 10, 20, 21, 70, 119, 120, 130, 140, 150])
    v = tr.paper_ivb_speed(t)
    ramp = 0.35 * 12 / 16  # 16 - (2 s - 4)^2 = 12
    np.testing.assert_allclose(v, [0, ramp, 0.35, 0.35, 0.35, 0.35, 0.35, ramp, 0, 0],
                               atol=1e-15)
    assert tr.paper_ivb_speed(np.array([5]))[0] == pytest.approx(0.35 * (16 - 9) / 16)
    assert tr.paper_ivb_speed(np.array([135]))[0] == pytest.approx(0.35 * (16 - 9) / 16)


def test_unicycle_reference_is_the_continuous_time_path():
    v, w, dt = 0.4, 0.2, 0.5
    r = tr.unicycle_reference(lambda t: v + 0 * t, lambda t: w + 0 * t, 6, dt, (1.0, 2.0, 0.3))
    th = 0.3 + w * dt * np.arange(6)
    np.testing.assert_allclose(r[:, 2], th, atol=1e-13)
    np.testing.assert_allclose(r[:, 0], 1.0 + v / w * (np.sin(th) - np.sin(0.3)), atol=1e-10)
    np.testing.assert_allclose(r[:, 1], 2.0 - v / w * (np.cos(th) - np.cos(0.3)), atol=1e-10)
    # speed linear in t (sample index): x(k) = dt * 0.1 k^2 / 2, integrated exactly by RK4
    k = np.arange(5)
    ramp = tr.unicycle_reference(lambda t: 0.1 * t, lambda t: 0 * t, 5, dt)
    np.testing.assert_allclose(ramp[:, 0], dt * 0.05 * k ** 2, atol=1e-13)
    np.testing.assert_allclose(ramp[:, 1:], 0, atol=1e-15)
    turn = tr.unicycle_reference(lambda t: 0 * t, lambda t: 0.02 * t ** 2, 5, dt, substeps=1)
    np.testing.assert_allclose(turn[:, 2], dt * 0.02 * k ** 3 / 3, atol=1e-13)


def test_sampled_reference_lengths_and_headings():
    xy = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    r = tr.sampled_reference(xy, 5)  # one point short: extended linearly
    np.testing.assert_allclose(r[:, :2], [[0, 0], [1, 0], [1, 1], [0, 1], [-1, 1]])
    np.testing.assert_allclose(r[:, 2], [0, np.pi / 2, np.pi, np.pi, np.pi], atol=1e-15)
    r3 = tr.sampled_reference(xy, 3)  # longer than needed: cut, then extended for the tangent
    np.testing.assert_allclose(r3[:, :2], xy[:3])
    np.testing.assert_allclose(r3[:, 2], [0, np.pi / 2, np.pi / 2], atol=1e-15)
    given = tr.sampled_reference(xy, 4, heading=np.array([9.0, 8.0, 7.0, 6.0, 5.0]))
    np.testing.assert_array_equal(given[:, 2], [9.0, 8.0, 7.0, 6.0])
    with pytest.raises(ValueError, match="at least 2 points"):
        tr.sampled_reference(xy[:1], 1)
    with pytest.raises(ValueError, match="needs 5 points, got 4"):
        tr.sampled_reference(xy, 6)
    assert tr.sampled_reference(xy[:2], 2).shape == (2, 3)


def test_waypoint_reference():
    r = tr.waypoint_reference(np.array([0.0, 1.0, 2.0]),
                              np.array([[0, 0], [1, 0], [1, 1]], float), 5, 0.5)
    np.testing.assert_allclose(r[:, :2], [[0, 0], [0.5, 0], [1, 0], [1, 0.5], [1, 1]])
    np.testing.assert_allclose(r[:, 2], [0, 0, np.pi / 2, np.pi / 2, np.pi / 2], atol=1e-15)


def test_formation_positions_in_both_frames():
    ref = np.array([[1.0, 2.0, 0.0], [1.0, 2.0, np.pi / 2], [0.0, 0.0, np.pi]])
    base = np.array([[1.0, 0.0], [0.0, 2.0]])
    scales = [lambda s: 1.0 + s, lambda s: 2.0 + 0 * s]
    world = tr.formation_positions(ref, base, scales, 0.5, "world")
    np.testing.assert_allclose(world[0], [[2.0, 2.0], [2.5, 2.0], [2.0, 0.0]])
    np.testing.assert_allclose(world[1], [[1.0, 6.0], [1.0, 6.0], [0.0, 4.0]])
    lead = tr.formation_positions(ref, base, scales, 0.5, "leader")
    # x ahead, y left of the leader's heading
    np.testing.assert_allclose(lead[0], [[2.0, 2.0], [1.0, 3.5], [-2.0, 0.0]], atol=1e-15)
    np.testing.assert_allclose(lead[1], [[1.0, 6.0], [-3.0, 2.0], [0.0, -4.0]], atol=1e-15)
    with pytest.raises(ValueError, match="frame must be 'world' or 'leader', got 'body'"):
        tr.formation_positions(ref, base, scales, 0.5, "body")


def test_desired_trajectories_back_up_with_a_negative_speed():
    # one robot: forwards, forwards, back by half a step; a second turning
    p = np.array([[[0, 0], [1, 0], [2, 0], [1.5, 0], [1.0, 0]],
                  [[0, 0], [1, 0], [1.5, 0.5], [1.5, 1.5], [1.0, 2.0]]], float)
    ref = np.zeros((5, 3))
    d = tr.desired_trajectories(p, 0.5, ref)
    assert d.eta.shape == (2, 4, 3) and d.u.shape == (2, 3, 2)
    assert d.reference.shape == (4, 3)
    np.testing.assert_allclose(d.u[0], [[2.0, 0.0], [2.0, 0.0], [-1.0, 0.0]], atol=1e-15)
    th = d.eta[1, :, 2]
    np.testing.assert_allclose(th[:3], [0, np.pi / 4, np.pi / 2], atol=1e-15)
    np.testing.assert_allclose(d.u[1, :, 1], np.diff(th) / 0.5)
    np.testing.assert_allclose(d.u[1, :, 0], [2.0, np.sqrt(0.5) / 0.5, 2.0])
    np.testing.assert_array_equal(d.xi0, d.eta[:, 0])


def test_tangent_thresholds_and_leading_stand_stills():
    # two stand-stills before the first move, which is along +y
    p = np.array([[0, 0], [0, 0], [0, 0], [0, 1], [1, 1]], float)
    np.testing.assert_allclose(tr.path_headings(p), [np.pi / 2] * 3 + [0.0], atol=1e-15)
    # a step of exactly 1e-12 of the longest is a stand-still
    q = np.array([[0, 0], [1, 0], [1, 1e-12]], float)
    np.testing.assert_allclose(tr.path_headings(q), [0, 0], atol=1e-15)
    # the threshold is relative: a path of 1e-13 m steps still has headings
    r = np.array([[0, 0], [0, 1e-13], [-1e-13, 1e-13]])
    np.testing.assert_allclose(tr.path_headings(r), [np.pi / 2, np.pi], atol=1e-12)
    assert tr.path_headings(np.zeros((3, 2))).tolist() == [0.0, 0.0]
    assert tr.path_headings_signed(np.zeros((3, 2)))[0].tolist() == [0.0, 0.0]


def test_signed_headings_walk_both_ways_from_the_anchor():
    # the step right after the anchor reverses
    th, sign = tr.path_headings_signed(np.array([[0, 0], [2, 0], [1.5, 0]], float))
    np.testing.assert_allclose(th, [0, 0], atol=1e-15)
    np.testing.assert_array_equal(sign, [1, -1])
    # two reversed steps before the anchor
    th, sign = tr.path_headings_signed(np.array([[1, 0], [0.5, 0], [0, 0], [3, 0]], float))
    np.testing.assert_allclose(th, [0, 0, 0], atol=1e-15)
    np.testing.assert_array_equal(sign, [-1, -1, 1])
    # a square turn is a tie: driven forwards
    th, sign = tr.path_headings_signed(np.array([[0, 0], [2, 0], [2, 1]], float))
    np.testing.assert_allclose(th, [0, np.pi / 2], atol=1e-15)
    np.testing.assert_array_equal(sign, [1, 1])
    # more than a full turn forwards: unwrapped like the tangent
    ang = np.linspace(0, 2.5 * 2 * np.pi, 60)
    circle = np.column_stack([np.cos(ang), np.sin(ang)])
    th, sign = tr.path_headings_signed(circle)
    np.testing.assert_allclose(th, tr.path_headings(circle), atol=1e-12)
    assert (sign == 1).all()


def test_ivb_speed_inside_the_ramps_near_their_ends():
    v = tr.paper_ivb_speed(np.array([19.5, 120.5]))
    np.testing.assert_allclose(v, [0.35 * (16 - 0.01) / 16] * 2, rtol=1e-12)


def test_sinusoid_defaults_are_one_and_constant():
    s = np.array([0.0, 0.3, 0.6])
    assert tr.Sinusoid(period=2.0)(s).tolist() == [1.0] * 3
    assert tr.Sinusoid(amplitude=0.5)(s).tolist() == [1.0] * 3


def test_sampled_reference_extension_uses_the_last_step():
    xy = np.array([[0, 0], [1, 0], [2, 0], [3, 0], [4, 1]], float)
    r = tr.sampled_reference(xy, 6)  # one short: the last step repeated
    np.testing.assert_allclose(r[-1, :2], [5, 2])
    r3 = tr.sampled_reference(np.array([[0, 0], [2, 0], [4, 1]], float), 3)
    assert r3[-1, 2] == pytest.approx(np.arctan2(1, 2))  # tangent of the extra step


def test_robot_standing_still_takes_the_leaders_first_heading():
    p = np.zeros((1, 5, 2))
    ref = np.column_stack([np.zeros(5), np.zeros(5), [0.3, 0.5, 0.7, 0.9, 1.1]])
    d = tr.desired_trajectories(p, 0.5, ref)
    np.testing.assert_allclose(d.eta[0, :, 2], 0.3)
    np.testing.assert_allclose(d.u, 0, atol=1e-15)


def test_value_types_are_frozen():
    import dataclasses

    for obj in (tr.Sinusoid(), tr.Desired(np.zeros(1), np.zeros(1), np.zeros(1))):
        with pytest.raises(dataclasses.FrozenInstanceError):
            obj.eta = 1  # type: ignore[union-attr]
