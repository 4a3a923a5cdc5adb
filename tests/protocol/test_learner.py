"""The robot as a pure learner (no ROS): links, labels, eq. (11), zero-order hold, learning.

A team of ``RobotLearner`` objects fed event by event, as the robot nodes are fed by
messages, must command and learn exactly what the batch simulator computes, in both link
modes; refused inputs carry the reason they are counted under.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from formation_ilc.config.scenario import load_scenario
from formation_ilc.core.clock import Rejected, SampleClock, WallGrid
from formation_ilc.core.links import LEADER, Delivery, LinkInbox, delivered_label, robot_name
from formation_ilc.model.simulate import Problem
from formation_ilc.protocol.learner import RobotLearner

CLOCK = SampleClock.for_run(0.1, 10, gap=5)


def stamp(k: int, s: int) -> int:
    return CLOCK.stamp_ns(k, s)


# --------------------------------------------------------------------------- inboxes

def test_direct_inbox_uses_the_newest_label_not_after_rt():
    box = LinkInbox("robot_1", CLOCK, direct=True)
    for s in (1, 2, 4):
        box.offer(stamp(0, s), np.full(3, float(s)), trial=0)
    assert not box.has(stamp(0, 5)) and box.has(stamp(0, 4))
    d = box.take(stamp(0, 3))
    assert d is not None and d.label_ns == stamp(0, 2) and d.eta[0] == 2.0
    # the same pose is still the newest usable one a sample later
    assert box.take(stamp(0, 3)).label_ns == stamp(0, 2)
    assert box.take(stamp(0, 6)).label_ns == stamp(0, 4)
    # nothing of an earlier trial is used in a new one
    assert box.take(stamp(1, 2)) is None


@pytest.mark.parametrize(("label", "trial", "reason"), [
    (stamp(0, 4), 0, "duplicate"),
    (stamp(0, 3), 0, "out_of_order"),
    (stamp(2, 1), 3, "stale"),
    (stamp(5, 1), 3, "future"),
    (-5, 0, "malformed"),
    (stamp(0, 10) + 3 * CLOCK.dt_ns, 0, "malformed"),  # between trials
])
def test_direct_inbox_refuses_with_a_reason(label, trial, reason):
    box = LinkInbox("robot_1", CLOCK, direct=True)
    box.offer(stamp(0, 4), np.zeros(3), trial=0)
    with pytest.raises(Rejected) as exc:
        box.offer(label, np.zeros(3), trial=trial)
    assert exc.value.reason == reason


def test_emulated_inbox_delivers_per_tick_and_counts_late_deliveries():
    box = LinkInbox("leader", CLOCK, direct=False)
    d = Delivery("leader", stamp(0, 1), np.zeros(3))
    box.offer_tick(stamp(0, 3), d, trial=0)
    assert box.has(stamp(0, 3)) and not box.has(stamp(0, 4))
    box.offer_tick(stamp(0, 2), Delivery("leader", stamp(0, 0), np.zeros(3)), trial=0)
    assert box.take(stamp(0, 3)) is d
    assert box.unused == 1  # tick 2 came after sample 2 was commanded
    box.offer_tick(stamp(0, 4), None, trial=0)
    assert box.take(stamp(0, 4)) is None and box.unused == 1
    with pytest.raises(Rejected) as exc:
        box.offer_tick(stamp(0, 6), Delivery("leader", stamp(0, 7), np.zeros(3)), trial=0)
    assert exc.value.reason == "future"
    box.offer_tick(stamp(0, 6), None, trial=0)
    with pytest.raises(Rejected) as exc:
        box.offer_tick(stamp(0, 6), None, trial=0)
    assert exc.value.reason == "duplicate"


def test_delivered_label():
    assert delivered_label(7, 3) == 4
    assert delivered_label(2, 3) == -1


# --------------------------------------------------------------------------- a team

def run_team(pb: Problem, clock: SampleClock, memory, draws, direct: bool,
             in_step: bool = False):
    """Feed one learner per robot with the batch trial's outputs, event by event; return
    (commands (N, T, 2), learned memory (N, T, 2)). ``in_step``: lockstep with direct
    links, the leader link taken from the robot's own samples (no reference is fed)."""
    xi0, dist, noise, tau, tau0 = draws
    _, eta, u_ref, _ = pb.trial(memory, xi0, dist, noise, tau, tau0)
    team = [RobotLearner(pb, r, clock, direct=direct, memory=memory[r],
                         leader_in_step=in_step, safety=pb.safety) for r in range(pb.n)]
    k = 0
    u = np.zeros((pb.n, pb.samples, 2))
    ref_label = lambda s: clock.stamp_ns(k, s)  # noqa: E731
    for t in range(pb.samples + 1):
        for r, lrn in enumerate(team):
            ev = lrn.on_pose(clock.stamp_ns(k, t), eta[r, t])
            assert (ev.trial, ev.sample, ev.last) == (k, t, t == pb.samples)
        if t == pb.samples:
            break
        for r, lrn in enumerate(team):
            if pb.safety is not None:  # the team's poses of the sample (the plant's)
                for j in range(pb.n):
                    if j != r:
                        assert not lrn.can_command()  # lockstep: it waits for them
                        lrn.on_team_pose(j, clock.stamp_ns(k, t), eta[j, t])
                        if pb.safety.commands and t > 0:  # and what each applied before
                            assert not lrn.can_command()
                            lrn.on_told(j, clock.stamp_ns(k, t - 1), *u_ref[j, t - 1])
            for ell, j in enumerate(pb.src[r]):
                if j < 0:
                    continue
                sender = robot_name(j + 1)
                if direct:
                    lrn.on_link_pose(sender, clock.stamp_ns(k, t), eta[j, t])
                else:
                    s = delivered_label(t, int(tau[r, ell, t]))
                    lrn.on_link_tick(sender, clock.stamp_ns(k, t),
                                     None if s < 0 else (clock.stamp_ns(k, s), eta[j, s]))
            if lrn.sees_leader and not in_step:
                if direct:
                    lrn.on_link_pose(LEADER, ref_label(t), np.zeros(3))
                else:
                    s = delivered_label(t, int(tau0[r, t]))
                    lrn.on_link_tick(LEADER, clock.stamp_ns(k, t),
                                     None if s < 0 else (ref_label(s), np.zeros(3)))
            assert lrn.can_command()
            u[r, t] = lrn.command()
    trajs = [lrn.finish_trial()[1].copy() for lrn in team]
    for r, lrn in enumerate(team):
        learned = lrn.try_learn()  # a robot with no in-neighbour learns at once
        assert learned == (pb.src[r] < 0).all()
        for j in pb.src[r]:
            if j >= 0:
                learned = lrn.on_trajectory(robot_name(j + 1), np.array(
                    lrn.trajectory_stamps(k)), trajs[j])
        assert learned and lrn.learned == k
    np.testing.assert_allclose(u, u_ref, rtol=0, atol=0)
    return u, np.stack([lrn.memory[0] for lrn in team]), team


