"""The emulated links without ROS (formation_ilc.protocol.linkemu): the delay stream of the
iteration on every link, the trial window (held, refused, replayed), and realtime ticks with
their delivery deadline. Poses are (label, output) pairs, opaque to the core."""

from __future__ import annotations

import numpy as np
import pytest

from formation_ilc.config.runconfig import make_config
from formation_ilc.core.clock import Rejected
from formation_ilc.core.links import LEADER, delivered_label
from formation_ilc.protocol.linkemu import SHARED, EmulatedLinks
from formation_ilc.protocol.schedule import ABORT, START, TrialEvent


def emulator(mode: str = "lockstep", seed: int = 9) -> EmulatedLinks:
    return EmulatedLinks(make_config("paper-triangle3", seed=seed, mode=mode))


def start(links: EmulatedLinks, slot: int, seq: int, trial: int | None = None):
    links.said_ready()
    taken, out = links.on_event(TrialEvent(START, slot if trial is None else trial, slot, seq))
    assert taken is not None
    return out


def pose(links: EmulatedLinks, k: int, s: int, j: int) -> tuple[int, np.ndarray]:
    return links.clock.stamp_ns(k, s), np.full(3, 10.0 * j + s)


def feed(links: EmulatedLinks, k: int, s: int, first: int = 0):
    """The sample-s poses of robots ``first``.. and the reference of slot k; the ticks they
    release."""
    ns = links.clock.stamp_ns(k, s)
    ticks = links.on_reference(ns, (ns, np.zeros(3))).ticks
    for j in range(first, links.n):
        ticks += links.on_shared(j, ns, pose(links, k, s, j)).ticks
    return ticks


def reason(f, *args) -> str:
    with pytest.raises(Rejected) as exc:
        f(*args)
    return exc.value.reason


def test_each_tick_delivers_the_iterations_delay_stream_as_soon_as_its_poses_are_in():
    """Lockstep: robot i's tick t goes out at the input that completes what it needs (the
    poses its links deliver at t, its own sample t-1) once every tick t-1 is out; the
    poses delivered are the iteration's delay stream, each tick once."""
    links = emulator()
    assert not start(links, 0, 0).ticks
    pb, clock, sc = links.pb, links.clock, links.cfg.scenario
    tau, tau0 = sc.uncertainty.draw_delays(sc.seed, 0, pb.n, pb.src.shape[1], pb.samples)
    n_t = 6
    emitted: dict[tuple[int, int, int], tuple[int, int]] = {}  # (i, m, t) -> input step
    for t in range(n_t):
        ns = clock.stamp_ns(0, t)
        for step in range(pb.n + 1):  # the reference, then robot 0's pose, 1's, ...
            got = links.on_reference(ns, (ns, np.zeros(3))) if step == 0 else \
                links.on_shared(step - 1, ns, pose(links, 0, t, step - 1))
            for i, m, tick, p in got.ticks:
                tt = clock.decode(tick)[1]
                assert (i, m, tt) not in emitted  # each tick of each link once
                emitted[(i, m, tt)] = (t, step)
                sender, ell = links.links[i][m]
                d = int(tau0[i, tt] if sender == LEADER else tau[i, ell, tt])
                s = delivered_label(tt, d)
                assert p is None if s < 0 else p[0] == clock.stamp_ns(0, s)
    eager = 0
    opened = (0, 0)  # the input step at which tick t opened (every tick t-1 out)
    for t in range(n_t):
        out_at = []
        for i in range(pb.n):
            # the input step at which robot i's tick t has all it needs: the tick open,
            # its own sample t-1 in, every pose its links deliver at t in
            need = [opened] + ([(t - 1, i + 1)] if t > 0 else [])
            for _, ell in links.links[i]:
                s = delivered_label(t, int(tau0[i, t] if ell < 0 else tau[i, ell, t]))
                if s >= 0:
                    need.append((s, 0 if ell < 0 else int(pb.src[i, ell]) + 1))
            want = max(need)
            for m in range(len(links.links[i])):
                assert emitted[(i, m, t)] == want, (i, m, t)
            eager += want < (t, pb.n)
            out_at.append(want)
        opened = max(out_at)
    assert eager > 0  # some robots were not held for the last robot's pose
    # what went out (ticks up to n_t, the next ones of robots whose poses were in already)
    assert sum(sum(h.values()) for h in links.injected.values()) == sum(
        1 for i, m, t in emitted
        if delivered_label(t, int(tau0[i, t] if links.links[i][m][1] < 0
                                  else tau[i, links.links[i][m][1], t])) >= 0)


