"""Multi-process test of the realtime mode: the simulator ticks on the wall clock at dT.

A short run (paper-triangle3 with dT = 0.05 s and 120 samples, 6 s per trial, 2 trials)
of real node processes on localhost. Realtime runs are not bound to equal the batch
simulator (a late command is held, a late delivery is not delivered), so the test checks
the accounting that makes a realtime run interpretable, and equality with the batch
simulator when that accounting says nothing was late.
"""

from __future__ import annotations

import csv
import json
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import yaml

from formation_ilc.config.scenario import load_scenario
from formation_ilc.core.metrics import read_metrics
from formation_ilc.model.safety import body_spec
from formation_ilc.model.simulate import Problem, simulate
from tests.stack.test_stack import TOL, launch

pytestmark = [pytest.mark.ros, pytest.mark.multiprocess]

TRIALS = 2
SEED = 5
# Measured (docs/distributed-stack.md): with every command and delivery on time the run
# equals the batch simulator to 1e-9 (the lockstep tolerance; seen in every run so far).
# Robot 2 stopped (SIGSTOP) for 0.5 s in this scenario: 9 missed samples, metrics within
# 1.1e-4 m of the batch run. A run with a few misses (a loaded machine) must stay within
# MISS_ATOL, and more for each sample missed or late: a loaded CI stalled the whole team
# for about 0.55 s (34 samples missed, 9 deliveries late) and ended 0.0105 m from the
# batch run (3.1e-4 m a sample), its filter changing 10 commands in a trial against 3
MISS_ATOL = 0.01
MISS_PER_SAMPLE = 5e-4


def short_scenario(tmp: Path) -> Path:
    data = yaml.safe_load(load_scenario("paper-triangle3").text)
    data.update(dt=0.05, samples=120, name="triangle3-rt")
    path = tmp / "triangle3-rt.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def expected_deliveries(sc, trials: int) -> dict[str, Counter[int]]:
    """Per link, how often each delay tau is scheduled by the model at ticks 0..T-1 (the
    stream of draw_delays, as the batch simulator uses it)."""
    pb = Problem.from_scenario(sc)
    out: dict[str, Counter[int]] = {}
    for k in range(trials):
        tau, tau0 = sc.uncertainty.draw_delays(sc.seed, k, pb.n, pb.src.shape[1], pb.samples)
        for i in range(pb.n):
            for ell, j in enumerate(pb.src[i]):
                if j < 0:
                    continue
                h = out.setdefault(f"robot_{j + 1}->robot_{i + 1}", Counter())
                for t in range(pb.samples):
                    if t - tau[i, ell, t] >= 0:
                        h[int(tau[i, ell, t])] += 1
            if pb.leader[i] != 0.0:
                h = out.setdefault(f"leader->robot_{i + 1}", Counter())
                for t in range(pb.samples):
                    if t - tau0[i, t] >= 0:
                        h[int(tau0[i, t])] += 1
    return out