@pytest.mark.parametrize("scenario", ["paper-triangle3", "paper-hexagon6"])
@pytest.mark.parametrize("law", [9, 22, 23])
@pytest.mark.parametrize(("direct", "in_step"), [(False, False), (True, False), (True, True)],
                         ids=["emulated", "direct", "direct-leader-in-step"])
def test_a_team_of_learners_equals_the_batch_trial(scenario, law, direct, in_step):
    sc = load_scenario(scenario).with_options(law=law, delay=not direct)
    pb = Problem.from_scenario(sc)
    clock = SampleClock.for_run(sc.dt, sc.samples)
    mem = np.random.default_rng(law).normal(scale=0.1, size=(pb.n, pb.samples, 2))
    shift, dist, noise = sc.uncertainty.draw_plant(sc.seed, 0, pb.n, pb.samples)
    tau, tau0 = sc.uncertainty.draw_delays(sc.seed, 0, pb.n, pb.src.shape[1], pb.samples)
    draws = (pb.eta_d[:, 0] + shift, dist, noise, tau, tau0)
    _, nxt_ref = pb.trial(mem, *draws)[2:]
    _, nxt, team = run_team(pb, clock, mem, draws, direct, in_step)
    np.testing.assert_allclose(nxt, nxt_ref, rtol=0, atol=1e-15)
    for lrn in team:  # direct: the leader link has delay 0 at every sample, messages or none
        if direct and lrn.sees_leader:
            assert lrn.delays[LEADER] == {0: pb.samples}
    # eq. (11) from the labels: every robot measured the delays the links had
    for r, lrn in enumerate(team):
        for ell, j in enumerate(pb.src[r]):
            if j < 0:
                continue
            hist = lrn.delays[robot_name(j + 1)]
            if direct:
                assert hist == {0: pb.samples}
            else:
                d = tau[r, ell, :pb.samples]
                assert sum(hist.values()) == int((np.arange(pb.samples) - d >= 0).sum())


