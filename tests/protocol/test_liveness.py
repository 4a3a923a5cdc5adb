"""Liveness without ROS: the leader re-asserts its schedule against events it did not send,
a forged "down" cannot take a live node's ready away, a stuck phase passes its bound and
gives up after its retries, and the resume point is decided from state files that must tell
one story (formation_ilc.protocol.schedule, watchdog, resume)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from formation_ilc.config.scenario import load_scenario
from formation_ilc.protocol.resume import ResumeError, resume_point
from formation_ilc.protocol.schedule import ABORT, START, Ready, ScheduleError, TrialEvent
from formation_ilc.protocol.watchdog import (
    READY,
    SAMPLE,
    SECURE_PER_PAIR_S,
    STARTUP,
    Bounds,
    Watchdog,
)
from formation_ilc.store.robotstate import RobotState, save_state, state_path

from .test_schedule import ready_all, run_slot, sched


def answer(s, trial: int) -> None:
    """Every node answers the pending abort (robots ready for ``trial``)."""
    ready_all(s, trial, s.seq)


def test_a_forged_abort_of_the_running_slot_is_re_asserted_with_a_newer_seq():
    s = sched()
    ready_all(s, 0, -1)
    run_slot(s)                       # trial 0 committed in slot 0
    seq = s.started(1)
    assert s.foreign(TrialEvent(START, 1, 1, seq)) is None  # its own start comes back
    forged = TrialEvent(ABORT, 1, 1, seq + 1, why="forged")
    why = s.foreign(forged)
    assert why is not None and "did not send" in why
    # the slot is aborted by the leader itself, with a seq beyond the forged one: the
    # followers that took the forgery (seen = seq + 1) take this one too
    assert s.abort_pending == 1 and s.seq == seq + 2 and not s.running
    assert s.sent[s.seq] == (ABORT, 1, 1)
    assert s.foreign(TrialEvent(ABORT, 1, 1, s.seq)) is None  # its own abort, echoed
    answer(s, 1)
    assert s.abort_done() and s.next_start() == (1, 2)
    assert s.foreign_events == 1


def test_a_forged_start_between_trials_is_aborted_and_its_slot_skipped():
    s = sched()
    ready_all(s, 0, -1)
    run_slot(s)
    why = s.foreign(TrialEvent(START, 1, 1, s.seq + 1))
    assert why is not None
    assert s.abort_pending == 1 and s.seq == 2
    answer(s, 1)
    assert s.next_start() == (1, 2)


def test_a_forged_abort_of_the_committed_slot_never_takes_the_trial_back():
    """Without sealed events robots may take it and undo the step learned from it (they
    keep one). Before, the leader un-committed the trial and waited for every robot to
    roll back, which those that had not taken the forgery never did (status 4). Now the
    trial stays committed: the leader aborts the next slot, naming the committed one as
    ``kept``; a robot that undid its step takes it back, and the run goes on."""
    s = sched()
    ready_all(s, 0, -1)
    run_slot(s)
    run_slot(s)
    assert s.committed == 2 and s.committed_slot == 1
    why = s.foreign(TrialEvent(ABORT, 1, 1, s.seq + 1))
    assert why is not None and "committed: it stands" in why
    assert s.committed == 2 and s.abort_pending == 2 and s.kept == 1
    answer(s, 2)              # every robot is back at 2 learned trials
    assert s.abort_done() and s.next_start() == (2, 3)


def test_a_forged_abort_racing_the_next_start_aborts_the_running_slot_only():
    """The forger gives its abort of the committed slot the seq of the leader's next
    start: some followers take one, some the other. The leader aborts the running slot
    (newer seq), naming the committed one; the trial is not taken back."""
    s = sched()
    ready_all(s, 0, -1)
    run_slot(s)
    seq = s.started(1)
    why = s.foreign(TrialEvent(ABORT, 0, 0, seq))  # the same seq as its start of slot 1
    assert why is not None and s.abort_pending == 1 and s.kept == 0 and s.committed == 1
    assert s.seq == seq + 1 and s.sent[s.seq] == (ABORT, 1, 1)
    answer(s, 1)
    assert s.next_start() == (1, 2)


def test_a_robot_that_undid_a_committed_step_unseen_is_asked_once_to_take_it_back():
    """The leader never saw the forged abort (only its effect): a robot idle and one trial
    behind the team. It aborts the next slot naming the committed one, once per robot
    process; a robot that cannot take the step back stops the run with a clear error."""
    s = sched()
    ready_all(s, 0, -1)
    run_slot(s)
    assert s.undone() is None
    s.on_ready(Ready("robot_2", 0, "b0", s.seq))  # robot_2 undid slot 0's step
    why = s.undone()
    assert why is not None and "robot_2 undid trial 0 (slot 0)" in why
    assert s.abort_pending == 1 and s.kept == 0
    answer(s, 1)
    assert s.next_start() == (1, 2)
    s.on_ready(Ready("robot_2", 0, "b0", s.seq))  # it could not take it back
    assert s.undone() is None  # asked once
    with pytest.raises(ScheduleError, match="robot_2 undid a committed learning step"):
        s.next_start()


def test_a_leader_seals_its_events_and_counts_unsealed_ones_without_moving():
    """With a run key every event the leader publishes carries its seal; an unsealed start
    or abort on its topic moved no follower: counted, not re-asserted."""
    from formation_ilc.protocol.schedule import seal, sealed

    key = bytes(range(16))
    ev = TrialEvent(ABORT, 1, 1, 5, why="x", run="r", kept=0)
    tagged = seal(ev, key)
    assert sealed(tagged, key) and not sealed(ev, key) and sealed(ev, None)
    assert TrialEvent.from_json(tagged.to_json()) == tagged
    assert not sealed(seal(ev, bytes(16)), key)               # another key
    for field, value in (("slot", 2), ("seq", 6), ("kept", -1), ("why", "y"), ("run", "q")):
        forged = TrialEvent.from_json({**tagged.to_json(), field: value})
        assert not sealed(forged, key), field                   # any field changed
def test_a_ready_that_saw_an_unsent_seq_re_asserts_the_schedule():
    s = sched()
    ready_all(s, 0, -1)
    seq = s.started(0)
    r = Ready("robot_sim", 0, "b0", seq + 3)  # took a forged abort it alone saw
    s.on_ready(r)
    why = s.seen_unsent(r)
    assert why == "robot_sim saw seq 3, which the leader did not send"
    assert s.abort_pending == 0 and s.seq == seq + 4
    assert s.seen_unsent(Ready("robot_sim", 0, "b0", s.seq)) is None


def test_a_down_names_only_a_passive_node():
    s = sched()
    ready_all(s, 0, -1)
    s.on_ready(Ready("robot_2", 0, "b0", down=True))  # a robot's restart shows otherwise
    assert s.waiting_for() == []
    s.on_ready(Ready("monitor", 3, "b0", passive=True, down=True))
    assert s.waiting_for() == ["monitor"]


def test_the_wait_is_explained_node_by_node():
    s = sched()
    s.on_ready(Ready("robot_1", 0, "b0"))
    lines = s.explain_wait({"robot_2": "future: robot_2 ready for trial 5"})
    assert lines == ["robot_2 has not said ready (never seen); its last ready was refused: "
                     "future: robot_2 ready for trial 5",
                     "robot_sim has not said ready (never seen)",
                     "monitor has not said ready (never seen)"]
    # what a node not yet ready said it waits for (its diagnostics): its unmatched endpoints
    lines = s.explain_wait(waiting={"robot_sim": "/formation/robot_2/cmd_vel: 0 of 1 writers"})
    assert lines[1] == ("robot_sim has not said ready (never seen); it waits for "
                        "/formation/robot_2/cmd_vel: 0 of 1 writers")
    assert lines[0] == "robot_2 has not said ready (never seen)"
    ready_all(s, 0, -1)
    s.started(0)
    s.begin_abort("test")
    s.on_ready(Ready("robot_1", 0, "b0", s.seq))
    assert s.explain_wait()[0] == "robot_2 has not answered seq 1 (its last ready saw seq -1)"


def test_the_first_start_up_stops_within_about_its_bound():
    """Before any trial ran, re-running cannot help (nothing was lost to re-send): past its
    bound the watchdog re-reads the readies at once and gives up a quarter bound later;
    a node's first ready there is progress (a slow machine is not a stuck one)."""
    b = Bounds.for_run(dt=0.1, nodes=52, mode="lockstep", timeout=30.0)
    assert b.startup == 164.0
    w = Watchdog(b)
    w.moved(0.0, STARTUP)
    assert w.first_startup
    assert not w.expired(10.0, STARTUP)
    w.moved(10.0, STARTUP)  # a node said ready: the bound runs from here
    assert not w.expired(173.0, STARTUP)
    assert w.expired(175.0, STARTUP) and w.acting and not w.gave_up  # acts at once
    assert w.expired_bound == 164.0 and w.bound(STARTUP) == 41.0
    assert not w.expired(215.0, STARTUP)
    assert w.expired(217.0, STARTUP) and w.gave_up  # 1.25 bounds after the last progress
    assert w.expired_bound == 41.0
    # once a trial has run, a slot's start-up keeps the usual report / retries / give up
    w = Watchdog(b)
    w.moved(0.0, STARTUP)
    w.moved(10.0, SAMPLE)
    w.moved(20.0, STARTUP, progress=False)
    assert not w.first_startup
    assert w.expired(185.0, STARTUP) and not w.acting
    assert w.expired(350.0, STARTUP) and w.acting and not w.gave_up


