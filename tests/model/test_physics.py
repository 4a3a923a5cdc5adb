"""The PyBullet world: placement, driving, odometry, contacts, calibration."""

import numpy as np
import pytest

pytest.importorskip("pybullet", reason="the physics extra: pip install -e .[physics]")

from formation_ilc.model.physics import MODELS, PhysicsWorld, calibrate, robot_model  # noqa: E402


@pytest.fixture(scope="module")
def p3dx():
    with PhysicsWorld(MODELS["p3dx"], 2, 0.2) as w:
        yield w


def test_place_puts_tracked_points_at_rest(p3dx):
    poses = np.array([[1.0, 2.0, 0.5], [-1.0, 0.0, -2.0]])
    p3dx.place(poses)
    np.testing.assert_allclose(p3dx.truth(), poses, atol=2e-3)
    np.testing.assert_allclose(p3dx.odom, p3dx.truth())
    assert p3dx.tilt().max() < 0.02  # standing on wheels and caster
    assert p3dx.contacts() == {}


def test_drive_straight_and_turn(p3dx):
    p3dx.place(np.array([[0.0, 0.0, 0.0], [0.0, 3.0, 0.0]]))
    for _ in range(10):  # 2 s
        p3dx.step(np.array([[0.3, 0.0], [0.0, 0.5]]))
    truth = p3dx.truth()
    # the maker's acceleration limit (0.3 m/s^2: 0.06 m/s a sample) holds the command:
    # 0.06, 0.12, ... 0.3 m/s, then 0.3 m/s, 0.48 m in all; motors with a torque limit lag
    # that a little, no more
    # limited: robot 1's first 4 samples, robot 2's first (100 deg/s^2: 0.35 rad/s of 0.5)
    assert p3dx.limited == 5
    assert 0.42 < truth[0, 0] < 0.49 and abs(truth[0, 1]) < 0.01
    # spinning on the spot: the tracked point, 0.045 m ahead of the axle, circles it
    assert 0.85 < truth[1, 2] < 1.1 and np.hypot(*(truth[1, :2] - [0.0, 3.0])) < 0.1
    # the wheels barely slip on a two-wheel drive: odometry stays with the truth
    np.testing.assert_allclose(p3dx.odom, truth, atol=0.03)
    v, w = p3dx.body_twist().T
    assert v[0] == pytest.approx(0.3, abs=0.03) and w[1] == pytest.approx(0.5, abs=0.05)


@pytest.mark.parametrize("collide", [True, False])
def test_head_on_robots_collide_or_pass(collide):
    with PhysicsWorld(MODELS["p3dx"], 2, 0.2, collide=collide) as w:
        w.place(np.array([[0.0, 0.0, 0.0], [1.5, 0.0, np.pi]]))
        for _ in range(15):
            w.step(np.array([[0.4, 0.0], [0.4, 0.0]]))
        touched = w.contacts()
        x = w.truth()[:, 0]
    if collide:
        assert touched["robot_1-robot_2"] > 0.5 and x[0] < x[1]  # blocked by each other
    else:
        assert touched == {} and x[0] > x[1]  # passed through


def test_husky_from_pybullet_data_turns_about_a_point_behind_its_origin():
    husky = robot_model("husky")
    track, ahead = calibrate(husky, v=0.3, omega=0.3, seconds=5.0)
    # skid steer: the geometric track overstates the turn rate several times
    assert track > 2 * husky.geometric_track
    assert -0.25 < ahead < -0.1
    p3 = calibrate(MODELS["p3dx"], seconds=5.0)
    assert p3[0] == pytest.approx(0.33, rel=0.1) and abs(p3[1]) < 0.08
    with pytest.raises(ValueError, match="no robot model 'tb3'"):
        robot_model("tb3")
