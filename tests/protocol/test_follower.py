"""One rule for taking the leader's starts and aborts (formation_ilc.protocol.schedule.Follower),
without ROS."""

from __future__ import annotations

import pytest

from formation_ilc.core.clock import Rejected
from formation_ilc.protocol.schedule import ABORT, DONE, END, START, Follower, TrialEvent
from formation_ilc.protocol.wallclock import START_AHEAD_MAX, check_start_wall

RUN = "run-a"
SEC = 1_000_000_000


def start(slot: int, seq: int, trial: int | None = None, **kw) -> TrialEvent:
    return TrialEvent(START, slot if trial is None else trial, slot, seq, **kw)


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
    (start(1, 0), "stale"),                           # its seq again
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
