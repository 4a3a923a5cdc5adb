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
    """Two robots driven into each other: the first contact of a trial is one event, the
    robots stand afterwards (stop, abort), the trial is held for the leader's abort (stop;
    the abort of its slot releases it), and the re-runs of one iteration are counted."""
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
                ev = plant.take_contact()
                if ev is not None:
                    seen.append(ev)
                    assert (2, 3) in [(p[0], p[1]) for p in ev.pairs]
                    assert plant.take_contact() is None  # said once
                if plant.held:
                    break
            if seen[-1].action == "stop":
                assert plant.held  # no sample after the contact until the abort
                plant.on_event(TrialEvent(ABORT, 0, slot, seq + 1), 0.0)
                assert not plant.held
            if len(seen) == len(actions):
                break
        assert [e.action for e in seen] == actions
        if policy != "continue":  # the robots stood after the contact
            assert np.abs(plant.u[:, seen[-1].sample:]).max(initial=0.0) == 0.0
    finally:
        plant.close()
