"""The bridge's pure logic (formation_ilc.protocol.bridge) and the wall-clock schedule."""

from __future__ import annotations

import itertools
import math

import pytest

from formation_ilc.core.clock import Malformed
from formation_ilc.protocol.bridge import (
    PIONEER_OMEGA_MAX,
    PIONEER_V_MAX,
    CommandLimits,
    ReturnController,
    Watchdog,
    compose,
    initial_shift,
    odom_to_world,
    wrap,
)
from formation_ilc.protocol.wallclock import WallSchedule, start_wall_ns


def test_defaults_are_inside_the_pioneer_3dx_specification():
    # data sheet: 1.2 m/s, 300 deg/s
    assert PIONEER_V_MAX <= 1.2 and PIONEER_OMEGA_MAX <= math.radians(300)


@pytest.mark.parametrize(("v", "w", "cv", "cw", "clipped"), [
    (0.3, 0.5, 0.3, 0.5, False),
    (2.0, 0.1, 0.75, 0.1, True),
    (-2.0, -9.0, -0.75, -math.radians(100), True),
    (0.1, 3.0, 0.1, math.radians(100), True),
    (math.nan, 0.1, 0.0, 0.0, True),
    (0.1, math.inf, 0.0, 0.0, True),
])
def test_clamp(v, w, cv, cw, clipped):
    got = CommandLimits().clamp(v, w)
    assert got[0] == pytest.approx(cv) and got[1] == pytest.approx(cw) and got[2] is clipped


def test_limits_must_be_positive():
    with pytest.raises(ValueError, match="positive"):
        CommandLimits(v_max=0.0)


def test_watchdog_expires_after_the_timeout_and_counts_each_silence_once():
    w = Watchdog(0.5)
    assert w.expired(0.0)  # nothing yet: zero command
    w.feed(1.0)
    assert not w.expired(1.4) and not w.expired(1.5)
    assert w.expired(1.51) and w.expired(2.0)
    assert w.expired_count == 1
    w.feed(2.1)
    assert not w.expired(2.2) and w.expired(3.0)
    assert w.expired_count == 2


def test_odometry_composed_with_the_initial_pose():
    init = (1.0, 2.0, math.pi / 2)
    # 1 m forward in odometry from a robot facing +y is 1 m along +y in the world
    x, y, th = odom_to_world(init, (1.0, 0.0, 0.0))
    assert (x, y, th) == pytest.approx((1.0, 3.0, math.pi / 2))
    x, y, th = odom_to_world(init, (0.0, 0.5, 0.3))
    assert (x, y, th) == pytest.approx((0.5, 2.0, math.pi / 2 + 0.3))
    assert compose((0, 0, 0), (1, 2, 3)) == (1, 2, 3)


def test_initial_shift_wraps_the_heading():
    s = initial_shift((1.01, -0.02, math.pi - 0.01), (1.0, 0.0, -math.pi + 0.01))
    assert s == pytest.approx((0.01, -0.02, -0.02))
    assert wrap(3 * math.pi) == pytest.approx(math.pi)


def run_return(ctrl: ReturnController, start, dt=0.02):
    p = list(start)
    t = 0.0
    while True:
        st = ctrl.step(tuple(p), t)
        if st.done:
            return st, p, t
        assert abs(st.v) <= ctrl.limits.v_max and abs(st.omega) <= ctrl.limits.omega_max
        p[0] += dt * st.v * math.cos(p[2])
        p[1] += dt * st.v * math.sin(p[2])
        p[2] += dt * st.omega
        t += dt


@pytest.mark.parametrize("start", list(itertools.product((-3.0, 0.0, 2.5), (-2.0, 0.0, 2.0),
                                                         (0.0, 1.5, 3.0, -2.0))))
def test_return_controller_reaches_the_goal_within_tolerance(start):
    goal = (0.3, -0.2, 0.4)
    ctrl = ReturnController(goal, CommandLimits(), tol_pos=0.02, tol_heading=math.radians(2))
    st, p, t = run_return(ctrl, start)
    assert st.reached and not st.timed_out, (start, st)
    assert math.hypot(p[0] - goal[0], p[1] - goal[1]) <= 0.02
    assert abs(wrap(p[2] - goal[2])) <= math.radians(2)
    assert t < 20.0


def test_return_controller_reports_a_timeout():
    ctrl = ReturnController((5.0, 0.0, 0.0), CommandLimits(), timeout=1.0)
    st, p, t = run_return(ctrl, (0.0, 0.0, 0.0))
    assert st.timed_out and not st.reached and st.rho > 3.0
    assert st.v == 0.0 and st.omega == 0.0


def test_return_controller_stops_on_stale_odometry_and_its_timeout_still_runs():
    ctrl = ReturnController((1.0, 0.0, 0.0), CommandLimits(), timeout=1.0)
    assert ctrl.step((0.0, 0.0, 0.0), 0.0).v > 0
    st = ctrl.step((0.0, 0.0, 0.0), 0.5, stale=True)
    assert (st.v, st.omega, st.done) == (0.0, 0.0, False)
    assert ctrl.step((0.0, 0.0, 0.0), 1.1, stale=True).timed_out


def test_return_controller_gains_are_checked():
    with pytest.raises(ValueError, match="k_beta"):
        ReturnController((0, 0, 0), CommandLimits(), k_beta=0.5)


def test_wall_schedule_returns_each_due_sample_once_and_skips_overtaken_ones():
    w = WallSchedule(start_ns=1_000, dt_ns=100, samples=3)
    assert w.due(999) is None
    assert w.due(1_000) == 0 and w.due(1_050) is None
    assert w.due(1_100) == 1
    assert w.due(1_390) == 3 and w.skipped == 1 and w.finished  # sample 2 was overtaken
    assert w.due(5_000) is None
    assert w.time_of(2) == 1_200


def test_start_wall_ns_is_required_in_a_wallclock_start_event():
    assert start_wall_ns({"start_wall_ns": 5}) == 5
    for bad in ({}, {"start_wall_ns": True}, {"start_wall_ns": -1}, {"start_wall_ns": "5"}):
        with pytest.raises(Malformed, match="start_wall_ns"):
            start_wall_ns(bad)


def test_wallclock_needs_direct_links():
    from formation_ilc.config.runconfig import make_config

    with pytest.raises(ValueError, match="links direct"):
        make_config("paper-triangle3", mode="wallclock", links="emulated")
    cfg = make_config("paper-triangle3", mode="wallclock", links="direct")
    assert cfg.wall and cfg.to_json()["mode"] == "wallclock"


@pytest.mark.parametrize("module", ["formation_ilc.nodes.pioneer_bridge",
                                    "robot_sim.fake_pioneer"])
def test_help_of_the_new_entry_scripts(module):
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", module, "--help"], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0 and "cmd_vel" in r.stdout and "cmd_timeout" in r.stdout
