"""Lockstep recovers a lost sample by sending it again: the plant re-sends a sample whose
commands are not all in after RESEND_S (the time-out still counts from the first send), and
a robot that gets its current sample again shares again the poses it shared in the trial
(nodes.robot; tests/stack/test_liveness.py floods them) -- a pose lost in a flood, or sent
before a restarted reader matched, costs seconds, not the whole time-out (protocol.plant,
protocol.learner)."""

from __future__ import annotations

import numpy as np

from formation_ilc.config.runconfig import make_config
from formation_ilc.model.simulate import Problem
from formation_ilc.protocol.learner import RobotLearner
from formation_ilc.protocol.plant import RESEND_S, KinematicPlant
from formation_ilc.protocol.schedule import START, TrialEvent

NOW = 100.0


def test_the_plant_sends_a_stalled_sample_again_every_resend_interval():
    plant = KinematicPlant(make_config("paper-triangle3", seed=2))
    assert not plant.resend_due(NOW)  # no trial
    plant.said_ready()
    plant.on_event(TrialEvent(START, 0, 0, 0), NOW)
    plant.sent(NOW)
    assert not plant.resend_due(NOW + RESEND_S - 0.01)
    assert plant.resend_due(NOW + RESEND_S)
    assert not plant.resend_due(NOW + RESEND_S + 0.5)   # one per interval
    assert plant.resend_due(NOW + 2 * RESEND_S)
    assert plant.resends == 2 and plant.report()["resends"] == 2
    assert plant.overdue(NOW + 20.5, timeout=20.0) == [0, 1, 2]  # from the first send
    for r in range(3):
        plant.command(r, np.zeros(2), NOW + 21)
    plant.sent(NOW + 21)
    assert not plant.resend_due(NOW + 21 + RESEND_S / 2)  # the next sample's own clock
    rt = KinematicPlant(make_config("paper-triangle3", seed=2, mode="realtime"))
    rt.said_ready()
    rt.on_event(TrialEvent(START, 0, 0, 0), NOW)
    rt.sent(NOW)
    assert not rt.resend_due(NOW + 10 * RESEND_S)  # realtime: the next tick is the repair


def test_a_robot_knows_its_current_sample_again_and_nothing_else():
    cfg = make_config("paper-triangle3", seed=2)
    pb = Problem.from_scenario(cfg.scenario)
    clk = cfg.clock
    lrn = RobotLearner(pb, 1, clk)
    assert not lrn.is_repeat(clk.stamp_ns(0, 0))  # nothing taken yet
    lrn.on_pose(clk.stamp_ns(0, 0), pb.eta_d[1, 0])
    assert lrn.is_repeat(clk.stamp_ns(0, 0))
    assert not lrn.is_repeat(clk.stamp_ns(0, 1)) and not lrn.is_repeat(clk.stamp_ns(1, 0))
    assert not lrn.is_repeat(-5)  # off the grid
    rt = RobotLearner(pb, 1, clk, realtime=True)
    rt.on_pose(clk.stamp_ns(0, 0), pb.eta_d[1, 0])
    assert not rt.is_repeat(clk.stamp_ns(0, 0))
