"""The bridge's pure logic (formation_ilc.protocol.bridge), its state machine, and the
wall-clock schedule."""

from __future__ import annotations

import itertools
import math

import pytest

from formation_ilc.config.runconfig import make_config
from formation_ilc.core.clock import Malformed, Rejected
from formation_ilc.model.simulate import Problem
from formation_ilc.protocol.bridge import (
    IDLE,
    PIONEER_OMEGA_MAX,
    PIONEER_V_MAX,
    RETURN,
    TRIAL,
    Bridge,
    CommandLimits,
    ReturnController,
    Returned,
    Watchdog,
    compose,
    initial_shift,
    odom_to_world,
    wrap,
)
from formation_ilc.protocol.schedule import ABORT, START, TrialEvent
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


# --------------------------------------------------------------------------- the state machine

SEC = 1_000_000_000


def wall_bridge(**kw) -> Bridge:
    """Robot 1 of paper-triangle3 on a base that sits at odometry (0, 0, 0)."""
    cfg = make_config("paper-triangle3", links="direct", mode="wallclock", run_id="r")
    b = Bridge(cfg, 1, name="bridge_1", period=0.05, **kw)
    b.on_odom((0.0, 0.0, 0.0), 0.0)
    return b


def start_event(slot: int, seq: int, wall_ns: int, trial: int | None = None) -> TrialEvent:
    """The leader's start of ``slot`` at about ``wall_ns`` (a whole number of samples): on
    the wall-clock grid, its remainder by dT is the slot (``WallGrid.start_for``)."""
    return TrialEvent(START, slot if trial is None else trial, slot, seq,
                      start_wall_ns=wall_ns + slot)


