"""formation_ilc.protocol.trialrows: rows by iteration from trajectories labelled with slots, as the
monitor (strict) and the analysis of a recording (not strict) make them."""

from __future__ import annotations

import numpy as np
import pytest

from formation_ilc.config.scenario import load_scenario
from formation_ilc.core.clock import Rejected
from formation_ilc.core.metrics import ERROR_COLUMNS, METRIC_COLUMNS, TRUE_COLUMNS
from formation_ilc.model.simulate import Problem, simulate
from formation_ilc.protocol.schedule import TrialEvent
from formation_ilc.protocol.trialrows import SlotRows
from formation_ilc.recordings.recording import recording_parts

SC = load_scenario("paper-triangle3")
PB = Problem.from_scenario(SC)
_SIM = simulate(SC, trials=3, keep=range(3))


class RUN:  # the batch run's trials, as the wire carries them
    metrics = _SIM.metrics
    eta = {k: r.eta for k, r in _SIM.records.items()}
    xi = {k: r.xi for k, r in _SIM.records.items()}


def start(trial: int, slot: int) -> TrialEvent:
    return TrialEvent("start", trial, slot)


def abort(trial: int, slot: int) -> TrialEvent:
    return TrialEvent("abort", trial, slot)


def feed(rows: SlotRows, slot: int, trial: int, true: bool = True) -> list:
    """Every robot's measured (and true) trajectory of batch trial ``trial`` in ``slot``."""
    done = []
    for r in range(PB.n):
        done += rows.trajectory(slot, r, False, RUN.eta[trial][r])
        if true:
            done += rows.trajectory(slot, r, True, RUN.xi[trial][r])
    return done


