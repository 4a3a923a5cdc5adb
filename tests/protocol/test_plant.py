"""The kinematic plant without ROS (formation_ilc.protocol.plant), and a whole team run from the
pure cores alone: plant, emulated links and robot learners fed event by event, as their nodes
are fed by messages, equal the batch simulator bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from formation_ilc.config.runconfig import RunConfig, make_config
from formation_ilc.config.scenario import load_scenario, scenario_from_text
from formation_ilc.core.clock import Rejected
from formation_ilc.core.kinematics import step_into
from formation_ilc.core.links import LOST, robot_name
from formation_ilc.protocol.learner import RobotLearner
from formation_ilc.protocol.linkemu import EmulatedLinks
from formation_ilc.protocol.plant import KinematicPlant
from formation_ilc.protocol.schedule import ABORT, START, TrialEvent

NOW = 100.0  # [s] any monotonic time


def started(plant: KinematicPlant, slot: int, trial: int, seq: int,
            now: float = NOW) -> KinematicPlant:
    plant.said_ready()
    assert plant.on_event(TrialEvent(START, trial, slot, seq), now) is not None
    return plant


def run_team(cfg, trials: int):
    """Trials of a team made of the pure cores; returns per trial the plant's true states,
    the robots' commands and their memories after learning."""
    plant = KinematicPlant(cfg)
    links: EmulatedLinks[tuple[int, np.ndarray]] = EmulatedLinks(cfg)
    pb, clock, ref = plant.pb, plant.clock, cfg.scenario.reference
    team = [RobotLearner(pb, r, clock) for r in range(pb.n)]
    out = []
    for k in range(trials):
        links.said_ready()
        taken, sent = links.on_event(TrialEvent(START, k, k, k))
        assert taken is not None and not sent.ticks
        started(plant, k, k, k, now=float(k))
        u = np.zeros((pb.n, pb.samples, 2))
        done = 0
        while True:
            s = plant.sample()
            for r, lrn in enumerate(team):
                assert lrn.on_pose(s.stamp_ns, s.eta[r]).last == s.last
            if s.last:
                break
            plant.sent(float(k))
            ticks = links.on_reference(s.stamp_ns, (s.stamp_ns, ref[s.t])).ticks
            for j in range(pb.n):
                em = links.on_shared(j, s.stamp_ns, (s.stamp_ns, s.eta[j].copy()))
                ticks += em.ticks
                done += em.done  # once, when the last tick is out (which may be before
                # the last poses are: the ticks of a robot go out once its poses are in)
            for i, m, tick, pose in ticks:
                team[i].on_link_tick(links.links[i][m][0], tick, pose)
            for r, lrn in enumerate(team):
                assert lrn.can_command()
                u[r, s.t] = lrn.command()
                assert plant.command(r, u[r, s.t], float(k)) == (r == pb.n - 1)
        assert done == 1 and links.reported
        trajs = [lrn.finish_trial()[1].copy() for lrn in team]
        for r, lrn in enumerate(team):
            lrn.try_learn()
            for j in pb.src[r]:
                if j >= 0:
                    lrn.on_trajectory(robot_name(j + 1), np.array(lrn.trajectory_stamps(k)),
                                      trajs[j])
            assert lrn.learned == k
        out.append((plant.xi.copy(), u, np.stack([lrn.memory[0] for lrn in team])))
    return plant, links, out


def lossy_config(loss: float) -> RunConfig:
    d = yaml.safe_load(load_scenario("paper-triangle3").text)
    d["delay"]["loss"] = loss
    return RunConfig(scenario_from_text(yaml.safe_dump(d), "lossy.yaml").with_options(seed=5))


