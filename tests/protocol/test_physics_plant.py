"""The physics plant without ROS (formation_ilc.protocol.physics_plant): the kinematic
plant's schedule with the PyBullet world as its steps, and the physics bases."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("pybullet", reason="the physics extra: pip install -e .[physics]")

from formation_ilc.config.runconfig import RunConfig  # noqa: E402
from formation_ilc.config.scenario import load_scenario, scenario_from_text  # noqa: E402
from formation_ilc.protocol.physics_plant import BaseRobots, PhysicsPlant  # noqa: E402
from formation_ilc.protocol.schedule import START, TrialEvent  # noqa: E402


def short_config() -> RunConfig:
    text = load_scenario("paper-triangle3").text.replace("samples: 140", "samples: 20")
    sc = scenario_from_text(text, "short.yaml").with_options(noise=False, delay=False)
    return RunConfig(sc, run_id="r")


def test_a_lockstep_trial_drives_bodies_and_reports_them():
    plant = PhysicsPlant(short_config())
    try:
        plant.said_ready()
        assert plant.on_event(TrialEvent(START, 0, 0, 0), 0.0) is not None
        start = plant.xi[:, 0].copy()
        # placed at the desired start, settled on its wheels
        np.testing.assert_allclose(start, plant.pb.eta_d[:, 0], atol=5e-3)
        for _ in range(plant.T):
            s = plant.sample()
            np.testing.assert_array_equal(s.eta, plant.xi[:, s.t])  # ground truth, no noise
            plant.sent(0.0)
            for r in range(plant.n):
                plant.command(r, np.array([0.3, 0.0]), 0.0)
        assert plant.sample().last
        # 4 s at 0.3 m/s from rest: the motors' lag costs a little of the 1.2 m
        moved = np.hypot(*(plant.xi[:, -1, :2] - start[:, :2]).T)
        assert ((moved > 1.0) & (moved < 1.2)).all()
        rep = plant.report()
        assert rep["model"] == "p3dx" and rep["substeps"] == 48 and rep["contacts"] == {}
        assert rep["tilt_by_trial"]["0"] == rep["tilt_max"] < math.radians(5)
        assert rep["timing"]["samples"] == plant.T
    finally:
        plant.close()


def test_bad_plant_parameters_are_refused():
    with pytest.raises(ValueError, match="parameter pose: one of truth, odometry"):
        PhysicsPlant(short_config(), pose="gps")
    with pytest.raises(ValueError, match="parameter rate"):
        PhysicsPlant(short_config(), rate=0.0)


def test_bases_hold_commands_report_what_they_were_asked_and_stop_when_silent():
    bases = BaseRobots("p3dx", np.array([[0.0, 0.0, 0.0], [3.0, 0.0, math.pi / 2]]), 0.02)
    try:
        bases.command(0, 0.2, 0.0, stamp=1.0, now=0.0)
        bases.command(0, 0.3, 0.0, stamp=1.1, now=0.0)   # 1 m/s^2 between the stamps
        bases.command(1, 0.2, 0.5, stamp=1.0, now=0.0)
        for k in range(25):                              # 0.5 s: inside the time-out
            odom = bases.step(0.02 * k)
        (x0, y0, th0), (v0, _), q0 = odom[0]
        # held as asked, under the body's acceleration limit (0.3 m/s^2): 0.15 m/s after
        # 0.5 s, about 0.04 m
        assert x0 > 0.03 and v0 == 0.3 and abs(y0) < 0.01
        assert math.hypot(*q0) == pytest.approx(1.0)
        (x1, _, th1), _, _ = odom[1]
        assert x1 > 0.0 and th1 > 0.05                   # in its own start frame
        rep = bases.report()["commands_max"]["robot_1"]
        assert rep["v"] == 0.3 and rep["a"] == pytest.approx(1.0)
        assert bases.step(10.0)[0][1] == (0.0, 0.0)      # silent past cmd_timeout: zero
    finally:
        bases.close()


@pytest.mark.parametrize(("policy", "retries", "actions"), [
    ("stop", 1, ["stop", "give_up"]), ("abort", 2, ["abort"]), ("continue", 0, ["continue"])])
def test_a_contact_stops_the_robots_holds_the_trial_and_counts_the_reruns(policy, retries,
                                                                          actions):
    """Two robots driven into each other: the first contact of a trial is the event acted
    on, the robots stand afterwards (stop, abort), the trial is held for the leader's abort
    (stop; the abort of its slot releases it), and the re-runs of one iteration are
    counted. A pair is said once a trial."""
    from formation_ilc.protocol.schedule import ABORT

    plant = PhysicsPlant(short_config(), on_contact=policy, retries=retries)
    try:
        seen = []
        for slot, seq in ((0, 0), (1, 2)):
            plant.said_ready()
            plant.on_event(TrialEvent(START, 0, slot, seq), 0.0)
            # robots 2 and 3 (abeam, 1.2 m apart) turn towards each other at full speed
            while not plant.sample().last:
                plant.sent(0.0)
                for r, u in enumerate(([0.0, 0.0], [0.6, -1.5], [0.6, 1.5])):
                    plant.command(r, np.array(u), 0.0)
                for ev in plant.take_contacts():
                    assert ev.acts == (not seen or seen[-1].slot != slot)
                    if ev.acts:
                        seen.append(ev)
                        assert (2, 3) in [(p[0], p[1]) for p in ev.pairs]
                    assert plant.take_contacts() == []  # said once
                if plant.held:
                    break
            if seen[-1].action == "stop":
                assert plant.held  # no sample after the contact until the abort
                plant.on_event(TrialEvent(ABORT, 0, slot, seq + 1), 0.0)
                assert not plant.held
            if len(seen) == len(actions):
                break
        assert [e.action for e in seen] == actions
        # every event of the trial so far names a pair not said before in it
        said = [(p[0], p[1]) for ev in [seen[-1]] for p in ev.pairs]
        assert len(said) == len(set(said))
        if policy != "continue":  # the robots stood after the contact
            assert np.abs(plant.u[:, seen[-1].sample:]).max(initial=0.0) == 0.0
    finally:
        plant.close()


def test_every_new_contact_or_tilt_is_said_once_and_the_first_decides():
    """``ContactWatch``: each pair that comes into contact and each robot tipped past the
    limit is an event, once per trial or return; the first one of a window decides, later
    ones carry its action; the re-runs of an iteration end in give_up; a return's stop ends
    the run (nothing to run again); a return that begins with robots still touching does
    not say that contact again."""
    from formation_ilc.protocol.physics_plant import ContactWatch

    flat = np.zeros(3)
    w = ContactWatch("stop", retries=1, tilt_limit=math.radians(10))
    a = w.check(0, 0, 5, [(2, 3, 0.01, 0.001)], flat)
    assert a is not None and a.acts and a.action == "stop" and a.n == 1
    assert w.check(0, 0, 6, [(2, 3, 0.02, 0.001)], flat) is None  # the same pair, again
    b = w.check(0, 0, 7, [(2, 3, 0.03, 0.001), (1, 2, 0.01, 0.0)],
                np.radians([0.0, 12.0, 3.0]))
    assert b is not None and not b.acts and b.action == "stop"
    assert [p[:2] for p in b.pairs] == [(1, 2)] and b.tilted == 2 and b.n == 2
    assert "robot 2 tilted 12.0 deg" in b.line(0.2, w.tilt_limit)
    assert b.line(0.2, w.tilt_limit).startswith("trial 0 (slot 0), t = 1.4 s: robots 1 and 2")
    w.window()  # the trial runs again (slot 1): the same pair is news, the retry spent
    c = w.check(0, 1, 4, [(2, 3, 0.01, 0.0)], flat)
    assert c is not None and c.acts and c.action == "give_up" and w.reruns == {0: 2}
    w.window(carry=True)  # its return: still touching is no news, a new pair is
    assert w.check(0, 1, -1, [(2, 3, 0.5, 0.0)], flat, "return", 0.4) is None
    d = w.check(0, 1, -1, [(2, 3, 0.5, 0.0), (1, 3, 0.1, 0.0)], flat, "return", 0.6)
    assert d is not None and d.acts and d.action == "abort" and d.phase == "return"
    assert d.line(0.2, w.tilt_limit) == ("trial 0 (slot 1), 0.6 s into the return to the "
                                         "start poses: robots 1 and 3 in contact (0.0 cm "
                                         "deep)")
    with pytest.raises(ValueError, match="on_contact"):
        ContactWatch("ignore")


class _Bases:
    """What ``BaseTrials`` reads of the physics bases: the window's pairs, the tilts."""

    def __init__(self):
        self.pairs: list[tuple[int, int, float, float]] = []
        self.held = False
        self.windows = 0
        self.world = self

    def window(self):
        self.windows += 1
        self.pairs = []

    def window_pairs(self):
        return list(self.pairs)

    def tilt(self):
        return np.zeros(3)