def test_rows_equal_the_batch_metrics_and_come_once_all_trajectories_are_in():
    rows = SlotRows(PB)
    rows.event(start(0, 0))
    partial = []
    for r in range(PB.n):
        partial += rows.trajectory(0, r, False, RUN.eta[0][r])
    assert partial == []  # the true trajectories are missing
    done = feed_true_only(rows, 0, 0)
    assert [d.trial for d in done] == [0]
    np.testing.assert_allclose(done[0].row, RUN.metrics[0], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(done[0].eta, RUN.eta[0])


def feed_true_only(rows: SlotRows, slot: int, trial: int) -> list:
    done = []
    for r in range(PB.n):
        done += rows.trajectory(slot, r, True, RUN.xi[trial][r])
    return done


def test_an_aborted_slot_is_dropped_and_its_iteration_counted_where_it_runs_again():
    rows = SlotRows(PB)
    rows.event(start(0, 0))
    assert [d.trial for d in feed(rows, 0, 0)] == [0]
    rows.event(start(1, 1))
    rows.trajectory(1, 0, False, RUN.eta[1][0])   # a robot finished, then a node died
    rows.event(abort(1, 1))
    with pytest.raises(Rejected) as exc:
        rows.trajectory(1, 1, False, RUN.eta[1][1])
    assert exc.value.reason == "stale"
    rows.event(start(1, 2))                        # iteration 1 again, in slot 2
    done = feed(rows, 2, 1)
    assert [d.trial for d in done] == [1]
    np.testing.assert_allclose(done[0].row, RUN.metrics[1], rtol=0, atol=1e-12)
    assert sorted(rows.rows) == [0, 1]


def test_a_slot_aborted_after_it_was_complete_keeps_its_row_and_the_repeat_is_a_duplicate():
    rows = SlotRows(PB)
    rows.event(start(0, 0))
    first = feed(rows, 0, 0)
    rows.event(abort(0, 0))
    rows.event(start(0, 1))
    with pytest.raises(Rejected) as exc:
        feed(rows, 1, 0)
    assert exc.value.reason == "duplicate"
    assert list(rows.rows) == [0] and rows.rows[0] is first[0].row


def test_strict_refuses_events_out_of_order_and_trajectories_of_slots_not_started():
    rows = SlotRows(PB, strict=True)
    with pytest.raises(Rejected, match="slot 1") as exc:  # after the next slot
        rows.trajectory(1, 0, False, RUN.eta[0][0])
    assert exc.value.reason == "future"
    rows.event(start(0, 0))
    for ev, reason in ((start(0, 0), "stale"), (start(2, 2), "future"),
                       (abort(2, 2), "unexpected"), (TrialEvent("end", 1, 1), "unexpected")):
        with pytest.raises(Rejected) as exc:
            rows.event(ev)
        assert exc.value.reason == reason, ev
    with pytest.raises(Rejected) as exc:  # the same robot twice in one slot
        rows.trajectory(0, 0, False, RUN.eta[0][0])
        rows.trajectory(0, 0, False, RUN.eta[0][0])
    assert exc.value.reason == "duplicate"


def test_strict_keeps_the_next_slots_trajectories_until_its_start_comes():
    """The trajectories and the events are two topics: a loaded monitor took robots'
    trajectories of trial 14 before its start, refused them as future and the run stopped
    as stuck. A trajectory of the next slot is kept; the start completes its row."""
    rows = SlotRows(PB, strict=True)
    rows.event(start(0, 0))
    assert [d.trial for d in feed(rows, 0, 0)] == [0]
    assert feed(rows, 1, 1) == []                  # slot 1 not started yet: kept
    done = rows.event(start(1, 1))
    assert [d.trial for d in done] == [1]
    with pytest.raises(Rejected) as exc:            # two slots ahead: still refused
        rows.trajectory(3, 0, False, RUN.eta[0][0])
    assert exc.value.reason == "future"
    # kept for a slot that is then aborted: dropped with it, and no row is made
    feed(rows, 2, 2)
    rows.event(abort(2, 2))
    assert 2 not in rows.eta and 2 not in rows.rows


def test_the_leaders_repeat_of_a_start_is_no_news_and_not_a_refusal():
    """The leader sends a start again (the same seq) while its slot does not move: the
    monitor takes it as nothing, and still refuses a replay of an older start."""
    rows = SlotRows(PB, strict=True)
    rows.event(TrialEvent("start", 0, 0, 0))
    assert rows.event(TrialEvent("start", 0, 0, 0)) == []
    rows.event(TrialEvent("abort", 0, 0, 1))
    with pytest.raises(Rejected):  # its start after its abort: a replay, not a repeat
        rows.event(TrialEvent("start", 0, 0, 0))
    rows.event(TrialEvent("start", 0, 1, 2))
    assert rows.repeat(TrialEvent("start", 0, 1, 2))
    assert rows.event(TrialEvent("start", 0, 1, 2)) == []
    assert not rows.repeat(TrialEvent("start", 0, 0, 0))
    with pytest.raises(Rejected) as exc:
        rows.event(TrialEvent("start", 0, 0, 0))
    assert exc.value.reason == "stale"
    assert (rows.started, rows.iteration_of) == (1, {0: 0, 1: 0})


def test_a_recording_takes_a_trajectory_before_its_start_and_names_the_unstarted():
    rows = SlotRows(PB, strict=False)
    assert feed(rows, 0, 0) == []                 # held: no start seen yet
    rows.trajectory(7, 1, True, RUN.xi[0][1])     # a slot no start ever names
    done = rows.event(start(0, 0))
    assert [d.trial for d in done] == [0]
    assert rows.unstarted() == [(7, 1, True)]
    # a start naming a slot that runs another iteration is refused, even here
    with pytest.raises(Rejected):
        rows.event(start(1, 0))


def test_without_a_true_state_the_true_columns_are_nan():
    rows = SlotRows(PB, strict=False)
    rows.event(start(0, 0))
    assert feed(rows, 0, 0, true=False) == []     # waits for true trajectories...
    done = rows.measured_only()                   # ...until the file says there are none
    assert [d.trial for d in done] == [0] and done[0].xi is None
    true_cols = [METRIC_COLUMNS.index(c) for c in TRUE_COLUMNS]
    assert np.isnan(done[0].row[true_cols]).all()
    other = [METRIC_COLUMNS.index(c) for c in ERROR_COLUMNS if c not in TRUE_COLUMNS]
    assert np.isfinite(done[0].row[other]).all()


def test_iterations_before_first_are_not_reported_again():
    rows = SlotRows(PB, first=1)
    rows.event(start(0, 0))
    assert feed(rows, 0, 0) == [] and rows.rows == {}
    rows.event(start(1, 1))
    assert [d.trial for d in feed(rows, 1, 1)] == [1]


def test_recording_parts_come_in_the_order_they_were_written(tmp_path):
    names = ["run.mcap", "run.part2.mcap", "run.part10.mcap", "run.part1.mcap",
             "run.resumed1.mcap", "run.resumed1.part1.mcap", "run.resumed2.mcap",
             "other.part1.mcap", "run.partx.mcap", "run.mcap.bak"]
    for n in names:
        (tmp_path / n).write_bytes(b"")
    got = [p.name for p in recording_parts(tmp_path / "run.mcap")]
    assert got == ["run.mcap", "run.part1.mcap", "run.part2.mcap", "run.part10.mcap",
                   "run.resumed1.mcap", "run.resumed1.part1.mcap", "run.resumed2.mcap"]
    # a part given by itself is read alone
    assert recording_parts(tmp_path / "run.part1.mcap") == [tmp_path / "run.part1.mcap"]


def test_a_slot_whose_start_was_lost_gets_its_iteration_from_its_neighbours():
    """A recorder killed as slot 1 began: its trajectories (latched) are in the next part,
    its start is nowhere. Slot 0 committed trial 0, slot 2 runs trial 2: slot 1 ran 1."""
    rows = SlotRows(PB, strict=False)
    rows.event(start(0, 0))
    feed(rows, 0, 0)
    feed(rows, 1, 1)                       # no start for slot 1
    rows.event(start(2, 2))
    assert rows.infer() and sorted(rows.rows) == [0, 1]
    np.testing.assert_allclose(rows.rows[1], RUN.metrics[1], rtol=0, atol=1e-12)


def test_a_lost_start_is_inferred_only_when_the_next_slot_confirms_it():
    # slot 1 was aborted (slot 2 runs the same trial again): its trajectories are dropped
    rows = SlotRows(PB, strict=False)
    rows.event(start(0, 0))
    feed(rows, 0, 0)
    feed(rows, 1, 1)
    rows.event(start(1, 2))
    assert rows.infer() == [] and 1 in rows.aborted and rows.unstarted() == []
    # the slot before was aborted: slot 1 ran its trial again; the run's done confirms it
    rows = SlotRows(PB, strict=False)
    rows.event(start(0, 0))
    rows.event(abort(0, 0))
    feed(rows, 1, 0)
    rows.event(TrialEvent("done", 1, 2))
    assert [d.trial for d in rows.infer()] == [0]
    # nothing after it: left unknown
    rows = SlotRows(PB, strict=False)
    rows.event(start(0, 0))
    feed(rows, 1, 1)
    assert rows.infer() == [] and {s for s, _, _ in rows.unstarted()} == {1}


def test_a_start_lost_with_a_killed_leader_is_explained_by_the_abort_that_follows():
    """The leader sent slot 1's start and died; its successor aborts slot 1 and starts
    slot 2: a follower at slot 0 takes both (before, it refused slot 2 and the run hung)."""
    rows = SlotRows(PB, strict=True)
    rows.event(start(0, 0))
    feed(rows, 0, 0)
    rows.event(abort(1, 1))
    rows.event(start(1, 2))
    assert [d.trial for d in feed(rows, 2, 1)] == [1]
    # a gap that no abort explains is still refused
    with pytest.raises(Rejected) as exc:
        rows.event(start(2, 4))
    assert exc.value.reason == "future"


def test_unexplained_gap():
    from formation_ilc.protocol.schedule import unexplained_gap

    assert not unexplained_gap(-1, 7, set())      # a follower that just started takes any
    assert not unexplained_gap(3, 4, set())
    assert unexplained_gap(3, 5, set())
    assert not unexplained_gap(3, 6, {4, 5})
    assert unexplained_gap(3, 6, {5})


def test_rows_count_what_the_filter_changed_and_the_contacts_noted_before_them():
    rows = SlotRows(PB, safety=True)
    rows.event(start(0, 0))
    for r in range(PB.n):
        rows.note_filtered(0, r, r + 2)
    rows.note_contacts(0, 1)
    (d,) = feed(rows, 0, 0)
    assert d.row[METRIC_COLUMNS.index("filter_active")] == sum(r + 2 for r in range(PB.n))
    assert d.row[METRIC_COLUMNS.index("contacts")] == 1
    # a robot's count missing: unknown, not a smaller sum; no contact report: unknown
    rows.event(start(1, 1))
    rows.note_filtered(1, 0, 5)
    (d,) = feed(rows, 1, 1)
    assert np.isnan(d.row[METRIC_COLUMNS.index("filter_active")])
    assert np.isnan(d.row[METRIC_COLUMNS.index("contacts")])
    assert rows.late_counts == set()
    # a plant on the wall clock says the slot's contacts after its row was made (the
    # physics bases, the last trial): the row takes them then, once, and says so
    rows.note_contacts(1, 0)
    assert rows.rows[1][METRIC_COLUMNS.index("contacts")] == 0
    assert rows.late_counts == {1}
    rows.note_contacts(1, 2)  # a count the row has is not changed again
    assert rows.rows[1][METRIC_COLUMNS.index("contacts")] == 0
    rows.note_contacts(0, 3)  # nor one it was made with
    assert rows.rows[0][METRIC_COLUMNS.index("contacts")] == 1 and rows.late_counts == {1}
    # a recording's analysis (not strict: it knows no body watchers) takes none late
    loose = SlotRows(PB, safety=True, strict=False)
    loose.event(start(0, 0))
    (d,) = feed(loose, 0, 0)
    loose.note_contacts(0, 7)
    assert np.isnan(loose.rows[0][METRIC_COLUMNS.index("contacts")]) and not loose.late_counts
    # a run without a filter changed nothing
    plain = SlotRows(PB)
    plain.event(start(0, 0))
    (d,) = feed(plain, 0, 0)
    assert d.row[METRIC_COLUMNS.index("filter_active")] == 0


def test_no_event_sequence_files_one_trial_under_another_number():
    """The hostile peer's burst (before: a copy of trial 1 filed as trial 2, exit 0): a
    start of the next slot naming the next iteration while the leader then aborts the
    running slot and runs the same iteration again there. The monitor takes only the
    starts the schedule can make: every row is its own trial's."""
    rows = SlotRows(PB, strict=True)
    rows.event(TrialEvent("start", 0, 0, 0))
    assert [d.trial for d in feed(rows, 0, 0)] == [0]
    rows.event(TrialEvent("start", 1, 1, 1))
    assert [d.trial for d in feed(rows, 1, 1)] == [1]
    # forged: slot 2 starts trial 3 (the schedule's next is 2); slot 1 again as trial 2
    for ev in (TrialEvent("start", 3, 2, 2), TrialEvent("start", 2, 1, 2)):
        with pytest.raises(Rejected) as exc:
            rows.event(ev)
        assert exc.value.reason in ("unexpected", "stale"), ev
    # the leader's own: slot 1 aborted after its row was made, trial 1 runs again in 2
    rows.event(TrialEvent("abort", 1, 1, 2))
    with pytest.raises(Rejected, match="schedule runs trial 1"):
        rows.event(TrialEvent("start", 2, 2, 3))   # a forgery of the next number
    rows.event(TrialEvent("start", 1, 2, 3))
    with pytest.raises(Rejected) as exc:
        feed(rows, 2, 1)
    assert exc.value.reason == "duplicate"         # trial 1 again: its row stands
    rows.event(TrialEvent("start", 2, 3, 4))
    assert [d.trial for d in feed(rows, 3, 2)] == [2]
    for k in range(3):
        np.testing.assert_allclose(rows.rows[k], RUN.metrics[k], rtol=0, atol=1e-12)


def test_with_the_run_key_only_sealed_events_count():
    from formation_ilc.protocol.schedule import seal

    key = b"k" * 16
    rows = SlotRows(PB, strict=True, key=key)
    with pytest.raises(Rejected) as exc:
        rows.event(TrialEvent("start", 0, 0, 0))
    assert exc.value.reason == "foreign" and rows.foreign == 1
    with pytest.raises(Rejected):
        rows.event(seal(TrialEvent("start", 0, 0, 0), b"x" * 16))
    rows.event(seal(TrialEvent("start", 0, 0, 0), key))
    assert [d.trial for d in feed(rows, 0, 0)] == [0]
    assert rows.foreign == 2


def test_an_unsealed_copy_of_the_leaders_start_is_foreign_not_a_repeat():
    """A forger that copies the leader's start (same slot and seq, no seal) after it came:
    before, a recording's reader took it for the leader's repeat (no news) and did not
    count it, so the forgeries counted depended on their order."""
    from formation_ilc.protocol.schedule import seal

    key = b"k" * 16
    rows = SlotRows(PB, strict=True, key=key)
    real = seal(TrialEvent("start", 0, 0, 0), key)
    rows.event(real)
    assert rows.repeat(real)                       # the leader's own repeat: no news
    copy = TrialEvent("start", 0, 0, 0)
    assert not rows.repeat(copy)
    with pytest.raises(Rejected) as exc:
        rows.event(copy)
    assert exc.value.reason == "foreign" and rows.foreign == 1
    assert [d.trial for d in feed(rows, 0, 0)] == [0]


def test_a_recording_prefers_the_start_that_agrees_with_the_schedule():
    """A recording of a run without sealed events: a forged start of slot 1 naming trial 2
    came before the leader's (trial 1); the leader's replaces it while no row was made."""
    rows = SlotRows(PB, strict=False)
    rows.event(start(0, 0))
    feed(rows, 0, 0)
    rows.event(start(2, 1))                        # forged first
    rows.event(start(1, 1))                        # the leader's
    assert [d.trial for d in feed(rows, 1, 1)] == [1]
    assert rows.iteration_of[1] == 1
    with pytest.raises(Rejected):                  # a row made: its slot's trial stands
        rows.event(start(2, 1))


def test_an_abort_naming_a_committed_slot_restores_it():
    """An abort of slot 1 (forged, no key) came after its start and before its last
    trajectories; the leader's next abort names slot 1 as kept: it stands again, with
    what it held, and its row is made."""
    rows = SlotRows(PB, strict=True)
    rows.event(TrialEvent("start", 0, 0, 0))
    feed(rows, 0, 0)
    rows.event(TrialEvent("start", 1, 1, 1))
    rows.trajectory(1, 0, False, RUN.eta[1][0])
    rows.event(TrialEvent("abort", 1, 1, 2))        # forged
    assert 1 in rows.aborted
    done = rows.event(TrialEvent("abort", 2, 2, 3, kept=1))
    assert done == [] and 1 not in rows.aborted
    got = rows.trajectory(1, 0, True, RUN.xi[1][0])
    for r in range(1, PB.n):
        got += rows.trajectory(1, r, False, RUN.eta[1][r])
        got += rows.trajectory(1, r, True, RUN.xi[1][r])
    assert [d.trial for d in got] == [1]
    np.testing.assert_allclose(got[0].row, RUN.metrics[1], rtol=0, atol=1e-12)
    rows.event(TrialEvent("start", 2, 3, 4))       # the next trial, after slot 2's abort
    assert rows.iteration_of[3] == 2


def test_several_lost_starts_in_a_row_follow_from_the_slots_around_them():
    """A damaged chunk took the starts of slots 1 and 2 (their trajectories read back):
    from slot 0 (trial 0) to slot 3 (trial 3) the iteration rose by one per slot, so both
    committed: trials 1 and 2. With an abort known in between it rises by one less."""
    rows = SlotRows(PB, strict=False)
    rows.event(start(0, 0))
    feed(rows, 0, 0)
    feed(rows, 1, 1)
    feed(rows, 2, 2)
    rows.event(start(3, 3))
    assert sorted(d.trial for d in rows.infer()) == [1, 2]
    for k in range(3):
        np.testing.assert_allclose(rows.rows[k], RUN.metrics[k], rtol=0, atol=1e-12)
    rows = SlotRows(PB, strict=False)
    rows.event(start(0, 0))
    rows.event(abort(0, 0))                        # slot 0 aborted before its trajectories
    feed(rows, 1, 0)
    feed(rows, 2, 1)
    rows.event(start(2, 3))
    assert sorted(d.trial for d in rows.infer()) == [0, 1]
    np.testing.assert_allclose(rows.rows[1], RUN.metrics[1], rtol=0, atol=1e-12)
    # a batch simulation's recording: every slot runs its own number
    rows = SlotRows(PB, strict=False)
    feed(rows, 2, 2)
    feed(rows, 9, 2)                               # not a trial of the run: not taken
    assert [d.trial for d in rows.infer(identity=range(3))] == [2]
    assert {s for s, _, _ in rows.unstarted()} == {9}


def test_a_sealed_start_that_runs_the_last_iteration_again_explains_a_lost_abort():
    """A restarted leader aborts the slot it left open before this reader has matched it
    (the leader waits for no passive reader's answer), then starts the next slot with the
    same iteration: sealed, that start can only follow an abort, which is taken as lost
    (before: the monitor refused every later event and the run ended with no metrics for
    trials 2-6, CI of 27 Nov). Without the key, or two iterations back, it stays refused."""
    from formation_ilc.protocol.schedule import seal

    key = b"k" * 16
    rows = SlotRows(PB, strict=True, key=key)
    rows.event(seal(TrialEvent("start", 0, 0, 0), key))
    assert [d.trial for d in feed(rows, 0, 0)] == [0]
    rows.event(seal(TrialEvent("start", 1, 1, 1), key))  # the leader is killed in it
    with pytest.raises(Rejected, match="schedule runs trial 2"):
        rows.event(seal(TrialEvent("start", 0, 2, 3), key))
    rows.event(seal(TrialEvent("start", 1, 2, 3), key))  # its abort (seq 2) never came
    assert 1 in rows.aborted
    assert [d.trial for d in feed(rows, 2, 1)] == [1]
    np.testing.assert_allclose(rows.rows[1], RUN.metrics[1], rtol=0, atol=1e-12)
    bare = SlotRows(PB, strict=True)
    bare.event(TrialEvent("start", 0, 0, 0))
    bare.event(TrialEvent("start", 1, 1, 1))
    with pytest.raises(Rejected, match="schedule runs trial 2"):
        bare.event(TrialEvent("start", 1, 2, 3))