def test_a_trial_samples_on_the_wall_clock_then_drives_back_and_says_ready():
    b = wall_bridge(cmd_timeout=1.0)
    dt_ns = b.clock.dt_ns
    desired = Problem.from_scenario(make_config("paper-triangle3").scenario).eta_d[0, 0]
    assert b.initial == tuple(float(v) for v in desired)  # placed at its desired start
    assert b.shift() == (0.0, 0.0, 0.0) and not b.answers_abort()
    b.said_ready(0, b.shift())
    assert b.answers_abort() and b.shifts == {"0": [0.0, 0.0, 0.0]}
    t0 = 50 * SEC
    assert b.on_event(start_event(0, 0, t0), 1.0, t0 - SEC).slot == 0
    assert b.phase == TRIAL and not b.answers_abort()
    assert b.tick(1.0, t0 - 1).sample is None          # not due yet
    tick = b.tick(1.0, t0)
    assert tick.sample == (b.clock.stamp_ns(0, 0), b.world())
    assert tick.sample[0] == t0  # stamped with the wall time the sample is taken at
    # the robot node's commands go to the driver, clamped
    assert b.on_cmd((2.0, 0.1), 1.05) == (b.limits.v_max, 0.1)
    assert b.counts["clipped"] == 1
    assert b.tick(1.06, t0 + dt_ns // 2).cmd is None   # unchanged, sent 0.01 s ago
    assert b.tick(1.11, t0 + dt_ns // 2).cmd == (b.limits.v_max, 0.1)  # every period
    # the tick fell behind by two samples: the newest is sent, the overtaken one counted
    assert b.tick(1.2, t0 + 3 * dt_ns).sample[0] == b.clock.stamp_ns(0, 3)
    for s in range(4, b.T + 1):
        last = b.tick(1.2, t0 + s * dt_ns + 3_000_000)  # a timer 3 ms late
        assert last.sample[0] == b.clock.stamp_ns(0, s) == t0 + s * dt_ns
    assert b.counts["missed"] == 2  # samples 1 and 2
    # sample T: the return starts at once; the base is at its initial pose
    assert b.phase == IDLE and last.returned == Returned(1, True, (0.0, 0.0, 0.0), 0.0)
    assert last.cmd == (0.0, 0.0) and b.robot_cmd == (0.0, 0.0)
    # odometry of 0.0 s: the T - 1 samples sent (from 1.0 s) and the return's step
    assert b.counts["stale_odometry"] == b.T - 1 + 1
    assert b.returns == {"1": {"reached": True, "seconds": 0.0}}
    with pytest.raises(Rejected) as exc:
        b.on_cmd((0.1, 0.0), 2.1)
    assert exc.value.reason == "unexpected"
    assert b.report()["missed"] == 2 and b.report()["returns"] == b.returns


def test_behind_a_simulated_base_the_last_sample_gives_the_trials_true_poses():
    """With ``truth`` each sample keeps the base's newest true pose; the tick of sample T
    gives all T+1 with their labels (the skipped samples 1 and 2 hold sample 0's), and a
    trial's trail starts empty; without ``truth`` there is none."""
    for truth in (False, True):
        b = wall_bridge(truth=truth)
        dt_ns = b.clock.dt_ns
        t0 = 50 * SEC
        for k in range(2):
            start = t0 + 1000 * k * SEC
            b.said_ready(k, b.shift())
            b.on_event(start_event(k, 2 * k, start, trial=k), 1.0, start - SEC)
            paths = []
            for s in (0, *range(3, b.T + 1)):
                b.on_truth((float(k), float(s), 0.1 * s))
                paths.append(b.tick(1.0, start + k + s * dt_ns).true_path)  # + slot: the grid
            assert b.phase == IDLE
            assert all(p is None for p in paths[:-1])
            if not truth:
                assert paths[-1] is None
                continue
            poses, stamps = paths[-1]
            assert stamps == [b.clock.stamp_ns(k, s) for s in range(b.T + 1)]
            assert poses[:4] == [(k, 0.0, 0.0)] * 3 + [(k, 3.0, 0.1 * 3)]
            assert poses[-1] == (k, float(b.T), 0.1 * b.T) and len(poses) == b.T + 1


def test_a_silent_robot_node_gets_a_zero_command_counted_once():
    b = wall_bridge(cmd_timeout=0.5)
    b.said_ready(0, b.shift())
    b.on_event(start_event(0, 0, 10 * SEC), 0.0, 10 * SEC)
    b.on_odom((0.0, 0.0, 0.0), 1.0)
    b.on_cmd((0.2, 0.0), 1.0)
    assert b.tick(1.04, 10 * SEC).cmd is None and b.out_cmd == (0.2, 0.0)
    assert b.tick(1.6, 10 * SEC).cmd == (0.0, 0.0)
    assert b.counts["watchdog_zero"] == 1
    assert b.tick(1.7, 10 * SEC).cmd == (0.0, 0.0)  # re-sent at the period, not recounted
    assert b.counts["watchdog_zero"] == 1
    assert b.counts["stale_odometry"] == 0
    assert b.tick(1.7, 10 * SEC + b.clock.dt_ns).sample is not None
    assert b.counts["stale_odometry"] == 1  # a sample on odometry 0.7 s old


def test_an_abort_stops_the_trial_and_the_return_ends_with_a_ready_or_a_timeout():
    b = wall_bridge(initial=(1.0, 0.0, 0.0), tol=(0.02, 0.05, 2.0))
    b.said_ready(0, b.shift())
    b.on_event(start_event(0, 0, 10 * SEC), 0.0, 10 * SEC)
    assert b.on_event(TrialEvent(ABORT, 0, 0, 1), 0.5, 10 * SEC).event == ABORT
    assert b.phase == RETURN and b.schedule is None and not b.answers_abort()
    # the base stands still at odometry 0 (the world pose is the initial one), the
    # odometry goes stale: the controller stops and its timeout runs
    b.on_odom((0.1, 0.0, 0.0), 0.5)
    assert b.tick(0.6, 0).cmd[0] < 0          # 0.1 m ahead of the goal: back up
    assert b.tick(2.0, 0).cmd == (0.0, 0.0)   # stale odometry: stop
    end = b.tick(2.7, 0)
    assert end.returned is not None and not end.returned.reached
    # ready for the iteration after the aborted one's (as after a trial)
    assert end.returned.trial == 1 and end.returned.shift == pytest.approx((0.1, 0.0, 0.0))
    assert b.counts["return_timeouts"] == 1 and b.phase == IDLE and b.answers_abort()
    # the iteration runs again in slot 1 once the bridge said ready
    with pytest.raises(Rejected):
        b.on_event(start_event(1, 2, 10 * SEC, trial=0), 3.0, 10 * SEC)
    b.said_ready(0, end.returned.shift)
    assert b.on_event(start_event(1, 2, 10 * SEC, trial=0), 3.0, 10 * SEC).slot == 1


def test_the_bridge_needs_wallclock_direct_links_and_its_robot_in_the_team():
    with pytest.raises(ValueError, match="bridge_1: a real robot runs wall-clock"):
        Bridge(make_config("paper-triangle3"), 1, name="bridge_1")
    cfg = make_config("paper-triangle3", links="direct", mode="wallclock")
    with pytest.raises(ValueError, match="robots 1..3"):
        Bridge(cfg, 4, name="bridge_4")
    assert Bridge(cfg, 2, name="b").stop(0.0) == (0.0, 0.0)


def test_a_bases_acceleration_limits_hold_on_the_commands_stamps_in_trials_and_returns():
    from formation_ilc.core.limits import Limits

    b = wall_bridge(rate=Limits(0.3, 1.0, 0.5, 1.0))
    t0 = 10 * SEC
    assert b.tick(1.0, t0 - SEC).cmd == (0.0, 0.0)  # idle: zero, through the limits too
    b.said_ready(0, b.shift())
    b.on_event(start_event(0, 0, t0), 1.0, t0 - SEC)
    # 0.1 s of stamps after the zero command: at most 0.05 m/s more (0.5 m/s^2)
    assert b.on_cmd((0.3, 0.0), 1.1, t0 - SEC + SEC // 10) == pytest.approx((0.05, 0.0))
    assert b.on_cmd((0.3, 0.0), 1.2, t0 - SEC + 2 * SEC // 10) == pytest.approx((0.1, 0.0))
    assert b.counts["clipped_accel"] == 2 and b.counts["clipped"] == 0
    # the stamps rule, not the caller's clock: a late callback gets no larger step
    assert b.on_cmd((0.3, 0.0), 9.0, t0 - SEC + 3 * SEC // 10) == pytest.approx((0.15, 0.0))
    rep = b.report()
    assert rep["limits"] == [0.3, 1.0, 0.5, 1.0] and rep["clipped_accel"] == 3
    # a Pioneer driver's bridge has none: its runs are unchanged
    p = wall_bridge()
    p.said_ready(0, p.shift())
    p.on_event(start_event(0, 0, t0), 1.0, t0 - SEC)
    assert p.on_cmd((0.3, 0.0), 1.1, t0) == (0.3, 0.0) and p.rate is None
    assert p.report()["limits"][2:] == [math.inf, math.inf]


def test_bridge_limits_take_the_preset_then_every_given_value():
    from formation_ilc.config.bases import BASES
    from formation_ilc.protocol.bridge import bridge_limits

    assert bridge_limits(None).as_tuple() == (PIONEER_V_MAX, PIONEER_OMEGA_MAX, math.inf,
                                              math.inf)
    tb = BASES["turtlebot4"].limits
    got = bridge_limits("turtlebot4", {"v_max": 0.2, "omega_max": 0.0, "alpha_max": 90.0})
    assert got.as_tuple() == (0.2, tb.omega_max, tb.a_max, pytest.approx(math.pi / 2))
    with pytest.raises(ValueError, match="no base preset 'roomba'"):
        bridge_limits("roomba")
    with pytest.raises(ValueError, match="a_max: a limit >= 0 is required"):
        bridge_limits("jackal", {"a_max": -1.0})


# --------------------------------------------------------------------------- filtered returns


def _returning_pair(safety, starts, goals, seconds=40.0, tick=0.01, pose_every=None,
                    speeds=None):
    """Bridges 1 and 2 of paper-triangle3 driving back from ``starts`` to ``goals`` (world
    poses) on ideal unicycles, each hearing the other's whereabouts the moment it is said,
    stamped as the bridge node stamps them (when the pose came); returns the least
    distance between their covering discs' centres, the returns, and each bridge's counts.
    ``pose_every`` [s]: the odometry comes at its own rate (default: every tick);
    ``speeds``: a list that takes (the true speed of bridge 1's robot, bridge 2's estimate
    of it) at each whereabouts bridge 2 hears."""
    from formation_ilc.protocol.bridge import compose

    cfg = make_config("paper-triangle3", links="direct", mode="wallclock", run_id="r")
    bridges = [Bridge(cfg, i + 1, name=f"bridge_{i + 1}", period=0.05, initial=goals[i],
                      tol=(0.05, math.radians(5.0), seconds), safety=safety)
               for i in range(2)]
    world = [tuple(s) for s in starts]

    def odom(i):  # the odometry that puts robot i at world[i]: initial^-1 (x) world
        gx, gy, gth = goals[i]
        x, y, th = world[i]
        c, s = math.cos(-gth), math.sin(-gth)
        return (c * (x - gx) - s * (y - gy), s * (x - gx) + c * (y - gy), wrap(th - gth))

    for i, b in enumerate(bridges):
        b.on_odom(odom(i), 0.0)
        b.said_ready(0, b.shift())
        b.on_event(start_event(0, 0, 10 * SEC), 0.0, 10 * SEC)
        b.on_event(TrialEvent(ABORT, 0, 0, 1), 0.0, 10 * SEC)  # drive back now
        assert b.phase == RETURN
    offsets = (-0.114, 0.114) if safety is None else safety.discs
    least, done = math.inf, [None, None]
    now = 0.0
    next_pose = 0.0
    while now < seconds + 1 and None in done:
        now += tick
        cmds = []
        pose_due = pose_every is None or now >= next_pose - 1e-9
        if pose_due and pose_every is not None:
            next_pose += pose_every
        for i, b in enumerate(bridges):
            if pose_due:
                b.on_odom(odom(i), now)
            t = b.tick(now, int(now * SEC))
            if t.whereabouts is not None:
                stamp = int(round((now - t.whereabouts_age) * SEC))
                bridges[1 - i].on_peer(i + 1, t.whereabouts, stamp, now)
                if speeds is not None and i == 0 and 1 in bridges[1].peers:
                    vx, vy, _ = bridges[1].peers[1][3]
                    speeds.append((abs(b.out_cmd[0]), math.hypot(vx, vy)))
            if t.returned is not None:
                done[i] = t.returned
            cmds.append(b.out_cmd)
        for i, (v, w) in enumerate(cmds):
            x, y, th = world[i]
            world[i] = compose((x, y, th), (v * tick * math.cos(w * tick / 2),
                                            v * tick * math.sin(w * tick / 2), w * tick))
        (ax, ay, ath), (bx, by, bth) = world
        for la in offsets:
            for lb in offsets:
                least = min(least, math.hypot(ax + la * math.cos(ath) - bx - lb * math.cos(bth),
                                              ay + la * math.sin(ath) - by - lb * math.sin(bth)))
    return least, done, [b.counts for b in bridges]


def _return_spec():
    from formation_ilc.config.bases import base_preset
    from formation_ilc.config.safety import SafetySettings, default_margin
    from formation_ilc.protocol.bridge import return_filter

    # the bridge node's: decided every tick of 0.01 s
    return return_filter(SafetySettings("p3dx", base_preset("p3dx").limits,
                                        default_margin("p3dx")), 0.01)


def test_returns_through_the_filter_never_meet_head_on():
    """Two robots whose returns run head-on along one line (each drives to where the other
    starts): without the filter their discs meet; with it they never come closer than the
    filter's distance, hold each other off, and (as measured) work their way round each
    other: both returns end, each said (a timeout would be too)."""
    starts, goals = [(0.0, 0.0, 0.0), (3.0, 0.0, math.pi)], [(3.0, 0.0, 0.0),
                                                              (0.0, 0.0, math.pi)]
    spec = _return_spec()
    free, _, _ = _returning_pair(None, starts, goals, seconds=20.0)
    assert free < spec.distance - 0.3  # they drive into each other
    least, done, counts = _returning_pair(spec, starts, goals, seconds=20.0)
    assert least >= spec.distance - 1e-6
    assert all(d is not None for d in done)
    assert all(c["return_filtered"] > 0 for c in counts)


def test_returns_through_the_filter_cross_and_both_arrive():
    """Two returns whose paths cross at right angles at the same moment: the filter keeps
    the bodies apart and both robots still reach their start poses."""
    starts = [(0.0, 0.0, 0.0), (2.0, -2.0, math.pi / 2)]
    goals = [(4.0, 0.0, 0.0), (2.0, 2.0, math.pi / 2)]
    spec = _return_spec()
    free, _, _ = _returning_pair(None, starts, goals)
    assert free < spec.distance  # unfiltered, their bodies meet at the crossing
    least, done, counts = _returning_pair(spec, starts, goals)
    assert least >= spec.distance - 1e-6
    assert all(d is not None and d.reached for d in done)
    assert sum(c["return_filtered"] for c in counts) > 0


def test_whereabouts_are_stamped_when_their_pose_came_so_the_others_speeds_are_right():
    """Poses that come at their own rate (the physics bases' truth, motion capture: here
    every 0.04 s) against whereabouts said every 0.05 s: stamped at the tick, a pose's
    motion was divided by the ticks' time, and the other bridge heard a robot at 0.5 m/s
    as 0.4 or 0.8 by turns (the rehearsal's returns ran outside the filter's guarantee
    hundreds of ticks a run, and touched once); stamped when the pose came, the estimate
    is the robot's speed, and the crossing returns keep the filter's distance."""
    starts = [(0.0, 0.0, 0.0), (2.0, -2.0, math.pi / 2)]
    goals = [(4.0, 0.0, 0.0), (2.0, 2.0, math.pi / 2)]
    spec = _return_spec()
    speeds: list[tuple[float, float]] = []
    least, done, _ = _returning_pair(spec, starts, goals, pose_every=0.04, speeds=speeds)
    assert least >= spec.distance - 1e-6
    assert all(d is not None and d.reached for d in done)
    # while robot 1 drives steadily (its command the same a while), bridge 2's estimate
    # of its speed is its speed, to the straight-line chord of its arc
    steady = [(v, est) for v, est in speeds[5:] if v > 0.2]
    assert len(steady) > 10
    assert max(abs(est - v) for v, est in steady) < 0.05 * max(v for v, _ in steady)


def test_a_bridge_without_a_filter_says_no_whereabouts_and_takes_none():
    b = wall_bridge()
    b.on_peer(2, (0.5, 0.0, 0.0), SEC, 0.0)
    assert b.peers == {} and b.tick(0.0, 0).whereabouts is None
    assert "return_filtered" not in b.counts


def test_a_located_bridge_takes_its_world_pose_from_outside_not_from_odometry():
    """With a world pose from outside (motion capture; the physics bases' ground truth),
    the bridge's pose is that pose as it comes, and the driver's odometry, drifting, moves
    nothing; without it, the odometry composed with where the robot was placed."""
    cfg = make_config("paper-triangle3", links="direct", mode="wallclock", run_id="r")
    located = Bridge(cfg, 1, name="bridge_1", period=0.05, located=True)
    located.on_odom((0.5, 0.0, 0.0), 0.0, tilt=0.01)  # odometry alone locates nothing
    assert located.odom is None and located.tilt_max == 0.01
    located.on_located((1.0, 2.0, 0.3), 0.1)
    located.on_odom((7.0, -3.0, 1.0), 0.2)
    assert located.world() == (1.0, 2.0, 0.3) and located.odom_time == 0.1
    plain = wall_bridge()
    plain.on_located((1.0, 2.0, 0.3), 0.1)  # not located: an outside pose is unused
    assert plain.world() == odom_to_world(plain.initial, (0.0, 0.0, 0.0))


def test_the_estop_holds_every_command_at_zero_until_released():
    """The e-stop (issue 54): latched, the zero to send at once, then zero for the robot's
    commands, the repeats and the return alike; released, the robot's commands go again."""
    b = wall_bridge(cmd_timeout=1.0)
    b.said_ready(0, b.shift())
    t0 = 50 * SEC
    b.on_event(start_event(0, 0, t0), 1.0, t0 - SEC)
    b.tick(1.0, t0)
    assert b.on_cmd((0.3, 0.1), 1.01) == (0.3, 0.1)
    assert b.estop(True, 1.02) == (0.0, 0.0)  # sent at once, no limit holds it back
    assert b.estop(True, 1.03) == (0.0, 0.0) and b.counts["estops"] == 1  # latched once
    assert b.on_cmd((0.3, 0.1), 1.04) == (0.0, 0.0)
    assert b.tick(1.2, t0 + b.clock.dt_ns // 2).cmd in (None, (0.0, 0.0))
    assert b.tick(1.3, t0 + b.clock.dt_ns // 2).cmd == (0.0, 0.0)  # the repeat: zero
    assert b.estop(False, 1.31) is None
    assert b.on_cmd((0.3, 0.1), 1.32) == (0.3, 0.1)
    assert b.report()["estops"] == 1


def test_the_odometry_origin_of_a_located_robot_composes_back_to_its_world_pose():
    """map -> robot_i/odom of a located robot (REP-105): the frame in which its odometry
    reads where its world pose has it."""
    from formation_ilc.protocol.bridge import odom_origin

    for world, odom in (((1.0, 2.0, 0.3), (0.5, -0.2, 1.1)),
                        ((-3.0, 0.0, -2.9), (0.0, 0.0, 0.0)),
                        ((0.0, 0.0, 0.0), (2.0, 1.0, -0.7))):
        origin = odom_origin(world, odom)
        back = compose(origin, odom)
        assert abs(back[0] - world[0]) < 1e-12 and abs(back[1] - world[1]) < 1e-12
        assert abs(wrap(back[2] - world[2])) < 1e-12