def test_the_bases_count_contacts_per_trial_and_return_and_hold_the_robots():
    """``BaseTrials``: a start opens the trial (its agreed wall start), a contact holds the
    robots and waits for the leader's abort (``stop``), the abort begins the return, a
    trial that runs to its end reports its contacts for the rows and begins its return."""
    from formation_ilc.protocol.physics_plant import BaseTrials, ContactWatch
    from formation_ilc.protocol.schedule import ABORT

    cfg = short_config()
    bases = _Bases()
    trials = BaseTrials(cfg, bases, ContactWatch("stop", retries=2))  # type: ignore[arg-type]
    dt_ns, t0 = cfg.clock.dt_ns, 10**18
    trials.follower.said_ready()
    assert trials.on_event(TrialEvent(START, 0, 0, 0, start_wall_ns=t0), t0) is not None
    assert trials.phase == "trial" and bases.windows == 1
    assert trials.tick(t0 + 3 * dt_ns) == (None, False)
    bases.pairs = [(1, 2, 0.02, 0.001)]
    ev, ended = trials.tick(t0 + 4 * dt_ns)
    assert ev is not None and ev.sample == 4 and ev.action == "stop" and not ended
    assert trials.held and bases.held  # the robots stand until the leader aborts
    assert trials.tick(t0 + 30 * dt_ns) == (None, False)  # held: the trial does not end
    assert trials.by_trial["contacts_by_trial"] == {"0": {"robot_1-robot_2": 0.02}}
    assert trials.on_event(TrialEvent(ABORT, 0, 0, 1), t0 + 31 * dt_ns) is not None
    assert trials.phase == "return" and not bases.held
    trials.follower.said_ready()
    t1 = t0 + 40 * dt_ns
    assert trials.on_event(TrialEvent(START, 0, 1, 2, start_wall_ns=t1), t1) is not None
    ev, ended = trials.tick(t1 + cfg.scenario.samples * dt_ns)
    assert ev is None and ended  # no contact this time: it ran to its end
    report = trials.report()
    assert report["contact_report"] == {"slot": 1, "pairs": []}
    trials.ended(t1 + cfg.scenario.samples * dt_ns)
    bases.pairs = [(2, 3, 0.05, 0.0)]
    ev, _ = trials.tick(t1 + (cfg.scenario.samples + 5) * dt_ns)
    assert ev is not None and ev.phase == "return" and ev.action == "abort"
    assert abs(ev.seconds - 5 * dt_ns * 1e-9) < 1e-9
    assert trials.by_trial["return_contacts_by_trial"] == {"0": {"robot_2-robot_3": 0.05}}


def test_a_realtime_trial_of_the_physics_plant_keeps_its_commands_and_its_contacts_apart():
    """In realtime the plant marks each robot whose command came this tick (the kinematic
    plant's ``fresh``); the physics plant's contact events are a list of their own (a
    list once took that name and a realtime trial broke on its first command)."""
    from dataclasses import replace

    plant = PhysicsPlant(replace(short_config(), mode="realtime"))
    try:
        plant.said_ready()
        assert plant.on_event(TrialEvent(START, 0, 0, 0), 0.0) is not None
        for t in range(3):
            for r in range(plant.n):
                plant.command(r, np.array([0.2, 0.0]), 0.01 + t * plant.pb.dt)
            assert plant.tick((t + 1) * plant.pb.dt)
        assert sum(plant.missed.values()) == 0  # every command came before its tick
        assert plant.take_contacts() == []
        np.testing.assert_allclose(plant.u[:, :3, 0], 0.2)
    finally:
        plant.close()