def test_the_last_tick_reports_the_trial_and_opens_the_next_slot():
    links = emulator()
    start(links, 0, 0)
    done = []
    for t in range(links.T):
        ns = links.clock.stamp_ns(0, t)
        done.append(links.on_reference(ns, (ns, np.zeros(3))).done)
        for j in range(links.n):
            done.append(links.on_shared(j, ns, pose(links, 0, t, j)).done)
    assert done.count(True) == 1 and links.reported  # once, when the last tick went out
    rep = links.report()
    assert (rep["trial"], rep["slot"]) == (0, 0) and set(rep["injected"]) == set(links.injected)
    # now a pose of slot 1 may exist: held until its start, then replayed
    assert not links.on_shared(0, links.clock.stamp_ns(1, 0), pose(links, 1, 0, 0)).ticks
    assert len(links.early) == 1
    ticks = feed_after_start(links)
    assert links.k == 1 and not links.early
    tick0 = links.clock.stamp_ns(1, 0)
    assert sorted((i, m) for i, m, t, _ in ticks if t == tick0) == [
        (i, m) for i in range(links.n) for m in range(len(links.links[i]))]


def feed_after_start(links: EmulatedLinks):
    """Start slot 1 and feed the rest of its sample 0 (robot 0's came before the start)."""
    out = start(links, 1, 1)
    assert not out.refused and links.count[0] == 1
    ns = links.clock.stamp_ns(1, 0)
    ticks = out.ticks + links.on_reference(ns, (ns, np.zeros(3))).ticks
    for j in range(1, links.n):
        ticks += links.on_shared(j, ns, pose(links, 1, 0, j)).ticks
    return ticks


def test_labels_outside_the_window_are_refused_and_move_nothing():
    links = emulator()
    clk = links.clock
    # before any start: slot 0 is next (held), slot 1 is not
    assert reason(links.on_shared, 0, clk.stamp_ns(1, 0), pose(links, 1, 0, 0)) == "future"
    assert not links.on_shared(0, clk.stamp_ns(0, 0), pose(links, 0, 0, 0)).ticks
    start(links, 0, 0)
    assert links.count[0] == 1  # the held pose was replayed
    cases = [
        (clk.stamp_ns(1, 0), "future"),   # the next slot, before this one is delivered
        (clk.stamp_ns(2, 0), "future"),   # a later slot
        (clk.stamp_ns(0, 3), "future"),   # lockstep: beyond the sample being collected
        (clk.stamp_ns(0, 0), "duplicate"),
        (-1, "malformed"),
    ]
    for ns, why in cases:
        assert reason(links.on_shared, 0, ns, (ns, np.zeros(3))) == why, ns
    assert links.count[0] == 1 and not links.early
    feed(links, 0, 0, first=1)
    assert links.next_t >= 1  # every robot's tick 0 is out
    assert reason(links.on_shared, 0, clk.stamp_ns(0, 0), (0, np.zeros(3))) == "duplicate"
    # aborted: the rest of the slot is stale, and held inputs of it are forgotten
    taken, _ = links.on_event(TrialEvent(ABORT, 0, 0, 1))
    assert taken is not None and not links.active
    assert reason(links.on_reference, clk.stamp_ns(0, 1), (0, np.zeros(3))) == "stale"


def test_held_inputs_are_bounded_and_refused_on_replay_with_their_reason():
    links = emulator()
    ns = links.clock.stamp_ns(0, 0)
    links.on_shared(0, ns, pose(links, 0, 0, 0))
    links.on_shared(0, ns, pose(links, 0, 0, 0))  # a copy: held too (no trial yet)
    while len(links.early) < links.early_max:
        links.on_reference(ns, (ns, np.zeros(3)))
    assert reason(links.on_reference, ns, (ns, np.zeros(3))) == "future"
    out = start(links, 0, 0)
    assert [(kind, j, e.reason) for kind, j, e in out.refused][0] == (SHARED, 0, "duplicate")
    assert len(out.refused) == links.early_max - 2  # the second copy, every reference but one


