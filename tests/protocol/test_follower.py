"""One rule for taking the leader's starts and aborts (formation_ilc.protocol.schedule.Follower),
and every follower of the schedule applying it: the plant, the link emulator, the Pioneer
bridge and the robot refuse the same start for the same reason (no ROS)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from formation_ilc.config.runconfig import make_config
from formation_ilc.core.clock import Rejected
from formation_ilc.model.simulate import Problem
from formation_ilc.protocol.bridge import IDLE, RETURN, TRIAL, Bridge
from formation_ilc.protocol.learner import RobotLearner
from formation_ilc.protocol.linkemu import EmulatedLinks
from formation_ilc.protocol.plant import KinematicPlant
from formation_ilc.protocol.schedule import ABORT, DONE, END, START, Follower, TrialEvent
from formation_ilc.protocol.wallclock import START_AHEAD_MAX, check_start_wall

RUN = "run-a"
SEC = 1_000_000_000


def start(slot: int, seq: int, trial: int | None = None, **kw) -> TrialEvent:
    return TrialEvent(START, slot if trial is None else trial, slot, seq, **kw)


start_of = start


def reason(f, ev: TrialEvent, **kw) -> str:
    with pytest.raises(Rejected) as exc:
        f(ev, **kw)
    return exc.value.reason


def ready_follower(slot: int = 0, seen: int = 0) -> Follower:
    """A follower that ran ``slot`` (started with ``seen``) and said ready since."""
    f = Follower(RUN, slot=slot, trial=slot, seen=seen)
    f.said_ready()
    return f


def test_the_next_slot_is_taken_once_ready_and_idle_and_names_the_trial():
    f = Follower(RUN)
    assert reason(f.take, start(0, 0)) == "unexpected"  # before its first ready
    assert f.seen == -1 and f.slot == -1
    f.said_ready()
    ev = start(3, 0, trial=2)  # a follower that has just started takes any slot
    assert f.take(ev) is ev
    assert (f.seen, f.slot, f.trial, f.ready) == (0, 3, 2, False)
    # the next start needs a ready since this one
    assert reason(f.take, start(4, 1)) == "unexpected"
    f.said_ready()
    assert reason(f.take, start(4, 1), idle=False) == "unexpected"  # inside a trial
    assert f.take(start(4, 1)).slot == 4


@pytest.mark.parametrize(("ev", "why"), [
    (start(1, 0), "stale"),                           # its seq again, another slot
    (start(0, -1), "stale"),                          # an older seq
    (start(0, 5), "stale"),                           # the slot started already
    (start(2, 5), "future"),                          # slot 1 never started nor aborted
    (TrialEvent(START, 1, 1, 5, run="run-b"), "foreign"),
    (TrialEvent(END, 0, 0, 9, run="run-b"), "foreign"),
])
def test_refusals_carry_one_reason_each_and_move_nothing(ev, why):
    f = ready_follower()
    assert reason(f.take, ev) == why
    assert (f.seen, f.slot, f.trial, f.ready) == (0, 0, 0, True)


def test_aborts_are_taken_once_and_explain_a_gap():
    f = ready_follower()
    ab = TrialEvent(ABORT, 1, 1, 1, why="robot_2 restarted")
    assert f.take(ab) is ab and f.seen == 1 and f.aborted == {1}
    assert f.take(ab) is None  # the leader repeats an abort until answered: no drop
    assert f.take(TrialEvent(END, 0, 0, 1)) is None and f.take(TrialEvent(DONE, 3, 1, 1)) is None
    # slot 1's start was lost with a leader that was killed as it sent it
    assert f.take(start(2, 2, trial=1)).slot == 2
    assert reason(f.take, start(5, 3)) == "future"


def test_a_slot_run_without_its_start_is_behind_the_follower_and_no_gap():
    """A robot follows its own poses: a start lost on its way (its process was stopped as
    the start went out) leaves it learning the slot all the same; the next start is then
    the next slot, not a gap, and the lost start coming late is stale."""
    f = ready_follower(slot=1, seen=1)
    assert reason(f.take, start(3, 3)) == "future"  # slot 2 never taken here
    f.ran(2)
    assert f.take(start(3, 3)).slot == 3 and f.seen == 3
    f.said_ready()
    assert reason(f.take, start(2, 2)) == "stale"
    f.ran(1)  # never backwards
    assert f.slot == 3


def test_a_wallclock_follower_checks_the_agreed_start():
    trial_ns = 10 * SEC
    f = Follower(RUN, wall_trial_ns=trial_ns)
    f.said_ready()
    now = 1000 * SEC
    ahead = int(START_AHEAD_MAX * SEC)
    for wall, why in ((None, "malformed"), (0, "malformed"), (now + ahead + 1, "future"),
                      (now - trial_ns - 1, "stale")):
        assert reason(f.take, start(0, 0, start_wall_ns=wall), now_wall_ns=now) == why
    assert f.seen == -1
    assert f.take(start(0, 0, start_wall_ns=now + ahead), now_wall_ns=now).slot == 0
    with pytest.raises(ValueError, match="wall clock"):
        f.take(start(1, 1, start_wall_ns=now))
    assert check_start_wall(now - trial_ns, now, trial_ns) == now - trial_ns


# ------------------------------------------------------------------ every follower

def plant_follower():
    core = KinematicPlant(make_config("paper-triangle3", seed=1, run_id=RUN))
    return core, lambda ev: core.on_event(ev, 0.0)


def links_follower():
    core = EmulatedLinks(make_config("paper-triangle3", seed=1, run_id=RUN))
    return core, lambda ev: core.on_event(ev)[0]


def bridge_follower():
    """A bridge whose robot stands at its initial pose (a return ends at the next tick)."""
    cfg = make_config("paper-triangle3", links="direct", mode="wallclock", run_id=RUN)
    core = Bridge(cfg, 1, name="bridge_1", initial=(0.0, 0.0, 0.0))
    core.on_odom((0.0, 0.0, 0.0), 0.0)
    return core, lambda ev: core.on_event(ev, 0.0, ev.start_wall_ns or 1)


def robot_follower():
    """A robot node's learner and follower (the node holds both)."""
    cfg = make_config("paper-triangle3", seed=1, run_id=RUN)
    lrn = RobotLearner(Problem.from_scenario(cfg.scenario), 1, cfg.clock)
    robot = SimpleNamespace(learner=lrn, follower=Follower(cfg.run_id))

    def take(ev: TrialEvent) -> TrialEvent | None:  # as formation_ilc.nodes.robot does
        got = robot.follower.take(ev, idle=lrn.done_with(robot.follower.slot))
        if got is not None and got.event == ABORT:
            lrn.abort(got.slot)
            if got.kept >= 0:
                lrn.redo(got.kept)
        return got

    return robot, take