def test_a_secure_team_s_start_up_bound_grows_with_its_pairs():
    """SROS2 participants authenticate pair by pair: 52 secure nodes and the monitor (1,378
    pairs) get SECURE_PER_PAIR_S each on top of the insecure start-up bound (the measured
    50-robot secure start-up, 279 s, is inside it); the other phases are unchanged."""
    plain = Bounds.for_run(dt=0.1, nodes=52, mode="realtime", timeout=30.0)
    secure = Bounds.for_run(dt=0.1, nodes=52, mode="realtime", timeout=30.0, secure=True)
    assert secure.startup == pytest.approx(164.0 + SECURE_PER_PAIR_S * 53 * 52 / 2)
    assert secure.startup > 279.0 > plain.startup
    assert (secure.ready, secure.sample) == (plain.ready, plain.sample)
    small = Bounds.for_run(dt=0.1, nodes=3, mode="lockstep", timeout=30.0, secure=True, scale=2)
    assert small.startup == pytest.approx(2 * (66.0 + SECURE_PER_PAIR_S * 6))


def test_the_watchdog_reports_first_then_acts_then_gives_up():
    b = Bounds.for_run(dt=0.1, nodes=7, mode="lockstep", timeout=30.0)
    assert (b.startup, b.ready, b.sample) == (74.0, 33.5, 40.0)
    assert Bounds.for_run(0.5, 7, "realtime", 30.0).sample == 10.0
    assert Bounds.for_run(0.01, 7, "realtime", 30.0).sample == 5.0
    w = Watchdog(b, retries=2)
    w.moved(0.0, SAMPLE, progress=False)
    assert not w.expired(40.0, SAMPLE)
    assert w.expired(40.5, SAMPLE) and w.strikes == 1 and not w.acting  # reports only
    assert w.expired(81.0, SAMPLE) and w.acting and not w.gave_up     # re-runs
    w.moved(81.5, READY, progress=False)  # the watchdog's own abort is no progress
    assert w.expired(115.5, READY) and w.strikes == 3 and not w.gave_up
    assert not w.expired(116.0, STARTUP)      # another phase starts its own clock
    assert w.expired(191.0, STARTUP) and w.gave_up
    w.moved(192.0, SAMPLE)                    # a real sample clears the strikes
    assert w.strikes == 0 and not w.gave_up


