"""A wall-clock trial's progress on the console (formation_ilc.cli.trialprogress), without
ROS: the events and rows stand for what the launcher's monitor has."""

from __future__ import annotations

from formation_ilc.cli.trialprogress import TrialProgress

S = 1_000_000_000


def start(trial: int, wall: int, slot: int | None = None) -> dict:
    return {"event": "start", "trial": trial, "slot": trial if slot is None else slot,
            "start_wall_ns": wall}


def test_a_wall_clock_trial_says_its_progress_while_its_samples_run():
    p = TrialProgress(28.0, 20, every=10.0)
    t0 = 1_000 * S
    events = [start(3, t0)]
    assert p.update(t0 - S // 2, events, set()) is None  # (it starts a little ahead)
    assert p.update(t0 + S, events, set()) == "trial 3 of 0..19: 1 s of 28 s of samples"
    assert p.update(t0 + 5 * S, events, set()) is None  # within 10 s of the last
    assert p.update(t0 + 11 * S, events, set()) == "trial 3 of 0..19: 11 s of 28 s of samples"
    assert p.update(t0 + 21 * S, events, {3}) is None  # its row is in
    assert p.update(t0 + 29 * S, events, set()) is None  # its samples are over
    # an end, or a lockstep start (no wall time): nothing
    assert p.update(t0 + 30 * S, [*events, {"event": "end", "trial": 3, "slot": 3}],
                    set()) is None
    assert p.update(t0, [{"event": "start", "trial": 4, "slot": 4}], set()) is None
    # the next slot (a trial run again) is said at once
    again = [*events, start(3, t0 + 40 * S, slot=4)]
    assert p.update(t0 + 41 * S, again, set()) == "trial 3 of 0..19: 1 s of 28 s of samples"