@pytest.mark.parametrize("scenario", ["paper-triangle3", "paper-hexagon6", "lossy"])
def test_a_team_of_pure_cores_equals_the_batch_simulator(scenario):
    cfg = lossy_config(0.2) if scenario == "lossy" else make_config(scenario, seed=5)
    sc = cfg.scenario
    plant, links, got = run_team(cfg, trials=2)
    pb = plant.pb
    memory = np.zeros((pb.n, pb.samples, 2))
    for k, (xi, u, learned) in enumerate(got):
        shift, dist, noise = sc.uncertainty.draw_plant(sc.seed, k, pb.n, pb.samples)
        tau, tau0 = sc.uncertainty.draw_delays(sc.seed, k, pb.n, pb.src.shape[1], pb.samples)
        xi_ref, eta_ref, u_ref, memory = pb.trial(memory, pb.eta_d[:, 0] + shift, dist, noise,
                                                  tau, tau0)
        np.testing.assert_array_equal(xi, xi_ref)
        np.testing.assert_array_equal(u, u_ref)
        np.testing.assert_allclose(learned, memory, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(plant.eta, eta_ref)
    rep = plant.report()
    assert (rep["trial"], rep["slot"], rep["mode"]) == (1, 1, "lockstep")
    assert rep["timing"]["samples"] == 2 * pb.samples and rep["missed"] == {}
    # the links injected every delay the model scheduled, and nothing came late
    inj = links.report()
    assert "late" not in inj and ("lost" in inj) == (scenario == "lossy")
    n_links = int((pb.src >= 0).sum() + (pb.leader != 0).sum())
    assert len(inj["injected"]) == n_links
    # per link and trial: a delivery at every tick the model schedules one, or a loss
    lost = due = 0
    for k in range(2):
        tau, tau0 = sc.uncertainty.draw_delays(sc.seed, k, pb.n, pb.src.shape[1], pb.samples)
        ticks = [tau[i, ell, :pb.samples] for i in range(pb.n)
                 for ell in range(pb.src.shape[1]) if pb.src[i, ell] >= 0]
        ticks += [tau0[i, :pb.samples] for i in range(pb.n) if pb.leader[i]]
        lost += sum(int((d >= LOST).sum()) for d in ticks)
        due += sum(int((np.arange(pb.samples) - d >= 0).sum()) for d in ticks)
    assert sum(inj.get("lost", {}).values()) == lost
    assert sum(sum(h.values()) for h in inj["injected"].values()) == due
    assert (lost > 0) == (scenario == "lossy")


def test_lockstep_waits_for_every_robot_and_refuses_a_second_command():
    plant = KinematicPlant(make_config("paper-triangle3", seed=2))
    with pytest.raises(Rejected) as exc:
        plant.command(0, np.zeros(2), NOW)  # no trial
    assert exc.value.reason == "out_of_order"
    started(plant, 0, 0, 0)
    s = plant.sample()
    assert (s.k, s.t, s.last) == (0, 0, False) and s.stamp_ns == plant.clock.stamp_ns(0, 0)
    plant.sent(NOW)
    assert not plant.command(1, np.array([0.2, 0.1]), NOW + 0.01)
    with pytest.raises(Rejected) as exc:
        plant.command(1, np.array([0.2, 0.1]), NOW + 0.02)
    assert exc.value.reason == "out_of_order"
    assert plant.overdue(NOW + 5.0, timeout=4.0) == [0, 2]
    assert plant.overdue(NOW + 3.0, timeout=4.0) == []
    assert not plant.command(0, np.zeros(2), NOW + 0.03)
    assert plant.command(2, np.zeros(2), NOW + 0.5)
    assert plant.t == 1 and plant.latency == [pytest.approx(0.5)]
    # sample 1 is eq. (1) from sample 0 with the commands and the iteration's disturbance
    want = np.zeros((3, 3))
    step_into(plant.xi[:, 0], np.array([[0.0, 0.0], [0.2, 0.1], [0.0, 0.0]]),
              plant.dist[:, 0], plant.pb.dt, want)
    np.testing.assert_array_equal(plant.xi[:, 1], want)
    np.testing.assert_array_equal(plant.sample().eta, want + plant.noise[:, 1])


def test_a_trial_ends_at_sample_t_and_an_abort_stops_one():
    plant = started(KinematicPlant(make_config("paper-triangle3", seed=2, noise=False)),
                    0, 0, 0)
    for t in range(plant.T):
        plant.sent(NOW + t)
        for r in range(plant.n):
            plant.command(r, np.zeros(2), NOW + t + 0.5)
    s = plant.sample()
    assert s.last and s.t == plant.T and not plant.in_trial
    assert plant.stamps() == [plant.clock.stamp_ns(0, t) for t in range(plant.T + 1)]
    assert plant.report()["timing"]["seconds"] == pytest.approx(plant.T - 0.5)
    # the same iteration again in slot 1, aborted: the plant drops it
    started(plant, 1, 0, 1)
    assert plant.in_trial and plant.iteration == 0 and plant.k == 1
    plant.sent(NOW)
    taken = plant.on_event(TrialEvent(ABORT, 0, 1, 2), NOW)
    assert taken is not None and not plant.in_trial and not plant.pending
    assert plant.overdue(NOW + 100.0, 1.0) == []
    assert plant.on_event(TrialEvent(ABORT, 0, 1, 2), NOW) is None  # repeated


def test_realtime_holds_missed_commands_and_counts_them():
    plant = started(KinematicPlant(make_config("paper-triangle3", seed=2, mode="realtime")),
                    0, 0, 0)
    assert plant.tick_due == pytest.approx(NOW + plant.pb.dt)
    plant.sent(NOW)
    u1 = np.array([0.3, 0.0])
    assert not plant.command(0, np.array([0.1, 0.0]), NOW + 0.01)
    assert not plant.command(0, u1, NOW + 0.02)  # replaces the first before the tick
    assert not plant.command(1, u1, NOW + 0.03)
    assert plant.tick(NOW + plant.pb.dt + 0.004)
    assert plant.superseded == 1 and plant.arrival == pytest.approx([0.01, 0.03])
    assert plant.missed == {"robot_1": 0, "robot_2": 0, "robot_3": 1}
    np.testing.assert_array_equal(plant.u[:, 0], [u1, u1, [0.0, 0.0]])
    assert plant.tick_lag == pytest.approx([0.004])
    plant.sent(NOW + plant.pb.dt)
    assert plant.tick(NOW + 2 * plant.pb.dt)  # nobody commanded sample 1: all held
    np.testing.assert_array_equal(plant.u[:, 1], plant.u[:, 0])
    assert plant.missed == {"robot_1": 1, "robot_2": 1, "robot_3": 2}
    while plant.in_trial:
        plant.tick(NOW)
    assert plant.sample().last and not plant.tick(NOW)  # no trial: the ticks may stop
    plant.command(0, u1, NOW)
    assert plant.late_cmds == 1
    rep = plant.report()
    tim = rep["timing"]
    assert tim["commands"] == 2 and tim["missed_total"] == sum(plant.missed.values())
    # where in the trial: sample 0 (robot 3), then every robot at every later sample
    # (nobody commanded after the first tick); the report names the ten worst samples
    assert plant.missed_at[0] == 1 and plant.missed_at[1] == 3
    assert sum(plant.missed_at.values()) == tim["missed_total"]
    assert len(rep["missed_at"]) == 10 and set(rep["missed_at"].values()) == {3}


def test_the_simulator_refuses_wallclock():
    with pytest.raises(ValueError, match="wallclock"):
        KinematicPlant(make_config("paper-triangle3", links="direct", mode="wallclock"))


def test_the_poses_others_wait_for_are_sent_first():
    plant = KinematicPlant(make_config("paper-hexagon6"))
    senders = {int(j) for j in plant.pb.src.ravel() if j >= 0}
    k = len(senders)
    assert 0 < k < plant.n
    assert sorted(plant.send_order) == list(range(plant.n))
    assert set(plant.send_order[:k]) == senders