@pytest.mark.parametrize("commands", [False, True], ids=["poses", "told"])
@pytest.mark.parametrize("direct", [False, True], ids=["emulated", "direct"])
def test_a_team_of_learners_with_a_safety_filter_equals_the_batch_trials(direct, commands):
    """Cold start on P3-DX-size bodies, where the filter acts: each robot filters with the
    team's poses of its sample (and, told, every other robot's command of the sample
    before) and learns through the filter, exactly as the batch simulator does, trial
    after trial."""
    from dataclasses import replace

    from formation_ilc.model.footprint import footprint_of
    from formation_ilc.model.physics import MODELS
    from formation_ilc.model.safety import spec_for

    sc = load_scenario("paper-triangle3").with_options(delay=not direct)
    m = MODELS["p3dx"]
    pb = Problem.from_scenario(sc.for_plant("arc"), "arc",
                               spec_for(footprint_of("p3dx"), m.limits, sc.dt,
                                        commands=commands))
    clock = SampleClock.for_run(sc.dt, sc.samples)
    mem = np.zeros((pb.n, pb.samples, 2))
    acted = 0
    for k in range(4):
        shift, dist, noise = sc.uncertainty.draw_plant(sc.seed, k, pb.n, pb.samples)
        tau, tau0 = sc.uncertainty.draw_delays(sc.seed, k, pb.n, pb.src.shape[1], pb.samples)
        draws = (pb.eta_d[:, 0] + shift, dist, noise, tau, tau0)
        nxt_ref = pb.trial(mem, *draws)[3]
        _, nxt, team = run_team(pb, clock, mem, draws, direct)
        np.testing.assert_allclose(nxt, nxt_ref, rtol=0, atol=1e-15)
        acted += sum(lrn.filtered["changed"] for lrn in team)
        mem = nxt
    assert acted > 0  # the filter changed commands: the equality covers it
    # without the filter the learned memory differs
    free = replace(pb, safety=None)
    assert not np.allclose(free.trial(np.zeros_like(mem), *draws)[3], nxt)


def test_team_poses_are_refused_with_a_reason():
    from formation_ilc.model.footprint import footprint_of
    from formation_ilc.model.physics import MODELS
    from formation_ilc.model.safety import spec_for

    sc = load_scenario("paper-triangle3")
    sp = spec_for(footprint_of("p3dx"), MODELS["p3dx"].limits, sc.dt)
    pb = Problem.from_scenario(sc, safety=sp)
    clock = SampleClock.for_run(sc.dt, sc.samples)
    lrn = RobotLearner(pb, 1, clock, safety=sp)
    lrn.on_pose(clock.stamp_ns(0, 0), pb.eta_d[1, 0])
    lrn.on_team_pose(0, clock.stamp_ns(0, 0), pb.eta_d[0, 0])
    cases = [((0, clock.stamp_ns(0, 0)), "duplicate"), ((1, clock.stamp_ns(0, 0)), "unexpected"),
             ((7, clock.stamp_ns(0, 0)), "unexpected"), ((2, clock.stamp_ns(3, 0)), "future"),
             ((2, -5), "malformed")]
    for (j, label), reason in cases:
        with pytest.raises(Rejected) as exc:
            lrn.on_team_pose(j, label, pb.eta_d[j % 3, 0])
        assert exc.value.reason == reason, (j, label)
    plain = RobotLearner(pb, 1, clock)  # no filter: nothing to hear
    with pytest.raises(Rejected) as exc:
        plain.on_team_pose(0, clock.stamp_ns(0, 0), pb.eta_d[0, 0])
    assert exc.value.reason == "unexpected"