def test_realtime_run_accounts_for_every_sample(ros_env, tmp_path):
    """Through the safety filter (the plant's team/poses): each robot must filter with the
    other robots' poses of the sample itself, as lockstep and the batch simulator do (it
    took them a sample late, and widened its distance by what a robot may move in one)."""
    scen = short_scenario(tmp_path)
    out = tmp_path / "run"
    # speeds from poses: with told commands the filter changes nothing in these two
    # short trials (batch: 0 against 2), and the equality below would not cover it
    res = launch(ros_env, out, str(scen), "--trials", str(TRIALS), "--seed", str(SEED),
                 "--mode", "realtime", "--safety", "--safety-motion", "poses", timeout=120)
    assert res.returncode == 0, res.stdout
    sc = load_scenario(str(scen)).with_options(seed=SEED)
    n, n_t = sc.n, sc.samples

    got = read_metrics(out / "metrics.csv")
    assert got.shape == (TRIALS, 9)
    np.testing.assert_array_equal(got[:, 0], np.arange(TRIALS))
    assert np.isfinite(got[:, :8]).all() and np.isnan(got[:, 8]).all()  # no bodies

    diag = json.loads((out / "diagnostics.json").read_text())
    sim = diag["robot_sim"]
    assert sim["mode"] == "realtime" and sim["trial"] == TRIALS - 1
    # a missed-sample count for every robot, and every (robot, sample) is either a command
    # that arrived before the next tick or a missed sample
    assert set(sim["missed"]) == {f"robot_{i + 1}" for i in range(n)}
    tim = sim["timing"]
    missed = sum(sim["missed"].values())
    assert tim["samples"] == TRIALS * n_t
    assert tim["commands"] + missed == n * TRIALS * n_t, (tim, sim["missed"])
    # a command counts when it came before the next tick fired: its latency from its own
    # tick's due time is under dT plus how late a tick fired (under load a tick can fire
    # late, and a command after its due time is still in time; how often is
    # scripts/bench_stack.py's to measure, not a test's)
    assert 0 < tim["p50_ms"] <= tim["p99_ms"] <= tim["max_ms"]
    assert tim["max_ms"] < 1e3 * sc.dt + tim["tick_lag_max_ms"], tim
    # the ticks follow the wall clock: TRIALS * T ticks of dT in about TRIALS * T * dT
    assert tim["seconds"] == pytest.approx(TRIALS * n_t * sc.dt, rel=0.05)
    for node, d in diag.items():
        assert sum(d.get("dropped", {}).values()) == 0, (node, d["dropped"])

    # delays: the model holds in sample units. Every delivery the model schedules is either
    # delivered (injected) or counted late, and the robots' eq. (11) measurements equal
    # what was delivered, link by link and delay by delay
    link = diag["link_emulator"]
    assert link["trial"] == TRIALS - 1
    late_links = sum(link["late"].values())
    for name, hist in expected_deliveries(sc, TRIALS).items():
        inj = {int(t): c for t, c in link["injected"][name].items()}
        assert sum(inj.values()) + link["late"][name] == sum(hist.values()), name
        if link["late"][name] == 0:
            assert inj == {t: c for t, c in hist.items() if c}, name
    with (out / "delays.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert rows
    # every delivery is either measured (used at its tick) or reached the robot after it
    # had commanded that sample (unused, counted by the robot)
    unused = {f"{s}->robot_{i + 1}": c for i in range(n)
              for s, c in diag[f"robot_{i + 1}"]["unused"].items()}
    assert set(unused) == {r["link"] for r in rows}
    for name in unused:
        meas = {int(r["tau"]): int(r["measured"]) for r in rows if r["link"] == name}
        inj = {int(r["tau"]): int(r["injected"]) for r in rows if r["link"] == name}
        assert sum(meas.values()) + unused[name] == sum(inj.values()), name
        if unused[name] == 0:
            assert meas == inj, name
    late_robots = sum(diag[f"robot_{i + 1}"]["late"]["links"] for i in range(n))
    # the filter acted, and on poses of the sample itself: the plant sends team/poses
    # before the robots' own poses (before, every sample with a robot in range was stale,
    # 242 here); one the transport had to send again on a loaded machine may come after
    filt = [diag[f"robot_{i + 1}"]["filter_total"] for i in range(n)]
    assert sum(f["changed"] for f in filt) > 0, filt
    stale = sum(f["stale"] for f in filt)
    assert stale <= 0.02 * n * TRIALS * n_t, filt
    untold = sum(f["untold"] for f in filt)  # none told: counted as such only when asked
    assert untold == 0, filt

    ref = simulate(sc, trials=TRIALS, safety=body_spec("p3dx", sc.dt, sc.uncertainty,
                                                       "poses")).metrics
    disturbed = missed + late_links + late_robots + stale + untold
    if disturbed == 0:
        # nothing late: the realtime run is the batch run
        np.testing.assert_allclose(got[:, 1:], ref[:, 1:], rtol=0, atol=TOL)
    else:
        # the errors stay near, by as much more as samples came late; the filter's count
        # of changed commands moves by a few (a late pose or command changes what the
        # filter sees: 6 against 4 in a CI trial)
        np.testing.assert_allclose(got[:, 1:7], ref[:, 1:7], rtol=0,
                                   atol=MISS_ATOL + MISS_PER_SAMPLE * disturbed)
        assert (np.abs(got[:, 7] - ref[:, 7]) <= 3 + 0.5 * ref[:, 7] + disturbed).all(), (
            got, ref, disturbed)


@pytest.mark.slow
def test_realtime_direct_links_learn_and_report_the_measured_delays(ros_env, tmp_path):
    """paper-triangle3 as it is (dT = 0.2 s, 28 s a trial) on the wall clock, the robots
    subscribing to each other: the delays are whatever the links give (here DDS on one
    machine, under a sample), the robots measure them by eq. (11) and the report shows
    them, and the team learns."""
    trials = 3
    out = tmp_path / "run"
    res = launch(ros_env, out, "paper-triangle3", "--trials", str(trials), "--seed",
                 str(SEED), "--mode", "realtime", "--links", "direct", timeout=300)
    assert res.returncode == 0, res.stdout
    assert "delays measured by the robots (eq. 11, all links)" in res.stdout
    got = read_metrics(out / "metrics.csv")
    assert got.shape == (trials, 9) and np.isfinite(got[:, :8]).all()  # no bodies: no contacts
    sc = load_scenario("paper-triangle3").with_options(seed=SEED)
    # it learns as the batch simulator does with (almost) no delay: DDS on one machine
    # delivers within a sample, so eq. (11) measures 0 or 1 (batch: 4.71 -> 3.45 m in 3
    # trials with no delay)
    ref = simulate(sc.with_options(delay=False), trials=trials).metrics
    assert got[-1, 1] < 0.8 * got[0, 1], got[:, 1]
    np.testing.assert_allclose(got[:, 1], ref[:, 1], rtol=0, atol=0.05)
    with (out / "delays.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    per_link: dict[str, int] = {}
    for r in rows:
        assert r["injected"] == ""
        per_link[r["link"]] = per_link.get(r["link"], 0) + int(r["measured"])
    assert set(per_link) == {"leader->robot_1", "robot_1->robot_2", "robot_1->robot_3"}
    diag = json.loads((out / "diagnostics.json").read_text())
    for name, count in per_link.items():
        commands = diag[name.split("->")[1]]["commands"]
        # a link contributes at most one measurement per commanded sample; it has none only
        # when nothing usable had arrived by the command (e.g. sample 0 of a trial)
        assert 0.9 * commands <= count <= commands, (name, count, commands)
    assert sum(diag[f"robot_{i + 1}"]["commands"] for i in range(sc.n)) > 0.95 * (
        sc.n * trials * sc.samples)