def test_a_bound_grows_with_the_runs_own_pace():
    """On a loaded machine every wait is long: a phase that once took 20 s without a strike
    gets 4 x 20 s before the next wait of it counts as stuck."""
    w = Watchdog(Bounds.for_run(dt=0.1, nodes=3, mode="lockstep", timeout=5.0))
    assert w.bound(SAMPLE) == 15.0
    w.moved(5000.0, SAMPLE)   # the first call starts the clock (a monotonic time)
    assert w.bound(SAMPLE) == 15.0
    w.moved(0.0, SAMPLE)
    w.moved(12.0, SAMPLE)     # a slow sample, no strike: 12 s
    assert w.bound(SAMPLE) == 48.0
    assert not w.expired(12.0 + 40.0, SAMPLE)


# --------------------------------------------------------------------------- resume
SC = load_scenario("paper-triangle3").with_options(trials=10)


def robot(it: int, slot: int, pit: int | None = None, pslot: int | None = None) -> RobotState:
    m = np.zeros((SC.samples, 2))
    return RobotState(m, it, slot, m, it - 1 if pit is None else pit,
                      slot - 1 if pslot is None else pslot)


def write(tmp_path, leader: dict | None, robots: dict[int, RobotState]) -> None:
    if leader is not None:
        (tmp_path / "leader.json").write_text(json.dumps(leader))
    for i, st in robots.items():
        save_state(state_path(tmp_path, i), st, SC, i)