def test_told_commands_are_refused_with_a_reason():
    """What another robot tells it applied is checked before the filter uses it: its
    label, its limits, the robot itself, a filter that takes no told commands."""
    from formation_ilc.model.footprint import footprint_of
    from formation_ilc.model.physics import MODELS
    from formation_ilc.model.safety import spec_for

    sc = load_scenario("paper-triangle3")
    sp = spec_for(footprint_of("p3dx"), MODELS["p3dx"].limits, sc.dt, commands=True)
    pb = Problem.from_scenario(sc, safety=sp)
    clock = SampleClock.for_run(sc.dt, sc.samples)
    lrn = RobotLearner(pb, 1, clock, safety=sp)
    lrn.on_pose(clock.stamp_ns(0, 0), pb.eta_d[1, 0])
    lrn.on_told(0, clock.stamp_ns(0, 0), 0.2, -0.1)
    v_max = sp.limits.v_max
    cases = [((0, clock.stamp_ns(0, 0), 0.2, 0.0), "duplicate"),
             ((1, clock.stamp_ns(0, 1), 0.2, 0.0), "unexpected"),   # itself
             ((7, clock.stamp_ns(0, 1), 0.2, 0.0), "unexpected"),
             ((2, clock.stamp_ns(0, sc.samples), 0.2, 0.0), "unexpected"),  # no such command
             ((2, clock.stamp_ns(3, 0), 0.2, 0.0), "future"),
             ((2, clock.stamp_ns(0, 1), 2.0 * v_max, 0.0), "malformed"),
             ((2, clock.stamp_ns(0, 1), math.nan, 0.0), "malformed"),
             ((2, -5, 0.2, 0.0), "malformed")]
    for (j, label, v, w), reason in cases:
        with pytest.raises(Rejected) as exc:
            lrn.on_told(j, label, v, w)
        assert exc.value.reason == reason, (j, label, v)
    assert lrn.told_have[0, 0] and not lrn.told_have[2].any()
    poses = RobotLearner(pb, 1, clock, safety=replace(sp, commands=False))
    with pytest.raises(Rejected) as exc:  # a filter that estimates speeds from poses
        poses.on_told(0, clock.stamp_ns(0, 0), 0.2, 0.0)
    assert exc.value.reason == "unexpected"


def _filtering_pair(robot: int = 2):
    from formation_ilc.model.footprint import footprint_of
    from formation_ilc.model.physics import MODELS
    from formation_ilc.model.safety import spec_for

    sc = load_scenario("paper-hexagon6")
    sp = spec_for(footprint_of("p3dx"), MODELS["p3dx"].limits, sc.dt)
    pb = Problem.from_scenario(sc, safety=sp)
    clock = SampleClock.for_run(sc.dt, sc.samples)
    team = [RobotLearner(pb, robot, clock, safety=sp) for _ in range(2)]
    for lrn in team:
        lrn.on_pose(clock.stamp_ns(0, 0), pb.eta_d[robot, 0])
    return pb, clock, team


def _team_message(pb, labels, etas):
    from formation_ilc.protocol import wire

    data = wire.pose_set_bytes(int(labels[0]), [wire.raw_pose(e, int(lab))
                                                for e, lab in zip(etas, labels, strict=True)])
    return data, wire.read_pose_block(data, pb.n)


def _one_by_one(lrn, data, n):
    from formation_ilc.protocol import wire

    reasons = []
    for j, p in enumerate(wire.read_pose_set(data, n)[1]):
        if j == lrn.i:
            continue
        try:
            lrn.on_team_pose(j, p.label_ns, wire.world_eta(
                p, lrn.expected_team_heading(j, p.label_ns)))
        except Rejected as exc:
            reasons.append(exc.reason)
    return reasons


