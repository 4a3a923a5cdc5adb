"""The trial schedule's fault handling, without ROS: aborts, acks, commits, restarts, and a
robot learner that forgets an aborted trial (formation_ilc.protocol.schedule,
formation_ilc.protocol.learner)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from formation_ilc.config.runconfig import make_config
from formation_ilc.core.clock import Malformed, Rejected
from formation_ilc.model.simulate import Problem
from formation_ilc.protocol.learner import RobotLearner
from formation_ilc.protocol.schedule import (
    Ready,
    Schedule,
    ScheduleError,
    StartRepeat,
    TrialEvent,
)
from formation_ilc.store.robotstate import load_state, save_state

ROBOTS = ["robot_1", "robot_2"]
NODES = [*ROBOTS, "robot_sim", "monitor"]


def sched() -> Schedule:
    return Schedule(list(NODES), set(ROBOTS), trials=3)


def ready_all(s: Schedule, trial: int, seen: int, boots: dict[str, str] | None = None) -> None:
    for n in NODES:
        b = (boots or {}).get(n, "b0")
        s.on_ready(Ready(n, trial, b, seen, passive=n == "monitor"))


def run_slot(s: Schedule) -> tuple[int, int]:
    nxt = s.next_start()
    assert nxt is not None
    seq = s.started(nxt[1])
    s.ended(nxt[1])
    ready_all(s, nxt[0] + 1, seq)
    return nxt


def test_trials_run_in_slots_equal_to_iterations_without_faults():
    s = sched()
    assert s.next_start() is None  # nobody ready yet
    ready_all(s, 0, -1)
    assert [run_slot(s) for _ in range(3)] == [(0, 0), (1, 1), (2, 2)]
    assert s.done and s.committed == 3


def test_the_next_trial_waits_for_every_node_and_for_learning():
    s = sched()
    ready_all(s, 0, -1)
    seq = s.started(0)
    assert s.next_start() is None  # running
    s.ended(0)
    s.on_ready(Ready("robot_1", 1, "b0", seq))
    s.on_ready(Ready("robot_sim", 1, "b0", seq))
    assert s.next_start() is None and s.waiting_for() == ["robot_2"]
    # a ready sent before the start (seen = -1 would mean "never saw an event", so use 0
    # of an earlier seq) does not count as robot_2's answer to this trial
    s.on_ready(Ready("robot_2", 0, "b0", seq - 1))
    assert s.next_start() is None and s.committed == 0
    s.on_ready(Ready("robot_2", 1, "b0", seq))
    assert s.committed == 1 and s.next_start() == (1, 1)


def test_a_node_restarting_during_a_trial_aborts_it_and_the_iteration_runs_again():
    s = sched()
    ready_all(s, 0, -1)
    run_slot(s)
    seq = s.started(1)
    why = s.on_ready(Ready("robot_2", 1, "new-boot", -1))  # came back from its state file
    assert why == "robot_2 restarted during slot 1"
    assert s.abort_pending == 1 and s.seq == seq + 1 and s.restarted == {"robot_2": 1}
    # everyone else must answer the abort; their old readies do not
    assert s.next_start() is None
    assert set(s.acks_missing()) == {"robot_1", "robot_sim"}
    s.on_ready(Ready("robot_1", 1, "b0", s.seq))
    assert s.next_start() is None
    s.on_ready(Ready("robot_sim", 1, "b0", s.seq))
    assert s.next_start() == (1, 2)  # iteration 1 again, in a new slot
    assert s.committed == 1


def test_a_restart_between_trials_aborts_nothing():
    s = sched()
    ready_all(s, 0, -1)
    run_slot(s)
    assert s.on_ready(Ready("robot_2", 1, "new-boot", -1)) is None
    assert s.next_start() == (1, 1)


def test_a_restart_after_the_trial_ended_but_before_everyone_learned_aborts_it():
    s = sched()
    ready_all(s, 0, -1)
    seq = s.started(0)
    s.ended(0)
    s.on_ready(Ready("robot_1", 1, "b0", seq))  # robot_1 learned slot 0 ...
    assert s.on_ready(Ready("robot_2", 0, "new", -1)) is not None  # ... robot_2 died
    assert s.abort_pending == 0 and s.committed == 0
    # robot_1 rolls back and answers; then iteration 0 runs again in slot 1
    s.on_ready(Ready("robot_1", 0, "b0", s.seq))
    s.on_ready(Ready("robot_sim", 1, "b0", s.seq))
    assert s.next_start() == (0, 1)


def test_a_restarted_leader_aborts_the_slot_it_left_open(tmp_path):
    state = tmp_path / "leader.json"
    s = sched()
    ready_all(s, 0, -1)
    run_slot(s)
    seq = s.started(1)
    s.save(state)
    assert json.loads(state.read_text()) == {"committed": 1, "slot": 1, "seq": seq,
                                             "open": True, "kept": 0}
    s2 = sched()
    assert s2.restore(state)
    assert s2.abort_pending == 1 and s2.seq == seq + 1
    # the readies latched from before the restart are not answers to the abort
    ready_all(s2, 2, seq)
    assert s2.next_start() is None
    ready_all(s2, 1, s2.seq)
    assert s2.next_start() == (1, 2)
    assert not sched().restore(tmp_path / "none.json")


def test_a_robot_that_lost_its_memory_stops_the_schedule_with_a_clear_error():
    s = sched()
    ready_all(s, 0, -1)
    run_slot(s)
    s.on_ready(Ready("robot_2", 0, "new", -1))
    with pytest.raises(ScheduleError, match="robot_2 is ready for trial 0, but the team has "
                                            "learned 1 trials"):
        s.next_start()


@pytest.mark.parametrize("d", [{"event": "start", "trial": "1"}, {"event": "jump", "trial": 1},
                               {"event": "start", "trial": 2, "slot": 1},
                               {"event": "start", "trial": True}, {"trial": 1}])
def test_malformed_events_are_refused(d):
    with pytest.raises(Malformed):
        TrialEvent.from_json(d)


def test_events_and_readies_round_trip():
    ev = TrialEvent("abort", 3, 5, 9, why="robot_1 restarted")
    assert TrialEvent.from_json(ev.to_json()) == ev
    assert TrialEvent.from_json({"event": "start", "trial": 2}).slot == 2
    r = Ready("recorder", 4, "x", 2, passive=True)
    assert Ready.from_json(r.to_json()) == r
    with pytest.raises(Malformed):
        Ready.from_json({"node": "", "trial": 1})


# --------------------------------------------------------------------------- the learner

def learner_pair():
    cfg = make_config("paper-triangle3", noise=False, delay=False)
    pb = Problem.from_scenario(cfg.scenario)
    return cfg, pb


def drive_trial(lrn: RobotLearner, pb: Problem, clock, slot: int) -> None:
    """Feed robot 1 (which sees only the leader) one whole trial at its desired poses."""
    for t in range(pb.samples + 1):
        ns = clock.stamp_ns(slot, t)
        ev = lrn.on_pose(ns, pb.eta_d[0, t] + 0.1)  # off the desired path: it learns
        if ev.last:
            break
        lrn.on_link_tick("leader", ns, (ns, pb.eta_d[0, t] * 0.0))
        lrn.command()
    lrn.finish_trial()
    assert lrn.try_learn()


def test_an_aborted_trial_is_undone_and_its_labels_refused(tmp_path):
    cfg, pb = learner_pair()
    clock = cfg.clock
    lrn = RobotLearner(pb, 0, clock)
    assert lrn.neighbours == []  # robot 1 learns from its own trial and the leader
    drive_trial(lrn, pb, clock, 0)
    before = lrn.memory.copy()
    drive_trial(lrn, pb, clock, 1)
    assert lrn.iterations == 2 and not np.array_equal(lrn.memory, before)
    assert lrn.abort(1)  # learned from slot 1: rolled back
    np.testing.assert_array_equal(lrn.memory, before)
    assert (lrn.iterations, lrn.learned) == (1, 0)
    assert not lrn.abort(1)  # a repeated abort changes nothing
    with pytest.raises(Rejected) as exc:
        lrn.on_pose(clock.stamp_ns(1, 3), pb.eta_d[0, 3])
    assert exc.value.reason == "stale"
    with pytest.raises(Rejected):
        lrn.on_link_tick("leader", clock.stamp_ns(1, 0), None)
    # the iteration runs again in slot 2, from the memory of before
    drive_trial(lrn, pb, clock, 2)
    assert lrn.iterations == 2
    # the state file carries it through a crash, prev memory included
    path = tmp_path / "robot_1.npz"
    save_state(path, lrn.state(), cfg.scenario, 1)
    fresh = RobotLearner(pb, 0, clock)
    st = load_state(path, cfg.scenario, 1)
    assert st is not None
    fresh.restore(st)
    np.testing.assert_array_equal(fresh.memory, lrn.memory)
    assert (fresh.iterations, fresh.learned) == (2, 2)
    assert fresh.abort(2)
    np.testing.assert_array_equal(fresh.memory[0], st.prev_memory)
    with pytest.raises(ValueError, match="robot 1, this node is robot 2"):
        load_state(path, cfg.scenario, 2)
    assert load_state(tmp_path / "none.npz", cfg.scenario, 1) is None


def test_a_step_undone_on_an_abort_the_leader_did_not_send_is_taken_back():
    """A forged abort of the slot a robot learned last (the team had committed it): the
    robot undoes the step; the leader's next abort names that slot as kept, and the robot
    takes the step back, bit for bit. A step it has learned past is not taken back."""
    cfg, pb = learner_pair()
    clock = cfg.clock
    lrn = RobotLearner(pb, 0, clock)
    drive_trial(lrn, pb, clock, 0)
    before = lrn.memory.copy()
    drive_trial(lrn, pb, clock, 1)
    learned = lrn.memory.copy()
    assert lrn.abort(1)                        # the forgery: the step of slot 1 undone
    np.testing.assert_array_equal(lrn.memory, before)
    assert not lrn.redo(0)                     # not a step it undid
    assert lrn.abort(3) is False               # the leader's abort of the next slot...
    assert lrn.redo(1)                         # ...names slot 1 as kept: taken back
    np.testing.assert_array_equal(lrn.memory, learned)
    np.testing.assert_array_equal(lrn.prev_memory, before)
    assert (lrn.iterations, lrn.learned) == (2, 1) and lrn.done_with(3)
    assert not lrn.redo(1)                     # once
    drive_trial(lrn, pb, clock, 4)             # and it learns on from there
    assert lrn.iterations == 3
    # undone, then a later slot learned: the old step is not taken back over it
    other = RobotLearner(pb, 0, clock)
    drive_trial(other, pb, clock, 0)
    assert other.abort(0)
    drive_trial(other, pb, clock, 1)
    assert not other.redo(0) and other.iterations == 1


def test_a_robot_restored_with_the_aborted_slots_learning_must_roll_it_back(tmp_path):
    """The launcher was killed after the robots learned slot 1 but before the leader
    committed it: on resume every robot process is new (seen = -1) yet holds slot 1's
    learning step; the abort is done only when each has rolled it back."""
    state = tmp_path / "leader.json"
    s = sched()
    ready_all(s, 0, -1)
    run_slot(s)
    s.started(1)
    s.ended(1)
    s.save(state)
    s2 = sched()
    s2.restore(state)
    ready_all(s2, 2, -1, boots={n: "new" for n in NODES})  # restored, slot 1 learned
    assert set(s2.acks_missing()) == {"robot_1", "robot_2"}
    assert s2.next_start() is None
    ready_all(s2, 1, s2.seq, boots={n: "new" for n in NODES})  # rolled back
    assert s2.next_start() == (1, 2)


def test_a_restarted_recorder_writes_a_new_part_and_leaves_the_first_alone(tmp_path):
    import sys

    from formation_ilc.cli.launch import Stack

    st = Stack(dict(__import__("os").environ), tmp_path / "logs")
    argv = [sys.executable, "-c", "pass", "--output", str(tmp_path / "run.mcap")]
    st.start("recorder", argv)
    assert "run.part1.mcap" in st.restart("recorder")
    assert "run.part2.mcap" in st.restart("recorder")
    assert st.argv["recorder"][-1] == str(tmp_path / "run.part2.mcap")
    st.stop()
    assert (tmp_path / "logs" / "recorder.log").read_text().count("--- restarted") == 2


def test_a_passive_node_restarting_aborts_nothing():
    s = sched()
    ready_all(s, 0, -1)
    s.started(0)
    assert s.on_ready(Ready("monitor", 3, "new", -1, passive=True)) is None
    assert s.abort_pending is None


def test_a_supervisors_down_notice_makes_the_leader_wait_for_the_restarted_recorder():
    """The launcher says a recorder process died (its pid as boot): no slot starts until
    the restarted recorder says ready; a notice about an older process changes nothing."""
    s = Schedule(["robot_1", "recorder"], {"robot_1"}, trials=3)
    s.on_ready(Ready("robot_1", 0, "a"))
    s.on_ready(Ready("recorder", 3, "100", passive=True))
    assert s.next_start() == (0, 0)
    s.started(0)
    s.ended(0)
    s.on_ready(Ready("recorder", 3, "99", passive=True, down=True))  # not its process
    s.on_ready(Ready("robot_1", 1, "a", seen=s.seq))
    assert s.waiting_for() == [] and s.committed == 1
    s.on_ready(Ready("recorder", 3, "100", passive=True, down=True))
    assert s.waiting_for() == ["recorder"] and s.next_start() is None
    assert s.on_ready(Ready("recorder", 3, "101", passive=True)) is None  # no abort
    assert s.next_start() == (1, 1)
    assert Ready.from_json(Ready("recorder", 3, "1", down=True).to_json()).down

# --------------------------------------------------------------------------- edges
# (what the protocol tests above leave open: the exact wire form, defaults, refusals, the
# state file's failures and the schedule's corner decisions)

def test_events_carry_only_the_fields_they_have_and_default_the_rest():
    bare = TrialEvent("end", 4, 4)
    assert bare.to_json() == {"event": "end", "trial": 4, "slot": 4, "seq": -1}
    full = TrialEvent("start", 0, 2, 7, stamp_ns=0, start_wall_ns=0, why="w", run="r1")
    assert full.to_json() == {"event": "start", "trial": 0, "slot": 2, "seq": 7,
                              "stamp_ns": 0, "start_wall_ns": 0, "why": "w", "run": "r1"}
    assert TrialEvent.from_json(full.to_json()) == full
    got = TrialEvent.from_json({"event": "done", "trial": 0})
    assert (got.slot, got.seq, got.stamp_ns, got.start_wall_ns, got.why, got.run) == (
        0, -1, None, None, "", "")
    # trial == slot and trial < slot are both fine
    assert TrialEvent.from_json({"event": "abort", "trial": 1, "slot": 1}).slot == 1
    assert TrialEvent.from_json({"event": "abort", "trial": 0, "slot": 3}).slot == 3


def test_readies_carry_only_the_fields_they_have_and_default_the_rest():
    assert Ready("robot_1", 0).to_json() == {"node": "robot_1", "trial": 0, "boot": "",
                                             "seen": -1}
    r = Ready("monitor", 2, "b", 5, passive=True, run="r1")
    assert r.to_json() == {"node": "monitor", "trial": 2, "boot": "b", "seen": 5,
                           "passive": True, "run": "r1"}
    got = Ready.from_json({"node": "robot_2", "trial": 3})
    assert got == Ready("robot_2", 3, "", -1, False, "")


@pytest.mark.parametrize("d", [{"event": "start", "trial": -1, "slot": 0},
                               {"event": "start", "trial": 0, "stamp_ns": "5"},
                               {"event": "start", "trial": 0, "start_wall_ns": 1.5},
                               {"event": "start", "trial": 0, "seq": None},
                               {"event": "start", "trial": 0, "slot": False}])
def test_events_with_a_bad_field_are_refused_naming_it(d):
    with pytest.raises(Malformed):
        TrialEvent.from_json(d)


@pytest.mark.parametrize("d, field", [({"node": 5, "trial": 1}, "node"),
                                      ({"trial": 1}, "node"),
                                      ({"node": "a"}, "'trial'"),
                                      ({"node": "a", "trial": 1, "seen": "0"}, "'seen'")])
def test_readies_with_a_bad_field_are_refused_naming_it(d, field):
    with pytest.raises(Malformed, match=field):
        Ready.from_json(d)


def test_a_damaged_leader_state_file_is_one_clear_error(tmp_path):
    path = tmp_path / "leader.json"
    path.write_text("{not json")
    with pytest.raises(ScheduleError, match="unreadable schedule state"):
        sched().restore(path)
    path.write_text(json.dumps({"committed": 1, "slot": 1, "open": False}))
    with pytest.raises(ScheduleError, match="bad schedule state: 'seq'"):
        sched().restore(path)
    path.write_text(json.dumps({"committed": "x", "slot": 1, "seq": 1, "open": False}))
    with pytest.raises(ScheduleError, match="bad schedule state"):
        sched().restore(path)
    path.write_text("[]")
    with pytest.raises(ScheduleError, match="bad schedule state"):
        sched().restore(path)


def test_a_leader_restored_between_trials_goes_on_without_an_abort(tmp_path):
    path = tmp_path / "leader.json"
    s = sched()
    ready_all(s, 0, -1)
    run_slot(s)
    s.save(path)
    assert json.loads(path.read_text()) == {"committed": 1, "slot": 0, "seq": 0,
                                            "open": False, "kept": 0}
    s2 = sched()
    assert s2.restore(path)
    assert (s2.committed, s2.slot, s2.seq, s2.abort_pending, s2.open, s2.running) == (
        1, 0, 0, None, False, False)
    assert s2.kept == 0  # the slot last committed, which its aborts name
    # a state file written before the kept slot was saved still reads (kept unknown)
    path.write_text('{"committed": 1, "slot": 0, "seq": 0, "open": false}')
    s3 = sched()
    assert s3.restore(path) and s3.kept == -1
    ready_all(s2, 1, -1)
    assert s2.next_start() == (1, 1)
    sched().save(None)  # no state directory: nothing written, no error


def test_the_state_stays_open_while_an_abort_awaits_its_answers(tmp_path):
    s = sched()
    ready_all(s, 0, -1)
    s.started(0)
    s.begin_abort("test")
    assert not s.open and s.abort_pending == 0
    assert s.state() == {"committed": 0, "slot": 0, "seq": 1, "open": True, "kept": -1}
    assert not s.abort_done()
    ready_all(s, 0, s.seq)
    assert s.acks_missing() == [] and s.abort_done() and s.abort_pending is None
    assert s.state()["open"] is False
    assert s.abort_done()  # nothing pending: done at once


def test_readies_of_unknown_nodes_are_ignored_and_restarts_are_counted():
    s = sched()
    assert s.on_ready(Ready("stranger", 0, "b0", -1)) is None
    assert s.ready == {} and s.boots == {} and s.answered == set()
    ready_all(s, 0, -1)
    for boot in ("b1", "b2", "b2"):  # the same boot twice is one restart
        s.on_ready(Ready("robot_sim", 0, boot, -1))
    assert s.restarted == {"robot_sim": 2}


def test_a_ready_answers_the_last_event_only_if_it_has_seen_it():
    s = sched()
    ready_all(s, 0, -1)
    seq = s.started(0)
    s.ended(0)
    assert s.waiting_for() == ["robot_1", "robot_2", "robot_sim"]  # the monitor is passive
    s.on_ready(Ready("robot_sim", 1, "b0", seq))
    s.on_ready(Ready("robot_1", 1, "b0", seq + 1))  # seen a later event: also an answer
    assert s.waiting_for() == ["robot_2"]


def test_a_robot_that_learned_the_slot_without_its_start_answers_it():
    """The start of slot 1 never reached robot_2 (stopped as it went out) but robot_2 ran
    and learned the slot from its poses: its ready says one trial more than the team and
    an older seq. That answers the ended slot, and the run goes on; the same ready while
    the slot runs, or one trial short, answers nothing (CI stop 34: the leader waited
    for robot_2 until its watchdog gave up)."""
    s = sched()
    ready_all(s, 0, -1)
    run_slot(s)  # slot 0: seq 0
    seq = s.started(1)
    for n in ("robot_1", "robot_sim"):
        s.on_ready(Ready(n, 2, "b0", seq))
    s.on_ready(Ready("robot_2", 2, "b0", seq - 1))
    assert s.committed == 1 and s.open  # the reference still runs
    s.on_ready(Ready("robot_2", 1, "b0", seq - 1))  # its ready of slot 0, again
    s.ended(1)
    assert s.committed == 1 and s.waiting_for() == ["robot_2"]
    assert "has not answered seq 1 (its last ready saw seq 0)" in s.explain_wait()[0]
    s.on_ready(Ready("robot_2", 2, "b0", seq - 1))
    assert s.committed == 2 and not s.open and s.waiting_for() == []
    assert s.next_start() == (2, 2)


def test_a_robot_that_learned_an_aborted_slot_still_owes_its_roll_back():
    """One trial more than the team answers an open slot, never an abort."""
    s = sched()
    ready_all(s, 0, -1)
    seq = s.started(0)
    s.ended(0)
    s.begin_abort("robot_sim asked")
    ready_all(s, 1, seq)  # learned the aborted slot, and missed the abort
    assert s.abort_pending == 0 and s.committed == 0
    assert sorted(s.acks_missing()) == ["robot_1", "robot_2", "robot_sim"]


def test_a_slot_that_has_not_ended_is_not_committed_and_other_slots_do_not_end_it():
    s = sched()
    ready_all(s, 0, -1)
    seq = s.started(0)
    ready_all(s, 1, seq)  # every robot reports it learned, but the reference still runs
    assert s.committed == 0 and s.open and not s.done
    s.ended(5)
    assert s.running and s.committed == 0
    s.ended(0)
    assert s.committed == 1 and not s.open


def test_done_needs_every_trial_committed_and_no_open_slot():
    s = Schedule(list(NODES), set(ROBOTS), trials=1)
    assert not s.done
    ready_all(s, 0, -1)
    nxt = s.next_start()
    assert nxt == (0, 0)
    seq = s.started(0)
    s.ended(0)
    assert not s.done
    ready_all(s, 1, seq)
    assert s.done and s.committed == 1
    s2 = Schedule(list(NODES), set(ROBOTS), trials=1, committed=1, open=True)
    assert not s2.done


def test_a_fresh_leader_next_to_robots_that_learned_takes_their_count():
    s = sched()
    ready_all(s, 2, -1)  # no leader state, robots learned 2 trials
    assert s.next_start() == (2, 0) and s.committed == 2
    s = sched()
    s.on_ready(Ready("robot_1", 2, "b0", -1))
    s.on_ready(Ready("robot_2", 1, "b0", -1))
    s.on_ready(Ready("robot_sim", 0, "b0", -1))
    s.on_ready(Ready("monitor", 0, "b0", -1, passive=True))
    with pytest.raises(ScheduleError, match="the robots' learned trials disagree"):
        s.next_start()
    # once a slot has run, robots that are ahead of the schedule are an error too
    s = sched()
    ready_all(s, 0, -1)
    run_slot(s)
    ready_all(s, 2, s.seq)
    with pytest.raises(ScheduleError, match="disagree"):
        s.next_start()


def test_events_and_readies_are_values():
    """Frozen dataclasses: a decoded event or ready cannot be changed by a handler it is
    passed to, and equal ones hash alike (they can key a dict or a set)."""
    ev = TrialEvent("start", 1, 2, 3, stamp_ns=10, run="r")
    assert {ev, TrialEvent.from_json(ev.to_json())} == {ev}
    r = Ready("robot_1", 1, "b", 2)
    assert {r, Ready.from_json(r.to_json())} == {r}
    with pytest.raises(AttributeError):
        ev.trial = 0  # type: ignore[misc]
    with pytest.raises(AttributeError):
        r.trial = 0  # type: ignore[misc]


def test_a_ready_that_saw_an_earlier_event_is_no_answer_even_the_first_one():
    s = sched()
    ready_all(s, 0, -1)
    run_slot(s)  # slot 0: seq 0
    assert s.started(1) == 1
    s.ended(1)
    s.on_ready(Ready("robot_sim", 2, "b0", 0))  # answers slot 0's start, not slot 1's
    assert "robot_sim" in s.waiting_for()
    s.on_ready(Ready("robot_sim", 2, "b0", 1))
    assert "robot_sim" not in s.waiting_for()


def test_a_restarted_node_that_saw_an_event_must_still_answer_the_abort():
    """A node whose new process reports seen = 0 (it restored the seq of slot 0's start)
    has not answered the abort of slot 1; one that reports -1 holds nothing and has."""
    s = sched()
    ready_all(s, 0, -1)
    run_slot(s)  # seq 0
    s.started(1)  # seq 1
    assert s.on_ready(Ready("robot_sim", 1, "new", 0)) is not None
    assert "robot_sim" in s.acks_missing()
    s = sched()
    ready_all(s, 0, -1)
    run_slot(s)
    s.started(1)
    assert s.on_ready(Ready("robot_sim", 1, "new", -1)) is not None
    assert "robot_sim" not in s.acks_missing()


def test_a_start_goes_out_again_only_while_its_slot_does_not_move():
    rep = StartRepeat(2.0)
    assert rep.again(100.0) is None  # nothing started
    ev = TrialEvent("start", 3, 4, 7)
    rep.sent(ev, 10.0)
    assert rep.again(11.9) is None
    assert rep.again(12.0) is ev       # 2 s without a sample
    assert rep.again(13.0) is None     # then every 2 s
    assert rep.again(14.0) is ev
    rep.moved(15.0)                    # a sample: the next repeat is 2 s after it
    assert rep.again(16.5) is None
    assert rep.again(17.0) is ev
    rep.stop()                         # ended or aborted
    assert rep.again(1e9) is None
    assert rep.count == 3
