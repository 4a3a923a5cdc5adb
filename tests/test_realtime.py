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

from formation_ilc.scenario import load_scenario
from formation_ilc.simulate import Problem, simulate
from tests.test_stack import TOL, launch, read_metrics

pytestmark = [pytest.mark.ros, pytest.mark.multiprocess]

TRIALS = 2
SEED = 5
# Measured (docs/distributed-stack.md): with every command and delivery on time the run
# equals the batch simulator to 1e-9 (the lockstep tolerance; seen in every run so far).
# Robot 2 stopped (SIGSTOP) for 0.5 s in this scenario: 9 missed samples, metrics within
# 1.1e-4 m of the batch run. A run with a few misses (a loaded machine) must stay within:
MISS_ATOL = 0.01


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
    scen = short_scenario(tmp_path)
    out = tmp_path / "run"
    res = launch(ros_env, out, str(scen), "--trials", str(TRIALS), "--seed", str(SEED),
                 "--mode", "realtime", timeout=120)
    assert res.returncode == 0, res.stdout
    sc = load_scenario(str(scen)).with_options(seed=SEED)
    n, n_t = sc.n, sc.samples

    got = read_metrics(out / "metrics.csv")
    assert got.shape == (TRIALS, 7)
    np.testing.assert_array_equal(got[:, 0], np.arange(TRIALS))
    assert np.isfinite(got).all()

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
    assert 0 < tim["p50_ms"] <= tim["p99_ms"] < 1e3 * sc.dt
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
    for r in rows:
        assert int(r["measured"]) == int(r["injected"]), r
    late_bundles = sum(diag[f"robot_{i + 1}"]["late"]["bundle"] for i in range(n))

    ref = simulate(sc, trials=TRIALS).metrics
    if missed == 0 and late_links == 0 and late_bundles == 0:
        # nothing late: the realtime run is the batch run
        np.testing.assert_allclose(got[:, 1:], ref[:, 1:], rtol=0, atol=TOL)
    else:
        np.testing.assert_allclose(got[:, 1:], ref[:, 1:], rtol=0, atol=MISS_ATOL)