def _same_team_state(a, b):
    for name in ("team_eta", "team_have", "team_last"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.team_k == b.team_k


def test_the_team_poses_taken_at_once_are_those_taken_one_by_one():
    """The robot node's common case (``on_team_poses``, a whole ``team/poses`` message of
    arrays) holds the same bits as the one-by-one reading, headings unwrapped the same way
    however far the measured heading is from the desired one."""
    pb, clock, (bulk, single) = _filtering_pair()
    rng = np.random.default_rng(5)
    for t in range(pb.samples + 1):
        etas = pb.eta_d[:, t] + rng.normal(scale=(0.05, 0.05, 2.5), size=(pb.n, 3))
        labels = np.full(pb.n, clock.stamp_ns(0, t))
        data, block = _team_message(pb, labels, etas)
        assert bulk.on_team_poses(*block)
        assert _one_by_one(single, data, pb.n) == []
    _same_team_state(bulk, single)
    assert bulk.team_have.all()


def test_a_team_message_with_anything_to_refuse_is_left_to_the_one_by_one_reading():
    """Nothing is taken at once from a message that needs a verdict per pose: the one-by-one
    reading then takes what it can and counts the rest under its reason."""
    pb, clock, (bulk, single) = _filtering_pair()
    good = pb.eta_d[:, 3].copy()
    cases = []
    labels = np.full(pb.n, clock.stamp_ns(0, 3))
    labels[4] = clock.stamp_ns(0, 2)  # one robot's pose of another sample
    cases.append((labels, good, []))
    now = clock.stamp_ns(0, 4)
    etas = good.copy()
    etas[0, 0] = np.nan  # a non-finite position
    cases.append((np.full(pb.n, now), etas, ["malformed"]))
    cases.append((np.full(pb.n, clock.stamp_ns(5, 0)), good, ["future"] * (pb.n - 1)))
    # heard already, but for robot 1, whose pose was refused
    cases.append((np.full(pb.n, now), good, ["duplicate"] * (pb.n - 2)))
    for labels, etas, reasons in cases:
        data, block = _team_message(pb, labels, etas)
        before = bulk.team_have.copy()
        assert not bulk.on_team_poses(*block)
        np.testing.assert_array_equal(bulk.team_have, before)
        assert _one_by_one(bulk, data, pb.n) == _one_by_one(single, data, pb.n) == reasons
    _same_team_state(bulk, single)
    plain = RobotLearner(pb, 2, clock)  # no filter: nothing to hear
    assert not plain.on_team_poses(*_team_message(pb, np.full(pb.n, now), good)[1])


def test_robots_too_far_for_the_filter_are_dropped_before_it_without_a_change(monkeypatch):
    """A large team's robot drops the robots beyond the filter's radius before the filter
    runs (``_near``): the commands and flags are those of the filter given every robot."""
    import formation_ilc.protocol.hearing as hearing_module
    from formation_ilc.config.generate import team_yaml
    from formation_ilc.config.scenario import scenario_from_text
    from formation_ilc.model.footprint import footprint_of
    from formation_ilc.model.physics import MODELS
    from formation_ilc.model.safety import spec_for

    sc = scenario_from_text(team_yaml(24))
    sp = spec_for(footprint_of("p3dx"), MODELS["p3dx"].limits, sc.dt)
    pb = Problem.from_scenario(sc, safety=sp)
    clock = SampleClock.for_run(sc.dt, sc.samples)
    runs = []
    for near_from in (10**6, 2):
        monkeypatch.setattr(hearing_module, "NEAR_FROM", near_from)
        lrn = RobotLearner(pb, 9, clock, safety=sp)
        noise = np.random.default_rng(2).normal(scale=0.3, size=(pb.samples + 1, pb.n, 3))
        for t in range(pb.samples):
            lrn.on_pose(clock.stamp_ns(0, t), pb.eta_d[9, t] + noise[t, 9])
            for j in range(pb.n):
                if j != 9:
                    lrn.on_team_pose(j, clock.stamp_ns(0, t), pb.eta_d[j, t] + noise[t, j])
            lrn.t = t
            lrn.u[0] = (0.4, 0.3) + noise[t, 9, :2]
            lrn._filter(t)
            lrn.applied[0, t] = lrn.u[0]
        runs.append((lrn.applied.copy(), lrn.flags.copy()))
    np.testing.assert_array_equal(runs[0][0], runs[1][0])
    np.testing.assert_array_equal(runs[0][1], runs[1][1])
    assert (runs[0][1] != 0).any()  # the filter acted: the equality covers it


def test_realtime_missed_samples_are_held():
    sc = load_scenario("paper-triangle3").with_options(delay=False)
    pb = Problem.from_scenario(sc)
    clock = SampleClock.for_run(sc.dt, sc.samples)
    lrn = RobotLearner(pb, 1, clock, realtime=True, direct=True)
    lrn.on_pose(clock.stamp_ns(0, 0), pb.eta_d[1, 0])
    lrn.on_link_pose("robot_1", clock.stamp_ns(0, 0), pb.eta_d[0, 0])
    u0 = lrn.command().copy()
    lrn.on_pose(clock.stamp_ns(0, 1), pb.eta_d[1, 1])  # sample 1 never commanded
    lrn.on_pose(clock.stamp_ns(0, 3), pb.eta_d[1, 3])  # sample 2 never came
    assert lrn.missed == 2
    np.testing.assert_array_equal(lrn.applied[0, 1], u0)  # zero-order hold
    np.testing.assert_array_equal(lrn.applied[0, 2], u0)
    # lockstep refuses what realtime holds
    strict = RobotLearner(pb, 1, clock, direct=True)
    strict.on_pose(clock.stamp_ns(0, 0), pb.eta_d[1, 0])
    with pytest.raises(Rejected) as exc:
        strict.on_pose(clock.stamp_ns(0, 2), pb.eta_d[1, 2])
    assert exc.value.reason == "out_of_order"
    with pytest.raises(Rejected) as exc:
        strict.on_pose(clock.stamp_ns(0, 0), pb.eta_d[1, 0])
    assert exc.value.reason == "stale"
    with pytest.raises(Rejected) as exc:
        strict.on_link_pose("robot_3", clock.stamp_ns(0, 0), pb.eta_d[2, 0])
    assert exc.value.reason == "malformed"  # robot 3 is no in-link of robot 2


def test_trajectories_of_a_neighbour_are_checked():
    sc = load_scenario("paper-triangle3")
    pb = Problem.from_scenario(sc)
    clock = SampleClock.for_run(sc.dt, sc.samples)
    lrn = RobotLearner(pb, 1, clock)
    good = np.array(lrn.trajectory_stamps(0))
    eta = pb.eta_d[0]
    for stamps, reason in ((good[:-1], "malformed"), (good + clock.dt_ns, "malformed"),
                           (good, None)):
        if reason is None:
            assert lrn.on_trajectory("robot_1", stamps, eta) is False  # not finished yet
        else:
            with pytest.raises(Rejected) as exc:
                lrn.on_trajectory("robot_1", stamps, eta)
            assert exc.value.reason == reason
    lrn.learned = 0
    with pytest.raises(Rejected) as exc:
        lrn.on_trajectory("robot_1", good, eta)
    assert exc.value.reason == "stale"


# --------------------------------------------------------------------------- wall clock

def test_wall_clock_stamps_measure_the_same_delays_as_labels():
    """eq. (11) on real robots: a realtime robot on direct links whose neighbours' poses
    arrive late (the scenario's delays) measures the same delays, and commands the same,
    whether stamps are simulated-time labels or wall time (``WallGrid``)."""
    sc = load_scenario("paper-triangle3")
    pb = Problem.from_scenario(sc)
    tau, tau0 = sc.uncertainty.draw_delays(sc.seed, 0, pb.n, pb.src.shape[1], pb.samples)
    assert tau.max() > 0
    labels = SampleClock.for_run(sc.dt, sc.samples)
    wall = WallGrid(labels.dt_ns, labels.samples, labels.period)
    wall.agree(0, wall.start_for(0, 1_795_000_000_123_456_789))  # 2026-11-18, not on dT
    r = 1  # robot_2: robot_1 in
    runs = []
    for clock in (labels, wall):
        lrn = RobotLearner(pb, r, clock, realtime=True, direct=True)
        newest: dict[str, int] = {}
        u = []
        for t in range(pb.samples + 1):
            lrn.on_pose(clock.stamp_ns(0, t), pb.eta_d[r, t])
            if t == pb.samples:
                break
            for sender, s in [(robot_name(j + 1), t - int(tau[r, ell, t]))
                              for ell, j in enumerate(pb.src[r]) if j >= 0] + \
                    [(LEADER, t - int(tau0[r, t]))] * lrn.sees_leader:
                if s >= 0 and s > newest.get(sender, -1):  # what has arrived by now
                    newest[sender] = s
                    eta = pb.eta_d[0, s] if sender != LEADER else np.zeros(3)
                    lrn.on_link_pose(sender, clock.stamp_ns(0, s), eta)
            u.append(lrn.command().copy())
        runs.append((lrn.delays, np.array(u)))
    (d_label, u_label), (d_wall, u_wall) = runs
    assert d_label == d_wall and max(d_label["robot_1"]) > 0
    np.testing.assert_array_equal(u_label, u_wall)


def test_a_wall_clock_stamp_names_its_slot_and_sample():
    labels = SampleClock.for_run(0.05, 100, gap=20)
    grid = WallGrid(labels.dt_ns, labels.samples, labels.period)
    t0 = 1_795_000_000_000_000_000
    with pytest.raises(ValueError, match="does not fit"):
        grid.start_for(labels.dt_ns, t0)
    starts = {q: grid.start_for(q, t0 + q * 60_000_000_000 + 7) for q in (0, 1, 3)}
    for q, start in starts.items():
        assert 0 <= start - (t0 + q * 60_000_000_000 + 7) < labels.dt_ns  # < one sample late
        grid.agree(q, start)
        for s in (0, 1, 57, 100):
            ns = grid.stamp_ns(q, s)
            assert ns == start + s * labels.dt_ns  # the time sample s is taken
            assert grid.decode(ns) == (q, s)
    grid.agree(1, starts[1])  # the same start again: nothing changes
    for bad, why in (
            (lambda: grid.agree(1, starts[1] + labels.dt_ns), "unexpected"),  # moved
            (lambda: grid.agree(2, starts[1]), "malformed"),  # its remainder is slot 1's
            (lambda: grid.decode(starts[3] + 2), "unexpected"),  # slot 2: start not seen
            (lambda: grid.decode(starts[3] - labels.dt_ns), "malformed"),  # before it
            (lambda: grid.decode(grid.stamp_ns(3, 101)), "malformed"),  # after it
            (lambda: grid.decode(-5), "malformed"),
            (lambda: grid.stamp_ns(2, 0), "unexpected")):
        with pytest.raises(Rejected) as exc:
            bad()
        assert exc.value.reason == why


def test_leader_in_step_takes_no_reference_message():
    """Lockstep with direct links: a robot that sees the leader can command as soon as its
    own pose and its in-neighbours' poses are in; a reference message of the same label is
    refused (duplicate); the option is refused where the leader link has real delays."""
    sc = load_scenario("paper-triangle3").with_options(delay=False)
    pb = Problem.from_scenario(sc)
    clock = SampleClock.for_run(sc.dt, sc.samples)
    lead = next(r for r in range(pb.n) if pb.leader[r] != 0.0)
    lrn = RobotLearner(pb, lead, clock, direct=True, leader_in_step=True)
    plain = RobotLearner(pb, lead, clock, direct=True)
    for t in range(3):
        ns = clock.stamp_ns(0, t)
        for x in (lrn, plain):
            x.on_pose(ns, pb.eta_d[lead, t])
            for sender in x.neighbours:
                x.on_link_pose(sender, ns, pb.eta_d[pb.src[lead][x.slots[sender]], t])
        assert lrn.can_command() and not plain.can_command()
        plain.on_link_pose(LEADER, ns, np.zeros(3))
        with pytest.raises(Rejected) as exc:
            lrn.on_link_pose(LEADER, ns, np.zeros(3))
        assert exc.value.reason == "duplicate"
        np.testing.assert_array_equal(lrn.command(), plain.command())
    for kw in ({"realtime": True, "direct": True}, {"direct": False}):
        with pytest.raises(ValueError, match="lockstep with direct links"):
            RobotLearner(pb, lead, clock, leader_in_step=True, **kw)