FOLLOWERS = {"plant": plant_follower, "links": links_follower, "bridge": bridge_follower,
             "robot": robot_follower}


@pytest.mark.parametrize("kind", list(FOLLOWERS))
def test_every_follower_refuses_the_same_starts_for_the_same_reasons(kind):
    core, take = FOLLOWERS[kind]()
    f = core.follower

    def start(slot: int, seq: int, trial: int | None = None) -> TrialEvent:
        # a bridge's starts are on the wall-clock grid: the remainder by dT is the slot
        wall = {"start_wall_ns": 1000 * SEC + slot} if kind == "bridge" else {}
        return start_of(slot, seq, trial, **wall)

    assert reason(take, start(0, 0)) == "unexpected"  # before its first ready
    f.said_ready()
    assert take(start(0, 0)).slot == 0
    assert take(start(0, 0)) is None                  # the leader's repeat: nothing to do
    assert reason(take, start(0, 1)) == "stale"       # a second start of the slot
    assert reason(take, start(2, 1)) == "future"      # a later trial
    assert reason(take, start(1, 1)) == "unexpected"  # inside trial 0
    f.said_ready()  # a ready mid-trial does not open the next slot either
    assert reason(take, start(1, 1)) == "unexpected"
    assert reason(take, TrialEvent(START, 1, 1, 1, run="x")) == "foreign"
    assert f.slot == 0 and f.seen == 0
    # aborted: the node leaves the trial; the next slot is taken once it said ready
    assert take(TrialEvent(ABORT, 0, 0, 1)).event == ABORT
    assert take(TrialEvent(ABORT, 0, 0, 1)) is None
    assert reason(take, start(0, 0)) == "stale"       # a replay of the start it aborted
    assert reason(take, start(0, 1)) == "stale"       # a start with the abort's seq
    if kind == "bridge":
        assert reason(take, start(1, 2, trial=0)) == "unexpected"  # driving back
        assert core.tick(0.1, 2).returned.reached
    f.said_ready()
    assert take(start(1, 2, trial=0)).slot == 1


def test_each_follower_says_when_it_is_inside_a_trial():
    plant, take = plant_follower()
    plant.said_ready()
    take(start(0, 0))
    assert plant.in_trial
    links, take_l = links_follower()
    links.said_ready()
    take_l(start(0, 0))
    assert links.active and not links.reported
    bridge, take_b = bridge_follower()
    bridge.said_ready(0, (0.0, 0.0, 0.0))
    assert bridge.phase == IDLE and bridge.answers_abort()
    take_b(start(0, 0, start_wall_ns=1000 * SEC))
    assert bridge.phase == TRIAL
    take_b(TrialEvent(ABORT, 0, 0, 1))
    assert bridge.phase == RETURN and not bridge.answers_abort()
    robot, take_r = robot_follower()
    robot.follower.said_ready()
    take_r(start(0, 0))
    lrn = robot.learner
    assert lrn.done_with(-1)
    lrn.on_pose(lrn.clock.stamp_ns(0, 0), lrn.pb.eta_d[1, 0])
    assert not lrn.done_with(0)
    lrn.abort(0)
    assert lrn.done_with(0)


@pytest.mark.parametrize("kind", list(FOLLOWERS))
def test_with_the_run_key_every_follower_takes_only_the_leaders_sealed_events(kind):
    """DDS names no writer to a reader (rclpy's message info has no publisher GID), so a
    start or abort from any other writer with the run id looks like the leader's. With the
    run key, a follower takes only what the key sealed: a forged or stale leader's events
    are ``foreign`` and move nothing."""
    from formation_ilc.protocol.schedule import seal

    key = bytes(range(16))
    core, take = FOLLOWERS[kind]()
    f = core.follower
    f.key = key
    wall = {"start_wall_ns": 1000 * SEC} if kind == "bridge" else {}
    f.said_ready()
    forged = TrialEvent(START, 0, 0, 0, run=RUN, **wall)
    assert reason(take, forged) == "foreign"
    assert reason(take, seal(forged, b"\x01" * 16)) == "foreign"   # another key
    assert reason(take, seal(TrialEvent(ABORT, 0, 0, 5, run=RUN), None)) == "foreign"
    assert (f.slot, f.seen) == (-1, -1)                            # nothing moved
    assert take(seal(forged, key)).slot == 0
    assert reason(take, TrialEvent(ABORT, 0, 0, 1, run=RUN)) == "foreign"
    assert (f.slot, f.seen) == (0, 0)