def test_realtime_ticks_deliver_what_is_in_by_the_deadline_and_count_the_rest_late():
    """paper-triangle3: robot 1 sees the leader, robots 2 and 3 see robot 1, whose poses
    never come here."""
    links = emulator("realtime", seed=3)
    start(links, 0, 0)
    clk, sc, pb = links.clock, links.cfg.scenario, links.pb
    assert pb.src.tolist() == [[-1], [0], [0]]
    tau, _ = sc.uncertainty.draw_delays(sc.seed, 0, pb.n, 1, links.T)
    late = {"robot_1->robot_2": 0, "robot_1->robot_3": 0}
    for t in range(6):
        out = links.on_clock(clk.stamp_ns(0, t))
        assert out.arm
        ns = clk.stamp_ns(0, t)
        out.ticks += links.on_reference(ns, (ns, np.zeros(3))).ticks
        for j in (1, 2):
            out.ticks += links.on_shared(j, ns, pose(links, 0, t, j)).ticks
        missing = {i for i in (1, 2) if delivered_label(t, int(tau[i, 0, t])) >= 0}
        assert {i for i, *_ in out.ticks} == {0, 1, 2} - missing
        assert set(links.waiting) == missing
        forced = links.deadline()  # out without robot 1's pose, counted late
        assert not links.waiting and {i for i, *_ in forced.ticks} == missing
        assert all(p is None for *_, p in forced.ticks)
        for i in missing:
            late[f"robot_1->robot_{i + 1}"] += 1
        assert links.late == {"leader->robot_1": 0, **late}
    assert sum(late.values()) > 0
    assert reason(links.on_clock, clk.stamp_ns(0, 5)) == "duplicate"
    assert reason(links.on_clock, clk.stamp_ns(0, 4)) == "out_of_order"
    # a pose of a past sample is still taken in realtime (a stalled emulator)
    links.on_shared(0, clk.stamp_ns(0, 0), pose(links, 0, 0, 0))
    assert links.shared[0][0] is not None
    # a tick that comes before the previous deadline fired sends the previous one first
    links.on_clock(clk.stamp_ns(0, 6))
    waited = set(links.waiting)
    out = links.on_clock(clk.stamp_ns(0, 7))
    assert out.arm and waited <= {i for i, *_ in out.ticks}
    # an abort of the slot stops the deliveries
    links.on_event(TrialEvent(ABORT, 0, 0, 1))
    assert not links.waiting and not links.active


def test_realtime_reports_after_the_last_ticks_deliveries():
    links = emulator("realtime")
    start(links, 0, 0)
    clk = links.clock
    for t in range(links.T):
        out = links.on_clock(clk.stamp_ns(0, t))
        out_d = links.deadline() if links.waiting else out
        assert (out.done or out_d.done) == (t == links.T - 1)
    assert links.reported and not links.on_clock(clk.stamp_ns(0, links.T)).ticks


def test_realtime_a_tick_never_heard_is_counted_late_not_lost_from_the_count():
    """A starved emulator that never hears tick 2's ``/clock`` sends nothing at it: by the
    trial's report every due delivery of the model is either injected or late."""
    links = emulator("realtime", seed=3)
    start(links, 0, 0)
    clk, sc, pb = links.clock, links.cfg.scenario, links.pb
    tau, tau0 = sc.uncertainty.draw_delays(sc.seed, 0, pb.n, 1, links.T)
    for t in range(links.T):
        if t != 2:  # its poses come, its /clock does not
            links.on_clock(clk.stamp_ns(0, t))
        feed(links, 0, t)
        links.deadline()
    assert links.reported and links.unsent == pb.n
    due = {"leader->robot_1": sum(delivered_label(t, int(tau0[0, t])) >= 0
                                  for t in range(links.T))}
    for i in (1, 2):
        due[f"robot_1->robot_{i + 1}"] = sum(delivered_label(t, int(tau[i, 0, t])) >= 0
                                             for t in range(links.T))
    for name, n_due in due.items():
        assert sum(links.injected[name].values()) + links.late[name] == n_due, name
    # exactly tick 2's due deliveries are late: every pose came, nothing else was missing
    late2 = {"leader->robot_1": int(delivered_label(2, int(tau0[0, 2])) >= 0),
             **{f"robot_1->robot_{i + 1}": int(delivered_label(2, int(tau[i, 0, 2])) >= 0)
                for i in (1, 2)}}
    assert links.late == late2
    assert links.report()["ticks_unheard"] == pb.n