def test_a_consistent_state_resumes_at_its_committed_trial(tmp_path):
    write(tmp_path, {"committed": 3, "slot": 3, "seq": 4, "open": True},
          {1: robot(3, 2), 2: robot(4, 3), 3: robot(3, 2)})  # robot 2 learned the open slot
    p = resume_point(tmp_path, SC)
    assert (p.committed, p.open_slot) == (3, 3)
    assert resume_point(tmp_path / "none", SC).committed == 0


@pytest.mark.parametrize("leader, robots, why", [
    ({"committed": 999, "slot": 999, "seq": 999, "open": False}, {},
     "committed 999 is not in 0..10"),
    ({"committed": 10, "slot": 9, "seq": 9, "open": False},
     {1: robot(3, 2), 2: robot(3, 2), 3: robot(3, 2)}, "3 trials learned .* says 10"),
    ({"committed": 3, "slot": 3, "seq": 2, "open": False}, {}, "seq 2 below slot 3"),
    ({"committed": 3, "slot": 3, "seq": 4, "open": 1}, {}, "'open' must be true or false"),
    ({"committed": 1, "slot": 1, "seq": 1, "open": False},
     {1: robot(3, 2), 2: robot(3, 2), 3: robot(3, 2)}, "3 trials learned .* says 1"),
    ({"committed": 3, "slot": 3, "seq": 3, "open": False},
     {1: robot(3, 2), 2: robot(4, 3), 3: robot(3, 2)}, "robot_2.npz: 4 trials learned"),
    ({"committed": 3, "slot": 3, "seq": 3, "open": False},
     {1: robot(3, 2), 3: robot(3, 2)}, "robot_2.npz: missing"),
    (None, {1: robot(2, 1)}, "leader.json: missing"),
])
def test_state_files_that_disagree_are_refused_naming_the_file(tmp_path, leader, robots,
                                                                why):
    write(tmp_path, leader, robots)
    with pytest.raises(ResumeError, match=why) as err:
        resume_point(tmp_path, SC)
    assert str(err.value).startswith(str(tmp_path)) and "\n" not in str(err.value)


def test_a_restored_leader_refuses_an_impossible_state(tmp_path):
    (tmp_path / "leader.json").write_text(json.dumps({"committed": 999, "slot": 999,
                                                      "seq": 999, "open": False}))
    with pytest.raises(ScheduleError, match="impossible schedule state"):
        sched().restore(tmp_path / "leader.json")
